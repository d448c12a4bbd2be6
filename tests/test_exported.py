"""Traced programs stored beside the compilation cache (``jaxgrasp._exported``): read back
by a fresh ``stored_jit`` (as in a new process) without tracing, with the same values bit for
bit; keyed by name, static values and signature; a damaged file is traced again."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgrasp._exported import SUBDIR, stored_jit
from jaxgrasp.physics import mujoco_backend


@pytest.fixture
def store(tmp_path):
    """The compilation cache directory set to ``tmp_path`` for this test (JAX's own cache
    was set up at start and stays where it is; only the stored programs move)."""
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    yield tmp_path / SUBDIR
    jax.config.update("jax_compilation_cache_dir", before)


def _traced_counter(traced=None):
    """A new function object (JAX keeps traces per function: a new process has its own),
    noting each trace in ``traced``."""
    traced = [] if traced is None else traced

    def fn(x, pair):
        traced.append(x.shape)  # runs only while tracing
        return jnp.sin(x) * pair["a"] + jnp.cumsum(pair["b"])

    return fn, traced


def test_a_stored_program_is_read_back_without_tracing(store):
    args = (np.linspace(0, 1, 5, dtype=np.float32),
            {"a": np.float32(2.0), "b": np.arange(5, dtype=np.float32)})
    fn, traced = _traced_counter()
    first = np.asarray(stored_jit(fn, name="probe", static="s")(*args))
    assert len(traced) == 1 and len(list(store.glob("probe-*.bin"))) == 1
    again = stored_jit(_traced_counter(traced)[0], name="probe", static="s")  # a new process's
    np.testing.assert_array_equal(np.asarray(again(*args)), first)
    np.testing.assert_array_equal(np.asarray(again(*args)), first)
    assert len(traced) == 1  # read back, not traced
    # Another static value, or another signature: its own program, traced.
    stored_jit(_traced_counter(traced)[0], name="probe", static="t")(*args)
    again(np.zeros(3, np.float32), {"a": np.float32(1.0), "b": np.ones(3, np.float32)})
    assert len(traced) == 3 and len(list(store.glob("probe-*.bin"))) == 3
    assert again._cache_size() == 2  # its two signatures' programs
    # Under an outer jit it is the plain jitted function.
    assert jax.jit(lambda x: again(x, args[1]))(args[0]).shape == (5,)


def test_a_damaged_file_is_traced_and_written_again(store):
    args = (np.ones(4, np.float32), {"a": np.float32(1.0), "b": np.ones(4, np.float32)})
    fn, traced = _traced_counter()
    want = np.asarray(stored_jit(fn, name="probe", static="")(*args))
    (path,) = store.glob("probe-*.bin")
    path.write_bytes(b"not a program")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        got = np.asarray(stored_jit(_traced_counter(traced)[0], name="probe", static="")(*args))
    assert any("could not read" in str(w.message) for w in seen)
    np.testing.assert_array_equal(got, want)
    assert len(traced) == 2 and path.read_bytes() != b"not a program"


def test_without_a_compilation_cache_nothing_is_stored(tmp_path):
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", None)
    try:
        fn, traced = _traced_counter()
        stored_jit(fn, name="probe")(np.ones(2, np.float32),
                                     {"a": np.float32(1.0), "b": np.ones(2, np.float32)})
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
    assert len(traced) == 1 and not list(tmp_path.rglob("*.bin"))


def test_the_trial_epsilon_read_back_equals_its_trace(store):
    """The C trial's epsilon stage (8 trials of 8 contact slots), read back: the values of
    the traced program, bit for bit."""
    rng = np.random.default_rng(0)
    pts = rng.normal(0.0, 0.03, (8, 8, 3)).astype(np.float32)
    nrm = -pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    args = (pts, nrm, rng.random((8, 8)) < 0.8, np.ones(8, bool), np.float32(0.5),
            np.zeros(3, np.float32), np.float32(0.08))
    stage = mujoco_backend._stored_epsilon(8, None)
    traced = np.asarray(stage.jitted(*args))
    assert (traced > 0).sum() >= 4
    stage(*args)  # stores it
    read = mujoco_backend._stored_epsilon.__wrapped__(8, None)  # a new process's
    np.testing.assert_array_equal(np.asarray(read(*args)), traced)

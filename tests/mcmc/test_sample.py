"""The driver: chunking, callbacks, resume, aux, lift; imports; diagnostics."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.mcmc import diagnostics
from jaxgrasp.mcmc.sample import precompile

pytestmark = pytest.mark.compile_bound  # a few steps of a few chains each


def logdensity(x):
    return -0.5 * jnp.sum(x**2), {"norm": jnp.linalg.norm(x), "flag": jnp.int32(3)}


@pytest.fixture(scope="module")
def alg():
    sketch = jax.random.normal(jax.random.key(0), (40, 3))
    return jg.mcmc.kameleon_darting(
        logdensity, sketch, sketch[:2], gamma=0.1, adapt_steps=8
    )  # resume crosses it


def _assert_identical(a, b):
    jax.tree.map(lambda u, v: np.testing.assert_array_equal(np.asarray(u), np.asarray(v)), a, b)


def test_chunked_equals_one_call_and_callback(alg):
    x0 = jnp.zeros((6, 3))
    key = jax.random.key(1)
    pos, infos = jg.mcmc.sample(key, alg, x0, 12)
    seen = []
    pos_c, infos_c = jg.mcmc.sample(
        key, alg, x0, 12, chunk_size=6, callback=lambda t, s, p, i: seen.append((t, p.shape[0]))
    )
    assert seen == [(6, 6), (12, 6)]
    assert pos.shape == (12, 6, 3) and infos.is_accepted.shape == (12, 6)
    _assert_identical((pos, infos), (pos_c, infos_c))
    assert infos.aux["flag"].shape == (12, 6)


def test_short_last_chunk_in_power_of_two_scans(alg):
    """12 steps in chunks of 7: a chunk of 7, then 5 = 4 + 1 steps, handed over as one chunk."""
    x0 = jnp.zeros((6, 3))
    key = jax.random.key(1)
    pos, infos = jg.mcmc.sample(key, alg, x0, 12)  # compiled above
    seen = []
    pos_c, infos_c = jg.mcmc.sample(
        key, alg, x0, 12, chunk_size=7, callback=lambda t, s, p, i: seen.append((t, p.shape[0]))
    )
    assert seen == [(7, 7), (12, 5)]
    _assert_identical((pos, infos), (pos_c, infos_c))


def test_streamed_chunks_equal_kept_ones(alg):
    x0 = jnp.zeros((6, 3))
    key = jax.random.key(1)
    pos, infos = jg.mcmc.sample(key, alg, x0, 12)  # compiled above
    chunks = []
    out = jg.mcmc.sample(key, alg, x0, 12, chunk_size=6, keep=False,
                         callback=lambda t, s, p, i: chunks.append((p, i)))
    assert out == (None, None)
    streamed = jax.tree.map(lambda *xs: jnp.concatenate(xs), *chunks)
    _assert_identical((pos, infos), streamed)
    with pytest.raises(ValueError, match="callback"):
        jg.mcmc.sample(key, alg, x0, 12, keep=False)


def test_resume_equals_uninterrupted(alg):
    x0 = jnp.zeros((6, 3))
    key = jax.random.key(2)
    pos, infos, state = jg.mcmc.sample(key, alg, x0, 12, return_state=True)
    # 6 steps per call: the compiled chunk is shared with the test above
    pos_a, infos_a, state_a = jg.mcmc.sample(key, alg, x0, 6, return_state=True)
    # the state survives a save/load round trip through numpy
    leaves, treedef = jax.tree.flatten(state_a)
    restored = jax.tree.unflatten(treedef, [np.array(leaf) for leaf in leaves])
    pos_b, infos_b, state_b = jg.mcmc.sample(
        key, alg, None, 6, initial_state=restored, start_step=6, return_state=True
    )
    _assert_identical(pos, jnp.concatenate([pos_a, pos_b]))
    _assert_identical(infos, jax.tree.map(lambda a, b: jnp.concatenate([a, b]), infos_a, infos_b))
    _assert_identical(state, state_b)


def test_info_fields(alg):
    _, infos = jg.mcmc.sample(jax.random.key(3), alg, jnp.zeros((6, 3)), 6)
    for field in ("is_accepted", "acceptance_rate", "proposal", "logdensity", "is_jump", "aux"):
        assert hasattr(infos, field)
    np.testing.assert_allclose(
        infos.aux["norm"], np.linalg.norm(np.asarray(infos.proposal), axis=-1), rtol=1e-5
    )
    np.testing.assert_allclose(
        infos.logdensity, -0.5 * np.sum(np.asarray(infos.proposal) ** 2, -1), rtol=1e-5
    )


@pytest.mark.parametrize(
    "positions, kwargs, match",
    [
        (np.zeros(3), {}, r"\(C, d\)"),
        (np.full((2, 3), np.nan), {}, "non-finite"),
        (np.zeros((2, 3)), {"num_steps": 0}, "num_steps"),
        (np.zeros((2, 3)), {"chunk_size": 0}, "chunk_size"),
        (None, {}, "initial_state"),
    ],
)
def test_bad_arguments(alg, positions, kwargs, match):
    kwargs = {"num_steps": 3, **kwargs}
    with pytest.raises(ValueError, match=match):
        jg.mcmc.sample(jax.random.key(0), alg, positions, **kwargs)


def test_plain_function_algorithm_and_unhashable_target():
    """sample() also drives hand-written algorithms (plain functions are static to jit), and
    targets that are not hashable."""

    class Target:  # eq without hash: unhashable
        def __eq__(self, other):
            return self is other

        def __call__(self, x):
            return -jnp.sum(x**2)

    built = jg.mcmc.random_walk(Target(), position_scale=0.1, kappa=10.0)
    plain = jg.types.SamplingAlgorithm(
        init=lambda x: built.init(x), step=lambda k, s: built.step(k, s)
    )
    x0 = jnp.tile(jnp.array([0.0, 0, 0, 1, 0, 0, 0]), (2, 1))
    pos_a, _ = jg.mcmc.sample(jax.random.key(0), plain, x0, 4)
    pos_b, _ = jg.mcmc.sample(jax.random.key(0), built, x0, 4)
    # closed-over constants may be folded differently from arguments: equal up to rounding
    np.testing.assert_allclose(pos_a, pos_b, rtol=1e-5, atol=1e-6)


def test_lift_quaternion():
    def grasp_logdensity(g):
        return g[3] - g[0], {"q": g[3:]}

    lifted = jg.mcmc.lift_quaternion(grasp_logdensity, width=0.1)
    x = jnp.array([0.5, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0])  # |q| = 2
    logp, aux = jax.jit(lifted)(x)
    log_r = np.log(2.0)
    expected = 1.0 - 0.5 - 0.5 * (log_r / 0.1) ** 2 - 4 * log_r
    assert float(logp) == pytest.approx(expected, rel=1e-5)
    np.testing.assert_allclose(aux["q"], [1.0, 0, 0, 0])
    assert jg.mcmc.lift_quaternion(grasp_logdensity, width=0.1) == lifted  # hashable by value
    scalar = jg.mcmc.lift_quaternion(lambda g: g[3])
    assert jnp.shape(scalar(x)) == ()
    with pytest.raises(ValueError, match="width"):
        jg.mcmc.lift_quaternion(grasp_logdensity, width=0.0)


def test_mcmc_imports_no_mujoco():
    code = (
        "import sys, jaxgrasp, jaxgrasp.mcmc, jaxgrasp.so3; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('mujoco', 'trimesh') "
        "or m.startswith('jaxgrasp.physics')]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_diagnostics():
    rng = np.random.default_rng(0)
    iid = rng.normal(size=(1000, 4))
    assert diagnostics.effective_sample_size(iid) == pytest.approx(4000, rel=0.15)
    rho = 0.9  # AR(1): ESS ≈ N (1 − ρ)/(1 + ρ)
    x = np.zeros((4000, 4))
    for t in range(1, 4000):
        x[t] = rho * x[t - 1] + np.sqrt(1 - rho**2) * rng.normal(size=4)
    assert diagnostics.effective_sample_size(x) == pytest.approx(16000 / 19, rel=0.25)
    assert diagnostics.potential_scale_reduction(iid) == pytest.approx(1.0, abs=0.01)
    stuck = iid + np.arange(4) * 3.0
    assert diagnostics.potential_scale_reduction(stuck) > 1.5


SAMPLER = {"jit(_init_chains)", "jit(_scan_steps)"}


def test_precompile_leaves_sample_nothing_to_compile():
    """``precompile`` builds what ``sample`` runs (its init and one chunk's scan) from shapes
    alone; ``sample`` then compiles nothing and gives what it gives without. The companion:
    another chunk length is a program ``sample`` must build, and the listener sees it."""
    from jax import monitoring  # why: JAX's record of each XLA program it builds

    built = []

    def listen(event, secs, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            built.append(kwargs.get("fun_name"))

    def shifted(x):  # a target no other test compiled
        return -0.5 * jnp.sum((x - 0.25) ** 2)

    alg = jg.mcmc.random_walk(shifted, position_scale=0.1, kappa=50.0)
    key, x0 = jax.random.key(4), np.tile(np.array([0, 0, 0, 1, 0, 0, 0], np.float32), (3, 1))
    monitoring.register_event_duration_secs_listener(listen)
    try:
        precompile(key, alg, x0, 5)
        assert SAMPLER <= set(built)
        del built[:]
        pos, infos = jg.mcmc.sample(key, alg, x0, 10, chunk_size=5)
        assert not SAMPLER & set(built), built  # (small helpers of the driver aside)
        jg.mcmc.sample(key, alg, x0, 12, chunk_size=6)
        assert SAMPLER & set(built) == {"jit(_scan_steps)"}
    finally:
        monitoring.unregister_event_duration_listener(listen)
    fresh = jg.mcmc.random_walk(lambda x: shifted(x), position_scale=0.1, kappa=50.0)
    _assert_identical((pos, infos), jg.mcmc.sample(key, fresh, x0, 10, chunk_size=5))

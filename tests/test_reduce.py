"""Folded reductions (``jaxgrasp._reduce``): exactly numpy's min, max and any, for every
length around the fold threshold, odd ones included."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgrasp import _reduce as R

LENGTHS = [1, 2, 31, 32, 33, 63, 64, 65, 97, 224]


@pytest.mark.parametrize("n", LENGTHS)
def test_folded_reductions_equal_numpy(n):
    rng = np.random.default_rng(n)
    x = rng.normal(size=(3, n)).astype(np.float32)
    i = rng.integers(-50, 50, size=(3, n)).astype(np.int32)
    b = rng.random((4, n)) < 0.02
    b[0] = False  # a row with none set
    f = jax.jit(lambda x, i, b: (R.min_last(x, jnp.inf), R.max_last(x, -jnp.inf),
                                 R.min_last(i, 50), R.max_last(i, -50), R.any_last(b)))
    got = jax.device_get(f(x, i, b))
    want = (x.min(-1), x.max(-1), i.min(-1), i.max(-1), b.any(-1))
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)
    # Folding leaves at most TREE_REDUCE elements, and the extremes survive it.
    folded = R.fold_last(jnp.asarray(x), jnp.minimum, jnp.inf)
    assert folded.shape[-1] <= R.TREE_REDUCE
    np.testing.assert_array_equal(np.asarray(folded).min(-1), x.min(-1))


def test_a_wrong_fill_shows_on_odd_lengths():
    """Companion: the fill pads odd lengths, so a fill that is not the identity changes
    the result (the test above would catch a fold that padded wrongly)."""
    x = jnp.full((1, 65), 5.0, jnp.float32)
    assert float(R.min_last(x, jnp.inf)[0]) == 5.0
    assert float(R.min_last(x, 0.0)[0]) == 0.0


@pytest.mark.parametrize("n", [1, 16, 33])
def test_running_count_is_cumsum(n):
    b = np.random.default_rng(n).random(n) < 0.5
    got = np.asarray(jax.jit(R.running_count)(b))
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, np.cumsum(b))

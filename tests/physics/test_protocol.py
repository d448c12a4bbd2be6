"""Protocol helpers shared by the physics backends (no physics, no MuJoCo model)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgrasp.physics.protocol import Outcome, TrialResult, with_epsilon


def _results(outcomes, K=4, seed=0):
    rng = np.random.default_rng(seed)
    B = len(outcomes)
    return TrialResult(
        outcome=jnp.asarray(outcomes, jnp.int32),
        epsilon=jnp.full(B, -1.0, jnp.float32),
        displacement=jnp.zeros(B, jnp.float32),
        contact_points=jnp.asarray(rng.normal(size=(B, K, 3)), jnp.float32),
        contact_normals=jnp.asarray(rng.normal(size=(B, K, 3)), jnp.float32),
        contact_mask=jnp.asarray(rng.random((B, K)) < 0.7),
        pad_contact=jnp.zeros((B, 2), bool),
        unstable=jnp.zeros(B, bool),
        invalid=jnp.zeros(B, bool),
    )


def _fake_epsilon(p, n, m):
    # Distinct per trial, and NaN when nothing is masked in (must come out as 0).
    s = jnp.sum(jnp.where(m[:, None], p * n, 0.0))
    return jnp.where(jnp.any(m), jnp.abs(s) + 0.1, jnp.nan)


@pytest.mark.parametrize("chunk", [1, 3, 8, 64])
def test_with_epsilon_equals_vmap_where_graspable(chunk):
    rng = np.random.default_rng(1)
    outcomes = rng.integers(0, 4, size=21)  # 21: not a multiple of the chunk
    res = _results(outcomes)
    got = np.asarray(with_epsilon(res, _fake_epsilon, chunk=chunk).epsilon)
    full = np.asarray(jax.vmap(_fake_epsilon)(res.contact_points, res.contact_normals,
                                              res.contact_mask))
    graspable = np.isin(outcomes, [Outcome.SUCCESS, Outcome.SLIPPED])
    np.testing.assert_allclose(got[graspable], np.nan_to_num(full[graspable]), rtol=1e-6)
    assert np.all(got[~graspable] == 0.0)
    assert np.all(np.isfinite(got))


def test_with_epsilon_skips_chunks_without_graspable_trials():
    calls = []

    def counting(p, n, m):
        jax.debug.callback(lambda: calls.append(1))
        return _fake_epsilon(p, n, m)

    outcomes = [Outcome.COLLISION] * 13 + [Outcome.SUCCESS] * 3  # one chunk of 8 needed
    res = _results(outcomes)
    out = jax.jit(lambda r: with_epsilon(r, counting, chunk=8))(res)
    jax.block_until_ready(out)
    assert len(calls) == 1  # one chunk ran (a vmapped callback fires once per call)
    assert np.all(np.asarray(out.epsilon)[:13] == 0) and np.all(np.asarray(out.epsilon)[13:] > 0)
    calls.clear()
    jax.block_until_ready(jax.jit(lambda r: with_epsilon(r, counting, chunk=8))(
        _results([Outcome.MISS] * 16)))
    assert calls == []
    # 9 trials pad to 16 with copies of a graspable one: the padding must not run a chunk.
    out = jax.jit(lambda r: with_epsilon(r, counting, chunk=8))(
        _results([Outcome.SUCCESS] + [Outcome.COLLISION] * 8))
    jax.block_until_ready(out)
    assert len(calls) == 1 and np.asarray(out.epsilon)[0] > 0

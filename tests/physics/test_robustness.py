"""Physics never poisons a chain (reduced ``benchmarks/robustness.py``, MuJoCo C only).

Random and adversarial poses on the shipped pitcher (inside the object, far away, under the
support plane, zero / near-zero / huge quaternions, NaN/inf entries, huge positions) through
the trial and the vmapped target density: no non-finite log-density or trial field, no crash,
and every unstable trial is a failure (COLLISION/MISS) with epsilon 0 and the floor density.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.density import DEFAULT_FLOOR, grasp_logdensity
from jaxgrasp.physics.rules import normalize_grasps

PER_FAMILY = 20
BATCH = 200  # one compiled shape for everything below


@pytest.fixture(scope="module")
def robustness(load_benchmark):
    return load_benchmark("robustness")


@pytest.fixture(scope="module")
def pitcher_c():
    obj = jg.objects.load("pitcher")
    trial = jg.physics.make_trial(jg.physics.load_scene(obj), backend="mujoco")
    return obj, trial, jax.jit(jax.vmap(grasp_logdensity(trial)))


def test_adversarial_poses_never_give_nan(robustness, pitcher_c):
    obj, trial, vdens = pitcher_c
    families = robustness.pose_families(obj, PER_FAMILY, seed=1)
    assert len(families) >= 9
    poses = np.concatenate(list(families.values()))
    stats = robustness.run_family(trial, vdens, poses, BATCH, DEFAULT_FLOOR)
    assert stats["errors"] == []
    assert stats["poses"] == PER_FAMILY * len(families)
    assert stats["nonfinite_logp"] == 0
    assert stats["nonfinite_trial_fields"] == 0
    assert stats["logp_below_floor"] == 0
    assert stats["density_outcome_mismatch"] == 0
    assert stats["unstable_not_failure"] == 0
    assert stats["unstable_nonzero_epsilon"] == 0
    assert stats["unstable_logp_above_floor"] == 0
    # Under the support plane or with a NaN/inf entry: a collision, before any physics.
    blocked = np.concatenate([families["below_support"], families["nonfinite"]])
    out = robustness.run_family(trial, vdens, blocked, BATCH, DEFAULT_FLOOR)
    assert out["outcomes"]["COLLISION"] == len(blocked), out


def test_unstable_rollouts_are_failures_at_the_floor(robustness, pitcher_c):
    """Real rollouts flagged unstable (blow-up threshold lowered below what every moving
    rollout reaches): failures, epsilon 0, density at the floor, nothing non-finite."""
    obj, trial, vdens = pitcher_c
    poses = robustness.pose_families(obj, 100, seed=2)["uniform"]
    stats = robustness.forced_unstable(trial, vdens, poses, BATCH, DEFAULT_FLOOR)
    assert stats["errors"] == []
    assert stats["unstable"] > 5, stats
    assert stats["unstable_outcomes"]["SUCCESS"] == stats["unstable_outcomes"]["SLIPPED"] == 0
    assert stats["outcomes"]["SUCCESS"] == stats["outcomes"]["SLIPPED"] == 0
    assert stats["unstable_not_failure"] == 0
    assert stats["unstable_nonzero_epsilon"] == 0
    assert stats["unstable_logp_above_floor"] == 0
    assert stats["nonfinite_logp"] == stats["nonfinite_trial_fields"] == 0
    # The threshold is restored: the same poses are no longer all unstable.
    assert trial.engine.params.max_speed == jg.physics.TrialParams().max_speed


def test_huge_quaternions_normalize_like_the_c_backend():
    """|q| beyond ~1e19 overflowed the float32 norm: MJX saw a zero quaternion (unstable
    rollouts, 25 of 64 huge_quat poses) where MuJoCo C (float64) saw the rotation."""
    q = np.array([[3e30, -4e30, 0, 0], [3e38, 3e38, 3e38, 3e38], [1e19, 1e19, 0, 0],
                  [0.6, 0.8, 0, 0], [1e-12, 0, 0, 0], [0, 0, 0, 0]], np.float32)
    g = np.concatenate([np.zeros((len(q), 3), np.float32), q], axis=1)
    out = np.asarray(normalize_grasps(jnp.asarray(g)))[:, 3:]
    q64 = q.astype(np.float64)
    n = np.linalg.norm(q64, axis=1, keepdims=True)
    expected = np.where(n > 1e-9, q64 / np.where(n > 1e-9, n, 1), [1.0, 0, 0, 0])
    np.testing.assert_allclose(out, expected, atol=1e-6)

"""Grasp target density log(epsilon + floor): fake trials for the rules, real trials on a box."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.density import DEFAULT_FLOOR, grasp_logdensity
from jaxgrasp.physics.protocol import Outcome

FLOOR = 1e-3


class FakeResult(NamedTuple):
    outcome: jax.Array
    epsilon: jax.Array
    unstable: jax.Array


def fake_trial(grasps):
    """Outcome from the grasp's x coordinate, epsilon from its y (a pure, batched fake):
    x < 0 collision, 0 <= x < 1 success, 1 <= x < 2 slipped, 2 <= x < 3 miss,
    3 <= x < 4 "success" but unstable, x >= 4 success with a NaN epsilon."""
    x, y = grasps[:, 0], grasps[:, 1]
    outcome = jnp.select(
        [x < 0, x < 1, x < 2, x < 3],
        [Outcome.COLLISION, Outcome.SUCCESS, Outcome.SLIPPED, Outcome.MISS],
        Outcome.SUCCESS,
    ).astype(jnp.int32)
    eps = jnp.where(x >= 4, jnp.nan, jnp.abs(y))
    # Physics reports 0 for failures; the fake leaks a positive value for misses on purpose.
    return FakeResult(outcome, eps.astype(jnp.float32), (x >= 3) & (x < 4))


def _grasp(x, y):
    return jnp.array([x, y, 0.0, 1.0, 0.0, 0.0, 0.0], jnp.float32)


@pytest.mark.parametrize(
    "x, y, outcome, eps",
    [
        (0.5, 0.2, Outcome.SUCCESS, 0.2),
        (1.5, 0.05, Outcome.SLIPPED, 0.05),
        (-1.0, 0.3, Outcome.COLLISION, 0.0),
        (2.5, 0.3, Outcome.MISS, 0.0),  # a miss never counts, whatever epsilon says
        (3.5, 0.3, Outcome.SUCCESS, 0.0),  # unstable physics counts as failed
        (4.5, 0.3, Outcome.SUCCESS, 0.0),  # NaN epsilon counts as failed
    ],
)
def test_rules_on_fake_trial(x, y, outcome, eps):
    logp, aux = jax.jit(grasp_logdensity(fake_trial, floor=FLOOR))(_grasp(x, y))
    assert np.isfinite(logp)
    assert float(logp) == pytest.approx(np.log(eps + FLOOR), rel=1e-6)
    assert int(aux["outcome"]) == outcome
    assert float(aux["epsilon"]) == pytest.approx(eps)
    assert aux["outcome"].dtype == jnp.int32 and aux["outcome"].shape == ()
    assert aux["epsilon"].dtype == jnp.float32 and aux["epsilon"].shape == ()


@pytest.mark.parametrize("power", [1.0, 0.5, 0.25])
def test_power_and_slip_weight(power):
    """log pi = log(w eps^power + floor): w = slip_weight for SLIPPED, 1 for SUCCESS."""
    fn = jax.jit(grasp_logdensity(fake_trial, floor=FLOOR, slip_weight=0.1, power=power))
    for x, y, w in ((0.5, 0.04, 1.0), (1.5, 0.04, 0.1)):
        logp, aux = fn(_grasp(x, y))
        assert float(logp) == pytest.approx(np.log(w * 0.04**power + FLOOR), rel=1e-5)
        assert float(aux["epsilon"]) == pytest.approx(0.04)  # aux keeps the raw epsilon
    for x in (-1.0, 2.5, 0.5):  # failures, and a success with epsilon 0, sit on the floor
        logp, _ = fn(_grasp(x, 0.0))
        assert float(logp) == pytest.approx(np.log(FLOOR), rel=1e-6)
    with pytest.raises(ValueError, match="power"):
        grasp_logdensity(fake_trial, power=0.0)


def test_vmap_over_chains_is_one_batched_rollout():
    """Under vmap the trial runs once on all chains (one host call for a callback trial)."""
    calls = []
    trial = _counting_trial(calls)
    chains = jnp.stack([_grasp(x, 0.1 * x) for x in np.linspace(-0.5, 2.5, 9)])
    logp, aux = jax.jit(jax.vmap(grasp_logdensity(trial, floor=FLOOR)))(chains)
    assert len(calls) == 1 and calls[0][:-1] == (9, 1)
    ref_logp, ref_aux = jax.vmap(grasp_logdensity(fake_trial, floor=FLOOR))(chains)
    np.testing.assert_allclose(logp, ref_logp, rtol=1e-6)
    np.testing.assert_array_equal(aux["outcome"], ref_aux["outcome"])


def _counting_trial(calls):
    """The fake trial behind a host callback that records every (batched) call."""

    def host(grasps):
        calls.append(grasps.shape)
        res = fake_trial(jnp.asarray(grasps).reshape(-1, 7))
        return jax.tree.map(lambda a: np.asarray(a).reshape(grasps.shape[:-1]), res)

    def trial(grasps):
        shapes = FakeResult(
            jax.ShapeDtypeStruct(grasps.shape[:1], jnp.int32),
            jax.ShapeDtypeStruct(grasps.shape[:1], jnp.float32),
            jax.ShapeDtypeStruct(grasps.shape[:1], jnp.bool_),
        )
        return jax.pure_callback(host, shapes, grasps, vmap_method="expand_dims")

    return trial


def test_outcomes_reach_sampler_infos_with_one_rollout_per_step():
    """mcmc.sample with the density: the outcome of every proposal is in infos.aux, from the
    same (single, batched) rollout that decided the MH step."""
    calls = []
    logdensity = grasp_logdensity(_counting_trial(calls), floor=FLOOR)
    alg = jg.mcmc.random_walk(logdensity, position_scale=0.5, kappa=50.0)
    x0 = jnp.stack([_grasp(x, 0.1) for x in np.linspace(-0.5, 2.5, 6)])
    steps = 5
    _, infos = jg.mcmc.sample(jax.random.key(0), alg, x0, steps)
    assert len(calls) == 1 + steps  # init + one batched rollout per step
    assert all(c[:-1] == (6, 1) for c in calls)
    assert infos.aux["outcome"].shape == (steps, 6)
    expected = np.asarray(fake_trial(infos.proposal.reshape(-1, 7)).outcome)
    np.testing.assert_array_equal(infos.aux["outcome"].reshape(-1), expected)


def test_hashable_and_bad_input():
    a = grasp_logdensity(fake_trial, floor=FLOOR)
    assert a == grasp_logdensity(fake_trial, floor=FLOOR) and hash(a) == hash(
        grasp_logdensity(fake_trial, floor=FLOOR)
    )
    assert a != grasp_logdensity(fake_trial, floor=2 * FLOOR)
    assert grasp_logdensity(fake_trial).floor == DEFAULT_FLOOR
    for bad in (0.0, -1e-3, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="floor"):
            grasp_logdensity(fake_trial, floor=bad)
    with pytest.raises(ValueError, match="trial"):
        grasp_logdensity(None)
    with pytest.raises(ValueError, match="grasp"):
        a(jnp.zeros(6))


def test_lifted_composition_with_mcmc():
    """The R^7 target is mcmc.lift_quaternion(grasp_logdensity(...)): the grasp part depends
    on q/|q| only, the aux passes through."""
    lifted = jg.mcmc.lift_quaternion(grasp_logdensity(fake_trial, floor=FLOOR), width=0.05)
    g = _grasp(0.5, 0.2)
    lp1, aux1 = lifted(g)
    g2 = g.at[3:].multiply(1.1)
    lp2, aux2 = lifted(g2)
    assert float(aux1["epsilon"]) == float(aux2["epsilon"]) == pytest.approx(0.2)
    radial = jg.mcmc.lift.log_radial_density(jnp.float32(1.1), 0.05)
    assert float(lp2 - lp1) == pytest.approx(float(radial), rel=1e-5)


# ------------------------------------------------------------------------------------------
# Real trials on a box (MuJoCo C backend: cheap to build)
# ------------------------------------------------------------------------------------------

DOWN = [0.0, 1.0, 0.0, 0.0]  # top-down approach, pads close along y
GOOD = [0.0, 0.0, 0.085, *DOWN]  # centred on the top 3.5 cm of a 6 x 6 x 10 cm box
POOR = [0.025, 0.0, 0.11, *DOWN]  # pads hold only the top 1 cm, at the +x edge: low epsilon
INSIDE = [0.0, 0.0, 0.05, *DOWN]  # palm inside the box: collision
BESIDE = [0.15, 0.0, 0.05, *DOWN]  # closes on nothing: miss
CHAINS = 8


@pytest.fixture(scope="module")
def box_density():
    from jaxgrasp import physics  # here: the rest of this module never needs MuJoCo
    scene = physics.load_scene(jg.objects.make_box((0.03, 0.03, 0.05), mass=0.2))
    trial = physics.make_trial(scene, backend="mujoco")
    fn = jax.jit(jax.vmap(grasp_logdensity(trial, floor=DEFAULT_FLOOR)))

    def run(grasps):  # chains in batches of CHAINS: one compilation
        parts = [fn(jnp.asarray(grasps[i : i + CHAINS])) for i in range(0, len(grasps), CHAINS)]
        return jax.tree.map(lambda *a: np.concatenate(a), *parts)

    return run


def test_real_trial_ranks_good_above_poor(box_density):
    logp, aux = box_density(np.asarray([GOOD, POOR, INSIDE, BESIDE] * 2, np.float32))
    logp, outcome = np.asarray(logp)[:4], np.asarray(aux["outcome"])[:4]
    assert outcome[2] == Outcome.COLLISION and outcome[3] == Outcome.MISS
    assert outcome[0] <= Outcome.SLIPPED and outcome[1] <= Outcome.SLIPPED
    assert logp[0] > logp[1] > np.log(DEFAULT_FLOOR) + 3  # epsilon well above the floor
    np.testing.assert_allclose(logp[2:], np.log(np.float32(DEFAULT_FLOOR)), rtol=1e-6)


def test_real_trial_finite_on_random_poses(box_density):
    rng = np.random.default_rng(0)
    pos = rng.uniform([-0.1, -0.1, -0.05], [0.1, 0.1, 0.2], (32, 3))
    quat = rng.standard_normal((32, 4)) * rng.uniform(0.2, 3.0, (32, 1))  # unnormalized
    quat[0] = 0.0  # even a zero quaternion must not produce a NaN
    logp, aux = box_density(np.c_[pos, quat].astype(np.float32))
    logp = np.asarray(logp)
    assert np.isfinite(logp).all()
    assert (logp >= np.log(np.float32(DEFAULT_FLOOR)) - 1e-6).all()
    failed = np.asarray(aux["outcome"]) >= Outcome.COLLISION
    np.testing.assert_array_equal(np.asarray(aux["epsilon"])[failed], 0.0)


@pytest.mark.slow
def test_mjx_trial_density_matches_c_backend(box_density):
    """The MJX trial (the sampler's default) gives the same outcomes and ranking as the C
    backend (their epsilons may differ: contact patches differ between the engines)."""
    physics = jg.physics
    scene = physics.load_scene(jg.objects.make_box((0.03, 0.03, 0.05), mass=0.2))
    mjx = jax.jit(jax.vmap(grasp_logdensity(physics.make_trial(scene), floor=DEFAULT_FLOOR)))
    grasps = np.asarray([GOOD, POOR, INSIDE, BESIDE] * 2, np.float32)
    lp_mjx, aux_mjx = mjx(grasps)
    lp_c, aux_c = box_density(grasps)
    np.testing.assert_array_equal(aux_mjx["outcome"], aux_c["outcome"])
    assert lp_mjx[0] > lp_mjx[1] > lp_mjx[2]
    assert lp_c[0] > lp_c[1] > lp_c[2]


# ---------------------------------------------------------------- perturbed tries (pseudo-marginal)

def _band_trial(grasps):
    """SUCCESS with epsilon 1 where |x| < 0.004 m, MISS elsewhere (a pure, batched fake)."""
    held = jnp.abs(grasps[:, 0]) < 0.004
    outcome = jnp.where(held, Outcome.SUCCESS, Outcome.MISS).astype(jnp.int32)
    return FakeResult(outcome, held.astype(jnp.float32), jnp.zeros(held.shape, bool))


@pytest.mark.parametrize("estimate", ["mean", "all_held"])
@pytest.mark.parametrize("x0", [0.0, 0.003, 0.006])
def test_perturbed_tries_estimate_is_unbiased(x0, estimate):
    """exp(logp) - floor averages to (1[grasp holds] + k p) / (k + 1) ("mean") or to
    1[grasp holds] p^k ("all_held"), with p = P(|x0 + N(0, sd)| < r)."""
    from scipy.stats import norm

    k, sd, r, n = 3, 0.003, 0.004, 4000
    fn = grasp_logdensity(_band_trial, floor=FLOOR, tries=k, position_sd=sd, angle_sd=3.0,
                          estimate=estimate)
    assert fn.stochastic and not grasp_logdensity(_band_trial).stochastic
    keys = jax.random.split(jax.random.key(0), n)
    logp, aux = jax.jit(jax.vmap(fn, (None, 0)))(_grasp(x0, 0.0), keys)
    est = np.exp(np.asarray(logp, np.float64)) - FLOOR
    p_held = norm.cdf((r - x0) / sd) - norm.cdf((-r - x0) / sd)
    want = (((abs(x0) < r) + k * p_held) / (k + 1) if estimate == "mean"
            else (abs(x0) < r) * p_held**k)
    assert abs(est.mean() - want) < 4.5 * est.std(ddof=1) / np.sqrt(n) + 1e-6, (est.mean(), want)
    held = np.asarray(aux["held"])
    assert abs(held.mean() / k - p_held) < 4.5 * held.std(ddof=1) / k / np.sqrt(n) + 1e-6
    assert int(aux["outcome"][0]) == (Outcome.SUCCESS if abs(x0) < r else Outcome.MISS)
    with pytest.raises(ValueError, match="needs a key"):
        fn(_grasp(x0, 0.0))


def test_perturbed_poses_follow_the_robustness_law():
    """The density's pose error is jg.learn.robustness's: position offsets and turn angles
    agree in law (two-sample KS); a turn 20 % larger is told apart (the test can fail)."""
    from scipy.stats import ks_2samp

    from jaxgrasp.learn.evaluate.robustness import PoseNoise, perturbed_poses

    q = np.array([0.5, 0.5, -0.5, 0.5])
    pose = np.concatenate([[0.1, -0.2, 0.3], q]).astype(np.float32)
    n = 20000

    def angles(poses):
        return np.asarray(jg.so3.geodesic_angle(jnp.asarray(q, jnp.float32), poses[:, 3:]))

    ours = np.asarray(jg.so3.perturbed_poses(jax.random.key(1), pose, n, 0.003,
                                             np.radians(3.0)))
    ref = perturbed_poses(pose[None], PoseNoise(tries=n), seed=3)[0].astype(np.float32)
    for axis in range(3):
        assert ks_2samp(ours[:, axis], ref[:, axis]).pvalue > 1e-3
    assert ks_2samp(angles(ours), angles(ref)).pvalue > 1e-3
    wider = np.asarray(jg.so3.perturbed_poses(jax.random.key(1), pose, n, 0.003,
                                              np.radians(3.6)))
    assert ks_2samp(angles(wider), angles(ref)).pvalue < 1e-6


class _MovedResult(NamedTuple):
    outcome: jax.Array
    epsilon: jax.Array
    unstable: jax.Array
    displacement: jax.Array


def test_slip_scale_weighs_by_displacement():
    """q = w epsilon exp(-displacement / slip_scale) on contact; failures stay at the floor."""
    def trial(grasps):  # outcome from x as fake_trial; displacement from z
        base = fake_trial(grasps)
        return _MovedResult(base.outcome, base.epsilon, base.unstable, grasps[:, 2])

    fn = jax.jit(grasp_logdensity(trial, floor=FLOOR, slip_weight=0.5, slip_scale=0.002))
    for x, w in ((0.5, 1.0), (1.5, 0.5), (2.5, 0.0)):
        g = _grasp(x, 0.2).at[2].set(0.003)
        want = w * 0.2 * np.exp(-0.003 / 0.002) + FLOOR
        assert float(fn(g)[0]) == pytest.approx(np.log(want), rel=1e-5)
    with pytest.raises(ValueError, match="slip_scale"):
        grasp_logdensity(trial, slip_scale=-1.0)

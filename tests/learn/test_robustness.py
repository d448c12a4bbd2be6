"""``jg.learn.robustness``: hold probability under a robot's pose error, against a hand
calculation on the analytic box trial; perturbation statistics; the grasp files carry it."""

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import norm

import jaxgrasp as jg
from jaxgrasp import so3
from jaxgrasp.learn.evaluate.robustness import PoseNoise, Robustness, perturbed_poses, ranked
from jaxgrasp.learn.files.export import GraspSet, export_grasps, load_grasps, to_transforms

# The analytic box trial (tests/learn/conftest.py): half extents 3 x 3 x 5 cm, centre z = 5 cm;
# a grasp holds when its centre is inside the box but not in its inner half, closing axis
# within ~14° of x or y. At x = 2.25 cm it holds unless x leaves (1.5, 3) cm (+-2.5 sd of 3 mm);
# at x = 2.9 cm, only while x stays below 3 cm.
DEEP = [0.0225, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0]
EDGE = [0.029, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0]


def hold_probability(x, sd):
    """P(1.5 cm < x + N(0, sd) < 3 cm): the other axes and the turns never leave the region."""
    return norm.cdf((0.03 - x) / sd) - norm.cdf((0.015 - x) / sd)


def _within_mc_error(rob, sd):
    p = rob.probability
    expect = np.array([hold_probability(DEEP[0], sd), hold_probability(EDGE[0], sd)])
    se = np.sqrt(expect * (1 - expect) / rob.noise.tries) + 1e-12
    return bool(np.all(np.abs(p - expect) < 5 * se + 1e-3))


def test_hold_probability_matches_the_hand_calculation(box, fake_sim):
    rob = jg.learn.robustness(np.array([DEEP, EDGE]), box, trial=fake_sim,
                              noise=PoseNoise(tries=4000))
    assert _within_mc_error(rob, 0.003), rob.probability
    # The companion: the same check against twice the error the trials were made with fails.
    assert not _within_mc_error(rob, 0.006)
    assert rob.robust.tolist() == [True, False] and rob.robust_share == 0.5
    assert rob.num_trials == 8000


def test_same_seed_same_answer_and_no_noise_holds_exactly(box, fake_sim):
    g = np.array([DEEP, EDGE])
    a = jg.learn.robustness(g, box, trial=fake_sim, seed=3)
    np.testing.assert_array_equal(a.held, jg.learn.robustness(g, box, trial=fake_sim,
                                                              seed=3).held)
    exact = jg.learn.robustness(g, box, trial=fake_sim,
                                noise=PoseNoise(position_sd=0.0, angle_sd=0.0, tries=3))
    np.testing.assert_array_equal(exact.held, [3, 3])


def test_perturbations_have_the_stated_spread():
    g = np.tile(np.array([[0.1, -0.2, 0.3, 0.3, -0.5, 0.2, 0.7]]), (200, 1))
    g[:, 3:] /= np.linalg.norm(g[:, 3:], axis=1, keepdims=True)
    poses = perturbed_poses(g, PoseNoise(tries=50), seed=1).reshape(-1, 7)
    dx = poses[:, :3] - g[0, :3]
    n = len(dx)
    var = (dx**2).mean(axis=0)
    assert np.all(np.abs(var - 0.003**2) < 5 * 0.003**2 * math.sqrt(2 / n))
    angle = np.asarray(so3.geodesic_angle(np.asarray(g[:1, 3:]), poses[:, 3:]))
    mean, expect = angle.mean(), math.radians(3.0) * math.sqrt(2 / math.pi)
    se = math.radians(3.0) * math.sqrt(1 - 2 / math.pi) / math.sqrt(n)
    assert abs(mean - expect) < 5 * se
    assert abs(mean - 2 * expect) > 5 * se  # the companion: 6° would be told apart


def test_bad_noise_is_refused(box, fake_sim):
    for noise, match in ((PoseNoise(tries=0), "tries"), (PoseNoise(position_sd=-1.0), "position"),
                         (PoseNoise(min_share=0.0), "min_share")):
        with pytest.raises(ValueError, match=match):
            jg.learn.robustness(np.array([DEEP]), box, trial=fake_sim, noise=noise)
    with pytest.raises(ValueError, match="NaN"):
        jg.learn.robustness(np.array([[np.nan] * 7]), box, trial=fake_sim)


@pytest.mark.parametrize("suffix", [".npz", ".json", ".h5"])
def test_grasp_files_carry_it_most_robust_first(tmp_path, box, fake_sim, suffix):
    g = np.array([EDGE, DEEP])
    rob = jg.learn.robustness(g, box, trial=fake_sim, noise=PoseNoise(tries=20))
    gs = GraspSet(g, to_transforms(g), np.full(2, 0.085), np.zeros(2), np.zeros(2, np.int8),
                  "box", "0" * 16)
    top = ranked(gs, rob)
    np.testing.assert_allclose(top.grasps[0], DEEP)  # the robust one first
    assert top.robustness[0] >= top.robustness[1]
    back = load_grasps(export_grasps(top, tmp_path / f"g{suffix}"))
    np.testing.assert_allclose(back.robustness, top.robustness)
    np.testing.assert_allclose(back.grasps, top.grasps, atol=1e-9)


# --------------------------------------------------------------------------------------------
# A LearnResult carries its measurement, saved and loaded with it.

#: A second deep grasp, on the box's other side: robust, and not the demonstration.
DEEP_OTHER = [-0.0225, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0]
#: 0.5 mm inside a side wall in y (EDGE is the same grasp as DEEP: within 1 cm): held ~57 %.
EDGE_Y = [0.0, 0.0295, 0.05, 1.0, 0.0, 0.0, 0.0]


def box_run(box) -> jg.learn.LearnResult:
    """A run on the box whose successes are DEEP, EDGE_Y and DEEP_OTHER; DEEP is its demo."""
    pos = np.array([DEEP, EDGE_Y, DEEP_OTHER], np.float32)[:, None, :]
    outcomes = np.zeros((3, 1), np.int8)
    return jg.learn.LearnResult(
        object_name=box.name, object_hash=box.content_hash, workflow="active",
        method="kameleon_darting", sketch="biased", modes_kind="demos", seed=0,
        backend="mujoco", params=jg.learn.LearnParams(iterations=2, burn_in=1), positions=pos,
        proposals=pos, outcomes=outcomes, epsilons=np.full((3, 1), 0.1, np.float32),
        accepted=outcomes == 0, is_jump=np.zeros((3, 1), bool), initial_positions=pos[0],
        modes=pos[0], sketch_points=pos[:, 0], demos=jg.learn.Demos(pos[:1, 0], None))


def test_a_result_carries_its_robustness_through_save_and_load(tmp_path, box, fake_sim):
    plain = box_run(box)
    assert plain.robustness is None and plain.robust_share is None
    assert plain.distinct_robust_new is None
    rob = jg.learn.robustness(plain, trial=fake_sim, noise=PoseNoise(tries=20), seed=1)
    # Any order of the same grasps: the CLI attaches its most-robust-first measurement.
    result = plain.with_robustness(rob.most_robust_first()[1])
    assert result.robust_share == pytest.approx(2 / 3)  # DEEP and DEEP_OTHER
    assert result.distinct_robust_new == 1  # DEEP is the demonstration
    assert plain.robustness is None  # a copy
    back = jg.learn.load(result.save(tmp_path / "with"))
    assert back.robustness.noise == PoseNoise(tries=20)
    np.testing.assert_array_equal(back.robustness.held, result.robustness.held)
    np.testing.assert_array_equal(back.robustness.grasps, result.robustness.grasps)
    assert (back.robust_share, back.distinct_robust_new) == (result.robust_share, 1)
    np.testing.assert_array_equal(back.robustness.held_of(plain.grasps), rob.held)
    assert np.isnan(back.robustness.held_of(np.array([EDGE]))).all()  # not measured
    early = jg.learn.robustness(plain, trial=fake_sim, noise=PoseNoise(tries=20), seed=1,
                                stop_early=True)
    back = jg.learn.load(plain.with_robustness(early).save(tmp_path / "early"))
    np.testing.assert_array_equal(back.robustness.tries_made, early.tries_made)
    np.testing.assert_array_equal(back.robustness.tried_of(plain.grasps), early.tries_made)


def test_a_result_saved_without_robustness_loads_with_none(tmp_path, box):
    """What results written before they carried robustness hold: no arrays, no JSON key."""
    path = box_run(box).save(tmp_path / "old")
    meta = json.loads((path / "result.json").read_text())
    assert "robustness" not in meta
    assert not any("robustness" in k for k in np.load(path / "result.npz").files)
    assert jg.learn.load(path).robustness is None


def test_robustness_of_other_grasps_is_refused(box, fake_sim):
    result = box_run(box)
    rob = jg.learn.robustness(np.array([DEEP]), box, trial=fake_sim)
    with pytest.raises(ValueError, match="distinct successful grasps"):
        result.with_robustness(rob)


def test_stopping_early_keeps_every_robust_count(tmp_path, box, fake_sim):
    """The same perturbed poses in the same order: robust grasps keep their full counts, the
    others stop once they failed more than tries - min_held times, so fewer trials are made."""
    x = np.linspace(0.012, 0.031, 40)
    g = np.tile(np.array(DEEP), (len(x), 1))
    g[:, 0] = x
    full = jg.learn.robustness(g, box, trial=fake_sim, seed=5)
    early = jg.learn.robustness(g, box, trial=fake_sim, seed=5, stop_early=True)
    np.testing.assert_array_equal(early.robust, full.robust)
    assert 0 < full.robust.sum() < len(g)  # both kinds are present
    np.testing.assert_array_equal(early.held[full.robust], full.held[full.robust])
    np.testing.assert_array_equal(early.tries_made[full.robust], 10)
    stopped = early.tries_made < 10
    assert stopped.any() and not early.robust[stopped].any()
    # a stopped grasp failed exactly tries - min_held + 1 times
    np.testing.assert_array_equal((early.tries_made - early.held)[stopped], 3)
    assert early.num_trials == early.tries_made.sum() < full.num_trials
    assert np.all(early.probability <= 1) and early.most_robust_first()[1].tried is not None



# A ball of success: centre within 3 cm of BALL and turned at most 15° from the identity (one
# 12° neighbour turn holds, two do not); everything else misses.
BALL = np.array([0.0, 0.0, 0.05])


@pytest.fixture(scope="module")
def ball_sim(box):
    import jax  # why: only the ball trial is traced here
    import jax.numpy as jnp

    from tests.learn.conftest import fake_result  # why: the conftest's TrialResult builder

    @jax.jit
    def trial(grasps):
        g = jnp.asarray(grasps, jnp.float32)
        w = jnp.abs(g[:, 3]) / jnp.linalg.norm(g[:, 3:], axis=-1)
        held = (jnp.linalg.norm(g[:, :3] - BALL, axis=-1) < 0.03) & (w > np.cos(np.radians(7.5)))
        return fake_result(jnp.where(held, 0, 3).astype(jnp.int32),
                           jnp.where(held, 0.1, 0.0).astype(jnp.float32))

    return jg.learn.Simulator(box, trial=trial, batch_size=64)


def _grown(box, sim, budget, tried=None, defer=0):
    """The flood from one robust grasp at the ball (in order of kinds of step unless
    ``defer``: those tests check what it finds, and the order decides which pose of a cell)."""
    g = np.array([[*BALL, 1.0, 0.0, 0.0, 0.0]])
    grasps = GraspSet(g, to_transforms(g), np.full(1, 0.08), np.full(1, 0.1),
                      np.zeros(1, np.int8), "box", box.content_hash)
    rob = jg.learn.robustness(g, box, trial=sim)
    below = lambda p: np.asarray(p)[:, 2] < BALL[2] - 0.02  # noqa: E731 (a table, 2 cm down)
    return grasps, jg.learn.grow_robust(grasps, rob, box, trial=sim, budget=budget,
                                        tried=tried, seed=3, collides=below, defer=defer)


def test_grow_robust_finds_every_holding_neighbour_of_the_robust_grasps(box, ball_sim):
    """The flood from one robust grasp returns new distinct successes, each one step from a
    robust grasp and measured like any other, and, with an ample budget, it tried every
    neighbour of every robust grasp that holds, or the same grasp (1 cm / 10°) (so a flood
    that stopped early or skipped a neighbour fails)."""
    from jaxgrasp.learn.evaluate.atlas import neighbour_poses  # why: only this test needs it
    from jaxgrasp.learn.evaluate.distinct import same_as_any, same_grasp

    grasps, grown = _grown(box, ball_sim, budget=100_000)
    g, rob = grown.grasps, grown.robustness
    assert grown.added == len(g.grasps) - 1 > 20 and grown.rounds >= 2
    np.testing.assert_array_equal(g.grasps[:1], grasps.grasps)
    assert np.all(np.asarray(ball_sim.simulate_now(g.grasps.astype(np.float32)).outcome) == 0)
    same = same_grasp(g.grasps, g.grasps)
    np.fill_diagonal(same, False)
    assert not same.any()
    np.testing.assert_allclose(g.transforms[:, :3, 3], g.grasps[:, :3], atol=1e-6)
    assert len(rob.held) == len(g.grasps) and rob.robust[0] and not rob.robust.all()
    turned = np.abs(g.grasps[:, 3]) < 0.999  # a 12° turn: 3° of noise take it past 15° often
    assert rob.probability[turned].mean() < rob.probability[~turned].mean()
    robust = g.grasps[rob.robust]
    nb = neighbour_poses(robust)
    for k in range(1, len(g.grasps)):  # each added grasp: a neighbour of a robust one
        assert same_grasp(nb, g.grasps[k:k + 1]).any(), k
    # (1 cm above the table: nearer, a neighbour may be the same grasp as one that collided)
    held = (np.asarray(ball_sim.simulate_now(nb).outcome) == 0) & (nb[:, 2] >= BALL[2] - 0.01)
    assert held.sum() > 20
    assert same_as_any(nb[held], np.concatenate([grown.rolled, g.grasps[:1]])).all()
    assert len(grown.rolled) > grown.added  # the failures at the ball's edge were tried too
    # deferring the kinds of step that held least changes the order, not what an ample budget
    # tries: every holding neighbour of its own robust grasps too
    _, later = _grown(box, ball_sim, budget=100_000, defer=3)
    nb = neighbour_poses(later.grasps.grasps[later.robustness.robust])
    held = (np.asarray(ball_sim.simulate_now(nb).outcome) == 0) & (nb[:, 2] >= BALL[2] - 0.01)
    assert same_as_any(nb[held], np.concatenate([later.rolled, g.grasps[:1]])).all()
    assert abs(later.added - grown.added) < 0.1 * grown.added


def test_grow_robust_keeps_its_budget_and_skips_what_was_tried(box, ball_sim):
    _, small = _grown(box, ball_sim, budget=40)
    assert 0 < small.trials <= 40
    _, full = _grown(box, ball_sim, budget=100_000)
    assert full.trials < 100_000  # it ran dry
    _, none = _grown(box, ball_sim, budget=100_000, tried=full.grasps.grasps[1:])
    assert none.added == 0  # what was tried is not tried again
    with pytest.raises(ValueError, match="measured grasps"):
        jg.learn.grow_robust(full.grasps, small.robustness, box, trial=ball_sim, budget=10)


def test_grow_floods_from_every_success_robust_or_not(box, ball_sim):
    """``jg.learn.grow``: with an ample budget every holding neighbour of every grasp it holds
    was tried (or the same grasp); ``grow_robust`` leaves the neighbours of its grasps that are
    not robust (the companion: the same check fails on its set), and the budget holds."""
    from jaxgrasp.learn.evaluate.atlas import neighbour_poses  # why: only this test needs it
    from jaxgrasp.learn.evaluate.distinct import same_as_any

    grasps, robust_only = _grown(box, ball_sim, budget=100_000)
    below = lambda p: np.asarray(p)[:, 2] < BALL[2] - 0.02  # noqa: E731 (as _grown's table)
    full = jg.learn.grow(grasps, box, trial=ball_sim, budget=100_000, collides=below)
    assert full.trials < 100_000 and full.added > robust_only.added

    def untried_holding(g, rolled):
        nb = neighbour_poses(g)
        held = (np.asarray(ball_sim.simulate_now(nb).outcome) == 0) & (nb[:, 2] >= BALL[2] - 0.01)
        return int((held & ~same_as_any(nb, np.concatenate([rolled, grasps.grasps]))).sum())

    assert untried_holding(full.grasps.grasps, full.rolled) == 0
    assert untried_holding(robust_only.grasps.grasps, robust_only.rolled) > 0
    assert np.all(np.asarray(ball_sim.simulate_now(
        full.grasps.grasps.astype(np.float32)).outcome) == 0)
    small = jg.learn.grow(grasps, box, trial=ball_sim, budget=30, collides=below)
    assert 0 < small.trials <= 30 and small.added < full.added


@pytest.fixture(scope="module")
def islands(box):
    """A trial that holds within 1.5 cm and 15° of a grasp at the ball or of one of 30 seeded
    antipodal draws out of the ball's reach; the grasp's set and the distinct draws."""
    import jax  # why: only the islands' trial is traced here
    import jax.numpy as jnp

    from jaxgrasp.learn.evaluate.distinct import distinct_grasps
    from jaxgrasp.learn.setup.antipodal import antipodal_grasps
    from tests.learn.conftest import fake_result  # why: the conftest's TrialResult builder

    draws = antipodal_grasps(box, 30, seed=3, collides=_free).poses
    draws = draws[np.linalg.norm(draws[:, :3] - BALL, axis=1) > 0.03]  # out of the ball's reach
    centres = jnp.asarray(np.concatenate([BALL[None], draws[:, :3]]), jnp.float32)
    frames = jnp.asarray(np.concatenate([[[1.0, 0, 0, 0]], draws[:, 3:]]), jnp.float32)

    @jax.jit
    def trial(grasps):
        g = jnp.asarray(grasps, jnp.float32)
        q = g[:, 3:] / jnp.linalg.norm(g[:, 3:], axis=-1, keepdims=True)
        near = jnp.linalg.norm(g[:, None, :3] - centres, axis=-1) < 0.015
        turned = jnp.abs(q @ frames.T) > np.cos(np.radians(7.5))
        held = (near & turned).any(axis=1)
        return fake_result(jnp.where(held, 0, 3).astype(jnp.int32),
                           jnp.where(held, 0.1, 0.0).astype(jnp.float32))

    sim = jg.learn.Simulator(box, trial=trial, batch_size=64)
    distinct = distinct_grasps(draws)
    assert len(distinct) > 10
    return sim, _set_of(box, np.array([[*BALL, 1.0, 0.0, 0.0, 0.0]])), distinct


def _free(p):
    return np.zeros(len(p), bool)  # no table: every pose placed


def test_grow_robust_floods_from_antipodal_grasps_too(box, islands):
    """``antipodal=N``: the object's antipodal grasps (seeded) are rolled out first and the
    flood goes on from those that hold robustly too, islands the given grasps do not touch;
    without them the flood stays in the ball (the companion)."""
    from jaxgrasp.learn.evaluate.distinct import same_as_any  # why: only these tests need it

    sim, grasps, distinct = islands
    rob = jg.learn.robustness(grasps.grasps, box, trial=sim)
    grown = {n: jg.learn.grow_robust(grasps, rob, box, trial=sim, budget=100_000, seed=3,
                                     collides=_free, antipodal=n) for n in (0, 30)}
    assert not same_as_any(grown[0].grasps.grasps, distinct).any()
    assert same_as_any(distinct, grown[30].grasps.grasps).all()  # every draw held and kept
    # and the flood went on from them: their neighbours within the islands were added
    assert grown[30].added > grown[0].added + len(distinct) + 10
    assert grown[30].trials < 100_000 and grown[30].robustness.robust.sum() > len(distinct)


def test_grow_floods_from_antipodal_grasps_where_its_flood_ran_dry(box, islands):
    """``grow(..., antipodal=N)``: after the flood from the ball runs dry, the same draws are
    rolled out and flooded from; without them (the companion) nothing beyond the ball."""
    from jaxgrasp.learn.evaluate.distinct import same_as_any  # why: only these tests need it

    sim, grasps, distinct = islands
    grown = {n: jg.learn.grow(grasps, box, trial=sim, budget=100_000, collides=_free,
                              antipodal=n, seed=3) for n in (0, 30)}
    assert not same_as_any(grown[0].grasps.grasps, distinct).any()
    assert same_as_any(distinct, grown[30].grasps.grasps).all()
    assert grown[30].added > grown[0].added + len(distinct) + 10
    assert grown[30].trials < 100_000


def test_grow_draws_again_while_a_batch_finds_islands(box):
    """``grow(..., antipodal=N)`` draws another batch (the next seed) while the last one found
    a grasp: on a trial that holds only near the draws of seeds 3 and 4 (N each), both
    batches' islands are found and flooded; a third batch finds nothing and the drawing
    stops with budget left."""
    import jax  # why: only this test's trial is traced here
    import jax.numpy as jnp

    from jaxgrasp.learn.evaluate.distinct import distinct_grasps, same_as_any
    from jaxgrasp.learn.setup.antipodal import some_antipodal_grasps
    from tests.learn.conftest import fake_result  # why: the conftest's TrialResult builder

    draws = {s: some_antipodal_grasps(box, 12, seed=s, collides=_free) for s in (3, 4)}
    both = np.concatenate([draws[3], draws[4]])
    far = np.linalg.norm(both[:, :3] - BALL, axis=1) > 0.03
    centres = jnp.asarray(np.concatenate([BALL[None], both[far, :3]]), jnp.float32)
    frames = jnp.asarray(np.concatenate([[[1.0, 0, 0, 0]], both[far, 3:]]), jnp.float32)

    @jax.jit
    def trial(grasps):
        g = jnp.asarray(grasps, jnp.float32)
        q = g[:, 3:] / jnp.linalg.norm(g[:, 3:], axis=-1, keepdims=True)
        near = jnp.linalg.norm(g[:, None, :3] - centres, axis=-1) < 0.012
        held = (near & (jnp.abs(q @ frames.T) > np.cos(np.radians(6.0)))).any(axis=1)
        return fake_result(jnp.where(held, 0, 3).astype(jnp.int32),
                           jnp.where(held, 0.1, 0.0).astype(jnp.float32))

    sim = jg.learn.Simulator(box, trial=trial, batch_size=64)
    grasps = _set_of(box, np.array([[*BALL, 1.0, 0.0, 0.0, 0.0]]))
    grown = jg.learn.grow(grasps, box, trial=sim, budget=100_000, collides=_free, antipodal=12,
                          seed=3, finest=1.0)
    second = distinct_grasps(draws[4][np.linalg.norm(draws[4][:, :3] - BALL, axis=1) > 0.03])
    assert len(second) >= 3 and not same_as_any(second, draws[3]).all()
    assert same_as_any(distinct_grasps(both[far]), grown.grasps.grasps).all()
    assert grown.trials < 100_000  # the third batch found nothing: no fourth
    one = jg.learn.grow(grasps, box, trial=sim, budget=100_000, collides=_free, antipodal=12,
                        seed=4, finest=1.0)  # seeds 4, 5: the islands of seed 3 stay unfound
    assert not same_as_any(distinct_grasps(draws[3][far[:len(draws[3])]]),
                           one.grasps.grasps).all()


@pytest.mark.parametrize("robust", [False, True], ids=["grow", "grow_robust"])
def test_grow_tries_again_where_a_pose_failed(box, ball_sim, robust):
    """Budget left, ``grow`` (``grow_robust``) floods again from everything found (every
    robust grasp) at half the same-grasp distance from every tried pose: with each neighbour
    of the ball's grasp tried before at a pose turned 8° from it (the same grasp, 1 cm / 10°),
    the first flood tries nothing; the finer one rolls the neighbours out and fills the ball.
    Without it (the companion: ``finest=1``) nothing is added."""
    from jaxgrasp.learn.evaluate.atlas import neighbour_poses  # why: only these tests need it

    grasps, _ = _grown(box, ball_sim, budget=0)
    nb = neighbour_poses(grasps.grasps)
    turn = Rotation.from_euler("x", 8, degrees=True)
    tried = np.concatenate([nb[:, :3], (Rotation.from_quat(nb[:, 3:], scalar_first=True)
                                        * turn).as_quat(scalar_first=True)], axis=1)
    below = lambda p: np.asarray(p)[:, 2] < BALL[2] - 0.02  # noqa: E731 (as _grown's table)
    rob = jg.learn.robustness(grasps.grasps, box, trial=ball_sim)

    def grown(finest):
        kw = dict(trial=ball_sim, budget=100_000, tried=tried, collides=below, finest=finest)
        return (jg.learn.grow_robust(grasps, rob, box, seed=3, **kw) if robust
                else jg.learn.grow(grasps, box, **kw))

    finer = grown(0.25)
    assert finer.added > 20 and finer.trials < 100_000
    assert np.all(np.asarray(ball_sim.simulate_now(
        finer.grasps.grasps.astype(np.float32)).outcome) == 0)
    if robust:
        assert len(finer.robustness.held) == len(finer.grasps.grasps)
        np.testing.assert_array_equal(finer.robustness.grasps[1:], finer.grasps.grasps[1:])
    assert grown(1.0).added == 0


@pytest.fixture(scope="module")
def four_places(box):
    """A trial on the square box (4-fold turns) that holds only near a grasp on one face and
    near its quarter turns (1.5 cm and 15°); the grasp and the four places."""
    import jax  # why: only the four places' trial is traced here
    import jax.numpy as jnp

    from jaxgrasp.learn.evaluate.copies import symmetric_copies
    from jaxgrasp.objects.symmetry import Symmetry
    from tests.learn.conftest import fake_result  # why: the conftest's TrialResult builder

    g = np.array([[0.03, 0.0, 0.05, *Rotation.from_euler("y", 90, degrees=True).as_quat(
        scalar_first=True)]])
    places = np.concatenate([g, symmetric_copies(g, Symmetry("turns", order=4))]).astype(np.float32)
    assert len(places) == 4

    @jax.jit
    def four(grasps):
        x = jnp.asarray(grasps, jnp.float32)
        q = x[:, 3:] / jnp.linalg.norm(x[:, 3:], axis=-1, keepdims=True)
        near = jnp.linalg.norm(x[:, None, :3] - places[:, :3], axis=-1) < 0.015
        held = (near & (jnp.abs(q @ places[:, 3:].T) > np.cos(np.radians(7.5)))).any(axis=1)
        return fake_result(jnp.where(held, 0, 3).astype(jnp.int32),
                           jnp.where(held, 0.1, 0.0).astype(jnp.float32))

    return jg.learn.Simulator(box, trial=four, batch_size=64), g, places


def _set_of(box, g):
    return GraspSet(g, to_transforms(g), np.full(len(g), 0.08), np.full(len(g), 0.1),
                    np.zeros(len(g), np.int8), "box", box.content_hash)


def _near(grasps, places):
    """How many of ``grasps`` lie within 1.5 cm of each place."""
    d = np.linalg.norm(np.asarray(grasps)[:, None, :3] - places[:, :3], axis=-1)
    return [int(n) for n in (d < 0.015).sum(axis=0)]


def test_grow_robust_turns_robust_grasps_by_the_object_s_symmetry(box, four_places):
    """``symmetry``: after the flood, each robust grasp's copies turned by the object's
    symmetry are tried. On the square box (4-fold turns) the flood fills the first place and
    every robust grasp there is copied to the other three; without the symmetry only the first
    place has grasps (the companion)."""
    sim, g, places = four_places
    rob = jg.learn.robustness(g, box, trial=sim)
    free = lambda p: np.zeros(len(p), bool)  # noqa: E731 (no table: every pose placed)
    grown = {s: jg.learn.grow_robust(_set_of(box, g), rob, box, trial=sim, budget=100_000,
                                     seed=3, collides=free, symmetry=s, finest=1.0)
             for s in (None, "turns:4", "auto")}
    at = {s: _near(r.grasps.grasps, places) for s, r in grown.items()}
    robust = int(grown[None].robustness.robust.sum())
    assert at[None][0] > robust > 3 and at[None][1:] == [0, 0, 0]
    # the flood's grasps at the first place, and every robust one's copy at each other place
    assert at["turns:4"] == [at[None][0], robust, robust, robust], (at, robust)
    np.testing.assert_array_equal(
        grown["turns:4"].grasps.grasps[:len(grown[None].grasps.grasps)],
        grown[None].grasps.grasps)
    # found from the mesh: the quarter turns and four mirror planes, whose images add more
    assert min(at["auto"][1:]) >= robust and at["auto"][0] >= at[None][0], at
    assert grown[None].swapped == grown["turns:4"].swapped == 0  # no grasp there to replace


def test_a_robust_turned_copy_takes_the_place_of_a_grasp_that_is_not(box, four_places):
    """A set with a grasp 7 mm from the second place (the same grasp as the copy there, 1 cm /
    10°), measured not robust: the copy, robust, takes its row; nothing else is added there.
    Without the symmetry the row stays (the companion)."""
    from jaxgrasp.learn.evaluate.distinct import same_as_any  # why: only this test needs it

    sim, g, places = four_places
    off = places[1:2].astype(np.float64) + [[0.0, 0.0, 0.007, 0, 0, 0, 0]]
    both = np.concatenate([g, off])
    rob = Robustness(both, np.array([10, 2]), PoseNoise())
    free = lambda p: np.zeros(len(p), bool)  # noqa: E731 (no table: every pose placed)
    grown = {s: jg.learn.grow_robust(_set_of(box, both), rob, box, trial=sim, budget=100_000,
                                     seed=3, collides=free, symmetry=s)
             for s in (None, "turns:4")}
    turned = grown["turns:4"]
    assert turned.swapped == 1 and turned.robustness.held[1] >= 8
    np.testing.assert_allclose(turned.grasps.grasps[1, :3], places[1, :3], atol=1e-6)
    assert not same_as_any(turned.grasps.grasps[2:], places[1:2]).any()
    assert grown[None].swapped == 0 and grown[None].robustness.held[1] == 2
    # the copies keep to what the flood left of the budget (here two copies' worth)
    tight = grown[None].trials + 2 * 11 + 5
    few = jg.learn.grow_robust(_set_of(box, both), rob, box, trial=sim, budget=tight, seed=3,
                               collides=free, symmetry="turns:4")
    assert grown[None].trials < few.trials <= tight
    np.testing.assert_allclose(grown[None].grasps.grasps[1], off[0], atol=1e-6)


def test_grow_robust_takes_a_result(box_sim, kd_result):
    """A LearnResult: its selected grasps first, its proposals count as tried (real physics)."""
    from jaxgrasp.learn.evaluate.distinct import same_as_any  # why: only this test needs it
    from jaxgrasp.learn.files.export import select_grasps

    rob = jg.learn.robustness(kd_result, trial=box_sim, noise=PoseNoise(tries=4),
                              stop_early=True)
    grown = jg.learn.grow_robust(kd_result, rob, trial=box_sim, budget=300)
    n = len(kd_result.grasps)
    np.testing.assert_allclose(grown.grasps.grasps[:n], select_grasps(kd_result).grasps)
    assert rob.robust.any() and grown.added > 0 and 0 < grown.trials <= 300
    proposals = np.asarray(kd_result.proposals).reshape(-1, 7)
    assert not same_as_any(grown.rolled, proposals).any()
    assert np.all(grown.grasps.outcome[n:] == 0) and np.all(grown.grasps.epsilon[n:] > 0)


def test_robust_sets_overlap_counts_shared_grasps(load_benchmark):
    """``benchmarks/robust_grasps.py``'s overlap: 4 and 3 grasps sharing 2 give 5 in all and
    the estimate 4 * 3 / 2 = 6; a set turned by 90° about its approach shares none."""
    overlap = load_benchmark("robust_grasps").overlap
    unit = np.array([1.0, 0.0, 0.0, 0.0])
    a = np.array([[0.05 * i, 0.0, 0.0, *unit] for i in range(4)])
    b = np.concatenate([a[2:] + [0.003, 0, 0, 0, 0, 0, 0], [[0.0, 0.3, 0.0, *unit]]])
    out = overlap("x", {1: a, 2: b})
    assert out["robust_union"] == 5
    assert out["pairs"] == [{"seeds": [1, 2], "sizes": [4, 3], "shared": 2, "estimate": 6}]
    turned = a.copy()
    turned[:, 3:] = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    assert overlap("x", {1: a, 2: turned})["pairs"][0]["shared"] == 0


def test_grow_copies_its_grasps_by_the_object_s_symmetry(box, four_places):
    """``grow(..., symmetry=...)``: where the flood runs dry, the copies of its grasps under
    the object's turns are tried and flooded from, so each of the four places fills as the
    first did; without the symmetry (the companion) only the first place has grasps. The
    budget holds."""
    sim, g, places = four_places
    free = lambda p: np.zeros(len(p), bool)  # noqa: E731 (no table: every pose placed)
    grown = {s: jg.learn.grow(_set_of(box, g), box, trial=sim, budget=100_000, collides=free,
                              symmetry=s) for s in (None, "turns:4")}
    at = {s: _near(r.grasps.grasps, places) for s, r in grown.items()}
    assert at[None][0] > 5 and at[None][1:] == [0, 0, 0], at
    assert min(at["turns:4"][1:]) >= at[None][0] - 2, at  # (the same-grasp test's edges)
    assert grown["turns:4"].trials < 100_000 and grown["turns:4"].rounds > grown[None].rounds
    assert np.all(np.asarray(sim.simulate_now(
        grown["turns:4"].grasps.grasps.astype(np.float32)).outcome) == 0)
    tight = grown[None].trials + 5
    few = jg.learn.grow(_set_of(box, g), box, trial=sim, budget=tight, collides=free,
                        symmetry="turns:4")
    assert grown[None].trials < few.trials <= tight

"""Small-scale versions of the paper's experiments on the test box, with the real MJX trial."""

import jax
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn.algorithm import make_algorithm
from jaxgrasp.learn.chains import run_chains

SUCCESS = 0


def test_demonstrations_succeed_and_are_deterministic(box, box_sim, small_params, kd_result):
    d = jg.learn.demonstrations(box, num=3, seed=0, trial=box_sim, params=small_params)
    assert d.poses.shape == (3, 7)
    np.testing.assert_array_equal(d.results.outcome, SUCCESS)
    np.testing.assert_allclose(np.linalg.norm(d.poses[:, 3:], axis=1), 1.0, atol=1e-5)
    # the kept demos succeed again when re-simulated
    np.testing.assert_array_equal(box_sim(d.poses).outcome, SUCCESS)
    # same seed, same demos (active() made its own with seed 0)
    np.testing.assert_array_equal(d.poses, kd_result.demos.poses)


def test_learned_grasps_succeed_when_resimulated(box_sim, kd_result):
    r = kd_result
    hit = r.outcomes == SUCCESS
    assert hit.sum() > 0
    # the proposals exactly as simulated during the run
    np.testing.assert_array_equal(box_sim(r.proposals[hit]).outcome, SUCCESS)
    # the reported grasps (normalized, qw >= 0, de-duplicated)
    g = r.grasps
    assert 0 < len(g) <= hit.sum()
    ok = box_sim(g).outcome == SUCCESS
    assert ok.mean() >= 0.9, f"only {ok.sum()} of {len(g)} learned grasps succeed again"


def test_outcomes_match_a_fresh_simulation(box_sim, rw_result):
    """The counted outcome of each proposal is what the physics says for that proposal."""
    r = rw_result
    res = box_sim(r.proposals.reshape(-1, 7))
    np.testing.assert_array_equal(res.outcome.reshape(r.outcomes.shape), r.outcomes)


def test_one_rollout_per_proposal(box, fake_sim, small_params):
    alg = make_algorithm("random_walk", fake_sim, small_params)
    start = np.tile(np.array([0.0, 0.0, 0.05, 1, 0, 0, 0], np.float32), (4, 1))
    before = fake_sim.num_trials
    run_chains(alg, jax_key(0), start, 20, progress=False)
    assert fake_sim.num_trials - before == 4 * (20 + 1)  # 20 steps + the initial state


def jax_key(seed):
    import jax

    return jax.random.key(seed)


def test_kameleon_darting_beats_random_walk(kd_result, rw_result):
    """Paper Table II: Kameleon + GDMC finds far more grasps than the random walk."""
    kd, rw = kd_result.counts[:, SUCCESS], rw_result.counts[:, SUCCESS]
    assert kd.sum() >= 2 * rw.sum() + 10, (kd, rw)
    assert np.median(kd) > np.median(rw), (kd, rw)


def test_transfer_from_saved_source(tmp_path, box, box_sim, kd_result):
    kd_result.save(tmp_path / "source")
    tr = jg.learn.transfer(tmp_path / "source", box, modes="source", chains=4, seed=1,
                           trial=box_sim, progress=False)
    assert tr.workflow == "transfer" and tr.sketch == "source" and tr.modes_kind == "source"
    assert tr.source_object == box.name
    np.testing.assert_array_equal(tr.modes, kd_result.demos.poses)
    np.testing.assert_array_equal(tr.demos.poses, kd_result.demos.poses)
    # the sketch is the source's chain history, no new sketch run
    hist = kd_result.positions.reshape(-1, 7)
    assert len(tr.sketch_points) == min(len(hist), kd_result.params.sketch_size)
    assert np.isin(tr.sketch_points.view([("", tr.sketch_points.dtype)] * 7),
                   hist.view([("", hist.dtype)] * 7)).all()
    np.testing.assert_array_equal(tr.counts.sum(axis=1), kd_result.params.num_steps)
    assert tr.counts[:, SUCCESS].sum() > 0


def test_transfer_with_target_modes(tmp_path, box, fake_sim, small_params):
    src = jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=2,
                          params=small_params, trial=fake_sim, progress=False)
    src.save(tmp_path)
    tr = jg.learn.transfer(jg.learn.load(tmp_path), box, modes="target", seed=4,
                           trial=fake_sim, progress=False)
    target_demos = jg.learn.demonstrations(box, num=3, seed=4, trial=fake_sim,
                                           params=small_params)
    np.testing.assert_array_equal(tr.modes, target_demos.poses)
    with pytest.raises(ValueError, match="modes"):
        jg.learn.transfer(src, box, modes="mine", trial=fake_sim)


@pytest.mark.slow  # an option off by default; ~20 s of compiling its own run
def test_demo_fallback_to_slipped(box, fake_trial, small_params):
    """No candidate holds: an error by default, the best slipped ones when asked."""

    def never_holds(grasps):
        res = jax.tree.map(np.asarray, fake_trial(np.asarray(grasps)))
        return res._replace(outcome=np.where(res.outcome == 0, 1, res.outcome))

    sim = jg.learn.Simulator(box, trial=never_holds, batch_size=4)
    params = small_params.replace(demo_candidates=1)
    with pytest.raises(ValueError, match="no demonstrated grasp"):
        jg.learn.demonstrations(box, num=3, seed=0, trial=sim, params=params)
    with pytest.warns(UserWarning, match="slipped"):
        d = jg.learn.demonstrations(box, num=3, seed=0, trial=sim,
                                    params=params.replace(demo_fallback="slipped"))
    assert len(d.poses) == 3
    np.testing.assert_array_equal(d.results.outcome, 1)
    assert np.all(np.diff(d.results.epsilon) <= 0)  # best epsilon first

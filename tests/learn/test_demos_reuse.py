"""Precomputed demonstrations (``demos=``): same chains as computing them inside."""

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn.pipeline import chain_starts


def test_active_with_precomputed_demos_is_identical(box, fake_sim, small_params):
    kw = dict(method="kameleon_darting", sketch="random", chains=4, seed=3,
              params=small_params, trial=fake_sim, progress=False)
    inner = jg.learn.active(box, **kw)
    demos = jg.learn.demonstrations(box, num=small_params.num_demos, seed=3, trial=fake_sim,
                                    params=small_params)
    outer = jg.learn.active(box, demos=demos, **kw)
    np.testing.assert_array_equal(inner.demos.poses, outer.demos.poses)
    np.testing.assert_array_equal(inner.positions, outer.positions)
    np.testing.assert_array_equal(inner.outcomes, outer.outcomes)


@pytest.mark.slow  # the same reuse as the active test above, through transfer
def test_transfer_target_with_precomputed_demos_is_identical(box, fake_sim, small_params):
    src = jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=1,
                          params=small_params, trial=fake_sim, progress=False)
    kw = dict(modes="target", seed=5, trial=fake_sim, progress=False)
    inner = jg.learn.transfer(src, box, **kw)
    demos = jg.learn.demonstrations(box, num=small_params.num_demos, seed=5, trial=fake_sim,
                                    params=src.params)
    outer = jg.learn.transfer(src, box, demos=demos, **kw)
    np.testing.assert_array_equal(inner.positions, outer.positions)
    with pytest.raises(ValueError, match="modes='target'"):
        jg.learn.transfer(src, box, modes="source", demos=demos, trial=fake_sim)


def test_bad_demos_rejected(box, fake_sim, small_params):
    with pytest.raises(ValueError, match="demos"):
        jg.learn.active(box, demos=np.zeros((2, 7)), trial=fake_sim, params=small_params)


def test_demo_search_progress(box, fake_sim, small_params, capsys):
    """``progress=True`` shows the candidates simulated and the demos found; the same demos."""
    quiet = jg.learn.demonstrations(box, num=small_params.num_demos, seed=3, trial=fake_sim,
                                    params=small_params)
    shown = jg.learn.demonstrations(box, num=small_params.num_demos, seed=3, trial=fake_sim,
                                    params=small_params, progress=True)
    np.testing.assert_array_equal(quiet.poses, shown.poses)
    err = capsys.readouterr().err
    assert f"{box.name} demos" in err
    assert f"found={len(shown.poses)}/{small_params.num_demos}" in err


def test_spares_are_the_searchs_other_distinct_successes(box, fake_sim, small_params):
    """Every spare held in the trial, and none is the same grasp as a demo or another spare."""
    from jaxgrasp.learn.evaluate.distinct import same_grasp
    demos = jg.learn.demonstrations(box, num=small_params.num_demos, seed=3, trial=fake_sim,
                                    params=small_params)
    spares = demos.spares
    assert spares.shape[1:] == (7,) and len(spares) >= 1
    assert np.all(np.asarray(fake_sim(spares).outcome) == 0)
    assert not same_grasp(spares, demos.poses).any()
    pairs = same_grasp(spares, spares)
    assert not pairs[~np.eye(len(spares), dtype=bool)].any()


def test_spread_starts_use_the_spares_then_cycle():
    """Chains beyond the demos start at one spare each; without ``spread``, the paper's starts
    (chain c at demo c mod m); with too few spares the starts cycle over demos and spares."""
    unit = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    demos = jg.learn.Demos(np.array([[0.01, 0, 0, 1, 0, 0, 0], [0.02, 0, 0, 1, 0, 0, 0]]),
                           None, np.array([unit], np.float32) + [0.05, 0, 0, 0, 0, 0, 0])
    modes, spare = np.asarray(demos.poses, np.float32), demos.spares[0]
    paper = chain_starts(demos, 5, spread=False)
    np.testing.assert_array_equal(paper, modes[[0, 1, 0, 1, 0]])
    spread = chain_starts(demos, 5, spread=True)
    np.testing.assert_array_equal(spread, np.stack([modes[0], modes[1], spare, modes[0],
                                                    modes[1]]))
    np.testing.assert_array_equal(chain_starts(demos, 2, spread=True), modes)


def test_a_run_with_spread_starts_starts_there(box, fake_sim, small_params, tmp_path):
    """``LearnParams.spread_starts``: the run's initial positions are the demos, then spares,
    also when a checkpointed run is started again from its saved setup."""
    params = small_params.replace(spread_starts=True)
    demos = jg.learn.demonstrations(box, num=params.num_demos, seed=3, trial=fake_sim,
                                    params=params)
    chains = params.num_demos + 1
    kw = dict(method="random_walk", chains=chains, seed=3, params=params, trial=fake_sim,
              progress=False)
    res = jg.learn.active(box, demos=demos, **kw)
    np.testing.assert_allclose(res.initial_positions,
                               np.concatenate([demos.poses, demos.spares[:1]]), atol=1e-6)
    first = jg.learn.active(box, checkpoint_dir=tmp_path, **kw)
    for name in ("result.npz", "result.json"):  # the setup stays: the run starts from it
        (tmp_path / name).unlink()
    again = jg.learn.active(box, checkpoint_dir=tmp_path, **kw)
    np.testing.assert_array_equal(first.initial_positions, res.initial_positions)
    np.testing.assert_array_equal(again.initial_positions, res.initial_positions)


def test_spread_demos_are_farthest_apart(box, fake_sim, small_params):
    """``demo_choice="spread"``: the same search (same trials), the demos chosen among all its
    successes so that their closest pair is farther apart than the first ones' (farthest
    point: each next demo the success farthest from those chosen); the rest are spares."""
    from jaxgrasp.learn.evaluate.distinct import grasp_distances

    def closest_pair(poses):
        d = grasp_distances(poses, poses, length_scale=small_params.length_scale)
        return d[~np.eye(len(poses), dtype=bool)].min()

    n0 = fake_sim.num_trials
    first = jg.learn.demonstrations(box, num=small_params.num_demos, seed=3, trial=fake_sim,
                                    params=small_params)
    n1 = fake_sim.num_trials
    spread = jg.learn.demonstrations(box, num=small_params.num_demos, seed=3, trial=fake_sim,
                                     params=small_params.replace(demo_choice="spread"))
    assert fake_sim.num_trials - n1 == n1 - n0
    np.testing.assert_array_equal(spread.poses[0], first.poses[0])
    assert np.all(np.asarray(fake_sim(spread.poses).outcome) == 0)
    assert closest_pair(spread.poses) > closest_pair(first.poses)
    everything = np.concatenate([spread.poses, spread.spares])
    d = grasp_distances(everything, spread.poses[:2], length_scale=small_params.length_scale)
    assert np.argmax(d.min(axis=1)) == 2  # the third demo: farthest from the first two


def test_grasp_distances_fold_the_grippers_turn():
    """A hand value: 3 cm apart and turned 90° about x is 0.03 + L * pi / 2; turned 180° about
    the approach (z) it is the same grasp (distance 0)."""
    from jaxgrasp.learn.evaluate.distinct import grasp_distances
    a = np.array([[0.0, 0, 0, 1, 0, 0, 0]])
    b = np.array([[0.03, 0, 0, np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0]])
    flip = np.array([[0.0, 0, 0, 0, 0, 0, 1]])
    np.testing.assert_allclose(grasp_distances(a, b, length_scale=0.1), [[0.03 + 0.05 * np.pi]])
    np.testing.assert_allclose(grasp_distances(a, flip, length_scale=0.1), [[0.0]], atol=1e-7)


def test_spread_choice_never_picks_a_success_twice():
    """Six successes at two poses: five distinct rows are chosen, not the first one again."""
    from jaxgrasp.learn.setup.demos import _spread_choice
    poses = np.array([[0.0, 0, 0, 1, 0, 0, 0]] * 3 + [[0.05, 0, 0, 1, 0, 0, 0]] * 3)
    res = jg.physics.TrialResult(*[np.arange(6)] * len(jg.physics.TrialResult._fields))
    [(_, chosen)], _ = _spread_choice([(poses, res)], 5, jg.learn.LearnParams())
    picked = np.asarray(chosen.outcome)  # the rows chosen (outcome holds the row number)
    assert sorted(picked.tolist()) == sorted(set(picked.tolist())) and len(picked) == 5
    assert set(picked[:2].tolist()) == {0, 3}


def test_antipodal_demos_are_spread_antipodal_successes(box, fake_sim, small_params, tmp_path,
                                                        monkeypatch):
    """``demo_choice="antipodal"``: the demos are successes of the seeded antipodal batch,
    spread like ``"spread"``'s (the first, then the farthest); the batch is saved and read back
    (no trial again); where too few antipodal grasps succeed the candidate search runs (its
    first successes, the default's demos)."""
    from jaxgrasp.learn.evaluate.distinct import same_as_any
    from jaxgrasp.learn.files.checkpoint import CheckpointDir
    from jaxgrasp.learn.setup import demos as D
    from jaxgrasp.learn.setup.antipodal import antipodal_grasps, placement_collisions

    num, params = small_params.num_demos, small_params.replace(demo_choice="antipodal")
    draws = antipodal_grasps(box, num * D.ANTIPODAL_PER_DEMO, seed=3,
                             collides=placement_collisions(fake_sim)).poses
    held = draws[np.asarray(fake_sim(draws).outcome) == 0]
    assert len(held) >= num
    ckpt = CheckpointDir(tmp_path, {"run": "antipodal demos"})
    got = jg.learn.demonstrations(box, num=num, seed=3, trial=fake_sim, params=params,
                                  checkpoint=ckpt)
    assert same_as_any(got.poses, held).all() and np.array_equal(got.poses[0], held[0])
    assert np.all(np.asarray(fake_sim(got.poses).outcome) == 0)
    [(chosen, _)], _ = D._spread_choice([(held, fake_sim(held))], num, params)
    np.testing.assert_array_equal(got.poses, chosen.astype(np.float32))
    assert not same_as_any(got.spares, got.poses).any() and len(got.spares) > 0
    n = fake_sim.num_trials
    again = jg.learn.demonstrations(box, num=num, seed=3, trial=fake_sim, params=params,
                                    checkpoint=CheckpointDir(tmp_path, {"run": "antipodal demos"}))
    assert fake_sim.num_trials == n  # read back, not simulated again
    np.testing.assert_array_equal(again.poses, got.poses)
    # too few antipodal successes (none drawn here): the candidate search's first successes
    monkeypatch.setattr(D, "some_antipodal_grasps", lambda *a, **k: np.zeros((0, 7)))
    fallback = jg.learn.demonstrations(box, num=num, seed=3, trial=fake_sim, params=params)
    first = jg.learn.demonstrations(box, num=num, seed=3, trial=fake_sim, params=small_params)
    np.testing.assert_array_equal(fallback.poses, first.poses)
    assert not same_as_any(first.poses, held).all()  # the companion: other demos

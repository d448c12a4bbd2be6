"""The demo search saves each simulated batch of candidates; run again after an interruption,
it reads them back (no optimizing or simulating them again) and finds the same demos."""

import jax
import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp.learn.files.checkpoint import CheckpointDir
from jaxgrasp.learn.setup import demos as D


@pytest.fixture
def one_success_per_batch(monkeypatch, fake_sim):
    """Simulator calls hold one success each (row 0), so the search needs several batches;
    ``calls`` counts them and ``stop_at`` raises Ctrl-C at that call."""
    state = {"calls": 0, "stop_at": None}
    simulate = jg.learn.Simulator.__call__

    def call(self, grasps):
        state["calls"] += 1
        if state["calls"] == state["stop_at"]:
            raise KeyboardInterrupt
        res = jax.tree.map(np.asarray, simulate(self, grasps))
        outcome = np.full_like(res.outcome, int(jg.physics.Outcome.MISS))
        outcome[0] = int(jg.physics.Outcome.SUCCESS)
        return res._replace(outcome=outcome)

    monkeypatch.setattr(jg.learn.Simulator, "__call__", call)
    return state


def _search(box, fake_sim, small_params, checkpoint=None):
    # One candidate point per wanted demo and round: few poses to optimize, the same logic.
    params = small_params.replace(demo_candidates=1)
    return jg.learn.demonstrations(box, num=3, seed=0, trial=fake_sim, params=params,
                                   checkpoint=checkpoint)


def test_an_interrupted_demo_search_resumes_from_its_saved_batches(
        tmp_path, monkeypatch, box, fake_sim, small_params, one_success_per_batch):
    state = one_success_per_batch
    reference = _search(box, fake_sim, small_params)
    total = state["calls"]
    assert total >= 3  # one success a batch: three batches for three demos

    ckpt = CheckpointDir(tmp_path, {"run": "demo search"})
    state.update(calls=0, stop_at=total)  # Ctrl-C during the last batch
    with pytest.raises(KeyboardInterrupt):
        _search(box, fake_sim, small_params, ckpt)
    assert len(list(tmp_path.glob("setup_part_*.npz"))) == total - 1

    optimized, optimize = [], D.candidate_poses
    monkeypatch.setattr(D, "candidate_poses",
                        lambda *a, **k: optimized.append(1) or optimize(*a, **k))
    state.update(calls=0, stop_at=None)
    resumed = _search(box, fake_sim, small_params, CheckpointDir(tmp_path,
                                                                 {"run": "demo search"}))
    # Only the unfinished batch (the second round's optimized candidates) is made again.
    assert state["calls"] == 1 and len(optimized) == 1
    np.testing.assert_array_equal(resumed.poses, reference.poses)
    for a, b in zip(resumed.results, reference.results, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_another_runs_saved_batches_are_refused(tmp_path, box, fake_sim, small_params,
                                                one_success_per_batch):
    one_success_per_batch["stop_at"] = 2
    with pytest.raises(KeyboardInterrupt):
        _search(box, fake_sim, small_params, CheckpointDir(tmp_path, {"seed": 0}))
    with pytest.raises(ValueError, match="another run"):
        _search(box, fake_sim, small_params, CheckpointDir(tmp_path, {"seed": 1}))


def test_a_saved_setup_drops_the_parts(tmp_path):
    ckpt = CheckpointDir(tmp_path, {"run": 1})
    ckpt.save_part("demos_round0_family0", {"poses": np.zeros((2, 7), np.float32)})
    assert ckpt.load_part("demos_round0_family0")["poses"].shape == (2, 7)
    ckpt.save_setup({"demo_poses": np.zeros((1, 7), np.float32)})
    assert ckpt.load_part("demos_round0_family0") is None

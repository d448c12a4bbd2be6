"""A run as ArviZ's DataTree: the chains and per-step stats land where ArviZ looks."""

import numpy as np
import pytest
from arviz_stats.base import array_stats

import jaxgrasp as jg
from jaxgrasp.learn.evaluate.trace import COORDS, to_arviz
from jaxgrasp.mcmc import diagnostics


@pytest.fixture(scope="module")
def fake_result(box, fake_sim, small_params):
    return jg.learn.active(box, method="kameleon_darting", sketch="random", chains=4, seed=3,
                           params=small_params, trial=fake_sim, progress=False)


def test_groups_hold_the_chains_chain_major(fake_result):
    r, burn = fake_result, fake_result.params.burn_in
    tree = r.to_arviz()
    post = tree["posterior"]["grasp"]
    assert post.dims == ("chain", "draw", "coord")
    assert post.shape == (r.num_chains, r.num_steps - burn, 7)
    assert tuple(tree["posterior"]["coord"].values) == COORDS
    np.testing.assert_array_equal(post.values[2, :, :], r.positions[burn:, 2])
    stats = tree["sample_stats"]
    np.testing.assert_array_equal(stats["outcome"].values[1], r.outcomes[burn:, 1])
    np.testing.assert_array_equal(stats["accepted"].values.T, r.accepted[burn:])
    np.testing.assert_array_equal(stats["epsilon"].values.T, r.epsilons[burn:])
    np.testing.assert_array_equal(tree["warmup_posterior"]["grasp"].values[0],
                                  r.positions[:burn, 0])
    assert tree.attrs["object"] == r.object_name and tree.attrs["seed"] == r.seed
    assert "warmup_posterior" not in to_arviz(r, include_burn_in=False).children


def test_arviz_and_our_diagnostics_read_the_same_chains(fake_result):
    burn = fake_result.params.burn_in
    ours = diagnostics.effective_sample_size(fake_result.positions[burn:])
    theirs = array_stats.ess(to_arviz(fake_result)["posterior"]["grasp"].values,
                             chain_axis=0, draw_axis=1, method="bulk")
    moving = ours > 0
    assert moving.all(), ours  # every coordinate of the fake run moves: all are compared
    np.testing.assert_allclose(ours[moving], theirs[moving], rtol=1e-6)

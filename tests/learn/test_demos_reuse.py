"""Precomputed demonstrations (``demos=``): same chains as computing them inside."""

import numpy as np
import pytest

import jaxgrasp as jg


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

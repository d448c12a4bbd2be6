"""``python -m jaxgrasp.view``: one offline HTML page with the object, grasps and demos."""

import re

import numpy as np
import pytest

import jaxgrasp as jg
from jaxgrasp import view
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory):
    """A pitcher run of random proposals, 3 of them successes, saved as a run directory."""
    rng = np.random.default_rng(0)
    params = jg.learn.LearnParams(iterations=8, burn_in=2)
    pos = rng.normal(0.0, 0.05, size=(10, 2, 7)).astype(np.float32)
    pos[..., 3] += 1.0
    outcomes = np.full((10, 2), 1, np.int8)
    outcomes[[1, 4, 7], 0] = 0
    obj = jg.objects.load("pitcher")
    r = LearnResult(
        object_name=obj.name, object_hash=obj.content_hash, workflow="active",
        method="kameleon_darting", sketch="biased", modes_kind="demos", seed=0,
        backend="mujoco", params=params, positions=pos, proposals=pos, outcomes=outcomes,
        epsilons=(0.1 * (outcomes == 0)).astype(np.float32), accepted=outcomes == 0,
        is_jump=np.zeros((10, 2), bool), initial_positions=pos[0], modes=pos[0],
        sketch_points=pos[:, 0], demos=Demos(pos[0], None))
    out = tmp_path_factory.mktemp("run")
    r.save(out)
    return out


def test_page_is_self_contained_and_draws_every_group(saved_run, tmp_path, capsys):
    out = tmp_path / "v.html"
    assert view.main([str(saved_run), "--out", str(out), "--outcomes", "success,slipped"]) == 0
    html = out.read_text()
    assert not re.search(r"<script[^>]+src=", html)  # plotly.js inline: opens offline
    assert "success (3 distinct)" in html and "demos (2)" in html and "slipped (" in html
    assert "pitcher" in html and str(out) in capsys.readouterr().out


def test_marker_spans_the_opening():
    m = view.gripper_marker(0.08)
    assert np.ptp(m[:, 1]) == pytest.approx(0.08) and (m[:, 0] == 0).all()


@pytest.mark.parametrize("argv, match", [
    (["--outcomes", "won"], "unknown outcome"),
    (["--color", "red"], None),
])
def test_bad_flags(saved_run, tmp_path, argv, match, capsys):
    if match is None:
        with pytest.raises(SystemExit):
            view.main([str(saved_run), *argv])
        return
    assert view.main([str(saved_run), "--out", str(tmp_path / "v.html"), *argv]) == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "v.html").exists()


def test_missing_run_is_a_clear_error(tmp_path, capsys):
    assert view.main([str(tmp_path / "nothing")]) == 2
    assert "error:" in capsys.readouterr().err

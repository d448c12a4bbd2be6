"""``python -m jaxgrasp.view``: one offline HTML page with the object, grasps and demos."""

import re

import numpy as np
import pytest
import trimesh

import jaxgrasp as jg
from jaxgrasp import view
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos


def save_run(obj, out, *, name=None, content_hash=None):
    """A run on ``obj`` of random proposals, 3 of them successes, saved in ``out``."""
    rng = np.random.default_rng(0)
    params = jg.learn.LearnParams(iterations=8, burn_in=2)
    pos = rng.normal(0.0, 0.05, size=(10, 2, 7)).astype(np.float32)
    pos[..., 3] += 1.0
    outcomes = np.full((10, 2), 1, np.int8)
    outcomes[[1, 4, 7], 0] = 0
    r = LearnResult(
        object_name=name or obj.name, object_hash=content_hash or obj.content_hash,
        workflow="active", method="kameleon_darting", sketch="biased", modes_kind="demos",
        seed=0, backend="mujoco", params=params, positions=pos, proposals=pos,
        outcomes=outcomes, epsilons=(0.1 * (outcomes == 0)).astype(np.float32),
        accepted=outcomes == 0, is_jump=np.zeros((10, 2), bool), initial_positions=pos[0],
        modes=pos[0], sketch_points=pos[:, 0], demos=Demos(pos[0], None))
    r.save(out)
    return out


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory):
    """A pitcher run of random proposals, 3 of them successes, saved as a run directory."""
    return save_run(jg.objects.load("pitcher"), tmp_path_factory.mktemp("run"))


@pytest.fixture(autouse=True)
def _own_object_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # from_mesh's decompositions


@pytest.fixture(scope="module")
def cylinder(tmp_path_factory):
    """A user's 6 x 10 cm cylinder, its file centred on the origin, and runs learned on it with
    ``--scale`` 1 and 0.5 (objects stand on z = 0: the grasps are in that frame)."""
    tmp = tmp_path_factory.mktemp("cylinder")
    stl = tmp / "cylinder.stl"
    trimesh.creation.cylinder(radius=0.03, height=0.1).export(stl)
    runs = {scale: save_run(jg.objects.from_mesh(stl, scale=scale, cache=False),
                            tmp / f"run_{scale:g}") for scale in (1.0, 0.5)}
    return stl, runs


def test_page_is_self_contained_and_draws_every_group(saved_run, tmp_path, capsys):
    out = tmp_path / "v.html"
    assert view.main([str(saved_run), "--out", str(out), "--outcomes", "success,slipped"]) == 0
    html = out.read_text()
    assert not re.search(r"<script[^>]+src=", html)  # plotly.js inline: opens offline
    assert "success (3 distinct)" in html and "demos (2)" in html and "slipped (" in html
    assert "pitcher" in html and str(out) in capsys.readouterr().out


def test_a_run_carrying_robustness_is_coloured_by_it(saved_run, tmp_path):
    """The saved run's grasps with their hold counts: the page's colour bar and each grasp's
    hover text say how often it held; the colours are the hold probabilities."""
    run = jg.learn.load(saved_run)
    held = np.array([9, 2, 10])[:len(run.grasps)]
    rob = jg.learn.Robustness(run.grasps.astype(float), held, jg.learn.PoseNoise(tries=10))
    run.with_robustness(rob).save(tmp_path / "run")
    assert view.main([str(tmp_path / "run"), "--out", str(tmp_path / "v.html")]) == 0
    html = (tmp_path / "v.html").read_text()
    # plotly writes "/" and "°" as \u escapes
    assert "held in k of 10 tries" in html and "held in 2 of 10 tries under 3 mm" in html
    fig = view.grasp_figure(jg.learn.load(tmp_path / "run"), jg.objects.load("pitcher").mesh)
    success = next(t for t in fig.data if t.name.startswith("success"))
    assert success.name == "success (3 distinct, 2 robust: held in >= 8 of 10)"
    np.testing.assert_allclose(np.asarray(success.line.color)[::12], [1.0, 0.9, 0.2])
    plain = view.grasp_figure(run, jg.objects.load("pitcher").mesh)
    assert all(getattr(t, "line", None) is None or t.line.colorbar.title.text is None
               for t in plain.data[1:])


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


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_own_mesh_is_drawn_in_the_frame_it_was_learned_in(cylinder, scale, tmp_path,
                                                            monkeypatch):
    stl, runs = cylinder
    drawn = {}

    def spy(result, mesh, path, **kw):
        drawn["bounds"] = np.asarray(mesh.bounds)
        return real(result, mesh, path, **kw)

    real = view.view_html
    monkeypatch.setattr(view, "view_html", spy)
    out = tmp_path / "v.html"
    assert view.main([str(runs[scale]), "--mesh", str(stl), "--scale", f"{scale:g}",
                      "--out", str(out)]) == 0
    # stood on z = 0 and scaled, as from_mesh (the learn command) had it, not as the file reads
    assert drawn["bounds"][:, 2] == pytest.approx([0.0, 0.1 * scale])
    assert drawn["bounds"][:, 0] == pytest.approx([-0.03 * scale, 0.03 * scale])
    assert out.exists()


@pytest.mark.parametrize("case", ["no --scale", "other file"])
def test_a_mesh_or_scale_other_than_the_runs_is_refused(cylinder, case, tmp_path, capsys):
    stl, runs = cylinder
    run = runs[0.5 if case == "no --scale" else 1.0]
    if case == "other file":
        stl = tmp_path / "box.stl"
        trimesh.creation.box([0.06, 0.06, 0.1]).export(stl)
    out = tmp_path / "v.html"
    assert view.main([str(run), "--mesh", str(stl), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1
    assert "the mesh file or the scale differs" in err and "'cylinder'" in err
    assert not out.exists()


def test_own_mesh_run_without_mesh_says_to_pass_it(cylinder, tmp_path, capsys):
    run = cylinder[1][1.0]
    assert view.main([str(run), "--out", str(tmp_path / "v.html")]) == 2
    err = capsys.readouterr().err
    assert err == (f"error: {run} was learned on your own mesh 'cylinder': pass --mesh PATH "
                   "(and --scale S if the run used one)\n")
    # a user mesh file called pitcher.stl is not the shipped pitcher
    named = save_run(None, tmp_path / "named", name="pitcher", content_hash="0" * 64)
    assert view.main([str(named), "--out", str(tmp_path / "v.html")]) == 2
    err = capsys.readouterr().err
    assert "not the shipped 'pitcher'" in err and "pass --mesh PATH" in err
    assert view.main([str(run), "--scale", "0.5"]) == 2
    assert "--scale goes with --mesh" in capsys.readouterr().err
    assert not (tmp_path / "v.html").exists()

"""``python -m jaxgrasp.learn``: one command from a mesh to grasp files, a view and a summary."""

import json

import numpy as np
import pytest
import trimesh

from jaxgrasp.learn import __main__ as cli
from jaxgrasp.learn.files.export import load_grasps


@pytest.fixture(scope="module")
def can_stl(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "can.stl"
    mesh = trimesh.creation.cylinder(radius=0.035, height=0.12)
    mesh.apply_translation([0.0, 0.0, 0.06])
    mesh.export(path)
    return path


def test_help_shows_a_worked_example(capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0 and "python -m jaxgrasp.learn" in out
    assert "example" in out and "--gripper" in out and "robotiq_2f85" in out


@pytest.mark.parametrize("argv, match", [
    (["no_such_object"], "no_such_object"),
    (["pitcher", "--scale", "0"], "--scale"),
    (["pitcher", "--demos", "missing.h5"], "no such grasp file"),
    (["pitcher", "--demos", "demos.csv"], "unknown grasp file type"),
])
def test_bad_input_is_one_clear_line_and_writes_nothing(tmp_path, capsys, argv, match):
    out = tmp_path / "out"
    assert cli.main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and match in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("flag", [["--chains", "0"], ["--gripper", "ur5"]])
def test_bad_flags_are_refused_by_the_parser(flag, tmp_path):
    with pytest.raises(SystemExit):
        cli.main(["pitcher", *flag, "--out", str(tmp_path)])


@pytest.mark.slow
def test_mesh_to_grasp_files_then_resume(can_stl, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [str(can_stl), "--chains", "2", "--iterations", "20", "--burn-in", "4",
            "--gripper", "franka", "--quiet", "--robust-tries", "4", "--out", str(out)]
    assert cli.main(argv) == 0
    g = load_grasps(out / "grasps.h5")
    assert len(g.grasps) > 0 and (g.outcome == 0).all() and g.object_name == "can"
    assert g.width[0] == pytest.approx(0.08)  # the Franka hand's opening
    # Each grasp tried 4 more times under the pose error: most robust first.
    assert np.all(np.diff(g.robustness) <= 0) and set(g.robustness * 4) <= {0, 1, 2, 3, 4}
    as_json = load_grasps(out / "grasps.json")
    assert len(as_json.grasps) == len(g.grasps)
    np.testing.assert_allclose(as_json.robustness, g.robustness)
    text = (out / "summary.md").read_text()
    assert "distinct new grasps" in text and "distinct robust new grasps" in text
    assert "<html" in (out / "grasps.html").read_text()[:2000]
    measured, spent = (out / "robustness.npz").stat().st_mtime_ns, cli._seconds(out)
    assert cli.main(argv) == 0  # finished run: loaded, not re-run
    assert (out / "robustness.npz").stat().st_mtime_ns == measured  # nor measured again
    assert cli._seconds(out) == spent  # a rerun that did nothing adds no time
    other = [a if a != "franka" else "robotiq_2f85" for a in argv]
    assert cli.main(other) == 2
    assert "other settings" in capsys.readouterr().err
    assert json.loads((out / "command.json").read_text())["gripper"] == "franka"


def test_ctrl_c_ends_with_one_line_saying_how_to_resume(tmp_path, capsys, monkeypatch):
    def interrupted_run(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "active", interrupted_run)
    out = tmp_path / "out"
    assert cli.main(["pitcher", "--out", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("interrupted:"), err
    assert str(out / "run") in err[0] and "same command again" in err[0]

"""``python -m jaxgrasp.learn``: one command from a mesh to grasp files, a view and a summary."""

import json

import numpy as np
import pytest
import trimesh

import jaxgrasp as jg
from jaxgrasp.learn import __main__ as cli
from jaxgrasp.learn import _flags
from jaxgrasp.learn.files.export import load_grasps, select_grasps
from jaxgrasp.objects.symmetry import find_symmetry


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
    (["pitcher", "--param", "gamma=-1"], "--param gamma=-1.0: LearnParams.gamma must be"),
    (["pitcher", "--param", "uniform_jumps=yes"], "uniform_jumps must be a bool"),
    (["pitcher", "--slip-scale", "0.001", "--param", "slip_scale=0"], "both set"),
    (["pitcher", "--method", "antipodal", "--learn-tries", "2"], "--method antipodal reads"),
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


@pytest.mark.parametrize("flag, match", [
    (["--method", "mcmc"], "invalid choice: 'mcmc'"),
    (["--learn-tries", "-1"], "--learn-tries: expected an integer >= 0"),
    (["--slip-scale", "2mm"], "--slip-scale: expected metres"),
    (["--slip-scale", "nan"], "--slip-scale: expected finite metres"),
    (["--robust-estimate", "median"], "invalid choice: 'median'"),
    (["--param", "gamma"], "expected NAME=VALUE"),
    (["--param", "no_such=1"], "'no_such' is no LearnParams field; fields: gamma"),
    (["--param", "iterations=5"], "use --iterations"),
])
def test_bad_learning_flags_exit_2_with_the_parser_message(flag, match, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["pitcher", *flag, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and match in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_help_tells_learning_tries_from_scoring_tries(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    for flag in ("--method", "antipodal", "--learn-tries", "--slip-scale", "--robust-estimate",
                 "--param NAME=VALUE", "Not --robust-tries", "Scoring only: --learn-tries"):
        assert flag in out, flag


def test_learning_flags_make_the_params_and_the_record(tmp_path):
    args = cli.parser().parse_args([
        "pitcher", "--out", str(tmp_path), "--iterations", "7", "--learn-tries", "2",
        "--robust-estimate", "all_held", "--slip-scale", "0.002", "--param", "gamma=1",
        "--param", "region_scale=none", "--param", "uniform_jumps=true"])
    params, record = _flags.learn_params(args)
    assert (params.iterations, params.robust_tries, params.robust_estimate) == (7, 2, "all_held")
    assert params.gamma == 1.0 and isinstance(params.gamma, float)
    assert params.region_scale is None and params.uniform_jumps is True
    # the record: the fields off their defaults (slip_scale 0.002 is the default)
    assert record == {"robust_tries": 2, "robust_estimate": "all_held", "gamma": 1.0,
                      "uniform_jumps": True}
    again = cli.parser().parse_args(["x", "--out", "o", *_flags.passed_on(args)])
    assert _flags.learn_params(again) == (params.replace(iterations=1000), record)


def test_a_run_from_before_the_method_or_sketch_was_recorded_resumes(tmp_path):
    args = cli.parser().parse_args(["pitcher", "--out", str(tmp_path)])
    old = {"object": "pitcher", "gripper": "default", "seed": 0, "chains": 8,
           "iterations": 1000, "burn_in": 100, "scale": 1.0, "demos": None}
    (tmp_path / "command.json").write_text(json.dumps(old))
    cli._check_out(tmp_path, args, {})  # the defaults it ran with: accepted
    args.sketch = "random"
    with pytest.raises(ValueError, match="'sketch': \\('biased', 'random'\\)"):
        cli._check_out(tmp_path, args, {})
    args.sketch, args.method = "biased", "random_walk"
    with pytest.raises(ValueError, match="'method': \\('kameleon_darting', 'random_walk'\\)"):
        cli._check_out(tmp_path, args, {})


@pytest.mark.parametrize("method", [
    "antipodal",
    pytest.param("random_walk", marks=pytest.mark.slow),
    pytest.param("kameleon_darting", marks=pytest.mark.slow),
])
def test_each_method_writes_its_files_and_refuses_another_on_resume(method, can_stl, tmp_path,
                                                                   capsys):
    out = tmp_path / "run"
    argv = [str(can_stl), "--chains", "2", "--iterations", "6", "--burn-in", "2", "--quiet",
            "--robust-tries", "2", "--method", method, "--out", str(out)]
    if method != "antipodal":  # fewer, cheaper demos and a small sketch
        argv += ["--param", "num_demos=2", "--param", "demo_candidates=4",
                 "--param", "sketch_size=20", "--param", "subsample_size=10"]
    assert cli.main(argv) == 0
    exported = len(load_grasps(out / "grasps.h5").grasps)
    assert exported == len(load_grasps(out / "grasps.json").grasps)
    assert exported > 0 or method == "random_walk"  # 2 x 8 steps of a walk may find none
    assert "<html" in (out / "grasps.html").read_text()[:2000]
    text = (out / "summary.md").read_text()
    assert f"| method | {method} |" in text and f"| exported grasps | {exported} |" in text
    demos = json.loads((out / "run" / "result.json").read_text())["num_demos"]
    assert demos == 0 if method == "antipodal" else 1 <= demos <= 2
    assert json.loads((out / "command.json").read_text())["method"] == method
    learned = (out / "run" / "result.npz").stat().st_mtime_ns
    assert cli.main(argv) == 0  # finished: loaded, not learned again
    assert (out / "run" / "result.npz").stat().st_mtime_ns == learned
    capsys.readouterr()
    other = "kameleon_darting" if method == "random_walk" else "random_walk"
    assert cli.main([*argv[:argv.index("--method") + 1], other,
                     *argv[argv.index("--method") + 2:]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and f"'method': ('{method}', '{other}')" in err


@pytest.mark.slow
def test_mesh_to_grasp_files_then_resume(can_stl, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [str(can_stl), "--chains", "2", "--iterations", "20", "--burn-in", "4",
            "--gripper", "franka", "--quiet", "--robust-tries", "4", "--out", str(out)]
    assert cli.main(argv) == 0
    g = load_grasps(out / "grasps.h5")
    assert len(g.grasps) > 0 and (g.outcome == 0).all() and g.object_name == "can"
    assert g.width[0] == pytest.approx(0.08)  # the Franka hand's opening
    # Each grasp tried up to 4 more times under the pose error (until it can no longer be
    # robust): held / tried, most robust first.
    assert np.all(np.diff(g.robustness) <= 0)
    assert all(min(abs(p * k - round(p * k)) for k in (1, 2, 3, 4)) < 1e-9 for p in g.robustness)
    as_json = load_grasps(out / "grasps.json")
    assert len(as_json.grasps) == len(g.grasps)
    np.testing.assert_allclose(as_json.robustness, g.robustness)
    text = (out / "summary.md").read_text()
    assert "distinct new grasps" in text and "distinct robust new grasps" in text
    assert "<html" in (out / "grasps.html").read_text()[:2000]
    measured, spent = (out / "robustness.npz").stat().st_mtime_ns, cli._seconds(out)
    grown = (out / "grown.npz").stat().st_mtime_ns
    assert cli.main(argv) == 0  # finished run: loaded, not re-run
    assert (out / "robustness.npz").stat().st_mtime_ns == measured  # nor measured again
    assert (out / "grown.npz").stat().st_mtime_ns == grown  # nor grown (copies replace rows)
    assert cli._seconds(out) == spent  # a rerun that did nothing adds no time
    other = [a if a != "franka" else "robotiq_2f85" for a in argv]
    assert cli.main(other) == 2
    assert "other settings" in capsys.readouterr().err
    assert json.loads((out / "command.json").read_text())["gripper"] == "franka"


def test_the_recipe_follows_the_object_s_symmetry():
    """No flag of a recipe given: a mesh with no axis of revolution (a box: half turns) gets
    the flood recipe, and --grow from its shorter run; a solid of revolution (a cylinder) the
    parser's defaults; a recipe flag given (even at its default) or another method keeps
    those too."""
    box = find_symmetry(trimesh.creation.box((0.05, 0.04, 0.1)))
    can = find_symmetry(trimesh.creation.cylinder(0.03, 0.1))

    def chosen(*flags, symmetry=box):
        args = cli.parser().parse_args(["x", "--out", "o", *flags])
        args.recipe = _flags.choose_recipe(args, symmetry)
        return (args.recipe, args.iterations, args.burn_in, args.sketch, args.grow_every,
                _flags.grow_budget(args))

    assert box.kind != "revolution" and can.kind == "revolution"
    assert chosen() == ("flood", 100, 10, "random", 8750, 880)
    assert chosen("--chains", "16")[4:] == (17500, 1760)
    assert chosen(symmetry=can) == ("chains", 1000, 100, "biased", 0, 8800)
    assert chosen("--iterations", "1000") == ("chains", 1000, 100, "biased", 0, 8800)
    assert chosen("--sketch", "random") == ("chains", 1000, 100, "random", 0, 8800)
    assert chosen("--grow", "5")[0] == "flood" and chosen("--grow", "5")[5] == 5
    assert chosen("--method", "random_walk")[0] == "chains"


def test_a_mesh_with_no_axis_of_revolution_learns_with_the_flood_recipe(tmp_path, monkeypatch,
                                                                        can_stl, capsys):
    """The command line chooses the recipe from the mesh it loads (the run itself stubbed)."""
    seen = []

    def learn(*args, **kwargs):
        seen.append((kwargs["params"].iterations, kwargs["params"].burn_in, kwargs["sketch"]))
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "active", learn)
    box = tmp_path / "box.stl"
    trimesh.creation.box((0.05, 0.04, 0.1)).apply_translation([0, 0, 0.05]).export(box)
    assert cli.main([str(box), "--out", str(tmp_path / "b"), "--quiet"]) == 130
    assert cli.main([str(can_stl), "--out", str(tmp_path / "c"), "--quiet"]) == 130
    assert seen == [(100, 10, "random"), (1000, 100, "biased")]
    assert json.loads((tmp_path / "b" / "command.json").read_text())["iterations"] == 100
    capsys.readouterr()
    assert cli.main([str(box), "--out", str(tmp_path / "b"), "--quiet", "--iterations",
                     "1000"]) == 2  # the chains on the flood's run: refused, with the way back
    err = capsys.readouterr().err
    assert "resume it with --iterations 100 --burn-in 10 --sketch random" in err, err


def test_ctrl_c_ends_with_one_line_saying_how_to_resume(tmp_path, capsys, monkeypatch):
    def interrupted_run(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "active", interrupted_run)
    out = tmp_path / "out"
    assert cli.main(["pitcher", "--out", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("interrupted:"), err
    assert str(out / "run") in err[0] and "same command again" in err[0]
    assert cli.main(["pitcher", "--out", str(out), "--quiet", "--method", "antipodal"]) == 2
    assert "other settings" in capsys.readouterr().err  # that run was kameleon_darting's
    assert cli.main(["pitcher", "--out", str(tmp_path / "a"), "--quiet",
                     "--method", "antipodal"]) == 130
    err = capsys.readouterr().err.strip()
    assert "--method antipodal keeps no partial run" in err and "starts it over" in err


def test_grow_adds_the_robust_grasps_neighbours_to_the_files(can_stl, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [str(can_stl), "--chains", "2", "--iterations", "10", "--burn-in", "2", "--quiet",
            "--robust-tries", "2", "--method", "antipodal", "--grow", "200", "--out", str(out)]
    assert cli.main(argv) == 0
    result = jg.learn.load(out / "run")
    with np.load(out / "grown.npz") as z:
        added, trials = int(z["added"]), int(z["trials"])
        np.testing.assert_allclose(z["selected"], select_grasps(result).grasps, atol=1e-9)
    g = load_grasps(out / "grasps.h5")
    assert added > 0 and len(g.grasps) == len(result.grasps) + added and 0 < trials <= 200
    assert np.all(np.diff(g.robustness) <= 0) and (g.outcome == 0).all()
    text = (out / "summary.md").read_text()
    assert f"| exported grasps | {len(g.grasps)} |" in text
    assert ("| grasps added by --grow (robust ones' neighbours and symmetric copies, antipodal "
            "draws) |") in text
    grown = (out / "grown.npz").stat().st_mtime_ns
    assert cli.main(argv) == 0  # finished: not grown again
    assert (out / "grown.npz").stat().st_mtime_ns == grown
    assert cli.main([*argv, "--grow-antipodal", "0"]) == 0  # another flood: grown again
    with np.load(out / "grown.npz") as z:
        assert int(z["antipodal"]) == 0 and (out / "grown.npz").stat().st_mtime_ns != grown
    capsys.readouterr()
    assert cli.main([*argv[:-2], "--robust-tries", "0", "--out", str(tmp_path / "b")]) == 2
    assert "--grow" in capsys.readouterr().err
    default = [*argv[:-4], "--out", str(tmp_path / "c")]  # no --grow
    assert cli.main(default) == 0  # the default budget: the chains' proposals, 2 x (2 + 10)
    with np.load(tmp_path / "c" / "grown.npz") as z:
        assert int(z["budget"]) == 24 and 0 < int(z["trials"]) <= 24


def test_a_grown_file_with_replaced_grasps_is_read_back(tmp_path, monkeypatch):
    """``grown.npz`` keeps the measurement it grew from: a rerun reads a flood whose copies
    replaced measured rows instead of flooding again, and floods again when the run's symmetry
    differs (the copies were made, or not, under another)."""
    from types import SimpleNamespace

    from jaxgrasp.learn.evaluate.robustness import Grown, PoseNoise, Robustness
    from jaxgrasp.learn.files.export import GraspSet, to_transforms
    from jaxgrasp.objects import Symmetry

    calls = []

    def flood(grasps, rob, obj, **kw):  # one measured row replaced by a robust copy
        calls.append(kw["symmetry"])
        held = rob.held.copy()
        held[0] = 10
        return Grown(grasps, Robustness(rob.grasps, held, rob.noise), 0, 5, 1,
                     np.zeros((0, 7), np.float32), 1)

    monkeypatch.setattr(cli, "grow_robust", flood)
    g = np.array([[0.0, 0, 0.05, 1, 0, 0, 0], [0.02, 0, 0.05, 1, 0, 0, 0]])
    grasps = GraspSet(g, to_transforms(g), np.full(2, 0.08), np.full(2, 0.1),
                      np.zeros(2, np.int8), "box", "hash")
    rob = Robustness(g, np.array([2, 3]), PoseNoise())
    run = SimpleNamespace(info={"symmetry": Symmetry("revolution").to_dict()},
                          proposals=np.zeros((1, 7)))
    sim = SimpleNamespace(obj=None)
    first, grew = cli._grown(tmp_path, grasps, rob, run, sim, 100, 0, 0)
    assert grew and calls == [Symmetry("revolution")] and first.swapped == 1
    again, grew = cli._grown(tmp_path, grasps, rob, run, sim, 100, 0, 0)
    assert not grew and len(calls) == 1 and again.swapped == 1
    np.testing.assert_array_equal(again.robustness.held, [10, 3])
    _, grew = cli._grown(tmp_path, grasps, rob, SimpleNamespace(info={}, proposals=run.proposals),
                         sim, 100, 0, 0)
    assert grew and calls[-1] is None


def test_grow_every_floods_from_every_success_into_the_files(can_stl, tmp_path):
    out = tmp_path / "run"
    argv = [str(can_stl), "--chains", "2", "--iterations", "10", "--burn-in", "2", "--quiet",
            "--robust-tries", "0", "--method", "antipodal", "--grow-every", "300",
            "--out", str(out)]
    assert cli.main(argv) == 0
    result = jg.learn.load(out / "run")
    with np.load(out / "flooded.npz") as z:
        added, trials = int(z["added"]), int(z["trials"])
    g = load_grasps(out / "grasps.json")
    assert added > 0 and 0 < trials <= 300
    assert len(g.grasps) == len(select_grasps(result).grasps) + added and (g.outcome == 0).all()
    text = (out / "summary.md").read_text()
    assert (f"| grasps added by --grow-every (a flood from every success) | {added} in "
            f"{trials} trials |") in text
    assert f"success ({len(g.grasps)} distinct" in (out / "grasps.html").read_text()
    flooded = (out / "flooded.npz").stat().st_mtime_ns
    assert cli.main(argv) == 0  # finished: not flooded again
    assert (out / "flooded.npz").stat().st_mtime_ns == flooded
    assert cli.main([*argv[:-4], "--grow-every", "100", "--out", str(out)]) == 0
    with np.load(out / "flooded.npz") as z:  # another budget: flooded again
        assert int(z["budget"]) == 100 and 0 < int(z["trials"]) <= 100


def test_grow_every_grasps_are_scored_with_the_run_s(can_stl, tmp_path):
    """With scoring, the flood's grasps are measured with the run's and the summary counts
    every exported grasp."""
    out = tmp_path / "run"
    argv = [str(can_stl), "--chains", "2", "--iterations", "10", "--burn-in", "2", "--quiet",
            "--robust-tries", "2", "--method", "antipodal", "--grow-every", "200", "--grow",
            "0", "--out", str(out)]
    assert cli.main(argv) == 0
    result = jg.learn.load(out / "run")
    g = load_grasps(out / "grasps.json")
    with np.load(out / "robustness.npz") as z:
        held, tried = z["held"], z["tried"]
    assert len(held) == len(g.grasps) > len(result.grasps)
    assert "<html" in (out / "grasps.html").read_text()[:2000]
    text = (out / "summary.md").read_text()
    assert f"| exported grasps | {len(g.grasps)} |" in text
    assert f"| trials to measure robustness | {int(tried.sum())} |" in text
    assert f"({int((held >= 2).sum())} robust" not in text  # no --grow row
    assert f"| {int((held >= 2).sum())} (" in text  # the robust count over everything

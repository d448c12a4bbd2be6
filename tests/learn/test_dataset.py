"""``python -m jaxgrasp.learn FOLDER --out DATASET``: the index, the skips and the seeds of a
dataset, with the single-object command replaced by a fake that writes its files at once (the
real one on the invalid mesh: it fails before any learning)."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from jaxgrasp.learn import __main__ as cli
from jaxgrasp.learn import _flags, dataset

SUMMARY = """| | |
|---|---:|
| object | {name} |
| success | {success} |
| slipped | 3 |
| collision | 2 |
| miss | 1 |
| distinct new grasps (not a demo) | {new} |
| exported grasps | 4 |
| robust grasps (held in >= 2 of 2 tries under 3 mm, 3 deg) | 1 (25.0 %) |
| distinct robust new grasps | 1 |
"""


@pytest.fixture
def meshes(tmp_path):
    folder = tmp_path / "meshes"
    (folder / "kitchen").mkdir(parents=True)
    trimesh.creation.cylinder(radius=0.03, height=0.1).export(folder / "can.stl")
    trimesh.creation.box(extents=[0.05, 0.06, 0.08]).export(folder / "kitchen" / "box.obj")
    (folder / "bad.stl").write_text("solid nothing\nendsolid nothing\n")  # no triangles
    (folder / "notes.txt").write_text("not a mesh")
    return folder


class FakeLearn:
    """The single-object command's files for a good mesh, the real command for a bad one."""

    def __init__(self, crash=()):
        self.calls, self.crash, self.argvs = [], set(crash), []

    def __call__(self, argv):
        mesh, out, seed = Path(argv[0]), Path(argv[argv.index("--out") + 1]), argv[
            argv.index("--seed") + 1]
        self.calls.append(mesh.stem)
        self.argvs.append(argv)
        if mesh.stem == "bad":
            return cli.main(argv)
        if mesh.stem in self.crash:
            raise RuntimeError("a bug")
        (out / "run").mkdir(parents=True, exist_ok=True)
        success = int(seed) % 50
        (out / "summary.md").write_text(SUMMARY.format(name=mesh.stem, success=success, new=3))
        (out / "run" / "result.json").write_text(json.dumps(
            {"num_demos": 5, "totals": {"success": success, "slipped": 3, "collision": 2,
                                        "miss": 1}}))
        (out / "timings.json").write_text(json.dumps({"seconds": [1.5, 0.25]}))
        (out / "grasps.html").write_text("<html></html>")
        return 0


def run(folder, out, fake, *extra):
    args = cli.parser().parse_args([str(folder), "--out", str(out), "--quiet", "--seed", "7",
                                    "--workers", "1", *extra])
    return dataset.main(args, single=fake)


def test_folder_is_a_dataset_one_mesh_is_not(meshes):
    assert dataset.is_dataset(str(meshes)) and dataset.is_dataset(str(meshes / "*.stl"))
    assert not dataset.is_dataset(str(meshes / "can.stl")) and not dataset.is_dataset("pitcher")
    assert [n for n, _ in dataset.find_meshes(str(meshes))] == ["bad", "can", "kitchen__box"]
    assert [n for n, _ in dataset.find_meshes(str(meshes / "*.stl"))] == ["bad", "can"]
    assert [n for n, _ in dataset.find_meshes(str(meshes / "**" / "*.obj"))] == ["kitchen__box"]
    with pytest.raises(ValueError, match="no mesh files"):
        dataset.find_meshes(str(meshes / "*.ply"))


def test_seed_depends_on_base_seed_and_mesh_bytes_only():
    a = dataset.object_seed(0, "ab" * 32)
    assert a == dataset.object_seed(0, "ab" * 32) and 0 <= a < 2**31
    assert a != dataset.object_seed(1, "ab" * 32) and a != dataset.object_seed(0, "cd" * 32)


def test_index_failed_mesh_and_rerun_skips_finished_objects(meshes, tmp_path, capsys):
    out, fake = tmp_path / "dataset", FakeLearn(crash={"box"})
    assert run(meshes, out, fake) == 1  # some objects failed
    assert sorted(fake.calls) == ["bad", "box", "can"]
    with open(out / "index.csv") as f:
        rows = {r["object"]: r for r in csv.DictReader(f)}
    assert list(rows) == ["bad", "can", "kitchen__box"]
    assert tuple(rows["can"]) == dataset.COLUMNS
    can = rows["can"]
    assert can["status"] == "ok" and can["demos"] == "5" and can["distinct_new"] == "3"
    assert can["robust_share"] == "0.25" and can["distinct_robust_new"] == "1"
    assert int(can["trials"]) == int(can["successes"]) + 6 and can["seconds"] == "1.8"
    assert can["seed"] == str(dataset.object_seed(7, can["mesh_sha256"]))
    assert rows["bad"]["status"] == "failed" and "bad.stl" in rows["bad"]["error"]
    assert rows["kitchen__box"]["error"] == "RuntimeError: a bug"
    assert "Traceback" in (out / "kitchen__box" / "learn.log").read_text()
    index = json.loads((out / "index.json").read_text())
    assert index["totals"] | {"objects": 3, "ok": 1, "failed": 2, "pending": 0} == index["totals"]
    page = (out / "index.html").read_text()
    assert 'href="can/grasps.html"' in page and "RuntimeError: a bug" in page
    printed = capsys.readouterr().out
    assert "1 of 3 objects learned" in printed and "failed: bad:" in printed

    fake = FakeLearn()  # the rerun: the finished object is skipped, the failed ones tried again
    assert run(meshes, out, fake) == 1
    assert sorted(fake.calls) == ["bad", "box"]
    with open(out / "index.csv") as f:
        again = {r["object"]: r for r in csv.DictReader(f)}
    assert again["can"] == can and again["kitchen__box"]["status"] == "ok"
    assert run(meshes, out, fake, "--iterations", "5") == 2  # other settings: refused
    assert "other settings" in capsys.readouterr().err


def test_dataset_flags_are_checked_before_anything_is_written(meshes, tmp_path, capsys):
    out = tmp_path / "dataset"
    assert run(meshes, out, FakeLearn(), "--demos", "demos.h5") == 2
    assert run(meshes, out, FakeLearn(), "--threads-per-worker", "0") == 2
    assert run(tmp_path / "nothing_*.stl", out, FakeLearn()) == 2
    assert capsys.readouterr().err.count("error:") == 3 and not out.exists()


def test_learning_flags_reach_every_object_and_are_recorded(meshes, tmp_path, capsys):
    out, fake = tmp_path / "dataset", FakeLearn()
    flags = ["--method", "random_walk", "--learn-tries", "2", "--slip-scale", "0",
             "--param", "gamma=0.02"]
    assert run(meshes, out, fake, *flags) == 1  # bad.stl fails
    for argv in fake.argvs:  # each object's command line, parsed as the object's run does
        args = cli.parser().parse_args(argv)
        assert args.method == "random_walk" and args.learn_tries == 2
        assert args.slip_scale == 0.0 and args.param == [("gamma", 0.02)]
    settings = json.loads((out / dataset.SETTINGS_FILE).read_text())
    assert settings["method"] == "random_walk"
    assert settings["learn_params"] == {"robust_tries": 2, "slip_scale": 0.0, "gamma": 0.02}
    capsys.readouterr()
    assert run(meshes, out, FakeLearn(), *flags[2:]) == 2  # the default method: refused
    assert "'method': ('random_walk', 'kameleon_darting')" in capsys.readouterr().err
    assert run(meshes, out, FakeLearn(), *flags[:-1], "gamma=0.03") == 2
    assert "other settings" in capsys.readouterr().err
    assert run(meshes, tmp_path / "d2", FakeLearn(), "--param", "gamma=0") == 2
    assert "--param gamma=0.0: LearnParams.gamma" in capsys.readouterr().err
    assert not (tmp_path / "d2").exists()  # refused before any object


def test_each_object_chooses_its_recipe_unless_a_flag_of_one_is_given(meshes, tmp_path):
    fake = FakeLearn()
    run(meshes, tmp_path / "a", fake)
    recipe = {"--iterations", "--burn-in", "--sketch", "--grow-every", "--grow"}
    assert fake.argvs and all(not recipe & set(argv) for argv in fake.argvs)
    fake = FakeLearn()
    run(meshes, tmp_path / "b", fake, "--iterations", "50")
    for argv in fake.argvs:  # one given: the others at the parser's defaults, all passed on
        args = cli.parser().parse_args(argv)
        assert _flags.recipe_given(args) and set(argv) >= recipe
        assert (args.iterations, args.burn_in, args.sketch, args.grow_every) == (50, 100,
                                                                                  "biased", 0)


def test_a_dataset_from_before_the_method_was_recorded_resumes(meshes, tmp_path):
    out = tmp_path / "dataset"
    assert run(meshes, out, FakeLearn()) == 1
    settings = json.loads((out / dataset.SETTINGS_FILE).read_text())
    old = {k: v for k, v in settings.items() if k not in ("method", "learn_params")}
    (out / dataset.SETTINGS_FILE).write_text(json.dumps(old))
    fake = FakeLearn()
    assert run(meshes, out, fake) == 1 and sorted(fake.calls) == ["bad"]


def test_ctrl_c_keeps_the_finished_objects(meshes, tmp_path, capsys):
    class Interrupted(FakeLearn):
        def __call__(self, argv):
            if Path(argv[0]).stem == "box":
                return 130  # what the single command returns after Ctrl-C
            return super().__call__(argv)

    out = tmp_path / "dataset"
    assert run(meshes, out, Interrupted()) == 130
    assert "same command again" in capsys.readouterr().err
    index = json.loads((out / "index.json").read_text())
    assert [r["status"] for r in index["objects"]] == ["failed", "ok", "pending"]


def test_the_command_sends_a_folder_to_the_dataset(meshes, tmp_path, monkeypatch):
    seen = []
    monkeypatch.setattr(dataset, "main", lambda args, single: seen.append((args, single)) or 0)
    assert cli.main([str(meshes), "--out", str(tmp_path / "d"), "--workers", "2"]) == 0
    (args, single), = seen
    assert args.workers == 2 and single is cli.main  # this module by name: workers import it


def test_meshes_are_decomposed_ahead_into_the_cache(tmp_path, monkeypatch):
    """The background process stores what ``from_mesh`` computes for each mesh (the same
    pieces a worker would make) and skips an object a worker has started (its lock exists)."""
    from jaxgrasp.objects import user

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    jobs = []
    for name, r in (("ring", 0.03), ("started", 0.025)):  # non-convex: CoACD decomposes them
        mesh = tmp_path / f"{name}.stl"
        trimesh.creation.annulus(r_min=r - 0.01, r_max=r, height=0.02).export(mesh)
        jobs.append({"mesh": str(mesh), "out": str(tmp_path / "out" / name)})
    Path(jobs[1]["out"]).mkdir(parents=True)
    (Path(jobs[1]["out"]) / ".lock").touch()
    proc = dataset.decompose_ahead(jobs, scale=1.0)
    assert proc.wait(timeout=300) == 0
    stored = sorted(user.cache_dir().glob("*.npz"))
    assert len(stored) == 1 and ".tmp." not in stored[0].name  # the started one was skipped
    cached = user.from_mesh(jobs[0]["mesh"])
    assert cached.content_hash == stored[0].stem
    fresh = user.from_mesh(jobs[0]["mesh"], cache=False)
    assert len(fresh.pieces) == len(cached.pieces) > 1
    for a, b in zip(fresh.pieces, cached.pieces, strict=True):
        np.testing.assert_array_equal(a, b)
    assert dataset.decompose_ahead([], scale=1.0) is None

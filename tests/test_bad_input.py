"""Bad input gets ONE clear error and writes nothing half.

A corpus generated here: meshes, grasp arrays, LearnParams and learn arguments, bench CLI flags,
result and checkpoint files. Each case must raise a ValueError (or a project subclass) whose
message names the input, never an error from inside jax/mujoco/numpy/zipfile, and must leave
no new or half-written file. Fast: no physics rollout and no MJX compilation.
"""

import hashlib
import io
import json
import pickle
import struct

import numpy as np
import pytest
import trimesh

import jaxgrasp as jg
from jaxgrasp.bench import cli
from jaxgrasp.learn.files.checkpoint import CheckpointDir
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos
from jaxgrasp.objects.user import MAX_FACES, MeshError
from jaxgrasp.physics import check_grasps
from jaxgrasp.physics.protocol import TrialResult


def _files(root):
    return sorted(p.relative_to(root) for p in root.rglob("*"))


def _unchanged(root, before):
    """No new, temporary or half-written file under ``root``."""
    assert _files(root) == before


# ---------------------------------------------------------------------------------------------
# Meshes (jg.objects.from_mesh)

CUBE = """v 0 0 0\nv 0.05 0 0\nv 0.05 0.05 0\nv 0 0.05 0\nv 0 0 0.05\nv 0.05 0 0.05
v 0.05 0.05 0.05\nv 0 0.05 0.05
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7
f 4 1 5\nf 4 5 8
"""
PNG = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 8


def _big_stl(n=10**6):
    """A binary STL with ``n`` (zero) triangles: 50 MB written in a blink, no trimesh needed."""
    return b"\0" * 80 + struct.pack("<I", n) + b"\0" * (50 * n)


def _box(size):
    return lambda: trimesh.creation.box(extents=(size,) * 3).export(file_type="stl")


MESHES = {
    "empty.obj": (b"", "empty mesh"),
    "empty.stl": (b"", "empty mesh"),
    "empty.ply": (b"", "could not read"),
    "comment.obj": (b"# no geometry\n", "empty mesh"),
    "open.obj": ("\n".join(CUBE.splitlines()[:-6]) + "\n", "not watertight"),
    "fin.obj": (CUBE + "v 0.1 0.0 0.02\nf 1 2 9\n", "not watertight"),
    "nan.obj": (CUBE.replace("v 0.05 0 0\n", "v nan 0 0\n"), "NaN/inf"),
    "inf.obj": (CUBE.replace("v 0.05 0 0\n", "v 0.05 -inf 0\n"), "NaN/inf"),
    "degenerate.obj": ("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 1 2\nf 2 2 3\n"
                       "f 3 4 4\nf 4 1 1\n", "zero"),
    "flat.obj": ("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0.05 0.05 0\nf 1 2 3\nf 2 4 3\n"
                 "f 1 3 2\nf 2 3 4\n", "zero volume"),
    "one_mm.stl": (_box(1e-3), "absurd size.*can't be grasped"),
    "huge.obj": (CUBE.replace("0.05", "5000"), "absurd size.*millimetres"),
    "million.stl": (_big_stl, f"more than {MAX_FACES}.*simplify"),
    "picture.obj": (PNG, "could not read it as OBJ"),
    "picture.stl": (PNG, "could not read it as STL|empty mesh"),
    "picture.ply": (PNG, "could not read it as PLY"),
    "garbage.stl": (b"solid x\n facet normal oops\n", "could not read|empty mesh"),
    "model.step": (b"ISO-10303-21;\n", "unsupported format"),
    "mesh.npz": (io.BytesIO().getvalue(), "unsupported format"),
    "noextension": (CUBE, "unsupported format"),
}
MESH_ARGS = [
    ({"scale": "abc"}, "scale"),
    ({"scale": float("nan")}, "scale"),
    ({"scale": -1.0}, "scale"),
    ({"density": -5.0}, "density"),
    ({"mass": float("inf")}, "mass"),
    ({"density": 1.0, "mass": 1.0}, "not both"),
    ({"max_pieces": 0}, "max_pieces"),
    ({"threshold": 2.0}, "threshold"),
    ({"name": "../evil"}, "name"),
]


@pytest.fixture
def mesh_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # the cache must stay empty
    return tmp_path


@pytest.mark.parametrize("name", sorted(MESHES))
def test_bad_mesh(mesh_dir, name):
    content, match = MESHES[name]
    content = content() if callable(content) else content
    path = mesh_dir / name
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    before = _files(mesh_dir)
    with pytest.raises(MeshError, match=match) as err:
        jg.objects.from_mesh(path)  # cache on: a failure must not write it
    assert name in str(err.value)
    _unchanged(mesh_dir, before)


@pytest.mark.parametrize("kwargs, match", MESH_ARGS, ids=[str(k) for k, _ in MESH_ARGS])
def test_bad_mesh_arguments(mesh_dir, kwargs, match):
    path = mesh_dir / "cube.obj"
    path.write_text(CUBE)
    before = _files(mesh_dir)
    with pytest.raises(MeshError, match=match):
        jg.objects.from_mesh(path, **kwargs)
    _unchanged(mesh_dir, before)


def test_missing_mesh_and_directory(mesh_dir):
    for path in (mesh_dir / "nope.obj", mesh_dir):
        with pytest.raises(MeshError, match="no such mesh file"):
            jg.objects.from_mesh(path)


def test_ten_metre_mesh_warns_with_the_fix(mesh_dir):
    """10 m is a kitchen object in millimetres: loaded, with a warning that says scale=0.001."""
    path = mesh_dir / "ten.stl"
    path.write_bytes(_box(10.0)())
    with pytest.warns(UserWarning, match=r"ten\.stl.*millimetres.*scale=0\.001"):
        obj = jg.objects.from_mesh(path, cache=False)
    assert obj.dimensions["height"] == pytest.approx(10.0)


# ---------------------------------------------------------------------------------------------
# Grasp arrays: trials (make_trial, Simulator) and demonstrations

GOOD = np.tile(np.array([0.0, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0]), (2, 1))
BAD_SHAPE_OR_DTYPE = {
    "one_grasp_1d": (GOOD[0], "grasps\\[None\\]"),
    "six_columns": (np.zeros((3, 6)), "shape"),
    "three_dims": (np.zeros((2, 7, 1)), "shape"),
    "ragged_list": ([[0.0] * 7, [0.0] * 6], "array of numbers"),
    "strings": (np.array([["a"] * 7]), "dtype"),
    "bool": (np.ones((2, 7), bool), "dtype"),
    "complex": (GOOD.astype(complex), "dtype"),
    "object": (np.array([[None] * 7]), "dtype"),
}
BAD_VALUES = {
    "nan": (np.where(np.arange(7) == 0, np.nan, GOOD), "NaN/inf"),
    "inf": (np.where(np.arange(7) == 2, np.inf, GOOD), "NaN/inf"),
    "beyond_float32": (np.where(np.arange(7) == 1, 1e39, GOOD), "beyond float32"),
    "zero_quaternion": (np.where(np.arange(7) >= 3, 0.0, GOOD), "zero quaternion"),
}


def _zeros_trial(grasps):
    """A trial of the right shapes that simulates nothing (orchestration only)."""
    b = grasps.shape[0]
    z = np.zeros(b, np.float32)
    return TrialResult(outcome=np.full(b, 3, np.int32), epsilon=z, displacement=z,
                       contact_points=np.zeros((b, 4, 3), np.float32),
                       contact_normals=np.zeros((b, 4, 3), np.float32),
                       contact_mask=np.zeros((b, 4), bool), pad_contact=np.zeros((b, 2), bool),
                       unstable=np.zeros(b, bool), invalid=np.zeros(b, bool))


@pytest.fixture(scope="module")
def box():
    return jg.objects.make_box()


@pytest.fixture(scope="module")
def c_trial(box):
    """The MuJoCo C trial of the box (built, never rolled out: every call here is refused)."""
    return jg.physics.make_trial(jg.physics.load_scene(box), backend="mujoco")


@pytest.mark.parametrize("case", sorted(BAD_SHAPE_OR_DTYPE))
def test_bad_grasp_arrays_are_refused_by_every_entry(case, c_trial, box):
    grasps, match = BAD_SHAPE_OR_DTYPE[case]
    sim = jg.learn.Simulator(box, trial=_zeros_trial)
    for entry in (check_grasps, c_trial, sim, lambda g: Demos(g)):
        with pytest.raises(ValueError, match=match):
            entry(grasps)


@pytest.mark.parametrize("case", sorted(BAD_VALUES))
def test_non_finite_demonstrations_are_refused(case, box):
    """Demonstrations become GDMC modes and chain starts: NaN/inf/zero quaternion refused.
    (A trial takes them: the protocol reports such a proposal as a failed trial.)"""
    grasps, match = BAD_VALUES[case]
    with pytest.raises(ValueError, match=f"Demos.poses.*{match}"):
        Demos(grasps)
    with pytest.raises(ValueError, match=match):
        jg.learn.active(box, demos=Demos(grasps), trial=_zeros_trial, progress=False)


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.float16, np.float32, np.float64])
def test_int_and_float_grasps_are_accepted_and_cast(dtype, box):
    grasps = np.tile(np.array([0, 0, 0, 1, 0, 0, 0], dtype), (2, 1))
    assert check_grasps(grasps, finite=True) is grasps
    assert Demos(grasps).poses.dtype == dtype
    res = jg.learn.Simulator(box, trial=_zeros_trial)(grasps)
    assert res.outcome.shape == (2,)
    with pytest.raises(ValueError, match="no grasps"):
        jg.learn.Simulator(box, trial=_zeros_trial)(grasps[:0])


# ---------------------------------------------------------------------------------------------
# LearnParams and the learn entry points' arguments

BAD_PARAMS = [
    ({"iterations": -1}, "iterations"), ({"iterations": 0}, "iterations"),
    ({"iterations": 1.5}, "iterations"), ({"iterations": "10"}, "iterations"),
    ({"iterations": True}, "iterations"), ({"burn_in": -1}, "burn_in"),
    ({"gamma": float("nan")}, "gamma"), ({"gamma": -1e-4}, "gamma"),
    ({"nu": float("inf")}, "nu"), ({"kappa": "50"}, "kappa"),
    ({"position_scale": 0.0}, "position_scale"), ({"density_floor": -1.0}, "density_floor"),
    ({"p_check": float("nan")}, "p_check"), ({"p_check": 1.5}, "p_check"),
    ({"kernel_sigma": -1.0}, "kernel_sigma"), ({"demo_fallback": "maybe"}, "demo_fallback"),
    ({"nu_convention": 3}, "nu_convention"),
    ({"subsample_size": 500, "sketch_size": 100}, "subsample_size"),
]


@pytest.mark.parametrize("kwargs, match", BAD_PARAMS, ids=[str(k) for k, _ in BAD_PARAMS])
def test_bad_learn_params(kwargs, match):
    with pytest.raises(ValueError, match=f"LearnParams.{match}"):
        jg.learn.LearnParams(**kwargs)


BAD_ACTIVE = [
    ({"chains": 0}, "chains"), ({"chains": -2}, "chains"), ({"chains": 2.5}, "chains"),
    ({"seed": -1}, "seed"), ({"seed": float("nan")}, "seed"), ({"method": "hmc"}, "method"),
    ({"sketch": "none"}, "sketch"), ({"backend": "bullet"}, "backend"),
    ({"checkpoint_every": 0}, "checkpoint_every"), ({"params": {"iterations": 5}}, "params"),
    ({"iterations": -5}, "iterations"), ({"demos": np.zeros((2, 7))}, "demos"),
]


@pytest.mark.parametrize("kwargs, match", BAD_ACTIVE, ids=[str(k) for k, _ in BAD_ACTIVE])
def test_bad_learn_arguments_fail_before_any_work(kwargs, match, box, tmp_path):
    ckpt = tmp_path / "ckpt"
    with pytest.raises(ValueError, match=match):
        jg.learn.active(box, trial=_zeros_trial, progress=False, checkpoint_dir=ckpt, **kwargs)
    assert not ckpt.exists()
    with pytest.raises(ValueError, match="unknown object"):
        jg.learn.active("../pitcher", trial=_zeros_trial, progress=False)


# ---------------------------------------------------------------------------------------------
# The bench CLI (python -m jaxgrasp.bench)

BAD_FLAGS = [
    (["--chains", "-1"], "chains"), (["--chains", "0"], "chains"), (["--chains", "nan"], "chains"),
    (["--chains", "2.5"], "chains"), (["--iterations", "-5"], "iterations"),
    (["--iterations", "0"], "iterations"), (["--burn-in", "-1"], "burn_in"),
    (["--seed", "-1"], "seed"), (["--seed", "nan"], "seed"), (["--objects", "teapot"], "teapot"),
    (["--objects", "pitcher,,pan"], "empty name"), (["--objects", "pitcher,"], "empty name"),
    (["--objects", ","], "empty name"), (["--objects", "../x"], "unknown object '../x'"),
    (["--objects", "pitcher/../pan"], "unknown object"), (["--backend", "bullet"], "backend"),
    (["--profile", "huge"], "profile"), (["--devices", "0"], "devices"),
    (["--devices", "-1"], "devices"),
]


@pytest.mark.parametrize("flags, match", BAD_FLAGS, ids=[" ".join(f) for f, _ in BAD_FLAGS])
def test_bad_cli_flags(flags, match, tmp_path, capsys, monkeypatch):
    def started(*a, **k):
        raise AssertionError(f"{flags} passed validation")

    monkeypatch.setattr(cli, "_previous", started)
    out = tmp_path / "out"
    try:
        code = cli.main([*flags, "--out", str(out), "--quiet"])
    except SystemExit as exc:  # argparse: usage + one "error:" line, exit 2
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    assert len([line for line in err.splitlines() if "error:" in line]) == 1
    assert __import__("re").search(match, err), err
    assert "Traceback" not in err and not out.exists()


# ---------------------------------------------------------------------------------------------
# Result files (jg.learn.load) and checkpoints


def _result(info=None):
    steps, chains = 3, 2
    pos = np.tile(np.array([0, 0, 0.05, 1, 0, 0, 0], np.float32), (steps, chains, 1))
    params = jg.learn.LearnParams(iterations=2, burn_in=1, sketch_size=4, subsample_size=2)
    return LearnResult(
        object_name="box", object_hash="0" * 16, workflow="active", method="random_walk",
        sketch="none", modes_kind="none", seed=0, backend="mujoco", params=params,
        positions=pos, proposals=pos, outcomes=np.zeros((steps, chains), np.int8),
        epsilons=np.zeros((steps, chains), np.float32),
        accepted=np.zeros((steps, chains), bool), is_jump=np.zeros((steps, chains), bool),
        initial_positions=pos[0], modes=pos[0], sketch_points=np.zeros((0, 7), np.float32),
        demos=Demos(pos[0], None), info=info or {})


def _reseal(d, data: bytes, **meta_changes):
    """Replace result.npz by ``data`` and record its checksum (an edited but 'sealed' pair)."""
    (d / "result.npz").write_bytes(data)
    meta = json.loads((d / "result.json").read_text())
    meta["arrays"]["sha256"] = hashlib.sha256(data).hexdigest()
    meta.update(meta_changes)
    (d / "result.json").write_text(json.dumps(meta))


def _npz(**arrays):
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _edit_meta(d, change):
    meta = json.loads((d / "result.json").read_text())
    (d / "result.json").write_text(json.dumps(change(meta)))


def _edit_arrays(d, change):
    arrays = dict(np.load(d / "result.npz"))
    change(arrays)
    _reseal(d, _npz(**arrays))


def _half(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


#: kind -> (corrupt the saved result directory d, what the error must say)
RESULT_CASES = {
    "truncated_npz": (lambda d: _half(d / "result.npz"), "checksum"),
    "truncated_npz_resealed": (lambda d: _reseal(d, (d / "result.npz").read_bytes()[:900]),
                               "not an intact .npz"),
    "wrong_checksum": (lambda d: _edit_meta(d, lambda m: {**m, "arrays": {"sha256": "0"}}),
                       "checksum"),
    "other_version": (lambda d: _edit_meta(d, lambda m: {**m, "format_version": 99}),
                      "format version 99"),
    "other_format": (lambda d: _edit_meta(d, lambda m: {**m, "format": "x"}),
                     "not a jaxgrasp learning result"),
    "json_list": (lambda d: _edit_meta(d, lambda m: [1, 2]), "not a jaxgrasp chain file"),
    "json_garbage": (lambda d: (d / "result.json").write_bytes(b"\xff\xfe{not json"),
                     "not valid JSON"),
    "missing_params": (lambda d: _edit_meta(d, lambda m: {k: v for k, v in m.items()
                                                          if k != "params"}),
                       "'params' is missing"),
    "params_of_another_version": (
        lambda d: _edit_meta(d, lambda m: {**m, "params": {**m["params"], "warp": 9}}),
        "unknown LearnParams fields"),
    "params_negative": (
        lambda d: _edit_meta(d, lambda m: {**m, "params": {**m["params"], "iterations": -2}}),
        "iterations"),
    "steps_not_a_number": (lambda d: _edit_meta(d, lambda m: {**m, "steps": "many"}), "many"),
    "object_array": (lambda d: _reseal(d, _npz(positions=np.array([{"a": 1}], dtype=object))),
                     "not an intact .npz"),
    "pickle": (lambda d: _reseal(d, pickle.dumps({"positions": np.zeros(3)})),
               "not an intact .npz"),
    "missing_array": (lambda d: _edit_arrays(d, lambda a: a.pop("outcomes")),
                      "'outcomes' is missing"),
    "nan_demo": (lambda d: _edit_arrays(d, lambda a: a.update(
        demo_poses=np.full_like(a["demo_poses"], np.nan))), "NaN/inf"),
    "missing_json": (lambda d: (d / "result.json").unlink(), "need result.json"),
}


@pytest.mark.parametrize("kind", sorted(RESULT_CASES))
def test_bad_result_files(kind, tmp_path):
    d = tmp_path / "run"
    _result().save(d)
    assert jg.learn.load(d).num_chains == 2
    corrupt, match = RESULT_CASES[kind]
    corrupt(d)
    before = _files(tmp_path)
    with pytest.raises(ValueError, match=match) as err:
        jg.learn.load(d)
    assert str(d) in str(err.value)
    _unchanged(tmp_path, before)


def test_result_of_another_object_and_path_names(tmp_path, box):
    d = tmp_path / "run"
    _result().save(d)
    with pytest.raises(ValueError, match="not for 'box'"):
        jg.learn.load(d, box)
    with pytest.raises(ValueError, match="unknown object '../pitcher'"):
        jg.learn.load(d, "../pitcher")
    with pytest.raises(ValueError, match="no chain file"):
        jg.learn.load(tmp_path / "run" / ".." / "nowhere")


def test_unsaveable_metadata_writes_nothing(tmp_path):
    d = tmp_path / "run"
    with pytest.raises(ValueError, match="result.json.*NaN"):
        _result(info={"score": float("nan")}).save(d)
    assert _files(tmp_path) in ([], [d.relative_to(tmp_path)])
    assert not list(tmp_path.rglob("*.npz")) and not list(tmp_path.rglob("*.tmp"))


CONFIG = {"workflow": "active", "object": "box", "seed": 0}


def _meta_npz(meta_json, **arrays):
    return _npz(meta_json=np.str_(meta_json), **arrays)


#: kind -> (new bytes of the checkpoint file from its old bytes, what the error must say)
CHECKPOINT_CASES = {
    "truncated": (lambda b: b[: len(b) // 2], "not an intact .npz"),
    "empty": (lambda b: b"", "not an intact .npz"),
    "not_zip": (lambda b: b"PK\x03\x04" + b"\0" * 64, "not an intact .npz"),
    "pickle": (lambda b: pickle.dumps({"meta_json": "{}"}), "not an intact .npz"),
    "object_array": (lambda b: _meta_npz("{}", state_000=np.array([None], object)),
                     "not an intact .npz"),
    "no_meta": (lambda b: _npz(state_000=np.zeros(3)), "not a jaxgrasp checkpoint"),
    "meta_garbage": (lambda b: _meta_npz("{oops"), "not a jaxgrasp checkpoint"),
    "meta_list": (lambda b: _meta_npz("[1]"), "not a jaxgrasp checkpoint"),
    "no_step": (lambda b: _meta_npz(json.dumps({"config": CONFIG})), "bad step"),
    "other_config": (lambda b: _meta_npz(json.dumps({"config": {**CONFIG, "version": 2},
                                                     "step": 3})), "belongs to another run"),
}


@pytest.mark.parametrize("kind, stem", [(k, s) for k in sorted(CHECKPOINT_CASES)
                                         for s in ("checkpoint", "setup")
                                         if (k, s) != ("no_step", "setup")])  # setup: no step
def test_bad_checkpoint_files(kind, stem, tmp_path):
    ckpt = CheckpointDir(tmp_path, CONFIG)
    if stem == "setup":
        ckpt.save_setup({"demo_poses": np.zeros((1, 7), np.float32)})
    else:
        ckpt.save_state(5, {"state_000": np.zeros(3)})
    path = tmp_path / f"{stem}.npz"
    corrupt, match = CHECKPOINT_CASES[kind]
    path.write_bytes(corrupt(path.read_bytes()))
    before = _files(tmp_path)
    with pytest.raises(ValueError, match=match) as err:
        if stem == "setup":
            CheckpointDir(tmp_path, CONFIG)
        else:
            CheckpointDir(tmp_path, CONFIG).load_state()
    assert f"{stem}.npz" in str(err.value) or str(tmp_path) in str(err.value)
    _unchanged(tmp_path, before)


def test_learn_refuses_a_damaged_checkpoint_before_any_work(tmp_path, box):
    (tmp_path / "setup.npz").write_bytes(b"PK\x03\x04 torn")
    before = _files(tmp_path)
    with pytest.raises(ValueError, match="setup.npz is not an intact .npz"):
        jg.learn.active(box, trial=_zeros_trial, progress=False, checkpoint_dir=tmp_path)
    _unchanged(tmp_path, before)

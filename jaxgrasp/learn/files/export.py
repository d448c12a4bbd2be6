"""Learned grasps in forms other tools read: ``.npz``, ``.json`` and ACRONYM-style ``.h5``.

>>> jg.learn.export_grasps(result, "pitcher_grasps.h5")          # distinct successes
>>> grasps = jg.learn.load_grasps("pitcher_grasps.h5")           # a GraspSet

Every format holds the gripper poses in the object frame as 4x4 homogeneous transforms, with
the gripper's opening width, the grasp's epsilon and its outcome. The ``.npz`` and ``.json``
files use jaxgrasp's grasp frame (origin at the grasp center between the pads, +z approach,
+-y closing); the ``.h5`` file uses ACRONYM's Franka-hand frame (origin at the hand, fingertips
``ACRONYM_TCP`` ahead along +z, +-x closing), so ACRONYM's loaders and gripper markers draw the
grasps where they are. The formats are described in ``docs/grasp_files.md``.
"""

import io
import json
from pathlib import Path
from typing import NamedTuple

import h5py
import jsonschema
import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.distinct import distinct_grasps
from jaxgrasp.learn.files.atomic import atomic_write_bytes, read_npz
from jaxgrasp.learn.files.results import OUTCOME_NAMES
from jaxgrasp.physics.gripper import GripperParams

__all__ = ["GraspSet", "export_grasps", "load_grasps", "ACRONYM_TCP", "SCHEMA", "FORMAT_VERSION"]

FORMAT_VERSION = 1
#: Distance from the Franka hand frame to the center of its fingertip pads (Franka's TCP, m).
ACRONYM_TCP = 0.1034
#: ACRONYM's hand frame in jaxgrasp's grasp frame: x_acr = y, y_acr = -x, origin TCP behind.
_ACRONYM_IN_GRASP = np.array([[0.0, -1.0, 0.0, 0.0],
                              [1.0, 0.0, 0.0, 0.0],
                              [0.0, 0.0, 1.0, -ACRONYM_TCP],
                              [0.0, 0.0, 0.0, 1.0]])
SUFFIXES = (".npz", ".json", ".h5")

#: JSON schema of the ``.json`` grasp file (``docs/grasps.schema.json`` is a copy).
SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "jaxgrasp grasp file",
    "type": "object",
    "required": ["format", "version", "frame", "object", "grasps"],
    "properties": {
        "format": {"const": "jaxgrasp-grasps"},
        "version": {"const": FORMAT_VERSION},
        "frame": {"const": "grasp-center"},
        "object": {
            "type": "object", "required": ["name", "hash"],
            "properties": {"name": {"type": "string"}, "hash": {"type": "string"}},
        },
        "grasps": {
            "type": "array",
            "items": {
                "type": "object",
                "required": ["transform", "width", "epsilon", "outcome"],
                "properties": {
                    "transform": {"type": "array", "minItems": 4, "maxItems": 4,
                                  "items": {"type": "array", "minItems": 4, "maxItems": 4,
                                            "items": {"type": "number"}}},
                    "width": {"type": "number", "minimum": 0},
                    "epsilon": {"type": "number", "minimum": 0},
                    "outcome": {"enum": list(OUTCOME_NAMES)},
                    "robustness": {"type": "number", "minimum": 0, "maximum": 1},
                },
            },
        },
    },
}


class GraspSet(NamedTuple):
    """Grasps of one object, in jaxgrasp's grasp frame.

    grasps : (N, 7) positions and unit quaternions (w, x, y, z), object frame.
    transforms : (N, 4, 4) the same poses as homogeneous transforms.
    width : (N,) gripper opening (m); epsilon : (N,); outcome : (N,) int8 outcome codes.
    object_name, object_hash : the object the grasps belong to.
    robustness : (N,) hold probability under a robot's pose error
        (:func:`jaxgrasp.learn.robustness`), or None where it was not measured.
    """

    grasps: np.ndarray
    transforms: np.ndarray
    width: np.ndarray
    epsilon: np.ndarray
    outcome: np.ndarray
    object_name: str
    object_hash: str
    robustness: np.ndarray | None = None


def _outcome_code(outcome) -> int | None:
    if outcome is None or outcome == "all":
        return None
    if isinstance(outcome, str) and outcome in OUTCOME_NAMES:
        return OUTCOME_NAMES.index(outcome)
    raise ValueError(f"outcome must be one of {OUTCOME_NAMES} or 'all', got {outcome!r}")


def _suffix(path) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"{path}: unknown grasp file type {suffix!r}; use one of {SUFFIXES}")
    return suffix


def to_transforms(grasps) -> np.ndarray:
    """(N, 4, 4) homogeneous transforms of (N, 7) grasp poses."""
    g = np.asarray(grasps, np.float64).reshape(-1, 7)
    q = g[:, 3:] / np.linalg.norm(g[:, 3:], axis=1, keepdims=True)
    t = np.tile(np.eye(4), (len(g), 1, 1))
    t[:, :3, :3] = Rotation.from_quat(q, scalar_first=True).as_matrix()
    t[:, :3, 3] = g[:, :3]
    return t


def from_transforms(transforms, label="transforms") -> np.ndarray:
    """(N, 7) grasp poses of (N, 4, 4) rigid transforms (ValueError if they are not rigid)."""
    t = np.asarray(transforms, np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise ValueError(f"{label} must be (N, 4, 4), got {t.shape}")
    r = t[:, :3, :3]
    eye = np.broadcast_to(np.eye(3), r.shape)
    if (not np.isfinite(t).all() or not np.allclose(r @ r.transpose(0, 2, 1), eye, atol=1e-5)
            or not np.allclose(np.linalg.det(r), 1.0, atol=1e-5)):
        raise ValueError(f"{label}: not all rigid transforms (rotation blocks must be "
                         "orthonormal with det +1, entries finite)")
    q = Rotation.from_matrix(r).as_quat(scalar_first=True).reshape(-1, 4)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return np.concatenate([t[:, :3, 3], q], axis=1)


def select_grasps(result, *, outcome="success", distinct=True, width=None) -> GraspSet:
    """The proposals of ``result`` with ``outcome`` (first occurrence of each distinct grasp
    when ``distinct``), in order of proposal."""
    code = _outcome_code(outcome)
    proposals = np.asarray(result.proposals, np.float64).reshape(-1, 7)
    outcomes = np.asarray(result.outcomes).reshape(-1)
    epsilons = np.asarray(result.epsilons, np.float64).reshape(-1)
    keep = np.ones(len(outcomes), bool) if code is None else outcomes == code
    idx = np.flatnonzero(keep)
    if distinct and len(idx):
        kept = distinct_grasps(proposals[idx])
        unit = proposals[idx].copy()
        unit[:, 3:] /= np.linalg.norm(unit[:, 3:], axis=1, keepdims=True)
        # each kept grasp is one of the rows (normalised): the first row equal to it
        idx = idx[[int(np.argmax(np.abs(unit - row).max(axis=1) < 1e-9)) for row in kept]]
    grasps = proposals[idx]
    grasps[:, 3:] /= np.linalg.norm(grasps[:, 3:], axis=1, keepdims=True)
    grasps[:, 3:] *= np.where(grasps[:, 3:4] < 0, -1.0, 1.0)
    w = GripperParams().max_opening if width is None else float(width)
    return GraspSet(grasps, to_transforms(grasps), np.full(len(idx), w), epsilons[idx],
                    outcomes[idx].astype(np.int8), result.object_name, result.object_hash)


def export_grasps(result, path, *, outcome="success", distinct=True, mesh_file=None,
                  scale=1.0) -> Path:
    """Write the grasps of ``result`` (a LearnResult or a GraspSet) to ``path``.

    The suffix picks the format: ``.npz``, ``.json`` or ``.h5`` (ACRONYM layout:
    ``grasps/transforms``, ``grasps/qualities/flex/object_in_gripper``,
    ``grasps/qualities/jaxgrasp/epsilon``, ``object/file``, ``object/scale``). ``outcome``:
    an outcome name or ``"all"``; ``distinct``: one grasp per 1 cm / 10° cluster. The file is
    written atomically: a failure leaves no partial file. Returns the path.
    """
    suffix = _suffix(path)
    grasps = result if isinstance(result, GraspSet) else select_grasps(
        result, outcome=outcome, distinct=distinct)
    robust = {} if grasps.robustness is None else {
        "robustness": np.asarray(grasps.robustness, np.float64)}
    if suffix == ".npz":
        buf = io.BytesIO()
        np.savez(buf, format_version=np.int64(FORMAT_VERSION), transforms=grasps.transforms,
                 grasps=grasps.grasps, width=grasps.width, epsilon=grasps.epsilon,
                 outcome=grasps.outcome, object_name=np.str_(grasps.object_name),
                 object_hash=np.str_(grasps.object_hash), **robust)
        data = buf.getvalue()
    elif suffix == ".json":
        doc = {"format": "jaxgrasp-grasps", "version": FORMAT_VERSION, "frame": "grasp-center",
               "object": {"name": grasps.object_name, "hash": grasps.object_hash},
               "grasps": [{"transform": t.tolist(), "width": float(w), "epsilon": float(e),
                           "outcome": OUTCOME_NAMES[int(o)],
                           **({} if r is None else {"robustness": float(r)})}
                          for t, w, e, o, r in zip(
                              grasps.transforms, grasps.width, grasps.epsilon, grasps.outcome,
                              robust.get("robustness", [None] * len(grasps.width)),
                              strict=True)]}
        data = json.dumps(doc, indent=1).encode()
    else:
        data = _acronym_bytes(grasps, mesh_file or f"{grasps.object_name}.obj", scale)
    atomic_write_bytes(path, data)
    return Path(path)


def _acronym_bytes(grasps: GraspSet, mesh_file: str, scale: float) -> bytes:
    buf = io.BytesIO()
    with h5py.File(buf, "w") as f:
        f["grasps/transforms"] = grasps.transforms @ _ACRONYM_IN_GRASP
        f["grasps/qualities/flex/object_in_gripper"] = (grasps.outcome == 0).astype(np.int64)
        f["grasps/qualities/jaxgrasp/epsilon"] = grasps.epsilon
        f["grasps/qualities/jaxgrasp/outcome"] = grasps.outcome
        if grasps.robustness is not None:
            f["grasps/qualities/jaxgrasp/robustness"] = np.asarray(grasps.robustness, float)
        f["grasps/width"] = grasps.width
        f["object/file"] = mesh_file
        f["object/scale"] = float(scale)
        f["object/name"] = grasps.object_name
        f["object/hash"] = grasps.object_hash
        f["gripper/type"] = "franka_panda"
        f.attrs["jaxgrasp_format_version"] = FORMAT_VERSION
    return buf.getvalue()


def load_grasps(path) -> GraspSet:
    """Read a grasp file written by :func:`export_grasps` (or an ACRONYM ``.h5``)."""
    suffix = _suffix(path)
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such grasp file")
    try:
        if suffix == ".npz":
            a = read_npz(str(path), str(path))
            out = (a["grasps"], a["width"], a["epsilon"], a["outcome"], str(a["object_name"]),
                   str(a["object_hash"]), a.get("robustness"))
        elif suffix == ".json":
            doc = json.loads(path.read_text())
            jsonschema.validate(doc, SCHEMA)
            rows = doc["grasps"]
            t = np.array([r["transform"] for r in rows], np.float64).reshape(-1, 4, 4)
            robust = ([r["robustness"] for r in rows]
                      if rows and all("robustness" in r for r in rows) else None)
            out = (from_transforms(t, str(path)), [r["width"] for r in rows],
                   [r["epsilon"] for r in rows], [OUTCOME_NAMES.index(r["outcome"]) for r in rows],
                   doc["object"]["name"], doc["object"]["hash"], robust)
        else:
            out = _read_acronym(path)
    except (KeyError, jsonschema.ValidationError, json.JSONDecodeError, OSError,
            UnicodeDecodeError) as err:
        raise ValueError(f"{path} is not a valid grasp file ({type(err).__name__}: "
                         f"{str(err).splitlines()[0]})") from None
    grasps = np.asarray(out[0], np.float64).reshape(-1, 7)
    robust = None if out[6] is None else np.asarray(out[6], np.float64)
    return GraspSet(grasps, to_transforms(grasps), np.asarray(out[1], np.float64),
                    np.asarray(out[2], np.float64), np.asarray(out[3], np.int8), out[4], out[5],
                    robust)


def _read_acronym(path):
    with h5py.File(path, "r") as f:
        t = np.asarray(f["grasps/transforms"], np.float64)
        n = len(t)
        ok = np.asarray(f["grasps/qualities/flex/object_in_gripper"]).reshape(-1)
        grasps = from_transforms(t @ np.linalg.inv(_ACRONYM_IN_GRASP), str(path))
        outcome = (np.asarray(f["grasps/qualities/jaxgrasp/outcome"])
                   if "grasps/qualities/jaxgrasp/outcome" in f else np.where(ok > 0, 0, 1))
        eps = (np.asarray(f["grasps/qualities/jaxgrasp/epsilon"])
               if "grasps/qualities/jaxgrasp/epsilon" in f else np.zeros(n))
        width = (np.asarray(f["grasps/width"]) if "grasps/width" in f
                 else np.full(n, GripperParams().max_opening))
        name = f["object/name"][()].decode() if "object/name" in f else \
            Path(f["object/file"][()].decode()).stem
        digest = f["object/hash"][()].decode() if "object/hash" in f else ""
        key = "grasps/qualities/jaxgrasp/robustness"
        robust = np.asarray(f[key]) if key in f else None
    return grasps, width, eps, outcome, name, digest, robust

"""Grasp atlas: an object's distinct successful grasps from a large structured search (issue 18).

The atlas is the ground truth the learners' coverage is measured against. Candidates are
structured, not sampled around demos:

- area-uniform surface points (normals not facing the table), x
- approach directions (the gripper's +z axis, object frame): a Fibonacci sphere plus straight
  down, kept where ``dot(approach, outward normal) < 0.3`` (not from inside the surface), x
- rotations about the approach (6 angles in [0, pi): the gripper is symmetric under 180°), x
- 2 depths: grasp centre = point + depth * approach, depth in {0.6, 1.2} x pad half length;

poses whose open gripper reaches below the support plane are dropped. Every candidate runs on
the MuJoCo C backend; the successes are reduced to distinct grasps (1 cm / 10°, 180° symmetry,
:func:`jaxgrasp.learn.distinct.distinct_grasps`), most robust (highest epsilon) first.

Shipped as ``assets/atlas/<name>.npz``; rebuild with::

    python -m jaxgrasp.learn.atlas pitcher pan tall_pitcher --trials 100000 --seed 0
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxgrasp.learn.demos import MIN_NORMAL_Z, _gripper_corners, surface_points
from jaxgrasp.learn.distinct import ANGLE_TOL, POSITION_TOL, distinct_grasps
from jaxgrasp.learn.results import canonical_grasps

__all__ = ["Atlas", "atlas_poses", "build_atlas", "save_atlas", "load_atlas", "atlas_dir"]

#: Fibonacci-sphere approach directions (straight down is added on top).
NUM_DIRECTIONS = 20
#: Rotations about the approach, in [0, pi).
NUM_ROTATIONS = 6
#: Grasp-centre depths along the approach, in pad half lengths.
DEPTHS = (0.6, 1.2)
#: An approach is kept where dot(approach, outward normal) < this.
MAX_APPROACH_DOT = 0.3
#: Bump when the candidate generator changes (stored in the atlas settings).
VERSION = 1

REBUILD = "python -m jaxgrasp.learn.atlas {name} --trials 100000 --seed 0"


class Atlas(NamedTuple):
    """grasps (k, 7) distinct successful grasps; trial/success/slip counts; build seconds."""

    grasps: np.ndarray
    trials: int
    successes: int
    slipped: int
    seconds: float
    settings: dict


def atlas_dir() -> Path:
    """``assets/atlas`` (follows ``$JAXGRASP_ASSETS`` like the shipped objects)."""
    from jaxgrasp.objects.shipped import assets_dir

    return assets_dir() / "atlas"


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z**2)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _directions() -> np.ndarray:
    return np.concatenate([_fibonacci_sphere(NUM_DIRECTIONS), [[0.0, 0.0, -1.0]]])


def _frames(approach: np.ndarray) -> np.ndarray:
    """(D, R, 3, 3) grasp frames (columns x, y, z) with z = approach, y rotated about z."""
    z = approach / np.linalg.norm(approach, axis=1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    y0 = np.cross(z, helper)
    y0 /= np.linalg.norm(y0, axis=1, keepdims=True)
    x0 = np.cross(y0, z)
    ang = math.pi * np.arange(NUM_ROTATIONS) / NUM_ROTATIONS
    y = np.cos(ang)[None, :, None] * y0[:, None] + np.sin(ang)[None, :, None] * x0[:, None]
    zz = np.broadcast_to(z[:, None], y.shape)
    x = np.cross(y, zz)
    return np.stack([x, y, zz], axis=-1)


def atlas_poses(obj, *, num_points: int, seed: int, gripper=None) -> np.ndarray:
    """Structured candidate grasps (N, 7) float32 ``(x, y, z, qw, qx, qy, qz)``, object frame.

    For each of ``num_points`` surface points (in point order): approach directions (in
    :func:`_directions` order) with ``dot(approach, normal) < 0.3``, x ``NUM_ROTATIONS``
    rotations, x ``DEPTHS``; poses whose open gripper reaches below the support plane are
    dropped. Unit quaternions with qw >= 0.
    """
    from scipy.spatial.transform import Rotation

    if gripper is None:
        from jaxgrasp.physics import GripperParams

        gripper = GripperParams()
    obj = getattr(obj, "obj", obj)
    points, normals = surface_points(obj.mesh, int(num_points), int(seed),
                                     min_normal_z=MIN_NORMAL_Z)
    points = points.astype(np.float64)
    normals = normals.astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    dirs = _directions()
    frames = _frames(dirs)  # (D, R, 3, 3)
    depths = np.asarray(DEPTHS) * float(gripper.pad_half_size[2])
    corners = np.asarray(_gripper_corners(gripper), np.float64)
    # lowest corner offset (z) of each frame, relative to the grasp centre
    low = np.einsum("drij,kj->drki", frames, corners)[..., 2].min(axis=-1)  # (D, R)
    ok_dir = normals @ dirs.T < MAX_APPROACH_DOT  # (P, D)
    # centres (P, D, G, 3)
    centres = points[:, None, None, :] + depths[None, None, :, None] * dirs[None, :, None, :]
    # (P, D, R, G): above the support plane
    above = centres[:, :, None, :, 2] + low[None, :, :, None] >= float(obj.support_z) + 0.001
    keep = ok_dir[:, :, None, None] & above
    shape = keep.shape
    c_all = np.broadcast_to(centres[:, :, None], shape + (3,))[keep]
    quats = Rotation.from_matrix(frames.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    quats = quats.reshape(frames.shape[:2] + (4,))
    q_all = np.broadcast_to(quats[None, :, :, None], shape + (4,))[keep]
    poses = np.concatenate([c_all, q_all], axis=1)
    if len(poses) == 0:
        return np.zeros((0, 7), np.float32)
    return canonical_grasps(poses).astype(np.float32)


def _enough_poses(obj, num_trials: int, seed: int, gripper=None):
    """The candidates of the smallest tried ``num_points`` giving >= num_trials poses."""
    num_points = max(8, num_trials // 100)
    for _ in range(20):
        poses = atlas_poses(obj, num_points=num_points, seed=seed, gripper=gripper)
        if len(poses) >= num_trials:
            return poses, num_points
        per_point = max(len(poses), 1) / num_points
        num_points = max(num_points + 1, int(math.ceil(1.02 * num_trials / per_point)))
    raise RuntimeError(f"could not generate {num_trials} candidates on {obj.name!r}")


def build_atlas(obj, *, num_trials: int = 100_000, seed: int = 0, batch: int = 1024,
                progress: bool = True) -> Atlas:
    """Run the structured candidates (>= ``num_trials``) on MuJoCo C; keep distinct successes.

    ``obj``: a GraspObject or a shipped object's name. Every generated candidate is tried
    (the count is >= num_trials). Successes are ordered by epsilon (descending, stable) before
    the greedy reduction, so each distinct grasp is represented by its most robust member.
    """
    import jax

    from jaxgrasp.physics import Outcome, load_scene, make_trial

    if isinstance(obj, str):
        from jaxgrasp.objects.shipped import load

        obj = load(obj)
    t0 = time.perf_counter()
    poses, num_points = _enough_poses(obj, int(num_trials), int(seed))
    trial = make_trial(load_scene(obj), backend="mujoco")
    outcome = np.empty(len(poses), np.int32)
    epsilon = np.zeros(len(poses), np.float32)
    for lo in range(0, len(poses), batch):
        chunk = poses[lo:lo + batch]
        n = len(chunk)
        if n < batch:  # pad: one compiled shape
            chunk = np.concatenate([chunk, np.repeat(chunk[:1], batch - n, axis=0)])
        res = jax.device_get(trial(chunk))
        outcome[lo:lo + n] = np.asarray(res.outcome)[:n]
        epsilon[lo:lo + n] = np.nan_to_num(np.asarray(res.epsilon, np.float32)[:n], nan=0.0)
        if progress:
            done = lo + n
            print(f"\r{obj.name}: {done}/{len(poses)} trials, "
                  f"{int((outcome[:done] == Outcome.SUCCESS).sum())} successes, "
                  f"{time.perf_counter() - t0:.0f} s", end="", file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    ok = np.flatnonzero(outcome == Outcome.SUCCESS)
    ok = ok[np.argsort(-epsilon[ok], kind="stable")]
    grasps = canonical_grasps(distinct_grasps(poses[ok])).astype(np.float32)
    counts = np.bincount(outcome, minlength=4)
    settings = {
        "version": VERSION, "object": obj.name, "content_hash": obj.content_hash,
        "num_trials": int(num_trials), "seed": int(seed), "num_points": int(num_points),
        "num_directions": NUM_DIRECTIONS + 1, "num_rotations": NUM_ROTATIONS,
        "depths": list(DEPTHS), "max_approach_dot": MAX_APPROACH_DOT,
        "min_normal_z": MIN_NORMAL_Z, "position_tol": POSITION_TOL, "angle_tol": ANGLE_TOL,
        "backend": "mujoco", "outcome_counts": {o.name.lower(): int(counts[o]) for o in Outcome},
    }
    return Atlas(grasps, int(len(poses)), int(len(ok)), int(counts[Outcome.SLIPPED]),
                 float(time.perf_counter() - t0), settings)


def save_atlas(name: str, atlas: Atlas, *, directory=None) -> Path:
    """Write ``<directory or assets/atlas>/<name>.npz`` (arrays only)."""
    d = Path(directory) if directory is not None else atlas_dir()
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{name}.npz"
    np.savez_compressed(
        path, grasps=np.asarray(atlas.grasps, np.float32).reshape(-1, 7),
        trials=np.int64(atlas.trials), successes=np.int64(atlas.successes),
        slipped=np.int64(atlas.slipped), seconds=np.float64(atlas.seconds),
        settings=np.asarray(json.dumps(atlas.settings, sort_keys=True)))
    return path


def load_atlas(name: str, *, directory=None) -> Atlas:
    """The shipped atlas of an object (FileNotFoundError naming the rebuild command)."""
    d = Path(directory) if directory is not None else atlas_dir()
    path = d / f"{name}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"no grasp atlas for {name!r} at {path}; build it with "
                                f"`{REBUILD.format(name=name)}`")
    with np.load(path, allow_pickle=False) as z:
        return Atlas(np.asarray(z["grasps"], np.float32), int(z["trials"]),
                     int(z["successes"]), int(z["slipped"]), float(z["seconds"]),
                     json.loads(str(z["settings"])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m jaxgrasp.learn.atlas", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("objects", nargs="+", metavar="OBJECT", help="shipped object names")
    ap.add_argument("--trials", type=int, default=100_000, help="minimum trials per object")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=int, default=1024)
    args = ap.parse_args(argv)
    for name in args.objects:
        atlas = build_atlas(name, num_trials=args.trials, seed=args.seed, batch=args.batch)
        path = save_atlas(name, atlas)
        print(f"{name}: trials={atlas.trials} successes={atlas.successes} "
              f"slipped={atlas.slipped} distinct={len(atlas.grasps)} "
              f"seconds={atlas.seconds:.0f} -> {path}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""A grasp mapped by the object's own symmetry: the same grasp elsewhere on the object.

On a solid of revolution a rim pinch that holds under a robot's pose error holds the same way
all around the rim; on an object with n-fold turns at each of its n places, and with a mirror
plane at its mirror image; the chains and a flood of small steps reach only some of those
places. :func:`symmetric_copies` gives, for each grasp, its copies under the symmetry found
from the mesh (:class:`jaxgrasp.objects.Symmetry`), by :func:`copy_maps`:

- a revolution: turns about the vertical axis by ``±Δ, ±2Δ, ±4Δ, ...`` up to half a turn and
  the half turn itself, ``Δ`` the turn that moves the grasp centre one flood step
  (:data:`~jaxgrasp.learn.evaluate.atlas.NEIGHBOUR_STEP`) along its circle, at most
  :data:`~jaxgrasp.learn.evaluate.atlas.NEIGHBOUR_TURN_DEG` (so every copy is a distinct grasp);
- n-fold turns: by ``2πk/n``;
- each vertical mirror plane: the reflection ``p' = c + M (p - c)``, ``R' = M R S`` with ``S``
  the gripper's own mirror (its pads swapped), as the chains' mirror move.

A copy is kept only where the object looks the same around it as around the grasp
(:func:`jaxgrasp.objects.symmetry.same_surroundings`): a pan's handle is not turned into air.
Whether a copy holds is for the trial to say.
"""

import math

import numpy as np
from scipy.spatial.transform import Rotation

from jaxgrasp.learn.evaluate.atlas import NEIGHBOUR_STEP, NEIGHBOUR_TURN_DEG
from jaxgrasp.learn.evaluate.distinct import canonical_grasps
from jaxgrasp.objects.symmetry import Symmetry, find_symmetry, same_surroundings
from jaxgrasp.physics import GripperParams

__all__ = ["as_symmetry", "copy_maps", "same_around", "symmetric_copies"]


def as_symmetry(obj, symmetry) -> Symmetry | None:
    """``symmetry`` (a Symmetry, its text form, its dict as a run records it, or ``"auto"``:
    found from ``obj``'s mesh) when it has turns or mirrors, else None (also for None)."""
    if symmetry is None:
        return None
    if isinstance(symmetry, dict):
        symmetry = Symmetry.from_dict(symmetry)
    sym = (find_symmetry(obj) if isinstance(symmetry, str) and symmetry == "auto"
           else Symmetry.parse(symmetry) if isinstance(symmetry, str) else symmetry)
    return None if sym.trivial else sym


def same_around(sim, symmetry: Symmetry):
    """The copies' test for ``sim``'s object: it looks the same within the pads' reach of the
    grasp centre and of its copy's (:func:`~jaxgrasp.objects.symmetry.same_surroundings`)."""
    gripper = getattr(sim.scene, "gripper", None) or GripperParams()
    return same_surroundings(sim.obj, symmetry,
                             radius=0.5 * gripper.max_opening + gripper.pad_half_size[2])


def copy_maps(radius: float, symmetry: Symmetry) -> tuple[np.ndarray, np.ndarray]:
    """``(angles, mirror)``: the maps that copy a grasp whose centre is ``radius`` from the
    axis, each a turn by its angle (radians) or, where ``mirror``, the reflection through the
    vertical plane at that angle to the x axis."""
    if symmetry.kind == "turns":
        turns = 2.0 * np.pi * np.arange(1, symmetry.order) / symmetry.order
    elif symmetry.kind == "revolution":
        step = min(NEIGHBOUR_STEP / max(float(radius), 1e-9), math.radians(NEIGHBOUR_TURN_DEG))
        doubling = step * 2.0 ** np.arange(int(math.floor(math.log2(math.pi / step))) + 1)
        doubling = doubling[doubling < math.pi]
        turns = np.concatenate([doubling, -doubling, [math.pi]])
    else:
        turns = np.zeros(0)
    planes = np.radians(np.asarray(symmetry.mirrors, np.float64))
    return (np.concatenate([turns, planes]),
            np.concatenate([np.zeros(len(turns), bool), np.ones(len(planes), bool)]))


def symmetric_copies(grasps, symmetry: Symmetry, same=None) -> np.ndarray:
    """(m, 7) float32: each grasp mapped by :func:`copy_maps` (grasp-major order), less the
    copies ``same(centres, angles, mirror)`` rejects (optional:
    :func:`~jaxgrasp.objects.symmetry.same_surroundings`)."""
    g = np.asarray(grasps, np.float64).reshape(-1, 7)
    axis = np.asarray(symmetry.centre, np.float64)
    maps = [copy_maps(float(np.linalg.norm(row[:2] - axis)), symmetry) for row in g]
    rows = np.repeat(np.arange(len(g)), [len(a) for a, _ in maps])
    angles = np.concatenate([a for a, _ in maps]) if maps else np.zeros(0)
    mirror = np.concatenate([m for _, m in maps]) if maps else np.zeros(0, bool)
    if same is not None and len(rows):
        keep = np.asarray(same(g[rows, :3], angles, mirror), bool)
        rows, angles, mirror = rows[keep], angles[keep], mirror[keep]
    if len(rows) == 0:
        return np.zeros((0, 7), np.float32)
    p = g[rows, :3] - [*axis, 0.0]
    base = Rotation.from_quat(g[rows, 3:], scalar_first=True)
    turn = Rotation.from_euler("z", np.where(mirror, 0.0, angles)[:, None])
    # a mirror: p - 2 (p . n) n and Rot_pi(n) R Rot_pi(e_y), n the plane's normal
    n = np.stack([-np.sin(angles), np.cos(angles), np.zeros_like(angles)], axis=1)
    reflected = p - 2.0 * np.sum(p * n, axis=1, keepdims=True) * n
    flip = Rotation.from_rotvec(np.where(mirror[:, None], np.pi * n, 0.0))
    pads = Rotation.from_rotvec(np.where(mirror[:, None], [0.0, np.pi, 0.0], 0.0))
    centres = np.where(mirror[:, None], reflected, turn.apply(p)) + [*axis, 0.0]
    q = (turn * flip * base * pads).as_quat(scalar_first=True)
    return canonical_grasps(np.concatenate([centres, q], axis=1)).astype(np.float32)

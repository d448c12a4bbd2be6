"""Scene assembly: gripper (fixed at the world origin) + object (free body, convex pieces).

The gripper never moves in the simulation world, so its frame *is* the world frame; the grasp
is realized by placing the object at the inverse grasp pose through its free-joint ``qpos``
(plain data, so it vmaps). This avoids MJX's mocap-children bug (``docs/design.md``): nothing
hangs under a mocap body. Gravity is off in the model; the hold load is applied per trial through
``xfrc_applied`` in the gripper frame.

The model is compiled once per scene; ids are looked up by name at load time.
"""

from dataclasses import dataclass
from typing import NamedTuple

import mujoco
import numpy as np

from jaxgrasp.physics.collision import PairLayout, pair_layout
from jaxgrasp.physics.gripper import GripperParams, gripper_corners, gripper_xml
from jaxgrasp.physics.protocol import TrialParams

__all__ = ["Scene", "SceneIds", "load_scene", "scene_xml"]

#: MuJoCo needs at least 4 non-coplanar vertices for a convex hull; pieces above this are
#: rejected (MJX has no broadphase: every vertex costs every step).
MAX_PIECE_VERTS = 32


class SceneIds(NamedTuple):
    """Indices looked up by name once, at load time (python ints)."""

    object_body: int
    object_qpos: int  # first of the 7 free-joint qpos entries
    object_qvel: int  # first of the 6 free-joint dofs
    finger_qpos: tuple  # (left, right)
    pad_geoms: tuple  # (left, right)
    palm_geom: int
    layout: PairLayout  # collidable (gripper box, object piece) pairs in MJX slot order


@dataclass(frozen=True, eq=False)
class Scene:
    """A compiled grasp scene.

    Attributes
    ----------
    obj : GraspObject
    gripper : GripperParams
    params : TrialParams
    xml : str
        The MJCF it was compiled from (meshes inline; no asset files).
    mj_model : mujoco.MjModel
    ids : SceneIds
    corners : (24, 3) float32
        Gripper corners (palm + open pads) in the grasp frame, for the support-plane check.
    """

    obj: object
    gripper: GripperParams
    params: TrialParams
    xml: str
    mj_model: mujoco.MjModel
    ids: SceneIds
    corners: np.ndarray

    @property
    def friction(self) -> float:
        """Pad/object Coulomb coefficient (used for epsilon)."""
        return self.gripper.pad_friction

    def qpos0(self) -> np.ndarray:
        """Open fingers, object at the origin (placement overwrites the object's pose)."""
        q = self.mj_model.qpos0.copy()
        for a in self.ids.finger_qpos:
            q[a] = self.gripper.open_width
        return q


def _f(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.ravel(v))


def scene_xml(obj, gripper: GripperParams, params: TrialParams) -> str:
    """MJCF of the scene; meshes are inline vertex lists (convex hulls), inertial explicit."""
    gbody, gact = gripper_xml(gripper)
    meshes, geoms = [], []
    for i, piece in enumerate(obj.pieces):
        v = np.asarray(piece, dtype=float)
        meshes.append(f'    <mesh name="piece_{i}" vertex="{_f(v)}"/>')
        geoms.append(
            f'      <geom name="piece_{i}" type="mesh" mesh="piece_{i}" contype="2" '
            f'conaffinity="1" condim="3" friction="0 0 0" rgba="0.8 0.6 0.4 1"/>'
        )
    inertia = np.asarray(obj.inertia, dtype=float)
    full = [inertia[i, j] for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))]
    return f"""<mujoco model="jaxgrasp_{obj.name}">
  <compiler angle="radian" autolimits="true" inertiafromgeom="false"/>
  <option timestep="{params.timestep:.9g}" gravity="0 0 0" integrator="Euler"
          iterations="{params.iterations}" ls_iterations="{params.ls_iterations}">
    <flag warmstart="enable"/>
  </option>
  <default>
    <!-- Stiff contacts and limits (time constant 2 timesteps, impedance 0.99): MuJoCo's
         default softness lets a 20 N light finger sink ~1 cm into the object. -->
    <geom solref="{2 * params.timestep:.9g} 1" solimp="0.95 0.99 0.001"/>
    <joint solreflimit="{2 * params.timestep:.9g} 1" solimplimit="0.95 0.99 0.001"/>
  </default>
  <asset>
{chr(10).join(meshes)}
  </asset>
  <worldbody>{gbody}
    <body name="object">
      <freejoint name="object"/>
      <inertial pos="{_f(obj.com)}" mass="{float(obj.mass):.9g}" fullinertia="{_f(full)}"/>
{chr(10).join(geoms)}
    </body>
  </worldbody>
  <actuator>{gact}
  </actuator>
</mujoco>
"""


def _check_object(obj):
    if not obj.pieces:
        raise ValueError(f"object {obj.name!r} has no convex pieces")
    for i, p in enumerate(obj.pieces):
        p = np.asarray(p)
        if p.ndim != 2 or p.shape[1] != 3 or not 4 <= p.shape[0] <= MAX_PIECE_VERTS:
            raise ValueError(
                f"object {obj.name!r} piece {i} must be (V, 3) with 4 <= V <= {MAX_PIECE_VERTS},"
                f" got shape {p.shape}"
            )
    if not obj.mass > 0:
        raise ValueError(f"object {obj.name!r} mass must be > 0, got {obj.mass}")
    inertia = np.asarray(obj.inertia, dtype=float)
    if inertia.shape != (3, 3) or np.linalg.eigvalsh(0.5 * (inertia + inertia.T)).min() <= 0:
        raise ValueError(f"object {obj.name!r} inertia must be a positive definite 3x3 matrix")


def load_scene(obj, gripper: GripperParams | None = None, params: TrialParams | None = None):
    """Build and compile the grasp scene for an object.

    Parameters
    ----------
    obj : str or GraspObject
        A shipped object name (``jg.objects.load``) or a loaded object.
    gripper : GripperParams, optional
        Default: ``GripperParams()``.
    params : TrialParams, optional
        Default: ``TrialParams()``.

    Returns
    -------
    Scene
    """
    if isinstance(obj, str):
        # why: jaxgrasp.objects imports trimesh and manifold3d; only a shipped name needs them.
        from jaxgrasp import objects

        obj = objects.load(obj)
    if not hasattr(obj, "pieces"):
        raise ValueError(f"obj must be a shipped object name or a GraspObject, got {type(obj)}")
    gripper = GripperParams() if gripper is None else gripper
    params = TrialParams() if params is None else params
    if not isinstance(gripper, GripperParams) or not isinstance(params, TrialParams):
        raise ValueError("gripper must be GripperParams and params TrialParams")
    _check_object(obj)
    xml = scene_xml(obj, gripper, params)
    m = mujoco.MjModel.from_xml_string(xml)

    def name2id(kind, name):
        i = mujoco.mj_name2id(m, kind, name)
        if i < 0:
            raise ValueError(f"scene has no {kind} named {name!r}")
        return i

    J, B, GE = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_GEOM
    obj_joint, obj_body = name2id(J, "object"), name2id(B, "object")
    pads = tuple(name2id(GE, f"pad_{s}") for s in ("left", "right"))
    palm = name2id(GE, "palm")
    pieces = tuple(int(g) for g in np.flatnonzero(m.geom_bodyid == obj_body))
    ids = SceneIds(
        object_body=obj_body,
        object_qpos=int(m.jnt_qposadr[obj_joint]),
        object_qvel=int(m.jnt_dofadr[obj_joint]),
        finger_qpos=tuple(int(m.jnt_qposadr[name2id(J, f"finger_{s}")]) for s in ("left", "right")),
        pad_geoms=pads,
        palm_geom=palm,
        layout=pair_layout(m, (*pads, palm), pieces),
    )
    return Scene(
        obj=obj,
        gripper=gripper,
        params=params,
        xml=xml,
        mj_model=m,
        ids=ids,
        corners=gripper_corners(gripper),
    )

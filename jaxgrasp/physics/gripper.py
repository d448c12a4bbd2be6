"""A parametric parallel-jaw gripper, generated as MJCF from a frozen dataclass.

Grasp frame (the frame a grasp pose ``(x, y, z, q)`` places in the object frame):

- origin = the **grasp center**, midpoint between the two pad centers: the pose's position
  is where the object material should be;
- ``+z`` = **approach** direction: the palm sits behind the pads at ``z < 0`` and the gripper
  moves along ``+z`` toward the object;
- ``±y`` = **closing** direction: the left pad (``+y``) and right pad (``-y``) move toward
  ``y = 0``; their inner faces lie at ``y = ±q`` with ``q`` the finger joint position
  (``q = max_opening / 2`` open, ``q = 0`` closed);
- ``x`` = across the pads (their width).

Only the two pads and the palm collide with the object (contype/conaffinity); fingers are
independent prismatic joints with force-limited position actuators, so an off-center object is
pushed to the middle as in a real underactuated parallel gripper.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["GRIPPERS", "GripperParams", "gripper", "gripper_xml", "gripper_corners"]


@dataclass(frozen=True)
class GripperParams:
    """Geometry, dynamics and friction of the parallel-jaw gripper (metres, kg, N).

    Defaults resemble a Robotiq 2F-85 / Franka hand: 8.5 cm stroke, 70 N grip force (the
    Franka hand's continuous force; the 2F-85 spans 20-235 N), 2.5 cm wide rubber pads
    (mu = 1.0). With the former 20 N / 2 cm / mu 0.8 a 0.7-1.2 kg kitchen object slipped out
    of every sensible grasp (0/320 demo candidates on the pan); 20 N is a light-duty grip.

    Attributes
    ----------
    max_opening : float
        Distance between the pad inner faces when open (0.085).
    pad_half_size : (3,) tuple
        Pad box half extents (x width, y thickness, z length): 2.5 cm x 8 mm x 4 cm (Franka
        finger tips are ~2 cm, Robotiq 2F-85 pads 2.2 x 3.8 cm; wider pads resist the
        torque of a long handle through friction spread across the pad).
    palm_half_size : (3,) tuple
        Palm box half extents; it sits directly behind the pads (z < -pad length / 2).
    finger_mass : float
    finger_armature : float
        Reflected inertia of the finger drive (kg; a geared drive's motor inertia seen at the
        finger): 0.5. Without it a 0.1 kg finger under 70 N chatters on the object by
        millimetres per 3 ms step, and the outcome of a pinch on a thin wall becomes chaotic:
        MJX and MuJoCo C agreed on 87.1 % of the 512 pitcher agreement poses, 97.5 % with
        0.5 kg + 100 N s/m (``benchmarks/backend_agreement.py``).
    finger_damping : float
        Joint damping (N s/m): 100, overdamped (1.4x critical) for ``finger_kp`` on the
        finger's 0.6 kg effective mass; the fingers still close the 8.5 cm stroke in the
        protocol's 90 ms (70 N / 100 N s/m = 0.7 m/s).
    finger_kp : float
        Position-actuator stiffness (N/m).
    force_limit : float
        Finger force limit (N): the grip force once the pads press on the object (70 N).
        The protocol's ``close_target`` must lie ``force_limit / finger_kp`` past the closed
        limit for the grip to actually saturate here (``TrialParams.close_target``).
    pad_friction : float
        Sliding friction of the pads (MuJoCo takes the max of the two geoms; the object's
        geoms carry none, so this is the pad/object mu used for epsilon). 1.0: rubber on
        dry metal/ceramic/plastic is 0.8-1.2. Contacts stay condim 3 (no torsional friction):
        the stacked MJX collision path (``collision.py``) only handles condim-3 pairs.
    """

    max_opening: float = 0.085
    pad_half_size: tuple = (0.0125, 0.004, 0.02)
    palm_half_size: tuple = (0.025, 0.065, 0.015)
    finger_mass: float = 0.1
    finger_damping: float = 100.0
    finger_kp: float = 2000.0
    finger_armature: float = 0.5
    force_limit: float = 70.0
    pad_friction: float = 1.0

    def __post_init__(self):
        for name in ("max_opening", "finger_mass", "finger_kp", "force_limit", "pad_friction"):
            if not getattr(self, name) > 0:
                raise ValueError(f"GripperParams.{name} must be > 0, got {getattr(self, name)}")
        for name in ("finger_damping", "finger_armature"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("pad_half_size", "palm_half_size"):
            v = getattr(self, name)
            if len(v) != 3 or min(v) <= 0:
                raise ValueError(f"GripperParams.{name} must be 3 positive numbers, got {v}")
        if self.palm_half_size[1] < self.open_width + 2 * self.pad_half_size[1]:
            raise ValueError("palm_half_size[1] must cover the open fingers")

    @property
    def open_width(self) -> float:
        """Per-finger joint position when open (half the opening)."""
        return 0.5 * self.max_opening

    @property
    def palm_center_z(self) -> float:
        return -(self.pad_half_size[2] + self.palm_half_size[2])


#: Presets of real hands (docs/grippers.md gives the sources). The position gain makes the
#: actuator saturate at ``force_limit`` at the protocol's close target (0.035 m past closed),
#: and the damping keeps the default's 1.44 x critical damping on the 0.6 kg effective mass.
GRIPPERS = {
    "default": GripperParams(),
    # Franka Hand: 80 mm stroke, 70 N continuous grip force, 17 x 17 mm fingertip pads.
    "franka": GripperParams(max_opening=0.08, pad_half_size=(0.0085, 0.004, 0.0085)),
    # Robotiq 2F-85: 85 mm stroke, grip force 20-235 N (its maximum here), 22 x 37.5 mm pads.
    "robotiq_2f85": GripperParams(max_opening=0.085, pad_half_size=(0.011, 0.004, 0.01875),
                                  force_limit=235.0, finger_kp=6800.0, finger_damping=185.0),
}


def gripper(name: str) -> GripperParams:
    """The preset ``name`` of :data:`GRIPPERS`."""
    if name not in GRIPPERS:
        raise ValueError(f"unknown gripper {name!r}; presets: {', '.join(GRIPPERS)}")
    return GRIPPERS[name]


def _f(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.atleast_1d(v))


def gripper_xml(p: GripperParams) -> tuple[str, str]:
    """(worldbody fragment, actuator fragment) of the gripper, fixed at the world origin.

    Gripper geoms have contype=1, conaffinity=2; object geoms must have contype=2,
    conaffinity=1, so the gripper collides with the object and nothing collides with itself.
    """
    px, py, pz = p.pad_half_size
    fm = p.finger_mass
    # Box inertia of the finger (only its scale matters for a prismatic joint).
    ii = fm / 3.0 * np.array([py**2 + pz**2, px**2 + pz**2, px**2 + py**2])
    col = 'contype="1" conaffinity="2" condim="3"'
    fingers = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        fingers.append(f"""
      <body name="finger_{side}">
        <joint name="finger_{side}" type="slide" axis="0 {sign:g} 0"
               range="0 {p.open_width:.9g}" damping="{p.finger_damping:.9g}"
               armature="{p.finger_armature:.9g}"/>
        <inertial pos="0 {sign * py:.9g} 0" mass="{fm:.9g}" diaginertia="{_f(ii)}"/>
        <geom name="pad_{side}" type="box" size="{_f(p.pad_half_size)}" pos="0 {sign * py:.9g} 0"
              friction="{p.pad_friction:.9g} 0.005 0.0001" {col} rgba="0.2 0.2 0.2 1"/>
      </body>""")
    body = f"""
    <body name="gripper">
      <geom name="palm" type="box" size="{_f(p.palm_half_size)}" pos="0 0 {p.palm_center_z:.9g}"
            friction="{p.pad_friction:.9g} 0.005 0.0001" {col} rgba="0.5 0.5 0.55 1"/>
      {"".join(fingers)}
    </body>"""
    act = "".join(
        f"""
    <position name="finger_{side}" joint="finger_{side}" kp="{p.finger_kp:.9g}"
              forcerange="{-p.force_limit:.9g} {p.force_limit:.9g}"
              ctrlrange="-0.05 {p.open_width:.9g}"/>"""
        for side in ("left", "right")
    )
    return body, act


def _box_corners(center, half):
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return np.asarray(center, float) + signs * np.asarray(half, float)


def gripper_corners(p: GripperParams) -> np.ndarray:
    """(24, 3) corners of the palm and the open pads in the grasp frame.

    The pads sweep, while closing, inside the convex hull of these corners, so checking them
    against the support plane covers the whole closing motion.
    """
    px, py, pz = p.pad_half_size
    w = p.open_width
    return np.concatenate(
        [
            _box_corners([0, 0, p.palm_center_z], p.palm_half_size),
            _box_corners([0, w + py, 0], p.pad_half_size),
            _box_corners([0, -(w + py), 0], p.pad_half_size),
        ]
    ).astype(np.float32)

"""Every private piece of MJX that jaxgrasp uses, in one place.

MJX's public API cannot do four things the trial needs:

- collide the gripper's boxes with all convex pieces of an object in one vmapped kernel call
  (its collision driver compiles one function per distinct mesh): MJX's box-convex kernel,
  hull and box conversions, the contact frame and its pair/contact grouping are private;
- step with that collision routine in place of its own (``mjx.step`` has no hook):
  :func:`step_with_collision` is ``mjx.step`` for this model class with the collision swapped;
- read and write a data's contacts (kept in the private ``Data._impl``);
- place a body's geoms the way ``mjx.kinematics`` does (``local_to_global``), for pieces that
  are arguments rather than the model's geoms (the C trial's shared contact stage).

What is relied on is pinned by tests: ``tests/physics/test_mjx_internals.py`` (the step equals
``mjx.step``, the contact record, the version check) and ``tests/physics/test_collision.py``
(the stacked collision equals ``mjx.collision``). The names exist from mujoco-mjx 3.3.3
(3.3.0-3.3.2 have no ``Data._impl``); the results are pinned on the installed version.
"""

from importlib.metadata import version

from mujoco import mjx

#: mujoco-mjx versions whose internals this module reads: [3.3.3, 4).
SUPPORTED = ((3, 3, 3), (4,))
SUPPORTED_TEXT = "mujoco-mjx >= 3.3.3, < 4"


def _unsupported(installed, reason):
    return ImportError(
        f"jaxgrasp's physics needs {SUPPORTED_TEXT} (it uses MJX internals, see "
        f"jaxgrasp/physics/_mjx_internals.py); installed mujoco-mjx {installed}: {reason}. "
        "Install a supported one, e.g. pip install 'mujoco-mjx>=3.3.3,<4'."
    )


def check_version(installed: str) -> None:
    """Raise ``ImportError`` naming the supported versions unless ``installed`` is one."""
    release = tuple(int(p) for p in installed.split(".")[:3] if p.isdigit())
    if not SUPPORTED[0] <= release < SUPPORTED[1]:
        raise _unsupported(installed, "outside the supported range")


check_version(version("mujoco-mjx"))
# A missing internal is an ImportError that names the supported versions.
try:
    from mujoco.mjx._src import collision_driver, mesh
    from mujoco.mjx._src.collision_convex import _convex_convex as convex_convex
    from mujoco.mjx._src.collision_types import ConvexInfo, GeomInfo
    from mujoco.mjx._src.math import make_frame
    from mujoco.mjx._src.support import local_to_global

    geom_groups = collision_driver._geom_groups
    contact_groups = collision_driver._contact_groups
    convex_mesh, box_mesh = mesh.convex, mesh.box
except (ImportError, AttributeError) as err:
    raise _unsupported(version("mujoco-mjx"), f"{type(err).__name__}: {err}") from err

__all__ = [
    "ConvexInfo",
    "GeomInfo",
    "SUPPORTED",
    "box_mesh",
    "check_version",
    "contact_groups",
    "contacts",
    "convex_convex",
    "convex_mesh",
    "geom_groups",
    "local_to_global",
    "make_frame",
    "step_with_collision",
    "with_contacts",
]


def contacts(d: mjx.Data):
    """The data's contact record (fields ``dist``, ``pos``, ``frame``, ``geom``, ...)."""
    return d._impl.contact


def with_contacts(d: mjx.Data, contact) -> mjx.Data:
    """``d`` with its contact record replaced (what ``mjx.collision`` writes)."""
    return d.tree_replace({"_impl.contact": contact})


def step_with_collision(m: mjx.Model, d: mjx.Data, collide) -> mjx.Data:
    """``mjx.step`` (Euler, no sensors or cameras) with ``collide`` in place of
    ``mjx.collision``."""
    stages = (
        mjx.kinematics, mjx.com_pos, mjx.tendon, mjx.crb, mjx.tendon_armature, mjx.factor_m,
        collide,
        mjx.make_constraint, mjx.transmission, mjx.fwd_velocity, mjx.fwd_actuation,
        mjx.fwd_acceleration, mjx.solve, mjx.euler,
    )
    for stage in stages:
        d = stage(m, d)
    return d

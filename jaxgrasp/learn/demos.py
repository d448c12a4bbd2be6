"""Simulated demonstrations: the user's demonstrated grasps (paper §4, last paragraph).

The paper picks random points on the object's surface and finds a gripper orientation there by
optimization (Zech et al. 2015). Here, per surface point ``p`` with outward normal ``n``:

- the grasp center (the point between the pads, see ``jaxgrasp.physics.gripper``) is put at
  ``p - depth * n``, inside the material just below the surface;
- the gripper orientation ``q`` minimizes a smooth geometric cost on a surface point cloud:
  approach (grasp-frame ``+z``) along ``-n``; the surface inside the closing region faces the
  pads (normals along the closing axis ``y``: the pads sit antipodal across the local wall);
  no material beyond the open pads, in the pads or in the palm; no gripper corner below the
  support plane. It runs with optax (Adam) on the Riemannian gradient, followed by a
  retraction ``q <- q / |q|`` onto the unit sphere, from several starts (rotations about n);
- the best orientation per point is tried in physics and only successful grasps are kept.

Everything is seeded: the same seed gives the same demonstrations.
"""

import warnings
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp import so3
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.results import Demos, canonical_grasps

__all__ = ["demonstrations", "candidate_poses", "surface_points"]

#: Starts of the orientation search: rotations of the closing axis about the normal.
NUM_STARTS = 4
#: Adam steps and learning rate of the orientation search.
OPT_STEPS = 100
OPT_LR = 0.03
#: Depth of the grasp center below the surface, as a fraction of the pad half length.
DEPTH_FRACTION = 0.6
#: Smoothing length of the soft indicator functions (metres).
SOFT = 0.002
#: Candidate rounds before giving up on finding ``num`` successful demos.
MAX_ROUNDS = 4


def surface_points(mesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` seeded area-uniform surface points and their outward face normals."""
    import trimesh

    points, faces = trimesh.sample.sample_surface(mesh, count, seed=seed)
    normals = np.asarray(mesh.face_normals)[faces]
    return np.asarray(points, np.float32), np.asarray(normals, np.float32)


def _default_gripper():
    from jaxgrasp.physics import GripperParams

    return GripperParams()


def _frame_from_normal(n, angle):
    """A rotation matrix with z = -n and y rotated by ``angle`` about n (numpy, (3, 3))."""
    z = -n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y0 = np.cross(z, helper)
    y0 /= np.linalg.norm(y0)
    x0 = np.cross(y0, z)
    y = np.cos(angle) * y0 + np.sin(angle) * x0
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


def _matrix_to_quaternion(r):
    """(3, 3) rotation -> unit quaternion (w, x, y, z), numerically stable branch choice."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(r).as_quat()
    return np.array([w, x, y, z])


def _box_sdf(p, center, half):
    """Signed distance of points p (..., 3) to an axis-aligned box (negative inside)."""
    d = jnp.abs(p - center) - half
    # sqrt with an epsilon: the plain norm has a NaN gradient at zero.
    outside = jnp.sqrt(jnp.sum(jnp.maximum(d, 0.0) ** 2, axis=-1) + 1e-12)
    inside = jnp.minimum(jnp.max(d, axis=-1), 0.0)
    return outside + inside


def _cost(pose, point, normal, cloud, cloud_normals, support_z, gripper):
    """The orientation cost of one candidate (pure JAX; ``gripper`` is static)."""
    px, py, pz = (float(v) for v in gripper.pad_half_size)
    open_w = float(gripper.open_width)
    palm_c = jnp.array([0.0, 0.0, gripper.palm_center_z], jnp.float32)
    palm_h = jnp.asarray(gripper.palm_half_size, jnp.float32)
    pad_h = jnp.asarray(gripper.pad_half_size, jnp.float32)
    pads = jnp.array([[0.0, open_w + py, 0.0], [0.0, -(open_w + py), 0.0]], jnp.float32)
    corners = jnp.asarray(_gripper_corners(gripper), jnp.float32)

    def soft_pos(x):
        # Squared hinge: exactly zero when clear (sums over many points add no offset).
        return jnp.maximum(x, 0.0) ** 2 / SOFT

    q, shift = pose
    r = so3.to_matrix(q / jnp.linalg.norm(q))
    # The center may slide along the closing axis to straddle the local wall.
    center = point + shift * r[:, 1]
    local = (cloud - center) @ r  # gripper-frame coordinates of the cloud
    local_n = cloud_normals @ r
    approach = 1.0 + jnp.dot(r[:, 2], normal)
    # Material in the closing region (between the pads' x and z extents).
    w = jax.nn.sigmoid((px - jnp.abs(local[:, 0])) / SOFT) * jax.nn.sigmoid(
        (pz - jnp.abs(local[:, 2])) / SOFT)
    facing = jnp.sum(w * (1.0 - local_n[:, 1] ** 2)) / (jnp.sum(w) + 1e-6)
    too_wide = jnp.sum(w * soft_pos(jnp.abs(local[:, 1]) - (open_w - 0.005)))
    hits = soft_pos(-_box_sdf(local, palm_c, palm_h)).sum()
    hits = hits + sum(soft_pos(-_box_sdf(local, c, pad_h)).sum() for c in pads)
    world_corners = center + corners @ r.T
    below = soft_pos(support_z + 0.003 - world_corners[:, 2]).sum()
    slide = (shift / open_w) ** 2
    return approach + 0.5 * facing + 0.1 * slide + 1000.0 * (too_wide + hits + below)


@partial(jax.jit, static_argnames=("gripper",))
def _solve_all(q0, points, normals, cloud, cloud_normals, support_z, gripper):
    """Optimize (N, S) starts ``q0`` at N points; returns quaternions, centers and costs."""
    import optax

    opt = optax.adam(OPT_LR)

    def cost(pose, point, normal):
        return _cost(pose, point, normal, cloud, cloud_normals, support_z, gripper)

    def solve(q, point, normal):
        def step(carry, _):
            pose, opt_state = carry
            g_q, g_s = jax.grad(cost)(pose, point, normal)
            q = pose[0]
            g_q = g_q - jnp.dot(g_q, q) * q  # Riemannian gradient: tangent to the unit sphere
            updates, opt_state = opt.update((g_q, g_s), opt_state, pose)
            q, shift = optax.apply_updates(pose, updates)
            return ((q / jnp.linalg.norm(q), shift), opt_state), None  # retraction onto S^3

        pose = (q, jnp.zeros((), q.dtype))
        (pose, _), _ = jax.lax.scan(step, (pose, opt.init(pose)), None, length=OPT_STEPS)
        q, shift = pose
        return q, point + shift * so3.to_matrix(q)[:, 1], cost(pose, point, normal)

    return jax.vmap(jax.vmap(solve, in_axes=(0, None, None)))(q0, points, normals)


def _gripper_corners(gripper):
    try:
        from jaxgrasp.physics.gripper import gripper_corners

        return gripper_corners(gripper)
    except ImportError:  # pragma: no cover - physics is part of the package
        return np.zeros((1, 3))


def candidate_poses(obj, points, normals, *, gripper=None, cloud_size: int = 768,
                    seed: int = 0) -> np.ndarray:
    """Optimized gripper poses (N, 7) at surface ``points`` with outward ``normals``.

    Parameters
    ----------
    obj : GraspObject
    points, normals : (N, 3) arrays
    gripper : GripperParams, optional
        Gripper geometry (default: the physics default).
    cloud_size : int
        Surface points used by the cost (collision and antipodal terms).
    seed : int
        Seed of the cost's point cloud.

    Returns
    -------
    (N, 7) float32 poses (x, y, z, qw, qx, qy, qz), unit quaternion with qw >= 0.
    """
    gripper = gripper or _default_gripper()
    obj = getattr(obj, "obj", obj)
    points = np.asarray(points, np.float32).reshape(-1, 3)
    normals = np.asarray(normals, np.float32).reshape(-1, 3)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    cloud, cloud_normals = surface_points(obj.mesh, cloud_size, seed + 7919)
    depth = DEPTH_FRACTION * float(gripper.pad_half_size[2])
    centers = points - depth * normals
    angles = np.pi * np.arange(NUM_STARTS) / NUM_STARTS  # y and -y are the same gripper
    q0 = np.array([[_matrix_to_quaternion(_frame_from_normal(n, a)) for a in angles]
                   for n in normals], np.float32)  # (N, S, 4)
    q, c, final = jax.device_get(_solve_all(
        jnp.asarray(q0), jnp.asarray(centers), jnp.asarray(normals), jnp.asarray(cloud),
        jnp.asarray(cloud_normals), jnp.float32(obj.support_z), gripper))
    best = np.argmin(np.where(np.isfinite(final), final, np.inf), axis=1)
    rows = np.arange(len(q))
    q_best, c_best = q[rows, best], c[rows, best]
    return canonical_grasps(np.concatenate([c_best, q_best], axis=1)).astype(np.float32)


def demonstrations(obj_or_scene, *, num: int = 5, seed: int = 0, trial=None, backend="mjx",
                   params: LearnParams | None = None, gripper=None) -> Demos:
    """Simulated demonstrated grasps that succeed in physics.

    Parameters
    ----------
    obj_or_scene : GraspObject, Scene or str
    num : int
        Wanted demonstrations (paper: 5).
    seed : int
        Seeds the surface points and the cost's point cloud; same seed, same demos.
    trial : Simulator or callable, optional
        The object's physics trial (built from the object when None).
    backend : str
    params : LearnParams, optional
        ``demo_candidates``: surface points tried per wanted demo and round.
    gripper : GripperParams, optional
        Default: the scene's gripper, else the physics default.

    Returns
    -------
    Demos
        ``poses`` (m, 7) with m <= num (a warning when fewer than ``num`` succeed) and the
        trial ``results`` of those poses. ValueError when none succeeds.
    """
    from jaxgrasp.learn.sim import as_simulator

    if not isinstance(num, int) or num < 1:
        raise ValueError(f"num must be a positive int, got {num!r}")
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    params = params if params is not None else LearnParams()
    sim = as_simulator(obj_or_scene, backend=backend, trial=trial)
    obj = sim.obj
    if gripper is None:
        gripper = getattr(sim.scene, "gripper", None) or _default_gripper()
    per_round = num * params.demo_candidates
    kept_poses, kept_results = [], []
    for round_ in range(MAX_ROUNDS):
        points, normals = surface_points(obj.mesh, per_round, int(seed) * MAX_ROUNDS + round_)
        poses = candidate_poses(obj, points, normals, gripper=gripper, seed=int(seed))
        res = sim(poses)
        ok = np.flatnonzero(np.asarray(res.outcome) == 0)[: num - len(kept_poses)]
        kept_poses.append(poses[ok])
        kept_results.append(jax.tree.map(lambda x, ok=ok: np.asarray(x)[ok], res))
        if sum(len(p) for p in kept_poses) >= num:
            break
    poses = np.concatenate(kept_poses)
    if len(poses) == 0:
        raise ValueError(f"no demonstrated grasp on {obj.name!r} succeeded in physics after "
                         f"{MAX_ROUNDS * per_round} candidates")
    if len(poses) < num:
        warnings.warn(f"only {len(poses)} of {num} demonstrations on {obj.name!r} succeeded",
                      stacklevel=2)
    results = jax.tree.map(lambda *xs: np.concatenate(xs), *kept_results)
    return Demos(poses.astype(np.float32), results)

"""Rough sketches of the grasp density for Kameleon (paper §4 and experiment 2).

- :func:`random_sketch`: uniformly random gripper poses around the object; it captures no
  property of pi (experiment 2, "random initialization").
- :func:`biased_sketch`: the *proposals* (accepted or not) of a random-walk MH run started at
  the demonstrated grasps (experiment 3, "biased initialization"; paper §4: the chain itself
  holds almost no grasps, its proposals outline pi well enough).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrasp import so3
from jaxgrasp.learn.algorithm import make_algorithm
from jaxgrasp.learn.chains import DEFAULT_CHUNK, run_chains
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.sim import as_simulator

__all__ = ["random_sketch", "biased_sketch", "sketch_bounds", "DEFAULT_REACH"]

#: Gripper reach used when the gripper model is unknown (metres).
DEFAULT_REACH = 0.06


def gripper_reach(scene=None) -> float:
    """How far from the grasp center the gripper's hardware extends (pads and palm), metres.

    Grasp centers farther than this from the object touch nothing, so the random sketch
    inflates the object's bounds by about this much.
    """
    gripper = getattr(scene, "gripper", None)
    if gripper is None:
        return DEFAULT_REACH
    # The grasp center lies between the pads; the pad tips reach half their length ahead.
    return float(0.5 * gripper.max_opening + gripper.pad_half_size[1] * 2)


def sketch_bounds(obj, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) corners of the object's bounding box inflated by ``reach``, not below the table."""
    obj = getattr(obj, "obj", obj)
    lo, hi = np.asarray(obj.mesh.bounds, dtype=np.float64)
    lo, hi = lo - reach, hi + reach
    lo[2] = max(lo[2], float(obj.support_z))
    return lo, hi


def random_sketch(obj, key, n: int, *, reach: float | None = None) -> np.ndarray:
    """``n`` uniformly random gripper poses around ``obj``: (n, 7), unit quaternions, qw >= 0.

    Parameters
    ----------
    obj : GraspObject or Scene
    key : PRNGKey
    n : int
    reach : float, optional
        Inflation of the object's bounding box (metres); from the scene's gripper when
        ``obj`` is a Scene, else :data:`DEFAULT_REACH`.

    Returns
    -------
    (n, 7) float32: positions uniform in the inflated box (above the support plane),
    orientations uniform on SO(3), represented on the qw >= 0 hemisphere.
    """
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"sketch size n must be a positive int, got {n!r}")
    if reach is None:
        reach = gripper_reach(obj if hasattr(obj, "gripper") else None)
    if not (math.isfinite(reach) and reach >= 0):
        raise ValueError(f"reach must be finite and >= 0, got {reach!r}")
    lo, hi = sketch_bounds(obj, reach)
    k_pos, k_ori = jax.random.split(key)
    u = jax.random.uniform(k_pos, (n, 3), dtype=jnp.float32)
    pos = jnp.asarray(lo, jnp.float32) + u * jnp.asarray(hi - lo, jnp.float32)
    q = jax.vmap(so3.random_quaternion)(jax.random.split(k_ori, n)).astype(jnp.float32)
    # One representative per rotation: the modes are reported with qw >= 0 as well.
    q = jnp.where(q[:, :1] < 0, -q, q)
    return np.asarray(jnp.concatenate([pos, q], axis=1))


def biased_sketch(obj, key, n: int, *, demos, params: LearnParams | None = None,
                  chains: int | None = None, trial=None, backend: str = "auto",
                  progress: bool = False) -> np.ndarray:
    """The proposals of a random-walk MH run started at the demos: (n, 7).

    Parameters
    ----------
    obj : GraspObject, Scene or str
    key : PRNGKey
    n : int
        Sketch size; the run takes ``ceil(n / chains)`` steps of ``chains`` chains, rounded up
        to whole chunks (:data:`~jaxgrasp.learn.chains.DEFAULT_CHUNK`).
    demos : Demos or (m, 7) array
        Start points (chain ``c`` starts at demo ``c mod m``).
    params : LearnParams, optional
        Random-walk scales (``position_scale``, ``kappa``) and ``density_floor``.
    chains : int, optional
        Parallel chains (default: the number of demos). Use the main run's chain count so
        that the compiled trial is shared.
    trial : Simulator or callable, optional
        The object's trial (see :class:`~jaxgrasp.learn.sim.Simulator`).
    backend : str
        ``"auto"`` (MuJoCo C on a CPU, MJX on an accelerator), ``"mjx"`` or ``"mujoco"``.

    Returns
    -------
    (n, 7) float32 proposals in step-major order (every proposal, accepted or not).
    """
    params = params if params is not None else LearnParams()
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"sketch size n must be a positive int, got {n!r}")
    starts = np.asarray(getattr(demos, "poses", demos), dtype=np.float32)
    if starts.ndim != 2 or starts.shape[1] != 7 or len(starts) == 0:
        raise ValueError(f"demos must be a non-empty (m, 7) array of poses, got {starts.shape}")
    chains = len(starts) if chains is None else chains
    sim = as_simulator(obj, backend=backend, trial=trial, batch_size=chains)
    # A rough map: one trial per proposal, even when the main run scores perturbed tries.
    alg = make_algorithm("random_walk", sim, params.replace(robust_tries=0))
    # Whole chunks: the run shares the main run's compiled scan, not one of its own for a
    # shorter last chunk (a few proposals more, dropped below).
    steps = -(-n // chains)
    steps = -(-steps // DEFAULT_CHUNK) * DEFAULT_CHUNK
    init = starts[np.arange(chains) % len(starts)]
    hist = run_chains(alg, key, init, steps, progress=progress,
                      desc=f"biased sketch {sim.obj.name}")
    return hist["proposals"].reshape(-1, 7)[:n].astype(np.float32)

"""The sampler of a learning run: the random walk on grasps, or Kameleon + GDMC on R^7."""

import hashlib
import math

import numpy as np

from jaxgrasp import mcmc
from jaxgrasp.learn.metric import GraspMetric
from jaxgrasp.learn.params import LearnParams
from jaxgrasp.learn.sim import GraspTarget, Simulator
from jaxgrasp.objects.symmetry import Symmetry, find_symmetry

__all__ = ["METHODS", "make_algorithm", "object_symmetry", "sampler_metric", "turn_moves",
           "region_covariance"]

METHODS = ("random_walk", "kameleon_darting")
#: Smallest variance of a GDMC region axis: (1 mm)^2 in position, 1e-6 per quaternion component.
REGION_VAR_FLOOR = 1e-6


def make_algorithm(method: str, sim: Simulator, params: LearnParams, *, sketch=None,
                   modes=None, traced: bool = False, symmetry: Symmetry | None = None):
    """The sampler of a run: random walk on grasps, or Kameleon + GDMC on the lifted R^7 target.

    Parameters
    ----------
    method : "random_walk" or "kameleon_darting"
    sim : Simulator
        The object's compiled trial; the target is ``log(epsilon + floor)`` on its trials.
    params : LearnParams
    sketch : (n, 7) array
        Kameleon's rough sketch (kameleon_darting only).
    modes : (m, 7) array
        GDMC modes: the demonstrated grasps (kameleon_darting only).
    traced : bool
        Trace ``sim.trial`` into the sampler instead of reaching it through the host callback
        (:class:`~jaxgrasp.learn.sim.GraspTarget`): with chains sharded over devices, MJX
        rollouts then run on every device. Compiles the physics with the sampler.
    symmetry : Symmetry, optional
        The object's symmetry the turns follow (kameleon_darting); default
        :func:`object_symmetry` of ``sim.obj`` and ``params.symmetry``.
    """
    target = GraspTarget(sim, traced=traced)
    if method == "random_walk":
        logdensity = target.logdensity(**params.density_options())
        return mcmc.random_walk(logdensity, position_scale=params.position_scale,
                                kappa=params.kappa)
    if method == "kameleon_darting":
        if sketch is None or modes is None:
            raise ValueError("kameleon_darting needs a sketch and modes")
        metric = sampler_metric(method, params)
        # Kameleon's Gaussian proposals leave the unit sphere: sample the lifted R^7 target.
        logdensity = metric.wrap(target.logdensity(lifted=True, width=params.lift_width,
                                                   **params.density_options()))
        sketch = metric.to_sampler(sketch)
        sigma, nu = params.kameleon_scales(sketch)
        region_cov = (region_covariance(sketch) if params.region_scale is None
                      else params.region_scale**2 * np.eye(7, dtype=np.float32))
        return mcmc.kameleon_darting(
            logdensity, sketch, metric.to_sampler(modes),
            region_cov=region_cov, p_check=params.p_check, epsilon=params.epsilon,
            gamma=params.gamma, nu=nu, sigma=sigma,
            subsample_size=params.subsample_size, adapt_steps=params.burn_in,
            target_acceptance=params.target_acceptance, uniform_jumps=params.uniform_jumps,
            **turn_moves(params, symmetry if symmetry is not None
                         else object_symmetry(sim.obj, params.symmetry)))
    raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")


def object_symmetry(obj, spec: str = "auto") -> Symmetry:
    """``spec`` as a :class:`Symmetry`: found from ``obj``'s mesh for ``"auto"`` (once per
    object and process), else the user's override (:meth:`Symmetry.parse`)."""
    if spec != "auto":
        return Symmetry.parse(spec)
    # by content: an object without a hash (make_box) by its mesh, never by id (reused)
    key = obj.content_hash or hashlib.sha256(np.ascontiguousarray(
        obj.mesh.vertices, np.float64).tobytes() + np.ascontiguousarray(
        obj.mesh.faces, np.int64).tobytes()).hexdigest()
    if key not in _FOUND:
        _FOUND[key] = find_symmetry(obj)
    return _FOUND[key]


_FOUND: dict = {}


def turn_moves(params: LearnParams, symmetry: Symmetry | None = None) -> dict:
    """The symmetry-move arguments of Kameleon + GDMC, in the shares ``params`` asks for:
    turns about a vertical axis (``symmetry``'s; default the object frame's z axis), pivots
    about the gripper's closing axis, slides along its approach axis (sampler units:
    metres / length_scale) and the object's own symmetries (its n-fold turns and mirror
    planes, ``symmetry_share``; their share goes to the turns where it has none)."""
    if params.axis_moves == 0:
        return {}
    sym = mcmc.symmetry
    symmetry = symmetry or Symmetry("revolution")
    centre = tuple(float(c) / params.length_scale for c in symmetry.centre)
    # A turn about the vertical keeps the grasp's tilt to the table and gravity: it explores
    # whatever the symmetry (an exact map of grasps for a solid of revolution).
    axis = sym.Z_AXIS_PLANES if centre == (0.0, 0.0) else sym.Turn(centre)
    own = []
    if symmetry.kind == "turns":
        own.append(sym.Turn(centre, symmetry.order))
    if symmetry.mirrors and symmetry.kind != "revolution":
        own.append(sym.Mirror(centre, tuple(math.radians(a) for a in symmetry.mirrors)))
    own_share = params.symmetry_share if own else 0.0
    axis_share = 1.0 - params.pivot_share - params.slide_share - own_share
    groups = [(g, w, a) for g, w, a in (
        (axis, axis_share, params.axis_angle),
        (sym.PIVOT_PLANES, params.pivot_share, params.pivot_angle),
        (sym.APPROACH_SLIDE, params.slide_share, params.slide_distance / params.length_scale),
        *((g, own_share / len(own), 1.0) for g in own),  # discrete: a pick from N(0, 1)
    ) if w > 1e-9]  # the shares add up to 1: never empty
    if axis is not sym.Z_AXIS_PLANES and len(groups) > 1 and params.symmetry_share > 1e-9:
        # Never picked (weight 0; the pick's draws unchanged): every object on an offset axis
        # (a mesh's found one) has the same groups, so one compiled sampler serves them all.
        # Objects on the frame's z axis keep theirs: padded, their chains differ in the last bit.
        groups += [(sym.Turn(centre, 2), 0.0, 1.0)] * (2 - len(own))
    p_symmetry = params.axis_moves * params.p_check
    if len(groups) == 1:  # one group: the single-group move (its random stream unchanged)
        return {"symmetry_planes": groups[0][0], "p_symmetry": p_symmetry,
                "symmetry_scale": groups[0][2]}
    return {"symmetry_planes": tuple(g for g, _, _ in groups), "p_symmetry": p_symmetry,
            "symmetry_scale": np.array([a for _, _, a in groups], np.float32),
            "symmetry_weights": np.array([w for _, w, _ in groups], np.float32)}


def sampler_metric(method: str, params: LearnParams) -> GraspMetric:
    """The sampler's coordinates of a run: scaled for Kameleon + GDMC, raw for the walk."""
    return GraspMetric(params.length_scale if method == "kameleon_darting" else 1.0)


def region_covariance(sketch, floor: float = REGION_VAR_FLOOR) -> np.ndarray:
    """GDMC's shared region covariance: the sketch covariance, eigenvalues floored at ``floor``.

    The paper uses the covariance of the Markov chain (the sketch). A short chain history (a
    small transfer source) can be degenerate in some directions; flooring the spectrum keeps the
    ellipsoids proper and changes nothing for a well-spread sketch.
    """
    x = np.asarray(sketch, np.float64)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"the sketch must be (n >= 2, d), got shape {x.shape}")
    cov = np.cov(x, rowvar=False)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    return ((vec * np.maximum(lam, floor)) @ vec.T).astype(np.float32)

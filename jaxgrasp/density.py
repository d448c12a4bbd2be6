"""The grasp target density: ``log π(g) = log(epsilon(g) + floor)`` from one physics trial.

``π(g) ∝ epsilon(g)`` for grasps whose trial made contact (``SUCCESS`` or ``SLIPPED``), zero for
``COLLISION`` and ``MISS`` (``docs/design.md``). The floor keeps the log finite so
Metropolis-Hastings stays defined where the quality is zero: there every state has the same
density ``log(floor)``, every proposal inside the zero region is accepted and the chain is a random
walk, as in the paper, until it finds contact; leaving a contact state of quality ``eps`` for
a failure is accepted with probability ``floor / (eps + floor)``.

Choosing the floor: the chain targets ``π_floor ∝ epsilon + floor``, whose mass in the failure
region is ``floor * V_fail / (floor * V_fail + ∫ epsilon)``. Epsilon of real grasps is
``~1e-2 .. 3e-1`` (box grasps: 0.06-0.25), and failures fill most of the grasp space, so the
floor must sit far below typical epsilons; ``1e-4`` (the default here and in the paper's
``LearnParams.paper()``) keeps the ratio good/failed at ~10^3. The learning workflows default
to ``1e-6``: from a grasp of epsilon ~0.05 a failing proposal is then accepted with
probability ~2e-5 instead of ~2e-3, so chains explore grasps instead of a flat failure
region (docs/design.md).

The R^7 target for Kameleon (``docs/design.md``) is the composition
``jaxgrasp.mcmc.lift_quaternion(grasp_logdensity(trial, floor=...), width=...)``: the lift lives
in the sampler package (it knows nothing of physics) and this module never imports the
sampler, so there is exactly one implementation of each piece.
"""

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import jax.numpy as jnp

from jaxgrasp import so3
from jaxgrasp._wrapper import register_wrapper
from jaxgrasp.physics.protocol import Outcome

__all__ = ["DEFAULT_FLOOR", "ESTIMATES", "GraspLogDensity", "grasp_logdensity"]

#: Default density floor (see the module docstring).
DEFAULT_FLOOR = 1e-4
#: What a density's perturbed tries estimate (:class:`GraspLogDensity`).
ESTIMATES = ("mean", "all_held")


@partial(register_wrapper, child="trial")
@dataclass(frozen=True)
class GraspLogDensity:
    """``grasp (7,) -> (log π, aux)``; hashable by value so samplers rebuilt around an equal
    density reuse their compiled code.

    Attributes
    ----------
    trial : callable ``(B, 7) -> TrialResult``
        A pure, jittable trial (``jaxgrasp.physics.make_trial``) or anything returning the
        fields ``outcome``, ``epsilon``, ``unstable`` with leading dimension B.
    floor : float
        Added to epsilon before the log.
    slip_weight : float
        Factor on the epsilon of SLIPPED trials: 1 is the paper's ``π ∝ epsilon`` for every
        trial that made contact; below 1 the target prefers grasps that hold.
    power : float
        Exponent on epsilon, in (0, 1]: ``π ∝ w epsilon^power + floor``. 1 is the paper's;
        below 1 the target is flatter over the grasps that make contact.
    tries : int
        Perturbed tries per evaluation (0: the paper's single trial). With ``tries = k`` the
        grasp and k copies under a robot's pose error are simulated in one batch and their
        qualities averaged: the target becomes the quality smoothed over the pose error (an
        atom at zero error of weight 1 / (k + 1)), which only grasps that hold nearby reach.
    position_sd, angle_sd : float
        The pose error of the perturbed tries: metres per axis, and degrees of a turn about a
        uniformly random axis (``|N(0, angle_sd)|``), as ``jg.learn.PoseNoise``.
    estimate : {"mean", "all_held"}
        What the tries estimate (both unbiased and non-negative, so the chain is exact):
        ``"mean"``, the quality smoothed over the pose error (above); ``"all_held"``, the
        grasp's own quality times ``1[every perturbed try held]``, an estimate of
        ``q(g) P(held | g)^k`` that prefers grasps holding under the error far more sharply.
    slip_scale : float
        Metres; above 0 the quality is also weighted by ``exp(-displacement / slip_scale)``,
        the object's largest displacement relative to the gripper during the hold: grasps
        the object barely moves in are the ones that still hold when the pose is off
        (0: the paper's density).
    """

    trial: Callable
    floor: float = DEFAULT_FLOOR
    slip_weight: float = 1.0
    power: float = 1.0
    tries: int = 0
    position_sd: float = 0.003
    angle_sd: float = 3.0
    estimate: str = "mean"
    slip_scale: float = 0.0

    def __post_init__(self):
        floor = float(self.floor)
        if not (floor > 0 and math.isfinite(floor)):
            raise ValueError(f"floor must be positive and finite, got {self.floor}")
        object.__setattr__(self, "floor", floor)
        w = float(self.slip_weight)
        if not (0.0 <= w <= 1.0):
            raise ValueError(f"slip_weight must lie in [0, 1], got {self.slip_weight}")
        object.__setattr__(self, "slip_weight", w)
        beta = float(self.power)
        if not (0.0 < beta <= 1.0):
            raise ValueError(f"power must lie in (0, 1], got {self.power}")
        object.__setattr__(self, "power", beta)
        scale = float(self.slip_scale)
        if not (scale >= 0 and math.isfinite(scale)):
            raise ValueError(f"slip_scale must be finite and >= 0, got {self.slip_scale}")
        object.__setattr__(self, "slip_scale", scale)
        if self.estimate not in ESTIMATES:
            raise ValueError(f"estimate must be one of {ESTIMATES}, got {self.estimate!r}")
        if not (isinstance(self.tries, int) and self.tries >= 0):
            raise ValueError(f"tries must be an int >= 0, got {self.tries!r}")
        for name in ("position_sd", "angle_sd"):
            value = float(getattr(self, name))
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)}")
            object.__setattr__(self, name, value)
        if not callable(self.trial):
            raise ValueError(f"trial must be callable, got {type(self.trial).__name__}")

    @property
    def stochastic(self) -> bool:
        """True with perturbed ``tries``: a pseudo-marginal target ``(grasp, key) -> ...``."""
        return self.tries > 0

    def __call__(self, grasp, key=None):
        """Log-density of one grasp and the outcome of its trial.

        Parameters
        ----------
        grasp : (7,) array
            ``(x, y, z, qw, qx, qy, qz)`` in the object frame (quaternion normalized by the
            trial). Under ``jax.vmap`` over chains the trial sees the whole batch at once.
        key : PRNGKey
            The pose noise of the perturbed tries (required when ``tries > 0``; the samplers
            pass it, see :mod:`jaxgrasp.mcmc.mh`).

        Returns
        -------
        logp : float32 scalar
            ``log(q + floor)``, ``q = w epsilon^power`` after contact (0 for collision/miss and
            for unstable or non-finite trials); with ``tries`` the mean of ``q`` over the grasp
            and its perturbed poses. Always finite.
        aux : dict
            ``{"outcome": int32, "epsilon": float32}`` of the grasp itself (epsilon as used in
            logp, 0 for failures), for counting outcomes per proposal without a second rollout;
            with ``tries`` also ``"held"``: how many perturbed tries held (``SUCCESS``).
        """
        grasp = jnp.asarray(grasp, jnp.float32)
        if grasp.shape != (7,):
            raise ValueError(f"grasp must have shape (7,), got {grasp.shape}")
        if not self.tries:
            outcome, eps, quality = self._score(self.trial(grasp[None]))
            return jnp.log(quality[0] + jnp.float32(self.floor)), {"outcome": outcome[0],
                                                                    "epsilon": eps[0]}
        if key is None:
            raise ValueError("a density with perturbed tries needs a key for its pose noise")
        noisy = so3.perturbed_poses(key, grasp, self.tries, self.position_sd,
                                    math.radians(self.angle_sd))
        outcome, eps, quality = self._score(self.trial(jnp.concatenate([grasp[None], noisy])))
        held = jnp.sum(outcome[1:] == Outcome.SUCCESS).astype(jnp.int32)
        if self.estimate == "mean":
            # The grasp and its noisy copies, averaged: unbiased for the target smoothed by a
            # noise law with an atom at zero (pseudo-marginal MH).
            q = jnp.mean(quality)
        else:  # independent tries: E[prod 1[held_i]] = P(held)^k
            q = jnp.where(held == self.tries, quality[0], 0.0)
        logp = jnp.log(q + jnp.float32(self.floor))
        return logp, {"outcome": outcome[0], "epsilon": eps[0], "held": held}

    def _score(self, res):
        """Per trial row: ``(outcome int32, epsilon as used, q = w epsilon^power)``."""
        outcome = jnp.asarray(res.outcome).astype(jnp.int32)
        eps = jnp.asarray(res.epsilon, jnp.float32)
        unstable = jnp.asarray(res.unstable, bool)
        contact = (outcome == Outcome.SUCCESS) | (outcome == Outcome.SLIPPED)
        # A NaN/negative epsilon or an unstable rollout counts as a failed trial.
        ok = contact & ~unstable & jnp.isfinite(eps)
        eps = jnp.where(ok, jnp.maximum(eps, 0.0), 0.0)
        weight = jnp.where(outcome == Outcome.SLIPPED, jnp.float32(self.slip_weight), 1.0)
        # epsilon ** power (0 stays 0): power < 1 flattens the target over the holding grasps
        tempered = (eps if self.power == 1.0
                    else jnp.where(eps > 0, jnp.where(eps > 0, eps, 1.0) ** self.power, 0.0))
        if self.slip_scale > 0:  # a still object holds under pose error more often
            disp = jnp.asarray(res.displacement, jnp.float32)
            weight = weight * jnp.exp(-jnp.where(ok, disp, 0.0) / jnp.float32(self.slip_scale))
        return outcome, eps, weight * tempered


def grasp_logdensity(trial, *, floor: float = DEFAULT_FLOOR, slip_weight: float = 1.0,
                     power: float = 1.0, tries: int = 0, position_sd: float = 0.003,
                     angle_sd: float = 3.0, estimate: str = "mean",
                     slip_scale: float = 0.0) -> GraspLogDensity:
    """The grasp target ``log π(g) = log(epsilon(g) + floor)`` on one physics trial.

    Parameters
    ----------
    trial : callable ``(B, 7) -> TrialResult``
        From ``jaxgrasp.physics.make_trial`` (pure, jittable); called as ``trial(g[None])``.
    floor : float
        Positive density floor (see the module docstring for the choice).
    slip_weight : float
        Weight of a slipped grasp's epsilon (1: the paper's density).
    power : float
        Exponent in (0, 1] on epsilon: ``pi ∝ w epsilon^power + floor`` (1: the paper's).
    tries, position_sd, angle_sd, estimate
        Perturbed tries per evaluation, their pose error and what they estimate
        (:class:`GraspLogDensity`); 0 tries is the paper's density.
    slip_scale : float
        Weight ``exp(-displacement / slip_scale)`` on the quality (0: none, the paper's).

    Returns
    -------
    GraspLogDensity
        ``grasp (7,) -> (logp, {"outcome", "epsilon"})``, jittable; ``jax.vmap`` over chains
        gives one batched rollout. For the R^7 (Kameleon) target compose with
        ``jaxgrasp.mcmc.lift_quaternion``.

    Examples
    --------
    >>> logdensity = grasp_logdensity(jg.physics.make_trial(scene), floor=1e-4)
    >>> logp, aux = jax.vmap(logdensity)(grasps)      # (C,), {"outcome": (C,), ...}
    """
    return GraspLogDensity(trial, floor, slip_weight, power, tries, position_sd, angle_sd,
                           estimate, slip_scale)

"""What :func:`jaxgrasp.learn.robustness` measures: the pose-noise model (:class:`PoseNoise`)
and the hold counts of grasps under it (:class:`Robustness`).

Plain numpy and no physics, so a saved run (``LearnResult``) can carry a measurement; the
measurement itself is :mod:`jaxgrasp.learn.evaluate.robustness`.
"""

from typing import NamedTuple

import numpy as np

from jaxgrasp.learn.evaluate.distinct import canonical_grasps, is_new

__all__ = ["DEFAULT_NOISE", "PoseNoise", "Robustness", "pose_noise"]

#: Two measured grasps are the same row when they differ by less than this (m, quaternion).
_SAME_ROW = 1e-6


class PoseNoise(NamedTuple):
    """The pose error of the robot that executes the grasps.

    position_sd : metres, per axis of the object frame (3 mm).
    angle_sd : degrees; the orientation turns about a uniformly random axis by
        ``|N(0, angle_sd)|`` (3°).
    tries : perturbed trials per grasp (10).
    min_share : a grasp is robust when it held in at least this share of its tries (0.8).
    """

    position_sd: float = 0.003
    angle_sd: float = 3.0
    tries: int = 10
    min_share: float = 0.8

    @property
    def min_held(self) -> int:
        """Tries a robust grasp held at least: ``ceil(min_share * tries)``."""
        return int(np.ceil(self.min_share * self.tries - 1e-9))

    @property
    def label(self) -> str:
        """The error in words, e.g. ``"3 mm / 3°"``."""
        return f"{self.position_sd * 1000:g} mm / {self.angle_sd:g}°"

    def check(self) -> "PoseNoise":
        for name in ("position_sd", "angle_sd"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not isinstance(self.tries, int | np.integer) or self.tries < 1:
            raise ValueError(f"tries must be a positive int, got {self.tries!r}")
        if not (isinstance(self.min_share, int | float) and 0 < self.min_share <= 1):
            raise ValueError(f"min_share must lie in (0, 1], got {self.min_share!r}")
        return self


#: 3 mm / 3°, 10 tries, robust when held in 8 of them.
DEFAULT_NOISE = PoseNoise()


def pose_noise(text: str, tries: int) -> PoseNoise:
    """The noise of a command line's ``--pose-error MM,DEG`` with ``tries`` per grasp."""
    try:
        mm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--pose-error must be MM,DEG (e.g. 3,3), got {text!r}") from None
    return PoseNoise(position_sd=mm / 1000.0, angle_sd=deg, tries=tries).check()


class Robustness(NamedTuple):
    """Hold counts of grasps under a pose-noise model (:func:`jaxgrasp.learn.robustness`).

    grasps : (N, 7) the grasps tried (unit quaternions).
    held : (N,) int, perturbed tries that held (``SUCCESS``).
    noise : the PoseNoise used.
    tried : (N,) int or None, perturbed tries made per grasp; None: ``noise.tries`` each.
        A measurement that stops early (``robustness(..., stop_early=True)``) tries a grasp
        only until it can no longer be robust.
    """

    grasps: np.ndarray
    held: np.ndarray
    noise: PoseNoise
    tried: np.ndarray | None = None

    @property
    def tries_made(self) -> np.ndarray:
        """(N,) int: perturbed tries made per grasp."""
        if self.tried is None:
            return np.full(len(self.held), int(self.noise.tries), np.int64)
        return np.asarray(self.tried, np.int64)

    @property
    def probability(self) -> np.ndarray:
        """(N,) estimated hold probability: held / tries made."""
        return self.held / np.maximum(self.tries_made, 1)

    @property
    def robust(self) -> np.ndarray:
        """(N,) bool: held in at least ``min_share`` of the tries."""
        return self.held >= self.noise.min_held

    @property
    def robust_share(self) -> float:
        """Share of the grasps that are robust (NaN for no grasps)."""
        return float(self.robust.mean()) if len(self.held) else float("nan")

    def robust_new(self, demos) -> np.ndarray:
        """(N,) bool: robust and not the same grasp as any of ``demos`` (1 cm / 10°, as
        ``LearnResult.learned.new``): the grasps counted as *distinct robust new*."""
        demos = np.asarray(demos, np.float64).reshape(-1, 7)
        if len(self.held) == 0 or len(demos) == 0:
            return self.robust.copy()
        return self.robust & is_new(self.grasps, demos)

    def most_robust_first(self) -> tuple[np.ndarray, "Robustness"]:
        """``(order, this measurement in that order)``, the most robust grasp first (equal
        probabilities keep their order)."""
        order = np.argsort(-self.probability, kind="stable")
        tried = None if self.tried is None else np.asarray(self.tried)[order]
        return order, Robustness(self.grasps[order], self.held[order], self.noise, tried)

    def held_of(self, grasps) -> np.ndarray:
        """(M,) float: the tries held by each of ``grasps`` that this measured (the same pose,
        ``q`` or ``-q``, in any order); NaN where it was not measured."""
        return self._lookup(self.held, grasps)

    def tried_of(self, grasps) -> np.ndarray:
        """(M,) float: the tries made for each of ``grasps`` (as :meth:`held_of`)."""
        return self._lookup(self.tries_made, grasps)

    def _lookup(self, values, grasps) -> np.ndarray:
        # why: scipy.spatial is a heavy import that only this look-up needs.
        from scipy.spatial import cKDTree

        want = canonical_grasps(grasps)
        out = np.full(len(want), np.nan)
        if len(want) == 0 or len(self.held) == 0:
            return out
        dist, idx = cKDTree(canonical_grasps(self.grasps)).query(
            want, distance_upper_bound=_SAME_ROW)
        hit = np.isfinite(dist)
        out[hit] = np.asarray(values)[idx[hit]]
        return out

    @property
    def num_trials(self) -> int:
        """Physics trials this measurement cost."""
        return int(self.tries_made.sum())

    def summary(self) -> dict:
        return {"grasps": int(len(self.held)), "robust": int(self.robust.sum()),
                "robust_share": self.robust_share,
                "mean_hold_probability": float(self.probability.mean()) if len(self.held)
                else float("nan"), "trials": self.num_trials, **self.noise._asdict()}

"""Chain diagnostics on the host (numpy): acceptance, and ESS, R-hat and MCSE from ArviZ.

Sample arrays are laid out as :func:`jaxgrasp.mcmc.sample` returns them: ``(num_steps, C, ...)``.
ESS (bulk), R-hat (rank-normalized split R-hat) and MCSE of the mean are ``arviz-stats``'
(Vehtari et al. 2021). One rule is ours: chains that never move carry no information about the
target beyond their start points, so a coordinate on which every chain is constant has ESS 0
(ArviZ reports T * C), MCSE inf (NaN when all chains sit at the same value) and R-hat NaN.
"""

import numpy as np
from arviz_stats.base import array_stats

__all__ = [
    "acceptance_rate",
    "effective_sample_size",
    "potential_scale_reduction",
    "mcse_mean",
]


def acceptance_rate(infos, *, burn_in: int = 0) -> float:
    """Fraction of accepted proposals over all steps (after ``burn_in``) and chains."""
    return float(np.mean(np.asarray(infos.is_accepted)[burn_in:]))


def _samples(samples, min_steps: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """``(x (T, C, ...) float64, stuck)``: ``stuck`` marks coordinates no chain moves on."""
    x = np.asarray(samples, np.float64)
    if x.ndim < 2 or x.shape[0] < min_steps:
        raise ValueError(f"samples must be (T >= {min_steps}, C, ...), got shape {x.shape}")
    return x, ~np.ptp(x, axis=0).any(axis=0)


def _per_coordinate(fn, x: np.ndarray, stuck: np.ndarray, value_if_stuck: float, **kw):
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.asarray(fn(x, chain_axis=1, draw_axis=0, **kw), np.float64)
    return np.where(stuck, value_if_stuck, out)


def effective_sample_size(samples) -> np.ndarray:
    """Bulk ESS of each coordinate: samples (T, C, ...) -> shape ``samples.shape[2:]``;
    0 where no chain ever moves."""
    x, stuck = _samples(samples)
    return _per_coordinate(array_stats.ess, x, stuck, 0.0, method="bulk")


def potential_scale_reduction(samples) -> np.ndarray:
    """Rank-normalized split R-hat of each coordinate; NaN where no chain ever moves."""
    x, stuck = _samples(samples, min_steps=4)
    return _per_coordinate(array_stats.rhat, x, stuck, np.nan, method="rank")


def mcse_mean(samples) -> np.ndarray:
    """Monte Carlo standard error of the mean per coordinate (inf where no chain moves, NaN
    when every sample is also equal)."""
    x, stuck = _samples(samples)
    spread = np.where(x.reshape(-1, *x.shape[2:]).std(axis=0) > 0, np.inf, np.nan)
    return np.where(stuck, spread, _per_coordinate(array_stats.mcse, x, stuck, 0.0,
                                                   method="mean"))

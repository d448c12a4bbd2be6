"""Chain diagnostics on the host (numpy): acceptance, ESS, split R-hat, MCSE.

Sample arrays are laid out as :func:`jaxgrasp.mcmc.sample` returns them: ``(num_steps, C, ...)``.
ESS and R-hat follow Vehtari et al. (2021) / Stan (rank-normalization left out).

Chains that never move carry no information about the target beyond their start points: a
coordinate on which every chain is constant has ESS 0 (its MCSE is then inf, or NaN when all
chains sit at the same value) and R-hat NaN.
"""

import numpy as np

__all__ = [
    "acceptance_rate",
    "effective_sample_size",
    "potential_scale_reduction",
    "mcse_mean",
]


def acceptance_rate(infos, *, burn_in: int = 0) -> float:
    """Fraction of accepted proposals over all steps (after ``burn_in``) and chains."""
    return float(np.mean(np.asarray(infos.is_accepted)[burn_in:]))


def _autocovariance(x: np.ndarray) -> np.ndarray:
    """Autocovariance along axis 0 via FFT, for every chain (axis 1): (T, C)."""
    n = x.shape[0]
    centered = x - x.mean(axis=0)
    size = 2 ** int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(centered, n=size, axis=0)
    return np.fft.irfft(f * np.conj(f), n=size, axis=0)[:n] / n


def effective_sample_size(samples) -> np.ndarray:
    """Multi-chain ESS of each coordinate (Geyer's initial monotone sequence).

    samples : (T, C) or (T, C, ...) -> ESS with shape ``samples.shape[2:]``. A coordinate on
    which no chain ever moves has ESS 0 ("no information"), not T * C.
    """
    x = np.asarray(samples, np.float64)
    if x.ndim < 2:
        raise ValueError(f"samples must be (T, C, ...), got shape {x.shape}")
    t, c = x.shape[:2]
    flat = x.reshape(t, c, -1)
    out = np.empty(flat.shape[2])
    for k in range(flat.shape[2]):
        chains = flat[:, :, k]
        if not np.ptp(chains, axis=0).any():  # no chain ever moves (exactly constant)
            out[k] = 0.0
            continue
        acov = _autocovariance(chains)
        chain_var = acov[0] * t / max(t - 1, 1)
        within = chain_var.mean()
        between_plus = within * (t - 1) / t + (np.var(chains.mean(axis=0), ddof=1) if c > 1 else 0)
        if between_plus <= 0:  # spread below float resolution: no information either
            out[k] = 0.0
            continue
        rho = 1.0 - (within - acov.mean(axis=1)) / between_plus
        rho[0] = 1.0
        # Geyer: sum pairs while positive, enforce monotone decrease
        pairs = rho[: (t // 2) * 2].reshape(-1, 2).sum(axis=1)
        positive = np.cumprod(pairs > 0).astype(bool)
        pairs = np.minimum.accumulate(pairs[positive]) if positive.any() else pairs[:1]
        tau = -1.0 + 2.0 * pairs.sum()
        out[k] = t * c / max(tau, 1.0 / np.log10(max(t * c, 10)))
    return out.reshape(x.shape[2:])


def potential_scale_reduction(samples) -> np.ndarray:
    """Split R-hat of each coordinate: samples (T, C, ...) -> shape ``samples.shape[2:]``."""
    x = np.asarray(samples, np.float64)
    t = x.shape[0] // 2
    if t < 2:
        raise ValueError("need at least 4 steps for split R-hat")
    split = np.concatenate([x[:t], x[t : 2 * t]], axis=1)
    within = split.var(axis=0, ddof=1).mean(axis=0)
    between = t * split.mean(axis=0).var(axis=0, ddof=1)
    var_plus = (t - 1) / t * within + between / t
    return np.sqrt(var_plus / np.where(within > 0, within, np.nan))


def mcse_mean(samples) -> np.ndarray:
    """Monte Carlo standard error of the mean: ``sd / sqrt(ESS)``, per coordinate (inf, or
    NaN when every sample is equal, on a coordinate where no chain moves)."""
    x = np.asarray(samples, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (x.reshape(-1, *x.shape[2:]).std(axis=0, ddof=1)
                / np.sqrt(effective_sample_size(x)))

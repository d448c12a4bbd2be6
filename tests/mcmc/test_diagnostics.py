"""Chain diagnostics on chains that never move: no information, ESS 0 (was T * C)."""

import numpy as np
import pytest

from jaxgrasp.mcmc import diagnostics


@pytest.mark.parametrize("values", [
    np.full(4, 0.1),                    # every chain stuck at the same value
    np.array([0.1, -2.0, 3.5, 7.0]),    # each chain stuck at its own start point
])
def test_constant_chains_have_zero_ess(values):
    t = 200
    x = np.broadcast_to(values, (t, len(values))).astype(np.float32)
    assert diagnostics.effective_sample_size(x) == 0.0
    assert np.isnan(diagnostics.potential_scale_reduction(x))
    assert not np.isfinite(diagnostics.mcse_mean(x))


def test_only_the_stuck_coordinate_has_zero_ess():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 4, 3))
    x[:, :, 1] = 0.25  # one coordinate never moves
    ess = diagnostics.effective_sample_size(x)
    assert ess.shape == (3,) and ess[1] == 0.0
    assert ess[0] == pytest.approx(2000, rel=0.2) and ess[2] == pytest.approx(2000, rel=0.2)


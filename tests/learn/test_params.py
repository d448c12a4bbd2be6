import math

import pytest

import jaxgrasp as jg


def test_table_one_defaults():
    p = jg.learn.LearnParams.paper()
    assert (p.iterations, p.burn_in, p.subsample_size, p.num_demos) == (1000, 100, 100, 5)
    assert p.gamma == 1e-4 and p.p_check == 0.6 and p.epsilon == 0.7
    assert math.isclose(p.nu, 2.38 / math.sqrt(6))
    assert p.num_steps == 1100
    # the paper's sampler: raw coordinates, fixed scales, sketch regions, epsilon density
    assert p.length_scale == 1.0 and p.target_acceptance is None and p.slip_weight == 1.0
    assert p.region_scale is None and not p.uniform_jumps and p.density_floor == 1e-4
    assert p.axis_moves == 0.0 and p.pivot_share == 0.0 and p.epsilon_power == 1.0
    assert p.slip_scale == 0.0 and p.robust_tries == 0 and p.trials_per_proposal == 1


def test_defaults_keep_the_protocol_and_change_only_the_exploration_levers():
    d, p = jg.learn.LearnParams(), jg.learn.LearnParams.paper()
    assert d.num_steps == p.num_steps and d.subsample_size == p.subsample_size
    changed = {k for k, v in d.to_dict().items() if p.to_dict()[k] != v}
    assert changed == {"gamma", "p_check", "density_floor", "length_scale",
                       "target_acceptance", "slip_weight", "axis_moves", "pivot_share",
                       "slip_scale", "symmetry_share"}


@pytest.mark.parametrize(
    "bad",
    [dict(iterations=0), dict(burn_in=-1), dict(gamma=0.0), dict(nu=float("nan")),
     dict(p_check=1.5), dict(epsilon=-0.7), dict(num_demos=0), dict(position_scale=0),
     dict(kappa=-1.0), dict(iterations=10.5), dict(sketch_size=50, subsample_size=100),
     dict(density_floor=0.0), dict(iterations=True), dict(robust_tries=-1),
     dict(robust_tries=1.5), dict(slip_scale=-0.001), dict(robust_estimate="median"),
     dict(robust_angle_sd=float("inf")), dict(symmetry_share=0.6), dict(symmetry="spiral")],
)
def test_bad_params_raise(bad):
    with pytest.raises(ValueError, match="LearnParams"):
        jg.learn.LearnParams(**bad)


def test_round_trip_and_unknown_fields():
    p = jg.learn.LearnParams(iterations=7, kappa=12.0)
    assert jg.learn.LearnParams.from_dict(p.to_dict()) == p
    with pytest.raises(ValueError, match="unknown"):
        jg.learn.LearnParams.from_dict({**p.to_dict(), "temperature": 1.0})


def test_kameleon_scales_conventions():
    import numpy as np

    sketch = np.random.default_rng(0).normal(size=(200, 7))
    lit = jg.learn.LearnParams(nu_convention="literal", subsample_size=100)
    grad = jg.learn.LearnParams(subsample_size=100)
    s_lit, nu_lit = lit.kameleon_scales(sketch)
    s_grad, nu_grad = grad.kameleon_scales(sketch)
    assert s_lit == s_grad and nu_lit == lit.nu
    # M = 2 eta grad k with eta = sigma^2 / 2, averaged over the n subsample columns
    assert math.isclose(nu_grad, grad.nu * s_grad**2 / (2 * math.sqrt(100)))
    fixed = jg.learn.LearnParams(kernel_sigma=3.0).kameleon_scales(sketch)
    assert fixed[0] == 3.0
    with pytest.raises(ValueError, match="nu_convention"):
        jg.learn.LearnParams(nu_convention="eta")

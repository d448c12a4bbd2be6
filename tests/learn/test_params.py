import math

import pytest

import jaxgrasp as jg


def test_table_one_defaults():
    p = jg.learn.LearnParams()
    assert (p.iterations, p.burn_in, p.subsample_size, p.num_demos) == (1000, 100, 100, 5)
    assert p.gamma == 1e-4 and p.p_check == 0.6 and p.epsilon == 0.7
    assert math.isclose(p.nu, 2.38 / math.sqrt(6))
    assert p.num_steps == 1100


@pytest.mark.parametrize(
    "bad",
    [dict(iterations=0), dict(burn_in=-1), dict(gamma=0.0), dict(nu=float("nan")),
     dict(p_check=1.5), dict(epsilon=-0.7), dict(num_demos=0), dict(position_scale=0),
     dict(kappa=-1.0), dict(iterations=10.5), dict(sketch_size=50, subsample_size=100),
     dict(density_floor=0.0), dict(iterations=True)],
)
def test_bad_params_raise(bad):
    with pytest.raises(ValueError, match="LearnParams"):
        jg.learn.LearnParams(**bad)


def test_round_trip_and_unknown_fields():
    p = jg.learn.LearnParams(iterations=7, kappa=12.0)
    assert jg.learn.LearnParams.from_dict(p.to_dict()) == p
    with pytest.raises(ValueError, match="unknown"):
        jg.learn.LearnParams.from_dict({**p.to_dict(), "temperature": 1.0})

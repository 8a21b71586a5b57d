"""A parameter may have a prior of its own (a stiffness beside a modulus)."""

from __future__ import annotations

import numpy as np
import pytest

from idbench import ParameterSpec
from idbench.plan.config import ConfigError
from idbench.plan.validity import check_prior


def spec(priors=()):
    return ParameterSpec(
        ("E", "k"), (1.0, 10.0), (1e5, 1e8), default=(4000.0, 1e4), priors=priors
    )


def test_the_comparison_prior_is_every_other_parameters():
    s = spec((("k", 5e3, 5e3),))
    p = s.prior(2000.0, 2000.0)
    assert p.mean == (2000.0, 5e3) and p.std == (2000.0, 5e3)
    plain = spec().prior(2000.0, 1000.0)
    assert plain.mean == (2000.0, 2000.0) and plain.std == (1000.0, 1000.0)


def test_an_own_prior_is_checked_against_the_bounds():
    check_prior(spec((("k", 5e3, 5e3),)), (2000.0, 2000.0), "m")
    # the comparison's mean 5 is below k's lower bound, but k has its own
    check_prior(
        ParameterSpec(("E", "k"), (1.0, 10.0), (1e5, 1e8), priors=(("k", 50.0, 1.0),)),
        (5.0, 1.0),
        "m",
    )
    with pytest.raises(ConfigError, match="outside the parameter bounds"):
        check_prior(spec((("k", 1.0, 1.0),)), (2000.0, 2000.0), "m")


@pytest.mark.parametrize(
    "priors", [(("q", 1.0, 1.0),), (("k", 1.0, 0.0),), (("k", np.nan, 1.0),)]
)
def test_bad_own_priors_are_refused(priors):
    with pytest.raises(ValueError, match="prior of"):
        spec(priors)

"""calib.special against scipy.special (the reference it replaces on the commands' path): the
chi-square tail down to 1e-290 and the quantiles the workspace bound uses."""

import numpy as np
import pytest
import scipy.special

from calib import special


@pytest.mark.parametrize("a", [0.5, 1.0, 2.7, 10.0, 200.0, 5000.0, 20000.0])
def test_incomplete_gamma_matches_scipy(a):
    pairs = ((special.gammaincc, scipy.special.gammaincc), (special.gammainc, scipy.special.gammainc))
    for x in np.geomspace(1e-3, 1e5, 80):
        for ours, theirs in pairs:
            expected = theirs(a, x)
            if expected > 1e-290:
                assert ours(a, x) == pytest.approx(expected, rel=1e-9, abs=0), (ours.__name__, a, x)
            else:
                assert ours(a, x) < 1e-280


@pytest.mark.parametrize("a", [0.5, 1.0, 1.5, 4.0, 37.5, 1000.0])
@pytest.mark.parametrize("p", [1e-10, 0.05, 0.5, 0.95, 0.999999])
def test_the_inverse_matches_scipy(a, p):
    assert special.gammaincinv(a, p) == pytest.approx(scipy.special.gammaincinv(a, p), rel=1e-10)

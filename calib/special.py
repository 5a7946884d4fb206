"""The regularised incomplete gamma functions a calibration's statistics need (the chi-square's tail
and quantile), in plain Python: ``scipy.special`` costs a command about half a second to import,
more than the calibration it serves.

``P(a, x) = gamma(a, x) / Gamma(a)`` (lower) and ``Q(a, x) = 1 - P(a, x)`` (upper), by the series
for ``x < a + 1`` and Lentz's continued fraction otherwise (Numerical Recipes, 6.2), to about
1e-14 relative; the inverse of ``P`` by Halley's method from the Wilson-Hilferty start.
"""

from __future__ import annotations

import math

_EPS, _TINY, _MAX_TERMS = 1e-15, 1e-300, 10_000


def _prefactor(a: float, x: float) -> float:
    """``x^a e^-x / Gamma(a)``, through logarithms (0 where it underflows)."""
    return math.exp(a * math.log(x) - x - math.lgamma(a))


def _series(a: float, x: float) -> float:
    """``P(a, x)`` by its power series (converges fast for ``x < a + 1``)."""
    term = total = 1.0 / a
    ap = a
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * _prefactor(a, x)


def _continued_fraction(a: float, x: float) -> float:
    """``Q(a, x)`` by its continued fraction, modified Lentz (for ``x >= a + 1``)."""
    b = x + 1.0 - a
    c, d = 1.0 / _TINY, 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * _prefactor(a, x)


def gammainc(a: float, x: float) -> float:
    """``P(a, x)``, the regularised lower incomplete gamma function (``a > 0``, ``x >= 0``)."""
    if x <= 0.0:
        return 0.0
    return _series(a, x) if x < a + 1.0 else 1.0 - _continued_fraction(a, x)


def gammaincc(a: float, x: float) -> float:
    """``Q(a, x) = 1 - P(a, x)``, the regularised upper incomplete gamma function, accurate also
    where it is tiny (a chi-square's p-value far in the tail)."""
    if x <= 0.0:
        return 1.0
    return 1.0 - _series(a, x) if x < a + 1.0 else _continued_fraction(a, x)


def gammaincinv(a: float, p: float) -> float:
    """The ``x`` with ``P(a, x) = p`` (``a > 0``, ``0 < p < 1``): Halley's method from the
    Wilson-Hilferty approximation of the chi-square quantile, kept inside a bracket."""
    if p <= 0.0:
        return 0.0
    if p >= 1.0:
        return math.inf
    x = _wilson_hilferty(a, p)
    lo, hi = 0.0, math.inf
    for _ in range(100):
        f = gammainc(a, x) - p
        if f < 0:
            lo = x
        else:
            hi = x
        density = _prefactor(a, x) / x  # dP/dx
        if density <= 0.0:
            step = math.nan
        else:
            newton = f / density
            step = newton / (1.0 - 0.5 * newton * ((a - 1.0) / x - 1.0))  # Halley
        new = x - step
        if not lo < new < hi:  # outside the bracket (or no slope): bisect instead
            new = 0.5 * (lo + hi) if math.isfinite(hi) else 2.0 * x
        if abs(new - x) <= 1e-14 * max(x, 1e-300):
            return new
        x = new
    return x


def _wilson_hilferty(a: float, p: float) -> float:
    """A start for ``gammaincinv``: the cube-root normal approximation of ``Gamma(a)``'s quantile."""
    z = _normal_quantile(p)
    k = 1.0 / (9.0 * a)
    return max(a * (1.0 - k + z * math.sqrt(k)) ** 3, 1e-3 * a, 1e-300)


def _normal_quantile(p: float) -> float:
    """The standard normal's quantile, to a few 1e-3 (a start, refined by ``gammaincinv``):
    Abramowitz and Stegun 26.2.23."""
    q = p if p < 0.5 else 1.0 - p
    t = math.sqrt(-2.0 * math.log(q))
    numerator = 2.515517 + 0.802853 * t + 0.010328 * t * t
    z = t - numerator / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t**3)
    return -z if p < 0.5 else z

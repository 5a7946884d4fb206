import numpy as np
from scipy.optimize import least_squares

from calib.lm import LMOptions, levenberg_marquardt


def _exp_problem(rng, outliers=0):
    t = np.linspace(0, 4, 80)
    y = 3.0 * np.exp(-1.3 * t) + 0.5 + rng.normal(0, 0.01, t.size)
    bad = rng.choice(t.size, outliers, replace=False)
    y[bad] += 1.0

    def fun_jac(x, jacobian=True):
        e = np.exp(-x[1] * t)
        r = (x[0] * e + x[2] - y) / 0.01
        jac = np.column_stack([e, -x[0] * t * e, np.ones_like(t)]) / 0.01 if jacobian else None
        return r, jac

    return fun_jac, bad


def test_agrees_with_scipy_least_squares(rng):
    fun_jac, _ = _exp_problem(rng)
    x0 = np.array([1.0, 0.5, 0.0])
    ours = levenberg_marquardt(fun_jac, x0)
    ref = least_squares(lambda x: fun_jac(x)[0], x0, jac=lambda x: fun_jac(x)[1], method="lm", xtol=1e-12)
    assert ours.success, ours.message
    np.testing.assert_allclose(ours.x, ref.x, rtol=1e-7)
    costs = [h.cost for h in ours.history if h.accepted]
    assert all(b <= a for a, b in zip(costs, costs[1:], strict=False))


def test_held_parameters_do_not_move(rng):
    fun_jac, _ = _exp_problem(rng)
    x0 = np.array([1.0, 0.5, 0.5])
    res = levenberg_marquardt(fun_jac, x0, free=np.array([True, True, False]))
    assert res.x[2] == 0.5
    assert res.jacobian.shape[1] == 2


def test_cauchy_loss_ignores_gross_errors(rng):
    fun_jac, bad = _exp_problem(rng, outliers=5)
    x0 = np.array([1.0, 0.5, 0.0])
    plain = levenberg_marquardt(fun_jac, x0)
    robust = levenberg_marquardt(
        fun_jac, plain.x, options=LMOptions(loss="cauchy", loss_scale=np.array([3.0]))
    )
    truth = np.array([3.0, 1.3, 0.5])
    # 5 rows off by 100 sigma drag the plain fit far beyond its noise; the robust one stays near truth.
    assert np.abs(plain.x - truth).max() > 10 * np.abs(robust.x - truth).max()
    assert np.abs(robust.x[2] - 0.5) < 0.01
    assert set(np.flatnonzero(robust.weights**2 < 0.5)) == set(bad)

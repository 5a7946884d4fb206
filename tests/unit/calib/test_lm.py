import numpy as np
import pytest
from scipy.optimize import least_squares

from calib import lm
from calib.lm import LMOptions, check_termination, damping_update, gain_ratio, levenberg_marquardt


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


BAD_INPUTS = [
    ({"options": LMOptions(loss="l2")}, "`loss` must be one of"),
    ({"options": LMOptions(loss="cauchy")}, r"`loss_scale` is required with loss='cauchy'"),
    ({"options": LMOptions(loss="huber", loss_scale=np.array([0.0]))}, "`loss_scale` must be positive"),
    (
        {"options": LMOptions(loss="cauchy", loss_scale=np.array([1.0])), "groups": np.repeat([0, 1], 40)},
        r"`loss_scale` must be 1-D with one scale per residual group \(2",
    ),
    ({"groups": np.zeros(5, int)}, r"`groups` must be integers of shape \(80,\)"),
    ({"groups": np.zeros(80)}, r"`groups` must be integers of shape \(80,\)"),
    ({"groups": np.full(80, -1)}, "`groups` must be >= 0"),
    ({"free": np.array([True, False])}, r"`free` must be a boolean mask of shape \(3,\)"),
    ({"free": np.array([1, 1, 0])}, r"`free` must be a boolean mask of shape \(3,\)"),
    ({"free": np.zeros(3, bool)}, "`free` must select at least one"),
    ({"options": LMOptions(max_iter=0)}, "`max_iter` must be at least 1"),
    ({"options": LMOptions(max_iter=2.5)}, "`max_iter` must be an integer"),
    ({"options": LMOptions(ftol=-1.0)}, "`ftol` must be finite and >= 0"),
    ({"options": LMOptions(xtol=np.nan)}, "`xtol` must be finite and >= 0"),
    ({"options": LMOptions(damping=0.0)}, "`damping` must be finite and > 0"),
    ({"x0": np.array([1.0, np.nan, 0.0])}, "`x0` must be finite, not at entries 1"),
    ({"x0": np.ones((3, 1))}, r"`x0` must be a non-empty 1-D array, got shape \(3, 1\)"),
]


@pytest.mark.parametrize(("kwargs", "message"), BAD_INPUTS)
def test_rejects_bad_input_naming_the_argument(rng, kwargs, message):
    fun_jac, _ = _exp_problem(rng)
    kwargs = {"x0": np.array([1.0, 0.5, 0.0])} | kwargs
    with pytest.raises(ValueError, match=message):
        levenberg_marquardt(fun_jac, **kwargs)


def _spoiled(fun_jac, rows=(), column=None):
    """``fun_jac`` with NaN residuals at ``rows`` and a NaN Jacobian column at the start."""

    def spoiled(x, jacobian=True):
        r, jac = fun_jac(x, jacobian)
        r = r.copy()
        r[list(rows)] = np.nan
        if jacobian and column is not None:
            jac = jac.copy()
            jac[10:12, column] = np.nan
        return r, jac

    return spoiled


def test_non_finite_start_names_the_rows_and_columns(rng):
    fun_jac, _ = _exp_problem(rng)
    x0 = np.array([1.0, 0.5, 0.0])
    with pytest.raises(ValueError, match=r"`fun_jac\(x0\)` returned non-finite residuals at rows 3, 7$"):
        levenberg_marquardt(_spoiled(fun_jac, rows=(3, 7)), x0)
    with pytest.raises(ValueError, match=r"non-finite Jacobian at rows 10, 11, columns of x entries 1$"):
        levenberg_marquardt(_spoiled(fun_jac, column=1), x0)
    # a held parameter's column is never used: NaN there is no error
    held = levenberg_marquardt(_spoiled(fun_jac, column=2), x0, free=np.array([True, True, False]))
    assert held.success and np.all(np.isfinite(held.x))


def test_rejects_a_jacobian_of_the_wrong_shape(rng):
    fun_jac, _ = _exp_problem(rng)
    with pytest.raises(ValueError, match=r"Jacobian \(m, 3\), got shapes \(80,\) and \(80, 2\)"):
        levenberg_marquardt(lambda x, jacobian=True: (fun_jac(x)[0], fun_jac(x)[1][:, :2]), np.ones(3))


@pytest.mark.parametrize(
    ("gain", "nu", "expected"),
    [
        (1.0, 8.0, (1.0 / 3.0, 2.0)),  # perfect model: the damping shrinks by 3 at most
        (0.5, 8.0, (1.0, 2.0)),  # 1 - 0^3 = 1: kept
        (0.25, 2.0, (1.125, 2.0)),  # 1 - (-0.5)^3: a poor model grows it a little
        (-1.0, 4.0, (4.0, 8.0)),  # rejected: times nu, and nu doubles
        (0.0, 2.0, (2.0, 4.0)),  # no gain counts as rejected
    ],
)
def test_damping_update_is_nielsens_rule(gain, nu, expected):
    assert damping_update(1.0, nu, gain) == pytest.approx(expected)


def test_gain_ratio_fails_steps_the_model_predicts_nothing_for():
    assert gain_ratio(1.0, 2.0) == 0.5
    assert gain_ratio(-1.0, 2.0) == -0.5
    assert gain_ratio(1.0, 0.0) == -1.0 and gain_ratio(1.0, -1e-3) == -1.0


@pytest.mark.parametrize(
    ("cost_new", "step", "status"),
    [
        (0.5, 1.0, 0),  # a real reduction, a real step: go on
        (1.0 - 1e-10, 1.0, 2),  # relative reduction 1e-10 < ftol
        (0.5, 1e-10, 3),  # step 1e-10 < xtol (|D x| + xtol) = 1e-9 * 2
        (1.0, 1e-10, 2),  # both: ftol is reported
    ],
)
def test_check_termination(cost_new, step, status):
    assert check_termination(1.0, cost_new, step, 2.0, ftol=1e-9, xtol=1e-9) == status


@pytest.mark.parametrize("rows", [None, np.array([3, 10, 11, 12, 40, 49])])
def test_normal_equations_in_blocks_are_the_weighted_products(rng, monkeypatch, rows):
    """Summed over blocks of 4 rows, of all rows or a subset: the products of the weighted copy."""
    monkeypatch.setattr(lm, "NORMAL_ROWS", 4)
    jac, w, wr = rng.normal(size=(50, 5)), rng.uniform(0.1, 1.0, 50), rng.normal(size=50)
    free = np.array([True, False, True, True, False])
    normal, gradient = lm.normal_equations(jac, free, w, wr, rows)
    picked = np.arange(50) if rows is None else rows
    wj = jac[np.ix_(picked, np.flatnonzero(free))] * w[picked, None]
    np.testing.assert_allclose(normal, wj.T @ wj, rtol=1e-12)
    np.testing.assert_allclose(gradient, wj.T @ wr[picked], rtol=1e-12)


def test_the_normal_equations_of_each_fold_in_one_pass_are_each_folds_products(rng, monkeypatch):
    """Blocks of 4 rows cutting across the sets: each set's products as of its rows alone (none: zero)."""
    monkeypatch.setattr(lm, "NORMAL_ROWS", 4)
    jac, w, wr = rng.normal(size=(50, 5)), rng.uniform(0.1, 1.0, 50), rng.normal(size=50)
    free, label = np.array([True, False, True, True, False]), rng.integers(0, 3, 50)
    normal, gradient = lm.fold_normal_equations(jac, free, w, wr, label, 4)
    for lab in range(4):
        picked = np.flatnonzero(label == lab)
        wj = jac[np.ix_(picked, np.flatnonzero(free))] * w[picked, None]
        np.testing.assert_allclose(normal[lab], wj.T @ wj, rtol=1e-12)
        np.testing.assert_allclose(gradient[lab], wj.T @ wr[picked], rtol=1e-12)


def test_the_solvers_products_on_one_block_are_the_whole_arrays_to_the_last_digit(rng, monkeypatch):
    """The scaled normal equations and the predicted reduction: on rows that fit one block, exactly
    the whole-array products (what planning's fits computed before blocks); on several blocks the
    same to the rounding."""
    jac, w, wr = rng.normal(size=(50, 5)), rng.uniform(0.1, 1.0, 50), rng.normal(size=50)
    free, step = np.array([True, False, True, True, False]), rng.normal(size=3)
    wj = jac[:, free] * w[:, None]
    d = np.linalg.norm(wj, axis=0)
    js = wj / d
    predicted = 0.5 * (wr @ wr - np.sum((wr + wj @ step) ** 2))
    diag, d_one, hess, grad, predict = lm._gauss_newton(jac, free, w, wr, np.zeros(3))
    for got, expected in (
        (diag, d),
        (d_one, d),
        (hess, js.T @ js),
        (grad, js.T @ wr),
        (predict(step), predicted),
    ):
        np.testing.assert_array_equal(got, expected)
    monkeypatch.setattr(lm, "NORMAL_ROWS", 7)
    diag, _, hess, grad, predict = lm._gauss_newton(jac, free, w, wr, np.zeros(3))
    np.testing.assert_allclose(diag, d, rtol=1e-13)
    np.testing.assert_allclose(hess, js.T @ js, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(grad, js.T @ wr, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(predict(step), predicted, rtol=1e-12)


def test_the_fit_is_the_same_whatever_the_block_of_rows(rng, monkeypatch):
    """A fit over 300 rows in blocks of 16 lands where the one-block fit does."""
    t = np.linspace(0, 3, 300)
    y = 2.0 * np.exp(-0.7 * t) + 0.3 + rng.normal(0, 0.01, t.size)

    def fun_jac(x, jacobian=True):
        e = np.exp(-x[1] * t)
        r = x[0] * e + x[2] - y
        return r, (np.column_stack([e, -x[0] * t * e, np.ones_like(t)]) if jacobian else None)

    whole = levenberg_marquardt(fun_jac, np.array([1.0, 0.1, 0.0]))
    monkeypatch.setattr(lm, "NORMAL_ROWS", 16)
    blocks = levenberg_marquardt(fun_jac, np.array([1.0, 0.1, 0.0]))
    np.testing.assert_allclose(blocks.x, whole.x, rtol=1e-9)
    assert blocks.nit == whole.nit

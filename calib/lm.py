"""Levenberg-Marquardt on a measurement model, with parameter scaling and an optional robust loss.

Minimises ``F(x) = sum_i s_i^2 rho(r_i(x)^2 / s_i^2) / 2`` over the free entries of ``x``, where
``r`` are the model's whitened residuals, ``rho`` the loss and ``s_i`` the loss scale of residual
``i``'s group (``rho(z) = z`` for the linear loss, so ``F`` is half the sum of squares).

Each iteration solves the damped, column-scaled normal equations of the iteratively re-weighted
problem (weights ``w_i = sqrt(rho'(z_i))``)::

    (J^T W^2 J + mu D^2) dx = -J^T W^2 r,     D = diag(max column norms of W J seen so far)

by numpy's LU solve (``scipy.linalg``'s Cholesky would cost a command 0.2 s of import for a
symmetric positive definite system of a few dozen unknowns; both are backward stable, and the
calibrations agree to about 1e-13 relative, or to the stop tolerances where the rounding moves the
stop by an iteration), and updates the damping ``mu`` by the gain ratio (``gain_ratio``,
``damping_update``: Nielsen's rule): ``mu *= max(1/3, 1 - (2 gain - 1)^3)`` on success, else
``mu *= nu``, ``nu *= 2``. On rows that fit one block (``NORMAL_ROWS``) the column-scaled ``J^T W^2
J``, ``J^T W^2 r`` and a step's predicted cost reduction ``(|W r|^2 - |W (r + J dx)|^2) / 2`` are
whole-array products (planning's small fits, to the last digit as before blocks); on more rows
``J^T W^2 J`` and ``J^T W^2 r`` are summed over blocks in one pass (no weighted copy of a million
rows' Jacobian) and the predicted reduction is ``-g^T dx - dx^T J^T W^2 J dx / 2`` from them.

Stops (``status``) when

1. ``max |D^-1 J^T W^2 r| < gtol`` (scaled gradient, before a step),
2. ``F_old - F_new < ftol F_old`` (after an accepted step, ``check_termination``),
3. ``|D dx| < xtol (|D x| + xtol)`` (likewise),

or 0 when ``max_iter`` iterations ran, -1 when the damping passed ``MAX_DAMPING`` without a step
that reduces ``F``.

``levenberg_marquardt`` checks its inputs once, at entry, and raises ``ValueError`` naming the
argument (``loss``, ``loss_scale``, ``groups``, ``free``, ``x0``, an option, or ``fun_jac(x0)``
when the start's residuals or Jacobian are not finite); the iteration behind it trusts them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.blocks import each_block

TERMINATION_MESSAGES = {
    -1: "no step reduces the cost: the minimum is reached to machine precision",
    0: "the maximum number of iterations was reached",
    1: "the scaled gradient fell below gtol",
    2: "the relative cost reduction fell below ftol",
    3: "the scaled step fell below xtol",
}

LOSSES = ("linear", "huber", "cauchy")
MAX_DAMPING = 1e16
"""Damping beyond which no step can reduce the cost any more (status -1)."""


@dataclass(frozen=True, kw_only=True)
class LMOptions:
    """Solver options.

    Attributes
    ----------
    max_iter : int
        Jacobian evaluations (outer iterations), >= 1.
    ftol, xtol, gtol : float
        Stopping tolerances (module docstring), >= 0.
    damping : float
        Initial damping ``mu`` of the column-scaled normal equations, > 0.
    loss : {"linear", "huber", "cauchy"}
        ``rho`` of the cost.
    loss_scale : ndarray, shape (n_groups,), optional
        Where the robust loss starts to down-weight, one per residual group, in whitened units
        (positive); required unless ``loss`` is linear.
    """

    max_iter: int = 100
    ftol: float = 1e-9
    xtol: float = 1e-9
    gtol: float = 1e-10
    damping: float = 1e-3
    loss: str = "linear"
    loss_scale: np.ndarray | None = None


@dataclass(frozen=True)
class Iteration:
    """One accepted or rejected trial: cost after it, damping used, scaled step length."""

    cost: float
    damping: float
    step: float
    accepted: bool


@dataclass
class LMResult:
    """What ``levenberg_marquardt`` returns.

    Attributes
    ----------
    x : ndarray, shape (n,)
        Solution, the full vector (entries not ``free`` as given).
    cost : float
        ``F(x)`` (module docstring).
    residuals : ndarray, shape (m,)
        Whitened residuals at ``x``.
    weights : ndarray, shape (m,)
        Robust IRLS weights ``sqrt(rho')`` (1 for the linear loss).
    free : ndarray of bool, shape (n,)
        The fitted entries.
    status, message : int, str
        Why it stopped (``TERMINATION_MESSAGES``); ``success`` when ``status > 0``.
    nit, nfev : int
        Jacobian evaluations (iterations) and residual evaluations.
    history : list of Iteration
        Every trial step, accepted or not.
    """

    x: np.ndarray
    cost: float
    residuals: np.ndarray
    weights: np.ndarray
    free: np.ndarray
    status: int
    message: str
    nit: int
    nfev: int
    history: list[Iteration] = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.status > 0


def loss_terms(r: np.ndarray, scale: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-residual cost contributions and IRLS weights.

    With ``z = (r / s)^2``: linear ``rho(z) = z``; Huber ``rho(z) = z`` for ``z <= 1``, else
    ``2 sqrt(z) - 1``; Cauchy ``rho(z) = log(1 + z)``.

    Parameters
    ----------
    r : ndarray, shape (m,)
        Whitened residuals.
    scale : ndarray, shape (m,), or float
        Loss scale ``s`` of each residual (ignored by the linear loss).
    loss : {"linear", "huber", "cauchy"}

    Returns
    -------
    terms : ndarray, shape (m,)
        ``s^2 rho(z) / 2`` (``r^2 / 2`` for the linear loss); their sum is the cost.
    weights : ndarray, shape (m,)
        ``sqrt(rho'(z))``: 1 for the linear loss and inside Huber's threshold.

    Raises
    ------
    ValueError
        ``loss`` is not one of ``LOSSES``.
    """
    if loss == "linear":
        return 0.5 * r**2, np.ones_like(r)
    z = (r / scale) ** 2
    if loss == "huber":
        big = z > 1.0
        rho = np.where(big, 2.0 * np.sqrt(z) - 1.0, z)
        drho = np.where(big, 1.0 / np.sqrt(np.maximum(z, 1.0)), 1.0)
    elif loss == "cauchy":
        rho, drho = np.log1p(z), 1.0 / (1.0 + z)
    else:
        _check_loss(loss)
    return 0.5 * scale**2 * rho, np.sqrt(drho)


def robust_scale(r: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Per-group noise scale by the median absolute deviation: ``1.4826 median|r - median r|``.

    Parameters
    ----------
    r : ndarray, shape (m,)
        Residuals (whitened units).
    groups : ndarray of int, shape (m,)
        Group id of each residual, >= 0.

    Returns
    -------
    ndarray, shape (max(groups) + 1,)
        Scale of each group id, at least 1e-12; 1 for an id no residual carries.
    """
    n_groups = int(groups.max()) + 1
    scale = np.ones(n_groups)
    for g in range(n_groups):
        rg = r[groups == g]
        if rg.size:
            scale[g] = max(1.4826 * np.median(np.abs(rg - np.median(rg))), 1e-12)
    return scale


def damping_update(mu: float, nu: float, gain: float) -> tuple[float, float]:
    """Nielsen's rule: the damping ``mu`` and its growth factor ``nu`` after a trial step whose
    gain ratio (actual over predicted cost reduction) is ``gain``.

    Accepted (``gain > 0``): ``mu * max(1/3, 1 - (2 gain - 1)^3)`` and ``nu = 2``; rejected:
    ``mu * nu`` and ``2 nu``.
    """
    if gain > 0:
        return mu * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 2.0
    return mu * nu, 2.0 * nu


def gain_ratio(actual: float, predicted: float) -> float:
    """Actual over predicted cost reduction of a step; -1 where the model predicts none
    (``predicted <= 0``), so that the step counts as failed."""
    return actual / predicted if predicted > 0 else -1.0


def check_termination(
    cost: float, cost_new: float, step_norm: float, x_norm: float, ftol: float, xtol: float
) -> int:
    """Status after an accepted step from cost ``F_old`` to ``F_new`` with scaled step length
    ``|D dx|`` at scaled parameters ``|D x|``: 2 when ``F_old - F_new < ftol F_old``, else 3 when
    ``|D dx| < xtol (|D x| + xtol)``, else 0 (go on)."""
    if cost - cost_new < ftol * cost:
        return 2
    if step_norm < xtol * (x_norm + xtol):
        return 3
    return 0


def levenberg_marquardt(
    fun_jac: Callable[..., tuple[np.ndarray, np.ndarray | None]],
    x0: np.ndarray,
    *,
    free: np.ndarray | None = None,
    groups: np.ndarray | None = None,
    options: LMOptions = LMOptions(),
    callback: Callable[[Iteration], None] | None = None,
) -> LMResult:
    """Minimise the (robust) cost ``F`` of the module docstring over ``x[free]``.

    Parameters
    ----------
    fun_jac : callable
        ``fun_jac(x, jacobian=True) -> (r, J)``: whitened residuals ``r`` (m,) and their Jacobian
        ``J`` (m, n) by every entry of ``x``; with ``jacobian=False`` ``J`` may be None.
    x0 : ndarray, shape (n,)
        Start, finite; the entries not ``free`` keep their value.
    free : ndarray of bool, shape (n,), optional
        Which entries are fitted (at least one); default all.
    groups : ndarray of int, shape (m,), optional
        Residual group of each residual (index into ``options.loss_scale``); default all 0.
    options : LMOptions
        Loss, its scale per group (required, positive, for a robust loss), tolerances, damping.
    callback : callable, optional
        Called with every trial step's :class:`Iteration`.

    Returns
    -------
    LMResult
        The solution (full vector), cost, residuals, robust weights,
        ``status`` (see the module docstring) with its message, and the history of trials.

    Raises
    ------
    ValueError
        An input that cannot be solved as given, naming the argument: an unknown ``loss``, a robust
        loss without a positive scale for every group, ``groups`` or ``free`` of the wrong shape or
        type, options out of range, or a start whose residuals or Jacobian are not finite.
    """
    _check_options(options)
    x = _checked_start(x0)
    free = _checked_free(free, x.size)
    r, jac = fun_jac(x)
    _check_start_evaluation(r, jac, x.size, free)
    groups = _checked_groups(groups, r.size)
    scale = 1.0 if options.loss == "linear" else _checked_loss_scale(options, groups)[groups]
    return _solve(fun_jac, x, r, jac, free, scale, options, callback)


def _solve(fun_jac, x, r, jac, free, scale, options: LMOptions, callback) -> LMResult:
    """The iteration on checked inputs (the module docstring's), from residuals ``r`` and
    Jacobian ``jac`` at ``x``."""
    terms, w = loss_terms(r, scale, options.loss)
    cost, nfev = terms.sum(), 1
    mu, nu = options.damping, 2.0
    diag = np.zeros(free.sum())
    history: list[Iteration] = []
    status, nit = 0, 0
    while nit < options.max_iter and status == 0:
        nit += 1
        wr = r * w
        diag, d, hess, grad, predict = _gauss_newton(jac, free, w, wr, diag)
        if np.max(np.abs(grad)) < options.gtol:
            status = 1
            break
        while True:
            step = _damped_step(hess, grad, mu) / d
            x_new = x.copy()
            x_new[free] += step
            r_new, _ = fun_jac(x_new, jacobian=False)
            nfev += 1
            terms_new, w_new = loss_terms(r_new, scale, options.loss)
            cost_new = terms_new.sum()
            gain = gain_ratio(cost - cost_new, predict(step))
            step_norm = float(np.linalg.norm(d * step))
            history.append(Iteration(float(min(cost, cost_new)), float(mu), step_norm, gain > 0))
            if callback is not None:
                callback(history[-1])
            mu, nu = damping_update(mu, nu, gain)
            if gain > 0:
                break
            if mu > MAX_DAMPING:
                status = -1
                break
        if status == -1:
            break
        status = check_termination(
            cost, cost_new, step_norm, float(np.linalg.norm(d * x[free])), options.ftol, options.xtol
        )
        x, w, cost = x_new, w_new, cost_new
        del jac  # not alive beside the next one
        if status != 0 or nit == options.max_iter:
            r = r_new  # the run ends here: its residuals are the trial's, no Jacobian needed
            break
        r, jac = fun_jac(x)
    return LMResult(
        x=x,
        cost=float(cost),
        residuals=r,
        weights=w,
        free=free,
        status=status,
        message=TERMINATION_MESSAGES[status],
        nit=nit,
        nfev=nfev,
        history=history,
    )


NORMAL_ROWS = 8192
"""Rows per block of ``normal_equations`` and the solver's products: a block's weighted copy stays a
few MB."""


def row_blocks(a: np.ndarray):
    """``a``'s consecutive blocks of ``NORMAL_ROWS`` rows."""
    return (a[s : s + NORMAL_ROWS] for s in range(0, len(a), NORMAL_ROWS))


def weighted_blocks(jac: np.ndarray, cols: np.ndarray, w: np.ndarray):
    """The weighted columns ``cols`` (k indices) of ``W J`` (``jac`` (m, n), row weights ``w`` (m,)),
    a block of ``NORMAL_ROWS`` rows (rows, k) at a time: products without a weighted copy of all."""
    for block, w_block in zip(row_blocks(jac), row_blocks(w), strict=True):
        wj = block[:, cols]
        wj *= w_block[:, None]
        yield wj


def block_sum(parts):
    """The sum of ``parts`` (arrays or numbers), the first taken as it is: on a single block of rows
    each product is, to the last digit, the whole-array product's."""
    total = None
    for part in parts:
        total = part if total is None else total + part
    return total


def _gauss_newton(jac, free, w, wr, diag):
    """The iteration's linearisation from the Jacobian ``jac`` (m, n), its ``free`` columns (k), the
    row weights ``w`` and weighted residuals ``wr`` (m,): the column scales ``diag`` (k,) kept at
    their largest so far and ``d`` (no zeros), the column-scaled Gauss-Newton matrix (k, k) and
    gradient (k,), and ``predict(dx)``: the cost reduction the linearised model predicts for a step.

    Rows that fit one block (``NORMAL_ROWS``) are multiplied as whole arrays, the same to the last
    digit as before blocks (planning's small fits); more rows in one pass over blocks of them
    (``normal_equations``), the prediction ``-g^T dx - dx^T J^T W^2 J dx / 2`` from its products."""
    if len(jac) <= NORMAL_ROWS:
        wj = jac[:, free] * w[:, None]
        diag = np.maximum(diag, np.linalg.norm(wj, axis=0))
        d = np.where(diag > 0, diag, 1.0)
        js = wj / d
        return diag, d, js.T @ js, js.T @ wr, lambda step: 0.5 * (wr @ wr - np.sum((wr + wj @ step) ** 2))
    normal, gradient = normal_equations(jac, free, w, wr)
    diag = np.maximum(diag, np.sqrt(np.diag(normal)))
    d = np.where(diag > 0, diag, 1.0)
    return (
        diag,
        d,
        normal / np.outer(d, d),
        gradient / d,
        lambda step: -(gradient @ step) - 0.5 * step @ normal @ step,
    )


def normal_equations(
    jac: np.ndarray, free: np.ndarray, w: np.ndarray, wr: np.ndarray, rows: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(W J)^T W J`` (k, k) and ``(W J)^T W r`` (k,) of the ``free`` columns (k) of ``jac`` (m, n)
    with row weights ``w`` (m,) and weighted residuals ``wr`` (m,), over ``rows`` (indices; default
    all), summed ``NORMAL_ROWS`` rows at a time instead of from a weighted copy of the Jacobian (the
    blocks shared by ``each_block``'s threads)."""
    cols = np.flatnonzero(free)

    def block_products(s: int, e: int) -> tuple[np.ndarray, np.ndarray]:
        block = slice(s, e) if rows is None else rows[s:e]
        wj = jac[block, cols] if rows is None else jac[np.ix_(block, cols)]
        wj *= w[block, None]
        return wj.T @ wj, wr[block] @ wj

    halves = each_block(len(jac) if rows is None else rows.size, NORMAL_ROWS, block_products)
    if not halves:
        return np.zeros((cols.size, cols.size)), np.zeros(cols.size)
    return block_sum(h[0] for h in halves), block_sum(h[1] for h in halves)


def fold_normal_equations(
    jac: np.ndarray, free: np.ndarray, w: np.ndarray, wr: np.ndarray, label: np.ndarray, labels: int
) -> tuple[np.ndarray, np.ndarray]:
    """``normal_equations`` of each set of rows: ``(W J)^T W J`` (labels, k, k) and ``(W J)^T W r``
    (labels, k) over the rows of each ``label`` (m,) (0 to ``labels - 1``), in one pass over the
    Jacobian (cross-validation's folds: all rows less a fold's, without a pass per fold), its blocks
    shared by ``each_block``'s threads."""
    cols = np.flatnonzero(free)

    def block_products(s: int, e: int) -> tuple[np.ndarray, np.ndarray]:
        normal, gradient = np.zeros((labels, cols.size, cols.size)), np.zeros((labels, cols.size))
        wj = jac[s:e, cols]
        wj *= w[s:e, None]
        for lab in np.unique(label[s:e]):
            on = label[s:e] == lab
            part = wj[on]
            normal[lab] += part.T @ part
            gradient[lab] += wr[s:e][on] @ part
        return normal, gradient

    halves = each_block(len(jac), NORMAL_ROWS, block_products)
    if not halves:
        return np.zeros((labels, cols.size, cols.size)), np.zeros((labels, cols.size))
    return block_sum(h[0] for h in halves), block_sum(h[1] for h in halves)


def _damped_step(hess: np.ndarray, grad: np.ndarray, mu: float) -> np.ndarray:
    """Solve ``(H + mu I) dx = -g`` for the column-scaled Gauss-Newton matrix ``H``."""
    n = hess.shape[0]
    return -np.linalg.solve(hess + mu * np.eye(n) + 1e-12 * np.trace(hess) / n * np.eye(n), grad)


# -- input checks: once, at entry; the solver trusts what passes -----------------------------------
def _check_loss(loss: str) -> None:
    if loss not in LOSSES:
        raise ValueError(f"`loss` must be one of {LOSSES}, got {loss!r}")


def _check_options(options: LMOptions) -> None:
    _check_loss(options.loss)
    if isinstance(options.max_iter, bool) or not isinstance(options.max_iter, (int, np.integer)):
        raise ValueError(f"`max_iter` must be an integer, got {options.max_iter!r}")
    if options.max_iter < 1:
        raise ValueError(f"`max_iter` must be at least 1, got {options.max_iter}")
    for name in ("ftol", "xtol", "gtol"):
        value = getattr(options, name)
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"`{name}` must be finite and >= 0, got {value!r}")
    if not (np.isfinite(options.damping) and options.damping > 0):
        raise ValueError(f"`damping` must be finite and > 0, got {options.damping!r}")


def _checked_start(x0) -> np.ndarray:
    x = np.array(x0, float)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"`x0` must be a non-empty 1-D array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"`x0` must be finite, not at entries {_where(~np.isfinite(x))}")
    return x


def _checked_free(free, n: int) -> np.ndarray:
    if free is None:
        return np.ones(n, bool)
    free = np.asarray(free)
    if free.dtype != bool or free.shape != (n,):
        raise ValueError(
            f"`free` must be a boolean mask of shape ({n},) like `x0`, got {free.dtype} of shape {free.shape}"
        )
    if not free.any():
        raise ValueError("`free` must select at least one parameter")
    return free


def _check_start_evaluation(r, jac, n: int, free: np.ndarray) -> None:
    """Shapes and finiteness of what ``fun_jac`` returned at the start."""
    if np.ndim(r) != 1 or np.shape(jac) != (np.size(r), n):
        raise ValueError(
            f"`fun_jac(x0)` must return residuals (m,) and a Jacobian (m, {n}), "
            f"got shapes {np.shape(r)} and {np.shape(jac)}"
        )
    bad_r = ~np.isfinite(r)
    if bad_r.any():
        raise ValueError(f"`fun_jac(x0)` returned non-finite residuals at rows {_where(bad_r)}")
    bad_j = ~np.isfinite(jac)[:, free]
    if bad_j.any():
        entries = np.flatnonzero(free)[bad_j.any(axis=0)]
        raise ValueError(
            f"`fun_jac(x0)` returned a non-finite Jacobian at rows {_where(bad_j.any(axis=1))}, "
            f"columns of x entries {_where(np.isin(np.arange(free.size), entries))}"
        )


def _checked_groups(groups, m: int) -> np.ndarray:
    if groups is None:
        return np.zeros(m, int)
    groups = np.asarray(groups)
    if groups.shape != (m,) or not np.issubdtype(groups.dtype, np.integer):
        raise ValueError(
            f"`groups` must be integers of shape ({m},), one per residual, "
            f"got {groups.dtype} of shape {groups.shape}"
        )
    if m and groups.min() < 0:
        raise ValueError(f"`groups` must be >= 0, got {groups.min()}")
    return groups


def _checked_loss_scale(options: LMOptions, groups: np.ndarray) -> np.ndarray:
    need = int(groups.max()) + 1 if groups.size else 1
    if options.loss_scale is None:
        raise ValueError(
            f"`loss_scale` is required with loss={options.loss!r}: one positive scale per residual "
            f"group ({need})"
        )
    scale = np.asarray(options.loss_scale, float)
    if scale.ndim != 1 or scale.size < need:
        raise ValueError(
            f"`loss_scale` must be 1-D with one scale per residual group ({need}, `groups` goes up "
            f"to {need - 1}), got shape {scale.shape}"
        )
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"`loss_scale` must be positive and finite, got {scale.tolist()}")
    return scale


def _where(mask: np.ndarray, most: int = 5) -> str:
    """The first indices where ``mask`` holds, for a message."""
    idx = np.flatnonzero(mask)
    shown = ", ".join(str(i) for i in idx[:most])
    return shown + (f" and {idx.size - most} more" if idx.size > most else "")

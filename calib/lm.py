"""Levenberg-Marquardt on a measurement model, with parameter scaling and an optional robust loss.

Minimises ``F(x) = sum_i s_i^2 rho(r_i(x)^2 / s_i^2) / 2`` over the free entries of ``x``, where
``r`` are the model's whitened residuals, ``rho`` the loss and ``s_i`` the loss scale of residual
``i``'s group (``rho(z) = z`` for the linear loss, so ``F`` is half the sum of squares).

Each iteration solves the damped, column-scaled normal equations of the iteratively re-weighted
problem (weights ``w_i = sqrt(rho'(z_i))``)::

    (J^T W^2 J + mu D^2) dx = -J^T W^2 r,     D = diag(max column norms of W J seen so far)

by a Cholesky factorisation, and updates the damping ``mu`` by
the gain ratio (Nielsen's rule): ``mu *= max(1/3, 1 - (2 gain - 1)^3)`` on success, else ``mu *= nu``,
``nu *= 2``.

Stops (``status``) when, after an accepted step:

1. ``max |D^-1 J^T W^2 r| < gtol`` (scaled gradient),
2. ``F_old - F_new < ftol F_old``,
3. ``|D dx| < xtol (|D x| + xtol)``,

or 0 when ``max_iter`` iterations ran, -1 when no step could reduce ``F`` any more.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve

TERMINATION_MESSAGES = {
    -1: "no step reduces the cost: the minimum is reached to machine precision",
    0: "the maximum number of iterations was reached",
    1: "the scaled gradient fell below gtol",
    2: "the relative cost reduction fell below ftol",
    3: "the scaled step fell below xtol",
}

LOSSES = ("linear", "huber", "cauchy")


@dataclass(frozen=True, kw_only=True)
class LMOptions:
    """Solver options. ``loss_scale`` holds one scale per residual group (whitened units)."""

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
    """Solution ``x`` (full vector), final ``cost``, whitened ``residuals``, the Jacobian of the free
    columns at ``x``, robust ``weights`` (1 for the linear loss), ``status``/``message`` and the
    per-trial ``history``."""

    x: np.ndarray
    cost: float
    residuals: np.ndarray
    jacobian: np.ndarray
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
    """Per-residual cost contributions ``s^2 rho(z) / 2`` and IRLS weights ``sqrt(rho'(z))``."""
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
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    return 0.5 * scale**2 * rho, np.sqrt(drho)


def robust_scale(r: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Per-group noise scale by the median absolute deviation (1.4826 MAD), indexed by group id."""
    n_groups = int(groups.max()) + 1
    scale = np.ones(n_groups)
    for g in range(n_groups):
        rg = r[groups == g]
        if rg.size:
            scale[g] = max(1.4826 * np.median(np.abs(rg - np.median(rg))), 1e-12)
    return scale


def levenberg_marquardt(
    fun_jac: Callable[..., tuple[np.ndarray, np.ndarray | None]],
    x0: np.ndarray,
    *,
    free: np.ndarray | None = None,
    groups: np.ndarray | None = None,
    options: LMOptions = LMOptions(),
    callback: Callable[[Iteration], None] | None = None,
) -> LMResult:
    """Minimise the (robust) cost of ``fun_jac(x, jacobian=True) -> (r (m,), J (m, n) or None)``
    over ``x[free]``.

    ``groups`` (m,) labels each residual for ``options.loss_scale``; ``callback`` sees every trial.
    """
    x = np.array(x0, float)
    free = np.ones(x.size, bool) if free is None else np.asarray(free, bool)
    r, jac = fun_jac(x)
    groups = np.zeros(r.size, int) if groups is None else groups
    scale = 1.0 if options.loss == "linear" else np.asarray(options.loss_scale)[groups]
    terms, w = loss_terms(r, scale, options.loss)
    cost, nfev = terms.sum(), 1
    mu, nu = options.damping, 2.0
    diag = np.zeros(free.sum())
    history: list[Iteration] = []
    status, nit = 0, 0
    while nit < options.max_iter and status == 0:
        nit += 1
        wj, wr = jac[:, free] * w[:, None], r * w
        diag = np.maximum(diag, np.linalg.norm(wj, axis=0))
        d = np.where(diag > 0, diag, 1.0)
        js = wj / d
        hess, grad = js.T @ js, js.T @ wr
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
            predicted = 0.5 * (wr @ wr - np.sum((wr + wj @ step) ** 2))
            gain = (cost - cost_new) / predicted if predicted > 0 else -1.0
            step_norm = float(np.linalg.norm(d * step))
            history.append(Iteration(float(min(cost, cost_new)), float(mu), step_norm, gain > 0))
            if callback is not None:
                callback(history[-1])
            if gain > 0:
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                break
            mu, nu = mu * nu, nu * 2.0
            if mu > 1e16:
                status = -1
                break
        if status == -1:
            break
        if cost - cost_new < options.ftol * cost:
            status = 2
        elif step_norm < options.xtol * (np.linalg.norm(d * x[free]) + options.xtol):
            status = 3
        x, w, cost = x_new, w_new, cost_new
        r, jac = fun_jac(x)
    return LMResult(
        x=x,
        cost=float(cost),
        residuals=r,
        jacobian=jac[:, free],
        weights=w,
        free=free,
        status=status,
        message=TERMINATION_MESSAGES[status],
        nit=nit,
        nfev=nfev,
        history=history,
    )


def _damped_step(hess: np.ndarray, grad: np.ndarray, mu: float) -> np.ndarray:
    """Solve ``(H + mu I) dx = -g`` for the column-scaled Gauss-Newton matrix ``H`` (Cholesky)."""
    n = hess.shape[0]
    factor = cho_factor(hess + mu * np.eye(n) + 1e-12 * np.trace(hess) / n * np.eye(n))
    return -cho_solve(factor, grad)

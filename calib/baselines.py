"""The paper's compared calibrators (Table II, M1-M7) and M8 (LMLC), on any measurement model.

Every method sees the model only through its protocol (``residuals``, ``residuals_and_jacobian``,
``rows``, ``names``), starts from the same ``x0`` and moves the same ``free`` parameters, so that the
methods differ only in how they search. The line constraint is part of the model's residuals, so
every method carries it.

All of them work in the unit box around ``x0``: ``x[free] = x0[free] + half_width * z``, ``z`` in
``[-1, 1]^n``, where ``half_width`` (``search_half_widths``) is the size of the error a parameter is
expected to have (0.5 deg per table angle, 3 mm per table length, the setup unknowns' tolerances).
The global methods (PSO, SA, DE) search inside that box; the local and recursive ones (GN, EKF,
UKF, PF) use it as their scaling and prior (the box's half width is two prior standard deviations).
The cost is ``F = |r|^2 / 2`` over the whitened residuals ``r``.

- M1 ``pso``: global-best particle swarm (inertia 0.72, both pulls 1.49), the swarm clipped to the box;
- M2 ``ekf``, M3 ``ukf``, M6 ``pf``: the parameters as a static state observed through the model's
  rows, processed in seeded batches as measurements ``0 = r_batch(x) + noise`` (unit noise: the
  residuals are whitened), in several passes, each restarting the prior covariance around the last
  estimate. EKF linearises with the Jacobian, UKF propagates the symmetric sigma-point set, PF is a
  Gaussian particle filter (Kotecha & Djuric 2003) that absorbs each batch's likelihood in tempered
  steps chosen so that the effective sample size stays at half the particles;
- M4 ``gn``: Gauss-Newton, full steps, no damping;
- M5 ``sa``: ``scipy.optimize.dual_annealing`` as scipy designs it: generalised simulated annealing
  whose improvements are refined by its L-BFGS-B local search, here given the model's gradient
  ``J^T r`` (without the local search it does not get below the nominal's error within tens of
  thousands of evaluations on 24 parameters);
- M7 ``de``: ``scipy.optimize.differential_evolution`` without its final L-BFGS polish;
- M8 ``lmlc``: ``calib.calibrate.robust_fit`` (robust Levenberg-Marquardt).

A filter's iteration is one batch update, PSO's and DE's one generation, SA's one annealing chain
(2n visits), GN's and LMLC's one Jacobian evaluation.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution, dual_annealing

from calib.calibrate import CalibrationOptions, robust_fit
from calib.methods import METHODS
from calib.models import MeasurementModel
from calib.params import display_factor

# Expected error sizes (half widths of the search box) in display units, by name: the first rule
# whose prefix and suffix match. Table angles and lengths from a machined, assembled arm; the setup
# unknowns from what a person measures roughly (contract: anchor to +-50 mm, offset to +-10 mm);
# gauge-block lines from a line fitted to the nominal TCPs (a few mm, a few mrad).
HALF_WIDTH_RULES = (
    ("anchor.", "_mm", 50.0),
    ("length_offset", "_mm", 10.0),
    ("line", "_mm", 5.0),
    ("line", "", 5e-3),
    ("J", "_deg", 0.5),
    ("J", "_mm", 3.0),
)


def search_half_widths(names) -> np.ndarray:
    """Half width of the search box for each parameter (``HALF_WIDTH_RULES``).

    Parameters
    ----------
    names : sequence of str, length n
        Parameter names (table, setup, lines).

    Returns
    -------
    ndarray, shape (n,)
        Half widths in internal units (rad, mm).

    Raises
    ------
    ValueError
        A name no rule covers.
    """
    widths = []
    for name in names:
        rule = next(
            (w for pre, suf, w in HALF_WIDTH_RULES if name.startswith(pre) and name.endswith(suf)), None
        )
        if rule is None:
            raise ValueError(f"no expected error size for parameter {name!r}")
        widths.append(rule)
    return np.array(widths) / display_factor(names)


@dataclass(frozen=True, kw_only=True)
class BaselineOptions:
    """Budgets and seed. ``seed`` drives every random choice (batch order, swarm, particles, DE, SA);
    ``max_iter``: generations (PSO, DE), annealing chains (SA), iterations (GN); ``swarm``: PSO
    particles; ``popsize``: DE population per free parameter; ``batches``/``passes``: filter batches
    per pass over the rows and passes; ``particles`` and ``max_steps`` (tempering steps per batch): PF;
    ``ftol``: GN's relative cost reduction to stop; ``calibration``: LMLC's options."""

    seed: int = 0
    max_iter: int = 300
    swarm: int = 40
    popsize: int = 10
    batches: int = 8
    passes: int = 3
    particles: int = 200
    max_steps: int = 60
    ftol: float = 1e-9
    calibration: CalibrationOptions = field(default_factory=CalibrationOptions)


@dataclass
class MethodResult:
    """``x`` (full vector), final ``cost`` (``|r|^2 / 2``), ``iterations``, ``history`` (the cost of
    the method's current best or estimate after each iteration, for training curves), ``nfev``
    (residual evaluations, Jacobians included) and wall ``time_s``."""

    method: str
    x: np.ndarray
    cost: float
    iterations: int
    history: np.ndarray
    nfev: int
    time_s: float


class _Objective:
    """The model seen through its free parameters, scaled to the unit box around ``x0``."""

    def __init__(self, model: MeasurementModel, x0: np.ndarray, free: np.ndarray):
        self.model, self.x0, self.free = model, np.asarray(x0, float), np.asarray(free, bool)
        self.scale = search_half_widths(model.names)[self.free]
        self.n = int(self.free.sum())
        self.nfev = 0

    def x(self, z: np.ndarray) -> np.ndarray:
        x = self.x0.copy()
        x[self.free] += self.scale * z
        return x

    def residuals(self, z: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self.model.residuals(self.x(z))

    def cost(self, z: np.ndarray) -> float:
        r = self.residuals(z)
        return 0.5 * float(r @ r)

    def gradient(self, z: np.ndarray) -> np.ndarray:
        """Gradient of the cost by ``z``: ``J^T r``."""
        r, jac = self.residuals_and_jacobian(z)
        return jac.T @ r

    def residuals_and_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (m,) and their Jacobian by ``z`` (m, n)."""
        self.nfev += 1
        r, jac = self.model.residuals_and_jacobian(self.x(z))
        return r, jac[:, self.free] * self.scale


# -- M1: particle swarm ---------------------------------------------------------------------------
def _pso(obj: _Objective, opt: BaselineOptions, rng: np.random.Generator):
    inertia, pull = 0.72, 1.49
    pos = rng.uniform(-1.0, 1.0, (opt.swarm, obj.n))
    pos[0] = 0.0  # the common initial guess is one of the particles
    vel = np.zeros_like(pos)
    best_pos, best_f = pos.copy(), np.array([obj.cost(p) for p in pos])
    history = []
    for _ in range(opt.max_iter):
        g = best_pos[np.argmin(best_f)]
        r1, r2 = rng.random((2, *pos.shape))
        vel = inertia * vel + pull * r1 * (best_pos - pos) + pull * r2 * (g - pos)
        pos = np.clip(pos + vel, -1.0, 1.0)
        f = np.array([obj.cost(p) for p in pos])
        better = f < best_f
        best_pos[better], best_f[better] = pos[better], f[better]
        history.append(best_f.min())
    return best_pos[np.argmin(best_f)], history, opt.max_iter


# -- M2, M3, M6: filters on a static state --------------------------------------------------------
def _row_batches(rows: np.ndarray, n_batches: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Residual indices of each batch: the sample rows in a seeded order, split in ``n_batches``."""
    order = rng.permutation(np.unique(rows))
    return [np.flatnonzero(np.isin(rows, part)) for part in np.array_split(order, n_batches) if part.size]


def _kalman_update(z, cov, innovation, cross, innovation_cov):
    """Kalman measurement update from the state-measurement ``cross`` covariance (n, m) and the
    ``innovation_cov`` (m, m)."""
    gain = np.linalg.solve(innovation_cov, cross.T).T
    cov = cov - gain @ innovation_cov @ gain.T
    return z + gain @ innovation, 0.5 * (cov + cov.T)


def _ekf_update(obj: _Objective, z, cov, idx, opt, rng):
    r, jac = obj.residuals_and_jacobian(z)
    h = jac[idx]
    cross = cov @ h.T
    z, cov = _kalman_update(z, cov, -r[idx], cross, h @ cross + np.eye(idx.size))
    return z, cov, 0.5 * float(r @ r)


def _ukf_update(obj: _Objective, z, cov, idx, opt, rng):
    """Symmetric sigma-point set (2n points at ``z +- sqrt(n cov)`` columns, weights 1/2n) plus the
    centre, which only gives the cost at ``z``."""
    n = z.size
    spread = np.linalg.cholesky(n * cov + 1e-12 * np.eye(n)).T
    points = np.vstack([z, z + spread, z - spread])
    y_all = np.array([obj.residuals(p) for p in points])
    y, dz = y_all[1:, idx], points[1:] - z
    y_mean = y.mean(axis=0)
    dy = y - y_mean
    w = 1.0 / (2 * n)
    z, cov = _kalman_update(z, cov, -y_mean, w * dz.T @ dy, w * dy.T @ dy + np.eye(idx.size))
    return z, cov, 0.5 * float(y_all[0] @ y_all[0])


def _pf_update(obj: _Objective, z, cov, idx, opt: BaselineOptions, rng: np.random.Generator):
    """Draw particles from N(z, cov), weight them by a tempered share of the batch likelihood,
    refit the Gaussian to the weighted particles; repeat until the whole likelihood is absorbed."""
    cost = obj.cost(z)
    absorbed = 0.0
    for _ in range(opt.max_steps):
        pts = rng.multivariate_normal(z, cov, opt.particles, method="cholesky")
        loglik = np.array([-0.5 * np.sum(obj.residuals(p)[idx] ** 2) for p in pts])
        phi = _tempering_step(loglik, 1.0 - absorbed, opt.particles / 2)
        w = np.exp(phi * (loglik - loglik.max()))
        w /= w.sum()
        z = w @ pts
        dev = pts - z
        cov = (w * dev.T) @ dev / (1.0 - w @ w) + 1e-12 * np.eye(z.size)
        absorbed += phi
        if absorbed >= 1.0:
            break
    return z, cov, cost


def _tempering_step(loglik: np.ndarray, remaining: float, ess_target: float) -> float:
    """Largest exponent ``phi <= remaining`` whose weights ``exp(phi loglik)`` keep the effective
    sample size ``1 / sum(w^2)`` at or above ``ess_target`` (bisection in log space)."""

    def ess(phi):
        w = np.exp(phi * (loglik - loglik.max()))
        return w.sum() ** 2 / (w @ w)

    if ess(remaining) >= ess_target:
        return remaining
    lo, hi = np.log(remaining) - 60.0, np.log(remaining)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess(np.exp(mid)) >= ess_target else (lo, mid)
    return float(np.exp(lo))


def _filter(update: Callable) -> Callable:
    """A recursive estimator from a measurement ``update(obj, z, cov, idx, opt, rng) -> (z, cov, cost
    at the incoming z)``: seeded batches, passes restarting the prior covariance (the box's half width is two
    standard deviations) around the last estimate."""

    def run(obj: _Objective, opt: BaselineOptions, rng: np.random.Generator):
        batches = _row_batches(obj.model.rows, opt.batches, rng)
        z, history = np.zeros(obj.n), []
        for _ in range(opt.passes):
            cov = 0.25 * np.eye(obj.n)
            for idx in batches:
                z, cov, cost = update(obj, z, cov, idx, opt, rng)
                history.append(cost)
        history = history[1:] + [obj.cost(z)]  # the cost after each update
        return z, history, len(history)

    return run


# -- M4: Gauss-Newton ------------------------------------------------------------------------------
def _gauss_newton(obj: _Objective, opt: BaselineOptions, rng: np.random.Generator):
    z, history = np.zeros(obj.n), []
    r, jac = obj.residuals_and_jacobian(z)
    cost = 0.5 * float(r @ r)
    for _ in range(opt.max_iter):
        z = z + np.linalg.lstsq(jac, -r, rcond=None)[0]
        r, jac = obj.residuals_and_jacobian(z)
        cost, previous = 0.5 * float(r @ r), cost
        history.append(cost)
        if abs(previous - cost) < opt.ftol * previous:
            break
    return z, history, len(history)


# -- M5, M7: scipy's global optimisers ---------------------------------------------------------------
def _annealing(obj: _Objective, opt: BaselineOptions, rng: np.random.Generator):
    trace = _BestTrace(obj.cost)
    box, budget = [(-1.0, 1.0)] * obj.n, opt.max_iter * obj.n  # evaluations, local searches included
    res = dual_annealing(
        trace,
        box,
        x0=np.zeros(obj.n),
        maxiter=opt.max_iter,
        maxfun=budget,
        rng=rng,
        minimizer_kwargs={
            "method": "L-BFGS-B",
            "jac": obj.gradient,
            "bounds": box,
            "options": {"maxfun": budget},
        },
    )
    # the best point evaluated: when the budget runs out inside a local search, scipy drops it
    return trace.best_z, trace.best[:: 2 * obj.n][1:] + [trace.best[-1]], res.nit


def _evolution(obj: _Objective, opt: BaselineOptions, rng: np.random.Generator):
    history = []
    res = differential_evolution(
        obj.cost,
        [(-1.0, 1.0)] * obj.n,
        x0=np.zeros(obj.n),
        maxiter=opt.max_iter,
        popsize=opt.popsize,
        tol=0.0,
        polish=False,
        rng=rng,
        callback=lambda intermediate_result: history.append(float(intermediate_result.fun)),
    )
    return res.x, history, res.nit


class _BestTrace:
    """Wraps a cost function; keeps the best cost after every evaluation and the best point."""

    def __init__(self, fun):
        self.fun, self.best, self.best_z = fun, [], None

    def __call__(self, z):
        f = self.fun(z)
        if not self.best or f < self.best[-1]:
            self.best_z = np.array(z, float)
        self.best.append(min(f, self.best[-1]) if self.best else f)
        return f


# -- M8: LMLC ----------------------------------------------------------------------------------------
class _CostRecorder:
    """The model with every Jacobian evaluation's cost ``|r|^2 / 2`` recorded (LM evaluates the
    Jacobian once per accepted iterate)."""

    def __init__(self, model: MeasurementModel):
        self.model, self.groups, self.costs, self.nfev = model, model.groups, [], 0

    def residuals_and_jacobian(self, x, jacobian=True):
        self.nfev += 1
        r, jac = self.model.residuals_and_jacobian(x, jacobian)
        if jacobian:
            self.costs.append(0.5 * float(r @ r))
        return r, jac


def _lmlc(model, x0, free, opt: BaselineOptions):
    recorder = _CostRecorder(model)
    result, _ = robust_fit(recorder, x0, free, opt.calibration)
    return result.x, recorder.costs[1:], len(recorder.costs) - 1, recorder.nfev


_SEARCHES = {
    "pso": _pso,
    "ekf": _filter(_ekf_update),
    "ukf": _filter(_ukf_update),
    "gn": _gauss_newton,
    "sa": _annealing,
    "pf": _filter(_pf_update),
    "de": _evolution,
}


def run_method(
    method: str,
    model: MeasurementModel,
    x0: np.ndarray,
    free: np.ndarray,
    options: BaselineOptions | None = None,
) -> MethodResult:
    """Run one calibrator on a model.

    Parameters
    ----------
    method : str
        One of ``METHODS``.
    model : MeasurementModel
        What is minimised (its whitened residuals).
    x0 : ndarray, shape (n,)
        Common start.
    free : ndarray of bool, shape (n,)
        The parameters every method moves.
    options : BaselineOptions, optional
        Budgets and seed.

    Returns
    -------
    MethodResult
        Solution, cost ``|r|^2 / 2``, iterations, cost history, evaluations and wall time.

    Raises
    ------
    ValueError
        ``method`` is not one of ``METHODS``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    options = options or BaselineOptions()
    start = time.perf_counter()
    if method == "lmlc":
        x, history, iterations, nfev = _lmlc(model, x0, free, options)
    else:
        obj = _Objective(model, x0, free)
        z, history, iterations = _SEARCHES[method](obj, options, np.random.default_rng(options.seed))
        x, nfev = obj.x(np.asarray(z)), obj.nfev
    elapsed = time.perf_counter() - start
    r = model.residuals(x)
    return MethodResult(
        method, x, 0.5 * float(r @ r), int(iterations), np.asarray(history, float), nfev, elapsed
    )

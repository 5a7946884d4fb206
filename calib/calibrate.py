"""The calibration pipeline on any measurement model: setup fit, identifiability, full robust fit.

1. "before": the nominal table held, only the setup unknowns fitted (the contract's baseline);
2. identifiability at that point: the model's structural gauges are held, then a rank-revealing
   selection over the column-scaled Jacobian (setup unknowns first, then the table joint by joint)
   holds whatever else the data cannot tell apart;
3. "after": LMLC over the identified table parameters and the setup unknowns, first with the linear
   loss, then with the robust loss whose scale is re-estimated from the residuals (MAD, per group).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.identifiability import redundancy_partners, select_columns
from calib.lm import LMOptions, LMResult, levenberg_marquardt, loss_terms, robust_scale
from calib.models import N_DH, MeasurementModel


@dataclass(frozen=True, kw_only=True)
class CalibrationOptions:
    """``loss``: "linear", "huber" or "cauchy"; ``loss_threshold``: where the robust loss starts to
    down-weight, in robust standard deviations; ``rank_rtol``: relative size below which a scaled
    Jacobian column counts as produced by the others; ``lm``: solver options."""

    loss: str = "cauchy"
    loss_threshold: float = 3.0
    rank_rtol: float = 1e-6
    lm: LMOptions = field(default_factory=LMOptions)


@dataclass
class Calibration:
    """Result: the ``before`` (setup-only) and ``after`` fits, the ``identified`` table/setup mask
    (free in the final fit), ``held`` parameters with reasons, parameter ``sigma`` (internal units,
    NaN where held), the residual ``scale`` per group and the ``downweighted`` sample rows."""

    names: tuple[str, ...]
    before: LMResult
    after: LMResult
    identified: np.ndarray
    held: dict[str, str]
    sigma: np.ndarray
    covariance: np.ndarray
    scale: np.ndarray
    downweighted: np.ndarray

    @property
    def x(self) -> np.ndarray:
        return self.after.x


def robust_fit(
    model: MeasurementModel, x0: np.ndarray, free: np.ndarray, options: CalibrationOptions, callback=None
) -> tuple[LMResult, np.ndarray]:
    """Linear-loss LM, then (unless ``options.loss`` is linear) two robust rounds, each with the
    loss scale re-estimated from the previous residuals. Returns the result and the scale used."""
    fun = model.residuals_and_jacobian
    lm = options.lm
    kw = dict(free=free, groups=model.groups, callback=callback)
    result = levenberg_marquardt(fun, x0, options=_with(lm, loss="linear"), **kw)
    scale = robust_scale(result.residuals, model.groups)
    if options.loss == "linear":
        return result, scale
    history = list(result.history)
    for _ in range(2):
        loss_scale = options.loss_threshold * scale
        result = levenberg_marquardt(
            fun, result.x, options=_with(lm, loss=options.loss, loss_scale=loss_scale), **kw
        )
        history += result.history
        scale = robust_scale(result.residuals, model.groups)
    result.history = history
    return result, scale


def identify(
    model: MeasurementModel, x: np.ndarray, free_setup: np.ndarray, gauges: dict[str, str], rtol: float
) -> tuple[np.ndarray, dict[str, str]]:
    """Mask of the table parameters the data determines at ``x`` and the reasons for the others."""
    _, jac = model.residuals_and_jacobian(x)
    names = model.names
    candidates = [k for k in range(N_DH) if names[k] not in gauges]
    order = np.concatenate([np.flatnonzero(free_setup), candidates]).astype(int)
    kept = select_columns(jac, order, rtol)
    held = {n: r for n, r in gauges.items() if n in names}
    for k in candidates:
        if not kept[k]:
            partners = ", ".join(redundancy_partners(jac, k, kept, names))
            held[names[k]] = f"the data cannot tell it apart from {partners}"
    table = np.zeros(len(names), bool)
    table[candidates] = kept[candidates]
    return table, held


def calibrate(
    model: MeasurementModel, options: CalibrationOptions = CalibrationOptions(), callback=None
) -> Calibration:
    """Run the whole pipeline on ``model`` (see the module docstring)."""
    names = model.names
    gauges = model.gauges()
    free_setup = model.setup_mask & ~np.isin(names, list(gauges))
    before, _ = robust_fit(model, model.x0, free_setup, options)
    table, held = identify(model, before.x, free_setup, gauges, options.rank_rtol)
    free = free_setup | table
    after, scale = robust_fit(model, before.x, free, options, callback)
    sigma, cov = _uncertainty(after)
    full_sigma = np.full(len(names), np.nan)
    full_sigma[free] = sigma
    return Calibration(
        names=names,
        before=before,
        after=after,
        identified=free,
        held=held,
        sigma=full_sigma,
        covariance=cov,
        scale=scale,
        downweighted=_downweighted_rows(model, after, scale, options),
    )


def _uncertainty(result: LMResult) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviations and covariance of the free parameters, scaled by the fitted noise."""
    wj = result.jacobian * result.weights[:, None]
    wr = result.residuals * result.weights
    dof = max(wj.shape[0] - wj.shape[1], 1)
    cov = np.linalg.pinv(wj.T @ wj) * (wr @ wr / dof)
    return np.sqrt(np.diag(cov)), cov


def _downweighted_rows(model, result: LMResult, scale, options: CalibrationOptions) -> np.ndarray:
    """Sample rows with a residual whose robust weight fell below one half."""
    if options.loss == "linear":
        return np.array([], int)
    _, w = loss_terms(result.residuals, options.loss_threshold * scale[model.groups], options.loss)
    return np.unique(model.rows[w**2 < 0.5])


def _with(lm: LMOptions, **changes) -> LMOptions:
    return LMOptions(**{**lm.__dict__, **changes})

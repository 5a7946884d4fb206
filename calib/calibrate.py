"""The calibration pipeline on any measurement model: setup fit, identifiability, full robust fit.

1. "before": the nominal robot held (the table as built, no joint-space terms), only the setup
   unknowns fitted (the contract's baseline);
2. identifiability at that point: the model's structural gauges are held, then a rank-revealing
   selection over the column-scaled Jacobian (setup unknowns first, then the table joint by joint,
   then the joint-space terms) holds whatever else the data cannot tell apart;
3. "after": LMLC over the identified robot parameters (table and terms) and the setup unknowns,
   first with the linear loss, then with the robust loss whose scale is re-estimated from the
   residuals (MAD, per group); then identifiability again at the fitted table, and the fit again
   with what the nominal table's degeneracies held and the rows demand (``reidentify``);
4. where the residuals show an error that neighbouring poses share (``calib.discrepancy``), the
   same fit again by generalised least squares under it, the robust weights kept (``correlate``).

The robot's parameters are everything of ``x`` that is not setup (``~model.setup_mask``): the table,
then the terms (``calib.joint_terms``). Step 2's selection is ``calib.identifiability.identify``;
the unknowns' covariance after each fit, ``calib.uncertainty``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib.discrepancy import Blocks, Correlated, Discrepancy, estimate, tcp_rms_mm
from calib.identifiability import identify
from calib.lm import (
    NORMAL_ROWS,
    LMOptions,
    LMResult,
    block_sum,
    levenberg_marquardt,
    loss_terms,
    robust_scale,
    row_blocks,
    weighted_blocks,
)
from calib.models import GROUP_PRIOR, MeasurementModel, thinned
from calib.special import gammaincc
from calib.uncertainty import row_noise, uncertainty, workspace_mask

COARSE_ROWS = 20_000
"""Sample rows above which ``robust_fit`` first fits this many of them (``coarse``) and finishes on
all rows from there: each of its rounds still converges on all rows, to the same minimum within the
solver's tolerances, in a few iterations over all rows instead of some twenty."""

SETTLED_SCALE = 0.01
"""Relative change of every group's loss scale below which a robust round on many rows starts from
the previous round's solution on all rows, without its subset's run first (``robust_fit``)."""

FREED_P = 5.7e-7
"""Parameters held at the nominal table and seen at the fitted one (``reidentify``) are freed when
their move off the held values is significant (``freed_p``) below this p: five sigma, as
``calib.selection.DISCOVERY_P``, for a choice made after looking at the rows."""

FREED_STEPS = 3
"""Gauss-Newton steps (``robust_steps``) from the fit to where ``freed_p`` judges the freed
parameters: on the sweep plan's noise-free seeds 1 and 9 their chi-square there is the full
refit's to four digits (one step: a hundredth of it, the residuals still carrying the misfit)."""

DOWNWEIGHTED_BELOW = 0.25
"""A residual row whose squared robust weight falls below this counts as down-weighted (a gross
reading): for the Cauchy loss at 3 noise scales, beyond 5.2 of them."""


def coarse_draw(model: MeasurementModel) -> MeasurementModel:
    """``model`` on ``COARSE_ROWS`` of its sample rows, a fixed draw spread over all of them
    (``calib.models.thinned``), itself if it has no more: where many rows' model checks (the term
    choice's cross-validation, the dial check) run, on the rows the robust fits start from."""
    return thinned(model, COARSE_ROWS)


class WithPrior:
    """A model plus Gaussian prior residuals ``(x_k - x_ref_k) / sigma_k``.

    One prior row for every unknown with a finite prior sigma (``model.prior_sigma()``: the
    manufacturing tolerance of the table, the rough setup values): a direction the data cannot see
    stays where the robot was built instead of wandering. Prior rows carry group ``GROUP_PRIOR`` and
    row -1.

    Parameters
    ----------
    model : MeasurementModel
        The data's model.
    x_ref : ndarray, shape (n,)
        Where the prior centres each unknown, internal units.
    """

    def __init__(self, model: MeasurementModel, x_ref: np.ndarray):
        self.model, self.x_ref = model, np.asarray(x_ref, float)
        sigma = model.prior_sigma()
        self._k = np.flatnonzero(np.isfinite(sigma))
        self._inv = 1.0 / sigma[self._k]
        self.names, self.x0, self.setup_mask = model.names, model.x0, model.setup_mask
        self.tool_mask = model.tool_mask
        self.groups = np.concatenate([model.groups, np.full(self._k.size, GROUP_PRIOR)])
        self.rows = np.concatenate([model.rows, np.full(self._k.size, -1)])
        self.prior_names = tuple(self.names[k] for k in self._k)
        """The unknown of each prior row, in their order after the model's rows."""

    def coarse(self) -> WithPrior | None:
        """This model on ``COARSE_ROWS`` of its sample rows, a fixed draw spread over all of them
        (every k-th row would alias with a session's repeated poses), or None where it has no more
        (or its rows cannot be taken apart)."""
        samples = getattr(self.model, "samples", None)
        if samples is None or len(samples) <= COARSE_ROWS:
            return None
        return WithPrior(coarse_draw(self.model), self.x_ref)

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True):
        """The model's whitened residuals and Jacobian at ``x`` (n,), the prior rows appended: into
        the model's own Jacobian where it leaves room for them (``residuals_and_tall_jacobian``),
        else to a copy."""
        tall = getattr(self.model, "residuals_and_tall_jacobian", None)
        if jacobian and tall is not None:
            r, jac = tall(x, self._k.size)
        else:
            r, jac = self.model.residuals_and_jacobian(x, jacobian)
            if jacobian:
                jac = np.vstack([jac, np.zeros((self._k.size, x.size))])
        if jacobian:
            jac[r.size + np.arange(self._k.size), self._k] = self._inv
        r = np.concatenate([r, (x[self._k] - self.x_ref[self._k]) * self._inv])
        return r, jac


@dataclass(frozen=True, kw_only=True)
class CalibrationOptions:
    """Options of the pipeline.

    Attributes
    ----------
    loss : {"linear", "huber", "cauchy"}
        Loss of the robust rounds.
    loss_threshold : float
        Where the robust loss starts to down-weight, in noise scales of each group: the robust
        (MAD) scale, never below the stated noise.
    rank_rtol : float
        Relative size below which a scaled Jacobian column counts as produced by the others.
    hold_weak : bool
        Hold a parameter the data determines no better than its prior (True), or estimate it under
        its prior (False); exact redundancies are held either way.
    lm : LMOptions
        Solver options.
    correlated : bool
        Weigh the fit by the model's discrepancy where the rows show one (``correlate``).
    """

    loss: str = "cauchy"
    loss_threshold: float = 3.0
    rank_rtol: float = 1e-6
    hold_weak: bool = False
    lm: LMOptions = field(default_factory=LMOptions)
    correlated: bool = True


@dataclass
class Calibration:
    """The pipeline's result.

    Attributes
    ----------
    names : tuple of str
        The model's unknowns (n).
    before, after : LMResult
        The setup-only fit with the nominal table, and the full fit.
    identified : ndarray of bool, shape (n,)
        Unknowns free in the final fit (identified robot parameters and setup unknowns).
    held : dict of str to str
        Held parameters and why.
    sigma : ndarray, shape (n,)
        Standard deviation of each unknown, internal units; NaN where held.
    covariance : ndarray, shape (k, k)
        Covariance of the k free unknowns, internal units.
    robot_covariance : ndarray, shape (r, r)
        Covariance of what the TCP's workspace error depends on (``workspace_mask``: the table, the
        TCP where the model fits it, the terms), the held ones considered at their prior.
    robot_index : ndarray of int, shape (r,)
        Where ``robot_covariance``'s rows are in ``x``.
    scale : ndarray, shape (groups,)
        Fitted noise scale per residual group, in units of the stated noise.
    downweighted : ndarray of int
        Sample rows the robust loss cut to below a quarter of their weight.
    discrepancy : Discrepancy or None
        The joint-space error the fit was weighted by (``correlate``), None for a white fit.
    """

    names: tuple[str, ...]
    before: LMResult
    after: LMResult
    identified: np.ndarray
    held: dict[str, str]
    sigma: np.ndarray
    covariance: np.ndarray
    robot_covariance: np.ndarray
    robot_index: np.ndarray
    scale: np.ndarray
    downweighted: np.ndarray
    discrepancy: Discrepancy | None = None

    @property
    def x(self) -> np.ndarray:
        """The solution (n,), internal units."""
        return self.after.x


def robust_fit(
    model: MeasurementModel,
    x0: np.ndarray,
    free: np.ndarray,
    options: CalibrationOptions,
    callback=None,
    scale0: np.ndarray | None = None,
) -> tuple[LMResult, np.ndarray]:
    """Linear-loss LM, then (unless ``options.loss`` is linear) two robust rounds, each with the
    loss scale re-estimated from the previous residuals (MAD per residual group). On more than
    ``COARSE_ROWS`` sample rows each round starts from the same round on ``WithPrior.coarse``'s
    rows (coarse to fine: on all rows it then takes a few iterations) unless its loss scale is the
    previous round's within ``SETTLED_SCALE`` (its minimum is then that round's), and the robust
    rounds from the damping the run before ended with. Given the noise
    scale at ``x0`` (``scale0``: a fit that ended there, e.g. the setup's), the first round is robust
    at that scale too: least squares with every unknown free would bend the table towards a wild
    reading (36 rows, one 1000 mm off: the table 1.6 m wrong), and the robust rounds would start
    from there.

    Parameters
    ----------
    model : MeasurementModel or WithPrior
        Residuals and Jacobian, ``groups`` per residual.
    x0 : ndarray, shape (n,)
        Start, internal units.
    free : ndarray of bool, shape (n,)
        Unknowns to fit; the others stay at ``x0``.
    options : CalibrationOptions
        Loss and solver options.
    callback : callable, optional
        Called by the solver after each trial step.
    scale0 : ndarray, shape (groups,), optional
        Noise scale per residual group at ``x0``.

    Returns
    -------
    result : LMResult
        The last round's fit, with the history of every round.
    scale : ndarray, shape (groups,)
        Noise scale per residual group at the result.
    """
    lm = options.lm
    first = _with(lm, loss="linear")
    if scale0 is not None and options.loss != "linear":
        first = _with(lm, loss=options.loss, loss_scale=loss_scale(scale0, options))
    coarse = model.coarse() if isinstance(model, WithPrior) else None
    result = _fit(model, x0, free, first, callback, coarse)
    scale = _scale(result.residuals, model.groups)
    if options.loss == "linear":
        return result, scale
    history = list(result.history)
    before = scale0
    for _ in range(2):
        lm_round = _with(lm, loss=options.loss, loss_scale=loss_scale(scale, options))
        settled = before is not None and np.allclose(scale, before, rtol=SETTLED_SCALE, atol=0.0)
        if coarse is not None:
            lm_round = _carried(lm_round, result)
        result = _fit(model, result.x, free, lm_round, callback, None if settled else coarse)
        history += result.history
        before, scale = scale, _scale(result.residuals, model.groups)
    result.history = history
    return result, scale


def _fit(model, x: np.ndarray, free: np.ndarray, lm: LMOptions, callback, coarse) -> LMResult:
    """``levenberg_marquardt`` on ``model`` from ``x`` over ``x[free]``; where ``coarse`` (a
    ``WithPrior`` on fewer rows) is given, from its run with the same options, at the damping that
    run ended with (coarse to fine: the run on all rows then starts within the subset's spread of
    its minimum, with the steps the damping has grown to trust)."""
    if coarse is not None:
        start = levenberg_marquardt(
            coarse.residuals_and_jacobian, x, options=lm, free=free, groups=coarse.groups
        )
        x, lm = start.x, _carried(lm, start)
    return levenberg_marquardt(
        model.residuals_and_jacobian, x, options=lm, free=free, groups=model.groups, callback=callback
    )


def _carried(lm: LMOptions, result: LMResult) -> LMOptions:
    """``lm`` starting at the damping ``result``'s last trial used where that is smaller (a run that
    ended at its minimum; never a larger one: a run stopped by the damping's growth would hand on
    steps too short to move)."""
    if not result.history:
        return lm
    return _with(lm, damping=min(result.history[-1].damping, lm.damping))


def robust_steps(
    model: WithPrior, x: np.ndarray, free: np.ndarray, steps: int, options: CalibrationOptions
) -> np.ndarray:
    """``steps`` Gauss-Newton steps on ``robust_fit``'s cost from ``x`` (n,) over ``x[free]``, each
    weighted by the robust loss at the noise scale of the residuals it starts from (iteratively
    reweighted least squares): from a neighbouring solution (the same rows' calibration with one
    channel more) they land where ``robust_fit`` would, at one Jacobian a step instead of an LM
    run's three rounds. Returns the last step's solution (n,)."""
    x = np.array(x, float)
    for _ in range(steps):
        r, jac = model.residuals_and_jacobian(x)
        w = robust_weights(r, model.groups, _scale(r, model.groups), options)
        x[free] -= scaled_least_squares(jac, free, w, r * w)
    return x


def scaled_least_squares(jac: np.ndarray, free: np.ndarray, w: np.ndarray, wr: np.ndarray) -> np.ndarray:
    """numpy's least-squares solution ``dx`` (k,) of ``W J dx = W r``: the ``free`` columns (k) of
    ``jac`` (m, n) weighted by ``w`` (m,), scaled to unit norm, against ``wr = W r`` (m,). On rows
    that fit one block (``NORMAL_ROWS``) of the whole weighted copy, as before; on more, of ``R``
    of the QR factorisation of ``[W J / d | W r]`` built block by block (the same solution and
    singular-value cut, without m-row copies: a million rows' is some 1.5 GB each)."""
    if len(jac) <= NORMAL_ROWS:
        wj = jac[:, free] * w[:, None]
        d = np.linalg.norm(wj, axis=0)
        d[d == 0] = 1.0
        return np.linalg.lstsq(wj / d, wr, rcond=None)[0] / d
    cols = np.flatnonzero(free)
    d = np.sqrt(block_sum(np.sum(wj**2, axis=0) for wj in weighted_blocks(jac, cols, w)))
    d[d == 0] = 1.0
    r = np.empty((0, cols.size + 1))
    for wj, wr_block in zip(weighted_blocks(jac, cols, w), row_blocks(wr), strict=True):
        r = np.linalg.qr(np.vstack([r, np.column_stack([wj / d, wr_block])]), mode="r")
    cut = np.finfo(float).eps * max(len(jac), cols.size)  # lstsq's own on the m rows
    return np.linalg.lstsq(r[: cols.size, : cols.size], r[: cols.size, cols.size], rcond=cut)[0] / d


@dataclass
class SetupFit:
    """Steps 1-2 of the pipeline, all a table fit starts from.

    Attributes
    ----------
    prior : WithPrior
        The prior-augmented model the fits use.
    before : LMResult
        The setup-only fit with the nominal table (the contract's "before").
    free : ndarray of bool, shape (n,)
        Unknowns to fit: the setup's not held and the identified table parameters.
    held : dict of str to str
        Held parameters and why.
    scale : ndarray, shape (groups,)
        Noise scale per residual group at ``before``.
    """

    prior: WithPrior
    before: LMResult
    free: np.ndarray
    held: dict[str, str]
    scale: np.ndarray

    def before_of(self, prior: WithPrior) -> LMResult:
        """``before`` as the setup-only fit of ``prior`` (started at its model's ``x0``): the same rows
        and setup with other joint-space terms, those this fit lacks at zero. Terms at zero move no
        row, so the fit is the same: its solution, residuals and weights by unknown (a new term's
        prior row: residual 0, weight 1). Raises ``ValueError`` for another model."""
        mine, before = self.prior, self.before
        at = {name: i for i, name in enumerate(mine.names)}
        new = np.array([name not in at for name in prior.names])
        m = mine.model.rows.size
        if prior.model.rows.size != m or np.any(prior.x0[new] != 0.0) or np.any(prior.setup_mask[new]):
            raise ValueError("before_of: not the same rows and setup with other joint-space terms at zero")
        shared = [at[name] for name in np.asarray(prior.names)[~new]]
        x, free = prior.x0.copy(), np.zeros(new.size, bool)
        x[~new], free[~new] = before.x[shared], before.free[shared]
        rows = dict(zip(mine.prior_names, range(m, before.residuals.size), strict=True))
        pick = [rows.get(name, -1) for name in prior.prior_names]
        residuals = np.concatenate([before.residuals, [0.0]])[np.r_[np.arange(m), pick]]
        weights = np.concatenate([before.weights, [1.0]])[np.r_[np.arange(m), pick]]
        return replace(before, x=x, residuals=residuals, weights=weights, free=free)


def fit_setup(
    model: MeasurementModel, options: CalibrationOptions = CalibrationOptions(), held: SetupFit | None = None
) -> SetupFit:
    """Steps 1-2 of the pipeline: fit the setup unknowns with the nominal table, then identify.

    Parameters
    ----------
    model : MeasurementModel
        The data's model, started at the nominal table.
    options : CalibrationOptions
        Loss, rank tolerance and solver options.
    held : SetupFit, optional
        The same rows' steps 1-2 with other joint-space terms (``model``'s others at zero): their
        setup-only fit is this model's (``SetupFit.before_of``), only the identification is redone.

    Returns
    -------
    SetupFit
    """
    gauges = model.gauges()
    free_setup = setup_unknowns(model)
    if held is None:
        prior, before, scale = hold_robot(model, model.x0, options)
    else:
        prior = WithPrior(model, model.x0)
        before, scale = held.before_of(prior), held.scale
    table, held_names = identify(model, before.x, free_setup, gauges, options.rank_rtol, options.hold_weak)
    return SetupFit(prior, before, free_setup | table, held_names, scale)


def setup_unknowns(model: MeasurementModel) -> np.ndarray:
    """The setup unknowns a fit determines, shape (n,) of bool: all but the model's gauges."""
    return model.setup_mask & ~np.isin(model.names, list(model.gauges()))


def hold_robot(
    model: MeasurementModel, x: np.ndarray, options: CalibrationOptions = CalibrationOptions()
) -> tuple[WithPrior, LMResult, np.ndarray]:
    """The setup unknowns fitted with the robot (table and terms) held at ``x``'s (n,): the
    contract's "before" at the nominal robot, ``station verify`` at a corrected one. Returns the
    prior-augmented model (centred at ``x``), the fit and its noise scale per residual group."""
    held = WithPrior(model.holding_robot(), x)
    result, scale = robust_fit(held, np.asarray(x, float), setup_unknowns(model), options)
    return WithPrior(model, x), result, scale


def calibrate(
    model: MeasurementModel,
    options: CalibrationOptions = CalibrationOptions(),
    callback=None,
    start: SetupFit | None = None,
) -> Calibration:
    """Run the whole pipeline on ``model`` (see the module docstring).

    Parameters
    ----------
    model : MeasurementModel
        The data's model, started at the nominal table.
    options : CalibrationOptions
        Loss, rank tolerance and solver options.
    callback : callable, optional
        Called by the solver after each trial step of the full fit.
    start : SetupFit, optional
        Steps 1-2 already run on ``model`` with ``options`` (``fit_setup``; the fits run on its
        ``prior``); default: run them.

    Returns
    -------
    Calibration
        Fitted on ``model.by_axes()`` (the faster frame composition; planning keeps the products).
    """
    model = model.by_axes()
    start = fit_setup(model, options) if start is None else start
    after, scale = robust_fit(start.prior, start.before.x, start.free, options, callback, start.scale)
    start, after, scale = reidentify(model, start, after, scale, options, callback)
    sigma, cov, robot_cov = uncertainty(start.prior, after, start.free, scale)
    full_sigma = np.full(len(model.names), np.nan)
    full_sigma[start.free] = sigma
    cal = Calibration(
        names=model.names,
        before=start.before,
        after=after,
        identified=start.free,
        held=start.held,
        sigma=full_sigma,
        covariance=cov,
        robot_covariance=robot_cov,
        robot_index=np.flatnonzero(workspace_mask(model)),
        scale=scale,
        downweighted=_downweighted_rows(start.prior, after, scale, options),
    )
    return correlate(model, cal, options) if options.correlated else cal


def reidentify(
    model: MeasurementModel,
    start: SetupFit,
    after: LMResult,
    scale: np.ndarray,
    options: CalibrationOptions,
    callback=None,
) -> tuple[SetupFit, LMResult, np.ndarray]:
    """The fit ``after`` (from ``start``, noise ``scale`` per group) again with the robot parameters
    held at the nominal table that the rows determine at the fitted one, where they demand them.

    At the nominal table a degeneracy (the TCP on joint 6's axis, parallel axes) holds parameters
    that a real robot's table does not share; what they leave, the free ones cannot absorb. So
    ``identify`` runs again at ``after.x`` with the model's structural gauges there; the newly seen
    parameters are freed where their move is significant (``freed_p`` below ``FREED_P``) and the
    fit is rerun from ``after.x`` with them; else ``after`` stays. Both judged, above
    ``COARSE_ROWS`` sample rows, on the draw the robust fits start from (``WithPrior.coarse``, as the
    term choice's and the dial check's: on all of a million rows they cost 7.8 s and 0.5 GB more).
    Returns the setup fit with the freed parameters free and no longer held, the fit and its noise
    scale.
    """
    judged = start.prior.coarse() or start.prior
    rows = model if judged is start.prior else judged.model
    gauges = rows.gauges(after.x)
    found, _ = identify(rows, after.x, setup_unknowns(rows), gauges, options.rank_rtol, options.hold_weak)
    freed = found & ~start.free
    if not freed.any() or freed_p(judged, after, start.free | freed, freed, options) >= FREED_P:
        return start, after, scale
    refit, refit_scale = robust_fit(start.prior, after.x, start.free | freed, options, callback, scale)
    held = {name: why for name, why in start.held.items() if name not in np.asarray(model.names)[freed]}
    return replace(start, free=start.free | freed, held=held), refit, refit_scale


def freed_p(
    model: WithPrior, after: LMResult, free: np.ndarray, freed: np.ndarray, options: CalibrationOptions
) -> float:
    """Chi-square p of the ``freed`` parameters (n,) staying where the fit ``after`` held them:
    ``FREED_STEPS`` Gauss-Newton steps from ``after.x`` over ``free`` (n,) move them by ``dx``, and
    ``dx^T C^-1 dx`` against their covariance ``C`` there (``calib.uncertainty.uncertainty``: the
    noise the steps' residuals show, a sweep's shared errors) is chi-square with as many degrees as
    parameters."""
    x = robust_steps(model, after.x, free, FREED_STEPS, options)
    r = model.residuals_and_jacobian(x, jacobian=False)[0]
    scale = _scale(r, model.groups)
    stepped = replace(after, x=x, residuals=r, weights=robust_weights(r, model.groups, scale, options))
    at = freed[free]
    cov = uncertainty(model, stepped, free, scale)[1][np.ix_(at, at)]
    dx = (x - after.x)[freed]
    return gammaincc(dx.size / 2, float(dx @ np.linalg.solve(cov, dx)) / 2)


def correlate(model: MeasurementModel, cal: Calibration, options: CalibrationOptions) -> Calibration:
    """``cal`` refitted by generalised least squares under the model's discrepancy, where its
    residuals show one (``calib.discrepancy``); else ``cal`` itself.

    The white fit's robust weights stay (its gross readings stay out) and so do its ``scale`` and
    ``downweighted`` (the rows' spread, what the noise checks read); the solution, its residuals and
    its covariance are the weighted fit's.
    """
    if not model.pose_groups:
        return cal
    prior = WithPrior(model, model.x0)
    r, jac = prior.residuals_and_jacobian(cal.x)
    weights = cal.after.weights
    blocks = Blocks(prior.rows, prior.groups, model.pose_groups, model.samples.q, weights)
    found = estimate(r, jac[:, cal.identified], row_noise(prior, cal.scale), blocks, weights)
    if found is None:
        return cal
    weighted = Correlated(prior, blocks, found, weights)
    result = levenberg_marquardt(
        weighted.residuals_and_jacobian,
        cal.x,
        options=_with(options.lm, loss="linear"),
        free=cal.identified,
        groups=prior.groups,
    )
    scale = _scale(result.residuals, prior.groups)
    sigma, cov, robot_cov = uncertainty(weighted, result, cal.identified, scale)
    full_sigma = np.full(len(model.names), np.nan)
    full_sigma[cal.identified] = sigma
    after = replace(
        result,
        residuals=prior.residuals_and_jacobian(result.x, jacobian=False)[0],
        weights=weights,
        history=cal.after.history + result.history,
    )
    components = blocks.tables[0].shape[1]
    found = replace(found, tcp_rms_mm=tcp_rms_mm(found, model.row_error_mm(result.x), components))
    return replace(
        cal, after=after, sigma=full_sigma, covariance=cov, robot_covariance=robot_cov, discrepancy=found
    )


def loss_scale(scale: np.ndarray, options: CalibrationOptions) -> np.ndarray:
    """Where the robust loss starts to down-weight, per residual group (whitened units):
    ``loss_threshold`` fitted noise scales, never fewer than ``loss_threshold`` stated noises. A row
    within a few stated sigmas is no gross reading, however much better the instruments read than
    stated (averaged or quantised readings put the MAD at a fraction of it, and a threshold there
    flagged clean rows: ``benchmarks/false_alarms.py``)."""
    return options.loss_threshold * np.maximum(scale, 1.0)


def _scale(residuals: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Robust noise scale per residual group; prior rows are never down-weighted."""
    scale = robust_scale(residuals, groups)
    if scale.size > GROUP_PRIOR:
        scale[GROUP_PRIOR] = 1e6
    return scale


def robust_weights(
    residuals: np.ndarray, groups: np.ndarray, scale: np.ndarray, options: CalibrationOptions
) -> np.ndarray:
    """The robust loss's weights ``sqrt(rho')`` (m,) of whitened ``residuals`` (m,) in residual
    ``groups`` (m,), at a calibration's noise ``scale`` (per group); 1 for the linear loss."""
    return loss_terms(residuals, loss_scale(scale, options)[groups], options.loss)[1]


def _downweighted_rows(model, result: LMResult, scale, options: CalibrationOptions) -> np.ndarray:
    """Sample rows the robust loss down-weighted (``DOWNWEIGHTED_BELOW``): the gross readings."""
    if options.loss == "linear":
        return np.array([], int)
    w = robust_weights(result.residuals, model.groups, scale, options)
    rows = model.rows[w**2 < DOWNWEIGHTED_BELOW]
    return np.unique(rows[rows >= 0])


def _with(lm: LMOptions, **changes) -> LMOptions:
    return LMOptions(**{**lm.__dict__, **changes})

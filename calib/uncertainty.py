"""The unknowns' uncertainty after a fit (``calib.calibrate``'s last step): the sandwich covariance
of the fit as it was weighted, each row's fitted noise, the blocks of a sweep's passes whose rows
share their errors, and what the TCP's workspace error depends on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from calib.accuracy import robot_covariance
from calib.lm import LMResult, block_sum, row_blocks, weighted_blocks
from calib.models import GROUP_PRIOR, MeasurementModel
from calib.serial import block_covariance, pass_blocks

if TYPE_CHECKING:
    from calib.calibrate import WithPrior


def uncertainty(model: WithPrior, result: LMResult, free: np.ndarray, scale: np.ndarray):
    """Standard deviations and covariance of the free unknowns and the robot's covariance, of the
    fit as it was weighted (stated noise, robust weights), each instrument's rows with the noise
    the fit found (``scale``, per group)."""
    noise, shared = row_noise(model, scale), None
    blocks = sweep_blocks(model)
    if blocks is not None:  # a sweep's rows share their errors: their blocks' spread, not the noise's
        noise = np.where(blocks >= 0, 0.0, noise)
        shared = swept_covariance(model, result, free, blocks)
    cov, robot_cov = covariance(model, result.x, free, result.weights, noise, shared)
    return np.sqrt(np.diag(cov)), cov, robot_cov


def swept_covariance(model: WithPrior, result: LMResult, free: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """The swept rows' covariance of the free unknowns (``calib.serial.block_covariance``); the
    Jacobian freed before ``covariance`` takes its own."""
    jac = model.residuals_and_jacobian(result.x)[1]
    return block_covariance(jac, np.flatnonzero(free), result.weights, result.residuals, blocks)


def sweep_blocks(model: WithPrior) -> np.ndarray | None:
    """Each residual's block of a sweep pass (m,) (``calib.serial.pass_blocks``; -1 for rows of no
    pass and the prior); None for a set without passes."""
    samples = model.model.samples
    if getattr(samples, "sweep_pass", None) is None:
        return None
    blocks = np.append(pass_blocks(samples.sweep_pass, samples.t_s), -1)
    return blocks[np.where(model.rows >= 0, model.rows, -1)]


def row_noise(model: WithPrior, scale: np.ndarray) -> np.ndarray:
    """Each row's fitted noise in units of its stated noise (m,): its group's ``scale``; 1 for the
    prior rows (what was known before measuring does not shrink because the instruments read
    better than stated)."""
    return np.where(model.groups == GROUP_PRIOR, 1.0, scale[model.groups])


def covariance(
    model: WithPrior,
    x: np.ndarray,
    free: np.ndarray,
    row_weights: np.ndarray | float = 1.0,
    noise: np.ndarray | float = 1.0,
    shared: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the ``free`` unknowns and of the robot, the held parameters considered.

    The fit minimised ``|W r|^2`` with ``r`` the rows whitened by their stated noise and ``W`` the
    robust weights; the rows' actual noise is ``noise`` (stated units). Where the instruments read
    otherwise than stated, that fit is not the best-weighted one, and its covariance is the
    sandwich::

        A = W J,   C = (A^T A)^-1 A^T diag(W^2 noise^2) A (A^T A)^-1

    (``(A^T A)^-1`` when the noise is as stated). A held parameter moves the fit by
    ``-(A^T A)^-1 A^T W J_held`` per unit (``accuracy.robot_covariance``). The robot here is what the
    TCP's workspace error depends on (``workspace_mask``): the table, the terms and, where the model
    fits it (``model.tool_mask``: a tracker's probe), the TCP in the flange frame; so a held
    parameter the fitted TCP absorbs (any change of the last link, on a tracker) shifts the TCP
    instead and leaves the measured point where it is. Each held robot parameter counts at its
    prior (``model.prior_sigma()``).

    Parameters
    ----------
    model : WithPrior
        The prior-augmented model.
    x : ndarray, shape (n,)
        Where to linearise, internal units.
    free : ndarray of bool, shape (n,)
        The fitted unknowns (k of them).
    row_weights : ndarray, shape (m,), or float
        The fit's robust weights ``W``.
    noise : ndarray, shape (m,), or float
        Each row's actual noise in units of its stated noise (``row_noise``).
    shared : ndarray, shape (k, k), optional
        Covariance of the free unknowns from rows whose ``noise`` is 0 here: a sweep's rows, which
        share their errors (``calib.serial.block_covariance``).

    Returns
    -------
    covariance : ndarray, shape (k, k)
        Of the free unknowns, internal units.
    robot_covariance : ndarray, shape (r, r)
        Of ``workspace_mask(model)``'s entries, internal units, with the held ones considered.
    """
    _, jac = model.residuals_and_jacobian(x)
    w, noise = np.broadcast_to(row_weights, model.groups.shape), np.broadcast_to(noise, model.groups.shape)
    held = np.flatnonzero(~model.setup_mask & ~free)
    inverse = np.linalg.pinv(block_sum(a.T @ a for a in weighted_blocks(jac, np.flatnonzero(free), w)))
    cov = cross = None
    for a, a_held, w_block, noise_block in zip(
        weighted_blocks(jac, np.flatnonzero(free), w),
        weighted_blocks(jac, held, w),
        row_blocks(w),
        row_blocks(noise),
        strict=True,
    ):
        gain = inverse @ a.T  # the fit's response to these weighted rows
        spread = gain * w_block * noise_block
        products = spread @ spread.T, -gain @ a_held
        cov, cross = products if cov is None else (cov + products[0], cross + products[1])
    cov = cov if shared is None else cov + shared
    robot = np.flatnonzero(workspace_mask(model))
    robot_cov = robot_covariance(
        cov, cross, np.flatnonzero(free), held, model.model.prior_sigma()[held], robot
    )
    return cov, robot_cov


def workspace_mask(model: MeasurementModel) -> np.ndarray:
    """What the TCP's workspace error depends on, shape (n,) of bool: the robot's parameters (the
    table, the terms) and the TCP's flange coordinates where the model fits them; in ``x``'s order,
    which is table, TCP, terms (``accuracy.workspace_error_modes`` takes them so)."""
    return ~model.setup_mask | model.tool_mask

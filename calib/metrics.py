"""Accuracy figures: the contract's metrics and the workspace error after a rigid re-fit of the base."""

from __future__ import annotations

import numpy as np


def error_metrics(err_mm: np.ndarray) -> dict[str, float]:
    """The contract's metrics of residuals.

    Parameters
    ----------
    err_mm : array_like, shape (N,), N >= 1
        Residuals [mm].

    Returns
    -------
    dict
        ``rmse_mm`` (root mean square), ``mean_mm`` (mean absolute), ``max_mm`` (maximum absolute).
    """
    a = np.abs(np.asarray(err_mm, float))
    return {"rmse_mm": float(np.sqrt(np.mean(a**2))), "mean_mm": float(a.mean()), "max_mm": float(a.max())}


def rigid_fit(p_from: np.ndarray, p_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion that best maps one point set onto another (Kabsch).

    Parameters
    ----------
    p_from, p_to : ndarray, shape (N, 3)
        Corresponding points [mm], N >= 3 not on a line.

    Returns
    -------
    rot : ndarray, shape (3, 3)
        Rotation (determinant +1) minimising ``sum |R p_from + t - p_to|^2``.
    t : ndarray, shape (3,)
        Translation [mm].
    """
    c_from, c_to = p_from.mean(axis=0), p_to.mean(axis=0)
    u, _, vt = np.linalg.svd((p_from - c_from).T @ (p_to - c_to))
    s = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ s @ u.T
    return rot, c_to - rot @ c_from


def aligned_errors(p_model: np.ndarray, p_true: np.ndarray) -> np.ndarray:
    """Distances between model and true positions after the best rigid re-fit of the base (what
    re-registering the robot's base frame absorbs).

    Parameters
    ----------
    p_model, p_true : ndarray, shape (N, 3)
        Positions [mm].

    Returns
    -------
    ndarray, shape (N,)
        ``|R p_model + t - p_true|`` [mm] for the ``rigid_fit`` of ``p_model`` onto ``p_true``.
    """
    rot, t = rigid_fit(p_model, p_true)
    return np.linalg.norm(p_model @ rot.T + t - p_true, axis=1)

"""Prediction accuracy: MPE_n and Variance_n (Ali, Reilly & Shah 2007, section 5).

For a predicted track ``p_1..p_N`` against the true positions ``t_1..t_N``::

    MPE_n      = 1/n sum_{i=1}^n dist(p_i, t_i)
    Variance_n = 1/n sum_{i=1}^n (MPE_n - dist(p_i, t_i))^2

Distances are in whatever unit the positions are given in (multiply by metres per unit first to
report metres).
"""

from __future__ import annotations

import numpy as np

__all__ = ["prediction_errors", "mpe_n", "variance_n", "summarise"]


def prediction_errors(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean distances between predicted and true positions.

    Parameters
    ----------
    pred, truth : ndarray, shape (..., N, 2)

    Returns
    -------
    ndarray, shape (..., N)
    """
    d = np.asarray(pred, dtype=np.float64) - np.asarray(truth, dtype=np.float64)
    return np.hypot(d[..., 0], d[..., 1])


def mpe_n(errors: np.ndarray, n: int) -> np.ndarray:
    """MPE_n: mean of the first ``n`` errors of each predicted track.

    Parameters
    ----------
    errors : ndarray, shape (..., N), N >= n
    n : int

    Returns
    -------
    ndarray, shape (...)
    """
    e = np.asarray(errors, dtype=np.float64)
    if n < 1 or n > e.shape[-1]:
        raise ValueError(f"n must be in 1..{e.shape[-1]}, got {n}")
    return e[..., :n].mean(axis=-1)


def variance_n(errors: np.ndarray, n: int) -> np.ndarray:
    """Variance_n: spread of the first ``n`` errors about MPE_n. Shapes as :func:`mpe_n`."""
    e = np.asarray(errors, dtype=np.float64)[..., :n]
    m = mpe_n(errors, n)
    return ((e - m[..., None]) ** 2).mean(axis=-1)


def summarise(errors: np.ndarray, ns: list[int]) -> dict[int, dict[str, float]]:
    """Mean over queries of MPE_n and Variance_n for each n.

    Parameters
    ----------
    errors : ndarray, shape (Q, N)
        One row of per-frame errors per query.
    ns : list of int

    Returns
    -------
    dict n -> {"MPE": float, "Variance": float, "queries": int}
    """
    e = np.asarray(errors, dtype=np.float64)
    e = e.reshape(len(e), -1) if e.size else np.zeros((0, 1))
    out = {}
    for n in ns:
        if len(e) == 0:
            out[n] = {"MPE": float("nan"), "Variance": float("nan"), "queries": 0}
            continue
        out[n] = {"MPE": float(mpe_n(e, n).mean()), "Variance": float(variance_n(e, n).mean()),
                  "queries": int(len(e))}
    return out

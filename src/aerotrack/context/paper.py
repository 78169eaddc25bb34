"""Ali, Reilly & Shah 2007, sections 4.1-4.2, as written: predictors chosen by the Lyapunov
characteristic exponent (eq. 1) and the affine regression ``r(t) = m(t) + S(t) S(0)^-1 (r(0) -
m(0))`` on their positions (the ``paper`` prediction method, kept for comparison with aerotrack's
motion context, :mod:`aerotrack.context.motion`).
"""

from __future__ import annotations

import numpy as np

from .base import KalmanPredictor, MotionPredictor, TrackTable, _section

__all__ = ["PaperPredictor", "affine_regression", "lce"]


def lce(Z: np.ndarray, Zcn: np.ndarray) -> float:
    """Lyapunov characteristic exponent between two track sections (Ali et al. eq. 1).

    ``gamma = 1/F sum_{i=2}^F ln(d_i / d_{i-1})`` with ``d_i = |Z(i) - Zcn(i)|``.

    As printed, eq. 1 is degenerate: after normalisation both sections start at the same point, so
    ``d_1 = 0`` and the first term is infinite. The sum telescopes to ``ln(d_F / d_1) / F``; we start
    it at the first non-zero distance, ``gamma = ln(d_F / d_k) / F`` with ``d_k`` the first distance
    above 1e-9 of the section's extent, which is the paper's growth-rate idea without the division by
    zero. Two identical sections give 0. A section that ends where the predictand's ends (``d_F =
    0``) would give minus infinity and rank first whatever it did in between; ``d_F`` is floored
    at the same 1e-9 of the extent.

    Limits of eq. 1 itself, kept (this is the paper as written, for comparison): it compares the
    end distance with the first, not the way there, and it is blind to scale, so any two straight
    sections at constant speeds give the same ``ln(F - 1) / F`` whatever their speeds and directions
    (a parallel follower and an oncoming vehicle score alike). The ``context`` method does not use
    it.

    Parameters
    ----------
    Z, Zcn : ndarray, shape (F, 2)
        Predictand section and normalised candidate section (same start point).
    """
    d = np.hypot(*(np.asarray(Z, float) - np.asarray(Zcn, float)).T)
    F = len(d)
    scale = max(float(np.ptp(np.asarray(Z, float), axis=0).max()), 1e-12)
    nz = np.flatnonzero(d > 1e-9 * scale)
    if len(nz) == 0 or nz[0] == F - 1:
        return 0.0
    return float(np.log(max(d[-1], 1e-9 * scale) / d[nz[0]]) / F)


def _lce_batch(Z: np.ndarray, sections: np.ndarray) -> np.ndarray:
    """:func:`lce` for (K, F, 2) normalised sections at once -> (K,)."""
    d = np.hypot(*(sections - Z[None]).transpose(2, 0, 1))  # (K, F)
    F = d.shape[1]
    scale = max(float(np.ptp(Z, axis=0).max()), 1e-12)
    pos = d > 1e-9 * scale
    first = np.where(pos.any(axis=1), pos.argmax(axis=1), F - 1)
    d0 = d[np.arange(len(d)), first]
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.log(np.maximum(d[:, -1], 1e-9 * scale) / d0) / F
    g[first >= F - 1] = 0.0
    return g


def affine_regression(pred_start: np.ndarray, pred_now: np.ndarray, target_start: np.ndarray,
                      cond: float = 1e-6):
    """The motion-context regression of Ali et al. section 4.1.

    ``r(t) = m(t) + S(t) S(0)^-1 (r(0) - m(0))`` with ``m`` the predictors' centre of mass and
    ``S(t) = sum_j (r_j(t) - m(t)) (r_j(0) - m(0))^T``: the least-squares affine map taking the
    predictors' configuration at time 0 to time t, applied to the target.

    Parameters
    ----------
    pred_start : ndarray, shape (M, 2)
        Predictors' positions at time 0, world units (M >= 3).
    pred_now : ndarray, shape (M, 2)
        The same predictors at time t.
    target_start : ndarray, shape (2,)
        The target at time 0.

    Returns
    -------
    ndarray, shape (2,), or None when S(0) is singular (fewer than 3 non-collinear predictors).
    """
    a = np.asarray(pred_start, float).reshape(-1, 2)
    b = np.asarray(pred_now, float).reshape(-1, 2)
    if len(a) < 3:
        return None
    m0, mt = a.mean(axis=0), b.mean(axis=0)
    A0, At = a - m0, b - mt
    S0 = A0.T @ A0
    St = At.T @ A0
    # A near-singular S(0) (predictors on a line) makes the affine map arbitrary across the line.
    ev = np.linalg.eigvalsh(S0)
    if ev[0] <= cond * max(ev[1], 1e-300):
        return None
    return mt + St @ np.linalg.solve(S0, np.asarray(target_start, float) - m0)


class PaperPredictor(MotionPredictor):
    """Ali et al. 4.1-4.2 as written (LCE-selected predictors + affine regression).

    Choices where the paper is silent or degenerate (see :func:`lce`):

    * one predictor per other track: its section (ending at or before ``last_seen``, all F+1 frames
      present) whose LCE is closest to 0, kept when ``|gamma| <= config.lce_alpha``. The paper
      writes the test as ``gamma <= alpha`` and says "the closer the value of gamma is to 0, the
      more similar" the motions; read literally, the test admits a section converging on the
      predictand at any rate (gamma far below 0), which that sentence calls dissimilar, and the
      lowest gamma picks it over an identical section (gamma 0). (Until 2026-12-03 the code took
      the lowest gamma: on a convoy along one curved road it chose sections with gamma -0.11 to
      -0.27 at the wrong places over the leaders' aligned ones at 0.03-0.18, a probe.) Of
      sections equally close to 0 (a track that moved exactly alike for a while), the latest;
    * the set is kept as the paper keeps it (4.2.2): selected one window (F frames) before
      ``last_seen``, then advanced frame by frame with the predictand, each predictor dropped
      when its advanced section's LCE leaves the threshold (the tracks diverged); tracks not in
      the set are searched once more at ``last_seen``. The paper maintains the set from the
      predictand's first window on; one window back bounds the cost (a search per frame over
      every other track) and is what the drop test needs to see a divergence that is under way;
    * the regression runs on the predictors' raw positions: predictor j at step k is at
      ``r_j(t_e^j + k)``; a predictor whose track has no row there is dropped from then on;
    * during the prediction there is no observation of the target to test divergence against, so
      predictors are only dropped when their track ends;
    * fewer than 3 predictors (or a singular S(0)): the Kalman filter's prediction.
    """

    name = "paper"

    def _gamma(self, Z: np.ndarray, jf: np.ndarray, jxy: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """LCE (eq. 1) of the sections of one track ending at row indices ``ends``."""
        F = self.window
        idx = ends[:, None] - F + np.arange(F + 1)[None]
        sec = jxy[idx]  # (K, F+1, 2)
        return _lce_batch(Z, sec - sec[:, :1] + Z[None, :1])

    def select(self, table: TrackTable, track_id: int, T: int,
               previous: dict[int, int] | None = None, previous_T: int | None = None,
               search: bool = True) -> dict[int, int]:
        """PredictorSelection of Ali et al. 4.2.2: ``{predictor id: end frame t_e of its section}``.

        Without ``previous``, every other track's F-frame sections ending no later than ``T`` are
        searched and the section of each track whose LCE is closest to 0 is kept when
        ``|gamma| <= lce_alpha``. With ``previous`` (the set selected at ``previous_T``), each
        kept predictor's section is advanced by ``p = T - previous_T`` frames and dropped when its
        LCE against the predictand's new section leaves ``lce_alpha`` (the tracks diverged);
        tracks not in the set are searched as above unless ``search`` is False.
        """
        F = self.window
        Z = _section(table, track_id, T, F)
        if Z is None:
            return {}
        previous = previous or {}
        shift = 0 if previous_T is None else T - previous_T
        chosen: dict[int, int] = {}
        for j in table.track_ids():
            j = int(j)
            if j == track_id:
                continue
            jf, jxy = table.track(j)
            keep = jf <= T
            jf, jxy = jf[keep], jxy[keep]
            if len(jf) < F + 1:
                continue
            if j in previous:
                te = previous[j] + shift
                e = int(np.searchsorted(jf, te))
                if (e < len(jf) and jf[e] == te and e >= F and jf[e - F] == te - F
                        and abs(self._gamma(Z, jf, jxy, np.array([e]))[0])
                        <= self.config.lce_alpha):
                    chosen[j] = te
                continue  # a diverged predictor is dropped, not searched again at once
            if not search:
                continue
            ends = np.flatnonzero((jf[F:] - jf[:-F]) == F) + F  # sections of F+1 consecutive frames
            if len(ends) == 0:
                continue
            g = np.abs(self._gamma(Z, jf, jxy, ends))  # the closer to 0, the more alike
            k = len(g) - 1 - int(np.argmin(g[::-1]))  # of equals, the latest section
            if g[k] <= self.config.lce_alpha:
                chosen[j] = int(jf[ends[k]])
        return chosen

    def maintained(self, table: TrackTable, track_id: int, T: int) -> dict[int, int]:
        """The predictor set at ``T`` as the paper keeps it: selected at ``T - F`` (or where the
        predictand's first window ends, if later), advanced frame by frame to ``T`` with the
        diverged ones dropped (over frames the predictand missed, at its next row: one missed
        frame had emptied the set, a review), then every track not in the set (nor dropped on
        the way) searched at ``T``."""
        F = self.window
        t0 = T - F
        while t0 < T and _section(table, track_id, t0, F) is None:
            t0 += 1
        chosen = self.select(table, track_id, t0)
        seen = set(chosen)
        last = t0
        for t in range(t0 + 1, T + 1):
            if not chosen:
                break
            if _section(table, track_id, t, F) is None:
                continue  # the predictand missed frame t: advance over it at its next row
            chosen = self.select(table, track_id, t, previous=chosen, previous_T=last,
                                 search=False)
            last = t
        fresh = self.select(table, track_id, T, previous=chosen, previous_T=last)
        return {j: te for j, te in fresh.items() if j in chosen or j not in seen}

    #: Queries predicted by the Kalman fallback (fewer than ``min_predictors`` predictors), for
    #: ``aerotrack predict`` to say so.
    fallbacks = 0

    def _predict(self, table, track_id, fr, xy, T, h):
        fallback = _fallback_predict(fr, xy, h, self)
        chosen = sorted(self.maintained(table, track_id, T).items())
        if len(chosen) < self.config.min_predictors:
            self.fallbacks += 1
            return fallback
        tracks = {j: table.track(j) for j, _ in chosen}
        start = np.array([tracks[j][1][np.searchsorted(tracks[j][0], te)] for j, te in chosen])
        alive = np.ones(len(chosen), bool)
        out = np.empty((h, 2))
        r0 = xy[-1]
        for k in range(1, h + 1):
            now = np.zeros((len(chosen), 2))
            for n, (j, te) in enumerate(chosen):
                if not alive[n]:
                    continue
                jf, jxy = tracks[j]
                i = np.searchsorted(jf, te + k)
                # te + k <= T + k: the predictor's row is never later than the predicted frame
                if i < len(jf) and jf[i] == te + k:
                    now[n] = jxy[i]
                else:
                    alive[n] = False
            r = None
            if alive.sum() >= self.config.min_predictors:
                r = affine_regression(start[alive], now[alive], r0, self.config.regression_cond)
            out[k - 1] = fallback[k - 1] if r is None else r
        return out


def _fallback_predict(fr, xy, h, pred: MotionPredictor) -> np.ndarray:
    return KalmanPredictor(pred.config, pred.fps, pred.mpu)._predict(None, -1, fr, xy, int(fr[-1]), h)

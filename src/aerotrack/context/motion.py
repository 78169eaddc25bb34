"""Motion context: where does an unobserved target go? (Ali, Reilly & Shah 2007, sections 4.1-4.2).

Four predictors share one interface, :meth:`MotionPredictor.predict`, chosen by name from
:data:`PREDICTION_METHODS`:

``paper``
    Ali et al. as written: predictors chosen by the Lyapunov characteristic exponent (eq. 1) between
    the target's last F frames and every F-frame section of every other track (current or past,
    normalised to a common start), and the regression
    ``r(t) = m(t) + S(t) S(0)^-1 (r(0) - m(0))`` on their positions when there are >= 3 of them, the
    Kalman filter otherwise.
``context`` (default)
    aerotrack's motion context. The paper's idea, that predictors are objects that move or moved along
    the same stretch of path, used by *position*: the paths of past and current objects that passed
    where the target is (their hidden stretches rebuilt, :func:`bridge_gaps`), walked at the
    target's own speed, and the observed displacement of objects that were moving with it (a queue,
    a convoy), fused with the Kalman prediction by inverse variance (:class:`ContextPredictor`).
``kalman``
    The project's constant-velocity Kalman filter (:mod:`aerotrack.kalman`), run over the last F
    frames and then predicted forward.
``constant-velocity``
    A least-squares line fitted to the last F frames, extrapolated.

Causality: the prediction at frame ``f`` uses only the target's rows up to ``last_seen`` and other
tracks' rows up to ``f``; every neighbour set is put in a canonical (id, frame) order before it is
summed, so deleting any later row leaves the output bit-identical.

Coordinates: everything here is in one "world" frame (map pixels, frame pixels of a static camera,
or any planar coordinates); ``metres_per_unit`` converts the configuration's metres to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..config import ContextConfig
from ..errors import ConfigError, InputError

__all__ = [
    "PREDICTION_METHODS",
    "ConstantVelocityPredictor",
    "ContextPredictor",
    "KalmanPredictor",
    "MotionPredictor",
    "PaperPredictor",
    "TrackTable",
    "affine_regression",
    "bridge_gaps",
    "fit_constant_velocity",
    "follow_flow",
    "get_predictor",
    "kalman_state",
    "lce",
]


# --------------------------------------------------------------------------------------------------
# data


@dataclass(frozen=True)
class TrackTable:
    """Every row of a set of tracks, sorted by (id, frame), at most one row per (id, frame).

    Attributes
    ----------
    ids : ndarray, shape (N,), int64
    frames : ndarray, shape (N,), int64
        1-based frame numbers.
    xy : ndarray, shape (N, 2), float64
        Positions in world units.
    """

    ids: np.ndarray
    frames: np.ndarray
    xy: np.ndarray

    @classmethod
    def from_arrays(cls, ids, frames, xy) -> TrackTable:
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        frames = np.asarray(frames, dtype=np.int64).reshape(-1)
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if not (len(ids) == len(frames) == len(xy)):
            raise ValueError("TrackTable: ids, frames and xy must have the same length")
        order = np.lexsort((frames, ids))
        ids, frames, xy = ids[order], frames[order], xy[order]
        dup = (np.diff(ids) == 0) & (np.diff(frames) == 0)
        if dup.any():
            k = int(np.flatnonzero(dup)[0])
            raise InputError(f"track {ids[k]} has two rows for frame {frames[k]}")
        return cls(ids, frames, xy)

    def __len__(self) -> int:
        return len(self.ids)

    def track(self, track_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(frames (n,), xy (n, 2)) of one track, sorted by frame."""
        lo, hi = np.searchsorted(self.ids, [track_id, track_id + 1])
        return self.frames[lo:hi], self.xy[lo:hi]

    def track_ids(self) -> np.ndarray:
        return np.unique(self.ids)

    def without(self, track_id: int) -> TrackTable:
        keep = self.ids != track_id
        return TrackTable(self.ids[keep], self.frames[keep], self.xy[keep])


def _history(table: TrackTable, track_id: int, last_seen: int,
             window: int) -> tuple[np.ndarray, np.ndarray]:
    """The target's rows in [last_seen - window, last_seen] (only rows up to ``last_seen``)."""
    fr, xy = table.track(track_id)
    keep = (fr <= last_seen) & (fr >= last_seen - window)
    return fr[keep], xy[keep]


# --------------------------------------------------------------------------------------------------
# pure functions


def fit_constant_velocity(frames: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares line through a short history.

    Parameters
    ----------
    frames : ndarray, shape (n,)
    xy : ndarray, shape (n, 2), world units

    Returns
    -------
    p0 : ndarray, shape (2,)
        Fitted position at ``frames[-1]``.
    v : ndarray, shape (2,)
        Velocity, world units per frame (zero with a single row).
    """
    frames = np.asarray(frames, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(frames) < 2 or np.ptp(frames) == 0:
        return xy[-1].copy(), np.zeros(2)
    t = frames - frames[-1]
    tm = t.mean()
    dt = t - tm
    v = (dt[:, None] * (xy - xy.mean(axis=0))).sum(axis=0) / (dt * dt).sum()
    p0 = xy.mean(axis=0) - v * tm
    return p0, v


def lce(Z: np.ndarray, Zcn: np.ndarray) -> float:
    """Lyapunov characteristic exponent between two track sections (Ali et al. eq. 1).

    ``gamma = 1/F sum_{i=2}^F ln(d_i / d_{i-1})`` with ``d_i = |Z(i) - Zcn(i)|``.

    As printed, eq. 1 is degenerate: after normalisation both sections start at the same point, so
    ``d_1 = 0`` and the first term is infinite. The sum telescopes to ``ln(d_F / d_1) / F``; we start
    it at the first non-zero distance, ``gamma = ln(d_F / d_k) / F`` with ``d_k`` the first distance
    above 1e-9 of the section's extent, which is the paper's growth-rate idea without the division by
    zero. Two identical sections give 0.

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
    return float(np.log(d[-1] / d[nz[0]]) / F)


def _lce_batch(Z: np.ndarray, sections: np.ndarray) -> np.ndarray:
    """:func:`lce` for (K, F, 2) normalised sections at once -> (K,)."""
    d = np.hypot(*(sections - Z[None]).transpose(2, 0, 1))  # (K, F)
    F = d.shape[1]
    scale = max(float(np.ptp(Z, axis=0).max()), 1e-12)
    pos = d > 1e-9 * scale
    first = np.where(pos.any(axis=1), pos.argmax(axis=1), F - 1)
    d0 = d[np.arange(len(d)), first]
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.log(d[:, -1] / d0) / F
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


# --------------------------------------------------------------------------------------------------
# predictors


def _section(table: TrackTable, track_id: int, T: int, F: int) -> np.ndarray | None:
    """A track's section r(T-F .. T), (F+1, 2), interpolated over missing frames (rows <= T only);
    None when the track does not cover [T-F, T]."""
    fr, xy = _history(table, track_id, T, F)
    if len(fr) < 2 or fr[0] > T - F or fr[-1] != T:
        return None
    grid = np.arange(T - F, T + 1)
    return np.column_stack([np.interp(grid, fr, xy[:, 0]), np.interp(grid, fr, xy[:, 1])])


class MotionPredictor:
    """Predicts an unobserved target's positions from its history and the other tracks.

    Parameters
    ----------
    config : ContextConfig
    fps : float
        Frame rate (frames per second).
    metres_per_unit : float, optional
        World units -> metres; None means world units are metres.
    roads : RoadNetwork, optional
        Road centre-lines in the same world units (:mod:`aerotrack.context.roads`); used by the
        ``context`` method (a target on a road drives along it), ignored by the others. Also
        settable afterwards as the ``roads`` attribute.
    """

    name = "base"

    def __init__(self, config: ContextConfig | None = None, fps: float = 30.0,
                 metres_per_unit: float | None = None, roads=None) -> None:
        self.config = config or ContextConfig()
        if not fps or fps <= 0:
            raise ConfigError(f"fps must be positive, got {fps}")
        self.fps = float(fps)
        self.mpu = float(metres_per_unit) if metres_per_unit else 1.0
        self.window = max(2, int(round(self.config.history_s * self.fps)))
        self.roads = roads

    def m(self, metres: float) -> float:
        """Metres -> world units."""
        return metres / self.mpu

    def predict(self, table: TrackTable, track_id: int, last_seen: int, horizon: int) -> np.ndarray:
        """Positions of ``track_id`` at frames ``last_seen+1 .. last_seen+horizon``.

        Parameters
        ----------
        table : TrackTable
            Every track (the target's rows after ``last_seen`` and the others' rows after each
            predicted frame are ignored).
        track_id : int
        last_seen : int
            Last frame at which the target was observed (must be one of its rows).
        horizon : int
            Number of frames to predict (> 0).

        Returns
        -------
        ndarray, shape (horizon, 2), world units.
        """
        fr, xy = _history(table, track_id, last_seen, self.window)
        if len(fr) == 0 or fr[-1] != last_seen:
            raise InputError(f"track {track_id} has no row at last_seen frame {last_seen}")
        return self._predict(table, track_id, fr, xy, int(last_seen), int(horizon))

    def hypotheses(self, table: TrackTable, track_id: int, last_seen: int,
                   horizon: int) -> list[np.ndarray]:
        """Every place the target may be: :meth:`predict` first, then the other branches.

        With a road network (``context`` method, target on a road) the other entries are the
        routes through the junctions within reach that :meth:`predict` did not choose (a turn
        instead of straight on, the other side of a fork; see
        :func:`~aerotrack.context.roads.road_prediction`). A linker can gate and score a
        re-appearing object on the nearest entry at its first frame instead of on the chosen
        branch alone. Without roads, or off the roads, the list holds the prediction only.

        Returns
        -------
        list of ndarray, each (horizon, 2), world units, frames ``last_seen+1 .. +horizon``.
        """
        first = self.predict(table, track_id, last_seen, horizon)
        if self.roads is None or self.name != "context":
            return [first]
        from .roads import road_prediction

        fr, xy = _history(table, track_id, last_seen, self.window)
        p0, v0, _ = kalman_state(fr, xy, self.fps, self.mpu, self.config)
        rp = road_prediction(self.roads, p0, v0, int(horizon), self.fps, self.config,
                             index=self.index_for(table), frame=int(last_seen),
                             exclude_id=track_id)
        if rp is None:
            return [first]
        # hedged, the prediction is between the routes: every route is another place to look
        return [first, *(rp.hypotheses[1:] if self.config.road_hedge == "none" else rp.hypotheses)]

    def _predict(self, table, track_id, fr, xy, T, h) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


class ConstantVelocityPredictor(MotionPredictor):
    """Least squares over the last F frames, extrapolated."""

    name = "constant-velocity"

    def _predict(self, table, track_id, fr, xy, T, h):
        p0, v = fit_constant_velocity(fr, xy)
        k = np.arange(1, h + 1, dtype=np.float64)[:, None]
        return p0[None] + k * v[None]


def kalman_start(fr: np.ndarray, xy: np.ndarray, fps: float, mpu: float,
                 config: ContextConfig) -> tuple[np.ndarray, np.ndarray]:
    """Filter a history with the project's constant-velocity Kalman filter (:mod:`aerotrack.kalman`).

    Parameters
    ----------
    fr : ndarray, shape (n,)
        Frames of the history.
    xy : ndarray, shape (n, 2)
        Positions, world units.
    fps, mpu : float
        Frame rate and metres per world unit (the config's noise is in metres).

    Returns
    -------
    p : ndarray, shape (2,)
        Posterior position at the last frame, world units.
    v : ndarray, shape (2,)
        Posterior velocity, world units per frame. Its mean prediction ``p + k v`` is the
        ``kalman`` method.
    """
    p, v, _ = kalman_state(fr, xy, fps, mpu, config)
    return p, v


def kalman_state(fr: np.ndarray, xy: np.ndarray, fps: float, mpu: float,
                 config: ContextConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`kalman_start` with the posterior velocity covariance.

    Returns
    -------
    p : ndarray, shape (2,)
        Position at the last frame, world units.
    v : ndarray, shape (2,)
        Velocity, world units per frame.
    Pv : ndarray, shape (2, 2)
        Covariance of ``v``, (world units per frame)^2: large after one or two rows (the prior
        ``kalman_vel_std_mps``), small after a second of steady motion.
    """
    from ..kalman import ConstantVelocityKF  # the project's one Kalman filter

    kf = ConstantVelocityKF(accel_std=config.kalman_accel_mps2 / mpu,
                            pos_std=config.kalman_meas_std_m / mpu, pos_frac=0.0,
                            size_std=1.0, size_std_obs=1.0, size_frac=0.0,
                            vel_std=config.kalman_vel_std_mps / mpu)
    zs = np.column_stack([xy, np.ones((len(xy), 2))])
    xs, Ps, _ = kf.filter(zs, np.asarray(fr, dtype=np.float64) / fps)
    return xs[-1, :2].copy(), xs[-1, 4:6] / fps, Ps[-1, 4:6, 4:6] / (fps * fps)


class KalmanPredictor(MotionPredictor):
    """The project's constant-velocity Kalman filter over the last F frames, then predicted."""

    name = "kalman"

    def _predict(self, table, track_id, fr, xy, T, h):
        p, v = kalman_start(fr, xy, self.fps, self.mpu, self.config)
        return p[None] + np.arange(1, h + 1, dtype=np.float64)[:, None] * v[None]


class PaperPredictor(MotionPredictor):
    """Ali et al. 4.1-4.2 as written (LCE-selected predictors + affine regression).

    Choices where the paper is silent or degenerate (see :func:`lce`):

    * one predictor per other track: its section (ending at or before ``last_seen``, all F+1 frames
      present) with the lowest LCE, kept when ``gamma <= config.lce_alpha``;
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
               previous: dict[int, int] | None = None, previous_T: int | None = None) -> dict[int, int]:
        """PredictorSelection of Ali et al. 4.2.2: ``{predictor id: end frame t_e of its section}``.

        Without ``previous``, every other track's F-frame sections ending no later than ``T`` are
        searched and the lowest-LCE section of each track is kept when ``gamma <= lce_alpha``.
        With ``previous`` (the set selected at ``previous_T``), each kept predictor's section is
        advanced by ``p = T - previous_T`` frames and dropped when its LCE against the predictand's
        new section exceeds ``lce_alpha`` (the tracks diverged); tracks not in the set are searched
        as above.
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
                        and self._gamma(Z, jf, jxy, np.array([e]))[0] <= self.config.lce_alpha):
                    chosen[j] = te
                continue  # a diverged predictor is dropped, not searched again at once
            ends = np.flatnonzero((jf[F:] - jf[:-F]) == F) + F  # sections of F+1 consecutive frames
            if len(ends) == 0:
                continue
            g = self._gamma(Z, jf, jxy, ends)
            k = int(np.argmin(g))
            if g[k] <= self.config.lce_alpha:
                chosen[j] = int(jf[ends[k]])
        return chosen

    def _predict(self, table, track_id, fr, xy, T, h):
        fallback = _fallback_predict(fr, xy, h, self)
        chosen = sorted(self.select(table, track_id, T).items())
        if len(chosen) < self.config.min_predictors:
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



class PathIndex:
    """Other tracks' rows, sampled every ``config.path_sample_s``, for path-following queries.

    Rows are kept when their frame number is a multiple of the sampling stride, so the sample does
    not depend on which later rows exist; each carries its backward velocity over
    ``config.velocity_lag_s`` (only earlier rows of the same track are used).

    Parameters
    ----------
    table : TrackTable
    fps, mpu : float
    config : ContextConfig
    """

    def __init__(self, table: TrackTable, fps: float, mpu: float, config: ContextConfig) -> None:
        self.stride = stride = max(1, int(round(config.path_sample_s * fps)))
        lag = max(stride, int(round(config.velocity_lag_s * fps / stride)) * stride)
        sel = np.flatnonzero(table.frames % stride == 0)
        self.ids = table.ids[sel]
        self.frames = table.frames[sel]
        self.xy = table.xy[sel]
        n = len(sel)
        key = self.ids.astype(np.float64) * 1e9 + self.frames
        want = key - lag
        j = np.minimum(np.searchsorted(key, want), max(n - 1, 0))
        have = (key[j] == want) if n else np.zeros(0, bool)
        self.vel = np.where(have[:, None], (self.xy - self.xy[j]) / lag, np.nan)  # units / frame
        self.tree = cKDTree(self.xy) if n else None
        # start/end of each id's run of rows (sorted by id, frame)
        self._uid, self._lo = np.unique(self.ids, return_index=True)
        self._hi = np.append(self._lo[1:], n)

    def rows_of(self, track_id: int) -> tuple[int, int]:
        k = int(np.searchsorted(self._uid, track_id))
        return int(self._lo[k]), int(self._hi[k])

    def near(self, p: np.ndarray, radius: float, frame: int, exclude_id: int) -> np.ndarray:
        """Rows within ``radius`` of ``p`` (world units) with frame <= ``frame`` and another id,
        in canonical (id, frame) order."""
        if self.tree is None:
            return np.zeros(0, np.int64)
        cand = np.sort(np.asarray(self.tree.query_ball_point(p, radius * 1.01), dtype=np.int64))
        if len(cand) == 0:
            return cand
        d2 = ((self.xy[cand] - p) ** 2).sum(axis=1)
        keep = (d2 <= radius * radius) & (self.frames[cand] <= frame) & (self.ids[cand] != exclude_id)
        return cand[keep]


    def flow(self, p: np.ndarray, u: np.ndarray | None, frame: int, exclude_id: int, radius: float,
             cos_gate: float, min_speed: float) -> tuple[np.ndarray, np.ndarray, float]:
        """The local flow at ``p``: what earlier objects did where the target is.

        Rows within ``radius`` of ``p`` (world units), seen no later than ``frame``, of another id,
        moving at >= ``min_speed`` (units per frame) and, when ``u`` (unit heading) is given,
        within the heading gate ``cos(angle) >= cos_gate``, weighted by ``exp(-2 d^2 / radius^2)``.

        Returns
        -------
        w : ndarray, shape (m,)
            Weights, in canonical (id, frame) order of the rows.
        vel : ndarray, shape (m, 2)
            The rows' velocities, world units per frame.
        total : float
            Sum of ``w`` (0 without support).
        """
        rows = self.near(p, radius, frame, exclude_id)
        if len(rows) == 0:
            return np.zeros(0), np.zeros((0, 2)), 0.0
        vel = self.vel[rows]
        sp = np.hypot(vel[:, 0], vel[:, 1])
        ok = np.isfinite(sp) & (sp >= min_speed)
        if u is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                ok &= (vel @ u) >= cos_gate * sp
        rows, vel = rows[ok], vel[ok]
        d2 = ((self.xy[rows] - p) ** 2).sum(axis=1)
        w = np.exp(-2.0 * d2 / (radius * radius))
        return w, vel, float(w.sum())


def flow_velocity(index: PathIndex, p0: np.ndarray, v0: np.ndarray, Pv: np.ndarray, T: int,
                  exclude_id: int, radius: float, cos_gate: float, min_speed: float,
                  floor_std: float) -> np.ndarray:
    """The target's velocity with the local flow as a prior (Bayesian fusion of two Gaussians).

    A target seen for a frame or two has an almost unknown velocity (its Kalman covariance ``Pv`` is
    the prior ``kalman_vel_std_mps``); the objects that passed where it is tell how things move
    there. The flow's velocity is the weighted mean of :meth:`PathIndex.flow` (heading-gated by
    ``v0`` once the target's own heading is known, i.e. ``|v0|^2 > trace(Pv)``) with covariance
    its weighted spread + ``floor_std^2``. After a second of steady motion ``Pv`` is small and the
    result is the target's own velocity.

    Parameters
    ----------
    p0, v0 : ndarray, shape (2,)
        Kalman position (world units) and velocity (units per frame) at ``T``.
    Pv : ndarray, shape (2, 2)
        Covariance of ``v0``.
    floor_std : float
        Units per frame: the least uncertainty of the flow's velocity (objects on the same road
        drive at different speeds). Raising it trusts the target's own short history more.

    Returns
    -------
    ndarray, shape (2,), units per frame.
    """
    known = float(v0 @ v0) > float(np.trace(Pv))
    sp = math.hypot(v0[0], v0[1])
    w, vel, total = index.flow(p0, v0 / sp if known and sp > 0 else None, T, exclude_id, radius,
                               cos_gate, min_speed)
    if total <= 0:
        return v0
    vf = (w[:, None] * vel).sum(axis=0) / total
    dv = vel - vf
    Sf = (w[:, None, None] * dv[:, :, None] * dv[:, None, :]).sum(axis=0) / total
    Sf = Sf + floor_std * floor_std * np.eye(2)
    A = np.linalg.inv(Pv + 1e-12 * np.eye(2))
    B = np.linalg.inv(Sf)
    return np.linalg.solve(A + B, A @ v0 + B @ vf)


def _flow_heading(index: PathIndex, q: np.ndarray, u: np.ndarray, frame: int, exclude_id: int,
                  radius: float, cos_gate: float, min_speed: float) -> tuple[np.ndarray, float]:
    """Weighted mean unit heading of the flow at ``q`` gated around ``u``, and its total weight."""
    w, vel, total = index.flow(q, u, frame, exclude_id, radius, cos_gate, min_speed)
    if total <= 0:
        return u, 0.0
    sp = np.hypot(vel[:, 0], vel[:, 1])
    d = (w[:, None] * vel / sp[:, None]).sum(axis=0)
    n = math.hypot(d[0], d[1])
    return (d / n, total) if n > 0 else (u, 0.0)


def _rotate(u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``u`` turned by the angle from unit vector ``a`` to unit vector ``b``."""
    c, s = float(a @ b), float(a[0] * b[1] - a[1] * b[0])
    return np.array([c * u[0] - s * u[1], s * u[0] + c * u[1]])


def follow_flow(index: PathIndex, p0: np.ndarray, v0: np.ndarray, T: int, h: int, exclude_id: int,
                radius: float, cos_gate: float, min_speed: float, prior_weight: float,
                step: int) -> np.ndarray:
    """Drive along the learned road: turn the target's heading as the local flow turns.

    The flow heading at a point is the weighted mean unit heading of :meth:`PathIndex.flow` there
    (rows seen no later than that point's frame, within the heading gate, so at a fork the branch
    most earlier objects took wins and an opposite lane is ignored). Every ``step`` frames the
    target's heading is its own starting heading turned by the angle between the flow heading at
    ``p0`` and at the current position (the flow's *change*, not its direction: on a straight road
    the target's own heading, which is more precise than an average over a lane, is kept), shrunk
    by the confidence ``W / (W + prior_weight)`` of the support ``W`` found there. The speed stays
    ``|v0|``. Without support the heading is kept, so with no earlier objects the result is the
    straight line ``p0 + k v0``, the Kalman prediction.

    Parameters
    ----------
    p0 : ndarray, shape (2,)
        Start (world units) at frame ``T``.
    v0 : ndarray, shape (2,)
        Velocity, units per frame.
    h : int
        Frames to predict.
    prior_weight : float
        Support (sum of row weights, each at most 1) at which the flow's turn is half believed.
        Raising it follows the road only where many earlier objects passed.
    step : int
        Frames between heading updates.

    Returns
    -------
    ndarray, shape (h, 2), world units, frames ``T+1 .. T+h``.
    """
    k = np.arange(1, h + 1, dtype=np.float64)
    speed = math.hypot(v0[0], v0[1])
    straight = p0[None] + k[:, None] * v0[None]
    if speed < min_speed or index.tree is None:
        return straight
    u0 = np.asarray(v0, dtype=np.float64) / speed
    f0, W0 = _flow_heading(index, p0, u0, T, exclude_id, radius, cos_gate, min_speed)
    if W0 <= 0:
        return straight
    out = np.empty((h, 2))
    q = np.asarray(p0, dtype=np.float64).copy()
    u, fq = u0, f0
    for j0 in range(0, h, step):
        if j0 > 0:
            f, W = _flow_heading(index, q, fq, T + j0, exclude_id, radius, cos_gate, min_speed)
            if W > 0:
                fq = f
                turned = _rotate(u0, f0, f)
                a = W / (W + prior_weight)
                d = a * turned + (1 - a) * u
                n = math.hypot(d[0], d[1])
                u = d / n if n > 0 else u
        j1 = min(j0 + step, h)
        out[j0:j1] = q[None] + (np.arange(1, j1 - j0 + 1) * speed)[:, None] * u[None]
        q = out[j1 - 1].copy()
    return out


def bridge_gaps(path_xy: np.ndarray, path_frames: np.ndarray, max_step: int,
                parallel_sin: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Reconstruct where a predictor drove while it was hidden (the gaps in its track).

    A chord from the last row before a gap (A) to the first after it (B) is not where the object
    drove: it cuts the corner of a turn and hides a U-turn. The hidden path is rebuilt from two legs,
    one along the heading it had entering (A - A_prev) and one along the heading it had leaving
    (B_next - B), as roads do:

    * headings at an angle (``|sin| > parallel_sin``) whose rays meet ahead of A and behind B: the
      corner C where they meet, path A -> C -> B;
    * opposite headings (a U-turn at a dead end or a roundabout): out along the entry heading and
      back, each leg half of the distance it could drive in the gap (mean of its entry and exit
      speeds times the gap) beyond |AB|, path A -> A + L h_in -> B + L h_in -> B;
    * otherwise (straight on): the chord.

    The rebuilt points become known only when B_next is seen: they and B carry B_next's frame, so
    :func:`follow_path` uses them only for predicted frames at or after it. Without B_next (the
    track ends at B, or B is followed by another gap) the path ends at A: a later row must not
    change what is known at an earlier frame (causality).

    Parameters
    ----------
    path_xy : ndarray, shape (n, 2)
        A predictor's rows (world units), sorted by frame.
    path_frames : ndarray, shape (n,)
    max_step : int
        Rows more than this many frames apart enclose a gap.
    parallel_sin : float
        Headings closer to parallel than this are "straight on" or "U-turn".

    Returns
    -------
    xy : ndarray, shape (m, 2), m >= n
    frames : ndarray, shape (m,)
        The frame at which each point is known (not monotonic where points were inserted).
    """
    path_xy = np.asarray(path_xy, dtype=np.float64)
    path_frames = np.asarray(path_frames)
    gaps = np.flatnonzero(np.diff(path_frames) > max_step)
    if len(gaps) == 0:
        return path_xy, path_frames
    xs, fs = [path_xy[: gaps[0] + 1]], [path_frames[: gaps[0] + 1]]
    for n, g in enumerate(gaps):
        a, b = g, g + 1
        if b + 1 >= len(path_xy) or path_frames[b + 1] - path_frames[b] > max_step:
            break  # no exit heading (yet): the path ends before the gap, as it would have when
            # only the rows up to B were known; the rest cannot be rebuilt
        A, B = path_xy[a], path_xy[b]
        fB = path_frames[b + 1]
        insert: list[np.ndarray] = []
        din, dout = A - path_xy[a - 1] if a >= 1 else np.zeros(2), path_xy[b + 1] - B
        lin, lout = math.hypot(*din), math.hypot(*dout)
        if lin > 0 and lout > 0:
            hin, hout = din / lin, dout / lout
            speed = 0.5 * (lin / (path_frames[a] - path_frames[a - 1])
                           + lout / (path_frames[b + 1] - path_frames[b]))
            d = B - A
            sin = hin[0] * hout[1] - hin[1] * hout[0]
            if abs(sin) > parallel_sin:
                L1 = (d[0] * hout[1] - d[1] * hout[0]) / sin
                L2 = (hin[0] * d[1] - hin[1] * d[0]) / sin
                if L1 > 0 and L2 > 0:
                    insert = [A + L1 * hin]
            elif hin @ hout < 0:
                L = 0.5 * (speed * (path_frames[b] - path_frames[a]) - math.hypot(*d))
                if L > 0:
                    insert = [A + L * hin, B + L * hin]
        end = gaps[n + 1] + 1 if n + 1 < len(gaps) else len(path_xy)
        if insert:
            xs.append(np.array(insert))
            fs.append(np.full(len(insert), fB))
        xs.append(path_xy[b:end])
        fs.append(np.concatenate([[fB], path_frames[b + 1:end]]))
    return np.concatenate(xs), np.concatenate(fs)


def follow_path(path_xy: np.ndarray, path_frames: np.ndarray, start: np.ndarray, lengths: np.ndarray,
                frames: np.ndarray, start_frame: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Displacements along a predictor's polyline from the point nearest ``start``.

    Parameters
    ----------
    path_xy : ndarray, shape (n, 2)
        A predictor's positions around and after the matched point (world units), n >= 2.
    path_frames : ndarray, shape (n,)
        Their frame numbers.
    start : ndarray, shape (2,)
        The target's position; it is projected onto the first two segments of the path, so a target
        between two sampled rows starts where it is along the path (on a curve, starting at the
        nearest row instead would rotate the whole future).
    lengths : ndarray, shape (h,)
        Arc lengths travelled by the target at each predicted step (world units).
    frames : ndarray, shape (h,)
        The predicted frames; a point of the path may be used only if its row is not later.
    start_frame : int, optional
        The frame of ``start`` (``last_seen``): only segments whose rows are no later are used for
        the projection, so it does not depend on rows that a later prediction step may not see.

    Returns
    -------
    disp : ndarray, shape (h, 2)
        ``path(s0 + length) - path(s0)``, s0 the projection of ``start``.
    valid : ndarray, shape (h,), bool
    """
    seg_vec = np.diff(path_xy, axis=0)
    seg = np.hypot(seg_vec[:, 0], seg_vec[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    best, s0, base = np.inf, 0.0, path_xy[0]
    for j in range(min(2, len(seg))):
        if seg[j] <= 0 or (start_frame is not None and path_frames[j + 1] > start_frame):
            continue
        u = float(np.clip((start - path_xy[j]) @ seg_vec[j] / seg[j] ** 2, 0.0, 1.0))
        q = path_xy[j] + u * seg_vec[j]
        d = float(np.hypot(*(start - q)))
        if d < best:
            best, s0, base = d, cum[j] + u * seg[j], q
    target = s0 + lengths
    i = np.searchsorted(cum, target, side="left")
    valid = i < len(cum)
    i = np.clip(i, 1, len(cum) - 1)
    valid &= path_frames[i] <= frames
    a, b = cum[i - 1], cum[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(b > a, (target - a) / (b - a), 1.0)
    w = np.clip(w, 0.0, 1.0)[:, None]
    pos = path_xy[i - 1] * (1 - w) + path_xy[i] * w
    return pos - base, valid


def polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance from each of ``points`` (n, 2) to the polyline through ``line`` (m, 2) -> (n,)."""
    if len(line) == 1:
        return np.hypot(*(points - line[0]).T)
    a, b = line[:-1], line[1:]
    ab = b - a
    L2 = (ab * ab).sum(-1)
    u = ((points[:, None] - a[None]) * ab[None]).sum(-1) / np.where(L2 > 0, L2, 1.0)[None]
    q = a[None] + np.clip(u, 0.0, 1.0)[..., None] * ab[None]
    return np.sqrt(((points[:, None] - q) ** 2).sum(-1)).min(axis=1)


class ContextPredictor(MotionPredictor):
    """aerotrack's motion context: three estimates fused by inverse variance.

    The paper's predictors are objects that move or moved along the same stretch of road. Eq. 1
    matches them by displacement alone, from anywhere in the scene, and its affine regression on a
    few scattered agents extrapolates poorly. Here the same idea is used in two position-aware
    ways, each an estimate with a variance, fused with the Kalman prediction:

    1. **Kalman** (always): the project's constant-velocity filter over the last F frames, its
       variance ``meas^2 + (a t^2 / 2)^2`` growing with the prediction time t. Its velocity is
       fused with the local flow's (:func:`flow_velocity`, the learned road: what earlier objects
       did where the target is) by their covariances, so a target seen for a frame or two moves
       like the traffic there while one seen for a second keeps its own velocity. With
       ``flow_follow`` the straight line turns as the flow turns (:func:`follow_flow`; off by
       default, it did not help on the benchmarks).
    2. **Path following** (past and current objects that drove the same stretch,
       :meth:`select`): other tracks with a row within ``path_radius_m`` of the target's position,
       seen no later than ``last_seen``, heading and speed alike, whose path passes the target's
       last F positions (mean distance ~``path_match_m``). Each predictor's path from the point
       nearest the target is walked at the target's own speed (arc length, so a slower biker and a
       faster cart on the same curve agree), using only rows no later than the predicted frame.
       Where a predictor was itself hidden (an occluder, outside the view), its hidden path is
       rebuilt from its entry and exit headings (:func:`bridge_gaps`: a corner, a U-turn), not
       taken as the chord, which cuts corners. Gaps are where predictions matter and where every
       object is hidden alike, so these hidden transits are most of the support there.
       Variance: the predictors' spread + their match distance + ``path_noise_m^2 / W``.
    3. **Co-movers** (:meth:`comovers`): tracks seen at ``last_seen`` within ``group_radius_m``
       whose last F frames moved like the target's (the start-normalised sections of eq. 1,
       compared by RMS distance rather than by the degenerate growth ratio). Their displacement
       after ``last_seen`` is observed while the target is hidden: a queue starting to move, a
       convoy turning. Variance: their spread + ``group_noise_m^2 / n``.

    With a road network (``roads``), a target that snaps to a road (within ``road_snap_m``,
    heading within ``road_heading_deg``) has estimate 1 driven along the road instead of on a
    straight line (:func:`~aerotrack.context.roads.road_prediction`: its lane kept, at junctions
    the weighted centre of the branches, each as likely as earlier objects' choices make it
    (``road_hedge``), U-turns at dead ends), with the same variance; off the roads nothing
    changes.

    Where neither context estimate exists the prediction is the Kalman filter's, so the method is
    never worse than it by construction of the weights (up to their calibration). Raising
    ``path_noise_m`` / ``group_noise_m`` trusts the context less.
    """

    name = "context"

    def __init__(self, config=None, fps=30.0, metres_per_unit=None, roads=None) -> None:
        super().__init__(config, fps, metres_per_unit, roads)
        from .roads import check_hedge

        check_hedge(self.config.road_hedge)
        self._index_table: TrackTable | None = None  # held, so its id cannot be reused
        self._index: PathIndex | None = None

    def index_for(self, table: TrackTable) -> PathIndex:
        """The path index of ``table`` (built once per table object)."""
        if self._index_table is not table:
            self._index = PathIndex(table, self.fps, self.mpu, self.config)
            self._index_table = table
        return self._index

    def select(self, table: TrackTable, track_id: int, fr: np.ndarray, xy: np.ndarray, T: int,
               p0: np.ndarray, v0: np.ndarray) -> list[tuple[int, int, float]]:
        """The predictors of a target: ``[(track id, matched PathIndex row, path distance)]``.

        A predictor is another track with a row seen no later than ``T`` within ``path_radius_m``
        of ``p0``, moving within ``path_heading_deg`` of the target's heading at 1/ratio to ratio
        times its speed, whose path passes the target's last F positions at a mean distance of at
        most twice ``path_match_m``. Returned in id order (world units for the distance).
        """
        c = self.config
        speed = math.hypot(v0[0], v0[1])
        if table is None or speed * self.fps * self.mpu < c.min_speed_mps:
            return []
        index = self.index_for(table)
        radius = self.m(c.path_radius_m)
        cos_gate = math.cos(math.radians(c.path_heading_deg))
        own = v0 / speed
        # rows are sampled: widen by the spacing so a path passing between two rows is found
        rows = index.near(p0, radius + speed * index.stride, T, track_id)
        if len(rows) == 0:
            return []
        vel = index.vel[rows]
        sp = np.hypot(vel[:, 0], vel[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = (vel @ own) / sp
        ok = np.isfinite(cos) & (cos >= cos_gate) & (sp * self.fps * self.mpu >= c.min_speed_mps)
        ok &= (sp <= c.path_speed_ratio * speed) & (sp * c.path_speed_ratio >= speed)
        rows = rows[ok]
        # one matched row per predictor track: the nearest to p0 (ties: earliest, canonical order)
        d = np.hypot(*(index.xy[rows] - p0).T)
        best: dict[int, tuple[int, float]] = {}
        for r, t, dd in zip(rows, index.ids[rows], d):
            if t not in best or dd < best[t][1]:
                best[int(t)] = (int(r), float(dd))
        sigma = self.m(c.path_match_m)
        hist = xy[:: max(1, index.stride)]
        out = []
        for t in sorted(best):
            r, _ = best[t]
            lo, _hi = index.rows_of(t)
            back = index.xy[max(lo, r - 4 * self.window // index.stride): r + 1]
            dpath = float(polyline_distance(hist, back).mean())
            if dpath <= 2 * sigma:
                out.append((t, r, dpath))
        return out

    def _predict(self, table, track_id, fr, xy, T, h):
        c = self.config
        p0, v0, Pv = kalman_state(fr, xy, self.fps, self.mpu, c)
        k = np.arange(1, h + 1)
        if table is not None and c.flow_radius_m > 0:
            index = self.index_for(table)
            radius = self.m(c.flow_radius_m)
            cos_gate = math.cos(math.radians(c.flow_heading_deg))
            vmin = self.m(c.min_speed_mps) / self.fps
            v0 = flow_velocity(index, p0, v0, Pv, T, track_id, radius, cos_gate, vmin,
                               self.m(c.flow_velocity_std_mps) / self.fps)
        base = p0 + k[:, None] * v0
        if table is not None and c.flow_radius_m > 0 and c.flow_follow:
            step = max(1, int(round(c.flow_step_s * self.fps)))
            base = follow_flow(index, p0, v0, T, h, track_id, radius, cos_gate, vmin,
                               c.flow_prior_weight, step)
        if self.roads is not None:
            from .roads import road_prediction

            rp = road_prediction(self.roads, p0, v0, h, self.fps, c,
                                 index=None if table is None else self.index_for(table),
                                 frame=T, exclude_id=track_id)
            if rp is not None:
                base = rp.positions
        t = k / self.fps
        var_kf = self.m(c.kalman_meas_std_m) ** 2 + (0.5 * self.m(c.kalman_accel_mps2) * t * t) ** 2
        estimates = [(base, var_kf)]
        if table is not None:
            estimates.append(self._path_estimate(table, track_id, fr, xy, T, p0, v0, k))
            estimates.append(self._group_estimate(table, track_id, T, p0, k))
        num = np.zeros((h, 2))
        den = np.zeros(h)
        for est, var in estimates:
            w = np.where(np.isfinite(var), 1.0 / np.maximum(var, 1e-300), 0.0)
            num += w[:, None] * np.where(np.isfinite(var)[:, None], est, 0.0)
            den += w
        return num / den[:, None]

    def _path_estimate(self, table, track_id, fr, xy, T, p0, v0, k):
        """Path following: (positions (h, 2), variance (h,), inf where no predictor reaches)."""
        c = self.config
        h = len(k)
        none = (np.zeros((h, 2)), np.full(h, np.inf))
        chosen = self.select(table, track_id, fr, xy, T, p0, v0)
        if not chosen:
            return none
        index = self.index_for(table)
        speed = math.hypot(v0[0], v0[1])
        sigma = self.m(c.path_match_m)
        lengths = speed * k
        frames = T + k
        # coarse chords: arc length over jittery rows would run ahead of the target's chord speed
        chord = max(1, int(round(c.path_chord_s * self.fps / index.stride)))
        disps, valids, ws, d2s = [], [], [], []
        for t, r, dpath in chosen:
            lo, hi = index.rows_of(t)
            r0 = r - chord if r - chord >= lo else r
            if hi - r0 < chord + 1:
                continue
            # every chord-th row, and the rows on both sides of a gap (so a short visible stretch
            # between two hidden ones still gives its exit heading)
            fr_t = index.frames[r0:hi]
            max_step = int(1.5 * chord * index.stride)
            edge = np.flatnonzero(np.diff(fr_t) > max_step)
            keep = np.zeros(len(fr_t), bool)
            keep[::chord] = True
            keep[edge] = keep[edge + 1] = True
            keep[np.minimum(edge + 2, len(fr_t) - 1)] = True
            pxy, pfr = bridge_gaps(index.xy[r0:hi][keep], fr_t[keep], max_step)
            disp, valid = follow_path(pxy, pfr, p0, lengths, frames, start_frame=T)
            disps.append(disp)
            valids.append(valid)
            ws.append(math.exp(-0.5 * (dpath / sigma) ** 2))
            d2s.append(dpath * dpath)
        if not ws:
            return none
        wv = np.array(ws)[:, None] * np.array(valids)  # (M, h)
        W = wv.sum(axis=0)
        Wd = np.where(W > 0, W, 1.0)
        D = np.array(disps)  # (M, h, 2)
        mean = (wv[..., None] * D).sum(axis=0) / Wd[:, None]
        spread2 = (wv * ((D - mean[None]) ** 2).sum(-1)).sum(axis=0) / Wd
        match2 = (wv * np.array(d2s)[:, None]).sum(axis=0) / Wd
        var = spread2 + match2 + self.m(c.path_noise_m) ** 2 / np.maximum(W, 1e-9)
        return p0 + mean, np.where(W > 0, var, np.inf)

    def comovers(self, table: TrackTable, track_id: int, T: int) -> list[int]:
        """Tracks seen at ``T`` within ``group_radius_m`` whose last F frames moved like the
        target's: RMS difference of the two start-normalised sections (the sections of eq. 1)
        at most ``group_match_m``. Their displacement after ``T`` is observed while the target
        is not (a queue starting to move, a convoy turning)."""
        c = self.config
        F = self.window
        Z = _section(table, track_id, T, F)
        if Z is None:
            return []
        Zn = Z - Z[0]
        at_T = np.flatnonzero(table.frames == T)
        near = at_T[np.hypot(*(table.xy[at_T] - Z[-1]).T) <= self.m(c.group_radius_m)]
        out = []
        tol2 = self.m(c.group_match_m) ** 2
        for j in sorted(set(table.ids[near].tolist()) - {track_id}):
            S = _section(table, j, T, F)
            if S is None:
                continue
            if float(((S - S[0] - Zn) ** 2).sum(axis=1).mean()) <= tol2:
                out.append(int(j))
        return out

    def _group_estimate(self, table, track_id, T, p0, k):
        """Mean displacement of the co-moving tracks after T (translation), with its spread."""
        c = self.config
        h = len(k)
        group = self.comovers(table, track_id, T)
        if not group:
            return np.zeros((h, 2)), np.full(h, np.inf)
        D = np.zeros((len(group), h, 2))
        V = np.zeros((len(group), h), bool)
        for n, j in enumerate(group):
            jf, jxy = table.track(j)
            x0 = jxy[np.searchsorted(jf, T)]
            i = np.searchsorted(jf, T + k)  # rows at T + k only: never later than the predicted frame
            ok = (i < len(jf)) & (jf[np.minimum(i, len(jf) - 1)] == T + k)
            D[n, ok] = jxy[i[ok]] - x0
            V[n] = ok
        cnt = V.sum(axis=0)
        cd = np.maximum(cnt, 1)
        mean = (D * V[..., None]).sum(axis=0) / cd[:, None]
        spread2 = (V * ((D - mean[None]) ** 2).sum(-1)).sum(axis=0) / cd
        var = spread2 + self.m(c.group_noise_m) ** 2 / cd
        return p0 + mean, np.where(cnt > 0, var, np.inf)


PREDICTION_METHODS: dict[str, type[MotionPredictor]] = {
    "context": ContextPredictor,
    "paper": PaperPredictor,
    "kalman": KalmanPredictor,
    "constant-velocity": ConstantVelocityPredictor,
}


def get_predictor(name: str, config: ContextConfig | None = None, fps: float = 30.0,
                  metres_per_unit: float | None = None, roads=None) -> MotionPredictor:
    """A predictor by registered name; an unknown name lists the valid ones. ``roads``: a
    :class:`~aerotrack.context.roads.RoadNetwork` in the same world units (``context`` uses it)."""
    try:
        cls = PREDICTION_METHODS[name]
    except KeyError:
        raise ConfigError(
            f"config context.method: unknown prediction method {name!r} "
            f"(valid: {', '.join(PREDICTION_METHODS)})"
        ) from None
    return cls(config, fps, metres_per_unit, roads)

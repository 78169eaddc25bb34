"""What every motion predictor shares: the table of tracks it reads, the interface
(:class:`MotionPredictor`), and the two baselines the contexts are measured against,
constant velocity and the project's Kalman filter.

Coordinates: one planar "world" frame (map pixels, frame pixels of a static camera, or any planar
coordinates); ``metres_per_unit`` converts the configuration's metres to it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import ContextConfig
from ..errors import ConfigError, InputError

__all__ = ["ConstantVelocityPredictor", "KalmanPredictor", "MotionPredictor", "TrackTable",
           "fit_constant_velocity", "kalman_start", "kalman_state"]


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

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

Modules: :mod:`.base` (the track table, the interface and the two baselines), :mod:`.paper`
(Ali et al. as written), :mod:`.paths` (where earlier objects went: the path index and the
flow), this module (aerotrack's context predictor and the registry).

Coordinates: everything here is in one "world" frame (map pixels, frame pixels of a static camera,
or any planar coordinates); ``metres_per_unit`` converts the configuration's metres to it.
"""

from __future__ import annotations

import math

import numpy as np

from ..config import ContextConfig
from ..errors import ConfigError
from .base import (
    ConstantVelocityPredictor,
    KalmanPredictor,
    MotionPredictor,
    TrackTable,
    _section,
    fit_constant_velocity,
    kalman_start,
    kalman_state,
)
from .paper import PaperPredictor, affine_regression, lce
from .paths import (
    PathIndex,
    bridge_gaps,
    flow_velocity,
    follow_flow,
    follow_path,
    polyline_distance,
)

__all__ = [
    "PREDICTION_METHODS",
    "ConstantVelocityPredictor",
    "ContextPredictor",
    "KalmanPredictor",
    "MotionPredictor",
    "PaperPredictor",
    "PathIndex",
    "TrackTable",
    "affine_regression",
    "bridge_gaps",
    "fit_constant_velocity",
    "flow_velocity",
    "follow_flow",
    "follow_path",
    "get_predictor",
    "kalman_start",
    "kalman_state",
    "lce",
    "polyline_distance",
]


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
        from .roads import check_hedge, check_traffic_side

        check_hedge(self.config.road_hedge)
        check_traffic_side(self.config.road_traffic_side)
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
        if self.roads is not None and len(fr) < c.road_glimpse_frames:
            v0 = self._glimpse_velocity(table, track_id, p0, T, v0)
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

    def _glimpse_velocity(self, table, track_id: int, p0: np.ndarray, T: int,
                          v0: np.ndarray) -> np.ndarray:
        """Velocity (world units per frame) of a target seen too briefly to have one, from the
        lane it is in (``road_traffic_side``) and the speed of the other objects seen so far;
        ``v0`` when it is off-road or on the centre-line."""
        c = self.config
        speed = self.m(c.road_glimpse_speed_mps) / self.fps
        side = "right" if c.road_traffic_side == "auto" else c.road_traffic_side
        if table is not None:
            # each other object's mean velocity over its rows of the last second (half of them
            # seen): their median speed, and with ``auto`` the side of the road they keep to
            window = max(2, int(round(self.fps)))
            keep = (table.frames <= T) & (table.frames > T - window) & (table.ids != track_id)
            _, first, n = np.unique(table.ids[keep], return_index=True, return_counts=True)
            ok = n >= max(2, window // 2)
            f, xy = table.frames[keep], table.xy[keep]
            a, b = first[ok], first[ok] + n[ok] - 1
            v = (xy[b] - xy[a]) / np.maximum(1, f[b] - f[a])[:, None]
            moving = np.hypot(*v.T) * self.fps * self.mpu >= c.min_speed_mps
            if moving.any():
                speed = float(np.median(np.hypot(*v[moving].T)))
            if c.road_traffic_side == "auto":
                side = self._traffic_side(xy[b][moving], v[moving]) or side
        u = self.roads.lane_heading(p0, self.m(c.road_snap_m), self.m(c.road_lane_min_m), side)
        return v0 if u is None else u * speed

    def _traffic_side(self, positions: np.ndarray, velocities: np.ndarray) -> str | None:
        """``right`` or ``left``: the side of the road most of these moving objects keep to
        (at least ``road_lane_min_m`` off a centre-line they drive along); None with fewer than
        three such objects."""
        c = self.config
        right = left = 0
        for p, v in zip(positions, velocities):
            snap = self.roads.snap_state(p, v, self.m(c.road_snap_m), c.road_heading_deg)
            if snap is not None and abs(snap[3]) >= self.m(c.road_lane_min_m):
                off = snap[3] * self.roads.right_sign  # > 0: right of its travel
                right += off > 0
                left += off < 0
        if right + left < 3:
            return None
        return "right" if right >= left else "left"

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

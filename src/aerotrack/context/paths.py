"""The learned road: where earlier objects went, for aerotrack's motion context.

:class:`PathIndex` holds the other tracks' rows (sampled, with their velocities) for spatial
queries; :func:`flow_velocity` and :func:`follow_flow` read the local flow there;
:func:`bridge_gaps` rebuilds a predictor's hidden stretch from its entry and exit headings and
:func:`follow_path` walks a predictor's path at the target's speed. Coordinates are world units
(see :mod:`aerotrack.context.base`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..config import ContextConfig
from .base import TrackTable

__all__ = ["PathIndex", "bridge_gaps", "flow_velocity", "follow_flow", "follow_path",
           "polyline_distance"]


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
    # a floor relative to the covariance itself: an absolute 1e-12 swamped it in lon/lat degrees
    # (velocities of 1e-6 a frame), so that the same tracks predicted worse in degrees than in
    # metres (SDD nexus4, 2 s ahead: MPE 0.503 m against 0.384 m)
    A = np.linalg.inv(Pv + (1e-9 * float(np.trace(Pv)) + 1e-300) * np.eye(2))
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

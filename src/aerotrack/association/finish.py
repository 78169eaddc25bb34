"""What ``tracks.csv`` reports for each final track: smoothed ground points, one vehicle size per
track, and no tracks that never moved.

Local association reports each observed point with its detection's box. Detector boxes of 15-40 px
vehicles jitter by a pixel or two, are often partial (a vehicle half absorbed by the background,
cut by an occluder or the frame border), sometimes merged with a neighbour or a shadow; at that
size one pixel already costs a lot of HOTA. After global linking the whole track is known, so
:class:`TrackFinisher` rebuilds each in-view point (kinds ``observed``, ``bridged``,
``stationary``; ``predicted`` points are left alone):

1. **Smoothing** (:func:`rts_smooth`): the constant-velocity Kalman filter of
   :mod:`aerotrack.kalman` (Yu & Medioni eqs. 6-8) run forward over every frame of each run of
   in-view points (missed frames are predicted), then the Rauch-Tung-Striebel backward pass, in
   world coordinates. Robust (:func:`robust_smooth`): observations far from the smoothed path
   (squared Mahalanobis residual above ``outlier_chi2``) get their noise scaled up and the run is
   smoothed again. Once the vehicle's size is known (step 2), observations whose box is far
   from it (``size_outlier_ratio``: a blob merged with a neighbour, a fragment) have biased
   centres: the track is smoothed once more with their noise raised.
2. **One size per vehicle**: a vehicle's size on the ground does not change; partial and merged
   blobs do. Sizes are estimated per run of consecutive in-view frames (a tracklet: a wrong link
   between two vehicles must not give one the other's size), in one of two ways
   (``size_mode``):

   * ``window`` (default): per image axis, a quantile of the boxes' sides, normalised by the
     local scale of that frame's homography, over a short time window (:func:`window_sizes`;
     on registered frames 2 s, pooling only observations whose smoothed heading is close to
     the point's own, so that a turn does not mix the vehicle's two aspects; 1 s in image
     coordinates); the box is centred on the smoothed ground point. It follows turns and
     camera rotation through the window, and needs no vehicle model.
   * ``oriented``: one length and width per run (:func:`oriented_size`): each box gives a length
     estimate through the local Jacobian of the world -> frame homography at the smoothed
     heading, the run's length is their quantile, the width from the median aspect; each box is
     then the bounding box, in that frame's pixels, of the footprint centred on the smoothed
     ground point at the smoothed heading (:func:`footprint_box`). It is the better model when
     partial blobs last long (Santiago, generated scenes with the detector: +0.006 HOTA,
     +0.014 IDF1 over ``window``), but a heading error of a few degrees widens the box of a
     long, thin vehicle, and with noisy but unbiased boxes (noisy ground-truth detections) or
     small vehicles it loses to ``window`` (benchmarks/finish.py). Without registered frames the
     world is the image of a moving camera and headings mean nothing: ``auto`` then falls back
     to ``window``.
3. **Frame border**: a box touching the border is clipped by it; it gives no size and its centre
   is rebuilt from its inner edges and the track's size before the final smoothing. Reported
   boxes keep the whole vehicle past the border unless ``clip_to_frame`` (off by default, as
   ground truths draw them). A point whose whole box has its centre outside the frame is out of
   view (``centre_out_of_view``): it is reported as predicted.
4. **Static, wandering and small tracks** (:func:`is_static`, :func:`wanders`,
   :func:`is_small`): a track whose smoothed ground points stay within a box of
   ``static_extent_m`` diagonal never moved (a parked vehicle, a median blob, a registration
   artefact) and is dropped; so is one that went back and forth within ``wander_extent_m`` (the
   parallax of a tree's or a wall's edge under a moving camera), and one whose typical footprint
   is under ``min_size_m`` (``min_size_estimated_m`` when the scale was estimated from the
   objects: a pedestrian, a fragment). A vehicle that waits and then drives is
   kept whole.
5. **Standing vehicles** (:func:`hold_stops`, before the steps above): a vehicle that stopped
   where the detector lost it (its sliding-window background absorbs a standing vehicle) is
   reported ``stationary`` at its stop: over a gap between two observations at the same place,
   after the end of a track that came to a standstill, and before the start of one that drove
   off from one, until another track is seen at that place or ``stop_hold_s`` has passed
   (ends and starts are held only when ``stop_hold_s`` / ``stop_hold_back_s`` > 0; both are off
   by default, see ``FinishConfig``). Registered frames only.

Coordinates: ``TrackPoint.world`` in world units (map pixels or reference pixels),
``TrackPoint.box`` in the pixels of the point's own frame; ``Registration.H`` maps frame pixels to
world. Without registrations the world is the frame (association alone on external detections).
"""

from __future__ import annotations

import itertools
import logging
import math

import numpy as np
from numba import njit

from ..config import FinishConfig
from ..errors import ConfigError
from ..kalman import (
    ConstantVelocityKF,
    cholesky_solve,
    initiate_nb,
    predict_nb,
    process_noise_nb,
    transition_nb,
    update_nb,
)
from ..types import Registration, Track, TrackPoint, apply_homography, homography_jacobian
from .linking import same_frame_overlaps

__all__ = [
    "SIZE_MODES",
    "TrackFinisher",
    "end_state",
    "finish_tracks",
    "hold_stops",
    "is_small",
    "is_static",
    "oriented_size",
    "robust_smooth",
    "rts_smooth",
    "suppress_overlaps",
    "window_sizes",
]

log = logging.getLogger(__name__)

IN_VIEW = ("observed", "bridged", "stationary")
MEASURED = ("observed", "stationary")
SIZE_MODES = ("auto", "oriented", "window", "detection")


# -- smoothing -------------------------------------------------------------------------------------

#: Factor on the observation-noise variance of a box far from the vehicle's size
#: (``FinishConfig.size_outlier_ratio``): 5x the standard deviation.
SIZE_OUTLIER_NOISE = 25.0


def rts_smooth(times: np.ndarray, zs: np.ndarray, Rs: np.ndarray, kf: ConstantVelocityKF
               ) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel smoothing of the constant-velocity model over one run of frames.

    Parameters
    ----------
    times : ndarray (N,)
        Seconds, increasing (every frame of the run, observed or not).
    zs : ndarray (N, 4)
        Observations ``(x, y, w, h)``, world units; rows with a NaN are not observed (predicted
        through). The first row must be observed.
    Rs : ndarray (N, 4, 4)
        Observation noise of each row (world units squared).
    kf : ConstantVelocityKF
        Process noise (``accel_std``, ``size_std``) and the initial velocity spread.

    Returns
    -------
    xs : ndarray (N, 6)
        Smoothed states ``(x, y, w, h, vx, vy)``, world units and world units per second.
    Ps : ndarray (N, 6, 6)
        Smoothed covariances.
    """
    return _rts_kernel(np.ascontiguousarray(times, dtype=np.float64),
                       np.ascontiguousarray(zs, dtype=np.float64),
                       np.ascontiguousarray(Rs, dtype=np.float64),
                       float(kf.accel_std), float(kf.size_std), float(kf.vel_std))


@njit(cache=True)
def _rts_kernel(times, zs, Rs, accel_std, size_std, vel_std):
    """Compiled forward filter (kalman.py's functions) and backward RTS pass of
    :func:`rts_smooth`."""
    n = times.shape[0]
    xf = np.zeros((n, 6))
    Pf = np.zeros((n, 6, 6))
    xp = np.zeros((n, 6))
    Pp = np.zeros((n, 6, 6))
    As = np.zeros((n, 6, 6))
    x, P = initiate_nb(zs[0], Rs[0], vel_std)
    xf[0], Pf[0], xp[0], Pp[0] = x, P, x, P
    for i in range(1, n):
        dt = times[i] - times[i - 1]
        As[i] = transition_nb(dt)
        x, P = predict_nb(x, P, As[i], process_noise_nb(abs(dt), accel_std, size_std))
        xp[i], Pp[i] = x, P
        if np.all(np.isfinite(zs[i])):
            x, P, _, _ = update_nb(x, P, zs[i], Rs[i])
        xf[i], Pf[i] = x, P
    xs = xf.copy()
    Ps = Pf.copy()
    for i in range(n - 2, -1, -1):
        # smoother gain C = P_f A^T P_p^-1, as the transpose of P_p^-1 (A P_f) (P_p symmetric)
        X, logdet = cholesky_solve(Pp[i + 1], As[i + 1] @ Pf[i])
        if not np.isfinite(logdet):
            continue  # keep the filtered state
        C = X.T
        xs[i] = xf[i] + C @ (xs[i + 1] - xp[i + 1])
        Ps[i] = Pf[i] + C @ (Ps[i + 1] - Pp[i + 1]) @ C.T
    return xs, Ps


def robust_smooth(times: np.ndarray, zs: np.ndarray, Rs: np.ndarray, kf: ConstantVelocityKF,
                  outlier_chi2: float, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rts_smooth` with iteratively re-weighted observations.

    After each pass, an observation whose squared Mahalanobis distance (position only, 2 dof)
    to the smoothed state, under its noise plus the state's covariance, exceeds ``outlier_chi2``
    has its noise multiplied by ``d2 / outlier_chi2`` (a Huber-like weight), and the run is
    smoothed again. Returns the last pass's states (N, 6) and the weights (N,) (1 = full weight).
    """
    w = np.ones(len(times))
    xs, Ps = rts_smooth(times, zs, Rs, kf)
    seen = np.all(np.isfinite(zs), axis=1)
    for _ in range(max(0, int(iters))):
        e = zs[:, :2] - xs[:, :2]
        S = Rs[:, :2, :2] + Ps[:, :2, :2]
        d2 = np.full(len(times), 0.0)
        idx = np.flatnonzero(seen)
        if len(idx):
            d2[idx] = np.einsum("ni,nij,nj->n", e[idx], np.linalg.inv(S[idx]), e[idx])
        new = np.where(d2 > outlier_chi2, d2 / outlier_chi2, 1.0)
        if np.allclose(new, w):
            break
        w = new
        xs, Ps = rts_smooth(times, zs, Rs * w[:, None, None], kf)
    return xs, w


# -- geometry -------------------------------------------------------------------------------------

def _noise(sizes: np.ndarray, pos_std: float, pos_frac: float, size_std: float, size_frac: float
           ) -> np.ndarray:
    """(N, 4, 4) diagonal observation noise for (N, 2) sizes, as
    :func:`aerotrack.kalman.measurement_noise` row by row."""
    s = np.abs(sizes)
    R = np.zeros((len(s), 4, 4))
    for i in range(2):
        R[:, i, i] = pos_std ** 2 + (pos_frac * s[:, i]) ** 2
        R[:, i + 2, i + 2] = size_std ** 2 + (size_frac * s[:, i]) ** 2
    return R


def _project(Hinv: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (N, K, 2) through per-row homographies ``Hinv`` (N, 3, 3) -> (N, K, 2)."""
    h = np.einsum("nij,nkj->nki", Hinv, np.concatenate([pts, np.ones(pts.shape[:2] + (1,))], 2))
    return h[..., :2] / h[..., 2:3]


def _footprints(Hinv: np.ndarray, centre: np.ndarray, heading: np.ndarray, length: float,
                width: float) -> np.ndarray:
    """:func:`footprint_box` for N frames at once: (N, 4) boxes."""
    f = np.stack([np.cos(heading), np.sin(heading)], 1) * length / 2
    r = np.stack([-np.sin(heading), np.cos(heading)], 1) * width / 2
    corners = centre[:, None, :] + np.stack([f + r, f - r, -f - r, -f + r], 1)
    px = _project(Hinv, corners)
    lo, hi = px.min(axis=1), px.max(axis=1)
    return np.column_stack([lo, hi - lo])


def footprint_box(Hinv: np.ndarray, centre: np.ndarray, heading: float, length: float,
                  width: float) -> np.ndarray:
    """Frame-pixel box ``(left, top, w, h)`` of a ``length x width`` rectangle (world units)
    centred on world point ``centre`` at ``heading`` (radians, world axes), through ``Hinv``
    (world -> frame pixels)."""
    f = np.array([math.cos(heading), math.sin(heading)]) * length / 2
    r = np.array([-math.sin(heading), math.cos(heading)]) * width / 2
    corners = centre + np.array([f + r, f - r, -f - r, -f + r])
    px = apply_homography(Hinv, corners)
    lo, hi = px.min(axis=0), px.max(axis=0)
    return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]])


def oriented_size(boxes: np.ndarray, jacobians: np.ndarray, headings: np.ndarray,
                  quantile: float, default_aspect: float) -> tuple[float, float]:
    """A vehicle's (length, width) in world units from its frame-pixel boxes.

    The box of a ``L x W`` rectangle at heading theta seen through a local Jacobian J has half
    extents ``|a| L / 2 + |b| W / 2`` per axis, with ``a = J f``, ``b = J r`` (f, r the heading's
    forward and right unit vectors). Each observation where the 2x2 system is well conditioned
    (heading not near a diagonal of the image) gives the aspect ``W / L``; their median is the
    track's aspect (``default_aspect`` if none). With it, the sum of both box sides of every
    observation gives one length estimate; the track's length is their ``quantile``.

    Parameters
    ----------
    boxes : ndarray (N, 4)
        Observed boxes, frame pixels (only their sizes are used).
    jacobians : ndarray (N, 2, 2)
        World -> frame Jacobians at the observations.
    headings : ndarray (N,)
        Headings, radians in world axes.
    """
    f = np.stack([np.cos(headings), np.sin(headings)], axis=1)
    r = np.stack([-np.sin(headings), np.cos(headings)], axis=1)
    a = np.abs(np.einsum("nij,nj->ni", jacobians, f))  # (N, 2) |J f| per image axis
    b = np.abs(np.einsum("nij,nj->ni", jacobians, r))
    wh = boxes[:, 2:4]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    norm = np.hypot(a[:, 0], a[:, 1]) * np.hypot(b[:, 0], b[:, 1])
    good = np.abs(det) > 0.5 * norm
    aspect = default_aspect
    if good.any():
        L = (wh[good, 0] * b[good, 1] - wh[good, 1] * b[good, 0]) / det[good]
        W = (a[good, 0] * wh[good, 1] - a[good, 1] * wh[good, 0]) / det[good]
        ok = (L > 0) & (W > 0)
        if ok.any():
            aspect = float(np.clip(np.median(W[ok] / L[ok]), 0.2, 1.0))
    Ls = (wh[:, 0] + wh[:, 1]) / (a.sum(axis=1) + aspect * b.sum(axis=1))
    length = float(np.quantile(Ls, quantile))
    return length, aspect * length


def window_sizes(times: np.ndarray, sizes: np.ndarray, valid: np.ndarray, window_s: float,
                 quantile: float, headings: np.ndarray | None = None,
                 max_turn: float = 0.0) -> np.ndarray:
    """Per-point size (N, 2): the ``quantile`` of the valid ``sizes`` (N, 2) within
    ``window_s / 2`` seconds of each point (of the nearest valid point if none is that close).

    With ``headings`` (N,, radians, NaN where unknown) and ``max_turn`` > 0, only points whose
    heading is within ``max_turn`` of the point's own (modulo half a turn: a box is the same
    driving either way) count, when at least one does: during a turn a vehicle's box changes its
    aspect, and a window across the turn would mix the two."""
    out = np.full(sizes.shape, np.nan)
    tv, sv = times[valid], sizes[valid]
    if not len(tv):
        return out
    lo = np.searchsorted(tv, times - window_s / 2, side="left")
    hi = np.searchsorted(tv, times + window_s / 2, side="right")
    if (far := hi == lo).any():
        # no valid size that close (a long stop filled with held points): the window around the
        # nearest valid one, not the whole track's (which mixes in the other legs of a turn)
        j = np.searchsorted(tv, times[far])
        before, after = tv[np.maximum(j - 1, 0)], tv[np.minimum(j, len(tv) - 1)]
        t = np.where(np.abs(times[far] - before) <= np.abs(after - times[far]), before, after)
        lo[far] = np.searchsorted(tv, t - window_s / 2, side="left")
        hi[far] = np.searchsorted(tv, t + window_s / 2, side="right")
    m = hi - lo  # valid sizes in each window
    k = max(int(m.max()), 1)
    idx = lo[:, None] + np.arange(k)[None]
    inside = idx < hi[:, None]
    if headings is not None and max_turn > 0:
        hv = headings[valid][np.minimum(idx, len(tv) - 1)]
        d = np.abs((hv - headings[:, None] + np.pi / 2) % np.pi - np.pi / 2)
        same = inside & ~(d > max_turn)  # NaN headings compare False: kept
        keep = same.any(axis=1)
        inside = np.where(keep[:, None], same, inside)
        m = inside.sum(axis=1)
    win = np.where(inside[:, :, None], sv[np.minimum(idx, len(sv) - 1)], np.inf)
    win = np.sort(win, axis=1)  # (N, k, 2), the window's values first
    # linear interpolation between order statistics, as numpy's default quantile
    pos = quantile * np.maximum(m - 1, 0)
    a = np.floor(pos).astype(int)
    b = np.minimum(a + 1, np.maximum(m - 1, 0))
    frac = (pos - a)[:, None]
    rows = np.arange(len(times))
    some = m > 0
    out[some] = win[rows[some], a[some]] * (1 - frac[some]) + win[rows[some], b[some]] * frac[some]
    out[~some] = np.quantile(sv, quantile, axis=0)
    return out


def is_static(world: np.ndarray, metres_per_unit: float, extent_m: float,
              duration_s: float | None = None, speed_mps: float = 0.0) -> bool:
    """True when the world points (N, 2) fit in a box of diagonal ``extent_m`` metres and, with
    ``speed_mps`` > 0, of ``speed_mps`` x ``duration_s`` (the track's span in seconds): a track
    seen for a moment has not had the time to leave ``extent_m`` (a car at 5 m/s covers 3.3 m in
    the 0.67 s of a 20-frame clip, and a probe's moving cars there were dropped as parked)."""
    if extent_m <= 0 or not len(world):
        return False
    ext = np.ptp(np.asarray(world, dtype=np.float64), axis=0)
    diag = float(np.hypot(*ext)) * metres_per_unit
    if speed_mps > 0 and duration_s is not None and diag >= speed_mps * duration_s:
        return False
    return diag < extent_m


def wanders(world: np.ndarray, times: np.ndarray, metres_per_unit: float, extent_m: float,
            path_ratio: float, step_s: float) -> bool:
    """True when the world points (N, 2) at ``times`` (s) stay within a box of diagonal
    ``extent_m`` metres while the path through them, sampled every ``step_s`` seconds, is more than
    ``path_ratio`` x that diagonal: something that went back and forth over a few metres."""
    if extent_m <= 0 or path_ratio <= 0 or len(world) < 3:
        return False
    world = np.asarray(world, dtype=np.float64)
    diag = float(np.hypot(*np.ptp(world, axis=0))) * metres_per_unit
    if diag >= extent_m or diag <= 0:
        return False
    times = np.asarray(times, dtype=np.float64)
    grid = np.arange(times[0], times[-1] + 1e-9, max(step_s, 1e-6))
    idx = np.unique(np.searchsorted(times, grid).clip(0, len(times) - 1))
    idx = np.union1d(idx, [len(times) - 1])
    path = float(np.hypot(*np.diff(world[idx], axis=0).T).sum()) * metres_per_unit
    return path > path_ratio * diag


def is_small(sizes: np.ndarray, metres_per_unit: float, min_size_m: float) -> bool:
    """True when the median footprint ``sqrt(w * h)`` of the world sizes (N, 2) is below
    ``min_size_m`` metres (False without sizes or with ``min_size_m`` 0)."""
    sizes = np.abs(np.asarray(sizes, dtype=np.float64).reshape(-1, 2))
    if min_size_m <= 0 or not len(sizes):
        return False
    return float(np.median(np.sqrt(sizes[:, 0] * sizes[:, 1]))) * metres_per_unit < min_size_m


def _headings(vel: np.ndarray, min_speed: float) -> np.ndarray:
    """Heading (radians) of each velocity (N, 2); where slower than ``min_speed`` (world units/s)
    the nearest faster point's heading (NaN when none is)."""
    speed = np.hypot(vel[:, 0], vel[:, 1])
    fast = np.flatnonzero(speed >= min_speed)
    out = np.full(len(vel), np.nan)
    if not len(fast):
        return out
    h = np.arctan2(vel[fast, 1], vel[fast, 0])
    pos = np.searchsorted(fast, np.arange(len(vel)))
    left = fast[np.clip(pos - 1, 0, len(fast) - 1)]
    right = fast[np.clip(pos, 0, len(fast) - 1)]
    i = np.arange(len(vel))
    pick = np.where(np.abs(i - left) <= np.abs(right - i), np.clip(pos - 1, 0, len(fast) - 1),
                    np.clip(pos, 0, len(fast) - 1))
    return h[pick]


# -- the stage ------------------------------------------------------------------------------------

class TrackFinisher:
    """Rebuilds the in-view points of final tracks (see the module docstring).

    Parameters
    ----------
    config : FinishConfig
    fps : float
    metres_per_unit : float, optional
        Metres per world unit; without it the scale is estimated as global linking does
        (the median observed object's longer side is ``object_size_m``).
    object_size_m : float
        See ``metres_per_unit``.
    scale_estimated : bool
        ``metres_per_unit`` is such an estimate (made by global linking): small tracks are then
        judged by ``min_size_estimated_m``. Also True when ``metres_per_unit`` is not given.
    """

    def __init__(self, config: FinishConfig | None = None, fps: float = 30.0, *,
                 metres_per_unit: float | None = None, object_size_m: float = 4.5,
                 scale_estimated: bool = False) -> None:
        self.config = config or FinishConfig()
        self._dropped = ""  # why the track being finished is left out (``finish``'s log)
        if self.config.size_mode not in SIZE_MODES:
            raise ConfigError(f"config finish.size_mode: unknown {self.config.size_mode!r} "
                              f"(valid: {', '.join(SIZE_MODES)})")
        if not 0.0 <= self.config.size_quantile <= 1.0:
            raise ConfigError(f"config finish.size_quantile: {self.config.size_quantile} "
                              "must be in [0, 1]")
        for name in ("stop_hold_s", "stop_hold_back_s", "stop_speed_mps", "stop_decel_mps2",
                     "stop_radius_m", "stop_window_s", "stop_run_gap_s", "stop_gap_speed_mps",
                     "static_speed_mps"):
            if not getattr(self.config, name) >= 0:
                raise ConfigError(f"config finish.{name}: must be >= 0")
        if not (0.0 <= self.config.absorbed_ratio < 1.0 and self.config.absorbed_speed > 0):
            raise ConfigError("config finish.absorbed_ratio must be in [0, 1) and "
                              "finish.absorbed_speed > 0")
        if not (self.config.size_outlier_ratio == 0 or self.config.size_outlier_ratio > 1):
            raise ConfigError(f"config finish.size_outlier_ratio: "
                              f"{self.config.size_outlier_ratio} must be 0 (off) or > 1")
        for name in ("regain_gap_s", "regain_end_s"):
            if not getattr(self.config, name) >= 0:
                raise ConfigError(f"config finish.{name}: must be >= 0")
        if not 0.0 < self.config.regain_iou <= 1.0:
            raise ConfigError(f"config finish.regain_iou: {self.config.regain_iou} must be in "
                              "(0, 1]")
        if not 0.0 < self.config.max_overlap <= 1.0:
            raise ConfigError(f"config finish.max_overlap: {self.config.max_overlap} "
                              "must be in (0, 1]")
        self.fps = float(fps)
        self.metres_per_unit = metres_per_unit
        self.object_size_m = object_size_m
        self.scale_estimated = scale_estimated or not metres_per_unit

    def finish(self, tracks: list[Track], registrations: dict[int, Registration] | None = None,
               frame_size: tuple[int, int] | None = None) -> list[Track]:
        """The tracks with their in-view points rebuilt (in place) and static tracks left out.

        Parameters
        ----------
        tracks : list of Track
            Final tracks (world coordinates, boxes in frame pixels).
        registrations : dict frame -> Registration, optional
            Frame pixels -> world of every frame; None: the world is the frame.
        frame_size : (W, H), optional
            Boxes are clipped to it (``clip_to_frame``) and the border test uses it.
        """
        c = self.config
        if not c.enabled or not tracks:
            return list(tracks)
        mpu = self.metres_per_unit
        if not mpu:
            from .linking import estimate_scale

            mpu = estimate_scale(tracks, self.object_size_m)
        mode = c.size_mode
        if mode == "auto":
            mode = "oriented" if registrations else "window"
        if c.fill_gaps_s > 0:
            for t in tracks:
                _fill_gaps(t, round(c.fill_gaps_s * self.fps))
        if registrations and (c.stop_hold_s > 0 or c.stop_hold_back_s > 0 or c.stop_radius_m > 0
                              or c.stop_gap_speed_mps > 0):
            n = hold_stops(tracks, self.fps, mpu, registrations, frame_size, c)
            log.debug("finish: %d stationary points added", n)
        out = []
        dropped: dict[str, int] = {}
        for t in tracks:
            self._dropped = ""
            try:
                keep = self._finish_track(t, registrations or None, frame_size, mpu, mode)
            except np.linalg.LinAlgError:  # a degenerate run: report it as linking made it
                log.debug("finish: track %d left as is (singular smoother)", t.id)
                keep = True
            if keep:
                out.append(t)
            else:
                dropped[self._dropped] = dropped.get(self._dropped, 0) + 1
        if dropped:  # a probe's far vehicles of an oblique view vanished here without a word
            still = any("static_extent_m" in why or "wander_extent_m" in why for why in dropped)
            # with a trained detector's boxes those are often real vehicles that never moved in
            # the clip (a queue at a red light, parked cars: issue 4 leaves the latter out)
            log.info("finish: %d of %d tracks left out: %s%s", sum(dropped.values()), len(tracks),
                     "; ".join(f"{n} {why}" for why, n in sorted(dropped.items())),
                     " (vehicles never seen moving, parked or waiting all along; to keep them: "
                     "--set finish.static_extent_m=0 --set finish.wander_extent_m=0)"
                     if still else "")
        if registrations and c.max_overlap < 1.0:  # (an oblique camera's image has overlaps)
            n = suppress_overlaps(out, c.max_overlap)
            log.debug("finish: %d points on another track's object removed", n)
            out = [t for t in out if any(p.kind in IN_VIEW for p in t.points)]
        return out

    # -- one track --------------------------------------------------------------------------------
    def _finish_track(self, t: Track, regs, frame_size, mpu: float, mode: str) -> bool:
        c = self.config
        pts = [p for p in t.points if p.kind in IN_VIEW and p.box is not None]
        if regs is not None:
            pts = [p for p in pts if p.frame in regs]
        if len(pts) < 2:
            return True
        pts.sort(key=lambda p: p.frame)
        n = len(pts)
        frames = np.array([p.frame for p in pts])
        times = (frames - 1) / self.fps
        boxes = np.array([np.asarray(p.box, dtype=np.float64) for p in pts])
        measured = np.array([p.kind in MEASURED for p in pts]) & np.all(np.isfinite(boxes), axis=1)
        if measured.sum() < 2:
            return True
        if regs is not None:
            Hinv = np.linalg.inv(np.array([regs[p.frame].H for p in pts], dtype=np.float64))
        else:  # detections alone: the identity, or on a map the still placement
            still = getattr(self, "still_H", None)
            Hinv = np.tile(np.eye(3) if still is None else np.linalg.inv(still), (n, 1, 1))
        world = np.array([np.asarray(p.world, dtype=np.float64) for p in pts])
        edge = self._at_border(boxes, frame_size) & measured
        # kalman.process_noise holds the acceleration constant over each step (discrete white
        # noise): over one-frame steps the velocity then wanders by accel_std / sqrt(fps) in a
        # second. Scaled so that accel_std_mps2 is the velocity's spread after 1 s at any fps.
        kf = ConstantVelocityKF(accel_std=c.accel_std_mps2 * math.sqrt(self.fps) / mpu,
                                size_std=0.3 / mpu, vel_std=20.0 / mpu)
        sizes = self._world_sizes(pts, boxes, Hinv, world)
        # one smoothing pass on the raw ground points gives headings and the size
        xs = self._smooth(times, frames, world, sizes, measured, kf, mpu)
        if not c.smooth:  # the smoothed velocity still gives the headings
            xs[:, :2] = world
        # only a registered world is the ground: in the image of a moving camera a vehicle
        # driving along with it stands still
        span = float(times[measured][-1] - times[measured][0]) if measured.any() else 0.0
        if regs is not None and is_static(xs[measured, :2], mpu, c.static_extent_m, span,
                                          c.static_speed_mps):
            self._dropped = "standing still (finish.static_extent_m)"
            return False
        if regs is not None and wanders(xs[measured, :2], times[measured], mpu, c.wander_extent_m,
                                        c.wander_path_ratio, c.wander_step_s):
            log.debug("finish: track of frames %d-%d dropped: back and forth within %.1f m",
                      frames[0], frames[-1],
                      float(np.hypot(*np.ptp(xs[measured, :2], axis=0))) * mpu)
            self._dropped = "moving back and forth in place (finish.wander_extent_m)"
            return False
        # a held stop's box is a copy, a persistence box (``weak``) a faint blob's: the size
        # comes from the regular observations around them
        full = measured & ~edge & np.array([p.kind == "observed" and not p.weak for p in pts])
        min_size = c.min_size_estimated_m if self.scale_estimated else c.min_size_m
        if regs is not None and is_small(sizes[full], mpu, min_size):
            self._dropped = (f"smaller than {min_size:g} m (finish.min_size_estimated_m, on a scale "
                             f"estimated from the objects)" if self.scale_estimated
                             else f"smaller than {min_size:g} m (finish.min_size_m)")
            return False
        if any(p.weak for p in pts) and not any(p.kind == "observed" and not p.weak for p in pts):
            # persistence boxes only: track-before-detect evidence extends a vehicle that the
            # regular detector saw at some point; alone it is a slow, small mover (on Santiago
            # mostly pedestrians)
            self._dropped = "faint persistence boxes only"
            return False
        J = homography_jacobian(Hinv, xs[:, :2])
        # one size per run of consecutive in-view frames (a tracklet): a wrong link between two
        # vehicles must not give one of them the other's size
        new = np.zeros((n, 4))
        cuts = np.flatnonzero(np.diff(frames) > 1) + 1
        weak = np.array([p.weak for p in pts])
        for run in np.split(np.arange(n), cuts):
            if mode != "detection" and not full[run].any() and weak[run].any() and full.any():
                # a run of persistence boxes only (the vehicle went faint, e.g. standing
                # half-absorbed by the background): its size from the track's regular
                # observations nearest in time rather than from faint blobs
                both = np.union1d(run, np.flatnonzero(full))
                new[run] = self._run_boxes(both, "window", xs, boxes, J, Hinv, times, full,
                                           mpu, registered=regs is not None
                                           )[np.searchsorted(both, run)]
                continue
            new[run] = self._run_boxes(run, mode, xs, boxes, J, Hinv, times, full, mpu,
                                       registered=regs is not None,
                                       absorbed=regs is not None)
        inflate = None
        if c.smooth and c.size_outlier_ratio > 0:
            # a merged blob's or a fragment's centre is off the vehicle's: smooth again with
            # those centres down-weighted (their box size is already left out of ``new``)
            area = boxes[:, 2] * boxes[:, 3]
            ref = new[:, 2] * new[:, 3]
            off = measured & ~edge & ((area > c.size_outlier_ratio * ref)
                                      | (area * c.size_outlier_ratio < ref))
            if off.any():
                inflate = np.where(off, SIZE_OUTLIER_NOISE, 1.0)
                if not edge.any():  # else the border pass below smooths with it
                    xs2 = self._smooth(times, frames, world, sizes, measured, kf, mpu, inflate)
                    new[:, :2] += (_project(Hinv, xs2[:, None, :2])
                                   - _project(Hinv, xs[:, None, :2]))[:, 0]
                    xs = xs2
        if c.smooth and edge.any():
            # a border-clipped box: its inner edges are right; rebuild its centre with the full
            # size, and smooth again with the rebuilt centres
            world2 = world.copy()
            for i in np.flatnonzero(edge):
                cx, cy = self._unclipped_centre(boxes[i], new[i], frame_size)
                world2[i] = apply_homography(np.linalg.inv(Hinv[i]), np.array([[cx, cy]]))[0]
            xs2 = self._smooth(times, frames, world2, sizes, measured, kf, mpu, inflate)
            new[:, :2] += (_project(Hinv, xs2[:, None, :2]) - _project(Hinv, xs[:, None, :2]))[:, 0]
            xs = xs2
        outside = np.zeros(n, bool)
        if c.centre_out_of_view and frame_size is not None:
            cx, cy = new[:, 0] + new[:, 2] / 2, new[:, 1] + new[:, 3] / 2
            outside = ~((cx >= 0) & (cx < frame_size[0]) & (cy >= 0) & (cy < frame_size[1]))
        if c.clip_to_frame and frame_size is not None:
            new = _clip(new, frame_size)
        good = (new[:, 2] > 0) & (new[:, 3] > 0) & np.all(np.isfinite(new), axis=1)
        for i in np.flatnonzero(good):
            pts[i].box = new[i]
            pts[i].world = xs[i, :2].copy()
            if outside[i]:  # more than half the vehicle past the border: out of view
                pts[i].kind, pts[i].conf, pts[i].det_index = "predicted", 0.0, -1
        return True

    def _unabsorbed(self, wh, norm, times, valid, vel) -> np.ndarray:
        """Window sizes ``wh`` (N, 2, world units) with a vehicle that the background half absorbed
        while it crept or waited given the size it had while it moved.

        A vehicle slower than ``absorbed_speed`` of its own sizes per second (the square root of
        its median box area while faster) stays over much of its own footprint for much of the
        background window, so the window median takes it in and only a fragment is detected: where
        the track is that slow and its window size's area is under ``absorbed_ratio`` of that
        moving area, its size comes from its other observations (nearest in time). Speeds in
        sizes per second need no scale (a map or ``--gsd``), which the metre thresholds would.
        ``vel`` (N, 2): smoothed velocity, world units per second."""
        c = self.config
        speed = np.hypot(vel[:, 0], vel[:, 1])
        area = np.prod(norm, axis=1)
        if valid.sum() < 3:
            return wh
        # the unit from every observation first, then from those that move by it
        moving = valid & (speed >= c.absorbed_speed * math.sqrt(float(np.median(area[valid]))))
        if moving.sum() < 3:
            return wh
        ref = float(np.median(area[moving]))
        unit = math.sqrt(ref)
        low = (speed < c.absorbed_speed * unit) & (np.prod(np.nan_to_num(wh), axis=1)
                                                   < c.absorbed_ratio * ref)
        if not low.any() or (valid & ~low).sum() < 3:
            return wh
        out = wh.copy()
        out[low] = window_sizes(times, norm, valid & ~low, c.size_window_s, c.size_quantile)[low]
        return out

    def _run_boxes(self, run, mode, xs, boxes, J, Hinv, times, full, mpu,
                   registered: bool = False, absorbed: bool = False) -> np.ndarray:
        """(len(run), 4) frame-pixel boxes of one run of consecutive frames (see ``size_mode``);
        ``registered``: the world is the ground (``size_window_s`` and ``size_turn_deg``, else
        ``size_window_image_s``); ``absorbed``: check for a vehicle half absorbed by the
        background (:meth:`_unabsorbed`; only on registered frames, where speeds are real)."""
        c = self.config
        if mode == "oriented":
            head = _headings(xs[run, 4:6], c.min_heading_speed_mps / mpu)
            ok = full[run]
            if np.all(np.isfinite(head)) and ok.any():
                L, W = oriented_size(boxes[run][ok], J[run][ok], head[ok], c.size_quantile,
                                     c.default_aspect)
                return _footprints(Hinv[run], xs[run, :2], head, L, W)
            mode = "window"  # never seen moving: no heading, keep the frame axes
        if mode == "window":
            scale = np.sqrt(np.abs(np.linalg.det(J[run])))
            norm = boxes[run, 2:4] / scale[:, None]
            # on registered frames sizes are on the ground: a longer window, and only the
            # observations facing the same way
            head = None
            if registered and c.size_turn_deg > 0:
                # where it moves too slowly for a heading, a point takes the nearest faster
                # one's: a vehicle standing after a turn has the size it drove in with
                head = _headings(xs[run, 4:6], c.min_heading_speed_mps / mpu)
            window = c.size_window_s if registered else c.size_window_image_s
            wh = window_sizes(times[run], norm, full[run], window, c.size_quantile, head,
                              math.radians(c.size_turn_deg))
            if absorbed and c.absorbed_ratio > 0:
                wh = self._unabsorbed(wh, norm, times[run], full[run], xs[run, 4:6])
            wh = np.where(np.isfinite(wh), wh, norm) * scale[:, None]
        else:
            wh = boxes[run, 2:4]
        c_px = _project(Hinv[run], xs[run, None, :2])[:, 0]
        return np.column_stack([c_px - wh / 2, wh])

    def _smooth(self, times, frames, world, sizes, measured, kf, mpu,
                inflate: np.ndarray | None = None) -> np.ndarray:
        """Robust RTS over each run of consecutive frames; (N, 6) states (unsmoothed rows copied
        for runs with fewer than two measurements). ``inflate`` (N,): factors on each
        observation's noise variance."""
        c = self.config
        n = len(times)
        xs = np.column_stack([world, sizes, np.zeros((n, 2))])
        cuts = np.flatnonzero(np.diff(frames) > 1) + 1
        for run in np.split(np.arange(n), cuts):
            m = measured[run]
            if m.sum() < 2:
                continue
            first, last = run[np.flatnonzero(m)[0]], run[np.flatnonzero(m)[-1]] + 1
            r = np.arange(first, last)
            # every frame of the run, observed or not (frames are consecutive inside a run)
            zs = np.column_stack([world[r], sizes[r]])
            zs[~measured[r]] = np.nan
            Rs = _noise(np.nan_to_num(sizes[r]), c.pos_std_m / mpu, c.pos_frac, 0.3 / mpu, 0.1)
            if inflate is not None:
                Rs = Rs * inflate[r][:, None, None]
            x_r, _ = robust_smooth(times[r], zs, Rs, kf, c.outlier_chi2, c.robust_iters)
            xs[r] = x_r
            # points of the run outside the measured span (bridged ends) keep constant velocity
            for i in run[run < first]:
                xs[i] = x_r[0]
                xs[i, :2] = x_r[0, :2] + x_r[0, 4:6] * (times[i] - times[first])
            for i in run[run >= last]:
                xs[i] = x_r[-1]
                xs[i, :2] = x_r[-1, :2] + x_r[-1, 4:6] * (times[i] - times[last - 1])
        return xs

    @staticmethod
    def _world_sizes(pts, boxes, Hinv, world) -> np.ndarray:
        """(N, 2) sizes in world units (``size_world``, else the box through the homography)."""
        nan2 = np.full(2, np.nan)
        out = np.abs(np.array([nan2 if p.size_world is None else p.size_world for p in pts],
                              dtype=np.float64).reshape(-1, 2))
        missing = ~np.all(np.isfinite(out), axis=1)
        if missing.any():
            scale = np.sqrt(np.abs(np.linalg.det(homography_jacobian(Hinv[missing], world[missing]))))
            out[missing] = boxes[missing, 2:4] / np.where(scale > 0, scale, 1.0)[:, None]
        return np.nan_to_num(out)

    def _at_border(self, boxes: np.ndarray, frame_size) -> np.ndarray:
        if frame_size is None:
            return np.zeros(len(boxes), bool)
        m = self.config.edge_margin_px
        W, H = frame_size
        with np.errstate(invalid="ignore"):
            return ((boxes[:, 0] <= m) | (boxes[:, 1] <= m) | (boxes[:, 0] + boxes[:, 2] >= W - m)
                    | (boxes[:, 1] + boxes[:, 3] >= H - m))

    def _unclipped_centre(self, box, full, frame_size) -> tuple[float, float]:
        """Centre of a ``full``-sized box aligned with the inner edges of border-clipped ``box``."""
        m = self.config.edge_margin_px
        W, H = frame_size
        cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
        left, right = box[0] <= m, box[0] + box[2] >= W - m
        top, bottom = box[1] <= m, box[1] + box[3] >= H - m
        if left and not right:
            cx = box[0] + box[2] - full[2] / 2
        elif right and not left:
            cx = box[0] + full[2] / 2
        if top and not bottom:
            cy = box[1] + box[3] - full[3] / 2
        elif bottom and not top:
            cy = box[1] + full[3] / 2
        return cx, cy


# -- standing vehicles -----------------------------------------------------------------------------

def end_state(frames: np.ndarray, world: np.ndarray, fps: float, window: int
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """Position at the last frame and velocity (world units per second) of the least-squares
    line through the observed points ``world`` (N, 2) at ``frames`` (N,, increasing) within the
    last ``window`` frames; None with fewer than 3 such points or when they span less than half
    the window (too short to tell a stop from a slow crawl)."""
    k = frames >= frames[-1] - window
    fr, xy = frames[k].astype(np.float64), world[k]
    if len(fr) < 3 or fr[-1] - fr[0] < window / 2:
        return None
    t = fr - fr.mean()
    mean = xy.mean(axis=0)
    slope = (t @ (xy - mean)) / float(t @ t)
    return mean + slope * t[-1], slope * fps


class _Occupancy:
    """Observed ground points of every track, by frame: which frames another track is seen within
    a radius of a world point (the place a held vehicle stands is taken: it left, or it is seen
    again under another identity)."""

    def __init__(self, tracks: list[Track]):
        self.by_frame: dict[int, list[tuple[int, np.ndarray]]] = {}
        for t in tracks:
            for p in t.points:
                if p.kind == "observed" and p.world is not None:
                    self.by_frame.setdefault(p.frame, []).append((t.id, np.asarray(p.world, float)))

    def taken(self, frame: int, world: np.ndarray, radius: float, tid: int) -> bool:
        return any(i != tid and float(np.hypot(*(w - world))) <= radius
                   for i, w in self.by_frame.get(frame, ()))


def hold_stops(tracks: list[Track], fps: float, mpu: float, registrations: dict[int, Registration],
               frame_size: tuple[int, int] | None, config: FinishConfig) -> int:
    """Report vehicles that stand still where the detector lost them, as ``stationary`` points.

    A vehicle that stops (at a light, in a queue) is absorbed by the detector's sliding-window
    background after about half the window (``detection.hold_stopped`` delays this, but a
    partial or noisy blob breaks it). Without this step its track then either ends (the rest
    of the stop is missing from ``tracks.csv``) or is linked over the stop with ``predicted``
    points (reported as out of view). In place, per track (registered frames only: in the image
    of a moving camera standing still means nothing):

    * **a gap** between two in-view points whose ground points lie within ``stop_radius_m`` of
      each other, where the track arrived at under ``stop_speed_mps`` (or left at under it),
      is filled with ``stationary`` points at the stop;
    * **a stop-and-go gap** of at least 1 s crossed at under ``stop_gap_speed_mps`` on average
      (the vehicle lost while braking and found again while pulling away, so neither end stands)
      whose ends are inside the frame and which the track was seen driving into and off from,
      is filled along braking, standing and pulling away at ``stop_decel_mps2``;
    * **the end**: a track seen driving into its stop (the run of observations before it,
      consecutive ones at most ``stop_run_gap_s`` apart, spreads over ``static_extent_m`` or
      more) and whose last ``stop_window_s`` of observations stand still (speed under
      ``stop_speed_mps``), with its last box inside the frame, stays at its stop for up to
      ``stop_hold_s`` (and the end of the video), after braking from its end speed at
      ``stop_decel_mps2`` (a few centimetres at the default ``stop_speed_mps``);
    * **the start** likewise, backwards, for up to ``stop_hold_back_s``: a vehicle that stood
      since before the video (or its detection) began and then drove off.

    A hold ends at the first frame in which another track is observed within ``stop_radius_m`` of
    the stop (the vehicle drove off and was seen again under another identity, or another
    vehicle stands there): a stop is never held over a detection. A never-moving track is not
    held (and is dropped later as static); a false alarm is held only when it moved like a
    vehicle and stopped, and never longer than the hold.

    Measured (``FinishConfig`` docs): on Santiago and on generated scenes, even ones with a stop
    at most junctions, the detector loses vehicles while they still creep (2-4 m/s), not once
    they stand: Santiago's GT 24 is lost at frame 62 at about 1 px/frame and creeps 13 px more
    to its stop at frame 80; linking's constant-velocity prediction of it (``predicted.csv``)
    overlaps the truth at IoU >= 0.5 in 26 of its 38 frames. Holding tracks that end at such
    speeds held more false and misplaced tracks than lost vehicles (convoy:2 -0.07 HOTA at 3 m/s), so only
    real standstills are held; without pixels a hold cannot be verified (a check of the
    frame's patch against the vehicle's and the road's appearance would need the images).

    Parameters
    ----------
    tracks : list of Track
        Final tracks, points sorted by frame (world units, frame-pixel boxes).
    mpu : float
        Metres per world unit.
    registrations : dict frame -> Registration
        Frame pixels -> world; their frames are the video's.
    frame_size : (W, H) or None
        A stop whose box touches the border is not held (the vehicle is leaving the view).

    Returns
    -------
    int
        Number of stationary points added.
    """
    frames_all = np.array(sorted(registrations), dtype=np.int64)
    if not len(frames_all) or mpu <= 0:
        return 0
    occ = _Occupancy(tracks)
    return sum(_hold_track(t, fps, mpu, registrations, frame_size, config, occ,
                           (int(frames_all[0]), int(frames_all[-1])))
               for t in tracks)


def _hold_track(t: Track, fps: float, mpu: float, registrations: dict[int, Registration],
                frame_size: tuple[int, int] | None, c: FinishConfig, occ: _Occupancy,
                span: tuple[int, int]) -> int:
    """:func:`hold_stops` for one track (in place); returns the points added."""
    obs = [p for p in t.points if p.kind == "observed" and np.all(np.isfinite(p.box))]
    if len(obs) < 3:
        return 0
    window = max(2, round(c.stop_window_s * fps))
    v_stop = c.stop_speed_mps / mpu
    decel = c.stop_decel_mps2 / mpu
    radius = c.stop_radius_m / mpu
    of = np.array([p.frame for p in obs], dtype=np.int64)
    ow = np.array([p.world for p in obs], dtype=np.float64)
    by_frame = {p.frame: p for p in t.points}
    new: dict[int, TrackPoint] = {}

    def anchor(k: int, forward: bool):
        """Stop position (median ground point), box size (``size_quantile``) and reference
        point, from the observations of the window up to (``forward``) or from index k."""
        sel = ((of <= of[k]) & (of >= of[k] - window)) if forward else \
            ((of >= of[k]) & (of <= of[k] + window))
        wh = np.quantile(np.array([obs[i].box[2:4] for i in np.flatnonzero(sel)]),
                         c.size_quantile, axis=0)
        return np.median(ow[sel], axis=0), wh, obs[k]

    def put(f: int, w: np.ndarray, wh: np.ndarray, ref: TrackPoint) -> None:
        reg = registrations.get(f)
        if reg is None:
            return
        q = apply_homography(np.linalg.inv(reg.H), w[None])[0]
        new[f] = TrackPoint(frame=f, box=np.array([q[0] - wh[0] / 2, q[1] - wh[1] / 2,
                                                   wh[0], wh[1]]),
                            world=w.copy(), conf=ref.conf, kind="stationary",
                            size_world=ref.size_world)

    def state(k: int, forward: bool):
        """(position, velocity) at observation k from the window before it (``forward``) or,
        in reversed time, after it; None when too few observations."""
        fr, xy = (of[:k + 1], ow[:k + 1]) if forward else (-of[k:][::-1], ow[k:][::-1])
        return end_state(fr, xy, fps, window)

    def standing(k: int, forward: bool) -> bool:
        st = state(k, forward)
        return st is not None and float(np.hypot(*st[1])) <= v_stop

    def hold(start: int, step: int, n: int, k: int) -> None:
        """Brake from observation k's state at ``stop_decel_mps2`` to a stop, then stand
        (backwards in time for ``step`` -1: a start from rest)."""
        p0, v = state(k, step > 0)
        _, wh, ref = anchor(k, step > 0)
        speed = float(np.hypot(*v))
        u = v / speed if speed > 0 else np.zeros(2)
        t_stop = speed / decel if decel > 0 else 0.0
        f = start
        for i in range(1, n + 1):
            dt = min(i / fps, t_stop)
            w = p0 + u * (speed * dt - 0.5 * decel * dt * dt)
            if not span[0] <= f <= span[1] or occ.taken(f, w, radius, t.id):
                break
            p = by_frame.get(f)
            if p is not None and p.kind != "predicted":
                break
            put(f, w, wh, ref)
            f += step

    def inside(p: TrackPoint) -> bool:
        if frame_size is None:
            return True
        W, H = frame_size
        x, y, bw, bh = p.box
        m = c.edge_margin_px
        return x > m and y > m and x + bw < W - m and y + bh < H - m

    # gaps between observations (after _fill_gaps: longer than fill_gaps_s)
    oi = {p.frame: k for k, p in enumerate(obs)}
    iv = [p for p in t.points if p.kind in IN_VIEW]
    v_gap = c.stop_gap_speed_mps / mpu
    for a, b in itertools.pairwise(iv):
        if b.frame - a.frame < 2 or a.frame not in oi or b.frame not in oi:
            continue
        ka, kb = oi[a.frame], oi[b.frame]
        d = float(np.hypot(*(np.asarray(b.world) - np.asarray(a.world))))
        T = (b.frame - a.frame) / fps
        if d <= radius and (standing(ka, True) or standing(kb, False)):
            w, wh, ref = anchor(ka, True)
            for f in range(a.frame + 1, b.frame):
                q = by_frame.get(f)
                if q is None or q.kind == "predicted":
                    put(f, w, wh, ref)
            continue
        if not (v_gap > 0 and T >= 1.0 and d <= v_gap * T and inside(a) and inside(b)):
            continue  # (a gap at the frame's edge: the vehicle may have left the view)
        # seen driving into the stop and off from it (a false alarm jittering in place, or a
        # parallax blob, does not travel): the observations of the 3 s before the gap and of the
        # 3 s after it spread over half ``static_extent_m`` each, one side over all of it
        span3 = round(3.0 * fps)
        ext_a = float(np.hypot(*np.ptp(ow[(of <= of[ka]) & (of >= of[ka] - span3)], axis=0))) * mpu
        ext_b = float(np.hypot(*np.ptp(ow[(of >= of[kb]) & (of <= of[kb] + span3)], axis=0))) * mpu
        if min(ext_a, ext_b) < c.static_extent_m / 2 or max(ext_a, ext_b) < c.static_extent_m:
            continue
        # stop and go: lost while braking, found again while pulling away. The stop lies
        # between the two ends, split by their braking distances (v^2); braking into it and
        # pulling away from it at ``stop_decel_mps2`` (the end speeds, fitted over a second of
        # acceleration, understate the speed reached), at most 45% of the gap each.
        sa, sb = state(ka, True), state(kb, False)
        va = float(np.hypot(*sa[1])) if sa is not None else 0.0
        vb = float(np.hypot(*sb[1])) if sb is not None else 0.0
        pa, pb = np.asarray(a.world, float), np.asarray(b.world, float)
        r = va * va / (va * va + vb * vb) if va + vb > 0 else 0.5
        S = pa + r * (pb - pa)
        d1, d2 = r * d, (1 - r) * d
        t1 = min(math.sqrt(2 * d1 / decel), 0.45 * T) if decel > 0 else 0.0
        t2 = min(math.sqrt(2 * d2 / decel), 0.45 * T) if decel > 0 else 0.0
        _, wha, refa = anchor(ka, True)
        _, whb, refb = anchor(kb, False)
        wha = whb = np.maximum(wha, whb)  # a vehicle fading while it brakes leaves partial boxes
        for f in range(a.frame + 1, b.frame):
            q = by_frame.get(f)
            if q is not None and q.kind != "predicted":
                continue
            tau = (f - a.frame) / fps
            if t1 > 0 and tau < t1:
                w = pa + (S - pa) * (1 - (1 - tau / t1) ** 2)
            elif t2 > 0 and tau > T - t2:
                w = S + (pb - S) * ((tau - (T - t2)) / t2) ** 2
            else:
                w = S
            if occ.taken(f, w, radius, t.id) or not _in_frame(registrations.get(f), w, frame_size):
                continue
            if tau <= T / 2:
                put(f, w, wha, refa)
            else:
                put(f, w, whb, refb)
    # the ends of a track that drove into its stop (or off from it)
    run_gap = max(1, round(c.stop_run_gap_s * fps)) if c.stop_run_gap_s > 0 else int(of[-1] - of[0])
    if c.stop_hold_s > 0 and inside(obs[-1]) and standing(len(obs) - 1, True) \
            and _run_extent(of, ow, run_gap, True) * mpu >= c.static_extent_m:
        hold(obs[-1].frame + 1, 1, round(c.stop_hold_s * fps), len(obs) - 1)
    if c.stop_hold_back_s > 0 and inside(obs[0]) and standing(0, False) \
            and _run_extent(of, ow, run_gap, False) * mpu >= c.static_extent_m:
        hold(obs[0].frame - 1, -1, round(c.stop_hold_back_s * fps), 0)
    if new:
        merged = {p.frame: p for p in t.points}
        merged.update(new)
        t.points = [merged[f] for f in sorted(merged)]
    return len(new)


def _in_frame(reg: Registration | None, world: np.ndarray, frame_size: tuple[int, int] | None
              ) -> bool:
    """Whether a world point falls inside a frame (True without a frame size)."""
    if reg is None:
        return False
    if frame_size is None:
        return True
    q = apply_homography(np.linalg.inv(reg.H), np.asarray(world, float)[None])[0]
    return bool(0 <= q[0] < frame_size[0] and 0 <= q[1] < frame_size[1])


def _run_extent(frames: np.ndarray, world: np.ndarray, max_gap: int, last: bool) -> float:
    """Diagonal (world units) of the ground points of the run of observations at the track's
    end (``last``) or start: consecutive observations at most ``max_gap`` frames apart."""
    cut = np.flatnonzero(np.diff(frames) > max_gap)
    sel = world[cut[-1] + 1:] if last and len(cut) else world[:cut[0] + 1] if len(cut) else world
    return float(np.hypot(*np.ptp(sel, axis=0)))


def _fill_gaps(track: Track, max_frames: int) -> None:
    """Turn the ``predicted`` points of gaps of at most ``max_frames`` frames between two in-view
    points into ``bridged`` ones (in place): a gap that short inside one tracklet would have been
    bridged by local association; across a tracklet boundary it is the same miss."""
    pts = track.points
    seen = [i for i, p in enumerate(pts) if p.kind in IN_VIEW]
    for a, b in itertools.pairwise(seen):
        if b - a > 1 and pts[b].frame - pts[a].frame - 1 <= max_frames:
            for p in pts[a + 1:b]:
                if p.kind == "predicted":
                    p.kind = "bridged"
                    p.box = np.full(4, np.nan)


def _clip(boxes: np.ndarray, frame_size: tuple[int, int]) -> np.ndarray:
    W, H = frame_size
    x0 = np.clip(boxes[:, 0], 0, W)
    y0 = np.clip(boxes[:, 1], 0, H)
    x1 = np.clip(boxes[:, 0] + boxes[:, 2], 0, W)
    y1 = np.clip(boxes[:, 1] + boxes[:, 3], 0, H)
    return np.column_stack([x0, y0, x1 - x0, y1 - y0])


def suppress_overlaps(tracks: list[Track], max_overlap: float) -> int:
    """Remove in-view points that lie on another track's object in the same frame (in place).

    Seen from above, two vehicles never overlap; two in-view boxes of one frame that overlap by
    more than ``max_overlap`` of the smaller box (intersection over the smaller area) are one
    object reported twice: typically a tracklet started on a fragment of a long vehicle and kept
    alive by bridging between the frames where the detector split the vehicle again, beside
    the whole vehicle's own. Local association's overlap penalty (Yu & Medioni eq. 10) covers
    observations only; bridged points escape it. The decision is per pair of tracks, not per
    frame (alternating would hand the object back and forth between the two identities): the
    track with fewer observed points in the frames where the two overlap (ties: fewer observed
    points in all, then the later track) loses its points in those frames.

    Returns
    -------
    int
        Points removed.
    """
    rows = [(p.frame, ti, pi) for ti, t in enumerate(tracks) for pi, p in enumerate(t.points)
            if p.kind in IN_VIEW and p.box is not None and np.all(np.isfinite(p.box))]
    if len(rows) < 2:
        return 0
    R = np.array(rows)
    B = np.array([tracks[ti].points[pi].box for _, ti, pi in rows], dtype=np.float64)
    pairs: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for i, j, o in zip(*same_frame_overlaps(R[:, 0], B)):
        (ti, pi), (tj, pj) = R[i, 1:].tolist(), R[j, 1:].tolist()
        if o <= max_overlap or ti == tj:
            continue
        if ti > tj:
            ti, pi, tj, pj = tj, pj, ti, pi
        pairs.setdefault((ti, tj), []).append((pi, pj))
    n_obs = [sum(p.kind == "observed" for p in t.points) for t in tracks]
    drop: dict[int, set[int]] = {}
    for (ti, tj), pts in sorted(pairs.items(), key=lambda kv: -len(kv[1])):
        obs_i = sum(tracks[ti].points[pi].kind == "observed" for pi, _ in pts)
        obs_j = sum(tracks[tj].points[pj].kind == "observed" for _, pj in pts)
        loser, k = (tj, 1) if (obs_i, n_obs[ti]) >= (obs_j, n_obs[tj]) else (ti, 0)
        winner = ti if loser == tj else tj
        gone = drop.get(winner, set())
        drop.setdefault(loser, set()).update(
            pp[k] for pp in pts if pp[1 - k] not in gone)  # (not if the winner's point went)
    for ti, idx in drop.items():
        tracks[ti].points = [p for k, p in enumerate(tracks[ti].points) if k not in idx]
    return sum(len(v) for v in drop.values())


def finish_tracks(tracks: list[Track], config: FinishConfig | None = None, fps: float = 30.0, *,
                  metres_per_unit: float | None = None,
                  registrations: dict[int, Registration] | None = None,
                  frame_size: tuple[int, int] | None = None,
                  object_size_m: float = 4.5, scale_estimated: bool = False,
                  still_H: np.ndarray | None = None) -> list[Track]:
    """:meth:`TrackFinisher.finish` in one call. ``still_H``: without registrations, the
    placement every frame's boxes went to the world through (detections alone on a map); the
    identity otherwise."""
    finisher = TrackFinisher(config, fps, metres_per_unit=metres_per_unit,
                             object_size_m=object_size_m, scale_estimated=scale_estimated)
    finisher.still_H = still_H
    return finisher.finish(tracks, registrations, frame_size)


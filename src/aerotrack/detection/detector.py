"""Moving-object detection on registered frames (Yu & Medioni section 3), streaming.

:class:`MovingObjectDetector` keeps a sliding window of downscaled sample frames with their
registrations, builds the background of each frame from them (:mod:`.background`), thresholds the
illumination-normalised residual, turns it into vehicle blobs (:mod:`.blobs`), refines each box at
full resolution with optional moving-shadow removal (:mod:`.shadows`), and attaches the appearance
data later stages need (:mod:`.appearance`). :func:`detect_moving` is the per-frame algorithm
as a pure function of the frame and its background.

Frame-to-frame relations come from the registrations: ``H_{i->c} = inv(H_c) @ H_i`` maps frame
``i``'s pixels to frame ``c``'s through the world.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict, deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np

from ..config import DetectionConfig, check_range
from ..errors import ConfigError
from ..registration.chain import uncovered_share
from ..types import Detections, Frame, Registration, apply_homography, local_scale, local_scales
from .appearance import colour_histogram, ring_descriptor
from .background import (
    subset_median,
    to_cv_homography,
    warp,
    warp_polygons,
    warp_samples,
)
from .blobs import Blob
from .moving import (
    FrameResult,
    SizeGates,
    detect_moving,
    model_scale_for,
    pixel_gate_scale,
    shadows_beside_detections_removed,
)
from .persistence import PersistenceTracker
from .persistence import validate as check_persistence
from .residual import ghost_score, pad0, residual_image
from .shadows import ShadowOffsets

log = logging.getLogger(__name__)

#: Registration statuses after which earlier frames no longer relate to this one.
RESTART_STATUSES = ("reset", "reanchored")
#: Statuses whose homography was not measured on this frame.
UNMEASURED = ("carried",)


@dataclass
class _Sample:
    index: int
    small: np.ndarray  # (h, w, 3) uint8, model resolution
    H: np.ndarray  # frame pixels -> world
    holes: np.ndarray | None = None  # (K, 4, 2) polygons of its own detections, once final
    known: bool = False


@dataclass
class _Pending:
    frame: Frame
    reg: Registration
    small: np.ndarray


@dataclass
class _Background:
    index: int
    H: np.ndarray
    bg: np.ndarray  # (h, w, 3) uint8 in that frame's model pixels
    testable: np.ndarray  # (h, w) uint8 255 where the background can be trusted
    held_since: np.ndarray  # (h, w) float32 time since which the pixel is held, +inf if not
    hold_bg: np.ndarray  # (h, w, 3) uint8: what a pixel that becomes held keeps (often ``bg``)
    cut: np.ndarray | None = None  # (h, w, 3) centred-window background when ``bg``'s was shifted
    #: The frame of the last scheduled update (every ``update_every_s``); a refresh for new ground
    #: (``refresh_uncovered``) keeps it, so the schedule stays on the run's grid (Dask segments
    #: are cut on that grid, :func:`aerotrack.parallel.phase_period`). None: ``index``.
    sched: int | None = None


def frames_for(seconds: float, fps: float) -> int:
    """A duration in whole frames (at least 1), halves rounded up.

    Python's ``round`` rounds halves to even: the half window of 3 s at 15 frames/s (22.5
    frames) became 22, a 2.93 s window with one background sample fewer than at 10 or 30
    frames/s, and a vehicle waiting for half the window was absorbed at 15 frames/s only (a
    probe, 2026-12-03: Santiago at every 2nd frame, detection recall 0.857 against 0.886 with
    the 3.07 s window of 23 frames).
    """
    return max(1, int(math.floor(seconds * fps + 0.5)))


@contextmanager
def cv_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``n`` OpenCV threads, then restore the setting; None changes nothing.
    (Changing it costs about 3 microseconds.)"""
    previous = cv2.getNumThreads()
    if n is None or n == previous:
        yield
        return
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(previous)


def _outline_ratio(small: np.ndarray, bg: np.ndarray, blob: Blob, mask: np.ndarray) -> float:
    """:func:`ghost_score` of the pixels ``mask`` (in ``blob``'s box) of a model-resolution
    frame ``small`` against its background ``bg``."""
    x, y, bw, bh = blob.box
    m = 3
    x0, y0 = max(0, x - m), max(0, y - m)
    x1, y1 = min(bg.shape[1], x + bw + m), min(bg.shape[0], y + bh + m)
    gm = np.zeros((y1 - y0, x1 - x0), bool)
    gm[y - y0:y - y0 + bh, x - x0:x - x0 + bw] = mask
    return ghost_score(small[y0:y1, x0:x1], bg[y0:y1, x0:x1], gm)


def protected_blobs(blobs: list[Blob], moved: list, stopped: np.ndarray) -> list[Blob]:
    """The parts of this frame's detections kept out of the background (model pixels).

    A vehicle that stands still (``stopped``) or whose past is unknown (``moved`` is None) is
    kept out whole. Of a moving one only the pixels that changed over the stationary lag are:
    those are the vehicle itself. The rest of its blob is road it uncovered, or the imprint
    of a vehicle that left (a ghost, joined to the vehicle's blob); keeping those out too let
    the imprint hold itself in the background, which grew boxes backwards into trails.

    Parameters
    ----------
    blobs : list of Blob
    moved : list of (ndarray (h_k, w_k) bool or None)
        Per blob, pixels (in its box) that differ from the registered frame one lag earlier.
    stopped : ndarray, shape (N,) bool

    Returns
    -------
    list of Blob
        Possibly fewer (a blob none of whose pixels changed is dropped).
    """
    out = []
    k3 = np.ones((3, 3), np.uint8)
    for b, mv, st in zip(blobs, moved, stopped):
        if mv is None or st:
            out.append(b)
            continue
        m = b.mask & (cv2.dilate(mv.astype(np.uint8), k3) > 0)
        if m.any():
            out.append(Blob(b.box, m))
    return out


def drop_ghost_parts(small: np.ndarray, bg: np.ndarray, other: np.ndarray, blobs: list[Blob],
                     threshold: float, ratio: float) -> list[Blob]:
    """Blobs without their parts that match a second background and look like a ghost.

    A blob part (model pixels) where the frame matches ``other`` (residual at most
    ``threshold``) but not ``bg`` is either a vehicle ``other`` absorbed or the imprint in ``bg``
    of a vehicle that is not here now. The outline tells them apart (:func:`ghost_score` of
    the part against ``bg`` below ``ratio``: a ghost). Blobs keep their boxes; ghost pixels are
    cleared from their masks.

    Parameters
    ----------
    small : ndarray, shape (h, w, 3) uint8
    bg, other : ndarray, shape (h, w, 3) uint8
        The background the blobs were found against and a second one, same pixels.
    blobs : list of Blob
    threshold : float
        Residual threshold, grey levels.
    ratio : float
        Outline ratio under which a part is a ghost; 0 keeps every part.
    """
    if ratio <= 0:
        return list(blobs)
    out = []
    for b in blobs:
        x, y, bw, bh = b.box
        same = residual_image(small[y:y + bh, x:x + bw], other[y:y + bh, x:x + bw], 1) <= threshold
        part = b.mask & same
        if part.sum() >= 4 and _outline_ratio(small, bg, b, part) < ratio:
            b = Blob(b.box, b.mask & ~part)
        out.append(b)
    return out


def choose_hold(small: np.ndarray, a: np.ndarray, b: np.ndarray, blobs: list[Blob]) -> np.ndarray:
    """Per pixel, the one of two background candidates a pixel that becomes held should keep.

    Under this frame's detections (model pixels of ``blobs``) the frame shows a vehicle, so the
    candidate that differs more from it is the road under the vehicle; elsewhere the frame shows
    the road, so the candidate closer to it is kept (the other holds some vehicle that passed).

    Parameters
    ----------
    small : ndarray, shape (h, w, 3) uint8
        The frame at model resolution.
    a, b : ndarray, shape (h, w, 3) uint8
        Candidate backgrounds in the same pixels.
    blobs : list of Blob

    Returns
    -------
    ndarray, shape (h, w, 3) uint8
    """
    fg = np.zeros(small.shape[:2], np.uint8)
    for bl in blobs:
        x, y, bw, bh = bl.box
        fg[y:y + bh, x:x + bw] |= bl.mask.astype(np.uint8)
    da, db = residual_image(small, a), residual_image(small, b)
    # under a detection: b differs more; elsewhere: b is closer to the frame
    take_b = cv2.bitwise_or(cv2.bitwise_and(cv2.compare(db, da, cv2.CMP_GT), fg * 255),
                            cv2.bitwise_and(cv2.compare(db, da, cv2.CMP_LT), (1 - fg) * 255))
    out = a.copy()
    cv2.copyTo(b, take_b, out)
    return out


def blob_polygons(blobs: list[Blob], grow: int = 1) -> list[np.ndarray]:
    """Convex hulls of blobs grown by ``grow`` pixels, as (P, 2) float polygons in the pixels
    the blobs were found in (the areas a frame's detections keep out of the background).

    The hull rather than the blob itself: a vehicle whose roof matches the road leaves a ring-
    shaped blob, and its roof must be kept out too or the background slowly absorbs it."""
    polys = []
    k = np.ones((2 * grow + 1,) * 2, np.uint8)
    for b in blobs:
        x, y, _, _ = b.box
        m = cv2.dilate(pad0(b.mask.astype(np.uint8), grow + 1), k)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if contours:
            hull = cv2.convexHull(np.concatenate(contours))
            polys.append(hull.reshape(-1, 2).astype(np.float64) + [x - grow - 1, y - grow - 1])
    return polys


class MovingObjectDetector:
    """Streaming sliding-window moving-object detector (Yu & Medioni section 3).

    Parameters
    ----------
    config : DetectionConfig
    fps : float
        Frame rate, to turn the config's seconds into frames.
    geomap : GeoMap, optional
        When given, world coordinates are map pixels and detections get ``mapxy``/``lonlat``.
    metres_per_unit : float, optional
        Metres per world unit; size gates are then in metres.

    Notes
    -----
    ``step`` returns the detections of the frames that became final: with a centred window
    (the paper's) frame ``c`` is final once frame ``c + w`` has arrived, ``w`` being half the
    window (with ``config.full_window_at_ends``, the first ``w`` frames of a segment wait for
    frame ``2w`` after its first); with ``config.causal`` every frame is final at once. Memory
    is bounded by the window: ``w`` full frames (``2w`` at the start of a segment) and
    ``window_s / sample_every_s`` downscaled samples.
    """

    def __init__(self, config: DetectionConfig, fps: float, geomap=None,
                 metres_per_unit: float | None = None) -> None:
        if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
            raise ConfigError(f"detection: fps must be positive, got {fps!r}")
        check_config(config)
        self.config = config
        self.fps = float(fps)
        self.geomap = geomap
        self.metres_per_unit = metres_per_unit
        #: Model resolution relative to the frame: ``config.model_scale`` until the first frame
        #: gives the frame size (:func:`model_scale_for`).
        self.scale = float(config.model_scale)
        self._scale_shape: tuple[int, int] | None = None
        self.half = frames_for(config.window_s / 2.0, fps)
        self.every = frames_for(config.sample_every_s, fps)
        self.update = frames_for(config.update_every_s, fps)
        self.lag = frames_for(config.stationary_lag_s, fps)
        self._pending: deque[_Pending] = deque()
        self._samples: OrderedDict[int, _Sample] = OrderedDict()
        self._bg: _Background | None = None
        self._last_fg: tuple[int, np.ndarray, np.ndarray] | None = None  # index, H, polygons
        self._last_final = 0
        self._first: int | None = None
        self._start: int | None = None  # first frame of the current window segment
        self._newest: int | None = None  # newest frame stepped
        self._ending = False  # inside flush(): no frame comes after the newest
        self.last_result: FrameResult | None = None
        # (made again with the first frame's scale, if that differs)
        self._persist = PersistenceTracker(config, fps, self.scale) if config.persist else None
        #: The sun's shadow offset measured over recent frames (``shadow_trim_pool_s``).
        self._shadows = (ShadowOffsets(config.shadow_trim_pool_s)
                         if config.shadow_trim_pool_s > 0 else None)
        #: (H, W) uint8, 255 on the frame pixels to work on, 0 under frame-space ignore regions
        #: (``geo.roi.frame_mask``), or None for all: under them no detection is looked for and
        #: no sample enters the background.
        self.frame_mask: np.ndarray | None = None
        self._mask_small: np.ndarray | None = None
        #: When True, ``debug_frames`` collects ``(index, image, residual, boxes, stationary)``
        #: of every finalised frame (the caller drains it).
        self.keep_debug = False
        self.debug_frames: list = []
        #: frame -> its residual threshold (grey levels), for the run's noise hint; the pipeline
        #: empties it as frames become final
        self.thresholds: dict[int, float] = {}
        #: OpenCV threads for the whole-frame work (the background's warps and medians, the
        #: model image); None: whatever the caller set. The pipeline runs the stages on one
        #: OpenCV thread (many small images, where the thread pool costs more than it brings)
        #: and gives this the setting the process had (OpenCV's default, all cores; one in a
        #: Dask worker).
        self.wide_threads: int | None = None

    # -- public API -----------------------------------------------------------------------
    def step(self, frame: Frame, registration: Registration) -> list[Detections]:
        """Add one frame; return the detections of frames that became final (oldest first)."""
        small = self.model_image(frame.image, self._metres_per_px(registration, frame.image.shape))
        out = []
        if registration.status in RESTART_STATUSES and self._pending:
            # The new world frame is unrelated to the old one: finish the frames waiting for their
            # window with what was seen before, then start a new window.
            out = self.flush()
            self._samples.clear()
            self._bg = None
            self._last_fg = None
            self._start = frame.index
            if self._persist is not None:
                self._persist.reset()
            if self._shadows is not None:
                self._shadows.clear()
        if self._first is None:
            self._first = frame.index
        if self._start is None:
            self._start = frame.index
        self._newest = frame.index
        Hm = np.asarray(registration.H, dtype=np.float64)
        # A frame whose homography is only carried forward (not measured) would smear the
        # background if it voted; it is still tested against its neighbours.
        if (frame.index - self._first) % self.every == 0 and registration.status not in UNMEASURED:
            self._samples[frame.index] = _Sample(frame.index, small, Hm)
        self._pending.append(_Pending(frame, registration, small))
        # With a full window at the ends, the first frames wait for the whole window (2w frames
        # after the segment's first) instead of w: their window is shifted forward, not cut.
        ready = (not self.config.full_window_at_ends
                 or frame.index - self._start >= 2 * self.half)
        while self._pending and (self.config.causal
                                 or (ready and self._pending[0].frame.index + self.half
                                     <= frame.index)):
            out.append(self._finalise(self._pending.popleft()))
        self._drop_old()
        return out

    def flush(self) -> list[Detections]:
        """Finalise every frame still waiting for its window (end of video)."""
        out = []
        self._ending = True
        try:
            while self._pending:
                out.append(self._finalise(self._pending.popleft()))
        finally:
            self._ending = False
        self._drop_old()
        return out

    def _metres_per_px(self, registration: Registration, shape: tuple[int, ...]) -> float | None:
        """Metres per frame pixel at the centre of the first frame (None without a metric scale,
        and once the model's scale is set)."""
        if self._scale_shape is not None or not self.metres_per_unit:
            return None
        centre = np.array([shape[1] / 2, shape[0] / 2])
        return self.metres_per_unit * local_scale(np.asarray(registration.H, np.float64), centre)

    def model_image(self, image: np.ndarray, metres_per_px: float | None = None) -> np.ndarray:
        """A frame at model resolution (:func:`model_scale_for` its size and, with a metric scale,
        the first frame's ground resolution ``metres_per_px``), as the detector keeps it; after
        the first frame a function of the frame alone, so a resumed run can make it again
        (:mod:`aerotrack.io.state`)."""
        H, W = image.shape[:2]
        if self._scale_shape is None:  # a video's frames all have the first one's size
            self._scale_shape = (H, W)
            scale = model_scale_for((H, W), self.config, bool(self.metres_per_unit),
                                    metres_per_px)
            if self._persist is not None and scale != self.scale:
                self._persist = PersistenceTracker(self.config, self.fps, scale)
            if metres_per_px and scale > self.config.model_scale:
                log.info("detection: %.2f m per pixel (small vehicles): background model at %.2f "
                         "of the frame's resolution instead of %.2f (detection.model_pixel_max_m)",
                         metres_per_px, scale, self.config.model_scale)
            self.scale = scale
        size = (max(1, int(round(W * self.scale))), max(1, int(round(H * self.scale))))
        if self.scale == 1:
            return image
        with cv_threads(self.wide_threads):
            return cv2.resize(image, size, interpolation=cv2.INTER_AREA)

    # -- internals ------------------------------------------------------------------------
    def _local_scale(self, H: np.ndarray, shape: tuple[int, int], mpp: float):
        """How many times longer a metre is at a frame pixel than at the centre (metres per
        pixel ``mpp``), as a callable for :class:`SizeGates`, and its range over the frame; (None,
        (1, 1)) where the scale hardly changes across the frame (nadir footage: its gates stay
        exactly as they were).

        An oblique view on a map (a probe, 2026-12-03: Santiago warped so that near vehicles are
        twice as large as far ones, with the warp's map placement) had one scale for the whole
        frame, the centre's: far vehicles failed the area gate (their recall at IoU 0.3 0.909
        without a map, 0.679 with one) and the map made tracking worse, not better."""
        h, w = shape
        pts = np.array([[x, y] for y in (0.0, h / 2, h) for x in (0.0, w / 2, w)], float)
        f = mpp / np.maximum(self.metres_per_unit * local_scales(H, pts), 1e-12)
        if not np.all(np.isfinite(f)) or float(f.max() / f.min()) < LOCAL_GATES_MIN_RATIO:
            return None, (1.0, 1.0)
        lo, hi = LOCAL_GATES_CLAMP
        mpu = self.metres_per_unit

        def local(x: float, y: float) -> float:
            s = float(local_scales(H, np.array([[x, y]], float))[0]) * mpu
            return min(max(mpp / s, lo), hi) if s > 0 and math.isfinite(s) else 1.0

        return local, (max(float(f.min()), lo), min(float(f.max()), hi))

    def _gates(self, H: np.ndarray, shape: tuple[int, int]) -> SizeGates:
        c = self.config
        if self.metres_per_unit:
            mpp = self.metres_per_unit * local_scale(H, np.array([shape[1] / 2, shape[0] / 2]))
            if mpp > 0 and math.isfinite(mpp):
                # the closing bridges gaps of model pixels (noise), not of metres: where close_m
                # spans more model pixels than the closing has without a scale, the vehicles are
                # resolved and get close_resolved_px (DetectionConfig.close_m)
                close = c.close_m / mpp
                if close * self.scale > c.close_px * c.model_scale:
                    close = (c.close_resolved_px if c.close_resolved_px > 0
                             else c.close_px * c.model_scale) / self.scale
                # likewise boxes are joined across at most the gap they are without a scale
                join = min(c.join_gap_m / mpp, c.join_gap_px * c.model_scale / self.scale)
                local, span = self._local_scale(H, shape, mpp)
                return SizeGates(min_area_px=c.min_area_m2 / mpp ** 2,
                                 max_length_px=c.max_length_m / mpp,
                                 close_px=close, join_gap_px=join,
                                 min_width_px=c.min_width_m / mpp, local=local, local_range=span)
        k = pixel_gate_scale(shape, c.pixel_gates_reference_px)
        return SizeGates(c.min_area_px * k * k, c.max_length_px * k, c.close_px * k,
                         c.join_gap_px * k, c.min_width_px * k)

    def _window(self, c: int) -> tuple[int, int]:
        """Frames ``[lo, hi]`` whose samples build frame ``c``'s background.

        Centred on ``c`` (the paper's), or ending at ``c`` in causal mode. With
        ``full_window_at_ends`` a centred window that would reach before the segment's first
        frame or after its last is shifted inside rather than cut: a vehicle that waits during
        the first (last) ``w`` frames then covers a share of a whole window, not of half of one,
        and is not absorbed.
        """
        if self.config.causal:
            return c - 2 * self.half, c
        lo, hi = c - self.half, c + self.half
        if self.config.full_window_at_ends and self._start is not None:
            if lo < self._start:
                lo, hi = self._start, self._start + 2 * self.half
            elif self._ending and self._newest is not None and hi > self._newest:
                lo, hi = max(self._start, self._newest - 2 * self.half), self._newest
        return lo, hi

    def _background(self, p: _Pending) -> tuple[np.ndarray, np.ndarray]:
        """Background and testable mask (255 = trusted) of a frame at model resolution."""
        c, t = p.frame.index, p.frame.time
        Hc = np.asarray(p.reg.H, dtype=np.float64)
        Hc_inv = np.linalg.inv(Hc)
        h, w = p.small.shape[:2]
        prev = self._bg
        sched = c  # a scheduled update, unless this is a refresh between two
        if prev is not None:
            last = getattr(prev, "sched", None)
            last = prev.index if last is None else last
            if 0 <= c - last < self.update:
                # new ground (a fast pan) has no value in the warped background: recompute
                shape = p.frame.image.shape[:2]
                if not (0 < self.config.refresh_uncovered
                        <= uncovered_share(np.linalg.inv(prev.H) @ Hc, shape)):
                    M = to_cv_homography(Hc_inv @ prev.H, self.scale)
                    return (warp(prev.bg, M, (w, h), replicate=True),
                            warp(prev.testable, M, (w, h), nearest=True))
                sched = last

        lo, hi = self._window(c)
        windows = [(lo, hi)]
        if lo > c - self.half and not self.config.causal:
            # A window shifted forward at the start of a segment holds more of the future than
            # the centred one: a vehicle that stops within it leaks into it. What is held later
            # is chosen per pixel from the two once this frame's detections are known
            # (choose_hold). (At the end of a segment the choice changed nothing measurable.)
            windows.append((c - self.half, c + self.half))
        meds = self._medians(windows, Hc_inv, (w, h), p.small)
        bg, count, n = meds[0]
        cut = meds[1][0] if len(meds) > 1 else None
        weak = count < min(self.config.min_valid_samples, max(1, n))
        testable = np.where(weak, 0, 255).astype(np.uint8)
        held_since = np.full((h, w), np.inf, np.float32)
        if prev is not None and self.config.hold_stopped:
            M = to_cv_homography(Hc_inv @ prev.H, self.scale)
            pbg = warp(prev.hold_bg, M, (w, h), replicate=True)
            ptest = warp(prev.testable, M, (w, h), nearest=True) > 0
            psince = warp(prev.held_since, M, (w, h), nearest=True, border=np.inf)
            hold = weak & ptest
            if hold.any():
                since = np.where(np.isfinite(psince), psince, np.float32(t))
                release = hold & (t - since > self.config.max_hold_s)
                hold &= ~release
                bg[hold] = pbg[hold]
                if cut is not None:
                    cut[hold] = pbg[hold]
                testable[hold] = 255
                held_since[hold] = since[hold]
        self._bg = _Background(c, Hc, bg, testable, held_since, bg, cut, sched)
        return bg, testable

    def _medians(self, windows: list[tuple[int, int]], Hc_inv: np.ndarray,
                 size: tuple[int, int], ref_small: np.ndarray | None = None
                 ) -> list[tuple[np.ndarray, np.ndarray, int]]:
        """Window medians of the samples of frames ``[lo, hi]`` for each window, in the model
        pixels of the frame whose inverse homography is ``Hc_inv``, sharing the sample warps.

        Returns
        -------
        list of (background, valid count, number of samples)
        """
        lo_all, hi_all = min(w[0] for w in windows), max(w[1] for w in windows)
        idx = [i for i in self._samples if lo_all <= i <= hi_all]
        chosen = [self._samples[i] for i in idx]
        to_ref = [to_cv_homography(Hc_inv @ s.H, self.scale) for s in chosen]
        ref_holes = None
        if self.config.hold_stopped and self._last_fg is not None:
            _, fH, fpolys = self._last_fg
            ref_holes = warp_polygons(fpolys, to_cv_homography(Hc_inv @ fH, self.scale))
        tol = self.config.exposure_tolerance
        warped = warp_samples([s.small for s in chosen], to_ref, [s.holes for s in chosen],
                              size, ref_holes, [not s.known for s in chosen],
                              exposure_ref=ref_small if tol > 0 else None,
                              exposure_tolerance=tol, mask=self._small_mask(chosen[0].small)
                              if chosen else None)
        out = []
        for j, (lo, hi) in enumerate(windows):
            which = [k for k, i in enumerate(idx) if lo <= i <= hi]
            bg, count = subset_median(warped, which, size, copy=j < len(windows) - 1)
            out.append((bg, count, len(which)))
        return out

    def _small_mask(self, small: np.ndarray) -> np.ndarray | None:
        """:attr:`frame_mask` at the model's resolution (the size of ``small``), or None."""
        if self.frame_mask is None:
            return None
        h, w = small.shape[:2]
        if self._mask_small is None or self._mask_small.shape != (h, w):
            self._mask_small = cv2.resize(self.frame_mask, (w, h),
                                          interpolation=cv2.INTER_NEAREST)
        return self._mask_small

    def _finalise(self, p: _Pending) -> Detections:
        c = p.frame.index
        Hc = np.asarray(p.reg.H, dtype=np.float64)
        with cv_threads(self.wide_threads):
            bg, testable = self._background(p)
        mask = self._small_mask(p.small)
        if mask is not None:
            # no sample holds those pixels: the frame itself stands in for their background, so
            # that they leave no residual and do not skew the gain normalisation around them
            testable = np.minimum(testable, mask)
            bg = np.where((mask == 0)[..., None], p.small, bg)
        gates = self._gates(Hc, p.frame.image.shape[:2])
        prior = None
        if self._shadows is not None:
            pool = self._shadows
            prior = lambda centres: pool.growth(Hc, centres)
        r = detect_moving(p.frame.image, p.small, bg, testable, self.config, self.scale, gates,
                          shadow_prior=prior)
        if self._shadows is not None:
            self._shadows.add(p.frame.time, Hc, r.shadow_samples)
        if self._persist is not None:
            r = self._add_persistent(p, r, bg, testable)
        self.last_result = r
        self.thresholds[c] = float(r.threshold)
        blobs = r.model_blobs
        if r.persistent is not None:
            # Persistent detections are not kept out of the background: a target faint enough to
            # need persistence changes few of its pixels above the single-frame threshold, so the
            # stationary test below calls it stopped (UAV123 truck4: 456 of 826 in frames 1-200)
            # and would hold its whole box out for up to max_hold_s, thinning the samples under
            # every vehicle that later passes there (truck4: its truck fell into two detections
            # for 20 frames; best ID 0.41 -> 0.67).
            # They come after the regular ones, so ``blobs`` stays aligned with ``moved``.
            blobs = [b for b, weak in zip(blobs, r.persistent) if not weak]
        if self._bg is not None and self._bg.cut is not None and len(blobs):
            # A window shifted forward holds vehicles that will stop here later: where the frame
            # shows the road they leave a ghost that joins the blob of a vehicle passing by.
            # Such parts are not kept out of the background (nor held as a vehicle).
            cut = self._bg.cut
            if self._bg.index != c:
                M = to_cv_homography(np.linalg.inv(Hc) @ self._bg.H, self.scale)
                cut = warp(cut, M, (p.small.shape[1], p.small.shape[0]), replicate=True)
            blobs = drop_ghost_parts(p.small, bg, cut, blobs, r.threshold,
                                     self.config.ghost_part_ratio)
            if self._bg.index == c:
                self._bg.hold_bg = choose_hold(p.small, self._bg.bg, self._bg.cut, blobs)
        # Kept out of the background (hold_stopped): in this frame's own sample, each
        # detection's pixels that changed over the lag; in the not-yet-final samples, with a
        # wider margin, those of them where the vehicle will still be (see _ahead).
        changed, moved = self._changed(p, r)
        stationary = changed < 0.2
        stopped = changed < self.config.protect_changed
        ahead = self._ahead(p, r, bg, moved)
        # Margins of 2 and 4 frame pixels (1 and 2 model pixels at model_scale 0.5): a margin of
        # one frame pixel lets a waiting vehicle's interpolated edge into the samples, and the
        # background eats it from the edges in (a stopped car kept half its box at scale 1.0).
        grow = max(1, round(2 * self.scale))
        if c in self._samples and self.config.hold_stopped:
            self._samples[c].holes = blob_polygons(protected_blobs(blobs, moved, stopped),
                                                   grow=grow)
        for i, s in self._samples.items():
            if i <= c:
                s.known = True
        self._last_fg = (c, Hc, blob_polygons(protected_blobs(blobs, ahead, stopped),
                                              grow=2 * grow))
        self._last_final = c
        if self.keep_debug:
            self.debug_frames.append((c, p.frame.image, r.residual, r.boxes, stationary))
        return self._to_detections(p, r, stationary)

    def _add_persistent(self, p: _Pending, r: FrameResult, bg: np.ndarray,
                        testable: np.ndarray) -> FrameResult:
        """``r`` with the small, faint movers found by multi-frame persistence appended
        (:class:`.persistence.PersistenceTracker`); their boxes come from the model-resolution
        evidence, their masks fill the boxes.

        With shadow suppression on, cast-shadow pixels (:func:`.shadows.shadow_mask`) within a
        box's size of a regular detection carry no evidence: the regular detector takes a
        vehicle's shadow off its box, and persistence would otherwise find the shadow beside it
        as a mover of its own (truck4 with persistence: the truck's boxes alternated between 33
        and 55 px wide and its track was cut in three). Elsewhere a moving shadow stays evidence:
        a vehicle too small to be detected alone is found with its shadow (truck4's first half,
        where removing all shadow evidence lost the truck until frame 160)."""
        H = np.asarray(p.reg.H, dtype=np.float64)
        residual = r.residual
        if self.config.shadow_suppression and len(r.boxes):
            residual = shadows_beside_detections_removed(residual, p.small, bg, r.boxes,
                                                         self.scale, self.config)
        image = p.frame.image
        mpp = None
        if self.metres_per_unit:
            mpp = self.metres_per_unit * local_scale(H, np.array([image.shape[1] / 2,
                                                                  image.shape[0] / 2]))
            mpp = mpp if mpp > 0 and math.isfinite(mpp) else None
        found = self._persist.step(residual, r.threshold, testable, H, p.frame.time, r.boxes, mpp)
        if not found:
            return r
        c = self.config
        Hf, Wf = image.shape[:2]
        boxes, confs = [r.boxes], list(r.conf)
        masks, crops, blobs = list(r.masks), list(r.crops), list(r.model_blobs)
        contrast = list(r.contrast) if r.contrast is not None else [1.0] * len(r.boxes)
        for d in found:
            x, y, w, h = d.box
            x0, y0 = int(math.floor(x / self.scale)), int(math.floor(y / self.scale))
            x1 = min(Wf, int(math.ceil((x + w) / self.scale)))
            y1 = min(Hf, int(math.ceil((y + h) / self.scale)))
            if x1 <= x0 or y1 <= y0:
                continue
            boxes.append(np.array([[x0, y0, x1 - x0, y1 - y0]], np.float64))
            confs.append(float(min(1.0, c.persist_conf * d.score / c.persist_threshold)))
            masks.append(np.ones((y1 - y0, x1 - x0), bool))  # the box is a tiny target's blob
            crops.append((x0, y0, x1, y1))
            blobs.append(Blob((x, y, w, h), np.ones((h, w), bool)))
            contrast.append(d.score)
        return FrameResult(boxes=np.vstack(boxes).reshape(-1, 4),
                           conf=np.asarray(confs, np.float64), masks=masks, crops=crops,
                           model_blobs=blobs, contrast=np.asarray(contrast, np.float64),
                           threshold=r.threshold, residual=r.residual,
                           persistent=np.arange(len(confs)) >= len(r.boxes))

    def _ahead(self, p: _Pending, r: FrameResult, bg: np.ndarray, moved: list) -> list:
        """Per detection, the pixels (in its model box) to keep out of the not-yet-final samples.

        Pixels that changed over the lag (``moved``) but match the newest sample (the frame
        ``stationary_lag_s`` or more ahead) are either a vehicle that is stopping there or the
        imprint (ghost) of one that left, which its blob joins while it is near: the road then
        looks the same now and ahead. The two differ in their outline: a vehicle's is an edge
        of the frame, a ghost's an edge of the background only (:func:`ghost_score` below
        ``ghost_part_ratio``). A ghost part is not kept out, so the samples ahead vote it back
        to road; keeping it out made ghosts hold themselves and boxes trail backwards.
        A detection of which nearly all changed pixels stay (``stopping_share``) is a vehicle
        coming to a stop unless its outline is weaker in the frame than in the background
        (``stopping_outline_ratio``) or it does not look so halfway there
        (``stopping_halfway_share``: the next car of a queue takes its place a lag later, while
        the gap between them passes at half the lag): the centred window already holds the
        stopping vehicle, so the outline test alone took it for a ghost and let the background
        absorb it.
        Without a sample ahead (causal mode, end of video) ``moved`` is returned as is.
        """
        _, fut = self._changed(p, r, future=True)
        out = []
        ratio = self.config.ghost_part_ratio
        share = self.config.stopping_share
        halfway = None
        for k, (b, mv, fm) in enumerate(zip(r.model_blobs, moved, fut)):
            if mv is None or fm is None or ratio <= 0:
                out.append(mv)
                continue
            part = b.mask & mv & ~fm
            if part.sum() < 4:
                out.append(mv & fm)
                continue
            score = _outline_ratio(p.small, bg, b, part)
            vehicle = score >= ratio
            if not vehicle and share > 0 and score >= self.config.stopping_outline_ratio \
                    and part.sum() >= share * (b.mask & mv).sum():
                # nothing of it moves on: a vehicle coming to a stop (see stopping_share), if
                # it looks so halfway there too (not the next car of a queue taking its place)
                if halfway is None:
                    halfway = self._changed(p, r, halfway=True)[1]
                hm = halfway[k]
                vehicle = hm is not None and (part & ~hm).sum() >= \
                    self.config.stopping_halfway_share * (b.mask & mv).sum()
            out.append(mv if vehicle else mv & fm)
        return out

    def _changed(self, p: _Pending, r: FrameResult, future: bool = False,
                 halfway: bool = False) -> tuple[np.ndarray, list]:
        """Which of each detection's pixels changed over ``stationary_lag_s`` (with ``future``:
        against the newest sample at least that far ahead; with ``halfway``: against the oldest
        sample at least half of it ahead).

        Returns
        -------
        fraction : ndarray, shape (N,)
            Fraction of the blob's pixels that changed: 0 for a vehicle standing still, near 1
            for one that moved by more than its length; 0 when the earlier frame did not see
            the whole blob.
        moved : list of (ndarray (h_k, w_k) bool or None)
            Per blob, in its model box: pixels that differ from the earlier frame (None where
            unknown).
        """
        n = len(r.boxes)
        out = np.zeros(n, np.float64)
        moved: list = [None] * n
        if n == 0:
            return out, moved
        c = p.frame.index
        if halfway:
            past = [i for i in self._samples if i >= c + self.lag // 2][:1]
        elif future:
            past = [i for i in self._samples if i >= c + self.lag][-1:]
        else:
            past = [i for i in self._samples if i <= c - self.lag]
        if not past:
            return out, moved
        s = self._samples[past[-1]]
        M = to_cv_homography(np.linalg.inv(p.reg.H) @ s.H, self.scale)
        sh, sw = s.small.shape[:2]
        M_inv = np.linalg.inv(M)
        for k, b in enumerate(r.model_blobs):
            x, y, bw, bh = b.box
            m = b.mask
            back = apply_homography(M_inv, np.array([[x, y], [x + bw, y + bh],
                                                     [x, y + bh], [x + bw, y]], float))
            if not (np.all(back >= 0) and np.all(back[:, 0] < sw) and np.all(back[:, 1] < sh)):
                continue  # the earlier frame did not see the whole blob
            # Warp only the blob's box: a translated homography into a (bh, bw) image.
            Mk = np.array([[1.0, 0, -x], [0, 1.0, -y], [0, 0, 1]]) @ M
            seen = cv2.warpPerspective(s.small, Mk, (bw, bh), flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
            d = residual_image(p.small[y:y + bh, x:x + bw], seen, 1) > r.threshold
            out[k] = float(np.mean(d[m]))
            moved[k] = d
        return out, moved

    def _to_detections(self, p: _Pending, r: FrameResult, stationary: np.ndarray) -> Detections:
        n = len(r.boxes)
        if n == 0:
            d = Detections.empty(p.frame.index)
            return Detections(frame=d.frame, boxes=d.boxes, conf=d.conf, world=d.world,
                              hist=np.zeros((0, 128)), size_world=np.zeros((0, 2)),
                              mapxy=None if self.geomap is None else np.zeros((0, 2)),
                              lonlat=None if self.geomap is None else np.zeros((0, 2)),
                              extra={"desc": np.zeros((0, 6, 8, 8)),
                                     "stationary": np.zeros(0, bool),
                                     "persistent": np.zeros(0, bool)})
        H = np.asarray(p.reg.H, dtype=np.float64)
        centres = r.boxes[:, :2] + r.boxes[:, 2:] / 2.0
        world = apply_homography(H, centres)
        size_world = r.boxes[:, 2:] * local_scales(H, centres)[:, None]
        hists = np.empty((n, 128))
        descs = np.empty((n, 6, 8, 8))
        for k, ((x0, y0, x1, y1), m) in enumerate(zip(r.crops, r.masks)):
            patch = p.frame.image[y0:y1, x0:x1]
            hists[k] = colour_histogram(patch, m)
            descs[k] = ring_descriptor(patch, m)
        mapxy = lonlat = None
        if self.geomap is not None:
            mapxy = self.geomap.pixel_to_crs(world)
            lonlat = self.geomap.pixel_to_lonlat(world)
        return Detections(frame=p.frame.index, boxes=r.boxes, conf=r.conf, world=world,
                          mapxy=mapxy, lonlat=lonlat, hist=hists, size_world=size_world,
                          extra={"desc": descs, "stationary": stationary,
                                 "persistent": (np.zeros(n, bool) if r.persistent is None
                                                else r.persistent)})

    def _drop_old(self) -> None:
        if self._pending:
            c = self._pending[0].frame.index
        else:
            c = self._last_final + 1
        keep_from = min(self._window(c)[0], c - self.lag - self.every)
        if self.config.full_window_at_ends and self._newest is not None:
            keep_from = min(keep_from, self._newest - 2 * self.half)  # for flush's shifted window
        for i in [i for i in self._samples if i < keep_from]:
            del self._samples[i]


#: Metric size gates follow the scale across the frame (:meth:`_local_scale`) only where it
#: changes by more than this between the frame's corners and centre (oblique views, not nadir
#: footage), within LOCAL_GATES_CLAMP of the centre's.
LOCAL_GATES_MIN_RATIO = 1.25
LOCAL_GATES_CLAMP = (0.25, 4.0)


def check_config(c: DetectionConfig) -> None:
    """Raise :class:`ConfigError` naming the first out-of-range detection parameter and its
    valid range (it said only "out of range (0.0)", and a bad ``shadow_beta`` was reported as
    ``shadow_alpha`` with the latter's value)."""
    # name, low, high, low excluded, high excluded (None: no bound)
    ranges = [
        ("window_s", 0, None, True, False), ("sample_every_s", 0, c.window_s, True, False),
        ("update_every_s", 0, None, True, False), ("model_scale", 0, 1, True, False),
        ("refresh_uncovered", 0, 1, False, False),
        ("min_valid_samples", 1, None, False, False), ("threshold_sigma", 0, None, False, False),
        ("min_threshold", 0, 255, False, True), ("seed_ratio", 1, None, False, False),
        ("seed_sigma", 0, None, False, False), ("gain_block_px", 0, None, False, False),
        ("close_m", 0, 10, False, False), ("exposure_tolerance", 0, None, False, False),
        ("close_px", 0, 1000, False, False), ("close_resolved_px", 0, 100, False, False),
        ("min_area_m2", 0, None, False, False), ("min_area_px", 0, None, False, False),
        ("max_length_m", 0, None, True, False), ("max_length_px", 0, None, True, False),
        ("min_width_m", 0, None, False, False), ("min_width_px", 0, None, False, False),
        ("pixel_gates_reference_px", 0, None, False, False),
        ("shadow_beta", 0, 1, False, False), ("shadow_alpha", 0, c.shadow_beta, False, False),
        ("shadow_trim_share", 0, 1, True, False), ("shadow_trim_pool_s", 0, None, False, False),
        ("structure_ncc", 0, 1, False, False), ("shadow_chroma_px", 0, 32, False, False),
        ("max_hold_s", 0, None, False, False), ("stationary_lag_s", 0, None, True, False),
        ("min_conf", 0, 1, False, False), ("protect_changed", 0, 1, False, False),
        ("ghost_part_ratio", 0, None, False, False), ("stopping_share", 0, 1, False, False),
        ("stopping_outline_ratio", 0, None, False, False),
        ("stopping_halfway_share", 0, 1, False, False), ("drop_small_ratio", 0, None, False, False),
        ("drop_small_near", 0, None, False, False), ("regrow_ratio", 0, 1, False, True),
        ("regrow_ghost_ratio", 0, None, False, False), ("join_cab_ratio", 0, None, False, False),
        ("split_full_ratio", 0, None, False, False), ("split_colour_dist", 0, None, False, False),
        ("split_full_sides", 0, 1, False, False),
        ("box_edge_level", 0, 1, False, True),
        # (upper bounds on the kernels' sizes: a 5000 px closing ran for hours, a 10^6 px blur
        # failed deep in OpenCV; no vehicle needs more)
        ("residual_sigma_px", 0, 32, False, False),
    ]
    for name, lo, hi, lo_open, hi_open in ranges:
        bound = {"sample_every_s": "window_s", "shadow_alpha": "shadow_beta"}.get(name)
        check_range(f"detection.{name}", getattr(c, name), lo, hi, lo_open, hi_open,
                    hi_name=f"detection.{bound}" if bound else None)
    if c.overlay_mask not in ("edges", "all", "off"):
        raise ConfigError(f"config detection.overlay_mask: expected edges, all or off, got "
                          f"{c.overlay_mask!r}")
    for name, ok, want in (("overlay_min_s", c.overlay_min_s > 0, "> 0"),
                           ("overlay_share", 0 < c.overlay_share <= 1, "in (0, 1]")):
        if not ok:
            raise ConfigError(f"config detection.{name}: must be {want}, got {getattr(c, name)!r}")
    check_persistence(c)  # off by default, but a file with bad values fails when turned on

"""Multi-frame persistence for small, faint movers (a track-before-detect step).

A vehicle a few pixels long at the model resolution, or one whose colour is close to the road's,
leaves only a handful of scattered residual pixels above the single-frame threshold, so no blob
passes the size gates; lowering the gates floods the frame with noise blobs. Noise and a target
differ in *persistence*: the target's weak residual comes back frame after frame at places
reachable from each other at a vehicle's speed, the noise's does not.

:func:`accumulate` keeps a motion-compensated, leaky sum of per-frame evidence (a max-product
track-before-detect recursion): the previous sum is warped into the current frame through the
registrations, grey-dilated by the distance a target can travel in one frame (``v_max dt``), decayed
and added to the current evidence::

    A_t(x) = lambda * max_{|y - x| <= v_max dt} A_{t-1}(H_{t-1 -> t}^{-1} y) + e_t(x)

A target whose evidence is ``e`` in every frame reaches ``e / (1 - lambda)``; flicker that is
strong in one frame only decays away. :func:`frame_evidence` turns the residual into the evidence
``e_t``: the residual over the frame's threshold, capped (so one strong noise pixel cannot make a
track by itself), box-averaged over about a small target's size (a target is a coherent patch,
compression noise is not) and divided by its local RMS where that is above the frame's (textured
ground, foliage and parallax leave more residual everywhere; without this the sum ranks them
above a faint target). :func:`persistent_peaks` thresholds the sum, in units of the steady state,
where the current frame also shows evidence; :func:`peak_box` boxes each peak from the current
frame's weak residual. :class:`PersistenceTracker` runs the recursion over the frames a detector
finalises and requires, as a last guard against persistent clutter, that a peak had support (a
peak or a regular detection) near its world position in a share of the recent frames.

All maps are at the detector's model resolution, in the current frame's model pixels.

Measured by ``benchmarks/persistence.py`` (both columns in the same run, other settings default,
at 63c86d3; ``benchmarks/results/persistence.json``):

==============================================  =============  ==============
                                                persist off    persist on
==============================================  =============  ==============
truck4: best single ID's coverage, seeds 0-2    0.589-0.591    0.777 (x3)
Santiago P / R at IoU 0.5 (detections)          0.754 / 0.860  0.732 / 0.863
Santiago HOTA / IDF1 (mean of seeds 0-2)        0.634 / 0.851  0.629 / 0.833
Santiago GT 24 (stands at the light from ~64):
frames covered by a track at IoU 0.5 (mean)     44             55
generated scenes P / R (3 seeds, 150 frames)    0.877 / 0.808  0.875 / 0.810
detection CPU time per frame, 720p and 1080p    1              1.21 (1.17-1.27)
==============================================  =============  ==============

Off by default, because of what the table shows: persistence finds what it is built for, small
real movers, and on Santiago most of those are not annotated (of its 91 detections there, 62
overlap no vehicle of the ground truth or of ``labels.csv`` -- those inspected were slow,
person-sized movers -- 10 are moving
vehicles the ground truth leaves out, 17 are the half-absorbed GT 24 standing at the light,
boxed at IoU 0.34-0.41, and 2 match), which costs 0.022 precision and 0.018 IDF1. Its gains are
on vehicles a single frame cannot see: truck4's tiny truck (from frame 74; before that its
box is under half the typical detection's area, ``persist_min_area_ratio``, the typical one
being a nearer, larger car) and GT 24 while it waits (covered in 55 instead of 44 frames).
GT 10, standing in frames 1-23, is not found by persistence either (not investigated why).

Since 2026-11-26 a track made of persistence boxes only (no regular detection ever saw it) is
dropped when tracks are finished (``association.finish``): persistence extends vehicles, it does
not start them. Santiago with persistence, HOTA/IDF1 mean of seeds 0-2: 0.638/0.853 ->
0.643/0.861 (default, persistence off: 0.650/0.871); truck4 unchanged. Measured then too: the
colour check of local association (``association.split_appearance``) cuts truck4's truck where
its boxes trail road behind it and where it passes a palm tree, and linking does not rejoin
every cut (the box centre jumps by half the trail): its best ID with persistence is
0.461/0.755/0.458 over seeds 0-2, 0.767/0.755/0.753 with the check off. The check now skips
runs across which the box changes size by more than ``association.split_max_size_ratio`` (1.5),
which gives 0.767/0.755/0.753 with it on. Still off by default (same day): the identity
benchmark (5 generated scenes, own detector, MCMC seeds 0-2) goes IDF1 0.826/0.832/0.813 ->
0.818/0.815/0.811, HOTA 0.625 -> 0.621 (mean), occlusions re-acquired 18.3 -> 17.3 of 31, exits
4 -> 4 of 7; with Santiago's -0.007 HOTA / -0.010 IDF1 that outweighs truck4's +0.17.

Since the shadow test skips the hue of nearly grey pixels (``detection/shadows.py``) the regular
detector takes truck4's truck's cast shadow off its box, and persistence found the shadow beside it
as a mover of its own (best ID 0.33 over seeds 0-2); shadow pixels near a regular detection now
carry no evidence (``MovingObjectDetector._add_persistent``): 0.653 (x3). Removing shadow evidence everywhere
gave 0.599/0.599/0.618 (the tiny truck of the first half is found with its shadow). With the
truck's boxes now tight, its track in the first half takes a box of 6x5 px (the truck is 13x10)
and is cut at frame 113 (not investigated further). ``benchmarks/persistence.py`` then (off / on):
Santiago P/R 0.772/0.884 / 0.753/0.892, HOTA/IDF1 (seeds 0-2) 0.665/0.885 / 0.642/0.847, truck4
0.553/0.594/0.594 / 0.653 (x3), generated P/R 0.903/0.850 / 0.900/0.851, detection CPU time
1.46x (720p) and 1.39x (1080p).

Re-measured at 143d3fd (after tracks' footprints were judged at 2.0 m under an estimated scale,
``finish.min_size_estimated_m``), off / on: truck4 0.663/0.658/0.658 / 0.948/0.933/0.952 (issue
6's goal of 0.80 met with persistence on), Santiago P/R 0.772/0.884 / 0.752/0.885, HOTA/IDF1
0.666/0.887 / 0.642/0.848, generated P/R 0.893/0.843 / 0.890/0.844, detection CPU time 1.31x
(720p) and 1.45x (1080p); the 18 held-out generated scenes (``benchmarks/scenarios.py``)
HOTA/IDF1 0.700/0.857 / 0.691/0.848 (both in one environment). Part of Santiago's loss is
tracks on movers its ground truth omits (a pedestrian on the pavement, 57 frames, cars creeping
in the queue): scored without the tracks that overlap no annotated vehicle, seed 0 gives
0.710/0.952 off and 0.696/0.930 on. The rest is mostly one track that persistence kept for the whole clip behind a
queued car: 33 of its 97 boxes are on that car (GT 12), the others on the empty road behind it.
Still off by default.

Tried and not kept (truck4's best ID over seeds 0-2 is the most sensitive check: it moved by
0.1-0.3 with small changes of the detections):

* ``persist_min_area_ratio`` 0.7: Santiago P 0.742, truck4 0.606/0.615/0.606.
* ``persist_noise_ratio`` 1.7: Santiago P 0.738, truck4 0.703/0.701/0.606.
* Boxes refined at full resolution (residual above half the threshold, shadows removed as
  for a blob): truck4 detected in 0.710 of frames instead of 0.696, but best ID
  0.658/0.409/0.658; GT 24's boxes shrank (found in 4 frames instead of 18).
* On truck4 (10 fps, ``update_every_s`` 0.2 = 2 frames) the threshold alternates: mean 18-19
  grey levels on frames whose background is a new median, 26-28 on frames that warp the
  previous one (presumably the second bilinear interpolation blurs it). Nearest-neighbour
  warping of that background removes the alternation (18.0 / 18.5) and a median every frame
  (``update_every_s`` 0.1) does too, but truck4's best ID fell (0.658/0.658/0.489 and
  0.342/0.321/0.713, measured at 91ecf59; as is, persistence gives 0.777 x3 at 6bac780 and
  63c86d3).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from ..config import DetectionConfig, check_range
from ..types import apply_homography
from .background import to_cv_homography, warp


def frame_evidence(residual: np.ndarray, threshold: float, valid: np.ndarray | None = None, *,
                   cap: float = 2.0, blur_px: int = 3, noise_block_px: int = 31) -> np.ndarray:
    """Per-pixel evidence of a moving target in one frame, (h, w) float32 (model pixels).

    Parameters
    ----------
    residual : ndarray, shape (h, w) uint8
        The frame's residual against its background (grey levels).
    threshold : float
        The frame's single-frame residual threshold, grey levels.
    valid : ndarray, shape (h, w), optional
        Non-zero where the residual can be trusted; evidence is 0 elsewhere.
    cap : float
        Evidence is ``min(residual / threshold, cap)`` before averaging. Higher lets single strong
        pixels count more (a sharp small target, but also a compression artefact).
    blur_px : int
        Side of the box average (model pixels), about a small target's size. 1 disables.
    noise_block_px : int
        Side of the block (model pixels) over which the local RMS of the evidence is measured,
        leaving out the central ``3 blur_px`` square (:func:`clutter_gain`); where it exceeds
        the frame's RMS the evidence is scaled down by the ratio. 0 disables. Smaller adapts to
        finer clutter but lets a larger target's own evidence count as clutter.

    Returns
    -------
    ndarray, shape (h, w) float32
    """
    e = cv2.min(cv2.multiply(residual.astype(np.float32), 1.0 / max(float(threshold), 1e-6)),
                float(cap))
    if valid is not None:
        # multiply rather than index: boolean assignment costs ~10x more on a whole frame
        e = cv2.multiply(e, (np.asarray(valid) > 0).astype(np.float32))
    if blur_px > 1:
        e = cv2.blur(e, (blur_px, blur_px))
    if noise_block_px > 1:
        e = e * clutter_gain(e, noise_block_px, 3 * max(1, blur_px))
    return e


def clutter_gain(e: np.ndarray, block_px: int, inner_px: int) -> np.ndarray:
    """Per-pixel factor <= 1 that scales evidence down where the clutter around is above the
    frame's, (h, w) float32.

    The clutter is the RMS of ``e`` over a ``block_px`` square *minus* the ``inner_px`` square at
    its centre (a ring): a target smaller than the inner square does not count as its own
    clutter, so a lone target in a clean neighbourhood keeps its evidence while one in foliage or
    textured ground is damped. The factor is ``g / max(ring RMS, g)``, ``g`` the frame's RMS.
    """
    B = int(block_px)
    b = int(min(inner_px, B - 1))
    e2 = cv2.multiply(e, e)
    g = float(np.sqrt(cv2.mean(e2)[0]))
    if g <= 0:
        return np.ones_like(e)
    ring = cv2.boxFilter(e2, -1, (B, B), normalize=False)
    if b > 0:
        ring = cv2.subtract(ring, cv2.boxFilter(e2, -1, (b, b), normalize=False))
    ring = cv2.max(cv2.multiply(ring, 1.0 / (B * B - b * b)), g * g)
    return cv2.divide(g, cv2.sqrt(ring))


def quantile(image: np.ndarray, q: float, mask: np.ndarray | None, top: float) -> float:
    """The ``q`` quantile of a float image over ``mask`` from a 256-bin histogram on
    ``[0, top]`` (resolution ``top / 256``; ~20x faster than ``np.quantile`` on a frame)."""
    u8 = cv2.convertScaleAbs(image, alpha=255.0 / top)
    m = None if mask is None else mask.astype(np.uint8)
    hist = cv2.calcHist([u8], [0], m, [256], [0, 256]).ravel()
    total = hist.sum()
    if total <= 0:
        return 0.0
    k = int(np.searchsorted(np.cumsum(hist), q * total))
    return (k + 0.5) * top / 255.0


def accumulate(previous: np.ndarray | None, to_current: np.ndarray | None,
               evidence: np.ndarray, decay: float, radius: int) -> np.ndarray:
    """One step of the motion-compensated leaky max-sum (see the module docstring).

    Parameters
    ----------
    previous : ndarray, shape (h', w') float32 or None
        The sum at the previous frame, in its model pixels; None starts afresh.
    to_current : ndarray, shape (3, 3) or None
        OpenCV homography (model pixel indices) previous frame -> current frame.
    evidence : ndarray, shape (h, w) float32
        This frame's evidence (:func:`frame_evidence`).
    decay : float
        ``lambda`` in [0, 1): ``exp(-dt / tau)``.
    radius : int
        Grey dilation radius in model pixels: how far a target may move in one frame. 0 keeps the
        sum in place (a target standing still in the world).

    Returns
    -------
    ndarray, shape (h, w) float32
    """
    if previous is None or to_current is None:
        return evidence.astype(np.float32, copy=True)
    h, w = evidence.shape
    moved = warp(previous, to_current, (w, h))
    if radius > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        moved = cv2.dilate(moved, k)
    return cv2.scaleAdd(moved, float(decay), evidence.astype(np.float32))


def persistent_peaks(score: np.ndarray, evidence: np.ndarray, threshold: float,
                     min_evidence: float, exclude: np.ndarray | None = None,
                     nms_px: int = 7) -> list[tuple[int, int, float]]:
    """Local maxima of a steady-state-normalised sum above ``threshold`` (model pixels).

    Parameters
    ----------
    score : ndarray, shape (h, w) float32
        ``(1 - lambda) A_t``: a target with evidence ``e`` in every frame scores ``e``.
    evidence : ndarray, shape (h, w) float32
        This frame's evidence; a peak must have at least ``min_evidence`` within 1 pixel (the
        target is here now, not only its trail).
    threshold, min_evidence : float
    exclude : ndarray, shape (h, w) bool, optional
        Where peaks are not reported (regular detections, untrusted background).
    nms_px : int
        Side of the window a peak must be the maximum of (about a small target's size; larger
        windows let a stronger neighbour hide a target).

    Returns
    -------
    list of (x, y, score)
        Model pixel column, row and the score at the peak, strongest first.
    """
    k = max(1, int(nms_px)) | 1
    top = cv2.dilate(score, np.ones((k, k), np.uint8))
    near = cv2.dilate(evidence, np.ones((3, 3), np.uint8))
    m = (score >= top) & (score > threshold) & (near >= min_evidence)
    if exclude is not None:
        m &= ~exclude
    ys, xs = np.nonzero(m)
    if len(xs) == 0:
        return []
    v = score[ys, xs]
    order = np.argsort(-v, kind="stable")
    return [(int(xs[i]), int(ys[i]), float(v[i])) for i in order]


def peak_box(evidence: np.ndarray, x: int, y: int, max_side: int,
             ratio: float = 0.35) -> tuple[int, int, int, int] | None:
    """Box (model pixels ``x, y, w, h``) of the evidence blob at a peak, or None.

    The region of ``evidence`` above ``ratio`` x its largest value within 1 pixel of the peak,
    connected to that pixel, clipped to ``max_side`` around the peak. A threshold relative to the
    peak rather than to the frame keeps a faint target's box from spreading into the clutter
    around it. The evidence is box-averaged, which widens a target by the averaging's
    half-width; a faint target's residual is also sparser than its body, which narrows it:
    the box is not corrected for either (on truck4, shrinking it by the half-width lowered its
    IoU with the annotated truck).
    """
    h, w = evidence.shape
    r = max(2, int(max_side))
    x0, y0, x1, y1 = max(0, x - r), max(0, y - r), min(w, x + r + 1), min(h, y + r + 1)
    win = evidence[y0:y1, x0:x1]
    px, py = x - x0, y - y0
    ys0, xs0 = max(0, py - 1), max(0, px - 1)
    nb = win[ys0:py + 2, xs0:px + 2]
    top = float(nb.max())
    if top <= 0:
        return None
    ky, kx = np.unravel_index(int(np.argmax(nb)), nb.shape)
    m = (win >= ratio * top).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    lab = labels[ys0 + ky, xs0 + kx]
    if lab == 0:
        return None
    bx, by, bw, bh = (int(v) for v in stats[lab, :4])
    half = max_side // 2
    bx0, by0 = max(bx, px - half), max(by, py - half)
    bx1, by1 = min(bx + bw, px + half + 1), min(by + bh, py + half + 1)
    if bx1 <= bx0 or by1 <= by0:
        return None
    return x0 + bx0, y0 + by0, bx1 - bx0, by1 - by0


@dataclass(frozen=True)
class PersistentDetection:
    """One detection found by persistence.

    Attributes
    ----------
    box : (int, int, int, int)
        ``x, y, w, h`` in model pixels of the current frame.
    score : float
        Steady-state-normalised accumulated evidence at the peak.
    support : float
        Share of the recent frames with support near its world position.
    """

    box: tuple[int, int, int, int]
    score: float
    support: float


class PersistenceTracker:
    """Runs the persistence recursion over a detector's finalised frames (in order).

    Parameters
    ----------
    config : DetectionConfig
        Uses the ``persist_*`` fields.
    fps : float
    scale : float
        Model / full resolution.

    Notes
    -----
    The recursion is causal over finalised frames: a target needs about ``persist_tau_s`` of
    evidence before it is reported. ``reset`` starts afresh (a new registration segment).
    """

    def __init__(self, config: DetectionConfig, fps: float, scale: float) -> None:
        validate(config)
        self.config = config
        self.fps = float(fps)
        self.scale = float(scale)
        self.decay = math.exp(-1.0 / (self.fps * config.persist_tau_s))
        self._history_n = max(1, int(round(config.persist_window_s * self.fps)))
        self.reset()

    def reset(self) -> None:
        self._acc: np.ndarray | None = None
        self._H: np.ndarray | None = None
        self._budget = 0.0
        #: per recent frame: (time, (K, 2) world positions of peaks and detections)
        self._history: deque[tuple[float, np.ndarray]] = deque(maxlen=self._history_n)
        #: per recent frame: (time, (N,) areas of its regular detections, frame pixels^2)
        self._areas: deque[tuple[float, np.ndarray]] = deque()

    def step(self, residual: np.ndarray, threshold: float, valid: np.ndarray, H: np.ndarray,
             time: float, det_boxes: np.ndarray, metres_per_px: float | None,
             ) -> list[PersistentDetection]:
        """Add one finalised frame; return the persistent detections not among ``det_boxes``.

        Parameters
        ----------
        residual : ndarray, shape (h, w) uint8
            Model-resolution residual of the frame (``FrameResult.residual``).
        threshold : float
            Its single-frame threshold, grey levels.
        valid : ndarray, shape (h, w)
            Non-zero where the background is trusted.
        H : ndarray, shape (3, 3)
            Frame pixels (full resolution) -> world.
        time : float
            Seconds.
        det_boxes : ndarray, shape (N, 4)
            The frame's regular detections, ``x, y, w, h`` in full-resolution frame pixels.
        metres_per_px : float or None
            Metres per full-resolution frame pixel when known (speeds and sizes in metres),
            else None (pixels).
        """
        c = self.config
        s = self.scale
        if metres_per_px:
            speed_px_s = c.persist_max_speed_mps / metres_per_px
            max_len_px = c.persist_max_length_m / metres_per_px
        else:
            speed_px_s, max_len_px = c.persist_max_speed_px_s, c.persist_max_length_px
        blur = max(1, int(round(c.persist_blur_px * s)))
        e = frame_evidence(residual, threshold, valid, cap=c.persist_cap, blur_px=blur,
                           noise_block_px=int(round(c.persist_noise_block_px * s)))
        to_cur = None
        if self._acc is not None and self._H is not None:
            to_cur = to_cv_homography(np.linalg.inv(H) @ self._H, s)
        # Sub-pixel speeds: the dilation budget accumulates until it reaches a whole pixel.
        self._budget += speed_px_s * s / self.fps
        radius = int(self._budget)
        self._budget -= radius
        self._acc = accumulate(self._acc, to_cur, e, self.decay, radius)
        self._H = np.asarray(H, np.float64)
        score = self._acc * np.float32(1.0 - self.decay)

        h, w = residual.shape
        # Near the edge of the trusted area (pixels entering the view, the video's border) the
        # background has few samples and its noise is not that of the frame.
        edge = max(1, int(round(c.persist_edge_px * s)))
        trusted = np.pad((np.asarray(valid) > 0).astype(np.uint8), 1)
        trusted = cv2.erode(trusted, np.ones((2 * edge + 1, 2 * edge + 1), np.uint8))[1:-1, 1:-1]
        untrusted = trusted == 0
        exclude = untrusted.copy()
        for bx, by, bw, bh in np.asarray(det_boxes, np.float64).reshape(-1, 4):
            # A regular detection's surroundings up to its own length are left to the blobs:
            # there persistence only finds the other part of a vehicle they split in two, and
            # the second box splits the track.
            pad = max(1, int(round(max(c.persist_exclude_px,
                                       c.persist_exclude_length * max(bw, bh)) * s)))
            x0, y0 = max(0, int(bx * s) - pad), max(0, int(by * s) - pad)
            x1, y1 = min(w, int(math.ceil((bx + bw) * s)) + pad), min(h, int(math.ceil((by + bh) * s)) + pad)
            exclude[y0:y1, x0:x1] = True
        thr = c.persist_threshold
        if c.persist_noise_ratio > 0 and (~untrusted).any():
            # Relative to the sum's own clutter level: a larger search (faster allowed speed,
            # longer memory) or more clutter lifts every maximum, and the threshold with them.
            # Over the whole trusted frame, detections included: leaving them out lowered the
            # level where vehicles are many and large, and let clutter through.
            thr = max(thr, c.persist_noise_ratio * quantile(score, 0.99, ~untrusted, c.persist_cap))
        self.last_threshold = thr
        # Peaks down to persist_support_level x the threshold count as support for later frames
        # (the first threshold of an M-of-N test); only those above it can be reported.
        cands = persistent_peaks(score, e, c.persist_support_level * thr, c.persist_min_evidence,
                                 exclude, 2 * blur + 1)
        pk = np.array([[(x + 0.5) / s, (y + 0.5) / s] for x, y, _ in cands]).reshape(-1, 2)
        db = np.asarray(det_boxes, np.float64).reshape(-1, 4)
        pts = np.vstack([pk, db[:, :2] + db[:, 2:] / 2])
        world = apply_homography(self._H, pts) if len(pts) else np.zeros((0, 2))
        wpp = _world_per_px(self._H, residual.shape, s)

        max_side = max(2, int(round(max_len_px * s)))
        min_area = self._min_area(time, db)
        out = []
        taken = np.zeros((h, w), bool)
        for k, (x, y, sc) in enumerate(cands):
            if sc <= thr:
                break  # strongest first
            if taken[y, x]:
                continue  # a second peak of a stronger one's blob
            b = peak_box(e, x, y, max_side, c.persist_box_ratio)
            if b is None or taken[b[1]:b[1] + b[3], b[0]:b[0] + b[2]].any():
                continue
            if b[2] * b[3] < min_area * s * s:
                continue
            support = self._support(world[k], time, speed_px_s * wpp, max_len_px * wpp)
            if support >= c.persist_min_support:
                out.append(PersistentDetection(b, sc, support))
                taken[b[1]:b[1] + b[3], b[0]:b[0] + b[2]] = True
                if len(out) >= c.persist_max_per_frame:
                    break
        self._history.append((time, world))
        return out

    def _min_area(self, time: float, det_boxes: np.ndarray) -> float:
        """Smallest persistence box area (full-resolution pixels^2): ``persist_min_area_ratio``
        x the median area of the regular detections of the last ``persist_typical_s`` seconds,
        0 with fewer than 5 of them.

        Without a vehicle model the typical detection is the best guess of one vehicle's size:
        this keeps persistence to targets of about a vehicle's size in the scene (a far, small
        truck among small detections) and away from pedestrians and debris where vehicles are
        large (a nadir view of a street)."""
        c = self.config
        self._areas.append((time, det_boxes[:, 2] * det_boxes[:, 3]))
        while self._areas and self._areas[0][0] < time - c.persist_typical_s:
            self._areas.popleft()
        areas = np.concatenate([a for _, a in self._areas])
        if c.persist_min_area_ratio <= 0 or len(areas) < 5:
            return 0.0
        return c.persist_min_area_ratio * float(np.median(areas))

    def _support(self, p: np.ndarray, time: float, speed_w: float, tol_w: float) -> float:
        """Share of the recent frames with a peak or detection within reach of world point p."""
        if self._history.maxlen is None or self._history.maxlen == 0:
            return 1.0
        hits = 0
        for t, pts in self._history:
            if len(pts) == 0:
                continue
            reach = speed_w * abs(time - t) + tol_w
            if np.min(np.sum((pts - p) ** 2, axis=1)) <= reach * reach:
                hits += 1
        return hits / self._history.maxlen


def _world_per_px(H: np.ndarray, shape: tuple[int, int], scale: float) -> float:
    """World units per full-resolution frame pixel at the centre of a model-resolution frame."""
    h, w = shape
    cx, cy = w / scale / 2, h / scale / 2
    q = apply_homography(H, np.array([[cx, cy], [cx + 1.0, cy], [cx, cy + 1.0]]))
    J = np.stack([q[1] - q[0], q[2] - q[0]], axis=1)
    return math.sqrt(abs(float(np.linalg.det(J))))


def validate(c: DetectionConfig) -> None:
    """Raise :class:`ConfigError` naming the first ``persist_*`` option out of range."""
    ranges = [  # name, low, high, low excluded, high excluded (None: no bound)
        ("persist_tau_s", 0, None, True, False),
        ("persist_window_s", 0, None, False, False),
        ("persist_min_support", 0, 1, False, False),
        ("persist_max_speed_mps", 0, None, False, False),
        ("persist_max_speed_px_s", 0, None, False, False),
        ("persist_max_length_m", 0, None, True, False),
        ("persist_max_length_px", 0, None, True, False),
        ("persist_threshold", 0, None, True, False),
        ("persist_min_evidence", 0, None, False, False),
        ("persist_cap", 0, None, True, False),
        ("persist_blur_px", 0, None, False, False),
        ("persist_noise_block_px", 0, None, False, False),
        ("persist_box_ratio", 0, 1, True, False),
        ("persist_exclude_px", 0, None, False, False),
        ("persist_exclude_length", 0, None, False, False),
        ("persist_max_per_frame", 0, None, False, False),
        ("persist_conf", 0, 1, False, False),
        ("persist_noise_ratio", 0, None, False, False),
        ("persist_support_level", 0, 1, True, False),
        ("persist_min_area_ratio", 0, None, False, False),
        ("persist_typical_s", 0, None, True, False),
        ("persist_edge_px", 0, None, False, False),
    ]
    for name, lo, hi, lo_open, hi_open in ranges:
        check_range(f"detection.{name}", getattr(c, name), lo, hi, lo_open, hi_open)

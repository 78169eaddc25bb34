"""Moving vehicles in one registered frame: residual -> blobs -> refined boxes.

:func:`detect_moving` is the per-frame algorithm as a pure function of the frame and its
background (the streaming window that builds the background is :mod:`.detector`):

1. the residual at model resolution and its noise threshold (:mod:`.residual`);
2. model-resolution blobs (:func:`model_blobs`): hysteresis, splitting of merged blobs, joining
   of a vehicle's fragments, small blobs regrown or dropped (:mod:`.blobs`);
3. each blob refined at full resolution (:func:`refine_blob`): ghosts dropped, moving shadows
   removed (:mod:`.shadows`), side-by-side vehicles separated, each piece gated by size and
   thickness, scored and boxed at its half-contrast edge.

Boxes are ``x, y, w, h`` in full-resolution frame pixels.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from ..config import DetectionConfig
from .blobs import (
    Blob,
    close,
    drop_small,
    edge_extent,
    hysteresis_blobs,
    join_cabs,
    join_fragments,
    join_vehicle_parts,
    nearest_seed,
    open2,
    oriented_sides,
    regrow_small,
    split_blob,
    typical_sides,
)
from .residual import border_fill_mask, gain_normalise, ghost_score, pad0, robust_sigma, smoothed_residual
from .shadows import remove_shadows, shadow_mask, trim_boxes, trim_shadow_side


@dataclass
class FrameResult:
    """What :func:`detect_moving` found in one frame.

    Attributes
    ----------
    boxes : ndarray, shape (N, 4) float64
        ``x, y, w, h`` in full-resolution frame pixels.
    conf : ndarray, shape (N,)
    masks : list of ndarray (h_k, w_k) bool
        Blob of each box at full resolution, cropped to ``crops[k]``.
    crops : list of (x0, y0, x1, y1)
        Full-resolution integer crop of each mask.
    model_blobs : list of Blob
        The same detections' blobs at model resolution (kept out of the background).
    contrast : ndarray, shape (N,)
        Mean residual of each blob over the threshold.
    threshold : float
        Residual threshold used, grey levels.
    residual : ndarray, shape (h, w) uint8
        Model-resolution residual (for debug pictures).
    persistent : ndarray, shape (N,) bool, optional
        True for detections found by multi-frame persistence (None: none were).
    shadow_samples : ndarray, shape (K, 6), optional
        Box centre ``x, y`` and shadow growth (left, top, right, bottom) of the vehicles whose
        shadows were removed (:func:`.shadows.trim_shadow_side`), frame pixels.
    """

    boxes: np.ndarray
    conf: np.ndarray
    masks: list = field(default_factory=list)
    crops: list = field(default_factory=list)
    model_blobs: list = field(default_factory=list)
    contrast: np.ndarray | None = None
    threshold: float = 0.0
    residual: np.ndarray | None = None
    persistent: np.ndarray | None = None
    shadow_samples: np.ndarray | None = None


@dataclass(frozen=True)
class SizeGates:
    """Size limits of one frame in full-resolution frame pixels (from metres via the frame's
    scale when known; see ``DetectionConfig``).

    ``local`` (metric gates of a frame whose scale changes across it: an oblique view on a
    map): full-resolution ``(x, y)`` -> how many times longer a metre is there than where the
    gates were set (the frame's centre); :meth:`at` gives the gates at a blob's place, and
    ``local_range`` is the smallest and largest factor over the frame."""

    min_area_px: float
    max_length_px: float
    close_px: float
    join_gap_px: float
    min_width_px: float = 0.0
    local: Callable[[float, float], float] | None = None
    local_range: tuple[float, float] = (1.0, 1.0)

    def at(self, x: float, y: float) -> SizeGates:
        """The area, length and width gates where a metre is ``local(x, y)`` times as long."""
        if self.local is None:
            return self
        f = self.local(x, y)
        return replace(self, min_area_px=self.min_area_px * f * f,
                       max_length_px=self.max_length_px * f, min_width_px=self.min_width_px * f,
                       local=None)


#: Smallest factor :func:`pixel_gate_scale` gives (frames under 960 x 540: the rule was measured
#: down to 540p, and smaller gates let compression noise through).
MIN_PIXEL_GATE_SCALE = 0.5


def pixel_gate_scale(shape: tuple[int, ...], reference_px: float) -> float:
    """Factor of the pixel size gates (used without a scale) for a frame of ``shape`` (H, W, ...):
    its diagonal / ``reference_px``, at least :data:`MIN_PIXEL_GATE_SCALE`, and exactly 1 within
    1% of ``reference_px`` (``reference_px`` 0: always 1). The same flight filmed at 4K shows
    every vehicle twice as long, in pixels, as at 1080p, and at 540p half as long."""
    if reference_px <= 0:
        return 1.0
    k = math.hypot(shape[0], shape[1]) / reference_px
    return 1.0 if abs(k - 1.0) < 0.01 else max(MIN_PIXEL_GATE_SCALE, k)


#: Length in pixels of a car's box that the pixel gates assume on a frame of
#: ``pixel_gates_reference_px`` diagonal (1920x1080: Santiago's cars, 36 x 20 px); on other frames
#: times :func:`pixel_gate_scale`.
FRAMING_CAR_PX = 36.0


def small_vehicles_hint(tracks, frame_size: tuple[int, int], config: DetectionConfig,
                        n_frames: int | None = None) -> str | None:
    """A warning for a run without a map or ``--gsd`` whose tracked vehicles' median box is under
    half the length the pixel gates assume (:data:`FRAMING_CAR_PX`): vehicles that small are
    lost to the gates and the model's resolution, and a ground resolution lets the detector size
    both for them. Measured (``benchmarks/altitude.py``): generated scenes flown twice as high
    (cars 9 px, median tracked box 9 px against 24 and 18 assumed) scored HOTA 0.573 / 0.682
    without a scale and 0.665 / 0.712 with ``--gsd``; at 1.43x (13 px against 24), where the hint
    stays silent, 0.677 / 0.744 without and 0.669 / 0.724 with. Santiago (36 px against 36) and
    truck4 (19 against 24) get no hint. None when there is nothing to say.

    A run of at least ``n_frames`` 50 frames that tracked at most one vehicle gets a milder hint
    too (vehicles far below the gates leave too few tracks to measure: a 160x120 clip of 4 px
    cars gave 1 track, HOTA 0.11, and 0.51 with ``--gsd``).

    The gain of a scale for small vehicles is uneven (a probe, 2026-12-03): Santiago downscaled
    to 480x270 (cars 9.6 px) 0.562 -> 0.559 HOTA with ``--gsd``, to 384x216 (7.8 px) 0.498 ->
    0.537; generated scenes flown twice as high, seeds 5 / 7 / 11, 0.757 / 0.650 / 0.715 ->
    0.744 / 0.681 / 0.668; so the hint says what a scale does, not that it will gain.

    Vehicles over :data:`LARGE_RATIO` times the assumed length get the opposite hint: the
    pixel gates (closing, join gap) are then too small for them and they fall into pieces. A
    1024x540 crop of Santiago's 1080p frames (UAVDT's framing; cars 38 px against 19 assumed)
    scored HOTA/IDF1 0.602/0.772 and 0.548/0.696 (MCMC seeds 0, 1) without a scale and
    0.656/0.890, 0.660/0.892 with ``--gsd``; but generated scenes flown at a quarter of the
    altitude (cars 70 px in 640x480) scored better without a scale (0.518 against 0.464 with
    their map), hence the condition in its wording."""
    if config.pixel_gates_reference_px <= 0 or not frame_size:
        return None
    w, h = frame_size
    expected = FRAMING_CAR_PX * pixel_gate_scale((h, w), config.pixel_gates_reference_px)
    sides = [max(p.box[2], p.box[3]) for t in tracks for p in t.points
             if p.kind == "observed" and p.box is not None]
    if n_frames is not None and n_frames >= 50 and len(tracks) <= 1:
        return (f"{len(tracks)} vehicle{'s' * (len(tracks) != 1)} tracked in {n_frames} frames: "
                f"if the video shows more, they may be smaller than the detector is set for "
                f"without a scale (about {expected:.0f} px long in a {w}x{h} frame): give --gsd "
                f"(metres per pixel) or --map")
    if len(sides) < 20:
        return None
    median = float(np.median(sides))
    if median > LARGE_RATIO * expected:
        return (f"the tracked vehicles are large for a {w}x{h} frame (median box {median:.0f} px "
                f"long; without a scale the detector is set for about {expected:.0f} px): if "
                f"vehicles show as several boxes or tracks, give --gsd (metres per pixel) or --map, "
                f"which size the gates for them")
    if median >= 0.5 * expected:
        return None
    return (f"the tracked vehicles are small for a {w}x{h} frame (median box {median:.0f} px "
            f"long; without a scale the detector is set for about {expected:.0f} px), so smaller "
            f"ones may be missed: --gsd (metres per pixel) or --map sizes the gates for them "
            f"(it helps most below about 8 px; README, Fitting it to your footage)")


#: :func:`small_vehicles_hint` names vehicles this many times the length the pixel gates assume.
LARGE_RATIO = 1.75

#: :func:`oblique_hint` speaks when vehicles near one edge of the frame are this many times the
#: size of those near the other.
OBLIQUE_RATIO = 1.5


def oblique_hint(detections, gsd: float | None = None, *,
                 boxes: np.ndarray | None = None) -> str | None:
    """A warning when the detections' sizes grow from the top of the frame to the bottom (or the
    reverse): an oblique view, which the detector models only with a map (its metric gates are
    set at each blob's place, :meth:`SizeGates.at`). Otherwise its blob rules compare each blob
    with the frame's median blob, its pixel gates are one per frame, ``--gsd`` is one scale for
    the whole frame, and the finish stage judges sizes on one scale for the run.

    The ratio is the median box side of the detections in the bottom third of their rows over
    that of the top third. Measured: nadir Santiago 1.15, 19 nadir generated scenes 0.79-1.34;
    Santiago warped to an oblique view with near vehicles twice / three times as large as far
    ones 1.86 / 1.96, UAV123 truck4 1.68. Tracking those warps (a probe, 2026-12-03, HOTA/IDF1/
    MOTA): nadir 0.669/0.891/0.772, twice 0.555/0.781/0.572, three times 0.425/0.566/0.214;
    ``detection.split_blobs=false`` (near vehicles were cut into pieces, measured against the
    frame's median) 0.576/-/0.660 and 0.487/-/0.446 (nadir loses 0.017 HOTA); ``--gsd`` at the
    middle row's scale 0.495 instead of 0.555. None when there is nothing to say (fewer than 30
    detections in either third).

    ``boxes`` ((N, 4) frame pixels) replaces the detections: ``track`` gives its tracks'
    observed boxes, which hold no noise blob. On the raw detections, small noise blobs near the
    top pulled its median down and nadir footage of small vehicles was called oblique (a probe,
    2026-12-03: Santiago at 384x216 and 480x270 with tuned gates, a generated scene flown twice
    as high with ``--gsd``: 1.5-2.0x against 1.1-1.25 in the ground truth); on tracked boxes 4
    of those 5 runs are silent, and the oblique ones still speak (the warps 1.9 / 2.0, truck4
    2.3)."""
    rows, sides = [], []
    parts = ([np.asarray(boxes, float).reshape(-1, 4)] if boxes is not None else
             [np.asarray(d.boxes, float).reshape(-1, 4) for d in detections or () if len(d)])
    for b in parts:
        if len(b):
            rows.append(b[:, 1] + b[:, 3] / 2)
            sides.append(np.sqrt(np.abs(b[:, 2] * b[:, 3])))
    if not rows:
        return None
    y, side = np.concatenate(rows), np.concatenate(sides)
    lo, hi = np.percentile(y, [5, 95])
    if hi <= lo:
        return None
    t = (y - lo) / (hi - lo)
    top, bottom = side[t < 1 / 3], side[t > 2 / 3]
    if len(top) < 30 or len(bottom) < 30:
        return None
    ratio = float(np.median(bottom) / max(np.median(top), 1e-9))
    if max(ratio, 1 / max(ratio, 1e-9)) < OBLIQUE_RATIO:
        return None
    near = "bottom" if ratio > 1 else "top"
    return (f"vehicles near the {near} of the frame are {max(ratio, 1 / ratio):.1f}x the size of "
            f"those at the other side: an oblique view, which the detector models only with a map "
            f"(near vehicles may be cut into pieces: --set detection.split_blobs=false"
            + ("; --gsd is one scale for the whole frame, right only for a nadir view: leave it "
               "out" if gsd else "") + "; README, Oblique views)")


def model_scale_for(shape: tuple[int, ...], config: DetectionConfig,
                    metric: bool = False, metres_per_px: float | None = None) -> float:
    """Resolution of the background model for frames of ``shape`` (H, W, ...).

    With a metric scale (``metric``: a map or ``--gsd``) it is ``config.model_scale``, raised
    (at most to 1) where a model pixel would cover more than ``config.model_pixel_max_m`` metres
    of ground, ``metres_per_px`` being the frame's (the vehicles are then too small for the
    model to see). Without
    one, ``config.model_scale`` is meant for a frame of ``pixel_gates_reference_px`` diagonal
    (1080p) and the model keeps the same resolution per vehicle at other sizes:
    ``model_scale / pixel_gate_scale``, at most 1. A 720p clip is modelled at 0.75 and a 540p
    one at full resolution, where 0.5 would leave a car of 18 x 10 px 9 x 5 model pixels:
    Santiago downscaled to 960x540 scored HOTA/IDF1 0.549/0.704 with the 1080p model scale and
    gates, 0.642/0.858 with both scaled (0.658/0.874 at 1080p); at 1280x720 0.587/0.786 ->
    0.627/0.831.
    """
    if metric:
        scale = float(config.model_scale)
        if metres_per_px and config.model_pixel_max_m > 0 and math.isfinite(metres_per_px):
            scale = max(scale, min(1.0, metres_per_px / config.model_pixel_max_m))
        return scale
    k = pixel_gate_scale(shape, config.pixel_gates_reference_px)
    return min(1.0, float(config.model_scale) / k)


#: Full-resolution pixels of a blob's region count as vehicle above this fraction of the
#: model-resolution threshold (the threshold of a regrown blob's fainter pixels likewise).
FULL_THRESHOLD_FRACTION = 0.8
#: Vehicles whose shadows were removed that a frame needs to measure the sun's offset itself
#: (:func:`.shadows.trim_shadow_side`); with fewer, the detector's pooled offset applies.
TRIM_MIN_SAMPLES = 2
#: Components of a refined piece smaller than this fraction of its largest are dropped as stray
#: noise pixels.
STRAY_FRACTION = 0.15


def detect_moving(image: np.ndarray, small: np.ndarray, bg_small: np.ndarray,
                  testable: np.ndarray, config: DetectionConfig, scale: float,
                  gates: SizeGates, shadow_prior=None) -> FrameResult:
    """Detect moving blobs in one frame against its background.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) uint8
        Full-resolution frame (BGR).
    small : ndarray, shape (h, w, 3) uint8
        The frame at model resolution (``scale`` x full size).
    bg_small : ndarray, shape (h, w, 3) uint8
        Its background, in the same model pixels.
    testable : ndarray, shape (h, w) uint8
        255 where the background is trusted.
    config : DetectionConfig
    scale : float
        Model / full resolution.
    gates : SizeGates
        Size gates in full-resolution pixels for this frame.
    shadow_prior : callable, optional
        ``(N, 2)`` box centres -> ``(N, 4)`` shadow growth (left, top, right, bottom), or None
        while it knows too little (``shadow_trim_pool_s``): taken off dark vehicles' boxes in
        a frame with fewer than two vehicles whose shadows were removed, which measure it
        otherwise; without it such frames are not trimmed.

    Returns
    -------
    FrameResult
    """
    bgn = gain_normalise(small, bg_small, config.gain_block_px * scale)
    res, sigma, thr = model_residual(small, bgn, testable, config, scale)
    norm = None
    if gates.local is not None:  # the area a vehicle has at a blob's place, relative to mid-frame
        def norm(b: Blob) -> float:
            return gates.local((b.box[0] + 0.5 * b.box[2]) / scale,
                               (b.box[1] + 0.5 * b.box[3]) / scale) ** 2
    blobs, faint, typical = model_blobs(res, thr, sigma, config, scale, gates, norm)
    sides_t = (typical_sides(blobs) if config.split_full_ratio > 0 and config.split_full_sides > 0
               else None)
    found = [d for b, f in zip(blobs, faint)
             for d in refine_blob(b, image, small, bgn, thr, config, scale, gates,
                                  typical=typical * (norm(b) if norm else 1.0), faint=f,
                                  sides=sides_t)]
    boxes = np.asarray([d.box for d in found], np.float64).reshape(-1, 4)
    with_growth = [(d.box, d.growth) for d in found if d.growth is not None]
    shadow_samples = np.array([[b[0] + 0.5 * b[2], b[1] + 0.5 * b[3], *g]
                               for b, g in with_growth], np.float64).reshape(-1, 6)
    if config.shadow_suppression and config.shadow_trim:
        dark = np.asarray([d.dark for d in found], bool)
        if len(with_growth) >= TRIM_MIN_SAMPLES or shadow_prior is None:
            boxes = trim_shadow_side(boxes, dark, [g for _, g in with_growth],
                                     min_samples=TRIM_MIN_SAMPLES)
        elif dark.any():
            grow = shadow_prior(boxes[:, :2] + 0.5 * boxes[:, 2:])
            if grow is not None:
                boxes = trim_boxes(boxes, dark, grow)
    return FrameResult(
        boxes=boxes,
        conf=np.asarray([d.conf for d in found], np.float64),
        masks=[d.mask for d in found], crops=[d.crop for d in found],
        model_blobs=[d.blob for d in found],
        contrast=np.asarray([d.contrast for d in found], np.float64), threshold=thr, residual=res,
        shadow_samples=shadow_samples,
    )


def model_residual(small: np.ndarray, bgn: np.ndarray, testable: np.ndarray,
                   config: DetectionConfig, scale: float) -> tuple[np.ndarray, float, float]:
    """The model-resolution residual of ``small`` against its gain-normalised background ``bgn``,
    zero where the background is not trusted and on the black fill at the image border.

    Returns
    -------
    residual : ndarray, shape (h, w) uint8
    sigma : float
        Its noise level, grey levels (:func:`.residual.robust_sigma`).
    threshold : float
        ``max(min_threshold, threshold_sigma x sigma)``.
    """
    res = smoothed_residual(small, bgn, 1, config.residual_sigma_px * scale)
    res[testable == 0] = 0
    res[border_fill_mask(small)] = 0
    sigma = robust_sigma(res, testable)
    return res, sigma, max(config.min_threshold, config.threshold_sigma * sigma)


def model_blobs(res: np.ndarray, thr: float, sigma: float, config: DetectionConfig, scale: float,
                gates: SizeGates, norm=None) -> tuple[list[Blob], list[bool], float]:
    """Vehicle-sized blobs of the model-resolution residual ``res`` (model pixels).

    Hysteresis between ``thr`` and the seed level, then (each step as configured) blobs much
    bigger than the frame's typical one split, a vehicle's fragments and parts joined, small
    blobs regrown from fainter residual and the rest of the small ones dropped.

    ``norm`` (an oblique view with a map or ``--ground``): blob -> the area a vehicle has at its
    place relative to mid-frame; the frame-relative rules (split, regrow, drop) then compare
    areas divided by it, so that near vehicles are not split for being large nor far ones
    dropped for being small. Measured (Santiago warped so that near vehicles are twice / three
    times as large as far ones, on the warp's map and on its ``--ground`` plane, HOTA/IDF1/MOTA;
    before, with the gates already set per blob): twice 0.544/0.736/0.521 -> 0.567/0.789/0.609
    (map) and 0.552/0.747/0.545 -> 0.564/0.778/0.614 (ground); three times 0.495/0.655/0.341 ->
    0.480/0.646/0.388 and 0.470/0.627/0.310 -> 0.480/0.661/0.401. Measuring the trend from the
    blobs themselves, for footage without either, was tried and not kept: it fed on its own
    output (kept far fragments steepened it) and, measured on the raw blobs, flapped on and off.

    Returns
    -------
    blobs : list of Blob
    faint : list of bool
        Per blob: regrown, so that its pixels are only above ``regrow_ratio x thr``.
    typical : float
        The frame's median blob area before splitting, model pixels (0 with fewer than 5 blobs);
        with ``norm``, at mid-frame.
    """
    low = res > thr
    # Seeds also stand out of the noise by seed_sigma: the low threshold can then sit close to
    # the noise (whole dark vehicles), while noise alone rarely reaches a seed.
    high = res > max(thr * config.seed_ratio, config.seed_sigma * sigma)
    lo_f, hi_f = gates.local_range  # (each blob meets the gates of its place in refine_blob)
    model_min_area = 0.5 * gates.min_area_px * lo_f * lo_f * scale * scale
    blobs = hysteresis_blobs(low, high, close_radius=gates.close_px * scale,
                             min_area=model_min_area)
    max_len_model = gates.max_length_px * hi_f * scale
    # Without a vehicle model, the frame's typical blob is the best guess of one vehicle's size.
    areas = np.array([b.area for b in blobs], np.float64)
    k = np.array([norm(b) for b in blobs], np.float64) if norm is not None else np.ones(len(blobs))
    typical = float(np.median(areas / k)) if len(areas) >= 5 else 0.0
    if config.split_blobs:
        split: list[Blob] = []
        r_max = max(1, int(round(gates.close_px * scale)) + 1)
        # Only blobs much bigger than the frame's typical blob are candidates.
        for b, kb in zip(blobs, k):
            if typical > 0 and b.area >= config.split_area_ratio * typical * kb:
                split.extend(split_blob(b, min_area=0.5 * typical * kb, max_radius=r_max))
            else:
                split.append(b)
        blobs = split
    blobs = join_fragments(blobs, gap=gates.join_gap_px * scale, max_length=max_len_model)
    if config.join_parts_ratio > 0 and len(blobs) >= 5:
        # Without a vehicle model the frame's typical blob is the best guess of one vehicle.
        sides = np.array([sorted(cv2.minAreaRect(np.column_stack(np.nonzero(b.mask)[::-1])
                                                 .astype(np.float32))[1]) for b in blobs])
        long_t, short_t = np.median(sides[:, 1]), np.median(sides[:, 0])
        blobs = join_vehicle_parts(blobs, gap=2 * gates.join_gap_px * scale,
                                   max_long=config.join_parts_ratio * long_t,
                                   max_short=config.join_parts_ratio * short_t)
        if config.join_cab_ratio > 0:
            blobs = join_cabs(blobs, gap=gates.join_gap_px * scale, long_t=long_t,
                              max_long=max_len_model, cab_ratio=config.join_cab_ratio)
    faint_ids: set[int] = set()
    if config.regrow_ratio > 0:
        blobs, grown = regrow_small(blobs, res > config.regrow_ratio * thr,
                                    area_ratio=config.drop_small_ratio,
                                    close_radius=gates.close_px * scale,
                                    min_ratio=0.7, norm=norm)
        faint_ids = {id(b) for b, g in zip(blobs, grown) if g}
    blobs = drop_small(blobs, area_ratio=config.drop_small_ratio, near=config.drop_small_near,
                       norm=norm)
    return blobs, [id(b) in faint_ids for b in blobs], typical


@dataclass
class Refined:
    """One detection of :func:`refine_blob`."""

    box: list  # x, y, w, h, full-resolution frame pixels
    conf: float
    contrast: float  # mean full-resolution residual over the threshold
    mask: np.ndarray  # (h, w) bool, the vehicle's pixels in ``crop``
    crop: tuple[int, int, int, int]  # x0, y0, x1, y1, full-resolution
    blob: Blob  # its model-resolution blob (kept out of the background)
    dark: bool  # a dark vehicle kept whole with its shadow (shadows.trim_shadow_side)
    growth: np.ndarray | None  # how far a removed shadow reached past each box side


def blob_confidence(contrast: float, fill: float) -> float:
    """Confidence in [0, 1] of a detection from its ``contrast`` (mean residual over the
    threshold) and ``fill`` (its pixels' share of its box): rises with the contrast from 0 at
    0.8 x the threshold, and a box less than half filled (a thin or ragged blob) scores down to
    half."""
    c_contrast = 1.0 - math.exp(-1.5 * max(0.0, contrast - 0.8))
    c_shape = min(1.0, fill / 0.5)
    return float(np.clip(c_contrast * (0.5 + 0.5 * c_shape), 0.0, 1.0))


def refine_blob(b: Blob, image: np.ndarray, small: np.ndarray, bgn: np.ndarray, thr: float,
                config: DetectionConfig, scale: float, gates: SizeGates, *, typical: float,
                faint: bool, sides: tuple[float, float] | None = None) -> list[Refined]:
    """The detections of one model-resolution blob ``b``, refined at full resolution.

    A ghost (:func:`.residual.ghost_score`) gives none. Otherwise the blob's region is
    thresholded in the full-resolution residual, moving shadows are removed (as configured),
    side-by-side vehicles are separated (``split_full_ratio``), and each piece that passes the
    size, thickness, length and confidence gates becomes a detection boxed at its half-contrast
    edge (``box_edge_level``).

    Parameters
    ----------
    b : Blob
        In model pixels.
    image, small, bgn : ndarray
        The frame at full and model resolution, and the gain-normalised background (model).
    thr : float
        The model residual's threshold.
    typical : float
        The frame's typical blob area, model pixels (0: unknown).
    faint : bool
        ``b`` was regrown from residual above ``regrow_ratio x thr`` only.
    """
    H, W = image.shape[:2]
    h, w = small.shape[:2]
    margin = 2
    bx, by, bw, bh = b.box
    gates = gates.at((bx + 0.5 * bw) / scale, (by + 0.5 * bh) / scale)
    mx0, my0 = max(0, bx - margin), max(0, by - margin)
    mx1, my1 = min(w, bx + bw + margin), min(h, by + bh + margin)
    if config.ghost_ratio > 0 or (faint and config.regrow_ghost_ratio > 0):
        gm = np.zeros((my1 - my0, mx1 - mx0), np.uint8)
        gm[by - my0:by - my0 + bh, bx - mx0:bx - mx0 + bw] = b.mask
        gm = cv2.dilate(gm, np.ones((3, 3), np.uint8)) > 0
        # a regrown blob is mostly faint residual: it must show its outline in the frame
        ratio = max(config.ghost_ratio, config.regrow_ghost_ratio) if faint else config.ghost_ratio
        if ghost_score(small[my0:my1, mx0:mx1], bgn[my0:my1, mx0:mx1], gm) < ratio:
            return []
    fx0, fy0 = int(round(mx0 / scale)), int(round(my0 / scale))
    fx1, fy1 = min(W, int(round(mx1 / scale))), min(H, int(round(my1 / scale)))
    if fx1 <= fx0 or fy1 <= fy0:
        return []
    size = (fx1 - fx0, fy1 - fy0)
    crop = image[fy0:fy1, fx0:fx1]
    bg_crop = cv2.resize(bgn[my0:my1, mx0:mx1], size, interpolation=cv2.INTER_LINEAR)
    res_full = smoothed_residual(crop, bg_crop, max(1, int(round(1.0 / scale))),
                                 config.residual_sigma_px)
    mm = np.zeros((my1 - my0, mx1 - mx0), np.uint8)
    mm[by - my0:by - my0 + bh, bx - mx0:bx - mx0 + bw] = b.mask.astype(np.uint8) * 255
    mm = cv2.dilate(mm, np.ones((3, 3), np.uint8))
    region = cv2.resize(mm, size, interpolation=cv2.INTER_NEAREST) > 0
    # a regrown fragment's pixels are only above the lower threshold
    thr_b = config.regrow_ratio * thr if faint else thr
    fg = (res_full > FULL_THRESHOLD_FRACTION * thr_b) & region
    is_dark, growth = False, None
    if config.shadow_suppression:
        whole, info = fg, {}
        fg = remove_shadows(fg, crop, bg_crop, alpha=config.shadow_alpha,
                            beta=config.shadow_beta, tau_s=config.shadow_tau_s,
                            tau_h=config.shadow_tau_h,
                            min_core=config.shadow_min_core,
                            chroma_tolerance_px=config.shadow_chroma_px, info=info)
        if config.shadow_trim:
            n_fg = max(1, int(whole.sum()))
            is_dark = info["kept_shaded"] >= config.shadow_trim_share * n_fg
            if 0.1 * n_fg <= info["removed"] <= 0.6 * n_fg:
                growth = _box_growth(whole, fg)
    fg8 = open2(fg.astype(np.uint8))
    close_full = max(1.0, gates.close_px)
    # Vehicles side by side or nose to tail are separate pieces before the closing joins
    # them (their gap is a few pixels of road); each piece is a detection.
    pieces = None
    full_typical = typical / scale ** 2
    if config.split_full_ratio > 0 and typical > 0 \
            and int(np.count_nonzero(fg8)) >= config.split_area_ratio * full_typical:
        min_sides = None
        if sides is not None and config.split_full_sides > 0:
            min_sides = (config.split_full_sides * sides[0] / scale,
                         config.split_full_sides * sides[1] / scale)
        pieces = separate_pieces(fg8, max(gates.min_area_px,
                                          config.split_full_ratio * full_typical),
                                 gates.min_width_px, min_sides=min_sides)
    if pieces and config.split_full_shadow and cast_shadow_pieces(pieces, crop, bg_crop):
        pieces = None
    if pieces is None and config.split_colour_dist > 0 and typical > 0 \
            and int(np.count_nonzero(fg8)) >= config.split_area_ratio * full_typical:
        pieces = split_by_colour(fg8, crop, typical=full_typical,
                                 min_dist=config.split_colour_dist, min_width=gates.min_width_px)
    out = []
    for piece, pb in pieces_of(fg8, pieces, b, (mx0, my0, mx1, my1), scale):
        kept = piece_mask(piece, region, close_full, gates)
        if kept is None:
            continue
        fgm, (x0, y0, x1, y1), area = kept
        if config.structure_ncc > 0 and same_structure(crop, bg_crop, fgm) >= config.structure_ncc:
            continue
        contrast = float(res_full[fgm].mean()) / thr
        conf = blob_confidence(contrast, area / float((x1 - x0) * (y1 - y0)))
        if conf < config.min_conf:
            continue
        if config.box_edge_level > 0:
            # the box at the vehicle's half-contrast edge, not at the noise threshold
            ext = edge_extent(res_full, fgm, level=config.box_edge_level, floor=0.5 * thr_b)
            if ext is not None:
                x0, y0, x1, y1 = ext
        out.append(Refined(box=[fx0 + x0, fy0 + y0, x1 - x0, y1 - y0], conf=conf,
                           contrast=contrast, mask=fgm[y0:y1, x0:x1],
                           crop=(fx0 + int(x0), fy0 + int(y0), fx0 + int(x1), fy0 + int(y1)),
                           blob=pb, dark=is_dark, growth=growth))
    return out


#: Least grey-level spread of the background around a blob for :func:`same_structure` to judge it
#: (a vehicle on plain road has nothing to correlate with).
STRUCTURE_MIN_STD = 6.0


def same_structure(crop: np.ndarray, bg_crop: np.ndarray, mask: np.ndarray,
                   margin: int = 0) -> float:
    """Normalised cross-correlation of the frame and its background (grey) over the blob's
    pixels ``mask`` (grown by ``margin`` pixels): near 1 where the blob is the background's own
    structure with another contrast or sharpness (a thin bright wall or lane line rendered
    sharper than the warped samples keep it), low where something new covers the ground. 0
    where the background there is too plain to tell (spread under ``STRUCTURE_MIN_STD``).
    On the blob's own pixels it separates better than with a margin (generated convoy:21,
    frames 420-620: NCC >= 0.8 for 66% of the detections on nothing and none of the 368 within
    IoU 0.5 of a vehicle; with a 2 px margin 63% and 3%)."""
    k = 2 * margin + 1
    m = cv2.dilate(mask.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    a = cv2.cvtColor(np.ascontiguousarray(crop), cv2.COLOR_BGR2GRAY)[m].astype(np.float64)
    b = cv2.cvtColor(np.ascontiguousarray(bg_crop), cv2.COLOR_BGR2GRAY)[m].astype(np.float64)
    if len(a) < 3:
        return 0.0
    a -= a.mean()
    b -= b.mean()
    sb = float(np.sqrt((b * b).mean()))
    sa = float(np.sqrt((a * a).mean()))
    if sb < STRUCTURE_MIN_STD or sa <= 0:
        return 0.0
    return float((a * b).mean() / (sa * sb))


def piece_mask(piece: np.ndarray, region: np.ndarray, close_px: float, gates: SizeGates
               ) -> tuple[np.ndarray, tuple[int, int, int, int], int] | None:
    """The vehicle's pixels in one piece of a refined blob, or None when they fail the size gates.

    The piece (uint8, the blob's full-resolution crop) is closed by ``close_px``, kept inside the
    blob's ``region`` (bool), and its stray components (under ``STRAY_FRACTION`` of the largest)
    are dropped. The rest must reach ``gates.min_area_px`` and be ``gates.min_width_px`` thick,
    and its box no longer than ``gates.max_length_px``.

    Returns
    -------
    (mask (h, w) bool, (x0, y0, x1, y1) its box in the crop, its area in pixels), or None
    """
    fg8p = close(piece, close_px)
    fg8p &= region.astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg8p, connectivity=8)
    if n <= 1:
        return None
    # Keep the components that carry most of the blob (drop stray noise pixels).
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero(areas >= max(2.0, STRAY_FRACTION * areas.max())) + 1
    lut = np.zeros(n, bool)
    lut[keep] = True
    fgm = lut[labels]
    area = int(fgm.sum())
    if area < gates.min_area_px:
        return None
    if gates.min_width_px > 0:
        # Thickness = twice the largest inscribed radius: the residual of a parallax edge
        # (a wall or overpass side the ground homography does not register) is a thin
        # line however long; a vehicle is at least about its width thick.
        dist = cv2.distanceTransform(pad0(fgm.astype(np.uint8), 1), cv2.DIST_L2, 3)
        if 2.0 * float(dist.max()) < gates.min_width_px:
            return None
    ys, xs = np.nonzero(fgm)
    x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
    if max(x1 - x0, y1 - y0) > gates.max_length_px:
        return None
    return fgm, (x0, y0, x1, y1), area


def cast_shadow_pieces(pieces: list[np.ndarray], crop: np.ndarray, bg_crop: np.ndarray) -> bool:
    """True when the pieces :func:`separate_pieces` found are a vehicle and its own cast shadow
    rather than several vehicles: the darkest piece is darker than the ground it covers (mean
    grey level of the frame minus the background's below 0), the brightest is lighter than its
    ground, and the dark piece is no larger than the light one (in a nadir view a vehicle's
    shadow is its footprint moved by the sun's offset, partly hidden under the vehicle, so its
    visible part is smaller than the vehicle; the rule of ``shadows.remove_shadows``).

    Where the colour test of :func:`.shadows.shadow_mask` misses a shadow (compressed real
    video: Santiago's shadows, off the vehicle's sun side, stay in the blob), the shadow is
    a piece of its own one or two pixels from its vehicle, car-long and nearly car-wide, and
    was reported as a vehicle. Two vehicles, a dark one beside a light one, are told apart
    only when the dark one is the larger; two light or two dark ones are always split."""
    g = (cv2.cvtColor(np.ascontiguousarray(crop), cv2.COLOR_BGR2GRAY).astype(np.float32)
         - cv2.cvtColor(np.ascontiguousarray(bg_crop), cv2.COLOR_BGR2GRAY).astype(np.float32))
    d = [float(g[pc > 0].mean()) for pc in pieces]
    dark, light = int(np.argmin(d)), int(np.argmax(d))
    return (d[dark] < 0 < d[light]
            and np.count_nonzero(pieces[dark]) <= np.count_nonzero(pieces[light]))


def separate_pieces(mask: np.ndarray, min_area: float, min_width: float,
                    min_sides: tuple[float, float] | None = None) -> list[np.ndarray] | None:
    """Masks of the vehicles in one refined blob, when it holds two or more, else None.

    A blob found at the model's resolution can hold two vehicles whose bodies are a few pixels
    apart at full resolution: two cars passing in opposite lanes, a queue, a crossing at a
    junction (their shadows and the model's coarser pixels bridge the gap; the full-resolution
    closing that joins a vehicle's own fragments would bridge it again). Components of
    ``mask`` (full resolution, before the closing) of at least ``min_area`` pixels that are at
    least ``min_width`` thick are vehicles; the other pixels go to the nearest of them.
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    big = []
    for k in range(1, n):
        if stats[k, cv2.CC_STAT_AREA] < min_area:
            continue
        comp = (labels == k).astype(np.uint8)
        if min_width > 0:
            dist = cv2.distanceTransform(pad0(comp, 1), cv2.DIST_L2, 3)
            if 2.0 * float(dist.max()) < min_width:
                continue
        if min_sides is not None:
            lo, sh = oriented_sides(Blob((0, 0, comp.shape[1], comp.shape[0]), comp > 0))
            if lo < min_sides[0] or sh < min_sides[1]:
                continue
        big.append(k)
    if len(big) < 2:
        return None
    seeds = np.zeros(labels.shape, np.int32)
    for i, k in enumerate(big, start=1):
        seeds[labels == k] = i
    owner = nearest_seed(seeds, mask)
    return [(owner == i).astype(np.uint8) for i in range(1, len(big) + 1)]


#: :func:`split_by_colour`: the two colours must lie this many times their pooled spread apart.
COLOUR_SPLIT_CONTRAST = 2.5
#: ... and each part's area must be between these multiples of the frame's typical blob area: two
#: cars, not a truck's cab and its trailer, nor a van's windows and its roof.
COLOUR_SPLIT_PART_AREA = (0.5, 1.6)
#: ... and each part's largest connected piece must hold this share of its colour's pixels.
COLOUR_SPLIT_COHERENCE = 0.75
#: ... and at most this share of either piece may lie inside the other's convex hull.
COLOUR_SPLIT_HULL_SHARE = 0.2
#: ... and each piece must fill this share of its smallest enclosing (rotated) rectangle.
COLOUR_SPLIT_RECTANGULAR = 0.65


def split_by_colour(mask: np.ndarray, crop_bgr: np.ndarray, *, typical: float, min_dist: float,
                    min_width: float) -> list[np.ndarray] | None:
    """Masks of two touching vehicles of different colours in one refined blob, else None.

    Two vehicles side by side in adjacent lanes, or nose to tail in a queue, often touch in the
    residual (shadows and blur fill the lane line between them), so no erosion separates them
    (:func:`.blobs.split_blob` needs a waist) and their pixels are one component
    (:func:`separate_pieces`). Where their colours differ (most pairs: a dark car beside a
    white van) each is a compact, car-sized region of one colour. The blob's pixels (CIE Lab)
    are clustered by k-means in two and in three (deterministic farthest-point starts; the
    third cluster takes the rims and windows, which pair with neither body), and a pair of
    clusters is taken for two vehicles when their means are at least ``min_dist`` apart (Lab
    units, OpenCV's 8-bit scale) and ``COLOUR_SPLIT_CONTRAST`` times their pooled spread, and
    each of the two, smoothed by a 3x3 majority, has one connected piece holding
    ``COLOUR_SPLIT_COHERENCE`` of its pixels, at least ``min_width`` thick, whose area is within
    ``COLOUR_SPLIT_PART_AREA`` x ``typical`` (full-resolution pixels), that fills
    ``COLOUR_SPLIT_RECTANGULAR`` of its smallest rotated rectangle (vehicles are rectangles from
    above), and neither piece lies inside the other's convex hull (at most
    ``COLOUR_SPLIT_HULL_SHARE`` of it). A two-tone single vehicle fails those tests: its windows
    or cab are smaller than a car, a bus's roof larger, stripes are not one piece, and the rim
    where its edge blends into the road is a ring around its body. The other pixels go to the
    nearer piece. This is ours; neither paper splits blobs by colour.

    Parameters
    ----------
    mask : ndarray (h, w) uint8
        The blob's foreground at full resolution (after shadow removal), in ``crop_bgr``.
    crop_bgr : ndarray (h, w, 3) uint8
        The frame's pixels under ``mask``'s crop.
    """
    m = mask > 0
    lo = COLOUR_SPLIT_PART_AREA[0]
    if typical <= 0 or int(m.sum()) < 2 * lo * typical:
        return None
    X = cv2.cvtColor(crop_bgr, cv2.COLOR_BGR2LAB).astype(np.float32)[m]
    for k in (2, 3):
        fit = _kmeans(X, k)
        if fit is None:
            continue
        of, C = fit
        labels = np.zeros(m.shape, np.uint8)
        labels[m] = of.astype(np.uint8) + 1
        votes = np.stack([cv2.boxFilter((labels == c + 1).astype(np.float32), -1, (3, 3),
                                        normalize=False) for c in range(k)])
        smooth = (np.argmax(votes, axis=0).astype(np.uint8) + 1) * m
        for a, b in itertools.combinations(range(k), 2):
            both = (of == a) | (of == b)
            dist = float(np.linalg.norm(C[a] - C[b]))
            spread = float(np.sqrt(np.mean(((X[both] - C[of[both]]) ** 2).sum(1))))
            if dist < min_dist or dist < COLOUR_SPLIT_CONTRAST * spread:
                continue
            seeds = _vehicle_cores(smooth, (a + 1, b + 1), typical, min_width)
            if seeds is None:
                continue
            owner = nearest_seed(seeds, m)
            return [(owner == i).astype(np.uint8) for i in (1, 2)]
    return None


def _kmeans(X: np.ndarray, k: int, iters: int = 10) -> tuple[np.ndarray, np.ndarray] | None:
    """Lloyd's k-means of the rows of ``X`` from a deterministic start (the row farthest from the
    mean, then each next the row farthest from the centres so far): (labels, centres), or None
    when a cluster empties."""
    C = [X[np.argmax(((X - X.mean(0)) ** 2).sum(1))]]
    for _ in range(k - 1):
        d = np.min(np.stack([((X - c) ** 2).sum(1) for c in C]), axis=0)
        C.append(X[np.argmax(d)])
    C = np.stack(C)
    of = np.zeros(len(X), np.int64)
    for _ in range(iters):
        of = np.argmin(((X[:, None, :] - C[None]) ** 2).sum(2), axis=1)
        counts = np.bincount(of, minlength=k)
        if counts.min() == 0:
            return None
        newC = np.stack([X[of == c].mean(0) for c in range(k)])
        if np.allclose(newC, C, atol=0.05):
            break
        C = newC
    return of, C


def _vehicle_cores(smooth: np.ndarray, pair: tuple[int, int], typical: float,
                   min_width: float) -> np.ndarray | None:
    """Seeds (1, 2) of the two vehicles of colour clusters ``pair`` in the label image
    ``smooth``, or None when they fail :func:`split_by_colour`'s shape tests."""
    lo, hi = COLOUR_SPLIT_PART_AREA
    seeds = np.zeros(smooth.shape, np.int32)
    for i, c in enumerate(pair, start=1):
        part = (smooth == c).astype(np.uint8)
        cnt, cl, stats, _ = cv2.connectedComponentsWithStats(part, connectivity=4)
        if cnt <= 1:
            return None
        j = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        area = int(stats[j, cv2.CC_STAT_AREA])
        if area < COLOUR_SPLIT_COHERENCE * int(part.sum()) or not lo * typical <= area <= hi * typical:
            return None
        core = (cl == j).astype(np.uint8)
        if min_width > 0:
            dt = cv2.distanceTransform(pad0(core, 1), cv2.DIST_L2, 3)
            if 2.0 * float(dt.max()) < min_width:
                return None
        seeds[core > 0] = i
    # two vehicles lie beside each other; a vehicle's rim (its edge blended with the road) is a
    # ring whose hull holds the body
    for i in (1, 2):
        pts = cv2.findNonZero((seeds == i).astype(np.uint8))
        (_, _), (rw, rh), _ = cv2.minAreaRect(pts)
        if len(pts) < COLOUR_SPLIT_RECTANGULAR * (rw + 1) * (rh + 1):
            return None
        hull = np.zeros(seeds.shape, np.uint8)
        cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
        other = seeds == 3 - i
        if np.count_nonzero(hull[other]) > COLOUR_SPLIT_HULL_SHARE * np.count_nonzero(other):
            return None
    return seeds


def pieces_of(mask: np.ndarray, pieces: list[np.ndarray] | None, blob: Blob,
              model_crop: tuple[int, int, int, int], scale: float):
    """(full-resolution piece, its model-resolution blob) for each vehicle of a refined blob:
    ``[(mask, blob)]`` when it was not separated (:func:`separate_pieces`)."""
    if not pieces:
        return [(mask, blob)]
    mx0, my0, mx1, my1 = model_crop
    bx, by, bw, bh = blob.box
    out = []
    for pc in pieces:
        small = cv2.resize(pc, (mx1 - mx0, my1 - my0), interpolation=cv2.INTER_AREA) > 0
        sub = blob.mask & small[by - my0:by - my0 + bh, bx - mx0:bx - mx0 + bw]
        out.append((pc, Blob(blob.box, sub) if sub.any() else blob))
    return out


def _box_growth(whole: np.ndarray, core: np.ndarray) -> np.ndarray | None:
    """How far the box of mask ``whole`` reaches past the box of its part ``core`` on the left,
    top, right and bottom, pixels (4,); None when ``core`` is empty."""
    if not core.any():
        return None
    ys, xs = np.nonzero(whole)
    yc, xc = np.nonzero(core)
    return np.array([xc.min() - xs.min(), yc.min() - ys.min(), xs.max() - xc.max(),
                     ys.max() - yc.max()], np.float64)


def shadows_beside_detections_removed(residual: np.ndarray, small: np.ndarray,
                                      bg_small: np.ndarray, boxes: np.ndarray, scale: float,
                                      config: DetectionConfig) -> np.ndarray:
    """``residual`` (model pixels) with the cast-shadow pixels (:func:`.shadows.shadow_mask`)
    within one box size of a regular detection (``boxes``, full-resolution ``x, y, w, h``) set to
    0: the persistence step's evidence (see ``MovingObjectDetector._add_persistent``)."""
    h, w = residual.shape
    near = np.zeros((h, w), bool)
    for bx, by, bw, bh in np.asarray(boxes, np.float64).reshape(-1, 4) * scale:
        g = max(bw, bh)
        x0, y0 = max(0, int(bx - g)), max(0, int(by - g))
        x1, y1 = min(w, int(math.ceil(bx + bw + g))), min(h, int(math.ceil(by + bh + g)))
        near[y0:y1, x0:x1] = True
    bgn = gain_normalise(small, bg_small, config.gain_block_px * scale)
    shade = shadow_mask(small, bgn, alpha=config.shadow_alpha, beta=config.shadow_beta,
                        tau_s=config.shadow_tau_s, tau_h=config.shadow_tau_h,
                        chroma_tolerance_px=config.shadow_chroma_px)
    return np.where(shade & near, 0, residual).astype(residual.dtype)

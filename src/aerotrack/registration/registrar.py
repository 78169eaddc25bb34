"""The registration stage: every frame's homography to world coordinates, never raising on a bad frame.

World coordinates are map pixels when a map is given and frame 1's pixels otherwise. Each frame is
registered against the *last good frame* (normally the previous one), so a run of bad frames is
bridged without leaving frame 1's coordinates; with a map the chained homography is refined against
the map every ``refine_every_s`` seconds and whenever the frame-to-frame quality drops.
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections import Counter, deque
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from ..config import RegistrationConfig
from ..errors import ConfigError, InputError
from ..io.output import atomic_write_text
from ..types import Failure, Frame, Registration
from .chain import area_ratio, normalize, scale_homography, uncovered_share
from .frame2frame import (
    ESTIMATORS,
    METHODS,
    boxes_mask,
    detect_features,
    estimate_homography,
    frame_quality,
    polish_estimate,
    to_gray,
)
from .mapref import refine_against_map

log = logging.getLogger("aerotrack.registration")

STATUSES = ("ok", "refined", "carried", "reset", "reanchored")


def check_config(config: RegistrationConfig) -> None:
    """Raise :class:`ConfigError` naming the first out-of-range registration parameter."""
    if config.method not in METHODS:
        raise ConfigError(f"config registration.method: unknown {config.method!r} "
                          f"(valid: {', '.join(METHODS)})")
    if config.estimator not in ESTIMATORS:
        raise ConfigError(f"config registration.estimator: unknown {config.estimator!r} "
                          f"(valid: {', '.join(ESTIMATORS)})")
    if not (0 < config.scale <= 1):
        raise ConfigError(f"config registration.scale: must be in (0, 1], got {config.scale}")
    for name in ("max_features", "min_inliers", "refine_patch_px", "refine_patches"):
        if getattr(config, name) < 4:
            raise ConfigError(f"config registration.{name}: must be at least 4")
    if config.max_features > 100_000:  # (3e9 made OpenCV fail on every frame)
        raise ConfigError(f"config registration.max_features: at most 100000, got "
                          f"{config.max_features}")
    if config.refine_bins < 2:
        raise ConfigError("config registration.refine_bins: must be at least 2")
    if config.max_scale_change <= 1 or config.max_condition < 1:
        raise ConfigError("config registration.max_scale_change must be > 1 and max_condition >= 1")
    for name in ("ransac_threshold_px", "refine_search_px", "refine_max_correction_px"):
        if not getattr(config, name) > 0:
            raise ConfigError(f"config registration.{name}: must be positive")
    if not (0 < config.keyframe_min_overlap <= 1):
        raise ConfigError("config registration.keyframe_min_overlap: must be in (0, 1]")
    if not (0 <= config.keyframe_blur_ratio <= 1):
        raise ConfigError(f"config registration.keyframe_blur_ratio: "
                          f"{config.keyframe_blur_ratio!r} must be in [0, 1]")
    for name in ("refine_every_s", "carry_s", "reset_after_s", "keyframe_s"):
        if getattr(config, name) < 0:
            raise ConfigError(f"config registration.{name}: must not be negative")
    if not (isinstance(config.cut_frames, int) and config.cut_frames >= 0):
        raise ConfigError(f"config registration.cut_frames: {config.cut_frames!r} must be an "
                          "integer >= 0")
    if config.cut_frames == 1:
        raise ConfigError("config registration.cut_frames: 1 would reset on every failed frame; "
                          "use 0 (off) or >= 2")


class FrameRegistrar:
    """Registers frames one at a time, in order (Yu & Medioni section 2).

    Parameters
    ----------
    config : RegistrationConfig
    fps : float
        Frame rate; turns the config's seconds into frame counts where needed.
    geomap : GeoMap, optional
        The map; when given, world = map pixels and ``H_init`` is required.
    H_init : (3, 3) array, optional
        Frame 1 pixels -> world (``read_map_init``); identity without a map.

    Notes
    -----
    Frames are registered against a *keyframe* (eq. 1 with fewer, longer links): the keyframe's
    features are tracked into each new frame, starting from the predicted motion, and a new
    keyframe is taken every ``keyframe_s`` seconds, when fewer than ``keyframe_min_overlap`` of its
    features are still tracked, after a map refinement and after a failure. Fewer links in the
    chain means less drift without a map.

    ``step`` returns a :class:`~aerotrack.types.Registration` whose status says how it was
    obtained: ``ok`` (frame-to-frame, chained), ``refined`` (corrected against the map),
    ``carried`` (the frame could not be registered; the last motion is carried forward for up to
    ``carry_s`` seconds, then the position is held; the next good frame is registered against the
    last good one), ``reset`` (nothing registered for ``reset_after_s``, or a scene change:
    ``cut_frames`` consecutive frames that fail against the reference but register against each
    other; this frame becomes the new reference at its carried position, so later positions may
    be offset) or ``reanchored`` (same, but placed by a map refinement with a wider search).
    """

    def __init__(self, config: RegistrationConfig, fps: float, geomap=None,
                 H_init: np.ndarray | None = None) -> None:
        check_config(config)
        if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
            raise InputError(f"--fps {fps}: must be a positive number")
        self.config = config
        self.fps = float(fps)
        self.geomap = geomap
        if geomap is not None and H_init is None:
            raise InputError("--map needs --map-init (frame 1 -> map homography or control points)")
        self.H_init = np.eye(3) if H_init is None else normalize(H_init)
        self._map_gray = None
        #: working map pixels per map pixel along x and y (:meth:`_working_map`), None until
        #: the first refinement
        self._map_scale: float | None = None
        self._map_scale_y: float | None = None
        if geomap is not None:
            self._map_gray = cv2.cvtColor(geomap.read_image(), cv2.COLOR_BGR2GRAY)
        self.counts: Counter[str] = Counter()
        self.failures: list[tuple[int, str, str]] = []  # (frame, status, reason)
        self._ref_gray: np.ndarray | None = None
        self._ref_H = self.H_init
        self._ref_index = 0
        self._ref_time = 0.0
        #: Sharpness (:func:`sharpness`) of the last registered frames, the baseline a blurred
        #: frame is told by (a pan blurred throughout is its own baseline).
        self._recent_sharp: deque[float] = deque(maxlen=SHARPNESS_FRAMES)
        self._points: np.ndarray | None = None  # keyframe features, tracking-scale pixels
        self._key_n = 1  # features the keyframe started with
        self._M_key_last = np.eye(3)  # keyframe -> last good frame, tracking-scale pixels
        self._good_index, self._good_time = 0, 0.0  # last frame registered
        # frames given to step() since the last registered one (1: it was the previous frame;
        # counted in steps, not frame numbers, so that --stride is not taken for failures)
        self._since_good = 0
        self._motion = np.eye(3)  # last frame-to-frame motion, full-res frame pixels
        self._H_last: np.ndarray | None = None
        self._last_refine = -math.inf
        self._lost_gray: np.ndarray | None = None  # the previous frame, when it failed too
        self._lost_run = 0  # consecutive failed frames that registered against their predecessor

    # -- public ---------------------------------------------------------------------------------
    def step(self, frame: Frame, exclude_boxes: np.ndarray | None = None) -> Registration:
        """Register one frame (called for every frame, in order).

        Parameters
        ----------
        frame : Frame
        exclude_boxes : (N, 4) array, optional
            ``x, y, w, h`` boxes in the previous frame's pixels (its detections): no features are
            taken there, so moving vehicles do not pull the estimate.
        """
        self._since_good += 1
        try:
            reg = self._step(frame, exclude_boxes)
        except cv2.error as exc:  # a frame OpenCV chokes on is a failed frame, not a crash
            reg = self._carry(frame, f"OpenCV error ({str(exc).splitlines()[0][:80]})", bad=True)
        self._H_last = reg.H
        self.counts[reg.status] += 1
        if reg.status not in ("ok", "refined"):
            self.failures.append((reg.index, reg.status, reg.reason))
        return reg

    def summary(self) -> dict:
        """Counts per status and the first failures, for ``summary.json``."""
        return {"status_counts": dict(self.counts),
                "failures": [{"frame": f, "status": s, "reason": r} for f, s, r in self.failures[:200]],
                "n_failures": len(self.failures)}

    # -- internals ------------------------------------------------------------------------------
    def _scale(self, width: int) -> float:
        """Tracking scale for a frame ``width`` pixels wide (``scale``, raised for small frames)."""
        cfg = self.config
        return min(1.0, max(cfg.scale, cfg.min_track_width_px / max(width, 1)))

    def _step(self, frame: Frame, exclude_boxes: np.ndarray | None) -> Registration:
        cfg = self.config
        scale = self._scale(frame.image.shape[1])
        gray = to_gray(frame.image, scale)
        bad = frame_quality(gray, min_contrast=cfg.min_contrast, max_saturated=cfg.max_saturated,
                            min_neighbour_corr=cfg.min_neighbour_corr)
        # exclude_boxes are the previous frame's detections: a few pixels from where they are now
        mask = boxes_mask(gray.shape, exclude_boxes, scale, margin=4.0)
        if self._ref_gray is None:
            if bad:
                return Registration(frame.index, self.H_init.copy(), "reset", 0, float("nan"),
                                    float("nan"), f"{bad.reason}; no reference frame yet")
            return self._anchor(frame, gray, self.H_init, "ok", mask=mask)
        if bad is not None or gray.shape != self._ref_gray.shape:
            self._lost_gray, self._lost_run = None, 0
            return self._carry(frame, bad.reason if bad is not None else "frame size changed",
                               bad=True)
        fit = dict(ransac_threshold=cfg.ransac_threshold_px * scale,
                   estimator=cfg.estimator, min_inliers=cfg.min_inliers,
                   min_inlier_ratio=cfg.min_inlier_ratio,
                   max_scale_change=cfg.max_scale_change, max_condition=cfg.max_condition)
        common = dict(max_features=cfg.max_features, polish=False, **fit)
        guess = self._M_key_last
        est = estimate_homography(self._ref_gray, gray, method=cfg.method, prev_points=self._points,
                                  guess=guess if cfg.method == "lk" else None, **common)
        if not est and cfg.method == "lk":  # stale tracks: retry with fresh corners
            est = estimate_homography(self._ref_gray, gray, method="lk", guess=guess, **common)
        lk = bool(est)
        if not est and cfg.method != "orb":  # too large a motion for optical flow
            est = estimate_homography(self._ref_gray, gray, method="orb", **common)
        if not est:
            return self._lost(frame, gray, est.reason, common)
        self._lost_gray, self._lost_run = None, 0
        gap = self._since_good  # 1 unless frames failed since the last registered one
        refine_due = False
        if self._map_gray is not None:
            due = (cfg.refine_every_s > 0 and frame.time - self._last_refine >= cfg.refine_every_s - 1e-9)
            refine_due = due or est[1].inlier_ratio < cfg.refine_on_inlier_ratio or gap > 1
        if cfg.keyframe_grid:
            slot = math.floor(frame.time / cfg.keyframe_s + 1e-6)
            old = math.floor(self._ref_time / cfg.keyframe_s + 1e-6)
            timed = slot > old
        else:
            timed = frame.time - self._ref_time >= cfg.keyframe_s - 1e-9
        key_due = gap > 1 or timed or est[1].inliers < cfg.keyframe_min_overlap * self._key_n
        # Zooming out keeps every keyframe feature in view, so only the timer renewed the
        # keyframe, and over its 0.5 s a fast zoom (1-2 % a frame) passed max_scale_change: the
        # frames failed as degenerate, were taken for a scene change and reset, and detection
        # restarted with 11 frames of no detections (a probe, 2026-12-03). A new keyframe once
        # half the allowed scale change is used keeps the steps small.
        ratio = area_ratio(est[0], gray.shape[1], gray.shape[0])
        lim = math.sqrt(cfg.max_scale_change)
        scale_due = not (1.0 / lim <= ratio <= lim)
        sharp = self._sharpness(gray)
        if (key_due and not scale_due and gap == 1 and not cfg.keyframe_grid
                and sharp is not None and frame.time - self._ref_time < 2 * cfg.keyframe_s - 1e-9
                and uncovered_share(np.linalg.inv(est[0]), gray.shape[:2]) < BLUR_HOLD_UNCOVERED):
            # A blurred frame among sharp ones loses features (which called for a keyframe) and
            # registers worse: as the keyframe it would pass its error on to every later frame.
            # Only while the keyframe still shows the view: in a fast pan features leave it, and
            # holding the keyframe back there lost the frames (a review: 3.4 -> 13.7 px).
            log.debug("frame %d: blurred (sharpness %.2f of the recent frames'); not a keyframe",
                      frame.index, sharp)
            key_due = False
        key_due = key_due or scale_due
        if cfg.polish and lk and (key_due or refine_due):
            # Only a frame that becomes a keyframe (or starts a map refinement) is chained into
            # later frames: the polish, which removes the bias that chaining turns into drift, is
            # spent there. Other frames keep the first pass (about 0.01 px more error per frame,
            # far below what detection tolerates) at half the cost.
            est = polish_estimate(self._ref_gray, gray, est, **fit)
        M_small, stats = est
        M = scale_homography(M_small, scale)  # keyframe -> this frame, full-res pixels
        H = normalize(self._ref_H @ np.linalg.inv(M))
        if gap == 1:
            self._motion = normalize(M @ np.linalg.inv(scale_homography(self._M_key_last, scale)))
        elif gap > 1:
            log.info("frame %d: registered against frame %d after %d failed frames",
                     frame.index, self._ref_index, gap - 1)
        self._M_key_last = M_small
        self._good_index, self._good_time = frame.index, frame.time
        self._since_good = 0
        status = "ok"
        if refine_due:
            H, status, _ = self._refine(frame, H)
        # a new keyframe when the old one is old or mostly out of view, and after any correction
        if status == "refined" or key_due:
            self._set_keyframe(frame, gray, H, stats.points, mask)
        return Registration(frame.index, H, status, stats.inliers, stats.inlier_ratio,
                            stats.error / scale, "")

    def _sharpness(self, gray: np.ndarray) -> float | None:
        """This frame's sharpness over the median of the last :data:`SHARPNESS_FRAMES` registered
        frames' when it is under ``keyframe_blur_ratio`` (a blurred frame), else None; the frame
        joins the recent ones either way."""
        ratio = self.config.keyframe_blur_ratio
        if ratio <= 0:
            return None
        s = sharpness(gray)
        recent = self._recent_sharp
        base = float(np.median(recent)) if len(recent) >= 3 else None
        recent.append(s)
        if base is None or base <= 0 or s >= ratio * base:
            return None
        return s / base

    def _set_keyframe(self, frame: Frame, gray: np.ndarray, H: np.ndarray,
                      points: np.ndarray | None, mask: np.ndarray | None) -> None:
        """Make ``frame`` the reference later frames are registered against.

        Its features are the points tracked into it (cheap) topped up with fresh corners when
        fewer than ``keyframe_min_overlap`` of ``max_features`` are left; none inside ``mask``'s
        zeros (moving vehicles).
        """
        cfg = self.config
        pts = np.zeros((0, 2), np.float32) if points is None else np.asarray(points, np.float32)
        pts = pts.reshape(-1, 2)
        if mask is not None and len(pts):
            xi = np.clip(pts[:, 0].astype(int), 0, mask.shape[1] - 1)
            yi = np.clip(pts[:, 1].astype(int), 0, mask.shape[0] - 1)
            pts = pts[mask[yi, xi] > 0]
        if cfg.keyframe_grid or len(pts) < cfg.keyframe_min_overlap * cfg.max_features:
            pts = detect_features(gray, cfg.max_features, mask).reshape(-1, 2)
        self._ref_gray, self._ref_H, self._points = gray, normalize(H), pts
        self._ref_index, self._ref_time = frame.index, frame.time
        self._key_n = max(len(pts), 1)
        self._M_key_last = np.eye(3)

    def _anchor(self, frame: Frame, gray: np.ndarray, H: np.ndarray, status: str,
                reason: str = "", search_scale: float = 1.0,
                mask: np.ndarray | None = None) -> Registration:
        """Make ``frame`` the keyframe at ``H`` (refined against the map when there is one)."""
        if self._map_gray is not None:
            H2, st, why = self._refine(frame, H, search_scale)
            if st == "refined":
                H = H2
                status = "refined" if status == "ok" else "reanchored"
            elif status != "ok":
                reason = f"{reason}; {why}" if why else reason
        self._set_keyframe(frame, gray, H, None, mask)
        self._good_index, self._good_time = frame.index, frame.time
        self._since_good = 0
        return Registration(frame.index, normalize(H), status, 0, float("nan"), float("nan"), reason)

    def _working_map(self, frame: Frame, H: np.ndarray) -> tuple[float, float]:
        """Resample the map once so that its pixels are about the frames' ground size, and
        return working pixels per map pixel along x and y.

        The refinement's patch, search and correction sizes are pixels (``refine_*_px``), chosen
        where a map pixel is about a frame pixel on the ground. A drone orthomosaic at 5 cm
        under a video at 30 cm made the 12 px search 0.6 m and a patch a few square metres of
        asphalt; a 2 m satellite map left no room for a patch in the frame's footprint: the
        refinement never succeeded on either (a probe: a 2.5 m placement error stayed 2.5 m).
        A map up to :data:`MAP_SCALE_KEPT` times finer is used as it is, and so is a coarser
        one: upsampled, a 2 m map (video at 0.3 m) corrected a 2.5 m placement error to 0.24 m
        but with the placement right it made the error 0.24 m instead of 0.13 m and cost 0.011
        HOTA. Measured on a generated scene (300 frames, 0.3 m frame pixels) with its map
        reprojected to 5 cm (downsampled 8x): a 2.5 m placement error 2.51 -> 0.14 m median geo
        error; placed right, HOTA/MOTA 0.745/0.854 -> 0.751/0.855, geo error 0.14 m either way
        (the exact factor, 5.9: 0.12 m and 0.763/0.864; 4x: 0.13 m and 0.747/0.833).

        The factor is a power of two (4, 8, ...), so that registrars started at other frames
        (a resumed run, Dask segments) choose the same one unless the zoom changed by about
        1.4x; each axis keeps its own scale, the resized sides being whole pixels (one scale
        for both had put a tall map's refined positions several pixels off in y: a reviewer).
        """
        h, w = frame.image.shape[:2]
        J = _jacobian(H, w / 2.0, h / 2.0)
        ratio = math.sqrt(abs(float(np.linalg.det(J))))  # map pixels per frame pixel
        sx = sy = 1.0
        if math.isfinite(ratio) and ratio > MAP_SCALE_KEPT:
            f = 2.0 ** round(math.log2(ratio))
            mh, mw = self._map_gray.shape
            size = (max(1, round(mw / f)), max(1, round(mh / f)))
            self._map_gray = cv2.resize(self._map_gray, size, interpolation=cv2.INTER_AREA)
            sx, sy = size[0] / mw, size[1] / mh
            log.info("registration: the map's pixels are %.2f of a frame pixel on the ground; "
                     "refined against it downsampled %gx to %dx%d", 1 / ratio, f, *size)
        self._map_scale, self._map_scale_y = sx, sy
        return sx, sy

    def _refine(self, frame: Frame, H: np.ndarray, search_scale: float = 1.0
                ) -> tuple[np.ndarray, str, str]:
        cfg = self.config
        self._last_refine = frame.time
        kx, ky = ((self._map_scale, self._map_scale_y) if self._map_scale is not None
                  else self._working_map(frame, H))
        S = np.diag([kx, ky, 1.0])  # map pixels -> working pixels (continuous, corner origin)
        r = refine_against_map(frame.image, S @ H, self._map_gray,
                               search_px=cfg.refine_search_px * search_scale,
                               patch_px=cfg.refine_patch_px, n_patches=cfg.refine_patches,
                               bins=cfg.refine_bins,
                               max_correction_px=cfg.refine_max_correction_px * search_scale)
        if isinstance(r, Failure):
            log.debug("frame %d: %s", frame.index, r.reason)
            return H, "ok", r.reason
        return normalize(np.diag([1 / kx, 1 / ky, 1.0]) @ r[0]), "refined", ""

    def _lost(self, frame: Frame, gray: np.ndarray, reason: str, common: dict) -> Registration:
        """A frame of good quality that did not register against the reference: carried, or
        the new reference when it ends a run of ``cut_frames`` failed frames that each register
        against the one before (a scene change)."""
        cfg = self.config
        prev, self._lost_gray = self._lost_gray, gray
        if cfg.cut_frames < 2:
            return self._carry(frame, reason, bad=False)
        if prev is not None and prev.shape == gray.shape and \
                estimate_homography(prev, gray, method="lk", **common):
            self._lost_run += 1
        else:
            self._lost_run = 0
        if self._lost_run + 1 >= cfg.cut_frames:
            self._lost_gray, self._lost_run = None, 0
            return self._carry(frame, f"{reason}; scene change", bad=False, reset=True)
        return self._carry(frame, reason, bad=False)

    def _carry(self, frame: Frame, reason: str, *, bad: bool, reset: bool = False
               ) -> Registration:
        cfg = self.config
        H_last = self._H_last if self._H_last is not None else self._ref_H
        if frame.time - self._good_time <= cfg.carry_s + 1e-9:
            H = normalize(H_last @ np.linalg.inv(self._motion))
        else:
            H = H_last.copy()
        if not bad and (reset or frame.time - self._good_time >= cfg.reset_after_s - 1e-9):
            gray = to_gray(frame.image, self._scale(frame.image.shape[1]))
            self._lost_gray, self._lost_run = None, 0
            log.warning("frame %d: no registration for %.1f s (%s); new reference",
                        frame.index, frame.time - self._good_time, reason)
            self._motion = np.eye(3)
            return self._anchor(frame, gray, H, "reset", f"{reason}; new reference",
                                search_scale=3.0)
        log.info("frame %d: %s; carrying the last motion", frame.index, reason)
        return Registration(frame.index, H, "carried", 0, float("nan"), float("nan"), reason)


#: Registered frames whose median sharpness is the baseline of :meth:`FrameRegistrar._sharpness`.
SHARPNESS_FRAMES = 9
#: A blurred frame is held back from becoming the keyframe only while it shows less than this
#: share of ground the keyframe did not.
BLUR_HOLD_UNCOVERED = 0.1


#: A map whose pixels are finer than the frames' by more than this (on the ground) is
#: downsampled for the refinement (``FrameRegistrar._working_map``); the defaults were chosen
#: on maps about as fine as the frames. At 2x (generated scenes flown twice as high, placed
#: right) downsampling cost HOTA/MOTA 0.006/0.010 (0.694/0.773 -> 0.688/0.763, same run).
MAP_SCALE_KEPT = 3.0


def _jacobian(H: np.ndarray, x: float, y: float) -> np.ndarray:
    """The 2x2 derivative of the homography ``H`` at (x, y)."""
    p = H @ np.array([x, y, 1.0])
    return (H[:2, :2] * p[2] - np.outer(p[:2], H[2, :2])) / p[2] ** 2


def sharpness(gray: np.ndarray) -> float:
    """Mean absolute Laplacian of a grey image: falls to a third or less on a motion-blurred
    frame of the same view (Santiago at half size: 11.3 -> 3.9 for a 25-pixel streak)."""
    return float(np.abs(cv2.Laplacian(gray, cv2.CV_16S)).mean())


def register_frames(frames: Iterable[Frame], config: RegistrationConfig, fps: float, geomap=None,
                    H_init: np.ndarray | None = None) -> list[Registration]:
    """Register every frame of a sequence (a convenience loop over :class:`FrameRegistrar`)."""
    reg = FrameRegistrar(config, fps, geomap, H_init)
    return [reg.step(f) for f in frames]


REGISTRATION_HEADER = (["frame"] + [f"h{r}{c}" for r in range(3) for c in range(3)]
                       + ["status", "inliers", "inlier_ratio", "error", "reason"])


def write_registration_csv(path: str | Path, registrations: Iterable[Registration]) -> None:
    """Write ``registration.csv`` atomically: ``frame,h00..h22,status,inliers,inlier_ratio,error,reason``.

    ``h00..h22`` is the row-major homography frame pixels -> world (``H[2,2] = 1``); unknown
    ratios and errors are written as ``nan``.
    """
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(REGISTRATION_HEADER)
    for r in registrations:
        H = normalize(r.H)
        w.writerow([r.index] + [f"{v:.12g}" for v in H.ravel()]
                   + [r.status, int(r.inliers), f"{r.inlier_ratio:.4f}", f"{r.error:.4f}", r.reason])
    atomic_write_text(path, buf.getvalue())


def read_registration_csv(path: str | Path) -> list[Registration]:
    """Read back a ``registration.csv`` written by :func:`write_registration_csv`."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: file not found")
    out = []
    with p.open(encoding="utf-8", newline="") as fh:
        rd = csv.reader(fh)
        header = next(rd, None)
        if header is None or header[:10] != REGISTRATION_HEADER[:10]:
            raise InputError(f"{p}: not a registration.csv (header {header!r})")
        for lineno, row in enumerate(rd, start=2):
            try:
                H = np.array([float(v) for v in row[1:10]]).reshape(3, 3)
                out.append(Registration(int(row[0]), H, row[10], int(row[11]), _num(row[12]),
                                        _num(row[13]), row[14] if len(row) > 14 else ""))
            except (ValueError, IndexError):
                raise InputError(f"{p} line {lineno}: malformed row") from None
    return out


def _num(text: str) -> float:
    """A CSV number; empty means unknown (NaN), as aerotrack.outputs writes it."""
    return float(text) if text.strip() else float("nan")


def carry_placement(source, H_first: np.ndarray, start: int, geomap, fps: float,
                    config: RegistrationConfig, undistort=None, *, first: int = 1,
                    stride: int = 1) -> np.ndarray:
    """Frame ``start``'s pixels -> map pixels, from ``H_first`` (frame ``first``'s, as
    ``--map-init`` gives it for frame 1): frames ``first`` to ``start`` registered in order,
    refined against the map as in a run.

    A run of ``--frames A:B`` used to take frame 1's placement for frame A: on a generated scene
    whose camera moved 50 map pixels by frame 100, every map position of the run was 8 m off
    (and map refinement, which searches a few pixels, never caught it).

    ``stride``: register every ``stride``-th frame only (and ``start``), for a placement wanted
    quickly (the later segments of a ``--workers`` run): the registrar matches each frame against
    a keyframe up to ``keyframe_s`` old anyway, so frames a fraction of that apart chain as well."""
    registrar = FrameRegistrar(config, fps, geomap=geomap, H_init=H_first)
    H = np.asarray(H_first, np.float64)
    last = None
    for frame in source.frames(first, start, max(1, int(stride))):
        if undistort is not None:
            frame = undistort(frame)
        H = registrar.step(frame).H
        last = frame.index
    if last is not None and last != start:
        for frame in source.frames(start, start):
            if undistort is not None:
                frame = undistort(frame)
            H = registrar.step(frame).H
    return H

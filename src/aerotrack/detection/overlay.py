"""On-screen overlays: text, crosshairs and logos burned into the frames of a moving camera.

An overlay stays put on the screen while the ground moves under it, so the background, registered
to the ground, sees it move: its blobs became tracks (a caption's 26 on UAV123 truck4), and their
boxes set the scale a run without one estimates, until the truck's own tracks were dropped as too
small. :class:`OverlayFinder` finds such pixels and the detector leaves them out, as it does an
``--ignore-region``.

Between two frames of a camera that moved (``LAG_S`` apart), a ground pixel keeps its value after registration
(the previous frame warped onto this one) and changes without it, where the ground has texture;
an overlay pixel does the opposite: unchanged in the raw frames, changed after registration
wherever the overlay has contrast with what the warp brings in. A pixel that does the latter in
at least ``overlay_share`` of the frames in which the camera moved (by a decaying count over about
3 s), once the camera has moved for ``overlay_min_s``, is an overlay edge; the edges, closed over
gaps of about a glyph, are the mask. A camera that does not move gives no evidence (a fixed
camera's overlay does not move against the ground either, except where its digits change); a
vehicle the camera follows does not stay within a few grey levels for most of the frames.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import ConfigError

log = logging.getLogger(__name__)

#: Longest side of the working image (pixels): the test is about edges a few pixels wide.
WORK_PX = 640
#: Grey levels: "unchanged" in the raw frames (compression noise), "changed" after registration.
RAW_STILL = 4.0
REG_CHANGED = 25.0
#: Median displacement of the working image (pixels) for a frame to count as the camera moving,
#: against the frame ``LAG_S`` seconds before (a slow camera moves too little in one frame).
MIN_MOTION_PX = 1.5
LAG_S = 0.3
#: Decay of the counts (seconds): an overlay that appears or goes is followed.
MEMORY_S = 3.0
#: Seconds between the frames looked at (the evidence needs a second or two, not every frame).
SAMPLE_S = 0.1
#: A mark whose centre lies within this share of the frame's width or height from an edge is
#: masked in mode ``edges``.
EDGE_SHARE = 0.2
#: Where a run keeps the mask beside its cached stages (``track --from`` uses it).
OVERLAY_FILE = "overlay_mask.png"


def write_mask(path, mask: np.ndarray) -> None:
    """Save an overlay mask as a PNG (255 on the overlay), atomically."""
    import cv2

    from ..io.output import atomic_write_bytes

    ok, data = cv2.imencode(".png", np.where(mask, 255, 0).astype(np.uint8))
    if ok:
        atomic_write_bytes(path, data.tobytes())


def read_mask(path) -> np.ndarray | None:
    """The mask :func:`write_mask` saved, or None when there is none (or it is unreadable)."""
    import cv2

    from ..io.frames import cv_path

    if not Path(path).is_file():
        return None
    img = cv2.imread(cv_path(path), cv2.IMREAD_GRAYSCALE)
    return None if img is None else img > 127


class OverlayFinder:
    """Finds pixels fixed on the screen while the camera moves.

    Parameters
    ----------
    fps : float
    min_s : float
        Seconds of camera motion (decayed) before any pixel is called an overlay.
    share : float
        Share of those frames in which a pixel must behave as an overlay.
    mode : str
        ``edges``: only marks whose centre lies within ``EDGE_SHARE`` of the frame's edge are
        masked (captions, time stamps and logos sit there); a mark in the middle could be a
        vehicle the camera keeps centred, pixel for pixel, which would be lost with it (a
        synthetic follow-camera clip lost its target so): it is reported in :attr:`held`.
        ``all``: every mark, central crosshairs too.

    Attributes
    ----------
    mask : ndarray (H, W) bool or None
        Overlay pixels at full frame resolution (None while nothing is found).
    """

    def __init__(self, fps: float, min_s: float = 1.0, share: float = 0.5,
                 mode: str = "edges") -> None:
        if mode not in ("edges", "all"):
            raise ConfigError(f"config detection.overlay_mask {mode!r}: expected 'edges' or 'all'")
        self.mode = mode
        #: Boxes (x, y, w, h, frame pixels) of overlay-like marks away from the frame's edges,
        #: not masked in mode ``edges``.
        self.held: list[tuple[int, int, int, int]] = []
        self.fps = float(fps)
        self.min_s = float(min_s)
        self.share = float(share)
        self.mask: np.ndarray | None = None
        self._every = max(1, round(SAMPLE_S * self.fps))  # frames between samples
        dt = self._every / self.fps  # seconds between samples
        self._lag = max(1, round(LAG_S / dt))  # samples between the two frames compared
        self._recent: list[tuple[np.ndarray, np.ndarray | None]] = []  # the last _lag samples
        self._scale = 1.0
        self._evidence: np.ndarray | None = None  # decayed share of samples, x 255
        self._decay = float(np.exp(-dt / MEMORY_S))
        self._moving = 0.0  # decayed count of samples in which the camera moved
        self._moving_share = 0.0  # the same, as a share (the evidence's scale)
        self._min_moving = self.min_s / dt
        self._update_every = max(1, round(0.5 / dt))  # the mask, twice a second
        self._frames = 0
        self._since_update = 0
        self.changed = False  # the mask changed at the last step

    def step(self, image: np.ndarray, H: np.ndarray | None) -> None:
        """Take the next frame (BGR or grey uint8) and its registration ``H`` (frame pixels ->
        world; None: a failed registration). One frame in ``SAMPLE_S`` seconds is looked at."""
        import cv2

        self.changed = False
        self._frames += 1
        if (self._frames - 1) % self._every:
            return
        h, w = image.shape[:2]
        self._scale = min(1.0, WORK_PX / max(h, w))
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self._scale < 1.0:
            grey = cv2.resize(grey, (round(w * self._scale), round(h * self._scale)),
                              interpolation=cv2.INTER_AREA)
        H = None if H is None else np.asarray(H, np.float64)
        self._recent.append((grey, H))
        if len(self._recent) <= self._lag:
            return
        prev, prev_H = self._recent.pop(0)
        if prev_H is None or H is None or prev.shape != grey.shape:
            return
        S = np.diag([self._scale, self._scale, 1.0])
        try:
            M = S @ np.linalg.inv(H) @ prev_H @ np.linalg.inv(S)  # prev -> this frame
        except np.linalg.LinAlgError:
            return
        gh, gw = grey.shape
        pts = np.array([[x, y, 1.0] for x in np.linspace(0, gw, 5) for y in np.linspace(0, gh, 5)])
        moved = pts @ M.T
        moved = moved[:, :2] / moved[:, 2:3]
        if float(np.median(np.hypot(*(moved - pts[:, :2]).T))) < MIN_MOTION_PX:
            return
        M = M / M[2, 2]
        affine = pts[:, :2] @ M[:2, :2].T + M[:2, 2]
        if float(np.abs(affine - moved).max()) < 0.25:  # 3x faster, as good to a quarter pixel
            warped = cv2.warpAffine(prev, M[:2], (gw, gh), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REPLICATE)
        else:
            warped = cv2.warpPerspective(prev, M, (gw, gh), flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_REPLICATE)
        still = cv2.bitwise_and(cv2.compare(cv2.absdiff(grey, prev), RAW_STILL, cv2.CMP_LE),
                                cv2.compare(cv2.absdiff(grey, warped), REG_CHANGED, cv2.CMP_GE))
        if self._evidence is None or self._evidence.shape != grey.shape:
            self._evidence = np.zeros(grey.shape, np.float32)
        cv2.accumulateWeighted(still, self._evidence, 1.0 - self._decay)
        self._moving = self._moving * self._decay + 1.0
        self._moving_share = self._moving_share * self._decay + (1.0 - self._decay)
        self._since_update += 1
        if self._since_update >= self._update_every:
            self._since_update = 0
            self._update(image.shape[:2])

    def _update(self, shape: tuple[int, int]) -> None:
        import cv2

        if self._moving < self._min_moving:
            return
        edges = (self._evidence >= 255.0 * self.share * self._moving_share).astype(np.uint8)
        small = np.zeros_like(edges)
        held = []
        if edges.any():
            gap = max(3, round(0.012 * max(edges.shape)))  # a glyph or two apart
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * gap + 1, 2 * gap + 1))
            n, labels, stats, _ = cv2.connectedComponentsWithStats(cv2.dilate(edges, k))
            gh, gw = edges.shape
            f = 1.0 / self._scale
            for j in range(1, n):
                x, y, w, h, area = stats[j]
                if area < 4 * (2 * gap + 1) ** 2:  # isolated speckles are not an overlay
                    continue
                cx, cy = (x + w / 2) / gw, (y + h / 2) / gh
                border = min(cx, 1 - cx) < EDGE_SHARE or min(cy, 1 - cy) < EDGE_SHARE
                if border or self.mode == "all":
                    small[labels == j] = 1
                else:  # central: a crosshair, or a vehicle the camera keeps in the middle
                    held.append((round(x * f), round(y * f), round(w * f), round(h * f)))
        mask = cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0
        if not mask.any():
            mask = None
        self.held = held
        if (mask is None) != (self.mask is None) or (
                mask is not None and not np.array_equal(mask, self.mask)):
            self.changed = True
            if mask is not None and (self.mask is None or mask.sum() > 1.5 * self.mask.sum()):
                log.info("on-screen overlay found: %.1f%% of the frame left out of detection",
                         100.0 * mask.mean())
        self.mask = mask

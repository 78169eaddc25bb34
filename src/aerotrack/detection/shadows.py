"""Moving cast-shadow suppression: the deterministic non-model-based HSV test of Prati et al.
(PAMI 2003, "Detecting moving shadows"), the method Yu & Medioni section 3 names.

A foreground pixel ``p`` is a shadow when the background darkens without changing colour::

    alpha <= V_I(p) / V_B(p) <= beta,   |S_I(p) - S_B(p)| <= tau_S,   D_H(p) <= tau_H

where I is the frame, B the background and ``D_H`` the angular hue difference. Prati et al. use
a signed ``S_I - S_B <= tau_S``; we use the absolute difference, which behaves better on the
compressed, low-saturation colours of aerial video (a vehicle with the road's hue but a different
saturation is then not mistaken for shadow). The hue test is skipped where the frame or the
background pixel is nearly grey (saturation under 40 of 255), whose hue is noise: sunlit asphalt
is a little warm and its shadow, lit by the blue sky alone, a little blue, so their hues differ by
up to 150 degrees although neither has much colour. Prati et al. test the hue everywhere, and an
earlier version here skipped it only where both pixels were grey: the shadow of UAV123 truck4's
truck stayed in its box (mean IoU of its detections with the annotation 0.646 -> 0.691 in part
2; Santiago and generated scenes unchanged, see benchmarks/detection.py).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..types import homography_jacobian


def shadow_mask(image_bgr: np.ndarray, background_bgr: np.ndarray, *, alpha: float = 0.4,
                beta: float = 0.9, tau_s: float = 0.15, tau_h: float = 50.0,
                chroma_tolerance_px: int = 0) -> np.ndarray:
    """Pixels of ``image_bgr`` that look like a cast shadow on ``background_bgr``.

    Parameters
    ----------
    image_bgr, background_bgr : ndarray, shape (h, w, 3) uint8
        Frame and background in the same pixels.
    alpha, beta : float
        Allowed range of the brightness ratio V_I / V_B (alpha: darkest shadow; beta below 1
        so that noise on unchanged background is not called shadow).
    tau_s : float
        Largest saturation difference, on a [0, 1] scale.
    tau_h : float
        Largest hue difference, degrees.
    chroma_tolerance_px : int
        The saturation and hue tests pass when they pass at any pixel within this distance
        (chroma subsampling of compressed video); 0 tests each pixel alone, as Prati et al.

    Returns
    -------
    ndarray, shape (h, w) bool
    """
    hi = cv2.cvtColor(np.ascontiguousarray(image_bgr), cv2.COLOR_BGR2HSV_FULL).astype(np.float32)
    hb = cv2.cvtColor(np.ascontiguousarray(background_bgr), cv2.COLOR_BGR2HSV_FULL).astype(np.float32)
    ratio = (hi[..., 2] + 0.5) / (hb[..., 2] + 0.5)
    ds = np.abs(hi[..., 1] - hb[..., 1]) / 255.0
    dh = np.abs(hi[..., 0] - hb[..., 0]) * (360.0 / 256.0)
    dh = np.minimum(dh, 360.0 - dh)
    # Hue is undefined for grey pixels: do not let it veto a shadow on or into grey.
    grey = (hi[..., 1] < 40) | (hb[..., 1] < 40)
    chroma = ((ds <= tau_s) & ((dh <= tau_h) | grey)).astype(np.uint8)
    if chroma_tolerance_px > 0:
        # compressed video keeps colour at half resolution (4:2:0): next to a coloured vehicle
        # its shadow takes the vehicle's colour for a pixel or two and would fail the colour
        # test; the colour may match anywhere within the tolerance, the brightness must here
        k = 2 * int(chroma_tolerance_px) + 1
        chroma = cv2.dilate(chroma, np.ones((k, k), np.uint8))
    return (ratio >= alpha) & (ratio <= beta) & (chroma > 0)


def remove_shadows(fg: np.ndarray, image_bgr: np.ndarray, background_bgr: np.ndarray, *,
                   alpha: float = 0.4, beta: float = 0.9, tau_s: float = 0.15, tau_h: float = 50.0,
                   min_core: float = 0.4, chroma_tolerance_px: int = 0,
                   info: dict | None = None) -> np.ndarray:
    """Foreground without cast shadows, decided per connected region.

    Prati et al.'s test is per pixel, and a dark grey vehicle on lighter grey asphalt passes it
    exactly as a shadow does (the road darkened, hue and saturation unchanged): removing every
    shadow-like pixel erased dark vehicles whole (on the generated scenes, 2/3 of the missed
    vehicles). A moving cast shadow, however, is cast by a vehicle beside it, and in a nadir
    view it is smaller than the vehicle. So in each 8-connected region of ``fg`` the
    shadow-like pixels are removed only when what is left (the *core*) is at least ``min_core``
    of the region; otherwise the region is taken to be a dark vehicle (with its own shadow,
    which widens its box slightly) and kept whole. This region rule is ours, not Prati et al.'s.
    Removing the shadow before the blobs are formed also parts two vehicles joined only by the
    shadow of one of them.

    Parameters
    ----------
    fg : ndarray, shape (h, w) bool
        Foreground pixels.
    image_bgr, background_bgr : ndarray, shape (h, w, 3) uint8
        Frame and background, same pixels as ``fg``.
    alpha, beta, tau_s, tau_h, chroma_tolerance_px
        As in :func:`shadow_mask`.
    min_core : float
        Smallest fraction of a region that must remain for its shadow to be removed. Raising it
        keeps more dark vehicles but leaves more vehicles with long shadows unseparated; 0 is
        Prati et al.'s pixel test alone.
    info : dict, optional
        Filled with ``removed`` (pixels removed as shadow) and ``kept_shaded`` (shadow-like
        pixels left in regions kept whole: a dark vehicle with its shadow).

    Returns
    -------
    ndarray, shape (h, w) bool
    """
    fg = np.asarray(fg, bool)
    if info is not None:
        info.update(removed=0, kept_shaded=0)
    if not fg.any():
        return fg
    shadow = fg & shadow_mask(image_bgr, background_bgr, alpha=alpha, beta=beta, tau_s=tau_s,
                              tau_h=tau_h, chroma_tolerance_px=chroma_tolerance_px)
    if min_core <= 0:
        if info is not None:
            info["removed"] = int(shadow.sum())
        return fg & ~shadow
    n, labels = cv2.connectedComponents(fg.astype(np.uint8), connectivity=8)
    total = np.bincount(labels.ravel(), minlength=n)
    shaded = np.bincount(labels[shadow], minlength=n)
    remove = (total - shaded) >= min_core * total
    remove[0] = False
    if info is not None:
        info["removed"] = int(shaded[remove].sum())
        info["kept_shaded"] = int(shaded[1:][~remove[1:]].sum())
    return fg & ~(shadow & remove[labels])


def trim_shadow_side(boxes: np.ndarray, dark: np.ndarray, samples: list, *, min_samples: int = 2,
                     min_px: float = 0.5, keep: float = 0.5) -> np.ndarray:
    """Boxes of dark vehicles without the part their own shadow adds.

    A dark vehicle is shadow-like itself (:func:`remove_shadows` keeps its region whole), so its
    box is the box of the vehicle and its shadow. The shadow is the vehicle's footprint moved by
    the sun's offset, the same for every vehicle in the frame, so the box of the union is the
    vehicle's box grown by that offset on the shadow's sides. Where :func:`remove_shadows` did
    separate a lighter vehicle from its shadow, the difference of the two boxes measures the
    growth on each side; the frame's median growth (``min_samples`` or more vehicles) is taken
    off the boxes of the dark ones, on the sides where it exceeds ``min_px``, never shrinking a
    side of a box below ``keep`` of its length. Without such vehicles (overcast, no shadows
    removed) nothing changes. This is ours, not Prati et al.'s.

    Parameters
    ----------
    boxes : ndarray, shape (N, 4)
        x, y, w, h (frame pixels).
    dark : ndarray, shape (N,) bool
        Which boxes hold a dark vehicle with its shadow.
    samples : list of (4,) arrays
        Growth of the left, top, right and bottom sides by a removed shadow, pixels (>= 0).

    Returns
    -------
    ndarray, shape (N, 4)
    """
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    if len(samples) < min_samples or not np.any(dark):
        return boxes
    grow = np.median(np.asarray(samples, np.float64).reshape(-1, 4), axis=0)
    return trim_boxes(boxes, dark, np.broadcast_to(grow, boxes.shape), min_px=min_px, keep=keep)


def trim_boxes(boxes: np.ndarray, dark: np.ndarray, grow: np.ndarray, *, min_px: float = 0.5,
               keep: float = 0.5) -> np.ndarray:
    """The ``dark`` boxes (N, 4: x, y, w, h) less their shadow's growth ``grow`` (N, 4: left,
    top, right, bottom, pixels): sides growing by ``min_px`` or less are left, and no side of a
    box is cut below ``keep`` of its length (:func:`trim_shadow_side`). Returns a new array."""
    boxes = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    grow = np.asarray(grow, np.float64).reshape(-1, 4)
    for i in np.flatnonzero(dark):
        g = np.where(grow[i] > min_px, grow[i], 0.0)
        if not g.any():
            continue
        x, y, w, h = boxes[i]
        cut_x = min(g[0] + g[2], (1.0 - keep) * w)
        cut_y = min(g[1] + g[3], (1.0 - keep) * h)
        fx = cut_x / max(g[0] + g[2], 1e-9)
        fy = cut_y / max(g[1] + g[3], 1e-9)
        boxes[i] = [x + g[0] * fx, y + g[1] * fy, w - cut_x, h - cut_y]
    return boxes


class ShadowOffsets:
    """The sun's shadow offset, pooled over the last ``span_s`` seconds on the ground plane.

    :func:`trim_shadow_side` measures the offset in each frame from the lighter vehicles whose
    shadows were removed, and needs two of them: in a frame with fewer (a quiet road, mostly
    dark cars), a dark vehicle's box kept its shadow (the fresh generated scene static:52: half
    the frames with a dark vehicle, whose boxes then had twice their area).
    The sun does not move in minutes, so every measured growth (left, top, right, bottom) is
    kept as an offset vector ``(right - left, bottom - top)`` on the registered plane (through
    the homography's derivative at the vehicle), and a frame short of samples takes the
    median of the pool, brought back through its own homography at each dark box: the shadow
    side grows by the offset's component, the other side by nothing. Ours, not Prati et al.'s.
    """

    def __init__(self, span_s: float, min_samples: int = 5) -> None:
        self.span_s = float(span_s)
        self.min_samples = int(min_samples)
        self.times = np.zeros(0)
        self.offsets = np.zeros((0, 2))

    def clear(self) -> None:
        """Forget every sample (the registered plane changed)."""
        self.times = np.zeros(0)
        self.offsets = np.zeros((0, 2))

    def add(self, t: float, H: np.ndarray, samples: np.ndarray | None) -> None:
        """Add a frame's ``samples`` (K, 6: centre x, y and growth left, top, right, bottom,
        frame pixels; :attr:`.moving.FrameResult.shadow_samples`) taken at time ``t`` in a frame
        whose pixels ``H`` maps to the registered plane; drop samples older than the span."""
        keep = self.times >= t - self.span_s
        self.times, self.offsets = self.times[keep], self.offsets[keep]
        if samples is None or not len(samples):
            return
        s = np.asarray(samples, np.float64).reshape(-1, 6)
        o = np.stack([s[:, 4] - s[:, 2], s[:, 5] - s[:, 3]], axis=1)
        o = np.einsum("nij,nj->ni", _jacobians(H, s[:, :2]), o)
        self.times = np.concatenate([self.times, np.full(len(s), float(t))])
        self.offsets = np.concatenate([self.offsets, o])

    def growth(self, H: np.ndarray, centres: np.ndarray) -> np.ndarray | None:
        """Growth (N, 4: left, top, right, bottom, frame pixels) of boxes centred at
        ``centres`` (N, 2) in a frame whose pixels ``H`` maps to the plane; None with fewer
        than ``min_samples`` pooled samples."""
        if len(self.times) < self.min_samples:
            return None
        o = np.median(self.offsets, axis=0)
        J = _jacobians(H, centres)
        f = np.linalg.solve(J, np.broadcast_to(o, (len(J), 2))[..., None])[..., 0]
        return np.stack([np.maximum(-f[:, 0], 0), np.maximum(-f[:, 1], 0),
                         np.maximum(f[:, 0], 0), np.maximum(f[:, 1], 0)], axis=1)


def _jacobians(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2, 2) derivatives of one homography ``H`` at ``points`` (N, 2)."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    return homography_jacobian(np.broadcast_to(np.asarray(H, np.float64), (len(p), 3, 3)), p)

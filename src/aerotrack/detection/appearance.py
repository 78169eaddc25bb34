"""Appearance data of a blob: colour histogram (Yu & Medioni eq. 9) and the sufficient statistics
of the ring descriptor of section 5.2 (Figure 3).

The ring descriptor divides the blob's smallest enclosing circle into 6 rings of equal width and
8 direction sectors of 45 degrees (sector 0 starts at the frame's +x axis and turns towards +y).
For each (ring, sector) it keeps ``[n_pixels, sum_B, sum_G, sum_R, sumsq_B, sumsq_G, sumsq_R,
n_edge_pixels]`` over the blob's pixels, so statistics of many blobs of a tracklet add up and the
linker can form per-ring Gaussians (eq. 13) and edge distributions (eq. 14), made rotation
invariant by pooling each ring over its 8 sectors (``TrackletDescriptor.from_stats``).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

N_RINGS = 6
N_DIRECTIONS = 8
HIST_BINS = (8, 4, 4)  # H, S, V
HIST_SIZE = int(np.prod(HIST_BINS))


def colour_histogram(patch_bgr: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Normalised HSV histogram (8 hue x 4 saturation x 4 value bins) of a blob.

    Yu & Medioni eq. 9 concatenates RGB bins; a joint HSV histogram gives most bins to hue, the
    channel shade changes least (a choice, not measured against RGB bins).

    Parameters
    ----------
    patch_bgr : ndarray, shape (h, w, 3) uint8
        Image patch around the blob.
    mask : ndarray, shape (h, w), optional
        Nonzero on the blob's pixels (the whole patch when None).

    Returns
    -------
    ndarray, shape (128,) float64
        Sums to 1 (uniform when the mask is empty).
    """
    patch = np.ascontiguousarray(patch_bgr, dtype=np.uint8)
    if patch.size == 0:
        return np.full(HIST_SIZE, 1.0 / HIST_SIZE)
    hsv = cv2.cvtColor(patch, cv2.COLOR_BGR2HSV)
    m = None if mask is None else (np.asarray(mask) > 0).astype(np.uint8)
    hist = cv2.calcHist([hsv], [0, 1, 2], m, list(HIST_BINS), [0, 180, 0, 256, 0, 256])
    hist = hist.astype(np.float64).ravel()
    total = hist.sum()
    if total <= 0:
        return np.full(HIST_SIZE, 1.0 / HIST_SIZE)
    return hist / total


def ring_descriptor(patch_bgr: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Sufficient statistics of the Yu & Medioni 5.2 ring descriptor of one blob.

    Parameters
    ----------
    patch_bgr : ndarray, shape (h, w, 3) uint8
        Image patch containing the blob (patch pixels; the circle is found in them).
    mask : ndarray, shape (h, w), optional
        Nonzero on the blob's pixels (the whole patch when None).

    Returns
    -------
    ndarray, shape (6, 8, 8) float64
        ``[ring, direction, (n, sum_B, sum_G, sum_R, sumsq_B, sumsq_G, sumsq_R, n_edge)]``.
        Ring 0 is the innermost. Edges are Canny edges of the grey patch (thresholds from its
        median) that fall on the blob. All zeros for an empty mask.
    """
    out = np.zeros((N_RINGS, N_DIRECTIONS, 8), np.float64)
    patch = np.ascontiguousarray(patch_bgr, dtype=np.uint8)
    if patch.size == 0:
        return out
    m = np.ones(patch.shape[:2], bool) if mask is None else np.asarray(mask) > 0
    ys, xs = np.nonzero(m)
    if len(xs) == 0:
        return out
    pts = np.empty((len(xs), 2), np.float32)
    pts[:, 0] = xs
    pts[:, 1] = ys
    (cx, cy), radius = cv2.minEnclosingCircle(pts)
    radius = max(float(radius), 0.5)
    dx = xs + 0.5 - (cx + 0.5)
    dy = ys + 0.5 - (cy + 0.5)
    r = np.hypot(dx, dy)
    ring = np.minimum((r / radius * N_RINGS).astype(np.int64), N_RINGS - 1)
    ang = np.mod(np.arctan2(dy, dx), 2 * np.pi)
    sector = np.minimum((ang / (2 * np.pi) * N_DIRECTIONS).astype(np.int64), N_DIRECTIONS - 1)
    cell = ring * N_DIRECTIONS + sector
    grey = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)
    med = median_u8(grey)
    edges = cv2.Canny(grey, max(10.0, 0.66 * med), max(20.0, 1.33 * med))
    _accumulate(out.reshape(N_RINGS * N_DIRECTIONS, 8), patch, edges, ys, xs, cell)
    return out


def median_u8(values: np.ndarray) -> float:
    """``float(np.median(values))`` of non-empty uint8 values from their 256-bin histogram
    (exactly equal: the mean of the two middle values of an even count, an integer or a half in
    float64), without numpy's sort and its per-call overhead."""
    counts = np.cumsum(np.bincount(values.ravel(), minlength=256))
    n = int(counts[-1])
    lo = int(np.searchsorted(counts, (n - 1) // 2, side="right"))
    hi = int(np.searchsorted(counts, n // 2, side="right"))
    return (lo + hi) / 2.0


@njit(cache=True)
def _accumulate(out, patch, edges, ys, xs, cell):  # pragma: no cover - compiled
    """Add each blob pixel ``(ys[i], xs[i])`` to row ``cell[i]`` of ``out`` (48, 8): count,
    B, G, R sums, their squares' sums and the edge count. Every term is an integer, so the float64
    sums are exact whatever the order (the same values as one ``np.bincount`` per column)."""
    for i in range(len(ys)):
        y, x, c = ys[i], xs[i], cell[i]
        b, g, r = float(patch[y, x, 0]), float(patch[y, x, 1]), float(patch[y, x, 2])
        out[c, 0] += 1.0
        out[c, 1] += b
        out[c, 2] += g
        out[c, 3] += r
        out[c, 4] += b * b
        out[c, 5] += g * g
        out[c, 6] += r * r
        if edges[y, x] > 0:
            out[c, 7] += 1.0


def box_mask(h: int, w: int) -> np.ndarray:
    """Filled ellipse inscribed in an (h, w) box: the blob shape assumed for external boxes."""
    m = np.zeros((h, w), np.uint8)
    if h > 0 and w > 0:
        cv2.ellipse(m, ((w / 2.0 - 0.5, h / 2.0 - 0.5), (float(w), float(h)), 0.0), 255, -1)
        if not m.any():
            m[:] = 255
    return m


def describe(frame_image: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Appearance of externally given boxes (``--detections``) on their frame.

    The blob of an external box is unknown; it is taken as the ellipse inscribed in the box,
    which for a tight vehicle box leaves out most of the background in the corners.

    Parameters
    ----------
    frame_image : ndarray, shape (H, W, 3) uint8
        The BGR frame.
    boxes : ndarray, shape (N, 4)
        ``x, y, w, h`` in frame pixels (clipped to the frame).

    Returns
    -------
    hist : ndarray, shape (N, 128) float64
        Rows sum to 1 (uniform for a box entirely outside the frame).
    desc : ndarray, shape (N, 6, 8, 8) float64
        Ring-descriptor statistics (zeros for a box outside the frame).
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    H, W = frame_image.shape[:2]
    hist = np.empty((len(b), HIST_SIZE))
    desc = np.zeros((len(b), N_RINGS, N_DIRECTIONS, 8))
    for k, (x, y, w, h) in enumerate(b):
        x0, y0 = int(np.clip(np.floor(x), 0, W)), int(np.clip(np.floor(y), 0, H))
        x1, y1 = int(np.clip(np.ceil(x + w), 0, W)), int(np.clip(np.ceil(y + h), 0, H))
        patch = frame_image[y0:y1, x0:x1]
        if patch.size == 0:
            hist[k] = 1.0 / HIST_SIZE
            continue
        m = box_mask(y1 - y0, x1 - x0)
        hist[k] = colour_histogram(patch, m)
        desc[k] = ring_descriptor(patch, m)
    return hist, desc

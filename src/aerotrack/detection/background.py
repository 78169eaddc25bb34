"""Sliding-window background on registered frames (Yu & Medioni section 3).

For a reference frame ``c`` the background of each pixel ``p`` is the mode of
``{I_i(H_{c,i} p)}`` over the frames ``i`` of a window around ``c``. We estimate it with the
per-pixel **median** of a subsampled window: for a pixel that is background in most samples the
median and the mode coincide, and the median is computable with a few dozen SIMD ``min``/``max``
image operations (a pruned Batcher sorting network), which a histogram mode is not. Samples are
warped into the reference frame with ``cv2.warpPerspective`` at a reduced resolution.

Pixels a sample did not see (outside its view) or that lie under a detection are *invalid* in
that sample. An invalid value is replaced alternately (per pixel) by 0 and 255: equal numbers of
the two extremes leave the median of the valid values unchanged (at most one rank off when the
count is odd), so no per-pixel bookkeeping is needed inside the sorting network. A separate count
of valid samples says where the estimate can be trusted.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import cv2
import numpy as np

_CORNER_TO_INDEX = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
_INDEX_TO_CORNER = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])


def to_cv_homography(H: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Convert a homography between continuous frame pixels (corner origin) at full resolution
    into one between OpenCV pixel indices of images downscaled by ``scale``.

    Parameters
    ----------
    H : ndarray, shape (3, 3)
        Source frame pixels -> destination frame pixels, continuous, full resolution.
    scale : float
        Image size ratio (model / full resolution).

    Returns
    -------
    ndarray, shape (3, 3)
        For ``cv2.warpPerspective`` on the downscaled images (pixel ``[r, c]`` at index ``(c, r)``).
    """
    S = np.diag([scale, scale, 1.0])
    Si = np.diag([1.0 / scale, 1.0 / scale, 1.0])
    M = _CORNER_TO_INDEX @ S @ np.asarray(H, dtype=np.float64) @ Si @ _INDEX_TO_CORNER
    return M / M[2, 2]


@lru_cache(maxsize=64)
def median_network(n: int) -> tuple[tuple[int, int, bool, bool], ...]:
    """Comparators of a pruned Batcher odd-even merge network that puts the (lower) median of
    ``n`` values on wire ``(n - 1) // 2``.

    Returns
    -------
    tuple of (a, b, need_min, need_max)
        Apply in order: ``x[a], x[b] = min, max``; only the outputs flagged are needed later.
    """
    if n < 1:
        raise ValueError("median_network needs n >= 1")
    p2 = 1
    while p2 < n:
        p2 *= 2
    comps: list[tuple[int, int]] = []

    def merge(lo: int, length: int, r: int) -> None:
        step = r * 2
        if step < length:
            merge(lo, length, step)
            merge(lo + r, length, step)
            for i in range(lo + r, lo + length - r, step):
                comps.append((i, i + r))
        else:
            comps.append((lo, lo + r))

    def sort(lo: int, length: int) -> None:
        if length > 1:
            m = length // 2
            sort(lo, m)
            sort(lo + m, m)
            merge(lo, length, 1)

    sort(0, p2)
    # Wires >= n carry +inf: any comparator touching them is a no-op.
    comps = [(a, b) for a, b in comps if b < n]
    needed = {(n - 1) // 2}
    kept: list[tuple[int, int, bool, bool]] = []
    for a, b in reversed(comps):
        na, nb = a in needed, b in needed
        if na or nb:
            kept.append((a, b, na, nb))
            needed.update((a, b))
    return tuple(reversed(kept))


def stack_median(images: Sequence[np.ndarray]) -> np.ndarray:
    """Per-pixel (lower) median of ``n`` images of equal shape and dtype.

    Parameters
    ----------
    images : sequence of ndarray, shape (H, W) or (H, W, C)

    Returns
    -------
    ndarray
        Same shape and dtype; for even ``n`` the lower of the two middle values.
    """
    images = list(images)
    if not images:
        raise ValueError("stack_median needs at least one image")
    network = median_network(len(images))
    first = images[0]
    # The network runs on blocks of rows small enough for the CPU cache (about 96 KB per image):
    # over whole frames every min/max streams its images from memory, three times slower.
    rows = max(4, _BLOCK_BYTES // max(1, first[:1].nbytes))
    if len(images) == 1 or first.shape[0] <= rows:
        return _network_median(images, network)
    out = np.empty_like(first)
    for y0 in range(0, first.shape[0], rows):
        out[y0:y0 + rows] = _network_median([im[y0:y0 + rows] for im in images], network)
    return out


_BLOCK_BYTES = 96 * 1024


def _network_median(x: list[np.ndarray], network) -> np.ndarray:
    """The middle output of ``network`` (:func:`median_network`) run on the images ``x``."""
    for a, b, need_min, need_max in network:
        xa, xb = x[a], x[b]
        if need_min:
            x[a] = cv2.min(xa, xb)
        if need_max:
            x[b] = cv2.max(xa, xb)
    return x[(len(x) - 1) // 2]


def warp(img: np.ndarray, M: np.ndarray, size: tuple[int, int], *, nearest: bool = False,
         border=0, replicate: bool = False) -> np.ndarray:
    """``cv2.warpPerspective`` that skips the work for an identity warp (a static or stabilised
    camera); returns a new array."""
    w, h = size
    if img.shape[1] == w and img.shape[0] == h and np.allclose(M, np.eye(3), atol=1e-9):
        return img.copy()
    mode = cv2.BORDER_REPLICATE if replicate else cv2.BORDER_CONSTANT
    if img.ndim == 3 and np.isscalar(border):
        border = (border,) * 3
    return cv2.warpPerspective(img, M, (w, h), flags=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                               borderMode=mode, borderValue=border)


def box_polygons(boxes: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """(K, 4, 2) corner polygons of (K, 4) ``x, y, w, h`` index boxes grown by ``pad`` pixels."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    x0, y0 = b[:, 0] - 0.5 - pad, b[:, 1] - 0.5 - pad
    x1, y1 = b[:, 0] + b[:, 2] - 0.5 + pad, b[:, 1] + b[:, 3] - 0.5 + pad
    return np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1),
                     np.stack([x1, y1], 1), np.stack([x0, y1], 1)], axis=1)


def warp_polygons(polys, M: np.ndarray) -> list[np.ndarray]:
    """Apply a 3x3 homography to a sequence of (P, 2) polygons."""
    return [cv2.perspectiveTransform(np.asarray(p, np.float64).reshape(-1, 1, 2), M).reshape(-1, 2)
            for p in polys]


def _fill(img: np.ndarray, polys, value) -> None:
    if polys is not None and len(polys):
        pts = [np.round(np.asarray(q) * 4).astype(np.int32) for q in polys
               if np.all(np.isfinite(q))]
        if pts:
            cv2.fillPoly(img, pts, value, lineType=cv2.LINE_8, shift=2)


def window_background(
    samples: Sequence[np.ndarray],
    to_ref: Sequence[np.ndarray],
    holes: Sequence[np.ndarray | None],
    size: tuple[int, int],
    ref_holes: np.ndarray | None = None,
    ref_holes_for: Sequence[bool] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Median background of warped samples and the number of valid samples per pixel.

    Parameters
    ----------
    samples : sequence of ndarray, shape (h, w, 3) uint8
        Downscaled sample frames, each in its own pixels.
    to_ref : sequence of ndarray, shape (3, 3)
        OpenCV homographies (pixel indices at model resolution) sample -> reference frame.
    holes : sequence of (list of (P, 2) ndarray) or None
        Per sample, polygons (sample pixels) that must not vote: its own detections.
    size : (int, int)
        (width, height) of the reference frame at model resolution.
    ref_holes : list of (P, 2) ndarray, optional
        Polygons in reference pixels left out of the samples flagged in ``ref_holes_for``
        (where vehicles were last seen, for samples whose own detections are not known yet).
    ref_holes_for : sequence of bool, optional

    Returns
    -------
    background : ndarray, shape (H, W, 3) uint8
        Reference-frame pixels; meaningless where ``count`` is 0.
    count : ndarray, shape (H, W) uint8
        Number of samples that saw each pixel and were valid there.

    Notes
    -----
    Samples are warped bilinearly. Nearest-neighbour is a third cheaper and scored the same on
    moving vehicles, but let the edges of a stopped vehicle leak past the detection masks into
    the median, so that it was absorbed (tests/test_detection.py). Validity is rasterised from
    polygons (the warped frame outline minus the warped detection boxes) instead of warping
    masks: one image warp per sample instead of two.
    """
    warped = warp_samples(samples, to_ref, holes, size, ref_holes, ref_holes_for)
    return subset_median(warped, range(len(warped)), size, copy=False)


def warp_samples(
    samples: Sequence[np.ndarray],
    to_ref: Sequence[np.ndarray],
    holes: Sequence[np.ndarray | None],
    size: tuple[int, int],
    ref_holes: np.ndarray | None = None,
    ref_holes_for: Sequence[bool] | None = None,
    exposure_ref: np.ndarray | None = None,
    exposure_tolerance: float = 0.04,
    mask: np.ndarray | None = None,
) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """The samples of :func:`window_background` warped into the reference frame, with their
    validity; several window medians (:func:`subset_median`) can then share the warps.

    With ``exposure_ref`` (the reference frame, same size as the warped samples) a sample whose
    exposure (:func:`exposure_gain`) differs from the reference's by more than
    ``exposure_tolerance`` is scaled to it, so that the median ranks the samples by their noise
    and not by the camera's auto-exposure.

    ``mask`` (uint8, the samples' own pixels, 0 where not to use them: a burned-in caption fixed
    on the screen) makes those pixels of every sample invalid.

    Returns
    -------
    list of (image, valid)
        ``image`` (H, W, 3) uint8 in reference pixels; ``valid`` (H, W) uint8, 1 where the
        sample saw the pixel and it is not under a hole.
    """
    w, h = size
    out = []
    ref_small = None
    if exposure_ref is not None:
        ref_small = _exposure_grey(exposure_ref)
    for k, (img, M) in enumerate(zip(samples, to_ref)):
        sh, sw = img.shape[:2]
        wimg = warp(img, M, (w, h))
        valid = np.zeros((h, w), np.uint8)
        outline = box_polygons(np.array([[0.5, 0.5, sw - 1.0, sh - 1.0]]))
        _fill(valid, warp_polygons(outline, M), 1)
        polys = []
        if holes[k] is not None and len(holes[k]):
            polys.extend(warp_polygons(holes[k], M))
        if ref_holes is not None and len(ref_holes) and (ref_holes_for is None or ref_holes_for[k]):
            polys.extend(ref_holes)
        _fill(valid, polys, 0)
        if mask is not None and mask.shape == (sh, sw):
            valid = cv2.bitwise_and(valid, (warp(mask, M, (w, h), nearest=True) > 0)
                                    .astype(np.uint8))
        if ref_small is not None:
            g = exposure_gain(ref_small, wimg, valid)
            if abs(g - 1.0) > exposure_tolerance:
                wimg = cv2.convertScaleAbs(wimg, alpha=g)
        out.append((wimg, valid))
    return out


def _quarter(img: np.ndarray) -> np.ndarray:
    """Every fourth pixel of every fourth row (nearest-neighbour decimation)."""
    h, w = img.shape[:2]
    return cv2.resize(img, (max(1, w // 4), max(1, h // 4)), interpolation=cv2.INTER_NEAREST)


def _exposure_grey(img: np.ndarray) -> np.ndarray:
    """Grey level of every fourth pixel of every fourth row, float32 (block means of these are
    as good as of all pixels for a global exposure, at a sixteenth of the cost)."""
    sub = _quarter(img)
    grey = cv2.cvtColor(sub, cv2.COLOR_BGR2GRAY) if sub.ndim == 3 else sub
    return grey.astype(np.float32)


def exposure_gain(ref_grey: np.ndarray, img: np.ndarray, valid: np.ndarray,
                  block: int = 12) -> float:
    """Exposure of the reference relative to a warped sample: the median over blocks of the
    ratio of their mean grey levels, over the blocks the sample saw whole and outside its
    holes (``ref_grey`` from :func:`_exposure_grey`; ``block`` in its pixels, 4 frame pixels
    each; the rows and columns that do not fill a block are left out). The median over blocks
    leaves out those where a vehicle is in one image and not the other. 1.0 when fewer than 4
    blocks qualify."""
    hh, ww = ref_grey.shape
    gh, gw = hh // block, ww // block
    if gh * gw < 4:
        return 1.0
    gi = _exposure_grey(img)
    v = _quarter(valid).astype(np.float32)

    # block means: an area resize by a whole factor is the box average
    stack = cv2.merge([ref_grey * v, gi * v, v])[:gh * block, :gw * block]
    mr, mi, mv = cv2.split(cv2.resize(stack, (gw, gh), interpolation=cv2.INTER_AREA))
    ok = (mv > 0.95) & (mi > 8.0) & (mr > 8.0)
    if int(ok.sum()) < 4:
        return 1.0
    return float(np.median(mr[ok] / mi[ok]))


def subset_median(warped: Sequence[tuple[np.ndarray, np.ndarray]], which: Sequence[int],
                  size: tuple[int, int], copy: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Median background and valid count (see :func:`window_background`) of the warped samples
    ``warped[k]`` for ``k`` in ``which``; ``copy`` False pads the images of ``warped`` in place
    (when they are not used again).

    An invalid value is replaced alternately (per pixel) by 0 and 255: equal numbers of the two
    extremes leave the median of the valid values unchanged (at most one rank off).
    """
    w, h = size
    count = np.zeros((h, w), np.uint8)
    parity = np.zeros((h, w), np.uint8)  # per pixel: next pad is 0 (0) or 255 (255)
    images = []
    for k in which:
        wimg, valid = warped[k]
        invalid = cv2.compare(valid, 0, cv2.CMP_EQ)
        if cv2.countNonZero(invalid):
            if copy:
                wimg = wimg.copy()
            # Pads alternate per pixel, so every pixel gets as many 0s as 255s (+-1).
            cv2.copyTo(cv2.merge([parity, parity, parity]), invalid, wimg)
            parity = cv2.bitwise_xor(parity, invalid)
        count = cv2.add(count, valid)
        images.append(wimg)
    if not images:
        return np.zeros((h, w, 3), np.uint8), count
    return stack_median(images), count

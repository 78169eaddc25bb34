"""Refinement of a rough frame-to-map homography against the map (Yu & Medioni section 2, step 2).

The frame is warped into map pixels by the rough homography (chained frame-to-frame motion), patch
correspondences between the warped frame and the map are found by maximising mutual information
(the paper's choice: the map is imagery of another date, sensor and illumination, so grey levels
are related by an unknown, not necessarily monotonic, mapping), and a homography is fitted to
them by RANSAC. The refined homography replaces the chained one, so drift does not accumulate.

The paper defers the details to its reference [8]; choices made here: grey levels are quantised by
quantiles of each image (equal-population bins, so contrast, gamma and colour shifts do not empty
bins); the search is coarse to fine over a 2x pyramid; the sub-pixel offset is the vertex of a
parabola through the mutual-information peak and its neighbours; textureless patches are skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..types import Failure, apply_homography
from .chain import frame_corners, normalize


@dataclass(frozen=True)
class RefineStats:
    """Quality figures of one map refinement.

    Attributes
    ----------
    inliers, tentative : int
        Patch correspondences consistent with the refined homography / found.
    inlier_ratio : float
    error : float
        Median residual of the inlier correspondences, map pixels.
    correction_px : float
        Mean displacement of the frame's corners between the rough and the refined homography,
        map pixels (the drift removed).
    """

    inliers: int
    tentative: int
    inlier_ratio: float
    error: float
    correction_px: float


def quantize(gray: np.ndarray, valid: np.ndarray | None, bins: int) -> np.ndarray:
    """Grey levels -> bin indices 0..bins-1 by the quantiles of the valid pixels (uint8).

    The quantiles (``numpy.quantile``'s linear interpolation between order statistics) are read
    from the 256-bin histogram, and the image is mapped through a 256-entry table: the same
    result as ``searchsorted(quantile(gray[valid]), gray)`` at a fraction of the cost.
    """
    hist = np.bincount((gray[valid] if valid is not None else gray).ravel().astype(np.intp),
                       minlength=256)
    n = int(hist.sum())
    if n == 0:
        return np.zeros(gray.shape, np.uint8)
    cum = np.cumsum(hist)
    pos = np.linspace(0, 1, bins + 1)[1:-1] * (n - 1)
    lo = np.floor(pos)
    t = pos - lo
    a = np.searchsorted(cum, lo, side="right").astype(np.float64)  # order statistic lo
    b = np.searchsorted(cum, np.minimum(lo + 1, n - 1), side="right").astype(np.float64)
    diff = b - a
    edges = np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)  # numpy's _lerp
    lut = np.searchsorted(edges, np.arange(256), side="right").astype(np.uint8)
    return cv2.LUT(gray, lut) if gray.dtype == np.uint8 else lut[gray]


@lru_cache(maxsize=8)
def _xlogx(n: int) -> np.ndarray:
    """``k log k`` for k = 0..n (0 log 0 = 0)."""
    k = np.arange(n + 1, dtype=np.float64)
    out = np.zeros(n + 1)
    out[1:] = k[1:] * np.log(k[1:])
    return out


def mutual_information_surface(template: np.ndarray, search: np.ndarray, bins: int,
                               valid: np.ndarray | None = None) -> np.ndarray:
    """Mutual information between a template and every same-size window of a search area.

    Parameters
    ----------
    template : (p, q) uint8
        Bin indices (0..bins-1) of the template.
    search : (p + 2r, q + 2s) uint8
        Bin indices of the search area.
    bins : int
    valid : (p, q) bool, optional
        Template pixels to use.

    Returns
    -------
    (2r + 1, 2s + 1) float64
        MI in nats for each offset ``(dy, dx)`` of the window from the search area's top-left.
    """
    p, q = template.shape
    win = sliding_window_view(search, (p, q))  # (2r+1, 2s+1, p, q), a view
    ny, nx = win.shape[:2]
    k = ny * nx
    # joint bin index of every (offset, pixel) pair; 16-bit while it fits (a third of the cost)
    dt = np.uint16 if k * bins * bins <= np.iinfo(np.uint16).max else np.intp
    t = template.ravel().astype(dt)
    w = win.reshape(k, p * q)
    if valid is not None and not valid.all():
        keep = np.flatnonzero(valid.ravel())
        t, w = t[keep], w[:, keep]
    n = t.size
    if n == 0:
        return np.zeros((ny, nx))
    joint_idx = w.astype(dt) * dt(bins) + t + (np.arange(k, dtype=dt) * dt(bins * bins))[:, None]
    joint = np.bincount(joint_idx.ravel(), minlength=k * bins * bins).reshape(k, bins, bins)
    # MI from integer counts: (sum c log c - sum cw log cw - sum ct log ct) / n + log n
    xlx = _xlogx(n)
    cw = joint.sum(axis=2)
    ct = np.bincount(t, minlength=bins)
    mi = (xlx[joint].sum(axis=(1, 2)) - xlx[cw].sum(axis=1) - xlx[ct].sum()) / n + math.log(n)
    return mi.reshape(ny, nx)


def _subpixel(surface: np.ndarray, iy: int, ix: int) -> tuple[float, float]:
    """Parabola vertex around the integer peak (offsets in [-0.5, 0.5])."""
    def vertex(a, b, c):
        den = a - 2 * b + c
        return 0.0 if den >= 0 else float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
    dy = vertex(surface[iy - 1, ix], surface[iy, ix], surface[iy + 1, ix])
    dx = vertex(surface[iy, ix - 1], surface[iy, ix], surface[iy, ix + 1])
    return dy, dx


def _match_patch(warped_q: np.ndarray, valid: np.ndarray, map_q: np.ndarray, cy: float, cx: float,
                 prior: tuple[float, float], radius: int, half: int, bins: int
                 ) -> tuple[float, float, float] | None:
    """Offset (dy, dx) of the map content under a warped-frame patch centred at (cy, cx)."""
    y0, x0 = int(round(cy)) - half, int(round(cx)) - half
    H, W = warped_q.shape
    if y0 < 0 or x0 < 0 or y0 + 2 * half > H or x0 + 2 * half > W:
        return None
    vt = valid[y0:y0 + 2 * half, x0:x0 + 2 * half]
    if np.count_nonzero(vt) < 0.95 * vt.size:
        return None
    tmpl = warped_q[y0:y0 + 2 * half, x0:x0 + 2 * half]
    py, px = int(round(prior[0])), int(round(prior[1]))
    sy0, sx0 = y0 + py - radius, x0 + px - radius
    sy1, sx1 = y0 + py + 2 * half + radius, x0 + px + 2 * half + radius
    if sy0 < 0 or sx0 < 0 or sy1 > map_q.shape[0] or sx1 > map_q.shape[1]:
        return None
    surf = mutual_information_surface(tmpl, map_q[sy0:sy1, sx0:sx1], bins, vt)
    iy, ix = np.unravel_index(int(np.argmax(surf)), surf.shape)
    if iy in (0, surf.shape[0] - 1) or ix in (0, surf.shape[1] - 1):
        return None  # peak on the border: the true offset may lie outside the search
    fy, fx = _subpixel(surf, iy, ix)
    # distinctiveness: the peak must stand out from the rest of the surface
    peak = surf[iy, ix]
    flat = surf.ravel()  # (2r+1)^2 offsets, an odd count: the middle order statistic is the median
    med = float(np.partition(flat, flat.size // 2)[flat.size // 2])
    if peak - med < 0.05:
        return None
    return py + iy - radius + fy, px + ix - radius + fx, peak - med


def refine_against_map(
    frame_img: np.ndarray,
    H_rough: np.ndarray,
    map_img: np.ndarray,
    *,
    search_px: float = 12.0,
    patch_px: int = 48,
    n_patches: int = 48,
    bins: int = 16,
    ransac_threshold: float = 1.5,
    min_inliers: int = 8,
    max_correction_px: float = 40.0,
) -> tuple[np.ndarray, RefineStats] | Failure:
    """Refine a frame-to-map homography by mutual-information patch matching against the map.

    Parameters
    ----------
    frame_img : (h, w, 3) or (h, w) uint8
        The frame, full resolution (BGR or grey).
    H_rough : (3, 3)
        Rough homography frame pixels -> map pixels (chained motion).
    map_img : (Hm, Wm, 3) or (Hm, Wm) uint8
        The map raster (BGR or grey), map pixels.
    search_px : float
        Largest correction looked for, map pixels (the drift since the last refinement). The
        search is coarse to fine, so its cost grows slowly with it; false peaks grow faster.
    patch_px : int
        Patch side, map pixels. Bigger patches give steadier MI peaks but fewer of them fit in the
        footprint and they average more perspective error.
    n_patches : int
        Most textured patches used (from a grid over the footprint).
    bins : int
        Grey-level bins of the joint histogram.
    ransac_threshold : float
        RANSAC inlier threshold, map pixels.
    min_inliers : int
        Fewer inlier correspondences is a failure.
    max_correction_px : float
        A result moving the frame's corners by more than this (mean, map pixels) is rejected.

    Returns
    -------
    (H, RefineStats) or Failure
        ``H`` (3, 3) frame pixels -> map pixels, ``H[2, 2] = 1``.
    """
    H_rough = normalize(H_rough)
    fgray = frame_img if frame_img.ndim == 2 else cv2.cvtColor(frame_img, cv2.COLOR_BGR2GRAY)
    mgray = map_img if map_img.ndim == 2 else cv2.cvtColor(map_img, cv2.COLOR_BGR2GRAY)
    h, w = fgray.shape
    corners = apply_homography(H_rough, frame_corners(w, h))
    if not np.all(np.isfinite(corners)):
        return Failure("map refinement: rough homography is not finite")
    half = patch_px // 2
    levels = max(1, int(math.ceil(math.log2(max(search_px, 1.0) / 4.0))) + 1)
    top = 2 ** (levels - 1)
    margin = int(math.ceil(search_px + 4 * top + 2))
    x0 = max(int(np.floor(corners[:, 0].min())) - margin, 0)
    y0 = max(int(np.floor(corners[:, 1].min())) - margin, 0)
    x1 = min(int(np.ceil(corners[:, 0].max())) + margin, mgray.shape[1])
    y1 = min(int(np.ceil(corners[:, 1].max())) + margin, mgray.shape[0])
    if x1 - x0 < 2 * patch_px or y1 - y0 < 2 * patch_px:
        return Failure("map refinement: frame footprint lies (mostly) outside the map")
    # frame -> ROI of the map, at map resolution; blur first when that shrinks the frame
    # OpenCV warps pixel indices (centre at integer coordinates); H_rough maps continuous pixels
    # (origin at the top-left corner): frame index -> continuous (+0.5) -> map -> ROI index
    T = np.array([[1, 0, -x0 - 0.5], [0, 1, -y0 - 0.5], [0, 0, 1]], dtype=np.float64)
    Hw = T @ H_rough @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]], dtype=np.float64)
    shrink = math.sqrt(abs(np.linalg.det(Hw[:2, :2] / Hw[2, 2])))
    if shrink < 0.7:
        fgray = cv2.GaussianBlur(fgray, (0, 0), 0.5 / shrink)
    size = (x1 - x0, y1 - y0)
    warped = cv2.warpPerspective(fgray, Hw, size, flags=cv2.INTER_LINEAR)
    # the frame's footprint, rasterised from its corners (ROI pixel indices, 1/16 px precision)
    # rather than warped: one warp instead of two
    outline = corners - [x0 + 0.5, y0 + 0.5]
    valid = np.zeros((size[1], size[0]), np.uint8)
    cv2.fillConvexPoly(valid, np.round(outline * 16).astype(np.int32), 1, lineType=cv2.LINE_8,
                       shift=4)
    valid = cv2.erode(valid, np.ones((3, 3), np.uint8)).astype(bool)
    mroi = mgray[y0:y1, x0:x1]
    # pyramid of quantised images, finest first
    pyr = []
    wimg, mimg, vimg = warped, mroi, valid
    for lvl in range(levels):
        nb = bins if lvl == 0 else max(8, bins // 2)  # coarse patches hold fewer pixels
        pyr.append((quantize(wimg, vimg, nb), vimg, quantize(mimg, None, nb), nb))
        if lvl + 1 < levels:
            wimg, mimg = cv2.pyrDown(wimg), cv2.pyrDown(mimg)
            vimg = cv2.resize(vimg.astype(np.uint8), (wimg.shape[1], wimg.shape[0]),
                              interpolation=cv2.INTER_NEAREST).astype(bool)
            vimg = cv2.erode(vimg.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    centres = _pick_patches(warped, valid, half, margin, n_patches)
    if len(centres) < min_inliers:
        return Failure(f"map refinement: too few textured patches ({len(centres)})")
    src, dst = [], []
    for cy, cx in centres:
        prior = (0.0, 0.0)
        result = None
        for lvl in range(levels - 1, -1, -1):
            f = 2 ** lvl
            wq, vq, mq, nb = pyr[lvl]
            radius = int(math.ceil(search_px / f)) + 1 if lvl == levels - 1 else 2
            # the same ground footprint at every level (a bigger coarse patch would leave the frame)
            result = _match_patch(wq, vq, mq, cy / f, cx / f, (prior[0] / f, prior[1] / f),
                                  radius, max(8, half // f), nb)
            if result is None:
                break
            prior = (result[0] * f, result[1] * f)
        if result is None:
            continue
        src.append((cx + x0 + 0.5, cy + y0 + 0.5))  # ROI index -> continuous map pixels
        dst.append((cx + x0 + 0.5 + prior[1], cy + y0 + 0.5 + prior[0]))
    n = len(src)
    if n < min_inliers:
        return Failure(f"map refinement: too few patch matches ({n} < {min_inliers})")
    src_map = np.asarray(src, dtype=np.float64)
    dst_map = np.asarray(dst, dtype=np.float64)
    src_frame = apply_homography(np.linalg.inv(H_rough), src_map)
    H, inl = cv2.findHomography(src_frame, dst_map, cv2.RANSAC, ransac_threshold,
                                maxIters=2000, confidence=0.999)
    if H is None or inl is None:
        return Failure("map refinement: no homography fits the patch matches")
    inl = inl.ravel().astype(bool)
    k = int(inl.sum())
    if k < min_inliers:
        return Failure(f"map refinement: too few inliers ({k} < {min_inliers})")
    H = normalize(H)
    res = np.linalg.norm(apply_homography(H, src_frame[inl]) - dst_map[inl], axis=1)
    moved = float(np.mean(np.linalg.norm(apply_homography(H, frame_corners(w, h)) - corners, axis=1)))
    if not np.isfinite(moved) or moved > max_correction_px:
        return Failure(f"map refinement: correction too large ({moved:.1f} map px)")
    return H, RefineStats(inliers=k, tentative=n, inlier_ratio=k / n, error=float(np.median(res)),
                          correction_px=moved)


def _pick_patches(warped: np.ndarray, valid: np.ndarray, half: int, margin: int,
                  n: int) -> list[tuple[float, float]]:
    """Centres (row, col) of the ``n`` most textured fully valid patches on a grid."""
    H, W = warped.shape
    lo_y, hi_y = margin + half, H - margin - half
    lo_x, hi_x = margin + half, W - margin - half
    if hi_y <= lo_y or hi_x <= lo_x:
        return []
    area = (hi_y - lo_y) * (hi_x - lo_x)
    step = max(half, int(math.sqrt(area / (3.0 * n))))
    gx = cv2.Sobel(warped, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(warped, cv2.CV_32F, 0, 1, ksize=3)
    energy = cv2.integral(gx * gx + gy * gy, sdepth=cv2.CV_64F)
    vint = cv2.integral(valid.astype(np.uint8))
    cands = []
    for cy in range(lo_y, hi_y + 1, step):
        for cx in range(lo_x, hi_x + 1, step):
            ya, yb, xa, xb = cy - half, cy + half, cx - half, cx + half
            nv = vint[yb, xb] - vint[ya, xb] - vint[yb, xa] + vint[ya, xa]
            if nv < 0.95 * (2 * half) ** 2:
                continue
            e = energy[yb, xb] - energy[ya, xb] - energy[yb, xa] + energy[ya, xa]
            cands.append((float(e), float(cy), float(cx)))
    cands.sort(reverse=True)
    return [(cy, cx) for _, cy, cx in cands[:n]]

"""What differs from the background, and how much of it is noise (Yu & Medioni section 3).

The residual of a registered frame against its background is the largest absolute channel
difference, with a small registration tolerance (:func:`residual_image`) and optionally smoothed
before the channels are compared (:func:`smoothed_residual`); its noise level
(:func:`robust_sigma`) sets the detection threshold. :func:`gain_normalise` brings the background
to the frame's local illumination first, and :func:`ghost_score` tells a vehicle's blob from the
imprint a vehicle left in the background. All images are at model resolution unless a
function says otherwise.
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def gain_normalise(image: np.ndarray, bg: np.ndarray, block: float) -> np.ndarray:
    """Background rescaled by the frame's local gain (illumination, auto-exposure).

    The gain is the ratio of block means of the frame and the background, median-filtered over
    3x3 blocks so that one dark vehicle does not change the gain of its block much.

    Returns
    -------
    ndarray, same shape as ``bg``, uint8
    """
    h, w = image.shape[:2]
    if block <= 1:
        return bg
    gw, gh = max(1, int(round(w / block))), max(1, int(round(h / block)))
    # Both block means from one 2-channel area resize (channels are resized independently, so the
    # values are those of two calls; the resize's fixed cost, most of it at this output size, is
    # paid once).
    gi, gb = cv2.split(cv2.resize(cv2.merge([cv2.cvtColor(image, cv2.COLOR_BGR2GRAY),
                                             cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY)]),
                                  (gw, gh), interpolation=cv2.INTER_AREA))
    gain = (gi.astype(np.float32) + 4.0) / (gb.astype(np.float32) + 4.0)
    if gw >= 3 and gh >= 3:
        gain = cv2.medianBlur(gain, 3)
    gain = np.clip(gain, 0.5, 2.0)
    gain = cv2.resize(gain, (w, h), interpolation=cv2.INTER_LINEAR)
    # products are >= 0: capping at 255 and truncating (the cast on assignment) is numpy's
    # clip(0, 255).astype(uint8); in blocks of rows, whose float products stay in the CPU cache
    out = np.empty_like(bg)
    for y0 in range(0, h, 32):
        g = gain[y0:y0 + 32]
        prod = cv2.multiply(bg[y0:y0 + 32], cv2.merge([g, g, g]), dtype=cv2.CV_32F)
        out[y0:y0 + 32] = np.minimum(prod, 255.0, out=prod)
    return out


def border_fill_mask(image: np.ndarray, level: int = 12) -> np.ndarray:
    """Near-black regions touching the image border (the fill of stabilised or warped video),
    dilated by one pixel; (H, W) bool. Dark vehicles inside the image are not affected."""
    dark = channel_max(image) < level
    if not (dark[0].any() or dark[-1].any() or dark[:, 0].any() or dark[:, -1].any()):
        return np.zeros(dark.shape, bool)
    # a ring of "dark" around the image joins every dark region touching the border; one flood
    # fill from the ring marks them all (8-connected), ~9x faster than labelling every component
    m = cv2.copyMakeBorder(dark.astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=1)
    cv2.floodFill(m, None, (0, 0), 2, flags=8)
    m = (m[1:-1, 1:-1] == 2).astype(np.uint8)
    return cv2.dilate(m, np.ones((3, 3), np.uint8)) > 0


def ghost_score(small: np.ndarray, bg: np.ndarray, mask: np.ndarray) -> float:
    """Ratio of the frame's to the background's gradient energy over a blob (model pixels).

    The energy is summed over the blob's outline (a 4-pixel band around its border): a real
    vehicle's outline is an edge of the frame (ratio > 1); a *ghost*, the imprint of a vehicle
    that sat in most of the window but is not at this place in the frame, has its outline in the
    background only (ratio < 1). The interior is left out because a flat-coloured vehicle on
    textured ground has less gradient inside than the ground it covers.
    """
    m8 = mask.astype(np.uint8)
    k = np.ones((3, 3), np.uint8)
    mask = cv2.dilate(m8, k, iterations=2) > cv2.erode(m8, k)
    gi = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(np.float32)
    gb = cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY).astype(np.float32)
    ei = np.abs(cv2.Sobel(gi, cv2.CV_32F, 1, 0)) + np.abs(cv2.Sobel(gi, cv2.CV_32F, 0, 1))
    eb = np.abs(cv2.Sobel(gb, cv2.CV_32F, 1, 0)) + np.abs(cv2.Sobel(gb, cv2.CV_32F, 0, 1))
    return float((ei[mask].sum() + 1.0) / (eb[mask].sum() + 1.0))


def residual_image(image: np.ndarray, bg: np.ndarray, tolerance_px: int = 0) -> np.ndarray:
    """Per-pixel largest absolute channel difference, (H, W) uint8.

    With ``tolerance_px`` = r > 0 the difference is taken to the nearest value of the background
    in a (2r+1)^2 neighbourhood (``max(I - dilate(B), erode(B) - I, 0)``): sub-pixel registration
    error and the blur of warping then leave no residual on sharp edges such as lane markings,
    while a vehicle larger than the neighbourhood still differs inside.
    """
    if tolerance_px <= 0:
        return channel_max(cv2.absdiff(image, bg))
    k = np.ones((2 * tolerance_px + 1,) * 2, np.uint8)
    d = cv2.add(cv2.subtract(image, cv2.dilate(bg, k)), cv2.subtract(cv2.erode(bg, k), image))
    return channel_max(d)


def smoothed_residual(image: np.ndarray, bg: np.ndarray, tolerance_px: int = 1,
                      sigma_px: float = 0.0) -> np.ndarray:
    """Residual of :func:`residual_image` whose *signed* per-channel difference is low-pass
    filtered before the largest absolute channel is taken, (H, W) uint8.

    A vehicle is a coherent difference over many pixels while sensor and compression noise is
    not: a Gaussian of ``sigma_px`` pixels cuts the noise by roughly ``2 sqrt(pi) sigma`` and keeps
    the difference inside regions wider than the kernel, so that dark vehicles on dark asphalt
    (a difference of a few grey levels per pixel) rise above the threshold. ``sigma_px`` = 0 is
    :func:`residual_image`.
    """
    if sigma_px <= 0:
        return residual_image(image, bg, tolerance_px)
    if tolerance_px > 0:
        k = np.ones((2 * tolerance_px + 1,) * 2, np.uint8)
        pos = cv2.subtract(image, cv2.dilate(bg, k))
        neg = cv2.subtract(cv2.erode(bg, k), image)
    else:
        pos = cv2.subtract(image, bg)
        neg = cv2.subtract(bg, image)
    d = cv2.subtract(pos, neg, dtype=cv2.CV_16S)
    d = cv2.GaussianBlur(d, (0, 0), sigma_px)
    return channel_max(cv2.convertScaleAbs(d))


def pad0(m: np.ndarray, n: int) -> np.ndarray:
    """``np.pad(m, n)`` of a 2-D uint8 image (zeros around it) at a tenth of the cost."""
    return cv2.copyMakeBorder(m, n, n, n, n, cv2.BORDER_CONSTANT, value=0)


def channel_max(img: np.ndarray) -> np.ndarray:
    """Largest channel of an (H, W, 3) image (OpenCV: numpy's axis-2 max is ~20x slower)."""
    if img.ndim == 2:
        return img
    b, g, r = cv2.split(img)
    return cv2.max(cv2.max(b, g), r)


def _half_normal_quantile(p: float) -> float:
    """``Phi^-1((1 + p) / 2)``: the p-quantile of |N(0, 1)| (bisection on erf)."""
    lo, hi = 0.0, 10.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if math.erf(mid / math.sqrt(2.0)) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def robust_sigma(residual: np.ndarray, valid: np.ndarray | None = None,
                 quantile: float = 0.9) -> float:
    """Noise level of a uint8 residual over the valid pixels, grey levels.

    The ``quantile`` of the residual divided by that of a half-normal distribution (1.645 for
    0.9). A high quantile rather than the median (1.4826 MAD): the residual with registration
    tolerance is 0 on most pixels, so its median says nothing about the noise. The quantile is
    interpolated inside the integer histogram bins (bin ``k`` spans ``[k - 0.5, k + 0.5)``).
    """
    hist = cv2.calcHist([residual], [0], None if valid is None else valid, [256], [0, 256]).ravel()
    total = hist.sum()
    if total <= 0:
        return 0.0
    cum = np.cumsum(hist)
    target = quantile * total
    k = int(np.searchsorted(cum, target))
    below = cum[k - 1] if k > 0 else 0.0
    frac = (target - below) / max(hist[k], 1.0)
    q = max(0.0, k - 0.5 + frac)
    return q / _half_normal_quantile(quantile)

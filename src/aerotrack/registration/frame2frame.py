"""Frame-to-frame homographies (Yu & Medioni section 2, first step).

Consecutive frames are registered on a downscaled grey image: corners are tracked by pyramidal
sparse optical flow (Lucas-Kanade) and a homography is fitted to them by a robust estimator
(RANSAC or MAGSAC). ORB descriptor matching is the fallback when the motion is too large for
optical flow (a sudden jump or rotation). Every failure is returned as a
:class:`~aerotrack.types.Failure` value with its reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from ..errors import ConfigError
from ..types import Failure
from .chain import check_homography, normalize

#: Robust estimators by name (``RegistrationConfig.estimator``).
ESTIMATORS = {"ransac": cv2.RANSAC, "magsac": cv2.USAC_MAGSAC}
#: Feature trackers by name (``RegistrationConfig.method``).
METHODS = ("lk", "orb")

# first pass: large motions, moderate precision (the polish pass below refines it). An 11 px
# window instead of 15 halves its cost with the same frame-to-frame error after the polish
# (generated scenes, 640x480 and 1280x720: 0.015 / 0.026 px either way).
_LK_PARAMS = dict(winSize=(11, 11), maxLevel=3,
                  criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03))
# after warping by a first estimate the residual motion is sub-pixel: no pyramid, tight convergence
# (a loose stopping rule stops short of the optimum on the same side every frame: a bias)
_POLISH_PARAMS = dict(winSize=(13, 13), maxLevel=0,
                      criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.003))


@dataclass(frozen=True)
class EstimateStats:
    """Quality figures of one robust homography estimate.

    Attributes
    ----------
    inliers : int
        Correspondences consistent with the homography.
    tentative : int
        Correspondences given to the robust estimator.
    inlier_ratio : float
        ``inliers / tentative``.
    error : float
        Median reprojection error of the inliers, in the pixels of the images given.
    points : ndarray, shape (N, 2), float32
        Inlier positions in the second image (its pixels), reusable as the next frame's features.
    source : ndarray, shape (N, 2), float32
        The same inliers in the first image.
    """

    inliers: int
    tentative: int
    inlier_ratio: float
    error: float
    points: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 2), np.float32))
    source: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 2), np.float32))


def to_gray(image: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Grey uint8 image downscaled by ``scale`` (linear interpolation), from BGR or grey input."""
    img = image
    if img.ndim == 3:  # grey first: one channel to resize (a third less time, +-1 grey level)
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if scale != 1.0:
        h, w = img.shape[:2]
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        interp = cv2.INTER_AREA if scale < 0.5 else cv2.INTER_LINEAR
        img = cv2.resize(img, size, interpolation=interp)
    return img


def frame_quality(gray: np.ndarray, *, min_contrast: float = 4.0, max_saturated: float = 0.6,
                  min_neighbour_corr: float = 0.3) -> Failure | None:
    """Say why a frame cannot be registered, before trying.

    Parameters
    ----------
    gray : (H, W) uint8
        The (downscaled) grey frame.
    min_contrast : float
        Grey-level standard deviation under which the frame is ``blank``.
    max_saturated : float
        Fraction of pixels at >= 250 above which the frame is ``overexposed``.
    min_neighbour_corr : float
        Correlation of horizontally adjacent pixels under which the frame is ``noise``: imagery
        of the ground is spatially smooth (correlation near 1), sensor noise or a broken stream is
        not (near 0).

    Returns
    -------
    Failure or None
    """
    g = gray[::2]  # every other row: adjacency along rows is kept, half the cost
    _, std = cv2.meanStdDev(g)
    sd = float(std[0, 0])
    if sd < min_contrast:
        return Failure(f"blank frame (grey-level std {sd:.1f})")
    sat = float(np.count_nonzero(g >= 250)) / g.size
    if sat > max_saturated:
        return Failure(f"overexposed frame ({sat:.0%} saturated)")
    d = cv2.absdiff(g[:, 1:], g[:, :-1])
    dvar = float(np.mean(np.square(d, dtype=np.float32)))
    corr = 1.0 - dvar / (2.0 * sd * sd)
    if corr < min_neighbour_corr:
        return Failure(f"noise frame (neighbour correlation {corr:.2f})")
    return None


def detect_features(gray: np.ndarray, max_features: int, mask: np.ndarray | None = None) -> np.ndarray:
    """(N, 1, 2) float32 Shi-Tomasi corners, spread over the image (minimum spacing from density)."""
    h, w = gray.shape[:2]
    spacing = max(3.0, 0.5 * np.sqrt(h * w / max(max_features, 1)))
    pts = cv2.goodFeaturesToTrack(gray, maxCorners=max_features, qualityLevel=0.01,
                                  minDistance=spacing, blockSize=3, mask=mask)
    if pts is None:
        return np.zeros((0, 1, 2), np.float32)
    return pts.astype(np.float32)


def boxes_mask(shape: tuple[int, int], boxes: np.ndarray | None, scale: float = 1.0,
               margin: float = 2.0) -> np.ndarray | None:
    """uint8 mask (255 = usable) of an image of ``shape``, zero inside the given boxes.

    ``boxes`` are (N, 4) ``x, y, w, h`` in full-resolution frame pixels; ``scale`` maps them to
    the image's pixels, ``margin`` (image pixels) grows them.
    """
    if boxes is None or len(boxes) == 0:
        return None
    mask = np.full(shape[:2], 255, np.uint8)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4) * scale
    for x, y, w, h in b:
        if not np.all(np.isfinite([x, y, w, h])):
            continue
        x0, y0 = int(np.floor(x - margin)), int(np.floor(y - margin))
        x1, y1 = int(np.ceil(x + w + margin)), int(np.ceil(y + h + margin))
        mask[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = 0
    return mask


def _fit(p0: np.ndarray, p1: np.ndarray, shape: tuple[int, int], *, threshold: float,
         estimator: str, min_inliers: int, min_inlier_ratio: float, max_scale_change: float,
         max_condition: float) -> tuple[np.ndarray, EstimateStats] | Failure:
    n = len(p0)
    if n < max(min_inliers, 4):
        return Failure(f"too few correspondences ({n} < {min_inliers})")
    try:
        method = ESTIMATORS[estimator]
    except KeyError:
        raise ConfigError(f"config registration.estimator: unknown {estimator!r} "
                          f"(valid: {', '.join(ESTIMATORS)})") from None
    H, inl = cv2.findHomography(p0, p1, method, threshold, maxIters=2000, confidence=0.995)
    if H is None or inl is None:
        return Failure("robust estimator found no homography")
    inl = inl.ravel().astype(bool)
    k = int(inl.sum())
    ratio = k / n
    if k < min_inliers:
        return Failure(f"too few inliers ({k} < {min_inliers})")
    if ratio < min_inlier_ratio:
        return Failure(f"inlier ratio too low ({ratio:.2f} < {min_inlier_ratio})")
    h, w = shape[:2]
    bad = check_homography(H, w, h, max_scale_change=max_scale_change, max_condition=max_condition)
    if bad is not None:
        return bad
    H = normalize(H)
    q = np.hstack([p0[inl], np.ones((k, 1))]) @ H.T
    err = float(np.median(np.linalg.norm(q[:, :2] / q[:, 2:3] - p1[inl], axis=1)))
    stats = EstimateStats(inliers=k, tentative=n, inlier_ratio=ratio, error=err,
                          points=p1[inl].astype(np.float32), source=p0[inl].astype(np.float32))
    return H, stats


def _polish(prev_gray: np.ndarray, gray: np.ndarray, H: np.ndarray, p0: np.ndarray,
            fit: dict) -> tuple[np.ndarray, EstimateStats] | Failure:
    """Re-track ``p0`` (prev pixels) between ``prev_gray`` warped by ``H`` and ``gray``.

    Once the previous frame is warped by the first estimate, the remaining motion is sub-pixel and
    free of scale change and rotation, so Lucas-Kanade's translational window model holds: this
    removes the bias it has under zoom (about 1e-4 in scale per frame, which chaining turns into
    drift) and the ~1 px localisation error of ORB keypoints.
    """
    h, w = gray.shape[:2]
    warped = cv2.warpPerspective(prev_gray, H, (w, h), flags=cv2.INTER_LINEAR)
    c0 = cv2.perspectiveTransform(np.asarray(p0, np.float32).reshape(-1, 1, 2), H)
    keep = ((c0[:, 0, 0] > 8) & (c0[:, 0, 0] < w - 9) & (c0[:, 0, 1] > 8) & (c0[:, 0, 1] < h - 9))
    c0 = c0[keep].astype(np.float32)
    q0 = np.asarray(p0, np.float32).reshape(-1, 2)[keep]
    if len(c0) < 4:
        return Failure("polish: too few points")
    c1, st, _ = cv2.calcOpticalFlowPyrLK(warped, gray, c0, None, **_POLISH_PARAMS)
    if c1 is None:
        return Failure("polish: optical flow failed")
    ok = st.ravel() == 1
    return _fit(q0[ok], c1[ok].reshape(-1, 2), gray.shape, **fit)


def polish_estimate(prev_gray: np.ndarray, gray: np.ndarray,
                    estimate: tuple[np.ndarray, EstimateStats], *, ransac_threshold: float = 1.0,
                    estimator: str = "ransac", min_inliers: int = 20,
                    min_inlier_ratio: float = 0.25, max_scale_change: float = 1.5,
                    max_condition: float = 4.0) -> tuple[np.ndarray, EstimateStats]:
    """The polish pass of :func:`estimate_homography` (``polish=True``) applied afterwards to an
    unpolished ``lk`` estimate: its inliers re-tracked after warping ``prev_gray`` by it.

    Returns the polished estimate, or ``estimate`` unchanged when the polish fails.
    """
    fit = dict(threshold=ransac_threshold, estimator=estimator, min_inliers=min_inliers,
               min_inlier_ratio=min_inlier_ratio, max_scale_change=max_scale_change,
               max_condition=max_condition)
    better = _polish(prev_gray, gray, estimate[0], estimate[1].source, fit)
    return _as_first_pass(better, estimate[1]) if better else estimate


def _as_first_pass(polished: tuple[np.ndarray, EstimateStats], first: EstimateStats
                   ) -> tuple[np.ndarray, EstimateStats]:
    """Polished estimate with the inlier ratio counted against the first pass's correspondences
    (the polish only re-tracks inliers, so its own ratio says little about the frame)."""
    H, st = polished
    return H, replace(st, tentative=first.tentative,
                      inlier_ratio=min(1.0, st.inliers / max(first.tentative, 1)))


def estimate_homography(
    prev_gray: np.ndarray,
    gray: np.ndarray,
    mask: np.ndarray | None = None,
    *,
    method: str = "lk",
    prev_points: np.ndarray | None = None,
    max_features: int = 400,
    ransac_threshold: float = 1.0,
    estimator: str = "ransac",
    min_inliers: int = 20,
    min_inlier_ratio: float = 0.25,
    max_scale_change: float = 1.5,
    max_condition: float = 4.0,
    polish: bool = True,
    guess: np.ndarray | None = None,
) -> tuple[np.ndarray, EstimateStats] | Failure:
    """Homography from ``prev_gray``'s pixels to ``gray``'s pixels (``H_{i-1,i}``).

    Parameters
    ----------
    prev_gray, gray : (H, W) uint8
        Two grey images of the same size (typically downscaled frames).
    mask : (H, W) uint8, optional
        Non-zero where features of ``prev_gray`` may be chosen (zero over moving vehicles).
    method : {'lk', 'orb'}
        ``lk``: Shi-Tomasi corners of ``prev_gray`` (or ``prev_points``) tracked into ``gray`` by
        pyramidal Lucas-Kanade flow; fast, for motions up to a few tens of pixels.
        ``orb``: ORB keypoints matched by descriptor (ratio test); slower, rotation-invariant.
    prev_points : (N, 2) or (N, 1, 2) float32, optional
        Features of ``prev_gray`` to track instead of detecting new ones (``lk`` only); points in
        a masked-out area are dropped.
    max_features : int
        Corners detected when ``prev_points`` is not given (or ORB keypoints).
    ransac_threshold : float
        Inlier threshold, in these images' pixels.
    estimator : {'ransac', 'magsac'}
    min_inliers, min_inlier_ratio, max_scale_change, max_condition
        Failure thresholds; see :class:`~aerotrack.config.RegistrationConfig`.
    polish : bool
        Re-track the inliers after warping ``prev_gray`` by the first estimate (see ``_polish``):
        about 30 % more time, several times less drift when chained over a zooming camera.
    guess : (3, 3) array, optional
        Predicted homography (``lk`` only): optical flow starts from it, so a reference frame
        several frames back can be used.

    Returns
    -------
    (H, EstimateStats) or Failure
        ``H`` (3, 3) float64 with ``H[2, 2] = 1`` maps pixels of ``prev_gray`` to ``gray``.
    """
    if prev_gray.shape != gray.shape:
        return Failure(f"frame size changed ({prev_gray.shape} -> {gray.shape})")
    fit = dict(threshold=ransac_threshold, estimator=estimator, min_inliers=min_inliers,
               min_inlier_ratio=min_inlier_ratio, max_scale_change=max_scale_change,
               max_condition=max_condition)
    if method == "lk":
        if prev_points is not None and len(prev_points):
            p0 = np.asarray(prev_points, np.float32).reshape(-1, 1, 2)
            if mask is not None:
                xi = np.clip(p0[:, 0, 0].astype(int), 0, mask.shape[1] - 1)
                yi = np.clip(p0[:, 0, 1].astype(int), 0, mask.shape[0] - 1)
                p0 = p0[mask[yi, xi] > 0]
        else:
            p0 = detect_features(prev_gray, max_features, mask)
        if len(p0) < max(min_inliers, 4):
            return Failure(f"featureless frame ({len(p0)} corners)")
        if guess is not None:
            init = cv2.perspectiveTransform(p0, np.asarray(guess, np.float64)).astype(np.float32)
            p1, st, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, p0, init,
                                                 flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **_LK_PARAMS)
        else:
            p1, st, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, p0, None, **_LK_PARAMS)
        if p1 is None:
            return Failure("optical flow failed")
        ok = st.ravel() == 1
        res = _fit(p0[ok].reshape(-1, 2), p1[ok].reshape(-1, 2), gray.shape, **fit)
        if res and polish:
            inl = res[1].source
            better = _polish(prev_gray, gray, res[0], inl, fit)
            if better:
                return _as_first_pass(better, res[1])
        return res
    if method == "orb":
        orb = cv2.ORB_create(nfeatures=max(2 * max_features, 500))
        k0, d0 = orb.detectAndCompute(prev_gray, mask)
        k1, d1 = orb.detectAndCompute(gray, None)
        if d0 is None or d1 is None or len(k0) < 4 or len(k1) < 4:
            return Failure("featureless frame (no ORB keypoints)")
        matches = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(d0, d1, k=2)
        good = [m[0] for m in matches if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
        p0 = np.float32([k0[m.queryIdx].pt for m in good]).reshape(-1, 2)
        p1 = np.float32([k1[m.trainIdx].pt for m in good]).reshape(-1, 2)
        res = _fit(p0, p1, gray.shape, **fit)
        if not res:
            return res
        # ORB keypoints are located to ~1 px: polish with fresh corners of the previous frame
        c0 = detect_features(prev_gray, max_features, mask)
        if len(c0) >= max(min_inliers, 4):
            polished = _polish(prev_gray, gray, res[0], c0.reshape(-1, 2), fit)
            if polished:  # fresh corners: the ORB matches' ratio describes the frame pair
                return polished[0], replace(polished[1], tentative=res[1].tentative,
                                            inlier_ratio=res[1].inlier_ratio)
        return res
    raise ConfigError(f"config registration.method: unknown {method!r} (valid: {', '.join(METHODS)})")

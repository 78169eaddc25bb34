"""Homography algebra: chaining (Yu & Medioni eq. 1), normalisation and sanity checks.

Convention: ``H_ij`` maps frame ``i``'s pixels to frame ``j``'s pixels (column vectors,
``x_j ~ H_ij @ x_i``), so ``H_ik = H_jk @ H_ij``.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from ..types import Failure, apply_homography


def normalize(H: np.ndarray) -> np.ndarray:
    """``H`` scaled so that ``H[2, 2] = 1`` (float64 copy)."""
    H = np.asarray(H, dtype=np.float64)
    return H / H[2, 2]


def chain(Hs: Sequence[np.ndarray], i: int, j: int) -> np.ndarray:
    """Homography from frame ``i`` to frame ``j`` by chaining consecutive ones (eq. 1).

    Parameters
    ----------
    Hs : sequence of (3, 3) arrays
        ``Hs[k]`` maps frame ``k``'s pixels to frame ``k+1``'s pixels (0-based frame indices).
    i, j : int
        0-based frame indices, ``0 <= i, j <= len(Hs)``.

    Returns
    -------
    (3, 3) float64
        ``H_ij`` with ``H[2, 2] = 1``: the identity for ``i == j``, the product of the
        consecutive homographies for ``i < j`` and the inverse of ``H_ji`` for ``i > j``.

    Notes
    -----
    The paper writes the product as :math:`\\prod_{k=i}^{j-1} H_{k,k+1}`; with column vectors the
    factors apply right to left, ``H_{j-1,j} ... H_{i,i+1}``, which is what is computed.
    """
    n = len(Hs)
    if not (0 <= i <= n and 0 <= j <= n):
        raise IndexError(f"chain: frames {i}, {j} outside 0..{n}")
    if i == j:
        return np.eye(3)
    if i > j:
        return normalize(np.linalg.inv(chain(Hs, j, i)))
    H = np.eye(3)
    for k in range(i, j):
        H = np.asarray(Hs[k], dtype=np.float64) @ H
        H = H / H[2, 2]
    return H


def scale_homography(H: np.ndarray, s: float) -> np.ndarray:
    """Express a homography between downscaled images in continuous full-resolution pixels.

    ``H`` maps OpenCV pixel *indices* (pixel centre at integer coordinates) of image A downscaled by
    ``s`` (``cv2.resize``) to those of image B; the result maps continuous full-resolution pixels
    (origin at the top-left corner, see :mod:`aerotrack.types`) of A to those of B:
    ``S^-1 H S`` with ``S: x -> s x - 0.5`` (the half-pixel shift is exact for ``cv2.resize``).
    """
    S = np.array([[s, 0, -0.5], [0, s, -0.5], [0, 0, 1.0]])
    Si = np.array([[1.0 / s, 0, 0.5 / s], [0, 1.0 / s, 0.5 / s], [0, 0, 1.0]])
    return normalize(Si @ np.asarray(H, dtype=np.float64) @ S)


def frame_corners(width: int, height: int) -> np.ndarray:
    """(4, 2) corners of a ``width`` x ``height`` frame, clockwise from top-left, frame pixels."""
    return np.array([[0, 0], [width, 0], [width, height], [0, height]], dtype=np.float64)


#: Index of the next corner of a quadrilateral (np.roll(-1) without its overhead).
_NEXT = np.array([1, 2, 3, 0])


def _signed_area(q: np.ndarray) -> float:
    x, y = q[:, 0], q[:, 1]
    return 0.5 * float(np.dot(x, y[_NEXT]) - np.dot(x[_NEXT], y))


def check_homography(H: np.ndarray | None, width: int, height: int, *,
                     max_scale_change: float = 1.5, max_condition: float = 4.0) -> Failure | None:
    """Reject a homography that cannot be a camera motion between two views of a plane.

    Parameters
    ----------
    H : (3, 3) array or None
        Maps pixels of a ``width`` x ``height`` frame to another frame (any frame pixels).
    max_scale_change : float
        Largest ratio between the areas of the frame and its image (either way).
    max_condition : float
        Largest condition number of the 2x2 linear part after normalisation (shear and
        anisotropic scale; a similarity has 1).

    Returns
    -------
    Failure or None
        ``None`` when ``H`` passes; otherwise the reason: not finite, corner flip or fold
        (non-convex or reversed image of the frame), area ratio, conditioning, or a vanishing line
        crossing the frame.
    """
    if H is None:
        return Failure("no homography")
    H = np.asarray(H, dtype=np.float64)
    if H.shape != (3, 3) or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return Failure("degenerate homography (not finite)")
    H = H / H[2, 2]
    c = frame_corners(width, height)
    hom = c @ H[:, :2].T + H[:, 2]  # (4, 3) homogeneous images of the corners
    w = hom[:, 2]
    if np.any(w <= 1e-6):
        return Failure("degenerate homography (horizon crosses the frame)")
    q = hom[:, :2] / w[:, None]
    # convexity and orientation: every consecutive edge pair turns the same way as the original
    e = q[_NEXT] - q
    en = e[_NEXT]
    cross = e[:, 0] * en[:, 1] - e[:, 1] * en[:, 0]
    if np.any(cross <= 0):
        return Failure("degenerate homography (corner flip or fold)")
    ratio = _signed_area(q) / float(width * height)
    if not (1.0 / max_scale_change <= ratio <= max_scale_change):
        return Failure(f"degenerate homography (area ratio {ratio:.2f})")
    # conditioning of the linear part at the frame centre (first-order approximation of H there)
    ctr = np.array([width / 2.0, height / 2.0])
    J = _jacobian(H, ctr)
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[1] <= 0 or sv[0] / sv[1] > max_condition:
        return Failure(f"degenerate homography (condition {sv[0] / max(sv[1], 1e-12):.1f})")
    return None


def area_ratio(H: np.ndarray, width: int, height: int) -> float:
    """Area of the frame's image under ``H`` over the frame's area (the scale change squared; the
    quantity ``check_homography`` bounds by ``max_scale_change``); NaN when a corner maps to or
    beyond the horizon."""
    H = np.asarray(H, dtype=np.float64)
    hom = frame_corners(width, height) @ H[:, :2].T + H[:, 2]
    if np.any(hom[:, 2] <= 1e-6 * abs(H[2, 2])):
        return float("nan")
    q = hom[:, :2] / hom[:, 2:3]
    return abs(_signed_area(q)) / float(width * height)


def uncovered_share(H: np.ndarray, shape: tuple[int, int]) -> float:
    """Share of a frame's area that another frame of the same size ``shape`` did not show (the
    new ground a pan brings); ``H`` maps this frame's pixels to the other's."""
    h, w = shape
    H = np.asarray(H, np.float64)
    if not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return 1.0
    rect = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float32)
    q = np.c_[rect, np.ones(4)] @ (H / H[2, 2]).T
    if np.any(q[:, 2] <= 1e-9):
        return 1.0
    q = (q[:, :2] / q[:, 2:]).astype(np.float32)
    area = abs(cv2.contourArea(q))
    if area <= 0:
        return 1.0
    inter, _ = cv2.intersectConvexConvex(rect, q)
    return float(max(0.0, 1.0 - inter / area))


def _jacobian(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """2x2 Jacobian of the projective map ``H`` at point ``p``."""
    x, y = p
    u = H[0, 0] * x + H[0, 1] * y + H[0, 2]
    v = H[1, 0] * x + H[1, 1] * y + H[1, 2]
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    return np.array([
        [(H[0, 0] * w - u * H[2, 0]) / w**2, (H[0, 1] * w - u * H[2, 1]) / w**2],
        [(H[1, 0] * w - v * H[2, 0]) / w**2, (H[1, 1] * w - v * H[2, 1]) / w**2],
    ])


def corner_error(H_est: np.ndarray, H_true: np.ndarray, width: int, height: int) -> float:
    """Mean distance (in the target's pixels) between the frame corners mapped by two homographies."""
    c = frame_corners(width, height)
    return float(np.mean(np.linalg.norm(apply_homography(H_est, c) - apply_homography(H_true, c),
                                        axis=1)))

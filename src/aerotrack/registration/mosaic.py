"""Geo-mosaic: registered frames painted onto the map (or onto frame 1's plane), like Yu & Medioni fig. 2.

A glance at the mosaic shows whether registration holds: roads continue across frame borders and
the painted frames line up with the map beneath them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import cv2
import numpy as np

from ..types import Frame, apply_homography
from .chain import frame_corners


def in_front(H: np.ndarray, width: int, height: int) -> bool:
    """Whether the whole frame maps to finite world points (its horizon lies outside the frame)."""
    c = frame_corners(width, height)
    w = c @ np.asarray(H, dtype=np.float64)[2, :2] + H[2, 2]
    return bool(np.all(np.isfinite(H)) and np.all(w * np.sign(H[2, 2]) > 1e-9))


def mosaic_bounds(Hs: Iterable[np.ndarray], width: int, height: int,
                  max_extent: float | None = None) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) world bounding box of the footprints of ``width`` x ``height`` frames.

    Frames whose horizon crosses them are ignored. ``max_extent`` (world units) clips the box to
    that distance around the first footprint's centre: on an oblique view the far corners of later
    frames map near the horizon of frame 1's plane, arbitrarily far away.
    """
    c = frame_corners(width, height)
    quads = [apply_homography(H, c) for H in Hs if in_front(H, width, height)]
    if not quads:
        return 0.0, 0.0, float(width), float(height)
    pts = np.vstack(quads)
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    if max_extent is not None:
        cx, cy = quads[0].mean(axis=0)
        x0, x1 = max(x0, cx - max_extent), min(x1, cx + max_extent)
        y0, y1 = max(y0, cy - max_extent), min(y1, cy + max_extent)
    return float(x0), float(y0), float(x1), float(y1)


def share_off_map(Hs: Iterable[np.ndarray], width: int, height: int,
                  map_size: tuple[int, int]) -> float:
    """Mean share of the frames' footprints (frame -> map pixels through each H) lying outside
    the ``map_size`` (width, height) raster: what a mosaic on the map cannot show."""
    c = frame_corners(width, height)
    rect = np.array([[0, 0], [map_size[0], 0], [map_size[0], map_size[1]], [0, map_size[1]]],
                    np.float32)
    shares = []
    for H in Hs:
        if not in_front(H, width, height):
            continue
        q = apply_homography(H, c).astype(np.float32)
        area = abs(float(cv2.contourArea(q)))
        if not np.all(np.isfinite(q)) or area <= 0:
            continue
        inside, _ = cv2.intersectConvexConvex(q, rect)
        shares.append(1.0 - min(1.0, max(0.0, float(inside)) / area))
    return float(np.mean(shares)) if shares else 0.0


def paint_mosaic(frames: Iterable[Frame], Hs: Mapping[int, np.ndarray], frame_size: tuple[int, int], *,
                 base: np.ndarray | None = None, max_side: int = 4000, margin: float = 50.0,
                 alpha: float = 0.75, outline_every: int = 1,
                 max_extent: float | None = None, with_transform: bool = False):
    """Paint frames into world coordinates.

    Parameters
    ----------
    frames : iterable of Frame
        The frames to paint, in order (later ones on top); typically every n-th frame.
    Hs : mapping frame index -> (3, 3)
        Frame pixels -> world for every frame (world = map pixels with ``base``, else frame 1's
        pixels). Only the frames painted and the bounds of all of them are used.
    frame_size : (width, height)
    base : (Hm, Wm, 3) uint8, optional
        The map (map pixels). The mosaic is then the map cropped to the footprints, with the frames
        blended over it (``alpha``) so misregistration shows as ghosting.
    max_side : int
        Longest side of the output; a larger world extent is scaled down.
    margin : float
        World units added around the footprints.
    alpha : float
        Opacity of the painted frames over the map.
    outline_every : int
        Draw the outline of every n-th painted frame (0: none): first green, last red, others yellow.
    max_extent : float, optional
        Clip the picture to this distance (world units) around frame 1's footprint; default twice
        the frame diagonal without a map (oblique views reach the horizon), unlimited with one.

    with_transform : bool
        Also return the (3, 3) world -> picture pixels transform (a scale and a shift), which
        georeferences the picture when the world is the map's pixels.

    Returns
    -------
    (h, w, 3) uint8 BGR image, or (image, transform) with ``with_transform``.
    """
    w, h = frame_size
    if max_extent is None and base is None:
        max_extent = 2.0 * float(np.hypot(w, h))
    x0, y0, x1, y1 = mosaic_bounds(Hs.values(), w, h, max_extent)
    x0, y0, x1, y1 = x0 - margin, y0 - margin, x1 + margin, y1 + margin
    if base is not None:
        x0, y0 = max(x0, 0.0), max(y0, 0.0)
        x1, y1 = min(x1, float(base.shape[1])), min(y1, float(base.shape[0]))
        if x1 - x0 < 2 or y1 - y0 < 2:  # frames entirely off the map: show the whole map
            x0, y0, x1, y1 = 0.0, 0.0, float(base.shape[1]), float(base.shape[0])
    s = min(1.0, max_side / max(x1 - x0, y1 - y0, 1.0))
    S = np.array([[s, 0, -s * x0], [0, s, -s * y0], [0, 0, 1]], dtype=np.float64)
    cw, ch = int(np.ceil((x1 - x0) * s)), int(np.ceil((y1 - y0) * s))
    if base is not None:
        canvas_base = cv2.warpAffine(base, S[:2], (cw, ch), flags=cv2.INTER_AREA if s < 1
                                     else cv2.INTER_LINEAR)
    else:
        canvas_base = np.full((ch, cw, 3), 40, np.uint8)
    layer = np.zeros_like(canvas_base)
    painted = np.zeros((ch, cw), bool)
    outlines = []
    last = None
    corners = frame_corners(w, h)
    for n, frame in enumerate(frames):
        H = Hs.get(frame.index)
        if H is None or not in_front(H, w, h):
            continue
        Hc = S @ H
        q = apply_homography(Hc, corners)
        if not np.all(np.isfinite(q)):
            continue
        bx0, by0 = max(int(np.floor(q[:, 0].min())), 0), max(int(np.floor(q[:, 1].min())), 0)
        bx1, by1 = min(int(np.ceil(q[:, 0].max())) + 1, cw), min(int(np.ceil(q[:, 1].max())) + 1, ch)
        if bx1 <= bx0 or by1 <= by0:
            continue
        T = np.array([[1, 0, -bx0], [0, 1, -by0], [0, 0, 1]], dtype=np.float64) @ Hc
        size = (bx1 - bx0, by1 - by0)
        # the border replicated: interpolating the frame's edge with the black outside left a
        # dark dotted seam along every painted frame's edge (a probe)
        warped = cv2.warpPerspective(frame.image, T, size, flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)
        m = cv2.warpPerspective(np.full(frame.image.shape[:2], 255, np.uint8), T, size,
                                flags=cv2.INTER_NEAREST) > 0
        sub = layer[by0:by1, bx0:bx1]
        sub[m] = warped[m]
        painted[by0:by1, bx0:bx1] |= m
        if outline_every and n % outline_every == 0:
            outlines.append(q)
        last = q
    if outlines and outlines[-1] is not last:
        outlines.append(last)
    out = canvas_base.copy()
    if base is not None:
        blend = cv2.addWeighted(layer, alpha, canvas_base, 1 - alpha, 0)
        out[painted] = blend[painted]
    else:
        out[painted] = layer[painted]
    for k, q in enumerate(outlines):
        colour = (0, 255, 0) if k == 0 else (0, 0, 255) if k == len(outlines) - 1 else (0, 220, 255)
        cv2.polylines(out, [np.round(q * 16).astype(np.int32)], True, colour, 1, cv2.LINE_AA, shift=4)
    if base is None and painted.any():  # crop the empty canvas around what was painted
        rows, cols = np.flatnonzero(painted.any(axis=1)), np.flatnonzero(painted.any(axis=0))
        pad = int(margin * s)
        r0, c0 = max(rows[0] - pad, 0), max(cols[0] - pad, 0)
        out = out[r0:rows[-1] + pad + 1, c0:cols[-1] + pad + 1]
        S = np.array([[1, 0, -c0], [0, 1, -r0], [0, 0, 1]], dtype=np.float64) @ S
    return (out, S) if with_transform else out


def picture_geotransform(geomap, S: np.ndarray):
    """The rasterio ``Affine`` of a picture painted in map pixels through ``S`` (map image
    indices -> picture indices, OpenCV's convention with pixel centres at integers, in which
    :func:`paint_mosaic` warped the map): picture pixel ``(c, r)`` shows the map at image index
    ``S^-1 (c, r)``, i.e. at continuous map pixel ``S^-1 (c, r) + 0.5`` (the raster's corner
    convention, :mod:`aerotrack.geo.maprast`), so the picture's map lies on the map file's in a
    GIS."""
    from rasterio.transform import Affine

    inv = np.linalg.inv(S)
    return (geomap.transform * Affine.translation(0.5, 0.5)
            * Affine(inv[0, 0], inv[0, 1], inv[0, 2], inv[1, 0], inv[1, 1], inv[1, 2])
            * Affine.translation(-0.5, -0.5))


def world_file_text(transform) -> str:
    """An ESRI world file (``.pgw``/``.jgw``) for ``transform``: the pixel sizes and rotations,
    then the map coordinates of the centre of the top-left pixel."""
    t = transform
    cx, cy = t * (0.5, 0.5)
    return "\n".join(f"{v:.12g}" for v in (t.a, t.d, t.b, t.e, cx, cy)) + "\n"

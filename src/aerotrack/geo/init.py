"""The frame-1 geo-initialisation (``--map-init``).

Accepted forms:

* 3 lines of 3 numbers (whitespace- or comma-separated): a homography from frame 1's pixels to
  map pixels;
* a CSV with header ``frame_x,frame_y,map_x,map_y`` (map pixels) or ``frame_x,frame_y,lon,lat``,
  with at least 4 non-collinear rows; the homography is fitted to them (least squares over all
  points, so more points average out clicking errors);
* a CSV with header ``frame_x,frame_y,crs_x,crs_y`` and a ``# crs: EPSG:XXXX`` line, or a QGIS
  georeferencer ``.points`` file: control points in any map CRS (see :mod:`aerotrack.geo.qgis`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import FormatError, GeoreferenceError, InputError
from ..io.textfile import read_text
from .maprast import GeoMap


def read_map_init(path: str | Path, geomap: GeoMap | None = None, *,
                  option: str = "--map-init") -> np.ndarray:
    """Read a map-init file and return the 3x3 homography frame-1 pixels -> map pixels."""
    p = Path(path)
    label = f"{option} {p}"
    if not p.exists():
        raise InputError(f"{label}: file not found")
    if p.suffix.lower() == ".points":  # QGIS georeferencer control points (geo/qgis.py)
        from .qgis import read_qgis_points

        if geomap is None:
            raise InputError(f"{label}: control points in a map CRS need --map")
        return read_qgis_points(p, option=option).homography(geomap)
    text = read_text(p, label)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    if not lines:
        raise FormatError(f"{label}: file is empty")
    header = [h.strip().lower() for h in lines[0].split(",")]
    if header == ["frame_x", "frame_y", "crs_x", "crs_y"]:  # CRS-tagged control points
        from .qgis import read_crs_gcps

        if geomap is None:
            raise InputError(f"{label}: control points in a map CRS need --map")
        return read_crs_gcps(p, option=option).homography(geomap)
    if header[:2] == ["frame_x", "frame_y"]:
        return _from_gcps(lines, header, label, geomap)
    return _from_matrix(lines, label)


def _from_matrix(lines: list[str], label: str) -> np.ndarray:
    if len(lines) != 3:
        raise FormatError(
            f"{label}: expected 3 lines of 3 numbers (a homography) or a CSV with a "
            f"frame_x,frame_y,... header; found {len(lines)} lines"
        )
    rows = []
    for i, ln in enumerate(lines, start=1):
        parts = ln.replace(",", " ").split()
        if len(parts) != 3:
            raise FormatError(f"{label} line {i}: expected 3 numbers, found {len(parts)}")
        try:
            rows.append([float(v) for v in parts])
        except ValueError:
            raise FormatError(f"{label} line {i}: non-numeric value") from None
    H = np.asarray(rows)
    if not np.all(np.isfinite(H)):
        raise FormatError(f"{label}: homography has NaN or infinite entries")
    if abs(np.linalg.det(H)) < 1e-12 or abs(H[2, 2]) < 1e-12:
        raise FormatError(f"{label}: homography is singular")
    return H / H[2, 2]


def _from_gcps(lines: list[str], header: list[str], label: str, geomap: GeoMap | None,
               target: str = "map") -> np.ndarray:
    if header == ["frame_x", "frame_y", "map_x", "map_y"]:
        kind = "pixel"
    elif header == ["frame_x", "frame_y", "lon", "lat"]:
        kind = "lonlat"
    else:
        raise FormatError(
            f"{label} line 1: header must be frame_x,frame_y,map_x,map_y or frame_x,frame_y,lon,lat"
        )
    pts = []
    for i, ln in enumerate(lines[1:], start=2):
        parts = ln.split(",")
        if len(parts) != 4:
            raise FormatError(f"{label} line {i}: expected 4 comma-separated numbers")
        try:
            vals = [float(v) for v in parts]
        except ValueError:
            raise FormatError(f"{label} line {i}: non-numeric value") from None
        if not np.all(np.isfinite(vals)):
            raise FormatError(f"{label} line {i}: NaN or infinite value")
        pts.append(vals)
    if len(pts) < 4:
        raise FormatError(f"{label}: needs at least 4 ground-control points, found {len(pts)}")
    a = np.asarray(pts)
    src, dst = a[:, :2], a[:, 2:]
    if kind == "lonlat":
        if geomap is None:
            raise InputError(f"{label}: lon/lat control points need --map")
        dst = geomap.lonlat_to_pixel(dst)
    for name, q in (("frame", src), (target, dst)):
        c = q - q.mean(axis=0)
        sv = np.linalg.svd(c, compute_uv=False)
        if sv[1] < 1e-6 * max(sv[0], 1e-12) or sv[0] == 0:
            raise FormatError(f"{label}: the {name} control points are collinear or repeated")
    H, _ = cv2.findHomography(src, dst, 0)
    if H is None or not np.all(np.isfinite(H)):
        raise GeoreferenceError(f"{label}: cannot fit a homography to the control points")
    return H / H[2, 2]


def read_ground(path: str | Path, option: str = "--ground") -> np.ndarray:
    """Frame-1 pixels -> a ground plane in metres, for footage without a map whose scale
    changes across the frame (an oblique view, where one ``--gsd`` is wrong): a 3x3 homography
    (3 lines of 3 numbers), or at least 4 control points as CSV with the header
    ``frame_x,frame_y,ground_x,ground_y`` (pixels of frame 1; metres on the ground, any origin,
    x and y at right angles, y 90 degrees anticlockwise from x as east and north are (headings
    are clockwise from y): measured lane widths and markings give them)."""
    p = Path(path)
    label = f"{option} {p}"
    if not p.exists():
        raise InputError(f"{label}: file not found")
    text = read_text(p, label)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    if not lines:
        raise FormatError(f"{label}: file is empty")
    header = [h.strip().lower() for h in lines[0].split(",")]
    if header[:2] != ["frame_x", "frame_y"]:
        if any(c.isalpha() for c in lines[0].replace("e", "").replace("E", "")):
            raise FormatError(f"{label} line 1: a header must be frame_x,frame_y,ground_x,ground_y "
                              "(comma-separated; ground in metres), or give 3 lines of 3 numbers "
                              "(a homography)")
        return _from_matrix(lines, label)
    if header != ["frame_x", "frame_y", "ground_x", "ground_y"]:
        raise FormatError(f"{label} line 1: header must be frame_x,frame_y,ground_x,ground_y "
                          "(ground in metres)")
    return _from_gcps(lines, ["frame_x", "frame_y", "map_x", "map_y"], label, None, "ground")


def ground_points(path: str | Path) -> np.ndarray | None:
    """The control points of a ``--ground`` CSV as (N, 4) ``frame_x, frame_y, ground_x,
    ground_y``; None for a homography file (call after :func:`read_ground` accepted it)."""
    lines = [ln.strip() for ln in read_text(Path(path), str(path)).splitlines()
             if ln.strip() and not ln.strip().startswith("#")]
    if [h.strip().lower() for h in lines[0].split(",")][:2] != ["frame_x", "frame_y"]:
        return None
    return np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]], np.float64)

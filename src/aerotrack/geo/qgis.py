"""Ground-control points in any map CRS: QGIS georeferencer ``.points`` files and CRS-tagged CSVs.

Two files an analyst brings instead of a hand-made homography:

* **QGIS georeferencer** ``.points`` (saved by *Georeferencer > Save GCP Points As*)::

      #CRS: PROJCRS["Korea 2000 / Central Belt 2010", ...]
      mapX,mapY,sourceX,sourceY,enable,dX,dY,residual
      170201.12,532274.39,3193.18,-1283.13,1,0,0,0

  The optional first line carries the WKT of the map coordinates' CRS. ``sourceX, sourceY`` are
  the frame pixel column and the **negated** pixel row (QGIS puts a non-georeferenced image's y
  axis upwards); older QGIS versions call them ``pixelX, pixelY``. Rows with ``enable = 0`` are
  ignored; at least 4 enabled points are needed.

* **CSV in a named CRS** (``--map-init``)::

      # crs: EPSG:5186
      frame_x,frame_y,crs_x,crs_y
      3193.18,1283.13,170201.12,532274.39

  ``crs_x, crs_y`` are easting/northing (or lon/lat, x first) in the CRS named by a
  ``# crs: <anything pyproj reads>`` comment line before the header (``EPSG:5186``, ``EPSG:4326``,
  a WKT or PROJ string). Without that line the map's own CRS is assumed.

Frame pixels follow aerotrack's convention (continuous, origin at the top-left corner of the
top-left pixel), which is also QGIS's for raster pixel coordinates.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import FormatError, GeoreferenceError, InputError
from ..io.textfile import read_text


@dataclass(frozen=True)
class ControlPoints:
    """Ground-control points: frame pixels paired with coordinates in a map CRS.

    Attributes
    ----------
    frame_xy : ndarray, shape (N, 2)
        Frame pixels (col, row).
    crs_xy : ndarray, shape (N, 2)
        The same points in ``crs`` (x = easting or longitude).
    crs : pyproj.CRS or None
        The CRS of ``crs_xy``; None means "the map's CRS".
    label : str
        File (and option) the points came from, for messages.
    """

    frame_xy: np.ndarray
    crs_xy: np.ndarray
    crs: Any
    label: str

    def to_target(self, target: Any = None) -> np.ndarray:
        """(N, 2) control points in ``target``: a GeoMap (its map pixels), a CRS, or None (as read)."""
        from pyproj import CRS, Transformer
        from pyproj.exceptions import CRSError

        from .maprast import GeoMap

        if target is None:
            return self.crs_xy.copy()
        if isinstance(target, GeoMap):
            dst_crs = CRS.from_user_input(target.crs.to_wkt())
        else:
            try:
                dst_crs = CRS.from_user_input(target)
            except CRSError as exc:
                raise InputError(f"{self.label}: target CRS {target!r} not understood ({exc})") from None
        xy = self.crs_xy
        if self.crs is not None and not self.crs.equals(dst_crs):
            t = Transformer.from_crs(self.crs, dst_crs, always_xy=True)
            x, y = t.transform(xy[:, 0], xy[:, 1])
            xy = np.column_stack([x, y])
            if not np.all(np.isfinite(xy)):
                raise GeoreferenceError(f"{self.label}: control points fall outside the map's CRS")
        if isinstance(target, GeoMap):
            return target.crs_to_pixel(xy)
        return xy

    def homography(self, target: Any = None) -> np.ndarray:
        """Least-squares homography frame pixels -> ``target`` (map pixels for a GeoMap).

        Raises
        ------
        FormatError
            Fewer than 4 points, or collinear/repeated points.
        GeoreferenceError
            No homography fits.
        """
        return fit_homography(self.frame_xy, self.to_target(target), self.label)


def fit_homography(src: np.ndarray, dst: np.ndarray, label: str) -> np.ndarray:
    """Fit a 3x3 homography ``src -> dst`` to >= 4 non-collinear point pairs (least squares)."""
    src = np.asarray(src, np.float64).reshape(-1, 2)
    dst = np.asarray(dst, np.float64).reshape(-1, 2)
    if len(src) < 4:
        raise FormatError(f"{label}: needs at least 4 enabled ground-control points, found {len(src)}")
    for name, q in (("frame", src), ("map", dst)):
        c = q - q.mean(axis=0)
        sv = np.linalg.svd(c, compute_uv=False)
        if sv[0] == 0 or sv[1] < 1e-6 * sv[0]:
            raise FormatError(f"{label}: the {name} control points are collinear or repeated")
    # Normalise the map side: projected coordinates of 1e5-1e6 m make the DLT ill-conditioned.
    mu, sc = dst.mean(axis=0), max(float(np.abs(dst - dst.mean(axis=0)).max()), 1e-12)
    T = np.array([[1 / sc, 0, -mu[0] / sc], [0, 1 / sc, -mu[1] / sc], [0, 0, 1]])
    H, _ = cv2.findHomography(src, (dst - mu) / sc, 0)
    if H is None or not np.all(np.isfinite(H)):
        raise GeoreferenceError(f"{label}: cannot fit a homography to the control points")
    H = np.linalg.inv(T) @ H
    return H / H[2, 2]




def _parse_crs(text: str, label: str, lineno: int):
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return CRS.from_user_input(text.strip())
    except CRSError as exc:
        raise FormatError(f"{label} line {lineno}: CRS not understood ({str(exc)[:80]})") from None


def _table(text: str, label: str) -> tuple[list[str], list[tuple[int, list[str]]], Any]:
    """Split a CSV with optional ``#CRS:``/``# crs:`` comment into header, numbered rows, CRS."""
    crs = None
    header: list[str] | None = None
    rows: list[tuple[int, list[str]]] = []
    for lineno, ln in enumerate(text.splitlines(), start=1):
        s = ln.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s[1:].strip()
            if body.lower().startswith("crs:") and crs is None:
                crs = _parse_crs(body[4:], label, lineno)
            continue
        cells = [c.strip() for c in next(csv.reader(io.StringIO(s)))]
        if header is None:
            header = [c.lower() for c in cells]
        else:
            rows.append((lineno, cells))
    if header is None:
        raise FormatError(f"{label}: file is empty")
    return header, rows, crs


def _num(cells: list[str], idx: int, name: str, label: str, lineno: int) -> float:
    try:
        v = float(cells[idx])
    except (ValueError, IndexError):
        raise FormatError(f"{label} line {lineno}: {name} is missing or not a number") from None
    if not np.isfinite(v):
        raise FormatError(f"{label} line {lineno}: {name} is NaN or infinite")
    return v


_PRETTY = {"sourcex": "sourceX", "sourcey": "sourceY", "pixelx": "pixelX", "pixely": "pixelY"}


def read_qgis_points(path: str | Path, *, option: str = "--map-init") -> ControlPoints:
    """Read a QGIS georeferencer ``.points`` file (see the module docstring).

    Raises
    ------
    InputError, FormatError
        Missing file, wrong header, a malformed row (message names the line), an unreadable CRS,
        or fewer than 4 enabled points.
    """
    p = Path(path)
    label = f"{option} {p}"
    header, rows, crs = _table(read_text(p, label), label)
    src_names = (("sourcex", "sourcey"), ("pixelx", "pixely"))
    try:
        ix_map = header.index("mapx"), header.index("mapy")
        sx = next(n for n in src_names if n[0] in header and n[1] in header)
    except (ValueError, StopIteration):
        raise FormatError(f"{label}: header must be mapX,mapY,sourceX,sourceY,enable,... "
                          f"(QGIS georeferencer points), found {','.join(header)!r}") from None
    ix_src = header.index(sx[0]), header.index(sx[1])
    ix_en = header.index("enable") if "enable" in header else None
    frame, mapxy = [], []
    for lineno, cells in rows:
        if len(cells) < len(header):
            raise FormatError(f"{label} line {lineno}: expected {len(header)} values, "
                              f"found {len(cells)}")
        if ix_en is not None and _num(cells, ix_en, "enable", label, lineno) == 0:
            continue
        mx = _num(cells, ix_map[0], "mapX", label, lineno)
        my = _num(cells, ix_map[1], "mapY", label, lineno)
        fx = _num(cells, ix_src[0], _PRETTY[sx[0]], label, lineno)
        fy = _num(cells, ix_src[1], _PRETTY[sx[1]], label, lineno)
        frame.append([fx, -fy])  # QGIS source y is the negated pixel row
        mapxy.append([mx, my])
    if len(frame) < 4:
        raise FormatError(f"{label}: needs at least 4 enabled ground-control points, "
                          f"found {len(frame)}")
    return ControlPoints(np.asarray(frame, np.float64).reshape(-1, 2),
                         np.asarray(mapxy, np.float64).reshape(-1, 2), crs, label)


def read_crs_gcps(path: str | Path, *, option: str = "--map-init") -> ControlPoints:
    """Read a ``frame_x,frame_y,crs_x,crs_y`` CSV with a ``# crs: ...`` line (module docstring)."""
    p = Path(path)
    label = f"{option} {p}"
    header, rows, crs = _table(read_text(p, label), label)
    if header != ["frame_x", "frame_y", "crs_x", "crs_y"]:
        raise FormatError(f"{label}: header must be frame_x,frame_y,crs_x,crs_y, "
                          f"found {','.join(header)!r}")
    pts = []
    for lineno, cells in rows:
        if len(cells) != 4:
            raise FormatError(f"{label} line {lineno}: expected 4 comma-separated numbers, "
                              f"found {len(cells)}")
        pts.append([_num(cells, i, header[i], label, lineno) for i in range(4)])
    if len(pts) < 4:
        raise FormatError(f"{label}: needs at least 4 ground-control points, found {len(pts)}")
    a = np.asarray(pts, np.float64)
    return ControlPoints(a[:, :2], a[:, 2:], crs, label)


def write_qgis_points(path: str | Path, frame_xy: np.ndarray, map_xy: np.ndarray,
                      crs: Any = None) -> None:
    """Write a QGIS georeferencer ``.points`` file (frame pixels -> map CRS coordinates)."""
    from pyproj import CRS

    lines = []
    if crs is not None:
        lines.append("#CRS: " + CRS.from_user_input(crs).to_wkt())
    lines.append("mapX,mapY,sourceX,sourceY,enable,dX,dY,residual")
    for (fx, fy), (mx, my) in zip(np.asarray(frame_xy).reshape(-1, 2),
                                  np.asarray(map_xy).reshape(-1, 2)):
        lines.append(f"{mx:.10g},{my:.10g},{fx:.10g},{-fy:.10g},1,0,0,0")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")

"""Scope: regions of interest / ignore masks, and the minimum-speed filter for tracks.

A region is one or more polygons, in frame pixels or on the map. Files:

* **GeoJSON** (``.geojson`` / ``.json``): a FeatureCollection, Feature or geometry of
  ``Polygon`` / ``MultiPolygon``. Coordinates are lon/lat (RFC 7946) unless the top-level object has
  ``"aerotrack_space": "frame"`` (frame pixels), ``"map_pixels"`` (map pixels), or a legacy
  ``"crs": {"properties": {"name": "EPSG:XXXX"}}`` member (coordinates in that CRS). Holes are
  honoured.
* **CSV of vertices** with a header: ``x,y`` (frame pixels), ``map_x,map_y`` (map pixels),
  ``lon,lat``, or ``crs_x,crs_y`` with a ``# crs: EPSG:XXXX`` line; an optional first column
  ``polygon`` (an integer) separates several polygons. Vertices in order, >= 3 per polygon.

Lon/lat and CRS polygons are converted to map pixels with the map at load time, so that
:meth:`Region.inside` tests the pipeline's world coordinates (map pixels) directly.

Whether a region keeps what is inside (``include``, a region of interest) or drops it (``ignore``,
an ignore mask) is the caller's choice (:meth:`Region.keep`).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError, InputError
from ..io.textfile import read_text
from ..types import Track

SPACES = ("frame", "world")


@dataclass(frozen=True)
class Region:
    """Polygons in one coordinate frame.

    Attributes
    ----------
    polygons : list of list of ndarray
        Each polygon is ``[exterior, hole, hole, ...]``, each ring an (M, 2) float64 array.
    space : str
        ``frame`` (frame pixels of each frame: the region is fixed on the screen) or ``world``
        (map pixels with a map, frame-1 pixels without: the region is fixed on the ground).
    mode : str
        ``include`` (keep what is inside) or ``ignore`` (drop what is inside).
    source : str
    """

    polygons: list = field(default_factory=list)
    space: str = "world"
    mode: str = "include"
    source: str = "<region>"

    def __post_init__(self) -> None:
        if self.space not in SPACES:
            raise InputError(f"{self.source}: region space must be one of {SPACES}, got {self.space!r}")
        if self.mode not in ("include", "ignore"):
            raise InputError(f"{self.source}: region mode must be include or ignore, got {self.mode!r}")

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which of the (N, 2) points (in ``space``) lie inside any polygon.

        Points on an edge count as inside (within 1e-9 units).
        """
        from matplotlib.path import Path as MplPath

        pts = np.asarray(points, np.float64).reshape(-1, 2)
        res = np.zeros(len(pts), bool)
        for rings in self.polygons:
            hit = MplPath(rings[0]).contains_points(pts, radius=1e-9) | MplPath(
                rings[0]).contains_points(pts, radius=-1e-9)
            for hole in rings[1:]:
                hit &= ~MplPath(hole).contains_points(pts, radius=-1e-9) & ~MplPath(
                    hole).contains_points(pts, radius=1e-9)
            res |= hit
        return res

    def keep(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points to keep (inside for ``include``, outside for ``ignore``)."""
        ins = self.inside(points)
        return ins if self.mode == "include" else ~ins

    def keep_detections(self, frame_points: np.ndarray, world_points: np.ndarray) -> np.ndarray:
        """(N,) keep mask for detections given their ground points in both frames."""
        return self.keep(frame_points if self.space == "frame" else world_points)


def frame_mask(regions, size: tuple[int, int]) -> np.ndarray | None:
    """The frame pixels the frame-space ``ignore`` regions leave to work on: (H, W) uint8, 0
    inside any of them, 255 elsewhere (``size`` is (W, H)); None without such regions. The
    detector neither looks for vehicles there nor lets those pixels into its background (a
    burned-in caption or timestamp stays put on the screen while the ground moves under it, so
    it differs from every background sample). ``include`` regions still act on detections only:
    a vehicle crossing a region of interest's edge keeps its whole box."""
    import cv2

    ignore = [r for r in regions or [] if r.space == "frame" and r.mode == "ignore"]
    if not ignore:
        return None
    w, h = size
    inside = np.zeros((h, w), np.uint8)
    for r in ignore:
        for rings in r.polygons:
            one = np.zeros((h, w), np.uint8)
            cv2.fillPoly(one, [np.round(rings[0]).astype(np.int32)], 255)
            for hole in rings[1:]:
                cv2.fillPoly(one, [np.round(hole).astype(np.int32)], 0)
            inside = np.maximum(inside, one)
    return 255 - inside


def _ring(coords: Any, label: str) -> np.ndarray:
    try:
        a = np.asarray(coords, np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"{label}: polygon coordinates must be numbers") from None
    if a.ndim != 2 or a.shape[1] < 2 or len(a) < 3 or not np.all(np.isfinite(a)):
        raise FormatError(f"{label}: each polygon ring needs >= 3 finite [x, y] vertices")
    a = a[:, :2]
    if np.allclose(a[0], a[-1]) and len(a) > 3:
        a = a[:-1]
    return a


def _geojson_polygons(obj: Any, label: str) -> list[list[np.ndarray]]:
    if not isinstance(obj, dict):
        raise FormatError(f"{label}: not a GeoJSON object")
    t = obj.get("type")
    if t == "FeatureCollection":
        return [p for f in obj.get("features", []) for p in _geojson_polygons(f, label)]
    if t == "Feature":
        return _geojson_polygons(obj.get("geometry") or {}, label)
    if t == "Polygon":
        return [[_ring(r, label) for r in obj.get("coordinates", [])]]
    if t == "MultiPolygon":
        return [[_ring(r, label) for r in poly] for poly in obj.get("coordinates", [])]
    if t == "GeometryCollection":
        return [p for g in obj.get("geometries", []) for p in _geojson_polygons(g, label)]
    raise FormatError(f"{label}: geometry type {t!r} is not a Polygon or MultiPolygon")


def _to_world(polygons, kind: str, crs: Any, geomap: Any, label: str):
    """Convert lonlat/crs rings to map pixels."""
    if kind in ("frame", "map_pixels"):
        return polygons
    if geomap is None:
        raise InputError(f"{label}: a region in lon/lat or a map CRS needs --map "
                         f"(or give it in frame pixels)")
    if kind == "lonlat":
        return [[geomap.lonlat_to_pixel(r) for r in rings] for rings in polygons]
    from pyproj import CRS, Transformer

    t = Transformer.from_crs(crs, CRS.from_user_input(geomap.crs.to_wkt()), always_xy=True)

    def conv(r):
        x, y = t.transform(r[:, 0], r[:, 1])
        return geomap.crs_to_pixel(np.column_stack([x, y]))

    return [[conv(r) for r in rings] for rings in polygons]


def read_region(path: str | Path, geomap: Any = None, *, mode: str = "include",
                option: str = "--roi") -> Region:
    """Read a region file (GeoJSON or CSV of vertices; see the module docstring).

    Parameters
    ----------
    path : path
    geomap : GeoMap, optional
        Needed for lon/lat or CRS polygons (converted to map pixels).
    mode : str
        ``include`` (region of interest) or ``ignore`` (ignore mask).
    option : str
        Command-line option named in messages (``--roi``, ``--ignore``).

    Raises
    ------
    InputError, FormatError
        Missing/unreadable file, bad JSON, non-polygon geometry, a ring with < 3 vertices, a bad
        CSV row (the message names the line).
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    p = Path(path)
    label = f"{option} {p}"
    text = read_text(p, label)
    crs = None
    if p.suffix.lower() in (".geojson", ".json"):
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FormatError(f"{label} line {exc.lineno}: not valid JSON ({exc.msg})") from None
        polys = _geojson_polygons(obj, label)
        space = obj.get("aerotrack_space") if isinstance(obj, dict) else None
        if space in ("frame", "map_pixels"):
            kind = space
        elif isinstance(obj, dict) and isinstance(obj.get("crs"), dict):
            props = obj["crs"].get("properties")
            name = props.get("name") if isinstance(props, dict) else None
            try:
                crs = CRS.from_user_input(name)
            except CRSError:
                raise FormatError(f"{label}: crs {name!r} not understood") from None
            kind = "lonlat" if crs.equals(CRS.from_epsg(4326)) else "crs"
        elif space is None:
            kind = "lonlat"
        else:
            raise FormatError(f"{label}: aerotrack_space must be 'frame' or 'map_pixels', "
                              f"got {space!r}")
    else:
        polys, kind, crs = _csv_polygons(text, label)
    if not polys:
        raise FormatError(f"{label}: no polygons found")
    polys = _to_world(polys, kind, crs, geomap, label)
    if geomap is not None and kind != "frame":
        _check_on_map(polys, geomap, label, mode)
    return Region(polygons=polys, space="frame" if kind == "frame" else "world", mode=mode,
                  source=label)


def _check_on_map(polys, geomap: Any, label: str, mode: str) -> None:
    """A region in ground coordinates that misses the map: an include region leaves nothing to
    track (refused), an ignore region ignores nothing (a warning). Swapped lon/lat or a wrong
    CRS are the usual causes."""
    pts = np.vstack([ring for poly in polys for ring in poly])
    finite = np.isfinite(pts).all(axis=1)
    if finite.any():
        lo, hi = pts[finite].min(axis=0), pts[finite].max(axis=0)
        if hi[0] >= 0 and hi[1] >= 0 and lo[0] <= geomap.width and lo[1] <= geomap.height:
            return
    why = (f"lies outside the map ({geomap.width}x{geomap.height} px; the region spans map "
           f"pixels {lo[0]:.0f}..{hi[0]:.0f} x {lo[1]:.0f}..{hi[1]:.0f})" if finite.any()
           else "has no vertex that lands on the map")
    hint = "check the lon/lat order (GeoJSON is lon, lat) and the CRS"
    if mode == "include":
        raise InputError(f"{label}: {why}: nothing could be tracked; {hint}")
    import logging

    logging.getLogger(__name__).warning("%s: %s: it ignores nothing; %s", label, why, hint)


_CSV_KINDS = {("x", "y"): "frame", ("frame_x", "frame_y"): "frame",
              ("map_x", "map_y"): "map_pixels", ("lon", "lat"): "lonlat",
              ("crs_x", "crs_y"): "crs"}


def _csv_polygons(text: str, label: str):
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    crs = None
    header = None
    groups: dict[int, list[list[float]]] = {}
    for lineno, ln in enumerate(text.splitlines(), start=1):
        s = ln.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s[1:].strip()
            if body.lower().startswith("crs:"):
                try:
                    crs = CRS.from_user_input(body[4:].strip())
                except CRSError:
                    raise FormatError(f"{label} line {lineno}: CRS not understood") from None
            continue
        cells = [c.strip() for c in next(csv.reader(io.StringIO(s)))]
        if header is None:
            header = [c.lower() for c in cells]
            has_id = header[0] == "polygon"
            key = tuple(header[1:] if has_id else header)
            if key not in _CSV_KINDS:
                raise FormatError(f"{label} line {lineno}: header must be [polygon,]x,y or "
                                  f"map_x,map_y or lon,lat or crs_x,crs_y; found {s!r}")
            kind = _CSV_KINDS[key]
            continue
        if len(cells) != len(header):
            raise FormatError(f"{label} line {lineno}: expected {len(header)} values, "
                              f"found {len(cells)}")
        try:
            vals = [float(c) for c in cells]
        except ValueError:
            raise FormatError(f"{label} line {lineno}: non-numeric value") from None
        if not all(math.isfinite(v) for v in vals):
            raise FormatError(f"{label} line {lineno}: NaN or infinite value")
        gid = int(vals[0]) if has_id else 0
        groups.setdefault(gid, []).append(vals[-2:])
    if header is None:
        raise FormatError(f"{label}: file is empty")
    if kind == "crs" and crs is None:
        raise FormatError(f"{label}: crs_x,crs_y vertices need a '# crs: EPSG:XXXX' line")
    polys = []
    for gid, verts in groups.items():
        if len(verts) < 3:
            raise FormatError(f"{label}: polygon {gid} has {len(verts)} vertices, needs >= 3")
        polys.append([_ring(verts, label)])
    return polys, kind, crs


# -- minimum-speed filter --------------------------------------------------------------------
def track_max_speed(track: Track, fps: float, metres_per_unit: float | None = None, *,
                    window_s: float = 2.0, smooth_s: float = 0.5,
                    kinds: tuple[str, ...] = ("observed",)) -> float:
    """The fastest a track moved over any ``window_s`` seconds, metres per second.

    The positions are first smoothed by a centred running median over ``smooth_s``; the speed over
    a window is then the net displacement between the smoothed positions at both ends of the
    window, divided by the elapsed time. Net displacement over seconds (rather than frame-to-frame
    steps) of median positions keeps the centroid jitter of a parked car's detections from looking
    like motion: jitter of ``j`` metres reads as roughly ``2 j / window_s`` m/s at worst. A track
    shorter than the window uses its whole span.

    Parameters
    ----------
    track : Track
        Points with ``world`` positions (world units) and 1-based frames.
    fps : float
    metres_per_unit : float, optional
        Metres per world unit; None = speeds in world units per second.
    window_s : float
        Longer windows suppress jitter better but need the vehicle to move for that long.
    smooth_s : float
        Running-median width, seconds (0 disables); wider rejects more jitter but rounds off
        starts and stops.
    kinds : tuple of str
        Point kinds used (predicted and bridged positions are not evidence of motion).

    Returns
    -------
    float
        0 for a track with fewer than two usable points.
    """
    pts = [p for p in track.points if p.kind in kinds]
    if len(pts) < 2:
        return 0.0
    t = np.array([(p.frame - 1) / fps for p in pts])
    xy = np.array([p.world for p in pts], np.float64).reshape(-1, 2)
    scale = 1.0 if metres_per_unit is None else float(metres_per_unit)
    span = t[-1] - t[0]
    if span <= 0:
        return 0.0
    if smooth_s > 0:  # centred running median: detection jitter is not motion
        lo = np.searchsorted(t, t - smooth_s / 2 - 1e-9, side="left")
        hi = np.searchsorted(t, t + smooth_s / 2 + 1e-9, side="right")
        xy = np.array([np.median(xy[a:b], axis=0) for a, b in zip(lo, hi)])
    w = min(window_s, span)
    j = np.searchsorted(t, t + w - 1e-9, side="left")
    j = np.minimum(j, len(t) - 1)
    dt = t[j] - t
    ok = dt >= 0.5 * w
    if not ok.any():
        return 0.0
    d = np.hypot(*(xy[j[ok]] - xy[ok]).T) * scale
    return float(np.max(d / dt[ok]))


def filter_min_speed(tracks: list[Track], min_speed_mps: float, fps: float,
                     metres_per_unit: float | None = None, *,
                     window_s: float = 2.0, smooth_s: float = 0.5) -> list[Track]:
    """Drop tracks that never move faster than ``min_speed_mps`` (parked vehicles).

    A track is kept when :func:`track_max_speed` over ``window_s`` reaches ``min_speed_mps`` at
    least once: a car that waits at a light and then drives off is kept whole; one that never moves
    is dropped. Without a scale (``metres_per_unit`` None) the threshold is in world units per
    second. ``min_speed_mps <= 0`` keeps every track.

    Raising ``min_speed_mps`` removes more parked cars (and their jitter) but also slow crawlers in
    queues; raising ``window_s`` tolerates noisier detections but drops vehicles seen moving for
    less than that.
    """
    if not fps > 0:
        raise InputError(f"--fps {fps}: must be positive")
    if min_speed_mps <= 0:
        return list(tracks)
    return [tr for tr in tracks
            if track_max_speed(tr, fps, metres_per_unit, window_s=window_s,
                               smooth_s=smooth_s) >= min_speed_mps]

"""GIS outputs: ``tracks.geojson`` (RFC 7946) and, with the ``gis`` extra, a GeoPackage.

One Feature per track, a LineString through the track's ground points in time order, in EPSG:4326
lon/lat (RFC 7946 has no other CRS). The properties carry, per vertex, the frame, the time in
seconds since frame 1, whether the target was in view (``tracks.csv``) or predicted out of view
(``predicted.csv``), and the speed; and per track, its extent in frames and time, its counts and
length. A track seen in a single frame becomes a two-vertex LineString with both vertices equal
(a valid geometry GIS tools open, unlike a one-vertex LineString). Longitudes are given in
[-180, 180) whatever the map's own coordinates say (a map across the antimeridian may run past
180), and a track that crosses the antimeridian is cut there into a MultiLineString (RFC 7946
3.1.9); the per-vertex lists then follow the parts' vertices in order.

:func:`write_tracks_gpkg` (Python API) writes the same lines (per-vertex lists as JSON text, as
GeoPackage fields are scalar) in layer ``tracks``, and one Point per vertex in layer
``track_points``; ``aerotrack track`` writes ``observations.gpkg`` (one Point per row) and
``track_segments.gpkg`` (each track's in-view and predicted stretches as lines) instead, in a
projected CRS (:mod:`aerotrack.io.geotable`).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import GeoreferenceError, InputError, install_extra
from .output import atomic_write_text

DECIMALS = 8  # ~1 mm at the equator; the contract asks for at least 7


def document_crs(doc: dict, label: str):
    """The CRS of a GeoJSON document: its legacy ``crs`` member, else WGS 84 lon/lat (RFC 7946).

    ``label`` starts the one-line :class:`InputError` of a malformed or unknown CRS."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    member = doc.get("crs")
    props = member.get("properties") if isinstance(member, dict) else None
    name = props.get("name") if isinstance(props, dict) else None
    if member is not None and not isinstance(name, str):
        raise InputError(f"{label}: malformed crs member (expected properties.name)")
    if not name:
        return CRS.from_epsg(4326)
    try:
        return CRS.from_user_input(name)
    except CRSError:
        raise InputError(f"{label}: unknown crs {name!r}") from None


def _merge(tracks_rows: np.ndarray, predicted_rows: np.ndarray | None) -> np.ndarray:
    """(N, 11) rows of both files with a last column 1 = in view, 0 = predicted; one row per
    (id, frame), in-view rows winning."""
    t = np.asarray(tracks_rows, dtype=np.float64).reshape(-1, 10)
    parts = [np.column_stack([t, np.ones(len(t))])]
    if predicted_rows is not None and len(predicted_rows):
        p = np.asarray(predicted_rows, dtype=np.float64).reshape(-1, 10)
        parts.append(np.column_stack([p, np.zeros(len(p))]))
    rows = np.vstack(parts)
    rows = rows[(rows[:, 7] != -1) | (rows[:, 8] != -1)]
    rows = rows[np.all(np.isfinite(rows[:, 7:9]), axis=1)]
    rows = rows[np.lexsort((-rows[:, 10], rows[:, 0], rows[:, 1]))]
    keep = np.r_[True, (np.diff(rows[:, 1]) != 0) | (np.diff(rows[:, 0]) != 0)] if len(rows) else []
    return rows[keep] if len(rows) else rows


#: Width of the centred window of :func:`window_motion`, seconds (``observations.csv`` uses the
#: same): per-vertex differences turned half a metre of box jitter at 30 frames/s into 30 m/s.
SPEED_WINDOW_S = 0.5


def window_ends(times: np.ndarray, smooth_s: float = SPEED_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """For each of a track's increasing ``times`` (seconds), the indices of the first and last
    vertex within ``smooth_s / 2`` of it, widened to its neighbours when none is (equal where a
    vertex has no neighbour): the ends of :func:`window_motion`'s centred window."""
    tt = np.asarray(times, dtype=np.float64)
    n = len(tt)
    half = smooth_s / 2.0
    lo = np.searchsorted(tt, tt - half - 1e-9, side="left")
    hi = np.searchsorted(tt, tt + half + 1e-9, side="right") - 1
    lo = np.where(hi == lo, np.maximum(lo - 1, 0), lo)
    hi = np.where(hi == lo, np.minimum(hi + 1, n - 1), hi)
    return lo, hi


def window_motion(lonlat: np.ndarray, times: np.ndarray, smooth_s: float = SPEED_WINDOW_S
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Ground speed (m/s) and compass azimuth (degrees clockwise from true north) at each vertex
    of one track, over a centred window of ``smooth_s`` seconds (geodesic, WGS 84).

    The window's ends are the first and last vertices within ``smooth_s / 2`` of the vertex
    (widened to its neighbours when none is); (N, 2) lon/lat degrees and increasing (N,)
    seconds in; NaN where a vertex has no neighbour.
    """
    from pyproj import Geod

    n = len(lonlat)
    speed = np.full(n, np.nan)
    azimuth = np.full(n, np.nan)
    if n < 2:
        return speed, azimuth
    tt = np.asarray(times, dtype=np.float64)
    lo, hi = window_ends(tt, smooth_s)
    ok = hi > lo
    az, _, dist = Geod(ellps="WGS84").inv(lonlat[lo[ok], 0], lonlat[lo[ok], 1],
                                          lonlat[hi[ok], 0], lonlat[hi[ok], 1])
    speed[ok] = np.asarray(dist) / (tt[hi[ok]] - tt[lo[ok]])
    azimuth[ok] = np.mod(np.asarray(az), 360.0)
    return speed, azimuth


def vertex_speeds(lonlat: np.ndarray, times: np.ndarray, smooth_s: float = SPEED_WINDOW_S
                  ) -> np.ndarray:
    """Speed at each vertex, metres per second: :func:`window_motion`'s (0 where undefined), as
    ``observations.csv``'s ``speed_mps``. (N, 2) lon/lat degrees and (N,) seconds in."""
    speed, _ = window_motion(np.asarray(lonlat, dtype=np.float64), times, smooth_s)
    return np.where(np.isfinite(speed), speed, 0.0)


def wrap_lon(lonlat: np.ndarray) -> np.ndarray:
    """(N, 2) lon/lat with longitudes brought into [-180, 180)."""
    out = np.array(lonlat, dtype=np.float64, copy=True)
    out[:, 0] = (out[:, 0] + 180.0) % 360.0 - 180.0
    return out


def line_geometry(coords: list[list[float]]) -> dict[str, Any]:
    """A GeoJSON LineString through ``coords`` (lon in [-180, 180)), or a MultiLineString cut
    where consecutive vertices are more than 180 degrees of longitude apart (the antimeridian)."""
    parts, start = [], 0
    for i in range(1, len(coords)):
        if abs(coords[i][0] - coords[i - 1][0]) > 180.0:
            parts.append(coords[start:i])
            start = i
    parts.append(coords[start:])
    if len(parts) == 1:
        return {"type": "LineString", "coordinates": coords}
    # each part ends (and the next begins) on the antimeridian, at the latitude where the segment
    # crosses it (RFC 7946 3.1.9): without it the parts stopped short of it (a 0.3 m gap)
    for k in range(len(parts) - 1):
        (x0, y0), (x1, y1) = parts[k][-1][:2], parts[k + 1][0][:2]
        side = 180.0 if x0 > 0 else -180.0
        span = (x1 + 360.0 if side > 0 else x1 - 360.0) - x0
        f = (side - x0) / span if span else 0.5
        lat = round(y0 + f * (y1 - y0), DECIMALS)
        parts[k] = [*parts[k], [side, lat]]
        parts[k + 1] = [[-side, lat], *parts[k + 1]]
    parts = [p * 2 if len(p) == 1 else p for p in parts]
    return {"type": "MultiLineString", "coordinates": parts}


def tracks_feature_collection(tracks_rows: np.ndarray, predicted_rows: np.ndarray | None, geomap,
                              fps: float, start_time=None,
                              kinds: dict[tuple[int, int], str] | None = None) -> dict[str, Any]:
    """Build the GeoJSON FeatureCollection (a dict) of a run's tracks.

    Parameters
    ----------
    tracks_rows : ndarray, shape (N, 10)
        ``tracks.csv`` rows: frame (1-based), id, box (frame pixels), conf, x, y (map CRS), z.
    predicted_rows : ndarray, shape (M, 10) or None
        ``predicted.csv`` rows, same columns.
    geomap : aerotrack.geo.GeoMap
        The run's map (its CRS turns ``x, y`` into lon/lat).
    fps : float
        Frame rate: time of frame n is ``(n - 1) / fps`` seconds.
    start_time : datetime, optional
        Wall-clock time of frame 1 (timezone-aware): each feature also gets ``start_time_utc``
        and ``end_time_utc`` (ISO 8601; GDAL reads them as date-times, for QGIS's temporal
        controller).
    kinds : dict (frame, id) -> str, optional
        Kind of each in-view row (``observed``, ``bridged``: filled between sightings,
        ``stationary``: held standing still), as ``observations.csv``'s ``kind``; rows not in it
        are ``observed``, predicted rows ``predicted``. Per vertex in ``kind``, counted in
        ``n_observed``, ``n_bridged``, ``n_stationary`` and ``n_predicted``.

    Rows whose ``x, y`` are both -1 (no map position) are left out. ``length_m`` is the whole
    line's (predictions after the last sighting included); ``in_view_length_m`` sums the steps
    between consecutive in-view vertices only (the report's distance also smooths positions).
    """
    if geomap is None:
        raise GeoreferenceError("tracks.geojson needs a map (--map): rows have no map coordinates")
    if not (fps > 0):
        raise InputError(f"--fps {fps}: must be positive")
    rows = _merge(tracks_rows, predicted_rows)
    features = []
    if len(rows):
        lonlat_all = geomap.crs_to_lonlat(rows[:, 7:9])
        for tid in np.unique(rows[:, 1]).astype(np.int64):
            sel = rows[:, 1] == tid
            r, ll = rows[sel], lonlat_all[sel]
            frames = r[:, 0].astype(np.int64)
            times = (frames - 1) / float(fps)
            observed = r[:, 10] > 0
            speeds = vertex_speeds(ll, times)
            coords = np.round(wrap_lon(ll), DECIMALS).tolist()
            if len(coords) == 1:
                coords = coords * 2
            from pyproj import Geod

            geod = Geod(ellps="WGS84")
            length = float(geod.line_length(ll[:, 0], ll[:, 1])) if len(ll) > 1 else 0.0
            step_in_view = observed[1:] & observed[:-1] & (np.diff(frames) == 1)
            in_view_length = float(np.sum(np.asarray(geod.inv(
                ll[:-1, 0], ll[:-1, 1], ll[1:, 0], ll[1:, 1])[2])[step_in_view])) \
                if len(ll) > 1 else 0.0
            kind = [("predicted" if not o else (kinds or {}).get((int(f), int(tid)), "observed"))
                    for f, o in zip(frames, observed)]
            features.append({
                "type": "Feature",
                "id": int(tid),
                "geometry": line_geometry(coords),
                "properties": {
                    "id": int(tid),
                    "first_frame": int(frames[0]),
                    "last_frame": int(frames[-1]),
                    "start_time_s": round(float(times[0]), 4),
                    "end_time_s": round(float(times[-1]), 4),
                    "n_vertices": int(len(frames)),
                    "n_observed": kind.count("observed"),
                    "n_bridged": kind.count("bridged"),
                    "n_stationary": kind.count("stationary"),
                    "n_predicted": kind.count("predicted"),
                    "length_m": round(length, 3),
                    "in_view_length_m": round(in_view_length, 3),
                    "mean_speed_mps": round(float(np.mean(speeds)), 3) if len(speeds) else 0.0,
                    "frames": frames.tolist(),
                    "times_s": np.round(times, 4).tolist(),
                    # 0/1, not JSON booleans: GDAL reads a list of booleans as a boolean
                    # integer list that pyogrio and geopandas could not read (the whole file failed)
                    "observed": observed.astype(int).tolist(),
                    "kind": kind,
                    "speeds_mps": np.round(speeds, 3).tolist(),
                    "conf": np.round(r[:, 6], 4).tolist(),
                },
            })
            if start_time is not None:
                from .geotable import frame_times, iso_utc

                first, last = iso_utc(frame_times(frames[[0, -1]], fps, start_time))
                features[-1]["properties"].update(start_time_utc=first, end_time_utc=last)
    return {"type": "FeatureCollection", "features": features}


def write_tracks_geojson(path: str | Path, tracks_rows: np.ndarray, predicted_rows: np.ndarray | None,
                         geomap, fps: float, start_time=None,
                         kinds: dict[tuple[int, int], str] | None = None) -> Path:
    """Write ``tracks.geojson`` atomically (see :func:`tracks_feature_collection`)."""
    fc = tracks_feature_collection(tracks_rows, predicted_rows, geomap, fps, start_time, kinds)
    atomic_write_text(path, json.dumps(fc, separators=(",", ":")) + "\n")
    return Path(path)


def _wkb_linestring(coords: list[list[float]]) -> bytes:
    return struct.pack(f"<BII{2 * len(coords)}d", 1, 2, len(coords), *np.ravel(coords))


def _wkb_multilinestring(parts: list[list[list[float]]]) -> bytes:
    return struct.pack("<BII", 1, 5, len(parts)) + b"".join(_wkb_linestring(p) for p in parts)


def _vertices(geom: dict[str, Any]) -> list[list[float]]:
    """A track line's vertices, one per frame: a MultiLineString's parts joined without the
    vertices :func:`line_geometry` put on the antimeridian."""
    if geom["type"] == "LineString":
        return geom["coordinates"]
    parts = geom["coordinates"]
    out: list[list[float]] = []
    for k, p in enumerate(parts):
        out += p[1 if k > 0 else 0:len(p) - 1 if k < len(parts) - 1 else len(p)]
    return out


def _wkb_point(x: float, y: float) -> bytes:
    return struct.pack("<BIdd", 1, 1, x, y)


def write_tracks_gpkg(path: str | Path, tracks_rows: np.ndarray, predicted_rows: np.ndarray | None,
                      geomap, fps: float) -> Path:
    """Write a GeoPackage with layers ``tracks`` (LineString per track) and ``track_points``
    (Point per vertex: id, frame, time_s, observed, speed_mps), EPSG:4326.

    Needs ``pyogrio`` (``pip install 'aerotrack[gis]'``).
    """
    try:
        import pyogrio.raw
    except ImportError:
        raise InputError(f"GeoPackage output needs pyogrio: {install_extra('gis')}") from None
    fc = tracks_feature_collection(tracks_rows, predicted_rows, geomap, fps)
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    tmp.unlink(missing_ok=True)
    feats = fc["features"]
    # a track across the antimeridian is a MultiLineString: then the layer's every line is one
    multi = any(f["geometry"]["type"] == "MultiLineString" for f in feats)
    geoms = np.array([_wkb_multilinestring(f["geometry"]["coordinates"]
                                           if f["geometry"]["type"] == "MultiLineString"
                                           else [f["geometry"]["coordinates"]]) if multi
                      else _wkb_linestring(f["geometry"]["coordinates"]) for f in feats],
                     dtype=object)
    scalar = ["id", "first_frame", "last_frame", "start_time_s", "end_time_s", "n_observed",
              "n_bridged", "n_stationary", "n_predicted", "length_m", "in_view_length_m",
              "mean_speed_mps"]
    lists = ["frames", "times_s", "observed", "kind", "speeds_mps"]
    data = [np.array([f["properties"][k] for f in feats]) for k in scalar]
    data += [np.array([json.dumps(f["properties"][k]) for f in feats], dtype=object) for k in lists]
    from .geotable import gpkg_date

    with gpkg_date():
        pyogrio.raw.write(tmp, geoms, data, scalar + lists, layer="tracks", driver="GPKG",
                          geometry_type="MultiLineString" if multi else "LineString",
                          crs="EPSG:4326")
    pts, cols = [], {k: [] for k in ("id", "frame", "time_s", "observed", "speed_mps")}
    for f in feats:
        p = f["properties"]
        vertices = _vertices(f["geometry"])
        for i, fr in enumerate(p["frames"]):
            x, y = vertices[i]
            pts.append(_wkb_point(x, y))
            cols["id"].append(p["id"])
            cols["frame"].append(fr)
            cols["time_s"].append(p["times_s"][i])
            cols["observed"].append(int(p["observed"][i]))
            cols["speed_mps"].append(p["speeds_mps"][i])
    with gpkg_date():
        pyogrio.raw.write(tmp, np.array(pts, dtype=object),
                          [np.asarray(v) for v in cols.values()], list(cols),
                          layer="track_points", driver="GPKG", geometry_type="Point",
                          crs="EPSG:4326", append=True)
    tmp.replace(path)
    return path

"""The per-observation geo table: one row per (frame, track) for a GIS.

Columns (CSV header, GeoPackage fields and Parquet columns alike):

==============  ==============================================================================
frame           1-based frame number
time_s          seconds since frame 1, ``(frame - 1) / fps``
time_utc        (with a start time only, the last column) ``time_s`` after frame 1's wall-clock
                time, ISO 8601 UTC with milliseconds
id              track id (as in ``tracks.csv``)
lon, lat        WGS 84 degrees of the ground point (8 decimals)
x, y            the ground point in the output CRS (metres; the local UTM zone by default)
crs             the output CRS, e.g. ``EPSG:32652``
speed_mps       ground speed, m/s, over a centred window of ``smooth_s`` (geodesic distance)
heading_deg     direction of travel, degrees clockwise from true north (geodesic azimuth);
                empty when the target moves less than ``min_heading_speed_mps``
length_m        ground size of the box's longer side, metres
width_m         ground size of the box's shorter side, metres
kind            rows of ``tracks.csv``: ``observed`` (a detection), ``bridged`` (interpolated
                across a short run of missed detections) or ``stationary`` (standing still
                where the detector lost it); rows of ``predicted.csv``: ``predicted``
==============  ==============================================================================

Box sizes: the box (frame pixels) is measured on the ground by mapping the midpoints of its sides
through that frame's homography (frame pixels -> map pixels, from ``registration.csv``), so they
are correct for axis-aligned vehicles and overestimate the length and width of a vehicle that is
diagonal in the frame (an axis-aligned box cannot tell its orientation). Without a homography for
the frame they are empty, or ``frame_gsd`` x the box sides when a frame scale is given.

The GeoPackage (``pyogrio``, extra ``gis``) holds one point layer ``observations`` in the output
CRS, and ``track_segments.gpkg`` beside it one line layer ``track_segments`` (:func:`track_segments`: each
track's path in pieces, in view and predicted apart, for styling); the Parquet file (written when ``pyarrow`` is installed) is GeoParquet 1.0: the same columns
plus a WKB point ``geometry`` in the output CRS (``geo`` metadata with the CRS as PROJJSON, so
``geopandas.read_parquet`` and GDAL open it as a layer; the short CRS name is also in a ``crs`` key).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError, InputError, OutputError, install_extra
from ..types import apply_homography
from .output import atomic_write

COLUMNS = ("frame", "time_s", "id", "lon", "lat", "x", "y", "crs", "speed_mps", "heading_deg",
           "length_m", "width_m", "kind")
#: Columns written only when asked for: ``time_utc`` with a start time (``track --start-time``).
OPTIONAL_COLUMNS = ("time_utc",)


def _names(cols: dict[str, np.ndarray]) -> list[str]:
    """The table's columns present in ``cols``, in order."""
    return [c for c in (*COLUMNS, *OPTIONAL_COLUMNS) if c in cols]


def frame_times(frames: np.ndarray, fps: float, start_time) -> np.ndarray:
    """UTC ``datetime64[ms]`` of 1-based ``frames``: ``start_time`` (an aware datetime, frame 1's)
    plus ``(frame - 1) / fps`` seconds."""
    import datetime

    t0 = np.datetime64(start_time.astimezone(datetime.UTC).replace(tzinfo=None), "ms")
    offset = np.round((np.asarray(frames, np.float64) - 1) / float(fps) * 1000).astype(np.int64)
    return t0 + offset.astype("timedelta64[ms]")


def iso_utc(t: np.ndarray) -> list[str]:
    """``datetime64`` values as ISO 8601 UTC text with milliseconds: ``2024-05-01T10:30:00.033Z``."""
    return [f"{v}Z" for v in np.asarray(t, "datetime64[ms]")]


def utm_crs_for(lon: float, lat: float) -> str:
    """The WGS 84 UTM zone holding (lon, lat), as ``EPSG:326zz`` (north) or ``EPSG:327zz`` (south).

    The standard 6-degree zones (the Norway/Svalbard exceptions are not applied: a neighbouring
    zone is still a valid, slightly less accurate, metric CRS there).
    """
    if not (math.isfinite(lon) and math.isfinite(lat) and -90 <= lat <= 90):
        raise InputError(f"cannot choose a UTM zone for lon/lat ({lon}, {lat})")
    zone = int(math.floor(((lon + 180.0) % 360.0) / 6.0)) + 1
    return f"EPSG:{(32600 if lat >= 0 else 32700) + min(zone, 60)}"


def read_registration_csv(path: str | Path) -> dict[int, np.ndarray]:
    """``registration.csv`` -> {frame: (3, 3) homography frame pixels -> world}.

    Reads the header ``frame,h00,...,h22[,...]``; extra columns are ignored.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: file not found")
    lines = p.read_text(encoding="utf-8-sig").splitlines()
    if not lines:
        raise FormatError(f"{p}: file is empty")
    header = [h.strip() for h in lines[0].split(",")]
    want = ["frame"] + [f"h{i}{j}" for i in range(3) for j in range(3)]
    try:
        idx = [header.index(w) for w in want]
    except ValueError:
        raise FormatError(f"{p} line 1: header must start frame,h00,...,h22") from None
    out = {}
    for lineno, ln in enumerate(lines[1:], start=2):
        if not ln.strip():
            continue
        cells = ln.split(",")
        try:
            vals = [float(cells[i]) for i in idx]
        except (ValueError, IndexError):
            raise FormatError(f"{p} line {lineno}: expected frame and 9 numbers") from None
        out[int(vals[0])] = np.asarray(vals[1:]).reshape(3, 3)
    return out


def _rows(arr: Any, name: str) -> np.ndarray:
    a = np.asarray(arr if arr is not None else np.zeros((0, 10)), np.float64)
    if a.size == 0:
        return np.zeros((0, 10))
    if a.ndim != 2 or a.shape[1] < 6:
        raise InputError(f"{name}: expected MOT rows of 6 to 10 columns, got shape {a.shape}")
    if a.shape[1] < 10:
        a = np.hstack([a, np.full((len(a), 10 - a.shape[1]), -1.0)])
    return a[:, :10]


def _ordered_rows(rows: Any, predicted: Any, kinds: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """``tracks.csv`` and ``predicted.csv`` rows together, sorted by (id, frame, predicted last),
    with each row's kind (``kinds`` of the in-view rows; ``observed`` where not given)."""
    obs, pred = _rows(rows, "tracks"), _rows(predicted, "predicted")
    a = np.vstack([obs, pred])
    kinds = kinds or {}
    kind = np.array([kinds.get((int(r[0]), int(r[1])), "observed") for r in obs]
                    + ["predicted"] * len(pred), dtype=object)
    order = np.lexsort((kind == "predicted", a[:, 0], a[:, 1]))
    return a[order], kind[order]


def _nearest_homography(homs: dict[int, np.ndarray], fps: float):
    """``f -> H`` of frame ``f``, or of the nearest registered frame within half a second: a frame
    without one of its own (skipped by --stride, or a row bridged over a frame that failed) is
    hardly moved from it, and the box is the track's, not that frame's measurement."""
    registered = np.array(sorted(homs), dtype=np.int64)
    reach = max(1, int(round(0.5 * fps)))

    def near(f: int):
        if f in homs or not len(registered):
            return homs.get(f)
        k = int(np.searchsorted(registered, f))
        cand = [registered[j] for j in (k - 1, k) if 0 <= j < len(registered)]
        best = min(cand, key=lambda g: abs(int(g) - f))
        return homs[int(best)] if abs(int(best) - f) <= reach else None

    return near


#: The ``crs`` of a table without a map (``track --gsd``): metres in frame 1's ground plane.
LOCAL_CRS = "LOCAL:frame1_metres"
#: ... and with ``track --ground``: metres in the ground plane it gives, its axes as given.
GROUND_CRS = "LOCAL:ground_metres"


def local_observation_table(rows: Any, fps: float, metres_per_unit: float, *,
                            predicted: Any = None,
                            homographies: dict[int, np.ndarray] | None = None,
                            smooth_s: float = 0.5, min_heading_speed_mps: float = 0.5,
                            kinds: dict[tuple[int, int], str] | None = None, start_time=None,
                            ground: bool = False) -> tuple[dict[str, np.ndarray], str]:
    """The table's columns for a run without a map but with a ground resolution (``--gsd``).

    With ``ground`` (``track --ground``: world units are metres of the ground plane the user
    gave) x, y are that plane's coordinates as given and ``crs`` is :data:`GROUND_CRS`.

    x, y are metres on the ground plane of frame 1 (where the run's world coordinates are: frame
    1's pixels), x to the right and y up in frame 1's image, from its top-left corner; heading is
    clockwise from frame 1's up; lon and lat are empty and ``crs`` is :data:`LOCAL_CRS`. Speed,
    heading and box sizes are measured as with a map (the same centred window), in the plane.
    ``homographies``: frame pixels -> world (frame-1 pixels) per frame; rows are placed through
    them (``tracks.csv``'s x, y are -1 without a map).
    """
    from .geojson import window_ends

    if not fps > 0:
        raise InputError(f"--fps {fps}: must be positive")
    if not metres_per_unit or metres_per_unit <= 0:
        raise InputError(f"--gsd {metres_per_unit}: must be a positive number of metres per pixel")
    a, kind = _ordered_rows(rows, predicted, kinds)
    n = len(a)
    frame, ids = a[:, 0].astype(np.int64), a[:, 1].astype(np.int64)
    boxes = a[:, 2:6]
    near = _nearest_homography(homographies or {}, fps)
    # image rows grow down, y grows up (a ground plane's axes are the user's)
    flip = np.array([metres_per_unit, metres_per_unit if ground else -metres_per_unit])
    crs = GROUND_CRS if ground else LOCAL_CRS
    xy = np.full((n, 2), np.nan)
    length = np.full(n, np.nan)
    width = np.full(n, np.nan)
    for i in range(n):
        H = near(int(frame[i]))
        if H is None:
            continue
        H = np.asarray(H, np.float64)
        bx, by, bw, bh = boxes[i]
        pts = apply_homography(H, np.array([[bx + bw / 2, by + bh / 2], [bx, by + bh / 2],
                                  [bx + bw, by + bh / 2], [bx + bw / 2, by],
                                  [bx + bw / 2, by + bh]]))
        if not np.isfinite(pts).all():
            continue
        xy[i] = pts[0] * flip
        sw = float(np.hypot(*(pts[2] - pts[1]))) * metres_per_unit
        sh = float(np.hypot(*(pts[4] - pts[3]))) * metres_per_unit
        length[i], width[i] = max(sw, sh), min(sw, sh)
    t = (frame - 1) / float(fps)
    speed = np.full(n, np.nan)
    heading = np.full(n, np.nan)
    good = np.isfinite(xy).all(axis=1)
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    for s, e in zip(starts, np.r_[starts[1:], n]):
        idx = np.arange(s, e)
        idx = idx[good[idx]]
        _, first = np.unique(frame[idx], return_index=True)  # observed before predicted
        idx = idx[first]
        if len(idx) < 2:
            continue
        lo, hi = window_ends(t[idx], smooth_s)
        ok = hi > lo
        d = xy[idx[hi[ok]]] - xy[idx[lo[ok]]]
        v = np.hypot(d[:, 0], d[:, 1]) / (t[idx[hi[ok]]] - t[idx[lo[ok]]])
        hd = np.where(v >= min_heading_speed_mps,
                      np.mod(np.degrees(np.arctan2(d[:, 0], d[:, 1])), 360.0), np.nan)
        per_frame = dict(zip(frame[idx[ok]].tolist(), zip(v.tolist(), hd.tolist())))
        for i in range(s, e):
            if int(frame[i]) in per_frame:
                speed[i], heading[i] = per_frame[int(frame[i])]
    cols = {"frame": frame, "time_s": t, "id": ids, "lon": np.full(n, np.nan),
            "lat": np.full(n, np.nan), "x": xy[:, 0], "y": xy[:, 1],
            "crs": np.array([crs] * n, dtype=object), "speed_mps": speed,
            "heading_deg": heading, "length_m": length, "width_m": width, "kind": kind}
    if start_time is not None:
        cols["time_utc"] = frame_times(frame, fps, start_time)
    return cols, crs


def write_local_observation_table(path: str | Path, rows: Any, fps: float,
                                  metres_per_unit: float, **kwargs: Any) -> Path:
    """Write :func:`local_observation_table` as ``observations.csv`` (CSV only: GIS formats need
    a CRS, which a run without a map has not)."""
    cols, _ = local_observation_table(rows, fps, metres_per_unit, **kwargs)
    p = Path(path).with_suffix(".csv")
    _write_csv(p, cols)
    return p


def observation_table(rows: Any, geomap: Any, fps: float, out_crs: Any = None, *,
                      predicted: Any = None, homographies: dict[int, np.ndarray] | None = None,
                      frame_gsd: float | None = None, smooth_s: float = 0.5,
                      min_heading_speed_mps: float = 0.5,
                      kinds: dict[tuple[int, int], str] | None = None, start_time=None
                      ) -> tuple[dict[str, np.ndarray], str]:
    """Compute the table's columns (see the module docstring) without writing anything.

    Parameters
    ----------
    rows : ndarray, shape (N, 10)
        ``tracks.csv`` rows: frame, id, box (frame pixels), conf, x, y (map CRS ground point), z.
    geomap : GeoMap
        The map whose CRS x, y are in (and whose pixels the homographies map to).
    fps : float
    out_crs : CRS-like, optional
        Projected output CRS (anything pyproj reads); default the UTM zone of the median position.
    predicted : ndarray, shape (M, 10), optional
        ``predicted.csv`` rows (kind ``predicted``).
    homographies : dict {frame: (3, 3)}, optional
        Frame pixels -> map pixels per frame (:func:`read_registration_csv`). Used for box sizes,
        and for the ground point of rows whose x, y are -1.
    frame_gsd : float, optional
        Metres per frame pixel for box sizes in frames without a homography.
    smooth_s : float
        Width of the centred window for speed and heading, seconds. Wider is smoother but lags
        through turns and stops.
    min_heading_speed_mps : float
        Below this speed the heading is left empty (the direction of jitter is meaningless).
    kinds : dict {(frame, id): str}, optional
        What each ``tracks.csv`` row is (``observed``, ``bridged``, ``stationary``); rows not
        in it are ``observed``.
    start_time : datetime, optional
        Wall-clock time of frame 1 (timezone-aware): adds ``time_utc`` (a GIS time slider's
        field; a date-time field in the GeoPackage, a UTC timestamp in the Parquet file).

    Returns
    -------
    columns : dict of str -> ndarray
        One array per column in :data:`COLUMNS`, rows sorted by (id, frame, kind).
    crs : str
        The output CRS as ``AUTH:CODE`` (``EPSG:32611+5773`` for a compound one), or as a PROJ
        string if it has no code (:func:`crs_label`).
    """
    from pyproj import CRS, Geod, Transformer

    from .geojson import window_motion

    if geomap is None:
        raise InputError("observation table: needs a map (--map) for lon/lat and the output CRS")
    if not fps > 0:
        raise InputError(f"--fps {fps}: must be positive")
    a, kind = _ordered_rows(rows, predicted, kinds)
    n = len(a)
    frame, ids = a[:, 0].astype(np.int64), a[:, 1].astype(np.int64)
    boxes = a[:, 2:6]
    mapxy = a[:, 7:9].copy()
    missing = np.all(mapxy == -1, axis=1) | ~np.isfinite(mapxy).all(axis=1)
    homs = homographies or {}
    centre = boxes[:, :2] + boxes[:, 2:] / 2
    for i in np.flatnonzero(missing):
        H = homs.get(int(frame[i]))
        mapxy[i] = geomap.pixel_to_crs(apply_homography(H, centre[i:i + 1]))[0] if H is not None else np.nan
    lonlat = np.full((n, 2), np.nan)
    good = np.isfinite(mapxy).all(axis=1)
    if good.any():
        from .geojson import wrap_lon

        lonlat[good] = wrap_lon(geomap.crs_to_lonlat(mapxy[good]))  # a map may run past 180

    if out_crs is None:  # the UTM zone of the rows, or of the map's centre (no row: empty table)
        if good.any():  # median longitude taken about the first (rows across the antimeridian)
            lon0 = lonlat[good][0, 0]
            med = np.median(lonlat[good], axis=0)
            med[0] = np.median((lonlat[good, 0] - lon0 + 180.0) % 360.0 - 180.0) + lon0
            med[0] = (med[0] + 180.0) % 360.0 - 180.0
        else:
            med = geomap.pixel_to_lonlat(np.array([[geomap.width / 2, geomap.height / 2]]))[0]
        out_crs = utm_crs_for(float(med[0]), float(med[1]))
    ocrs = projected_crs(out_crs)
    crs_name = crs_label(ocrs)
    to_out = Transformer.from_crs(CRS.from_epsg(4326), ocrs, always_xy=True)
    xy = np.full((n, 2), np.nan)
    if good.any():
        x, y = to_out.transform(lonlat[good, 0], lonlat[good, 1])
        xy[good] = np.column_stack([x, y])

    # Speed and heading: geodesic over a centred window within each track.
    geod = Geod(ellps="WGS84")
    t = (frame - 1) / float(fps)
    speed = np.full(n, np.nan)
    heading = np.full(n, np.nan)
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ends = np.r_[starts[1:], n]
    for s, e in zip(starts, ends):
        idx = np.arange(s, e)
        idx = idx[good[idx]]
        # one position per frame (an observed and a predicted row of one frame: keep observed)
        _, first = np.unique(frame[idx], return_index=True)
        idx = idx[first]
        if len(idx) < 2:
            continue
        v, az = window_motion(lonlat[idx], t[idx], smooth_s)
        ok = np.isfinite(v)
        v, hd = v[ok], np.where(v[ok] >= min_heading_speed_mps, az[ok], np.nan)
        # spread the per-frame values to every row of that frame in this track
        per_frame = dict(zip(frame[idx[ok]].tolist(), zip(v.tolist(), hd.tolist())))
        for i in range(s, e):
            if int(frame[i]) in per_frame:
                speed[i], heading[i] = per_frame[int(frame[i])]

    # Box ground sizes via the frame's homography (or a frame GSD).
    length = np.full(n, np.nan)
    width = np.full(n, np.nan)
    homography_near = _nearest_homography(homs, fps)
    for i in range(n):
        bx, by, bw, bh = boxes[i]
        H = homography_near(int(frame[i]))
        if H is not None:
            mids = np.array([[bx, by + bh / 2], [bx + bw, by + bh / 2],
                             [bx + bw / 2, by], [bx + bw / 2, by + bh]])
            m = geomap.pixel_to_lonlat(apply_homography(H, mids))
            if np.all(np.isfinite(m)):
                _, _, d = geod.inv(m[[0, 2], 0], m[[0, 2], 1], m[[1, 3], 0], m[[1, 3], 1])
                sw, sh = float(d[0]), float(d[1])
            else:
                continue
        elif frame_gsd is not None:
            sw, sh = abs(bw) * frame_gsd, abs(bh) * frame_gsd
        else:
            continue
        length[i], width[i] = max(sw, sh), min(sw, sh)

    cols = {"frame": frame, "time_s": t, "id": ids, "lon": lonlat[:, 0], "lat": lonlat[:, 1],
            "x": xy[:, 0], "y": xy[:, 1], "crs": np.array([crs_name] * n, dtype=object),
            "speed_mps": speed, "heading_deg": heading, "length_m": length, "width_m": width,
            "kind": kind}
    if start_time is not None:
        cols["time_utc"] = frame_times(frame, fps, start_time)
    return cols, crs_name


def projected_crs(out_crs, option: str = "--out-crs"):
    """``out_crs`` as a pyproj CRS with projected coordinates (a projected CRS, or a compound one
    whose horizontal part is projected), else a one-line :class:`InputError`: geographic (degrees),
    geocentric (x, y, z from the Earth's centre) and vertical CRSs give no map x, y."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_user_input(out_crs)
    except CRSError:
        raise InputError(f"{option} {out_crs}: unknown CRS") from None
    if not crs.is_projected:
        kind = ("geographic (degrees)" if crs.is_geographic else
                "geocentric" if crs.is_geocentric else
                "vertical" if crs.is_vertical else crs.type_name)
        raise InputError(f"{option} {out_crs}: must be a projected CRS (x, y in metres or feet), "
                         f"not {kind}")
    return crs


def crs_label(crs) -> str:
    """A short, comma-free name of a CRS for a table column: ``AUTH:CODE``, ``EPSG:32611+5773``
    for a compound CRS of two codes, else its PROJ string (a custom CRS's WKT is long and full of
    commas, which broke the CSV's columns)."""
    import warnings

    auth = crs.to_authority()
    if auth:
        return f"{auth[0]}:{auth[1]}"
    parts = [c.to_authority() for c in crs.sub_crs_list]
    if parts and all(parts) and len({a for a, _ in parts}) == 1:
        return f"{parts[0][0]}:" + "+".join(code for _, code in parts)
    with warnings.catch_warnings():  # "may lose important projection information"
        warnings.simplefilter("ignore")
        text = crs.to_proj4()
    return text.replace(" +type=crs", "").strip() if text else crs.to_wkt()


def _fmt(v: Any, digits: int, turn: bool = False) -> str:
    """``v`` as text with ``digits`` decimals; ``turn``: an angle in [0, 360), so a value that
    rounds to 360 is written as 0."""
    if isinstance(v, (str, np.str_)):
        text = str(v)
        if any(c in text for c in ',"\n\r'):  # CSV quoting (RFC 4180)
            text = '"' + text.replace('"', '""') + '"'
        return text
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if not np.isfinite(v):
        return ""
    text = f"{v:.{digits}f}"
    if turn and float(text) >= 360.0:
        text = f"{0.0:.{digits}f}"
    return text


_DIGITS = {"time_s": 4, "lon": 8, "lat": 8, "x": 3, "y": 3, "speed_mps": 3, "heading_deg": 2,
           "length_m": 3, "width_m": 3}


def _write_csv(path: Path, cols: dict[str, np.ndarray]) -> None:
    n = len(cols["frame"])
    names = _names(cols)
    text = {c: np.array(iso_utc(cols[c]), dtype=object) for c in names if c == "time_utc"}
    with atomic_write(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(names) + "\n")
        for i in range(n):
            fh.write(",".join(_fmt(text[c][i] if c in text else cols[c][i], _DIGITS.get(c, 0),
                                   c == "heading_deg") for c in names) + "\n")


@contextlib.contextmanager
def gpkg_date():
    """GDAL stamps a GeoPackage's ``gpkg_contents.last_change`` with the time of writing, so two
    identical runs gave different files; with ``SOURCE_DATE_EPOCH`` set (the reproducible-builds
    convention: seconds since 1970, UTC) that time is used instead, and the files are equal."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if not epoch:
        yield
        return
    import datetime

    from pyogrio import set_gdal_config_options

    try:
        when = datetime.datetime.fromtimestamp(int(epoch), datetime.UTC)
    except (ValueError, OverflowError, OSError):
        raise InputError(f"SOURCE_DATE_EPOCH={epoch!r}: not a number of seconds since "
                         "1970-01-01") from None
    set_gdal_config_options({"OGR_CURRENT_DATE": when.strftime("%Y-%m-%dT%H:%M:%S.000Z")})
    try:
        yield
    finally:
        set_gdal_config_options({"OGR_CURRENT_DATE": None})


def _point_wkbs(cols: dict[str, np.ndarray]) -> list[bytes | None]:
    """Each row's ground point (x, y in the output CRS) as little-endian WKB, None without one:
    the GeoPackage's and the GeoParquet's geometry."""
    return [struct.pack("<BIdd", 1, 1, a, b) if np.isfinite(a) and np.isfinite(b) else None
            for a, b in zip(np.asarray(cols["x"], np.float64), np.asarray(cols["y"], np.float64))]


def track_segments(cols: dict[str, np.ndarray]) -> tuple[list[bytes], dict[str, np.ndarray]]:
    """Each track's path cut where it goes from in view to predicted and back: (WKB LineStrings
    in the output CRS, columns ``id``, ``in_view`` (1: observed, bridged or stationary rows; 0:
    predicted), ``first_frame``, ``last_frame``, ``length_m``: geodesic, from the rows' lon/lat).
    A piece ends on the next one's first point, so the pieces join; a single predicted row at a
    track's end makes no piece of its own (a line needs two points). ``tracks.geojson`` draws a track as one line through both,
    which a GIS cannot style apart (its per-vertex lists read as text there: a probe)."""
    from pyproj import Geod

    geod = Geod(ellps="WGS84")  # lengths on the ground: --out-crs may be in feet, or 3857
    ids = np.asarray(cols["id"]).astype(np.int64)
    frames = np.asarray(cols["frame"]).astype(np.int64)
    x, y = np.asarray(cols["x"], np.float64), np.asarray(cols["y"], np.float64)
    lon = np.asarray(cols["lon"], np.float64) if "lon" in cols else None
    lat = np.asarray(cols["lat"], np.float64) if "lat" in cols else None
    seen = np.asarray(cols["kind"]).astype(str) != "predicted"
    geoms: list[bytes] = []
    out: dict[str, list] = {"id": [], "in_view": [], "first_frame": [], "last_frame": [],
                            "length_m": []}
    for tid in np.unique(ids):
        idx = np.flatnonzero((ids == tid) & np.isfinite(x) & np.isfinite(y))
        idx = idx[np.argsort(frames[idx], kind="stable")]
        if len(idx) < 2:
            continue
        cuts = np.flatnonzero(np.diff(seen[idx].astype(np.int8))) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(idx)]):
            part = idx[a:min(b + 1, len(idx))]  # to the next piece's first point
            if len(part) < 2:
                continue
            xy = np.column_stack([x[part], y[part]])
            geoms.append(struct.pack("<BII", 1, 2, len(xy)) + xy.astype("<f8").tobytes())
            out["id"].append(int(tid))
            out["in_view"].append(int(seen[idx[a]]))
            out["first_frame"].append(int(frames[part[0]]))
            out["last_frame"].append(int(frames[part[-1]]))
            if lon is not None and np.all(np.isfinite(lon[part])) and np.all(np.isfinite(lat[part])):
                length = float(geod.line_length(lon[part], lat[part]))
            else:
                length = float("nan")
            out["length_m"].append(round(length, 2))
    return geoms, {k: np.asarray(v, np.float64 if k == "length_m" else np.int64)
                   for k, v in out.items()}


def _write_gpkg(path: Path, cols: dict[str, np.ndarray], crs_name: str) -> None:
    try:
        from pyogrio.raw import write
    except ImportError:
        raise InputError(f"GeoPackage output needs pyogrio: {install_extra('gis')}") from None
    geom = np.array(_point_wkbs(cols), dtype=object)
    names = [c for c in _names(cols) if c != "crs"]
    data = []
    for c in names:
        v = cols[c]
        data.append(v.astype(str) if v.dtype == object else v)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    try:
        crs = crs_name
        if crs_name.startswith("+"):  # a PROJ string (no code): the GeoPackage gets the full WKT
            from pyproj import CRS

            crs = CRS.from_user_input(crs_name).to_wkt()
        with gpkg_date():
            write(str(tmp), geom, data, names, layer="observations", driver="GPKG",
                  geometry_type="Point", crs=crs)
        os.replace(tmp, path)
    except (OSError, RuntimeError, ValueError) as exc:  # pyogrio's errors are RuntimeErrors
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise OutputError(f"{path}: cannot write the GeoPackage ({exc})") from None


def _write_segments_gpkg(path: Path, cols: dict[str, np.ndarray], crs_name: str) -> None:
    """``track_segments.gpkg``: one layer ``track_segments`` (:func:`track_segments`; a file of its own: a
    second layer in observations.gpkg made every plain read of it warn)."""
    from pyogrio.raw import write

    segs, seg_cols = track_segments(cols)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    try:
        crs = crs_name
        if crs_name.startswith("+"):
            from pyproj import CRS

            crs = CRS.from_user_input(crs_name).to_wkt()
        with gpkg_date():
            write(str(tmp), np.array(segs, dtype=object), list(seg_cols.values()),
                  list(seg_cols), layer="track_segments", driver="GPKG", geometry_type="LineString",
                  crs=crs)
        os.replace(tmp, path)
    except (OSError, RuntimeError, ValueError) as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise OutputError(f"{path}: cannot write the GeoPackage ({exc})") from None


def _write_parquet(path: Path, cols: dict[str, np.ndarray], crs_name: str) -> None:
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq
    from pyproj import CRS

    x, y = np.asarray(cols["x"], np.float64), np.asarray(cols["y"], np.float64)
    geometry = _point_wkbs(cols)
    data = {c: (cols[c].astype(str) if cols[c].dtype == object else cols[c])
            for c in _names(cols) if c != "time_utc"}
    if "time_utc" in cols:
        data["time_utc"] = pa.array(np.asarray(cols["time_utc"], "datetime64[ms]"),
                                    type=pa.timestamp("ms", tz="UTC"))
    data["geometry"] = pa.array(geometry, type=pa.binary())
    ok = np.isfinite(x) & np.isfinite(y)
    # GeoParquet 1.0 (geopandas.read_parquet, GDAL): WKB points, the CRS as PROJJSON
    geo = {"version": "1.0.0", "primary_column": "geometry",
           "columns": {"geometry": {
               "encoding": "WKB", "geometry_types": ["Point"],
               "crs": json.loads(CRS.from_user_input(crs_name).to_json()),
               **({"bbox": [float(x[ok].min()), float(y[ok].min()), float(x[ok].max()),
                            float(y[ok].max())]} if ok.any() else {})}}}
    table = pa.table(data).replace_schema_metadata({"geo": json.dumps(geo), "crs": crs_name})
    with atomic_write(path, "wb") as fh:
        pq.write_table(table, fh)


def write_observation_table(path: str | Path, rows: Any, geomap: Any, fps: float,
                            out_crs: Any = None, *, predicted: Any = None,
                            homographies: dict[int, np.ndarray] | None = None,
                            formats: tuple[str, ...] | None = None,
                            **kwargs: Any) -> dict[str, Path]:
    """Write the per-observation table as CSV, GeoPackage and Parquet.

    Parameters
    ----------
    path : path
        The CSV path (``observations.csv``); the GeoPackage and Parquet files share its stem.
    rows, geomap, fps, out_crs, predicted, homographies, **kwargs
        See :func:`observation_table`.
    formats : tuple of str, optional
        Any of ``csv``, ``gpkg``, ``parquet``. Default: ``csv``, plus ``gpkg`` when pyogrio and
        ``parquet`` when pyarrow is importable. Asking for one whose library is missing raises
        an InputError naming the extra to install.

    Returns
    -------
    dict of str -> Path
        The files written, by format (``segments_gpkg``: ``track_segments.gpkg`` beside the
        GeoPackage).
    """
    p = Path(path)
    if formats is None:
        formats = ("csv",) + tuple(f for f, mod in (("gpkg", "pyogrio"), ("parquet", "pyarrow"))
                                   if _importable(mod))
        missing = [f"{p.stem}.{f}" for f in ("gpkg", "parquet") if f not in formats]
        if missing:
            logging.getLogger(__name__).info("%s not written: it needs the gis extra, %s",
                                             " and ".join(missing), install_extra("gis"))
    if "parquet" in formats and not _importable("pyarrow"):
        raise InputError(f"Parquet output needs pyarrow: {install_extra('gis')}")
    unknown = set(formats) - {"csv", "gpkg", "parquet"}
    if unknown:
        raise InputError(f"table formats {sorted(unknown)}: valid are csv, gpkg, parquet")
    cols, crs_name = observation_table(rows, geomap, fps, out_crs, predicted=predicted,
                                       homographies=homographies, **kwargs)
    out: dict[str, Path] = {}
    if "csv" in formats:
        out["csv"] = p.with_suffix(".csv")
        _write_csv(out["csv"], cols)
    if "gpkg" in formats:
        out["gpkg"] = p.with_suffix(".gpkg")
        _write_gpkg(out["gpkg"], cols, crs_name)
        out["segments_gpkg"] = p.with_name("track_segments.gpkg")
        _write_segments_gpkg(out["segments_gpkg"], cols, crs_name)
    if "parquet" in formats:
        out["parquet"] = p.with_suffix(".parquet")
        _write_parquet(out["parquet"], cols, crs_name)
    return out


def _importable(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None

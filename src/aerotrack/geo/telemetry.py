"""Geo-initialisation from flight telemetry: a pinhole camera over a flat ground plane.

A drone's flight log gives, per frame, where the camera is (lon, lat, height above the ground), where
it looks (heading, gimbal pitch and roll) and how wide it sees (horizontal field of view). Projecting
the frame through that camera onto a flat ground plane gives a first homography frame pixels -> map
pixels, good enough for map refinement (registration) to lock on; the residual error comes from the
log (GPS position, barometric height, compass heading) and from the flat-ground assumption.

Telemetry CSV (``read_telemetry_csv``), comma-separated, one header line, ``#`` lines ignored::

    frame,lon,lat,alt_m,heading_deg,pitch_deg,roll_deg,hfov_deg
    1,126.6629500,37.3889200,146.0,308.0,-90.0,0.0,73.7
    2,126.6629501,37.3889200,146.0,308.1,-90.0,0.0,73.7

* ``frame`` (1-based, as everywhere in aerotrack) **or** ``time_s`` (seconds since frame 1);
* ``lon``, ``lat``: camera position, WGS 84 degrees;
* ``alt_m``: camera height above the ground plane, metres (not above sea level);
* ``heading_deg``: compass azimuth, degrees clockwise from true north, of the direction the camera
  looks (for a nadir camera: the direction the top of the image points to);
* ``pitch_deg``: gimbal pitch, 0 = horizontal, -90 = straight down (nadir); default -90;
* ``roll_deg``: camera roll about its optical axis, positive = the image's right side tilts down
  (clockwise as seen from behind the camera); default 0;
* ``hfov_deg``: horizontal field of view of the frame, degrees; or ``focal_35mm``, the
  35-mm-equivalent focal length in mm, converted with the 36 mm frame width.

Column aliases accepted (so that a parsed DJI log loads as is): ``latitude``, ``longitude``,
``rel_alt`` (height above the take-off point, used as ``alt_m``), ``yaw``/``gb_yaw``/``gimbal_yaw``
(heading), ``gb_pitch``/``gimbal_pitch``, ``gb_roll``/``gimbal_roll``, ``focal_len`` (35-mm-equivalent
focal length, as DJI writes it). Columns a log does not have (most consumer DJI logs have no gimbal
heading) are taken from ``defaults`` or refused with a one-line error naming the column.

The start then goes through :func:`coarse_align` (translation and heading searched against the
map at a coarse scale) so that map refinement, which only looks a few map pixels around its
start, can lock on: see ``benchmarks/telemetry_init.py`` for the numbers on a real DJI log.

DJI SRT subtitles (``read_dji_srt``): the per-frame ``[latitude: ..] [longitude: ..] [rel_alt: ..]
[focal_len: ..]`` blocks of DJI video subtitles (and the older ``GPS(lon,lat,alt)`` form), with the
gimbal angles when the drone writes them (``gb_yaw``, ``gb_pitch``, ``gb_roll``).
"""

from __future__ import annotations

import csv
import functools
import io
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import FormatError, InputError
from ..io.textfile import read_text
from ..types import Failure, apply_homography

#: Width of the 35-mm film frame, mm: ``hfov = 2 atan(36 / (2 f_35mm))``.
FILM_WIDTH_MM = 36.0

_FIELDS = ("lon", "lat", "alt_m", "heading_deg", "pitch_deg", "roll_deg", "hfov_deg")
_ALIASES = {
    "longitude": "lon", "lng": "lon",
    "latitude": "lat",
    "rel_alt": "alt_m", "height_m": "alt_m", "alt": "alt_m",
    "heading": "heading_deg", "yaw": "heading_deg", "yaw_deg": "heading_deg",
    "gb_yaw": "heading_deg", "gimbal_yaw": "heading_deg",
    "pitch": "pitch_deg", "gb_pitch": "pitch_deg", "gimbal_pitch": "pitch_deg",
    "roll": "roll_deg", "gb_roll": "roll_deg", "gimbal_roll": "roll_deg",
    "hfov": "hfov_deg",
    "focal_len": "focal_35mm", "focal_35mm_mm": "focal_35mm",
    "time": "time_s", "t": "time_s",
}
_DEFAULTS = {"pitch_deg": -90.0, "roll_deg": 0.0}


def hfov_from_focal(focal_35mm: float) -> float:
    """Horizontal field of view (degrees) of a 35-mm-equivalent focal length (mm).

    Uses the 36 mm width of the 35-mm frame. Checked on the Songdo DJI log (24 mm): 73.7 deg against
    72.9 deg implied by that flight's frame-to-orthophoto homography (1 % scale error).
    """
    return math.degrees(2.0 * math.atan(FILM_WIDTH_MM / (2.0 * float(focal_35mm))))


@dataclass(frozen=True)
class CameraPose:
    """Where one frame's camera is and where it looks.

    Attributes
    ----------
    lon, lat : float
        Camera position, WGS 84 degrees.
    alt_m : float
        Height above the (flat) ground plane, metres.
    heading_deg, pitch_deg, roll_deg : float
        Compass azimuth of the viewing direction (clockwise from north), gimbal pitch (-90 = nadir),
        roll about the optical axis; degrees. See the module docstring for the signs.
    hfov_deg : float
        Horizontal field of view, degrees.
    """

    lon: float
    lat: float
    alt_m: float
    heading_deg: float
    pitch_deg: float = -90.0
    roll_deg: float = 0.0
    hfov_deg: float = 73.7

    def homography(self, frame_size: tuple[int, int], target: Any, *,
                   max_range_m: float | None = None) -> np.ndarray | Failure:
        """Frame pixels -> ``target`` homography; see :func:`pose_homography`."""
        return pose_homography(self, frame_size, target, max_range_m=max_range_m)


def camera_rotation(heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """(3, 3) rotation from local ENU (east, north, up) to OpenCV camera axes (right, down, forward).

    The forward axis is ``(sin h cos p, cos h cos p, sin p)``; the level right axis is
    ``(cos h, -sin h, 0)``; down = forward x right; roll turns right towards down.
    """
    h, p, r = (math.radians(v) for v in (heading_deg, pitch_deg, roll_deg))
    fwd = np.array([math.sin(h) * math.cos(p), math.cos(h) * math.cos(p), math.sin(p)])
    right = np.array([math.cos(h), -math.sin(h), 0.0])
    down = np.cross(fwd, right)
    right_r = right * math.cos(r) + down * math.sin(r)
    down_r = down * math.cos(r) - right * math.sin(r)
    return np.vstack([right_r, down_r, fwd])


def ground_to_frame_homography(alt_m: float, heading_deg: float, pitch_deg: float,
                               roll_deg: float, hfov_deg: float,
                               frame_size: tuple[int, int]) -> np.ndarray:
    """Homography from ground-plane metres to frame pixels for a pinhole camera.

    Parameters
    ----------
    alt_m, heading_deg, pitch_deg, roll_deg, hfov_deg : float
        The camera (see :class:`CameraPose`).
    frame_size : (int, int)
        (width, height) of the frame in pixels.

    Returns
    -------
    H : ndarray, shape (3, 3)
        (east, north) metres from the point on the ground below the camera -> frame pixels
        (continuous, origin at the top-left corner; the principal point is the frame centre,
        square pixels, no distortion: undistort first with :mod:`aerotrack.geo.lens`).
        ``H = K [r1 r2 -R C]`` with ``C = (0, 0, alt)``.
    """
    w, h = frame_size
    if not (alt_m > 0 and 0 < hfov_deg < 180 and w > 0 and h > 0):
        raise InputError(f"camera: need alt_m > 0 and 0 < hfov_deg < 180, got {alt_m}, {hfov_deg}")
    f = (w / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    K = np.array([[f, 0, w / 2.0], [0, f, h / 2.0], [0, 0, 1.0]])
    R = camera_rotation(heading_deg, pitch_deg, roll_deg)
    t = -R @ np.array([0.0, 0.0, float(alt_m)])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t])
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


@functools.lru_cache(maxsize=16)
def _lonlat_transformer(crs_text: str):
    from pyproj import CRS, Transformer

    return Transformer.from_crs(CRS.from_epsg(4326), CRS.from_user_input(crs_text),
                                always_xy=True)


def _target_transform(target: Any, lon: float, lat: float):
    """A function (N, 2) (E, N) metres around (lon, lat) -> target coordinates.

    ENU metres become lon/lat along geodesics from the camera (the azimuthal equidistant
    projection centred on it, exact in distance and azimuth from the centre), then the target.
    """
    from pyproj import Geod

    from .maprast import GeoMap

    geod = Geod(ellps="WGS84")

    def to_lonlat(en):
        az = np.degrees(np.arctan2(en[:, 0], en[:, 1]))
        lo, la, _ = geod.fwd(np.full(len(en), lon), np.full(len(en), lat), az,
                             np.hypot(en[:, 0], en[:, 1]))
        return np.column_stack([lo, la])

    if isinstance(target, GeoMap):
        return lambda en: target.lonlat_to_pixel(to_lonlat(en))
    from pyproj.exceptions import ProjError

    key = target if isinstance(target, str) else None
    try:
        if key is None:
            from pyproj import CRS

            key = CRS.from_user_input(target).to_wkt()
        t = _lonlat_transformer(key)
    except ProjError as exc:  # CRSError (not a CRS) or a failed transformer
        raise InputError(f"camera target CRS {target!r}: not understood ({exc})") from None

    def fn(en):
        ll = to_lonlat(en)
        x, y = t.transform(ll[:, 0], ll[:, 1])
        return np.column_stack([x, y])

    return fn


def pose_homography(pose: CameraPose, frame_size: tuple[int, int], target: Any, *,
                    max_range_m: float | None = None, grid: int = 7) -> np.ndarray | Failure:
    """The homography frame pixels -> map pixels (or map CRS) seen by a camera over flat ground.

    A ``grid`` x ``grid`` lattice of frame points is cast onto the ground plane (local ENU metres
    around the camera), carried to lon/lat with an azimuthal equidistant projection centred on the
    camera, then into ``target``; a homography is fitted to them by least squares (so the map CRS's
    own curvature over the footprint is absorbed, not assumed away).

    Parameters
    ----------
    pose : CameraPose
    frame_size : (int, int)
        (width, height), frame pixels.
    target : GeoMap or CRS
        A :class:`~aerotrack.geo.GeoMap` (result in its map pixels) or anything
        ``pyproj.CRS.from_user_input`` takes (``"EPSG:5186"``: result in that CRS's units).
    max_range_m : float, optional
        Frame points whose ground point lies farther than this from the camera are left out
        (oblique views near the horizon). Default ``20 * alt_m``.

    Returns
    -------
    H : ndarray (3, 3), normalised ``H[2, 2] = 1``, or Failure
        Failure when fewer than 4 lattice points hit the ground in range (camera looks at the sky).
    """
    w, h = frame_size
    G = ground_to_frame_homography(pose.alt_m, pose.heading_deg, pose.pitch_deg, pose.roll_deg,
                                   pose.hfov_deg, frame_size)
    rng = 20.0 * pose.alt_m if max_range_m is None else float(max_range_m)
    u, v = np.meshgrid(np.linspace(0, w, grid), np.linspace(0, h, grid))
    src = np.column_stack([u.ravel(), v.ravel()])
    hom = np.hstack([src, np.ones((len(src), 1))]) @ np.linalg.inv(G).T
    with np.errstate(divide="ignore", invalid="ignore"):
        en = hom[:, :2] / hom[:, 2:3]
    # A ray hits the ground in front of the camera iff the ground point has positive depth.
    fwd = camera_rotation(pose.heading_deg, pose.pitch_deg, pose.roll_deg)[2]
    with np.errstate(invalid="ignore"):
        depth = en @ fwd[:2] - pose.alt_m * fwd[2]
    ok = np.isfinite(en).all(axis=1) & (depth > 0)
    ok &= np.hypot(en[:, 0], en[:, 1]) <= rng
    if ok.sum() < 4:
        return Failure(f"camera sees the ground at only {int(ok.sum())} of {grid * grid} "
                       f"lattice points within {rng:.0f} m (pitch {pose.pitch_deg} deg)")
    dst = _target_transform(target, pose.lon, pose.lat)(en[ok])
    if not np.all(np.isfinite(dst)):
        return Failure("the camera's footprint falls outside the target CRS")
    # Centre and scale the target side: projected coordinates of 1e5-1e6 m would cost the
    # DLT millimetres of precision (and make numerical derivatives of the pose useless).
    mu = dst.mean(axis=0)
    sc = max(float(np.abs(dst - mu).max()), 1e-12)
    H, _ = cv2.findHomography(src[ok], (dst - mu) / sc, 0)
    if H is None or not np.all(np.isfinite(H)):
        return Failure("cannot fit a homography to the projected frame lattice")
    H = np.array([[sc, 0, mu[0]], [0, sc, mu[1]], [0, 0, 1.0]]) @ H
    return H / H[2, 2]


@dataclass(frozen=True)
class Telemetry:
    """A flight log: one camera pose per row, rows sorted by time.

    Attributes
    ----------
    time_s : ndarray (N,)
        Seconds since frame 1 (``(frame - 1) / fps`` when the log is indexed by frame).
    lon, lat, alt_m, heading_deg, pitch_deg, roll_deg, hfov_deg : ndarray (N,)
        As in :class:`CameraPose`.
    source : str
        The file it came from (for messages).
    """

    time_s: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    alt_m: np.ndarray
    heading_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    hfov_deg: np.ndarray
    source: str = "<telemetry>"

    def __len__(self) -> int:
        return len(self.time_s)

    def pose_at(self, time_s: float) -> CameraPose:
        """The camera pose at ``time_s`` (linear interpolation; angles along the shorter arc).

        Times before the first or after the last row take that row's pose.
        """
        t = self.time_s
        if len(t) == 1 or time_s <= t[0]:
            i, a = 0, 0.0
        elif time_s >= t[-1]:
            i, a = len(t) - 2, 1.0
        else:
            i = int(np.searchsorted(t, time_s, side="right") - 1)
            a = float((time_s - t[i]) / (t[i + 1] - t[i]))
        j = min(i + 1, len(t) - 1)

        def lerp(arr):
            return float(arr[i] + a * (arr[j] - arr[i]))

        def alerp(arr):
            d = (float(arr[j]) - float(arr[i]) + 180.0) % 360.0 - 180.0
            return float(arr[i] + a * d)

        return CameraPose(lon=lerp(self.lon), lat=lerp(self.lat), alt_m=lerp(self.alt_m),
                          heading_deg=alerp(self.heading_deg) % 360.0,
                          pitch_deg=lerp(self.pitch_deg), roll_deg=alerp(self.roll_deg),
                          hfov_deg=lerp(self.hfov_deg))

    def pose_at_frame(self, frame: int, fps: float) -> CameraPose:
        """The camera pose of 1-based ``frame`` at ``fps`` frames per second."""
        return self.pose_at((frame - 1) / float(fps))

    def homography(self, frame: int, fps: float, frame_size: tuple[int, int], target: Any,
                   **kwargs) -> np.ndarray | Failure:
        """Frame pixels -> ``target`` for 1-based ``frame``; see :func:`pose_homography`."""
        return pose_homography(self.pose_at_frame(frame, fps), frame_size, target, **kwargs)


def _build(rows: list[dict[str, float]], label: str, fps: float,
           defaults: dict[str, float] | None) -> Telemetry:
    if not rows:
        raise FormatError(f"{label}: no telemetry rows")
    dflt = {**_DEFAULTS, **(defaults or {})}
    if "focal_35mm" in dflt and "hfov_deg" not in dflt:
        dflt["hfov_deg"] = hfov_from_focal(dflt.pop("focal_35mm"))
    cols: dict[str, list[float]] = {k: [] for k in ("time_s", *_FIELDS)}
    for r in rows:
        line = int(r.pop("_line"))
        if "time_s" in r:
            t = r["time_s"]
        elif "frame" in r:
            if r["frame"] < 1 or not float(r["frame"]).is_integer():
                raise FormatError(f"{label} line {line}: frame must be a positive integer "
                                  f"(1-based), got {r['frame']:g}")
            t = (r["frame"] - 1) / fps
        else:
            raise FormatError(f"{label} line {line}: needs a frame or time_s value")
        if "hfov_deg" not in r and "focal_35mm" in r:
            if not r["focal_35mm"] > 0:
                raise FormatError(f"{label} line {line}: focal length must be positive")
            r["hfov_deg"] = hfov_from_focal(r["focal_35mm"])
        cols["time_s"].append(t)
        for k in _FIELDS:
            v = r.get(k, dflt.get(k))
            if v is None:
                raise FormatError(
                    f"{label} line {line}: no {k} (add the column, or give "
                    f"--telemetry-default {k}=VALUE)")
            cols[k].append(float(v))
        if not -180 <= cols["lon"][-1] <= 360 or not -90 <= cols["lat"][-1] <= 90:
            raise FormatError(f"{label} line {line}: lon/lat out of range "
                              f"({cols['lon'][-1]}, {cols['lat'][-1]})")
        if not cols["alt_m"][-1] > 0:
            raise FormatError(f"{label} line {line}: alt_m must be above the ground (> 0), "
                              f"got {cols['alt_m'][-1]}")
        if not 0 < cols["hfov_deg"][-1] < 180:
            raise FormatError(f"{label} line {line}: hfov_deg must be in (0, 180), "
                              f"got {cols['hfov_deg'][-1]}")
    arr = {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}
    order = np.argsort(arr["time_s"], kind="stable")
    arr = {k: v[order] for k, v in arr.items()}
    if np.any(np.diff(arr["time_s"]) <= 0):
        i = int(np.flatnonzero(np.diff(arr["time_s"]) <= 0)[0])
        raise FormatError(f"{label}: two rows at the same time ({arr['time_s'][i]:.3f} s)")
    return Telemetry(**arr, source=label)


def read_telemetry_csv(path: str | Path, *, fps: float = 30.0,
                       defaults: dict[str, float] | None = None, frame_base: int = 1,
                       option: str = "--telemetry") -> Telemetry:
    """Read the telemetry CSV described in the module docstring.

    Parameters
    ----------
    path : path
    fps : float
        Frame rate, to turn the ``frame`` column into seconds.
    defaults : dict, optional
        Values for columns the log lacks (``{"heading_deg": 308.0}``); columns win over defaults.
        ``pitch_deg`` defaults to -90 (nadir) and ``roll_deg`` to 0.
    frame_base : int
        Number of the first frame in the file's ``frame`` column: 1 (aerotrack's convention) or 0
        (logs that count from 0, like Geo-trax's); the frames are renumbered to 1-based.
    option : str
        Command-line option named in messages.

    Raises
    ------
    InputError, FormatError
        Missing file; a row with the wrong number of cells, a non-numeric cell, an out-of-range
        value, or a needed column absent (the message names the file and line).
    """
    p = Path(path)
    label = f"{option} {p}"
    text = read_text(p, label)
    lines = [(i, ln) for i, ln in enumerate(text.splitlines(), start=1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise FormatError(f"{label}: file is empty")
    hline, header_text = lines[0]
    header = [_ALIASES.get(h.strip().lower(), h.strip().lower())
              for h in next(csv.reader([header_text]))]
    if not {"lon", "lat"} <= set(header) or not ({"frame", "time_s"} & set(header)):
        raise FormatError(f"{label} line {hline}: header needs frame (or time_s), lon, lat, alt_m "
                          f"columns; found {header_text.strip()!r}")
    wanted = {"frame", "time_s", "focal_35mm", *_FIELDS}
    rows = []
    for lineno, ln in lines[1:]:
        cells = next(csv.reader(io.StringIO(ln)))
        if len(cells) != len(header):
            raise FormatError(f"{label} line {lineno}: expected {len(header)} cells, "
                              f"found {len(cells)}")
        r: dict[str, float] = {"_line": lineno}
        for name, cell in zip(header, cells):
            if name not in wanted:
                continue
            if not cell.strip() and defaults and name in defaults:
                continue  # an empty cell: the default fills it
            try:
                val = float(cell)
            except ValueError:
                raise FormatError(f"{label} line {lineno}: {name} is not a number "
                                  f"({cell.strip()!r})") from None
            if not math.isfinite(val):
                raise FormatError(f"{label} line {lineno}: {name} is NaN or infinite")
            r[name] = val + (1 - frame_base if name == "frame" else 0)
        rows.append(r)
    if defaults:
        for name in sorted(set(defaults) & set(header)):
            logging.getLogger(__name__).warning(
                "%s has a %s column: --telemetry-default %s fills only its empty cells", label,
                name, name)
    return _build(rows, label, fps, defaults)


_SRT_PAIR = re.compile(r"([A-Za-z_]+)\s*:\s*(-?\d+(?:\.\d+)?)")
_SRT_GPS = re.compile(r"GPS\s*\(\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\)")
_SRT_TIME = re.compile(r"(\d+):(\d\d):(\d\d)[,.](\d{1,3})\s*-->")


def read_dji_srt(path: str | Path, *, defaults: dict[str, float] | None = None,
                 option: str = "--telemetry") -> Telemetry:
    """Read DJI video subtitles (``.SRT``) as telemetry.

    Each cue's start time is the frame time. Recognised fields: ``latitude``, ``longitude``,
    ``rel_alt`` (height above take-off, used as height above ground), ``focal_len``
    (35-mm-equivalent focal length, mm), and when present ``gb_yaw``, ``gb_pitch``, ``gb_roll``;
    the older ``GPS(lon, lat, alt)`` with ``H <height>m`` form is also read. Values the subtitles
    lack come from ``defaults`` (see :func:`read_telemetry_csv`).
    """
    p = Path(path)
    label = f"{option} {p}"
    text = read_text(p, label)
    rows = []
    lines = text.splitlines()
    cue_start = None
    cur: dict[str, float] = {}

    def flush():
        if cur:
            rows.append(dict(cur))
            cur.clear()

    for lineno, ln in enumerate(lines, start=1):
        m = _SRT_TIME.search(ln)
        if m:
            flush()
            hh, mm, ss, ms = m.groups()
            cue_start = lineno
            cur["time_s"] = int(hh) * 3600 + int(mm) * 60 + int(ss) + int(ms.ljust(3, "0")) / 1000
            cur["_line"] = lineno
            continue
        if cue_start is None:
            continue
        g = _SRT_GPS.search(ln)
        if g:
            cur["lon"], cur["lat"] = float(g.group(1)), float(g.group(2))
        hm = re.search(r"\bH\s*(-?[\d.]+)\s*m", ln)
        if hm:
            cur["alt_m"] = float(hm.group(1))
        for key, val in _SRT_PAIR.findall(ln):
            name = _ALIASES.get(key.lower(), key.lower())
            if name in ("lon", "lat", "alt_m", "heading_deg", "pitch_deg", "roll_deg",
                        "focal_35mm"):
                cur[name] = float(val)
    flush()
    rows = [r for r in rows if "lon" in r or "lat" in r]
    if not rows:
        raise FormatError(f"{label}: no DJI telemetry cues (latitude/longitude) found")
    t0 = rows[0]["time_s"]
    for r in rows:
        r["time_s"] -= t0
        for k in ("lon", "lat"):
            if k not in r:
                raise FormatError(f"{label} line {int(r['_line'])}: cue has no {k}")
    return _build(rows, label, 1.0, defaults)


def parse_telemetry_defaults(items) -> dict[str, float]:
    """``--telemetry-default NAME=VALUE`` items as ``{"heading_deg": 29.0}`` (column names and
    their aliases, as in a log's header: ``heading``, ``yaw``, ``alt``, ``focal_35mm``, ...).

    Raises
    ------
    InputError
        An item without ``=``, an unknown name or a value that is not a finite number.
    """
    out: dict[str, float] = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        key = _ALIASES.get(name.strip().lower(), name.strip().lower())
        if not sep or key not in (*_FIELDS, "focal_35mm"):
            raise InputError(f"--telemetry-default {item}: expected NAME=VALUE with NAME one of "
                             f"{', '.join((*_FIELDS, 'focal_35mm'))}")
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise InputError(f"--telemetry-default {item}: {value!r} is not a number")
        if key in out:
            raise InputError(f"--telemetry-default {item}: {key} given twice")
        bounds = {"alt_m": (0.0, math.inf), "hfov_deg": (0.0, 180.0), "lat": (-90.0, 90.0),
                  "lon": (-180.0, 360.0), "focal_35mm": (0.0, math.inf)}
        lo, hi = bounds.get(key, (-math.inf, math.inf))
        if not lo < v < hi and not (key in ("lat", "lon") and lo <= v <= hi):
            raise InputError(f"--telemetry-default {item}: {key} must be in ({lo:g}, {hi:g})")
        out[key] = v
    return out


def read_telemetry(path: str | Path, *, fps: float = 30.0,
                   defaults: dict[str, float] | None = None, frame_base: int = 1,
                   option: str = "--telemetry") -> Telemetry:
    """Read a telemetry CSV or a DJI ``.srt`` (chosen by the suffix)."""
    if Path(path).suffix.lower() == ".srt":
        return read_dji_srt(path, defaults=defaults, option=option)
    return read_telemetry_csv(path, fps=fps, defaults=defaults, frame_base=frame_base,
                              option=option)




# -- metric scale without a map ----------------------------------------------------------------
def ground_sample_distance(altitude_m: float, image_width_px: int, *, hfov_deg: float | None = None,
                           focal_mm: float | None = None, sensor_width_mm: float | None = None,
                           focal_35mm: float | None = None, focal_px: float | None = None) -> float:
    """Metres per frame pixel at the image centre of a nadir camera ``altitude_m`` above flat ground.

    ``gsd = altitude / f_px`` where the focal length in pixels comes from the first of:
    ``focal_px``; ``focal_mm`` with ``sensor_width_mm`` (``f_px = W f / sensor_width``);
    ``hfov_deg`` (``f_px = W / (2 tan(hfov/2))``); ``focal_35mm`` (via :func:`hfov_from_focal`).

    Raises
    ------
    InputError
        Non-positive values, or no way to get the focal length in pixels.
    """
    if not (altitude_m and altitude_m > 0 and image_width_px and image_width_px > 0):
        raise InputError(f"--altitude {altitude_m}: altitude and image width must be positive")
    if focal_px is not None:
        f = float(focal_px)
    elif focal_mm is not None and sensor_width_mm is not None:
        if not (focal_mm > 0 and sensor_width_mm > 0):
            raise InputError("--focal-mm/--sensor-width-mm: must be positive")
        f = image_width_px * focal_mm / sensor_width_mm
    elif hfov_deg is not None:
        if not 0 < hfov_deg < 180:
            raise InputError(f"--hfov {hfov_deg}: must be in (0, 180) degrees")
        f = image_width_px / (2.0 * math.tan(math.radians(hfov_deg) / 2.0))
    elif focal_35mm is not None:
        if not focal_35mm > 0:
            raise InputError(f"--focal-35mm {focal_35mm}: must be positive")
        f = image_width_px / (2.0 * math.tan(math.radians(hfov_from_focal(focal_35mm)) / 2.0))
    else:
        raise InputError("--altitude needs a focal length: --hfov, --focal-35mm, or --focal-mm "
                         "with --sensor-width-mm")
    if not f > 0:
        raise InputError(f"focal length in pixels must be positive, got {f}")
    return float(altitude_m) / f


def metres_per_unit(*, gsd: float | None = None, geomap: Any = None,
                    altitude_m: float | None = None, image_width_px: int | None = None,
                    **camera: float | None) -> float | None:
    """Metres per world unit: the map's pixel size, else ``--gsd``, else altitude + optics.

    World units are map pixels with a map and frame 1's pixels without one, so ``gsd`` (metres per
    frame pixel of frame 1) and the altitude form apply only without a map; with both a map and a
    GSD the map wins (its scale is measured, not assumed). Returns None when nothing gives a scale
    (speeds then stay in world units per second).
    """
    if geomap is not None:
        return float(geomap.metres_per_pixel)
    if gsd is not None:
        if not (math.isfinite(gsd) and gsd > 0):
            raise InputError(f"--gsd {gsd}: must be a positive number of metres per pixel")
        return float(gsd)
    if altitude_m is not None:
        if image_width_px is None:
            raise InputError("--altitude: the frame width is needed to compute the scale")
        return ground_sample_distance(altitude_m, image_width_px,
                                      **{k: v for k, v in camera.items() if v is not None})
    return None


# -- coarse lock-on: from a telemetry start to within map refinement's reach -----------------
def _inradius(quad: np.ndarray, c: np.ndarray) -> float:
    """Distance from ``c`` to the nearest edge of the convex quadrilateral ``quad`` (4, 2)."""
    d = []
    for k in range(4):
        a, b = quad[k], quad[(k + 1) % 4]
        e = b - a
        n = np.hypot(*e)
        d.append(abs(e[0] * (c[1] - a[1]) - e[1] * (c[0] - a[0])) / max(n, 1e-12))
    return float(min(d))


def _cv(H: np.ndarray) -> np.ndarray:
    """An aerotrack-convention homography (pixel centres at +0.5) in OpenCV's (centres at 0)."""
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    return np.linalg.inv(T) @ H @ T


def coarse_align(frame_img: np.ndarray, H_start: np.ndarray, map_img: np.ndarray, *,
                 search_px: float, max_rotation_deg: float = 6.0,
                 rotation_step_deg: float = 1.0, min_score: float = 0.3,
                 template_px: int = 48, pixel_aspect: float = 1.0
                 ) -> tuple[np.ndarray, float] | Failure:
    """Correct a telemetry start's translation and heading error against the map, coarsely.

    Map refinement (``registration.mapref``) looks only a few map pixels around its start; a
    telemetry start is off by metres (the Songdo DJI log: 5.4 m of GPS offset, about 2 % of
    height, plus the compass error), which at a 0.03-0.3 m/px orthophoto is tens to hundreds of map
    pixels. This searches translation (+-``search_px``) and rotation (+-``max_rotation_deg``
    about the footprint's centre) by normalised cross-correlation of the frame's central region,
    warped onto the map at a coarse scale, against the map; the result is within a coarse pixel
    (or two) of the truth, which refinement then takes to sub-pixel.

    Parameters
    ----------
    frame_img : ndarray (h, w[, 3]) uint8
        The frame (undistorted), BGR or grey.
    H_start : ndarray (3, 3)
        Frame pixels -> map pixels from telemetry (:func:`pose_homography` with the GeoMap).
    map_img : ndarray (Hm, Wm[, 3]) uint8
        The map (``GeoMap.read_image()``).
    search_px : float
        Largest translation error searched, map pixels (position error / map GSD, with margin).
    max_rotation_deg, rotation_step_deg : float
        Heading uncertainty searched and its step. A wider range copes with a worse compass but
        costs one template match per step and admits more false matches.
    min_score : float
        Lowest accepted correlation peak (TM_CCOEFF_NORMED); below it the start is left alone.
    template_px : int
        Half-size of the coarse template, coarse pixels; sets the coarse scale.
    pixel_aspect : float
        Ground height / ground width of one map pixel (:func:`map_pixel_aspect`): 1 for projected
        maps, about ``1 / cos(lat)`` for maps in lon/lat degrees, where a rotation on the ground is
        not a rotation of map pixels.

    Returns
    -------
    (H, score) or Failure
        ``H`` (3, 3) frame pixels -> map pixels, corrected; ``score`` the correlation peak.
    """
    fg = frame_img if frame_img.ndim == 2 else cv2.cvtColor(frame_img, cv2.COLOR_BGR2GRAY)
    mg = map_img if map_img.ndim == 2 else cv2.cvtColor(map_img, cv2.COLOR_BGR2GRAY)
    h, w = fg.shape
    H0 = np.asarray(H_start, np.float64) / H_start[2, 2]
    quad = apply_homography(H0, np.array([[0, 0], [w, 0], [w, h], [0, h]], float))
    c = apply_homography(H0, np.array([[w / 2, h / 2]]))[0]
    if not (np.all(np.isfinite(quad)) and np.all(np.isfinite(c))):
        return Failure("coarse alignment: the start homography is not finite")
    r_in = _inradius(quad, c) / math.sqrt(2.0)  # half-side of a square inside at any rotation
    f = max(1.0, r_in / template_px)
    half = int(r_in / f)
    if half < 8:
        return Failure(f"coarse alignment: frame footprint too small on the map ({2 * r_in:.0f} px)")
    cw, ch = max(1, int(round(mg.shape[1] / f))), max(1, int(round(mg.shape[0] / f)))
    fx, fy = mg.shape[1] / cw, mg.shape[0] / ch
    mcoarse = cv2.resize(mg, (cw, ch), interpolation=cv2.INTER_AREA).astype(np.float32)
    s = int(math.ceil(search_px / min(fx, fy))) + 1
    rx0 = int(math.floor(c[0] / fx - half - s))
    ry0 = int(math.floor(c[1] / fy - half - s))
    rx1, ry1 = rx0 + 2 * (half + s) + 1, ry0 + 2 * (half + s) + 1
    if rx0 < 0 or ry0 < 0 or rx1 > cw or ry1 > ch:
        # clip the search window to the map (the template must stay inside it)
        rx0, ry0 = max(rx0, 0), max(ry0, 0)
        rx1, ry1 = min(rx1, cw), min(ry1, ch)
        if rx1 - rx0 <= 2 * half + 2 or ry1 - ry0 <= 2 * half + 2:
            return Failure("coarse alignment: the search window falls outside the map")
    region = mcoarse[ry0:ry1, rx0:rx1]
    shrink = math.sqrt(abs(np.linalg.det(H0[:2, :2]))) / f
    src = cv2.GaussianBlur(fg, (0, 0), 0.5 / shrink) if shrink < 0.7 else fg
    Sa = np.diag([1.0, float(pixel_aspect), 1.0])  # map pixels -> square ground units

    def rot(th: float) -> np.ndarray:
        R = np.array([[math.cos(th), -math.sin(th), 0], [math.sin(th), math.cos(th), 0], [0, 0, 1]])
        return np.linalg.inv(Sa) @ R @ Sa

    def match(th: float):
        R = rot(th)
        A = (np.array([[1 / fx, 0, half], [0, 1 / fy, half], [0, 0, 1]]) @ R
             @ np.array([[1, 0, -c[0]], [0, 1, -c[1]], [0, 0, 1]]))
        tmpl = cv2.warpPerspective(src, _cv(A @ H0), (2 * half, 2 * half),
                                   flags=cv2.INTER_LINEAR).astype(np.float32)
        if float(tmpl.std()) < 1.0:
            return None
        res = cv2.matchTemplate(region, tmpl, cv2.TM_CCOEFF_NORMED)
        iy, ix = np.unravel_index(int(np.argmax(res)), res.shape)
        return float(res[iy, ix]), th, iy, ix, res

    n_rot = int(round(max_rotation_deg / rotation_step_deg)) if rotation_step_deg > 0 else 0
    step = math.radians(rotation_step_deg)
    tried = [match(k * step) for k in range(-n_rot, n_rot + 1)]
    scores = [-np.inf if t is None else t[0] for t in tried]
    if not np.isfinite(max(scores)):
        return Failure("coarse alignment: the frame has no texture")
    kb = int(np.argmax(scores))
    best = tried[kb]
    if 0 < kb < len(tried) - 1 and np.isfinite(scores[kb - 1]) and np.isfinite(scores[kb + 1]):
        # the rotation between two steps: parabola through the three best scores
        a, b, cc = scores[kb - 1], scores[kb], scores[kb + 1]
        den = a - 2 * b + cc
        if den < 0:
            again = match(best[1] + step * float(np.clip(0.5 * (a - cc) / den, -0.5, 0.5)))
            if again is not None and again[0] >= best[0]:
                best = again
    score, th, iy, ix, res = best
    if score < min_score:
        return Failure(f"coarse alignment: best correlation {score:.2f} < {min_score}")
    if iy in (0, res.shape[0] - 1) or ix in (0, res.shape[1] - 1):
        return Failure("coarse alignment: best match on the border of the search window")

    def vertex(a, b, cc):
        den = a - 2 * b + cc
        return 0.0 if den >= 0 else float(np.clip(0.5 * (a - cc) / den, -0.5, 0.5))

    oy = iy + vertex(res[iy - 1, ix], res[iy, ix], res[iy + 1, ix])
    ox = ix + vertex(res[iy, ix - 1], res[iy, ix], res[iy, ix + 1])
    # Template pixel t sits on coarse map pixel (r0 + o + t): true map = R (m - c) + F (r0 + o + half)
    target = np.array([fx * (rx0 + ox + half), fy * (ry0 + oy + half)])
    R2 = rot(th)[:2, :2]
    C = np.eye(3)
    C[:2, :2] = R2
    C[:2, 2] = target - R2 @ c
    H1 = C @ H0
    return H1 / H1[2, 2], score


def map_pixel_aspect(geomap: Any, at_px: np.ndarray | None = None) -> float:
    """Ground height / ground width of one map pixel of ``geomap`` at ``at_px`` (default centre)."""
    from pyproj import Geod

    c = np.asarray(at_px if at_px is not None else [geomap.width / 2, geomap.height / 2],
                   np.float64).reshape(2)
    ll = geomap.pixel_to_lonlat(np.vstack([c, c + [1, 0], c + [0, 1]]))
    g = Geod(ellps="WGS84")
    dx = g.inv(ll[0, 0], ll[0, 1], ll[1, 0], ll[1, 1])[2]
    dy = g.inv(ll[0, 0], ll[0, 1], ll[2, 0], ll[2, 1])[2]
    return float(dy / dx)


def telemetry_map_init(telemetry: Telemetry, frame: Any, geomap: Any, fps: float, *,
                       search_m: float = 20.0, max_rotation_deg: float = 6.0
                       ) -> tuple[np.ndarray, str]:
    """The ``--map-init`` homography of one frame from telemetry: pinhole start + coarse lock-on.

    Parameters
    ----------
    telemetry : Telemetry
    frame : aerotrack.types.Frame
        The (undistorted) frame to anchor, usually frame 1.
    geomap : GeoMap
    fps : float
    search_m : float
        Largest position error searched, metres (consumer GPS: a few metres; 20 m leaves margin).
    max_rotation_deg : float
        Largest heading error searched, degrees.

    Returns
    -------
    H : ndarray (3, 3)
        Frame pixels -> map pixels: coarse-aligned, or the plain telemetry start when the
        alignment failed (map refinement may still lock on if the start is good enough).
    note : str
        What happened, for the log and ``summary.json``.

    Raises
    ------
    InputError
        The camera sees no ground (the start itself is unusable).
    """
    h, w = frame.image.shape[:2]
    H0 = telemetry.homography(frame.index, fps, (w, h), geomap)
    if isinstance(H0, Failure):
        raise InputError(f"{telemetry.source}: frame {frame.index}: {H0.reason}")
    r = coarse_align(frame.image, H0, geomap.read_image(),
                     search_px=search_m / geomap.metres_per_pixel,
                     max_rotation_deg=max_rotation_deg, pixel_aspect=map_pixel_aspect(geomap))
    if isinstance(r, Failure):
        return H0, f"telemetry start (not aligned: {r.reason})"
    return r[0], f"telemetry start, coarse-aligned to the map (score {r[1]:.2f})"

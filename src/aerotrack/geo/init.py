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


def check_overlap(size: tuple[int, int], H_init: np.ndarray, geomap: GeoMap, init_label: str
                  ) -> None:
    """Refuse a placement of frame 1 (``size`` (w, h) pixels) that misses ``geomap``: a centre off
    the map, a degenerate homography, or a corner more than 20 map sizes away (a homography in
    the wrong direction). ``init_label`` names where it came from in the message."""
    from ..types import apply_homography

    w, h = size
    corners = apply_homography(H_init, np.array([[0, 0], [w, 0], [w, h], [0, h]], float))
    centre = apply_homography(H_init, np.array([[w / 2, h / 2]], float))[0]
    where = f"{init_label}: frame 1"
    if not (np.all(np.isfinite(corners)) and np.all(np.isfinite(centre))):
        raise GeoreferenceError(f"{where} maps to infinity (a degenerate homography)")
    if not (0 <= centre[0] <= geomap.width and 0 <= centre[1] <= geomap.height):
        raise GeoreferenceError(
            f"{where} does not land on the map (its centre maps to map pixel "
            f"{centre[0]:.0f},{centre[1]:.0f}; the map is {geomap.width}x{geomap.height})")
    # A frame may be larger than the map (a wide frame over a small tile), but a corner 20 map
    # sizes away means a homography that nearly reaches the horizon or points the wrong way.
    far = 20 * max(geomap.width, geomap.height)
    if np.any(np.abs(corners - centre) > far):
        k = int(np.argmax(np.abs(corners - centre).max(axis=1)))
        raise GeoreferenceError(
            f"{where}'s corner {k + 1} maps to map pixel {corners[k, 0]:.0f},"
            f"{corners[k, 1]:.0f}, more than 20 map sizes from its centre: is the homography "
            "frame -> map pixels?")


#: Files beside a batch input ``NAME.mp4`` (or image folder ``NAME/``) that place its frame 1 on
#: the batch's ``--map``: ``NAME`` + one of these. As ``--map-init``:
MAP_INIT_SIDECARS = (".map-init.txt", ".map-init.csv", ".points")
#: ... and as ``--telemetry`` (a DJI subtitle flight log, or a telemetry CSV):
TELEMETRY_SIDECARS = (".srt", ".telemetry.csv")


def placement_sidecars(input_path: str | Path) -> tuple[list[Path], list[Path]]:
    """The ``--map-init`` and ``--telemetry`` files beside a batch input (:data:`MAP_INIT_SIDECARS`,
    :data:`TELEMETRY_SIDECARS`; suffixes in any case: ``NAME.SRT`` as DJI writes it)."""
    p = Path(input_path)
    stem = p.name if p.is_dir() else p.stem
    init, tel = [], []
    for q in sorted(p.parent.iterdir()) if p.parent.is_dir() else []:
        if not q.is_file() or not q.name.lower().startswith(stem.lower() + "."):
            continue
        if q.name[:len(stem)] != stem:  # another input's (names differing only in case)
            continue
        rest = q.name[len(stem):].lower()
        if rest in MAP_INIT_SIDECARS:
            init.append(q)
        elif rest in TELEMETRY_SIDECARS:
            tel.append(q)
    return init, tel


def placement_fingerprint(input_path: str | Path) -> str | None:
    """The file placing a batch input on the map (:func:`placement_sidecars`) as ``name size
    mtime``, so that a finished or interrupted input placed by an older version of it is
    known (None without exactly one such file)."""
    init, tel = placement_sidecars(input_path)
    if len(init) + len(tel) != 1:
        return None
    q = (init + tel)[0]
    st = q.stat()
    return f"{q.name} {st.st_size} {st.st_mtime_ns}"


def sidecar_placement(input_path: str | Path, source, geomap: GeoMap, *,
                      telemetry_defaults=(), undistort=None) -> tuple[np.ndarray, dict, dict]:
    """Frame 1 of a batch input placed on ``geomap`` by the file beside it
    (:func:`placement_sidecars`): ``(H_init, notes, options)``, ``notes`` as ``track`` writes
    them to ``summary.json`` (the telemetry's lock-on) and ``options`` naming the file used
    (``map_init``, or ``telemetry`` and ``telemetry_defaults``). Raises :class:`InputError` naming the files it looked for
    when there is none, or when more than one would place it."""
    init, tel = placement_sidecars(input_path)
    p = Path(input_path)
    stem = p.name if p.is_dir() else p.stem
    found = init + tel
    if not found:
        near = [q.name for q in sorted(p.parent.iterdir()) if q.name.lower().startswith(
            stem.lower() + ".") and q.name[len(stem):].lower() in (*MAP_INIT_SIDECARS,
                                                                  *TELEMETRY_SIDECARS)]
        if near:  # there, but as a folder or with the name in another case
            q = p.parent / near[0]
            raise InputError(f"{p}: {near[0]} beside it is " + (
                "a folder, not a file" if q.is_dir() else
                f"not named after it ({stem!r} in another case)") + "; it places nothing")
        raise InputError(
            f"{p}: nothing places it on --map: put {stem}.map-init.txt (frame 1 -> map: a 3x3 "
            f"homography, or control points as {stem}.map-init.csv or {stem}.points, as "
            f"--map-init) or its flight log {stem}.srt (or {stem}.telemetry.csv, as --telemetry) "
            "beside it")
    if len(found) > 1:
        raise InputError(f"{p}: {' and '.join(q.name for q in found)} would each place it on "
                         "--map; keep one")
    if init:
        H = read_map_init(init[0], geomap, option="map-init")
        check_overlap(source.size, H, geomap, f"map-init {init[0]}")
        return H, {}, {"map_init": str(init[0].resolve())}
    from .telemetry import parse_telemetry_defaults, read_telemetry, telemetry_map_init

    tel_path = tel[0]
    telemetry = read_telemetry(tel_path, fps=source.fps, option="telemetry",
                               defaults=parse_telemetry_defaults(telemetry_defaults))
    first = next(iter(source.frames(start=1, stop=1)), None)
    if first is None:
        raise InputError(f"{p}: frame 1 cannot be read")
    if undistort is not None:
        first = undistort(first)
    H, note = telemetry_map_init(telemetry, first, geomap, source.fps)
    check_overlap(source.size, H, geomap, f"telemetry {tel_path}")
    return H, {"telemetry": note}, {"telemetry": str(tel_path.resolve()),
                                    "telemetry_defaults": sorted(telemetry_defaults)}

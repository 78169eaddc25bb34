"""``aerotrack count``: screen-line counts and turning movements of a run's tracks."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import click
import numpy as np

from .common import PathArg, root_flags

log = logging.getLogger(__name__)

#: Default band about a line (:mod:`aerotrack.analysis.counting`): metres with a scale, pixels
#: without.
BAND_M, BAND_PX = 1.0, 4.0


@click.command("count")
@click.argument("run_dir", metavar="DIR", type=PathArg(exists=False, file_okay=False))
@click.option("--line", "line_texts", multiple=True, metavar="NAME:x1,y1,x2,y2",
              help="A count line from (x1, y1) to (x2, y2) in the pixels of the run's first "
                   "frame (repeatable). Crossings from its left to its right, as seen on the "
                   "screen walking from the first point to the second, count as '+'.")
@click.option("--lines", "lines_path", type=PathArg(dir_okay=False), default=None,
              help="GeoJSON of count lines (2-vertex LineStrings named by a 'name' property; "
                   "lon/lat, or the CRS of its 'crs' member); needs a run with a map.")
@click.option("--band", type=float, default=None,
              help=f"How far beyond a line a track must be to be on its other side: metres "
                   f"when the run has a scale (a map or --gsd), first-frame pixels otherwise. "
                   f"Default {BAND_M:g} m or {BAND_PX:g} px. Larger ignores more jitter about "
                   f"the line, smaller counts vehicles that only clip its end.")
@click.option("--bin", "bin_s", type=float, default=None,
              help="Also count per time bin of this many seconds (counts.csv). Default: one bin "
                   "for the whole run.")
@click.option("--out", "out_dir", type=PathArg(file_okay=False), default=None,
              help="Folder for crossings.csv, counts.csv and movements.csv. Default: DIR.")
@click.option("--map", "map_path", type=PathArg(dir_okay=False), default=None,
              help="The run's map raster (default: the map named in DIR/summary.json).")
@click.option("--gt", "gt_path", type=PathArg(dir_okay=False), default=None,
              help="Ground-truth boxes (MOTChallenge, the run's frames): counted the same way "
                   "through the run's registration and compared (count error, crossing "
                   "precision and recall, turning-movement error).")
@click.option("--gt-zero-based", is_flag=True,
              help="The ground truth numbers frames from 0 (as Santiago's): add 1.")
@click.option("--fix-gt", is_flag=True,
              help="Correct the ground truth first (as `aerotrack eval --fix-gt`).")
@click.option("--tolerance", "tolerance_s", type=float, default=1.0, show_default=True,
              help="With --gt: seconds within which a crossing matches a true one.")
@click.option("--picture/--no-picture", default=True, show_default=True,
              help="Write DIR/count_lines.png (or into --out): the run's first frame with the "
                   "lines, their '+' side, the tracks' paths and every crossing, to check where "
                   "the lines fell (needs the run's input, named in summary.json, or --input); "
                   "with a map, the map around them when a line lies outside that frame or the "
                   "input is not at hand.")
@click.option("--input", "input_path", type=PathArg(), default=None,
              help="The run's input video or image folder, for --picture (default: the input "
                   "named in DIR/summary.json, if it still exists).")
@click.option("--start-time", "start_time", metavar="TIME", default=None,
              help="Wall-clock time of the run's frame 1, ISO 8601 with a UTC offset "
                   "(2024-05-01T10:30:00Z): crossings get time_utc and bins start_utc/end_utc. "
                   "Default: the run's own --start-time, if it was given one.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the totals (and the comparison with --gt) as JSON instead of a table.")
@click.pass_context
def count_command(ctx: click.Context, run_dir, line_texts, lines_path, band, bin_s, out_dir,
                  map_path, gt_path, gt_zero_based, fix_gt, tolerance_s, picture, input_path,
                  start_time, as_json) -> None:
    """Count the tracks of DIR crossing lines, per direction and time bin, and each track's way
    through them (turning movements: the first and last line it crossed).

    A track changes side only when it is --band beyond a line, so jitter about it is not counted;
    predicted positions between two sightings count (a crossing under a bridge), predictions
    after a track's last sighting do not. Writes crossings.csv (one row per crossing),
    counts.csv (per line, direction and bin: the count, the mean spot speed, and the share of
    the bin the camera saw the line, since a zero count in a bin it did not see means nothing)
    and movements.csv (per track: first and last line crossed, travel time between them), and
    count_lines.png (the lines on the run's first frame, unless --no-picture), and prints the
    totals and the origin-destination matrix.

    \b
    Examples:
      aerotrack count run/ --line north:850,200,1100,260 --line south:700,900,980,960
      aerotrack count run/ --lines approaches.geojson --bin 60
      aerotrack count run/ --line stop:100,400,300,400 --gt gt.txt
    """
    from ..analysis.counting import (
        CountLine,
        compare_counts,
        count_crossings,
        in_view_per_bin,
        line_in_view,
        movement_matrix,
        movements,
        parse_line,
        read_count_lines,
        tally,
    )
    from ..errors import InputError
    from ..io.output import check_writable
    from ..viz.results import RunResults
    from .render_cmd import load_map

    parsed = [parse_line(t) for t in line_texts]  # malformed lines before any file is read
    for name, label in ((band, "--band"), (tolerance_s, "--tolerance")):
        if name is not None and not (math.isfinite(name) and name >= 0):
            raise InputError(f"{label} {name}: must be a number >= 0")
    if bin_s is not None and not (math.isfinite(bin_s) and bin_s > 0):
        raise InputError(f"--bin {bin_s}: must be a number of seconds > 0")
    if not parsed and lines_path is None:
        raise InputError("no count lines: give --line NAME:x1,y1,x2,y2 (first-frame pixels) or "
                         "--lines FILE.geojson")
    if gt_path is None and (gt_zero_based or fix_gt or tolerance_s != 1.0):
        raise InputError("--gt-zero-based, --fix-gt and --tolerance only apply with --gt")
    from .track_cmd import parse_start_time

    clock = parse_start_time(start_time, geomap=True)  # (no "without --map" warning here)
    results = RunResults.load(run_dir)
    clock = clock or results.summary.get("start_time")
    if gt_path is not None:  # a bad ground truth is refused before anything is written
        from ..io.mot import read_mot

        read_mot(gt_path, option="--gt", strict=False, allow_empty=False, zero_based=gt_zero_based)
    if bin_s is not None and bin_s < 1.0 / results.fps:
        raise InputError(f"--bin {bin_s}: shorter than one frame ({1.0 / results.fps:.4g} s)")
    geomap = load_map(results, map_path)
    if lines_path is not None and geomap is None:
        raise InputError(f"--lines {lines_path}: GeoJSON lines need a run with a map (this run "
                         "has none); give the lines with --line in first-frame pixels")
    if input_path is not None:
        if not Path(input_path).exists():
            raise InputError(f"--input {input_path}: no such file or folder")
        from ..io import open_source

        # (its first frame is drawn under the run's lines and tracks: another video's misled)
        results.check_input(open_source(input_path, results.fps), input_path, "--input")
    out = Path(out_dir) if out_dir is not None else Path(results.path)
    for name in ("crossings.csv", "counts.csv", "movements.csv") + \
            (("count_lines.png",) if picture else ()):
        check_writable(out / name, "--out")

    lines = []
    first = results.first_frame
    for name, pts in parsed:
        lines.append(CountLine(name, *_first_frame_to_world(results, first, pts)))
    if lines_path is not None:
        lines += [CountLine(n, *p) for n, p in read_count_lines(lines_path, geomap)]
    names = [ln.name for ln in lines]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        where = "--line/--lines" if lines_path is not None else "--line"
        raise InputError(f"{where}: the name {dup[0]!r} is given to two lines; names must differ")

    mpu = geomap.metres_per_pixel if geomap is not None else results.metres_per_unit
    band_world = (band if band is not None else BAND_M) / mpu if mpu else \
        (band if band is not None else BAND_PX)
    views = results.track_views(geomap)
    fps = results.fps
    crossings = count_crossings(views, lines, band_world, fps)
    moves = movements(crossings)
    last = max(results.last_frame, first)
    rows = tally(crossings, lines, fps, first, last, bin_s)
    seen = _in_view(results, lines, first, last, bin_s, line_in_view, in_view_per_bin)
    _write(out, crossings, rows, moves, fps, geomap, mpu, seen, clock, first)
    png = _count_picture(results, input_path, geomap, first, lines, views, crossings) \
        if picture else None
    if png is not None:
        from ..io.output import atomic_write_bytes

        atomic_write_bytes(out / "count_lines.png", png)
    elif (out / "count_lines.png").is_file():  # an earlier count's lines: the report showed them
        try:  # beside these counts
            (out / "count_lines.png").unlink()
        except OSError as exc:
            log.warning("count: %s is an earlier count's picture and could not be removed (%s)",
                        out / "count_lines.png", exc.strerror or exc)

    comparison = None
    if gt_path is not None:
        comparison = _compare(results, gt_path, gt_zero_based, fix_gt, lines, band_world,
                              crossings, tolerance_s * fps, compare_counts)
    quiet, _ = root_flags(ctx)
    totals = tally(crossings, lines, fps, first, max(results.last_frame, first), None)
    od = movement_matrix(moves)
    if as_json:
        doc = {"lines": {ln.name: {d: n for (nm, d, _, _, n) in totals if nm == ln.name}
                         for ln in lines},
               "movements": [{"from": a, "to": b, "tracks": n} for (a, b), n in sorted(od.items())]}
        if comparison is not None:
            doc["comparison"] = _comparison_doc(comparison)
        click.echo(json.dumps(doc, indent=2, allow_nan=False))
        return
    if quiet:
        return
    click.echo(f"{'line':<16}{'+':>7}{'-':>7}{'total':>8}")
    for ln in lines:
        n = {d: c for (nm, d, _, _, c) in totals if nm == ln.name}
        click.echo(f"{ln.name:<16}{n['+']:>7}{n['-']:>7}{n['+'] + n['-']:>8}")
    if od:
        click.echo("turning movements (first line crossed -> last line crossed: tracks)")
        for (a, b), n in sorted(od.items()):
            click.echo(f"  {a} -> {b}: {n}")
    if comparison is not None:
        _print_comparison(comparison, tolerance_s)
    click.echo(f"wrote {out / 'crossings.csv'}, counts.csv, movements.csv"
               + (", count_lines.png" if (out / "count_lines.png").is_file() and picture else ""))


def _first_frame_to_world(results, first: int, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) world points of a line given in the pixels of the run's first frame."""
    from ..errors import InputError

    reg = results.registration
    if reg is None or not len(reg):
        return pts[0], pts[1]
    k = np.searchsorted(reg.frames, first)
    if k >= len(reg.frames) or reg.frames[k] != first:
        raise InputError(f"--line: the run's first frame ({first}) has no registration in "
                         f"{results.path / 'registration.csv'}, so its pixels cannot be placed")
    w = results.boxes_world(np.full(2, first), np.column_stack([pts, np.zeros((2, 2))]))
    if not np.all(np.isfinite(w)):
        raise InputError("--line: an end point cannot be placed through the first frame's "
                         "registration (beyond the horizon?)")
    return w[0], w[1]


def _count_picture(results, input_path, geomap, first: int, lines, views, crossings
                   ) -> bytes | None:
    """count_lines.png: on the run's first frame when every line lies in it (lines drawn in its
    pixels are checked where they were drawn); else, or without the frame at hand, on the map
    around the lines and tracks (a moving camera's lines further along its flight)."""
    to_frame = _world_to_first_frame(results, first)
    image = results.reference_image(Path(input_path) if input_path else results.input_path)
    if image is not None and to_frame is not None:
        h, w = image.shape[:2]
        ends = to_frame(np.vstack([np.vstack([ln.a, ln.b]) for ln in lines]))
        inside = np.all(np.isfinite(ends)) and bool(
            ((ends >= 0) & (ends <= [w, h])).all())
        if inside or geomap is None:
            return _picture(image, to_frame, lines, views, crossings)
    if geomap is None:
        log.info("count: no picture (the run's input is not at hand; give --input)")
        return None
    return _map_picture(geomap, lines, views, crossings)


#: Longest side, pixels, of count_lines.png drawn on the map.
MAP_PICTURE_PX = 1600


def _map_picture(geomap, lines, views, crossings) -> bytes | None:
    """The map around the lines and the tracks' paths (a 10% margin, at most
    :data:`MAP_PICTURE_PX` on its longest side), drawn as :func:`_picture` draws."""
    import cv2

    pts = [np.vstack([ln.a, ln.b]) for ln in lines]
    pts += [np.asarray(v.world, dtype=np.float64)[np.all(np.isfinite(v.world), axis=1)]
            for v in views]
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.1 * (hi - lo).max() + 20.0
    x0, y0 = (max(0, int(v)) for v in np.floor(lo - pad))
    x1 = min(geomap.width, int(np.ceil(hi[0] + pad)))
    y1 = min(geomap.height, int(np.ceil(hi[1] + pad)))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    crop = geomap.read_image()[y0:y1, x0:x1]
    k = min(1.0, MAP_PICTURE_PX / max(crop.shape[:2]))
    if k < 1.0:
        crop = cv2.resize(crop, (max(1, round(crop.shape[1] * k)), max(1, round(crop.shape[0] * k))),
                          interpolation=cv2.INTER_AREA)
    origin = np.array([x0, y0], dtype=np.float64)
    return _picture(crop, lambda p: (np.asarray(p, dtype=np.float64).reshape(-1, 2) - origin) * k,
                    lines, views, crossings)


def _picture(image: np.ndarray, to_frame, lines, views, crossings) -> bytes | None:
    """PNG of ``image`` (the run's first frame, or a map crop) with the lines (name at the first
    point, an arrow to the '+' side), every track's path in grey and each crossing as a dot
    (green '+', red '-'), all carried from the world into its pixels by ``to_frame``."""
    import cv2

    img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    img = (img.astype(np.float32) * 0.6).astype(np.uint8)
    h, w = img.shape[:2]
    lw = max(1, round(h / 400))
    for v in views:
        q = to_frame(np.asarray(v.world, dtype=np.float64))
        ok = np.all(np.isfinite(q), axis=1) & (np.abs(q) < 4 * max(h, w)).all(axis=1)
        for a, b in zip(q[:-1][ok[:-1] & ok[1:]], q[1:][ok[:-1] & ok[1:]]):
            cv2.line(img, _ipt(a), _ipt(b), (170, 170, 170), 1, cv2.LINE_AA)
    for ln in lines:
        a, b = to_frame(np.vstack([ln.a, ln.b]))
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            continue
        cv2.line(img, _ipt(a), _ipt(b), (0, 255, 255), 2 * lw, cv2.LINE_AA)
        d = (b - a) / max(np.hypot(*(b - a)), 1e-9)
        right = np.array([-d[1], d[0]])  # y down: the '+' side as seen on the screen
        mid = (a + b) / 2
        cv2.arrowedLine(img, _ipt(mid), _ipt(mid + right * 12 * lw), (0, 255, 255), lw,
                        cv2.LINE_AA, tipLength=0.4)
        at = np.clip(a + np.array([4, -4]), [2, 14 * lw], [max(2, w - 40 * lw), h - 4])
        cv2.putText(img, ln.name, _ipt(at), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4 * lw + 0.2, (0, 255, 255), lw, cv2.LINE_AA)
    for c in crossings:
        q = to_frame(np.asarray(c.world, dtype=np.float64)[None])[0]
        if np.all(np.isfinite(q)):
            cv2.circle(img, _ipt(q), 3 * lw, (0, 200, 0) if c.direction == "+" else (0, 0, 230),
                       -1, cv2.LINE_AA)
    _legend(img, lw)
    ok, buf = cv2.imencode(".png", img)
    return buf.tobytes() if ok else None


def _legend(img: np.ndarray, lw: int) -> None:
    """A key in the lower left: what the dots, the grey lines and the arrows mean."""
    import cv2

    scale = 0.35 * lw + 0.1
    items = [((0, 200, 0), "crossing +"), ((0, 0, 230), "crossing -"),
             ((170, 170, 170), "track paths"), ((0, 255, 255), "line, arrow to its + side")]
    th = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, scale, lw)[0][1]
    row = int(th * 1.9)
    w = max(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, lw)[0][0] for _, t in items)
    x0, y0 = 6, img.shape[0] - 6 - row * len(items) - 6
    if img.shape[0] - y0 > 0.35 * img.shape[0] or x0 + w + 3 * th + 12 > 0.35 * img.shape[1]:
        return  # a small picture: the key would cover what it explains
    img[y0:img.shape[0] - 6, x0:x0 + w + 3 * th + 12] //= 3
    for k, (colour, text) in enumerate(items):
        cy = y0 + 6 + row * k + row // 2
        cv2.circle(img, (x0 + 6 + th // 2, cy), max(2, th // 2), colour, -1, cv2.LINE_AA)
        cv2.putText(img, text, (x0 + 12 + th, cy + th // 2), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    (235, 235, 235), lw, cv2.LINE_AA)


def _world_to_first_frame(results, first: int):
    """A function (N, 2) world -> (N, 2) pixels of the run's first frame, or None."""
    reg = results.registration
    if reg is None or not len(reg):
        return lambda p: np.asarray(p, dtype=np.float64).reshape(-1, 2)
    k = np.searchsorted(reg.frames, first)
    if k >= len(reg.frames) or reg.frames[k] != first:
        return None
    Hi = np.linalg.inv(reg.H[k])

    def apply(p):
        p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
        q = np.column_stack([p, np.ones(len(p))]) @ Hi.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(q[:, 2:3] > 0, q[:, :2] / q[:, 2:3], np.nan)
    return apply


def _ipt(p) -> tuple[int, int]:
    return int(round(float(p[0]))), int(round(float(p[1])))


def _in_view(results, lines, first: int, last: int, bin_s, line_in_view, in_view_per_bin
             ) -> dict[str, list[float]] | None:
    """{line: share of each bin the camera saw it} (None when the run does not know its frame
    size, e.g. a run from a detections file); warns of lines the camera did not always see."""
    size = results.summary.get("frame_size")
    if not (isinstance(size, list) and len(size) == 2 and min(size) > 0):
        return None
    reg = results.registration
    if reg is not None and len(reg):
        frames, hs = reg.frames, reg.H
    else:  # a fixed camera (no registration file): the frame is the world
        frames = np.arange(first, last + 1)
        hs = np.broadcast_to(np.eye(3), (len(frames), 3, 3))
    out = {}
    for ln in lines:
        share = line_in_view(ln, hs, (size[0], size[1]))
        out[ln.name] = in_view_per_bin(frames, share, results.fps, first, last, bin_s)
        whole = in_view_per_bin(frames, share, results.fps, first, last, None)[0]
        if whole < 0.995:
            log.warning("count: line %r was in view for %.0f%% of the run (line length x time); "
                        "counts.csv's in_view column says when", ln.name, 100 * whole)
    return out


def _write(out: Path, crossings, rows, moves, fps: float, geomap, mpu: float | None,
           seen: dict[str, list[float]] | None = None, clock: str | None = None,
           first: int = 1) -> None:
    from ..io.output import atomic_write

    xy = np.array([c.world for c in crossings], dtype=np.float64).reshape(-1, 2)
    vel = np.array([c.velocity for c in crossings], dtype=np.float64).reshape(-1, 2)
    ll = np.full_like(xy, np.nan)
    speed = np.full(len(xy), np.nan)
    if geomap is not None and len(xy):
        ll = geomap.pixel_to_lonlat(xy)
        ahead = geomap.pixel_to_lonlat(xy + np.nan_to_num(vel))  # a frame's travel, on the ground
        from pyproj import Geod

        metres = Geod(ellps="WGS84").inv(ll[:, 0], ll[:, 1], ahead[:, 0], ahead[:, 1])[2]
        speed = np.where(np.all(np.isfinite(vel), axis=1), np.asarray(metres) * fps, np.nan)
        xy = geomap.pixel_to_crs(xy)
    elif mpu:
        speed = np.hypot(vel[:, 0], vel[:, 1]) * mpu * fps
    digits = 8 if geomap is not None and geomap.crs.is_geographic else 3
    utc = _utc(clock)
    with atomic_write(out / "crossings.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("line,direction,id,frame,time_s,x,y,lon,lat,speed_mps,observed"
                 + (",time_utc" if utc else "") + "\n")
        for c, (x, y), (lon, lat), v in zip(crossings, xy, ll, speed):
            t = (c.frame - 1) / fps
            fh.write(f"{_csv(c.line)},{c.direction},{c.id},{c.frame:.2f},{t:.3f},"
                     f"{x:.{digits}f},{y:.{digits}f},{_num(lon, 8)},{_num(lat, 8)},"
                     f"{_num(v, 2)},{int(c.observed)}" + (f",{utc(t)}" if utc else "") + "\n")
    # the mean spot speed of each bin's crossings (a time-mean speed), from the same bins
    sums: dict[tuple[str, str, int], list[float]] = {}
    starts = {(name, d): [] for name, d, *_ in rows}
    for name, d, a, _b, _n in rows:
        starts[(name, d)].append(a)
    for c, v in zip(crossings, speed):
        if math.isfinite(v):
            edges = starts[(c.line, c.direction)]
            k = max(0, int(np.searchsorted(edges, (c.frame - 1) / fps, side="right")) - 1)
            sums.setdefault((c.line, c.direction, k), []).append(float(v))
    with atomic_write(out / "counts.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("line,direction,start_s,end_s,count,in_view,mean_speed_mps"
                 + (",start_utc,end_utc" if utc else "") + "\n")
        k: dict[tuple[str, str], int] = {}
        for name, d, a, b, n in rows:
            i = k[(name, d)] = k.get((name, d), -1) + 1
            share = seen[name][i] if seen is not None else math.nan
            vs = sums.get((name, d, i))
            mean = float(np.mean(vs)) if vs else math.nan
            fh.write(f"{_csv(name)},{d},{a:.3f},{b:.3f},{n},{_num(share, 3)},{_num(mean, 2)}"
                     + (f",{utc(a)},{utc(b)}" if utc else "") + "\n")
    with atomic_write(out / "movements.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("id,from_line,from_direction,from_time_s,to_line,to_direction,to_time_s,"
                 "travel_time_s\n")
        for m in moves:
            fh.write(f"{m.id},{_csv(m.from_line)},{m.from_direction},"
                     f"{(m.from_frame - 1) / fps:.3f},{_csv(m.to_line)},{m.to_direction},"
                     f"{_num((m.to_frame - 1) / fps, 3)},"
                     f"{_num((m.to_frame - m.from_frame) / fps, 3)}\n")


def _utc(clock: str | None):
    """Seconds since frame 1 -> ISO 8601 UTC text, from the run's start time (None without)."""
    if not clock:
        return None
    import datetime

    try:
        t0 = datetime.datetime.fromisoformat(clock)
    except (TypeError, ValueError):
        log.warning("count: summary.json's start_time %r is not an ISO 8601 time; no clock "
                    "times (give --start-time)", clock)
        return None

    def at(seconds: float) -> str:
        return (t0 + datetime.timedelta(seconds=seconds)).astimezone(
            datetime.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
    return at


def _compare(results, gt_path, zero_based, fix_gt, lines, band_world, crossings, tol_frames,
             compare_counts):
    from types import SimpleNamespace

    from ..analysis.counting import count_crossings
    from ..evaluation.mot import drop_exact_duplicates, fix_ground_truth
    from ..io.mot import read_mot

    gt = read_mot(gt_path, option="--gt", strict=False, allow_empty=False, zero_based=zero_based)
    if fix_gt:
        gt, _ = fix_ground_truth(gt, f"--gt {gt_path}")
    else:
        drop_exact_duplicates(gt, f"--gt {gt_path}")
    views = []
    for tid in np.unique(gt[:, 1]).astype(int):
        r = gt[gt[:, 1] == tid]
        r = r[np.argsort(r[:, 0], kind="stable")]
        frames = r[:, 0].astype(np.int64)
        views.append(SimpleNamespace(id=int(tid), frames=frames,
                                     world=results.boxes_world(frames, r[:, 2:6]),
                                     observed=np.ones(len(r), bool)))
    truth = count_crossings(views, lines, band_world, results.fps)
    return compare_counts(crossings, truth, lines, tol_frames)


def _comparison_doc(c) -> dict:
    def f(v):
        return v if math.isfinite(v) else None

    return {"count_error": f(c.count_error), "precision": f(c.precision), "recall": f(c.recall),
            "movement_error": f(c.movement_error), "movements_true": c.movements_true,
            "movements_measured": c.movements_measured,
            "per_line": [{"line": a, "direction": d, "true": t, "measured": m, "matched": k}
                         for a, d, t, m, k in c.per_line]}


def _print_comparison(c, tolerance_s: float) -> None:
    click.echo(f"against the ground truth (crossings matched within {tolerance_s:g} s):")
    click.echo(f"{'line':<16}{'dir':>4}{'true':>7}{'counted':>9}{'matched':>9}")
    for a, d, t, m, k in c.per_line:
        click.echo(f"{a:<16}{d:>4}{t:>7}{m:>9}{k:>9}")
    click.echo(f"count error {_num(c.count_error, 3)}  crossing precision "
               f"{_num(c.precision, 3)} recall {_num(c.recall, 3)}  turning-movement error "
               f"{_num(c.movement_error, 3)} ({c.movements_measured} tracks with a movement, "
               f"{c.movements_true} true)")


def _num(v: float, digits: int) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _csv(text: str) -> str:
    s = str(text)
    return '"' + s.replace('"', '""') + '"' if any(ch in s for ch in ',"\n') else s

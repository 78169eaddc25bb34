"""``aerotrack track``: the whole pipeline from frames (or detections) to the contract's files."""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import click

from .common import config_option, fps_option, seed_option, set_option

log = logging.getLogger("aerotrack")


def make_progress(total: int | None, label: str, quiet: bool):
    """A progress callback: a tqdm bar on a terminal, plain log lines otherwise."""
    if quiet:
        return (lambda n: None), (lambda: None)
    if sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=total, desc=label, unit="frame", file=sys.stderr, leave=False)
        state = {"n": 0}

        def update(n: int) -> None:
            bar.update(n - state["n"])
            state["n"] = n

        return update, bar.close
    step = max(1, (total or 1000) // 10)
    t0 = time.perf_counter()

    def log_line(n: int) -> None:
        if n % step == 0:
            rate = n / max(time.perf_counter() - t0, 1e-9)
            of = f"/{total}" if total else ""
            log.info("%s: %d%s frames (%.1f frames/s)", label, n, of, rate)

    return log_line, (lambda: None)


def load_inputs(input_path, detections_path, map_path, map_init_path, fps, gsd):
    """Open and validate every input before any work starts (so bad input fails fast)."""
    from ..errors import InputError
    from ..geo import GeoMap, read_map_init
    from ..io import open_source
    from ..io.mot import read_mot

    if input_path is None and detections_path is None:
        raise InputError("give INPUT (a video or image folder) or --detections FILE")
    if (map_path is None) != (map_init_path is None):
        raise InputError("--map and --map-init must be given together")
    if gsd is not None and not (gsd > 0):
        raise InputError(f"--gsd {gsd}: must be a positive number of metres per pixel")
    if fps is not None and not (fps > 0 and fps < 1e4):
        raise InputError(f"--fps {fps}: must be a positive number")
    source = open_source(input_path, fps) if input_path is not None else None
    dets = None
    if detections_path is not None:
        dets = read_mot(detections_path, option="--detections", strict=True)
        bad = (dets[:, 4] <= 0) | (dets[:, 5] <= 0)
        if bad.any():
            raise InputError(f"--detections {detections_path}: row {int(bad.argmax()) + 1} has a "
                             "zero-size box")
    geomap = H_init = None
    if map_path is not None:
        geomap = GeoMap(map_path)
        H_init = read_map_init(map_init_path, geomap)
        if source is not None:
            _check_overlap(source.size, H_init, geomap, map_init_path)
    return source, dets, geomap, H_init


def _check_overlap(size, H_init, geomap, map_init_path) -> None:
    import numpy as np

    from ..errors import GeoreferenceError
    from ..types import apply_homography

    w, h = size
    corners = apply_homography(H_init, np.array([[0, 0], [w, 0], [w, h], [0, h]], float))
    inside = ((corners[:, 0] > -geomap.width) & (corners[:, 0] < 2 * geomap.width)
              & (corners[:, 1] > -geomap.height) & (corners[:, 1] < 2 * geomap.height))
    centre = apply_homography(H_init, np.array([[w / 2, h / 2]], float))[0]
    if not np.all(np.isfinite(corners)) or not (0 <= centre[0] <= geomap.width
                                                and 0 <= centre[1] <= geomap.height) \
            or not inside.any():
        raise GeoreferenceError(
            f"--map-init {map_init_path}: frame 1 does not land on the map (its centre maps to "
            f"map pixel {centre[0]:.0f},{centre[1]:.0f}; the map is {geomap.width}x{geomap.height})"
        )


@click.command("track")
@click.argument("input_path", metavar="[INPUT]", required=False, type=click.Path(path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Output folder (new, or empty; see --overwrite/--resume).")
@click.option("--detections", "detections_path", type=click.Path(path_type=Path), default=None,
              help="MOTChallenge detections (frame,id,x,y,w,h,conf; 1-based) replacing the built-in "
                   "detector. Without INPUT: association alone in image coordinates.")
@click.option("--map", "map_path", type=click.Path(path_type=Path), default=None,
              help="Georeferenced raster (GeoTIFF) of the area: tracking happens on the map.")
@click.option("--map-init", "map_init_path", type=click.Path(path_type=Path), default=None,
              help="Frame 1 -> map: a 3x3 homography, or a CSV of >= 4 control points.")
@click.option("--gsd", type=float, default=None,
              help="Metres per frame pixel when no map is given (speeds and gates become metric).")
@fps_option
@seed_option
@config_option
@set_option
@click.option("--overwrite", is_flag=True, help="Replace results already in --out.")
@click.option("--resume", is_flag=True, help="Continue an interrupted run in --out.")
@click.pass_context
def track_command(ctx, input_path, out_dir, detections_path, map_path, map_init_path, gsd, fps,
                  seed, config_path, overrides, overwrite, resume):
    """Track every moving vehicle: registration, detection, local and global association.

    \b
    Writes to --out: tracks.csv, predicted.csv, detections.csv, registration.csv,
    tracks.geojson (with a map), config.toml, summary.json.

    \b
    Examples:
      aerotrack track flight.mp4 --out run/
      aerotrack track frames/ --out run/ --map ortho.tif --map-init h.txt --fps 30
      aerotrack track --detections yolo.txt --out run/          # association alone
      aerotrack track flight.mp4 --detections yolo.txt --out run/ --seed 3
    """
    from ..config import load_config
    from ..io.output import OutputDir
    from ..outputs import write_outputs
    from ..pipeline import run

    config = load_config(config_path, overrides)
    source, dets, geomap, H_init = load_inputs(input_path, detections_path, map_path,
                                               map_init_path, fps, gsd)
    out = OutputDir(out_dir, overwrite=overwrite, resume=resume)
    quiet = ctx.find_root().obj.get("quiet", False) if ctx.find_root().obj else False
    total = source.count if source is not None else (int(dets[:, 0].max()) if len(dets) else 0)
    progress, close = make_progress(total, "track", quiet)
    t0 = time.perf_counter()
    try:
        result = run(source, config=config, fps=fps, geomap=geomap, H_init=H_init, seed=seed,
                     detections=dets, metres_per_unit=None if geomap else gsd, progress=progress,
                     checkpoint_dir=out.partial, resume=resume)
    finally:
        close()
    info = {
        "input": str(input_path) if input_path else None,
        "detections": str(detections_path) if detections_path else None,
        "map": str(map_path) if map_path else None,
        "seed": seed,
        "wall_time_s": round(time.perf_counter() - t0, 3),
    }
    summary = write_outputs(result, out, config=config, geomap=geomap, run_info=info)
    out.finish()
    c = summary["counts"]
    if not quiet:
        click.echo(
            f"aerotrack: {result.frames} frames, {c['detections']} detections, {c['tracks']} tracks "
            f"-> {out.path}/tracks.csv ({summary['frames_per_second']} frames/s)", err=True)

"""Options and helpers shared by several commands."""

from __future__ import annotations

import logging
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Self

import click

log = logging.getLogger("aerotrack")


class PathArg(click.Path):
    """``click.Path`` that refuses an empty value: ``--out "$DIR"`` with ``DIR`` unset meant the
    current folder (``Path("")`` is ``.``), and an empty input path was reported as a folder."""

    def convert(self, value, param, ctx):
        if isinstance(value, str) and not value.strip():
            self.fail("empty path", param, ctx)
        return super().convert(value, param, ctx)


fps_option = click.option(
    "--fps", type=float, default=None,
    help="Frame rate. Defaults to the video's rate, and to 30 for image folders.",
)
track_fps_option = click.option(
    "--fps", type=float, default=None,
    help="Frame rate. Defaults to the video's rate, and to 30 for image folders and detections "
         "files.",
)
seed_option = click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
                           help="Random seed: the same input, config and seed give the same tracks.")
config_option = click.option("--config", "config_path", type=PathArg(dir_okay=False), default=None,
                             help="TOML file with per-stage parameters (see config.toml of any run).")
set_option = click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
                          help="Override one config parameter (repeatable).")
detections_zero_based_option = click.option(
    "--detections-zero-based", "detections_zero_based", is_flag=True,
    help="--detections numbers frames from 0 (as many detectors do); 1 is added.")
min_conf_option = click.option(
    "--min-conf", "min_conf", type=float, default=None,
    help="Drop detections whose confidence is below this (0-1; sets detection.min_conf, default "
         "0.05): for a detector's low-confidence boxes.")


ground_option = click.option(
    "--ground", "ground_path", type=PathArg(path_type=Path), default=None,
    help="Frame 1 -> a ground plane in metres, for an oblique view without a map (one --gsd is "
         "wrong there): a homography, or CSV frame_x,frame_y,ground_x,ground_y with 4+ measured "
         "points. Size gates and speeds follow the scale at each place.")
map_init_option = click.option(
    "--map-init", "map_init_path", type=PathArg(path_type=Path), default=None,
    help="Frame 1 -> map: a 3x3 homography, or a CSV of >= 4 control points.")
gsd_option = click.option(
    "--gsd", type=float, default=None,
    help="Metres per frame pixel when no map is given: gates become metric, and observations.csv "
         "gives positions (metres on frame 1's ground plane) and speeds.")
telemetry_option = click.option(
    "--telemetry", "telemetry_path", type=PathArg(path_type=Path), default=None,
    help="Flight log (CSV or DJI .srt) placing frame 1 on --map instead of --map-init.")
telemetry_default_option = click.option(
    "--telemetry-default", "telemetry_defaults", multiple=True, metavar="NAME=VALUE",
    help="A value for a column the --telemetry log lacks (repeatable): heading_deg=29 for a DJI "
         ".srt without gimbal yaw; also alt_m, pitch_deg, roll_deg, hfov_deg, focal_35mm.")
intrinsics_option = click.option(
    "--intrinsics", "intrinsics_path", type=PathArg(path_type=Path), default=None,
    help="Camera matrix and distortion (TOML/JSON, OpenCV model): frames are undistorted.")
roi_option = click.option(
    "--roi", "roi_paths", multiple=True, type=PathArg(path_type=Path),
    help="Region of interest (GeoJSON or CSV polygon, frame or map coordinates).")
ignore_option = click.option(
    "--ignore-region", "ignore_paths", multiple=True, type=PathArg(path_type=Path),
    help="Region whose detections are ignored (same formats as --roi). In frame coordinates "
         "(a burned-in caption or timestamp) its pixels are also kept out of detection and "
         "of the background.")
frames_option = click.option(
    "--frames", "frame_range", default=None, metavar="A:B",
    help="Process frames A..B only (1-based, inclusive; either end may be empty).")
stride_option = click.option(
    "--stride", type=click.IntRange(min=1), default=1, show_default=True,
    help="Use every N-th frame.")


class InputParam(PathArg):
    """INPUT: a video file or image folder (a Path), or a network stream's URL (kept as the
    text: ``Path("rtsp://host/live")`` would fold its double slash)."""

    name = "input"

    def convert(self, value, param, ctx):
        from ..io.frames import is_stream_url

        if isinstance(value, str) and is_stream_url(value):
            return value
        return super().convert(value, param, ctx)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM, turned into an exception at a safe point of a run.

    ``signum`` sets the exit code (128 + signum); ``note`` completes the line
    ``aerotrack: interrupted`` (what was kept and how to continue).
    """

    def __init__(self, signum: int = 2, note: str = "") -> None:
        super().__init__(signum)
        self.signum = int(signum)
        self.note = note


def root_flags(ctx: click.Context | None) -> tuple[bool, int]:
    """(quiet, verbose) from the command group's ``-q`` / ``-v`` options."""
    obj = (ctx.find_root().obj if ctx is not None else None) or {}
    return bool(obj.get("quiet", False)), int(obj.get("verbose", 0))


def make_progress(total: int | None, label: str, quiet: bool, verbose: int = 0):
    """A progress callback ``update(n_done)`` and a ``close()``.

    On a terminal: a tqdm bar on stderr (gone when done). Not on a terminal (a pipe, a log file):
    nothing, unless ``-v`` asks for a log line every tenth of the run and at least every
    ``LOG_EVERY_S`` seconds, with the time left. ``-q``: nothing at all.
    """
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
    if verbose < 1:
        return (lambda n: None), (lambda: None)
    step = max(1, (total or 1000) // 10)
    t0 = time.perf_counter()
    state = {"logged": t0, "n": 0}

    def log_line(n: int) -> None:
        now = time.perf_counter()
        if n % step and now - state["logged"] < LOG_EVERY_S:
            return
        rate = n / max(now - t0, 1e-9)
        # the time left at the rate since the last line: the first frames go fast (the
        # detector's window is still filling) and a 4K run's first estimates were half the time
        recent = (n - state["n"]) / max(now - state["logged"], 1e-9) if state["n"] else rate
        state["logged"], state["n"] = now, n
        of = f"/{total}" if total else ""
        left = ""
        if total and recent > 0 and n < total:
            left = f", about {_duration((total - n) / recent)} left"
        log.info("%s: %d%s frames (%.1f frames/s%s)", label, n, of, rate, left)

    return log_line, (lambda: None)


#: Seconds between two ``-v`` progress lines at most (a tenth of a long run is many minutes).
LOG_EVERY_S = 30.0


def _duration(seconds: float) -> str:
    """'45 s', '12 min', '3.5 h'."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def check_positive(value: float | None, option: str, what: str = "a positive number") -> None:
    """Refuse zero, negative, NaN and infinite values of a numeric option."""
    from ..errors import InputError

    if value is not None and not (math.isfinite(value) and value > 0):
        raise InputError(f"{option} {value}: must be {what}")


class CleanupOnBadInput:
    """Context manager: if bad input is found after an output folder was made, leave no trace.

    Some input errors only show once work has started (a config value a stage rejects, an image of
    another size half way through a folder). Then the folder's ``.partial/`` (and the folder
    itself, when this run created it) are removed, so the same command works once the input is
    fixed instead of being refused as "already holds results". Interruptions and other failures
    keep ``.partial/`` for ``--resume``; a ``--resume`` run never deletes what it resumes from.
    With ``always`` (commands that cannot resume) any failure or interruption cleans up.
    """

    def __init__(self, out_dir: Path, resume: bool = False, always: bool = False) -> None:
        self.path = Path(out_dir)
        self.resume = resume
        self.always = always
        self.existed = self.path.exists()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        from ..errors import InputError
        from ..io.output import PARTIAL

        if exc_type is None or self.resume:
            return False
        if not (self.always or issubclass(exc_type, InputError)):
            return False
        shutil.rmtree(self.path / PARTIAL, ignore_errors=True)
        if not self.existed and self.path.is_dir() and not any(self.path.iterdir()):
            self.path.rmdir()
        return False


def check_overwrite(out_dir, overwrite: bool) -> None:
    """``--overwrite`` replaces aerotrack results only: a folder holding anything else (a home
    folder given as --out by mistake) is refused rather than emptied."""
    from ..errors import OutputError
    from ..io.output import is_aerotrack_output

    p = Path(out_dir)
    if not overwrite or not p.is_dir():
        return
    foreign = sorted(e.name for e in p.iterdir() if not is_aerotrack_output(e.name))
    if foreign:
        raise OutputError(f"--out {p}: holds files aerotrack did not write (e.g. {foreign[0]!r}); "
                          "--overwrite only replaces aerotrack results")

"""``aerotrack render``: the overlay video and pictures of a run."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .common import PathArg, make_progress, root_flags

log = logging.getLogger(__name__)


def write_pictures(results, geomap, input_path) -> list[Path]:
    """Write ``map.png``, ``spacetime.png`` and ``registration.png`` into the run folder."""
    from ..viz.mapplot import write_pictures as write

    background = results.reference_image(input_path) if geomap is None else None
    return write(results, geomap, background=background)


def load_map(results, map_path):
    from ..geo import GeoMap

    path = map_path or results.map_path
    return GeoMap(path) if path else None


@click.command("render")
@click.argument("input_path", metavar="INPUT", type=PathArg(exists=False))
@click.argument("run_dir", metavar="DIR", type=PathArg(exists=False, file_okay=False))
@click.option("--out", "out_path", type=PathArg(dir_okay=False), default=None,
              help="Video to write: .webm (VP9, plays in browsers) or .mp4 (H.264). "
                   "Default: DIR/overlay.webm.")
@click.option("--trail-s", type=float, default=2.0, show_default=True,
              help="Seconds of trail drawn behind each target.")
@click.option("--max-width", type=int, default=None,
              help="Downscale wider frames to this width (smaller files; an odd size is padded "
                   "to an even one, which the codecs need).")
@click.option("--start", type=int, default=None,
              help="First frame (1-based). Default: the run's first frame.")
@click.option("--stop", type=int, default=None,
              help="Last frame (inclusive). Default: the run's last frame.")
@click.option("--map", "map_path", type=PathArg(dir_okay=False), default=None,
              help="The run's map raster (default: the map named in DIR/summary.json).")
@click.option("--text-height", type=float, default=0.017, show_default=True,
              help="Label text height, a fraction of the frame height: down to 0.008 for dense "
                   "traffic, where a label is larger than a car.")
@click.option("--labels/--no-labels", default=True, show_default=True,
              help="Draw the ID labels (--no-labels: boxes, trails and predictions only).")
@click.option("--pictures/--no-pictures", default=True, show_default=True,
              help="Also write DIR/map.png, DIR/spacetime.png and DIR/registration.png (into "
                   "DIR, wherever --out puts the video).")
@click.pass_context
def render_command(ctx: click.Context, input_path, run_dir, out_path, trail_s, max_width, start, stop,
                   map_path, text_height, labels, pictures) -> None:
    """Draw a run's tracks on its input video.

    INPUT is the video or image folder the run tracked, DIR its output folder. Targets in view get
    a solid box in a colour fixed by their ID, a label and a short trail; targets out of view get
    their predicted position as a dashed box with an uncertainty circle (or an arrow at the image
    border when predicted outside it).

    \b
    Examples:
      aerotrack render flight.mp4 run/                   # -> run/overlay.webm
      aerotrack render frames/ run/ --out run/overlay.mp4 --trail-s 5
      aerotrack render flight.mp4 run/ --max-width 1280 --start 100 --stop 400
    """
    from ..errors import InputError
    from ..io.frames import open_source
    from ..viz import OverlayStyle, RunResults, render_overlay

    results = RunResults.load(run_dir)
    given_stop = stop is not None
    # by default the frames the run tracked (a --frames A:B run is drawn on A..B, not the video)
    if start is None:
        start = int(results.summary.get("first_frame") or 1)
    if stop is None and results.summary.get("last_frame"):
        stop = int(results.summary["last_frame"])
    if start < 1:
        raise InputError(f"--start {start}: frames are numbered from 1")
    run_first, run_last = results.first_frame, results.last_frame
    if not given_stop and run_last and start > run_last:
        raise InputError(f"--start {start}: after the run's last frame ({run_last}); the run "
                         f"covers frames {run_first}-{run_last} (give --stop to draw others)")
    if run_last and (start > run_last or (stop is not None and stop < run_first)):
        log.warning("frames %d-%s hold none of the frames the run tracked (%d-%d): the video "
                    "shows no tracks", start, stop if stop is not None else "end", run_first,
                    run_last)
    if stop is not None and stop < start:
        raise InputError(f"--start {start} --stop {stop}: need --start <= --stop"
                         + ("" if given_stop else " (--stop defaults to the run's last frame)"))
    if not (trail_s >= 0 and trail_s < float("inf")):
        raise InputError(f"--trail-s {trail_s}: must be a number of seconds >= 0")
    if max_width is not None and max_width < 16:
        raise InputError(f"--max-width {max_width}: too small")
    style = OverlayStyle(trail_s=trail_s, max_width=max_width, text_height=text_height,
                         labels=labels)
    out = Path(out_path) if out_path else results.path / "overlay.webm"
    source = open_source(input_path, results.fps)  # fail fast on a bad input
    results.check_input(source, input_path)
    from ..io.output import check_apart, check_writable

    check_apart(out, "--out", [("INPUT", input_path), ("--map", map_path)], run_dir=results.path,
                own=("overlay.webm", "overlay.mp4"))
    check_writable(out, "--out")  # before rendering, not after
    geomap = load_map(results, map_path) if pictures else None  # a bad --map: before rendering
    if pictures:
        check_writable(results.path / "map.png", "DIR")
    quiet, verbose = root_flags(ctx)
    warn_large_h264(out, source.size, max_width)
    n = source.count
    if n and start > n:
        raise InputError(f"--start {start}: after the last frame of {input_path} ({n})")
    total = (min(stop, n) if stop and n else stop or n)
    total = total - start + 1 if total else None
    progress, close = make_progress(total, "render", quiet, verbose)
    try:
        render_overlay(input_path, results, out, style=style, start=start, stop=stop, progress=progress)
    finally:
        close()
    written = [out]
    if pictures:
        written += write_pictures(results, geomap, input_path)
    if not quiet:
        for p in written:
            click.echo(f"wrote {p}")


#: Largest frame most H.264 decoders play (level 5.2: 4096x2304; browsers and phones alike).
H264_MAX_SIZE = (4096, 2304)


def warn_large_h264(out: Path, size: tuple[int, int], max_width: int | None) -> None:
    """Warn when an .mp4 overlay will be larger than most H.264 decoders play (a wide-area frame
    was written at level 6 with no word, and many players show nothing)."""
    w, h = size
    if max_width is not None and w > max_width:
        w, h = max_width, round(h * max_width / w)
    big, small = max(w, h), min(w, h)
    if out.suffix.lower() == ".mp4" and (big > H264_MAX_SIZE[0] or small > H264_MAX_SIZE[1]):
        logging.getLogger("aerotrack").warning(
            "%s: a %dx%d H.264 video is larger than most players and browsers decode (%dx%d); "
            "--max-width 1920 or a .webm plays more widely", out, w, h, *H264_MAX_SIZE)

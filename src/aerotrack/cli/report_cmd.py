"""``aerotrack report``: one self-contained HTML file for a run."""

from __future__ import annotations

from pathlib import Path

import click

from .common import PathArg, make_progress, root_flags


@click.command("report")
@click.argument("run_dir", metavar="DIR", type=PathArg(exists=False, file_okay=False))
@click.option("--gt", "gt_path", type=PathArg(dir_okay=False), default=None,
              help="Ground truth (MOTChallenge, 1-based frames): adds the evaluation section "
                   "and its errors.")
@click.option("--gt-zero-based", is_flag=True,
              help="The ground truth numbers frames from 0 (as Santiago's): add 1.")
@click.option("--fix-gt", is_flag=True,
              help="Correct the ground truth first (as `aerotrack eval --fix-gt`).")
@click.option("--frames", "gt_frames", default=None, metavar="FIRST:LAST",
              help="Score only these 1-based frames, as `aerotrack eval --frames` (default: the "
                   "run's frames up to the ground truth's last).")
@click.option("--input", "input_path", type=PathArg(), default=None,
              help="The run's input video or image folder, for the overlay player "
                   "(default: the input named in DIR/summary.json, if it still exists).")
@click.option("--map", "map_path", type=PathArg(dir_okay=False), default=None,
              help="The run's map raster (default: the map named in DIR/summary.json).")
@click.option("--out", "out_path", type=PathArg(dir_okay=False), default=None,
              help="Report file to write (.html). Default: DIR/report.html.")
@click.option("--video-width", type=int, default=960, show_default=True,
              help="Width of the embedded overlay video at most (a wider DIR/overlay.webm is "
                   "not embedded: one this wide is rendered for the report).")
@click.option("--video/--no-video", default=True, show_default=True,
              help="Render DIR/overlay.webm from the input (when missing) and embed it.")
@click.pass_context
def report_command(ctx: click.Context, run_dir, gt_path, input_path, map_path, out_path,
                   video_width, video, gt_zero_based=False, fix_gt=False,
                   gt_frames=None) -> None:
    """Write DIR/report.html: a single offline file (no network needed) with the run's numbers,
    timings, registration quality, map and space-time pictures, an overlay player, the track
    table and, with --gt, the evaluation and where its errors are (over time, per true target,
    the frames with the most errors drawn).

    \b
    Examples:
      aerotrack report run/
      aerotrack report run/ --gt gt.txt --input flight.mp4
      aerotrack report run/ --gt dfs_ground_truth.csv --gt-zero-based --fix-gt --frames 2:98
    """
    from ..errors import InputError
    from ..viz.report import ReportOptions, build_report
    from ..viz.results import RunResults

    if gt_path is None and (gt_zero_based or fix_gt or gt_frames is not None):
        raise InputError("--gt-zero-based, --fix-gt and --frames only apply with --gt")
    from .eval_cmd import _parse_frames

    window = _parse_frames(gt_frames)
    results = RunResults.load(run_dir)
    if video_width < 16:
        raise InputError(f"--video-width {video_width}: must be at least 16 pixels")
    if gt_path is not None:
        from ..io.mot import read_mot

        gt_rows = read_mot(gt_path, option="--gt", strict=False, allow_empty=False,
                           zero_based=gt_zero_based)  # before any work
        if window is not None:
            window = _parse_frames(gt_frames, int(gt_rows[:, 0].max()))
            if not ((gt_rows[:, 0] >= window[0]) & (gt_rows[:, 0] <= window[1])).any():
                raise InputError(f"--frames {gt_frames}: no ground-truth rows in these frames "
                                 f"(the ground truth holds frames {int(gt_rows[:, 0].min())}-"
                                 f"{int(gt_rows[:, 0].max())})")
    if input_path is not None:
        if not Path(input_path).exists():
            raise InputError(f"--input {input_path}: no such file or folder")
        from ..io import open_source

        results.check_input(open_source(input_path, results.fps), input_path, "--input")
    from ..io.output import check_apart, check_writable

    if out_path is not None:
        check_apart(out_path, "--out", [("--input", input_path), ("--gt", gt_path),
                                        ("--map", map_path)], run_dir=results.path,
                    own=("report.html",))
        if Path(out_path).suffix.lower() not in (".html", ".htm"):
            # (HTML was written into report.pdf with exit 0)
            raise InputError(f"--out {out_path}: the report is an HTML file; name it .html")
    check_writable(out_path or Path(results.path) / "report.html", "--out")
    geomap = None
    if map_path is not None:
        from ..geo import GeoMap

        geomap = GeoMap(map_path)
    quiet, verbose = root_flags(ctx)
    last = results.last_frame
    progress, close = make_progress(last - results.first_frame + 1 if last else None, "report",
                                    quiet, verbose)  # while the overlay video is rendered
    try:
        out = build_report(results.path, input_path=input_path, gt_path=gt_path, geomap=geomap,
                           out_path=out_path, progress=progress, gt_zero_based=gt_zero_based,
                           fix_gt=fix_gt, checked=input_path is not None, gt_frames=window,
                           options=ReportOptions(video_width=video_width, render_video=video,
                                                 max_video_mb=ReportOptions.max_video_mb if video else 0.0))
    finally:
        close()
    if not quiet:
        click.echo(f"wrote {out}")

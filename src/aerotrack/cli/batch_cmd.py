"""``aerotrack batch``: track every video (and image folder) of a folder, one output folder each."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .common import config_option, fps_option, seed_option, set_option

log = logging.getLogger("aerotrack")


@click.command("batch")
@click.argument("input_dir", type=click.Path(path_type=Path, file_okay=False))
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path, file_okay=False),
              help="Output folder; each input gets OUT/<name>/ with the files of "
                   "`aerotrack track`.")
@click.option("--gsd", type=float, default=None,
              help="Metres per frame pixel (speeds and gates become metric).")
@fps_option
@seed_option
@config_option
@set_option
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Use every N-th frame.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Run on N local worker processes (Dask; pip install aerotrack[dask]): the "
                   "segments of all videos share the workers. Default: one process.")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on an existing Dask cluster (tcp://host:8786); its workers must see the "
                   "inputs under the same paths.")
@click.option("--segment-s", type=float, default=60.0, show_default=True,
              help="With --workers/--scheduler: seconds of video per segment.")
@click.pass_context
def batch_command(ctx, input_dir, out_dir, gsd, fps, seed, config_path, overrides, stride, workers,
                  scheduler, segment_s):
    """Track every video file and image-folder sub-folder of INPUT_DIR.

    Inputs whose output folder already has a summary.json are skipped (a finished run), so an
    interrupted batch continues where it stopped when run again.

    \b
    Examples:
      aerotrack batch flights/ --out runs/ --gsd 0.3
      aerotrack batch flights/ --out runs/ --workers 2
    """
    import contextlib

    from ..config import load_config
    from ..errors import InputError
    from ..parallel import ParallelConfig, dask_client, plan_batch, run_batch

    if gsd is not None and not gsd > 0:
        raise InputError(f"--gsd {gsd}: must be a positive number of metres per pixel")
    if not segment_s > 0:
        raise InputError(f"--segment-s {segment_s}: must be positive")
    config = load_config(config_path, overrides)
    items = plan_batch(input_dir, out_dir)
    if not items:
        raise InputError(f"{input_dir}: no video files or image folders")
    quiet = ctx.find_root().obj.get("quiet", False) if ctx.find_root().obj else False

    def report(item, summary, error):
        if quiet:
            return
        if error is not None:
            click.echo(f"aerotrack: {item.name}: failed: {error}", err=True)
        else:
            c = summary["counts"]
            click.echo(f"aerotrack: {item.name}: {summary['frames']} frames, {c['tracks']} tracks "
                       f"-> {item.out}", err=True)

    for it in items:
        if it.done and not quiet:
            click.echo(f"aerotrack: {it.name}: already finished, skipped", err=True)
    engine = (dask_client(workers=workers, scheduler=scheduler)
              if workers is not None or scheduler is not None else contextlib.nullcontext())
    with engine as client:
        results = run_batch(items, config=config, fps=fps, seed=seed, metres_per_unit=gsd,
                            stride=stride, client=client,
                            parallel=ParallelConfig(segment_s=segment_s), on_done=report)
    failed = [name for name, r in results.items() if isinstance(r, BaseException)]
    done = sum(1 for it in items if it.done)
    if not quiet:
        click.echo(f"aerotrack: batch: {len(results) - len(failed)} tracked, {done} skipped, "
                   f"{len(failed)} failed", err=True)
    if failed:
        raise InputError(f"batch: {len(failed)} of {len(items)} inputs failed: "
                         + ", ".join(failed))

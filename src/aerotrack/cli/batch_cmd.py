"""``aerotrack batch``: track every video (and image folder) of a folder, one output folder each."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .common import (
    PathArg,
    check_positive,
    config_option,
    detections_zero_based_option,
    min_conf_option,
    root_flags,
    seed_option,
    set_option,
)
from .hints import run_hints

log = logging.getLogger("aerotrack")


@click.command("batch")
@click.argument("input_dir", type=PathArg(path_type=Path, file_okay=False))
@click.option("--out", "out_dir", required=True, type=PathArg(path_type=Path, file_okay=False),
              help="Output folder; each input gets OUT/<name>/ with the files of "
                   "`aerotrack track`.")
@click.option("--gsd", type=float, default=None,
              help="Metres per frame pixel (gates become metric; observations.csv in metres).")
@click.option("--map", "map_path", type=PathArg(path_type=Path), default=None,
              help="Georeferenced raster (GeoTIFF) of the area: every input is tracked on it, "
                   "its frame 1 placed by the file beside it: NAME.map-init.txt (or .csv, "
                   ".points; as track's --map-init) or its flight log NAME.srt (or "
                   "NAME.telemetry.csv; as --telemetry).")
@click.option("--detections", "detections", metavar="PATTERN", default=None,
              help="Each input's own detections (MOTChallenge rows) instead of the built-in "
                   "detector: a path inside each input folder (det/det.txt: a MOTChallenge "
                   "sequence's public detections), or a pattern naming a file per input by its "
                   "name: dets/{name}.txt (relative to the current folder).")
@detections_zero_based_option
@min_conf_option
@click.option("--telemetry-default", "telemetry_defaults", multiple=True, metavar="NAME=VALUE",
              help="With --map: a value for a column the flight logs lack (repeatable), as "
                   "track's --telemetry-default.")
@click.option("--roads", "roads_path", type=PathArg(path_type=Path), default=None,
              help="Road centre-lines (needs --map), as track's --roads.")
@click.option("--min-speed", "min_speed", type=float, default=None,
              help="Drop tracks never faster than this many m/s (parked vehicles).")
@click.option("--out-crs", "out_crs", default=None,
              help="Projected CRS of observations.csv/.gpkg and track_segments.gpkg (default: the "
                   "local UTM zone).")
@click.option("--fps", type=float, default=None,
              help="Frame rate of the image folders (default 30) and of videos that name none; a "
                   "video's own rate is kept.")
@seed_option
@config_option
@set_option
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Use every N-th frame.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Run on N local worker processes (Dask; pip install 'aerotrack[dask]'): the "
                   "segments of all videos share the workers. Default: one process.")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on an existing Dask cluster (tcp://host:8786); its workers must see the "
                   "inputs under the same paths.")
@click.option("--stabilised", is_flag=True,
              help="The videos are already stabilised (frames registered to each other): skip "
                   "registration and use identity homographies.")
@click.option("--segment-s", type=float, default=60.0, show_default=True,
              help="With --workers/--scheduler: seconds of video per segment.")
@click.option("--overwrite", is_flag=True,
              help="Track finished inputs again (by default they are skipped; one finished with "
                   "other settings is named).")
@click.pass_context
def batch_command(ctx, input_dir, out_dir, gsd, fps, seed, config_path, overrides, stride, workers,
                  scheduler, segment_s, overwrite, stabilised=False, map_path=None,
                  telemetry_defaults=(), roads_path=None, min_speed=None, out_crs=None,
                  detections=None, detections_zero_based=False, min_conf=None):
    """Track every video file and image-folder sub-folder of INPUT_DIR.

    Inputs whose output folder already has a summary.json are skipped (a finished run), so an
    interrupted batch continues where it stopped when run again; one finished with other
    settings (--config/--set, --seed, --stride, --gsd, --fps, --stabilised, --map, --roads,
    --min-speed, --out-crs, --detections) is named in a warning and kept, and --overwrite tracks every input
    again. An input that cannot be tracked
    (an empty or unreadable video file) is reported on one line and counted as failed: the batch
    goes on with the others and exits with code 2.

    \b
    Examples:
      aerotrack batch flights/ --out runs/ --gsd 0.3
      aerotrack batch flights/ --out runs/ --workers 2
      aerotrack batch flights/ --out runs/ --map ortho.tif   # a.mp4 beside a.srt, b.mp4 ...
      aerotrack batch MOT17/train/ --out runs/ --detections det/det.txt   # public detections
    """
    import contextlib
    from dataclasses import replace

    from ..config import load_config
    from ..errors import InputError
    from ..io.output import check_writable
    from ..parallel import (
        VIDEO_SUFFIXES,
        ParallelConfig,
        batch_changes,
        check_scheduler,
        dask_client,
        plan_batch,
        run_batch,
    )
    from ..pipeline import check_config
    from .track_cmd import GracefulStop

    check_positive(gsd, "--gsd", "a positive number of metres per pixel")
    check_positive(fps, "--fps")
    if not segment_s > 0:
        raise InputError(f"--segment-s {segment_s}: must be positive")
    if min_conf is not None:  # (as track's: the option beats --config/--set)
        if not 0.0 <= min_conf <= 1.0:
            raise InputError(f"--min-conf {min_conf}: must be a confidence between 0 and 1")
        overrides = (*overrides, f"detection.min_conf={min_conf!r}")
    config = load_config(config_path, overrides)
    check_config(config, fps)  # once, before any input is tracked
    geomap, roads, run_info = map_options(map_path, telemetry_defaults, roads_path, min_speed,
                                          out_crs, gsd, stabilised, config)
    if detections_zero_based and detections is None:
        raise InputError("--detections-zero-based: only with --detections")
    if detections is not None and not detections.strip():
        raise InputError("--detections: give a path inside each input folder (det/det.txt) or a "
                         "pattern with {name} (dets/{name}.txt)")
    if detections is not None and "{name}" in detections and not Path(detections).is_absolute():
        # from the folder the command runs in, also on workers that run elsewhere
        detections = str(Path.cwd() / detections)
    if scheduler is not None:
        if workers is not None:
            raise InputError("--workers and --scheduler cannot be used together")
        check_scheduler(scheduler)
    if not Path(input_dir).is_dir():
        raise InputError(f"INPUT_DIR {input_dir}: " + ("is a file; batch takes a folder of videos "
                         "(track takes one video)" if Path(input_dir).exists() else
                         "no such folder"))
    check_writable(out_dir, "--out", folder=True)  # once, not once per input
    items = plan_batch(input_dir, out_dir)
    unusable = unusable_videos(input_dir)
    bad = {p for p, _ in unusable}
    items = [it for it in items if Path(it.input) not in bad]
    if not items and not unusable:
        # a camera card (DCIM/100MEDIA/...): name the sub-folders that hold videos
        deeper = sorted({q.parent.relative_to(input_dir).as_posix()
                         for q in Path(input_dir).glob("*/**/*")
                         if q.is_file() and q.suffix.lower() in VIDEO_SUFFIXES
                         and not any(part.startswith(".")
                                     for part in q.relative_to(input_dir).parts)})
        raise InputError(f"{input_dir}: no video files or image folders"
                         + (f"; videos are in its sub-folder{'s' * (len(deeper) > 1)} "
                            f"{', '.join(deeper[:3])}{', ...' if len(deeper) > 3 else ''}: "
                            "give that folder" if deeper else ""))
    lock = lock_batch(out_dir)
    if lock is not None:
        ctx.call_on_close(lock.close)  # released when the command ends, however it ends
    items = [it for it in plan_batch(input_dir, out_dir) if Path(it.input) not in bad]  # locked
    quiet, _ = root_flags(ctx)

    def report(item, summary, error):
        if error is not None:  # an error: shown even with -q
            click.echo(f"aerotrack: {Path(item.input).name}: failed: {error}", err=True)
        elif quiet:
            return
        else:
            c, k = summary["counts"], summary["frames"]
            click.echo(f"aerotrack: {Path(item.input).name}: {k} frame{'s' * (k != 1)}, "
                       f"{c['tracks']} track{'s' * (c['tracks'] != 1)} -> {item.out}", err=True)

    for path, why in unusable:
        click.echo(f"aerotrack: {path.name}: failed: {path}: {why}", err=True)
    if overwrite:
        items = [replace(it, done=False) for it in items]
    kept_other = 0  # finished inputs kept although tracked with other settings
    for it in items:
        if not it.done:
            continue
        changed = batch_changes(it, config=config, fps=fps, seed=seed, metres_per_unit=gsd,
                                stride=stride, stabilised=stabilised, geomap=geomap,
                                run_info=run_info, detections=detections)
        if changed:  # a warning: shown even with -q
            kept_other += 1
            click.echo(f"aerotrack: WARNING: {Path(it.input).name}: finished with other "
                       f"{', '.join(changed)}; kept as it is (--overwrite tracks it again)",
                       err=True)
        elif not quiet:
            click.echo(f"aerotrack: {Path(it.input).name}: already finished, skipped", err=True)
    local = workers is None and scheduler is None
    engine = contextlib.nullcontext() if local else dask_client(workers=workers,
                                                                scheduler=scheduler)
    # in this process a first Ctrl-C stops after the frame being tracked, keeping that input's
    # checkpoints; running the batch again continues it (it stopped at once and began it anew).
    # On Dask it stops once the input being joined is written (it stopped at once, losing it);
    # the segments of the others are dropped (a batch keeps no segment results)
    if local:
        stopper = GracefulStop(note="; finished inputs are kept, and the one being tracked is "
                                    "continued when the batch is run again")
    else:
        stopper = GracefulStop(note="; finished inputs are kept, the others are tracked when the "
                                    "batch is run again",
                               until="once the input being joined is written")
    with engine as client, _ReportedOnce(), stopper:
        results = run_batch(items, config=config, fps=fps, seed=seed, metres_per_unit=gsd,
                            stride=stride, client=client,
                            parallel=ParallelConfig(segment_s=segment_s), on_done=report,
                            stabilised=stabilised, resume=not overwrite,
                            progress=stopper.wrap(lambda n: None), geomap=geomap, roads=roads,
                            min_speed_mps=min_speed, out_crs=out_crs,
                            telemetry_defaults=telemetry_defaults, run_info=run_info,
                            detections=detections, detections_zero_based=detections_zero_based,
                            hints=run_hints)
    failed = [path.name for path, _ in unusable]
    names = {it.name: Path(it.input).name for it in items}
    failed += [names.get(name, name) for name, r in results.items() if isinstance(r, BaseException)]
    tracked = sum(1 for r in results.values() if not isinstance(r, BaseException))
    done = sum(1 for it in items if it.done)
    if not quiet:
        other = f" ({kept_other} of them tracked with other settings)" if kept_other else ""
        click.echo(f"aerotrack: batch: {tracked} tracked, {done} skipped{other}, "
                   f"{len(failed)} failed", err=True)
    if failed:
        raise InputError(f"batch: {len(failed)} of {len(items) + len(unusable)} inputs failed: "
                         + ", ".join(failed))


def map_options(map_path, telemetry_defaults, roads_path, min_speed, out_crs, gsd, stabilised,
                config):
    """The batch's ``--map``, ``--roads`` and the options that go with them, checked as ``track``
    checks them (before any input is tracked): ``(geomap, roads, run_info)``, ``run_info`` for
    every input's ``summary.json``."""
    from ..errors import InputError
    from .track_cmd import check_out_crs, load_roads, where

    if map_path is None:
        for name, value in (("--telemetry-default", telemetry_defaults),
                            ("--roads", roads_path)):
            if value:
                raise InputError(f"{name}: needs --map")
    if stabilised and map_path is not None:
        raise InputError("--stabilised: not with --map (frames are registered to the map)")
    if min_speed is not None and not (min_speed >= 0 and min_speed < float("inf")):
        raise InputError(f"--min-speed {min_speed}: must be >= 0 m/s")
    geomap = None
    if map_path is not None:
        from ..geo import GeoMap
        from ..geo.telemetry import parse_telemetry_defaults

        if gsd is not None:
            log.warning("--gsd %g: not used with --map (the map gives the scale)", gsd)
        parse_telemetry_defaults(telemetry_defaults)  # checked once, not once per input
        geomap = GeoMap(map_path)
    check_out_crs(out_crs, geomap)
    roads = load_roads(roads_path, geomap, config)
    run_info = {**({"roads": where(roads_path)} if roads_path is not None else {}),
                **({"min_speed": min_speed} if min_speed is not None else {}),
                **({"out_crs": out_crs} if out_crs is not None else {})}
    return geomap, roads, run_info


def lock_batch(out_dir):
    """Hold ``OUT/.batch.lock`` (an exclusive ``flock``, released when the process ends, however
    it ends) so that a second batch into the same --out is refused at once: two at a time each
    took the other's running items for interrupted ones, tracked everything twice and left an
    item with a summary.json but no stages/. Returns the open file (keep it); None where the
    platform has no ``fcntl``."""
    import os

    from ..errors import InputError

    try:
        import fcntl
    except ImportError:  # Windows: no lock
        return None
    path = Path(out_dir) / ".batch.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = open(path, "a+", encoding="utf-8")  # noqa: SIM115  kept open as the lock
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        pid = fh.read().strip() or "?"
        fh.close()
        raise InputError(f"--out {out_dir}: another batch is writing into it (process {pid}); "
                         "wait for it to end, or give another --out") from None
    except OSError as exc:  # e.g. ENOLCK on an NFS mount without a lock daemon
        log.warning("--out %s: cannot lock %s (%s): nothing stops a second batch into the same "
                    "folder; run one at a time", out_dir, path.name, exc.strerror or exc)
        return fh
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    return fh


def unusable_videos(input_dir: Path) -> list[tuple[Path, str]]:
    """Video files of ``input_dir`` that cannot be tracked at all, with the reason: empty files
    (which :func:`~aerotrack.parallel.plan_batch` leaves out) and files without read permission.
    Each is reported and counted as failed, never skipped silently."""
    import os

    from ..parallel import VIDEO_SUFFIXES

    out = []
    for p in sorted(Path(input_dir).iterdir(), key=lambda p: p.name):
        if p.name.startswith(".") or p.suffix.lower() not in VIDEO_SUFFIXES:
            continue
        if p.is_symlink() and not p.exists():
            out.append((p, "a link to nothing (its target is gone)"))
            continue
        if not p.is_file():
            continue
        try:
            size = p.stat().st_size
        except OSError as exc:
            out.append((p, f"cannot read ({exc.strerror})"))
            continue
        if size == 0:
            why = "empty file (0 bytes)"
        elif not os.access(p, os.R_OK):
            why = "cannot read (permission denied)"
        else:
            continue
        out.append((p, why))
    return out


class _ReportedOnce(logging.Filter):
    """While the batch runs, drop the library's own warning about a failed input: the command
    reports each failure once, on one line (``NAME: failed: reason``), through ``on_done``."""

    LOGGER = "aerotrack.parallel"

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.levelno == logging.WARNING and record.args
                    and isinstance(record.args, tuple)
                    and isinstance(record.args[-1], BaseException))

    def __enter__(self):
        logging.getLogger(self.LOGGER).addFilter(self)
        return self

    def __exit__(self, *exc) -> bool:
        logging.getLogger(self.LOGGER).removeFilter(self)
        return False

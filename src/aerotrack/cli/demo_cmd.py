"""``aerotrack demo``: the whole tool on built-in data, in one command."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from .common import PathArg

DEMO_FRAMES = 600  # 20 s at 30 fps: enough for occlusions and an exit/re-entry, quick to run


@click.command("demo")
@click.option("--out", "out_dir", type=PathArg(path_type=Path), default=Path("aerotrack-demo"),
              show_default=True, help="Folder for the scene, the run and the report.")
@click.option("--frames", type=click.IntRange(min=60), default=DEMO_FRAMES, show_default=True,
              help="Length of the rendered scene.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Scene and tracker seed.")
@click.option("--overwrite/--no-overwrite", default=True, show_default=True,
              help="Replace an earlier demo in --out.")
@click.pass_context
def demo_command(ctx: click.Context, out_dir: Path, frames: int, seed: int, overwrite: bool) -> None:
    """Render an aerial scene over a real satellite tile, track it with the full pipeline and its
    map, evaluate against the ground truth, and write an overlay video, pictures and a report.

    \b
    Writes:
      OUT/scene/    the rendered video frames, gt.txt, map.tif, map_init.txt, roads.geojson,
                    true homographies
      OUT/run/      what `aerotrack track` writes with a map (tracks.csv, predicted.csv,
                    links.csv, detections.csv, registration.csv, tracks.geojson,
                    observations.csv/.gpkg/.parquet, track_segments.gpkg, config.toml,
                    summary.json, stages/), then overlay.webm, map.png, spacetime.png,
                    registration.png, report.html

    \b
    Example:
      aerotrack demo --out /tmp/demo
    """
    from ..evaluation import evaluate
    from ..io.mot import read_mot
    from ..io.output import OutputDir
    from .common import check_overwrite
    from .report_cmd import report_command
    from .synth_cmd import synth_command
    from .track_cmd import track_command

    t0 = time.perf_counter()
    check_overwrite(out_dir, overwrite)
    _check_earlier_demo(out_dir, overwrite)
    root = OutputDir(out_dir, overwrite=overwrite)
    scene, run_dir = root.path / "scene", root.path / "run"
    root.finish()
    say = (lambda msg: None) if (ctx.find_root().obj or {}).get("quiet") else \
        (lambda msg: click.echo(f"aerotrack demo: {msg}", err=True))

    say(f"rendering a {frames}-frame scene over the bundled Las Vegas tile -> {scene}")
    ctx.invoke(synth_command, out_dir=scene, seed=seed, frames=frames, scenario="default")
    say("tracking it: registration to the map, detection, local and global association "
        "(unobserved vehicles predicted along the roads)")
    # the scene's frame rate (image files hold none; without it track says to give --fps,
    # which demo does not have)
    fps = float(json.loads((scene / "scenario.json").read_text())["fps"])
    ctx.invoke(track_command, input_path=scene / "frames", out_dir=run_dir,
               map_path=scene / "map.tif", map_init_path=scene / "map_init.txt", seed=seed,
               roads_path=scene / "roads.geojson", fps=fps)
    gt = read_mot(scene / "gt.txt", strict=False)
    pred = read_mot(run_dir / "tracks.csv")
    scores = evaluate(gt, pred)
    from ..errors import InputError
    from ..evaluation.geo import geo_errors

    try:
        geo = geo_errors(gt, pred, "EPSG:4326")
    except InputError:  # no matched boxes: nothing to measure
        geo = None
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary["eval"] = {k: scores[k] for k in ("HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW",
                                              "GT_IDs", "Pred_IDs")}
    if geo is not None:
        summary["eval"]["geo_error_median_m"] = geo["median_m"]
    from ..io.output import atomic_write_text

    atomic_write_text(summary_path, json.dumps(summary, indent=2) + "\n")
    say("writing the overlay video, map pictures and report")
    ctx.invoke(report_command, run_dir=run_dir, gt_path=scene / "gt.txt",
               input_path=scene / "frames")
    took = time.perf_counter() - t0
    click.echo(
        f"HOTA {scores['HOTA']:.3f}  IDF1 {scores['IDF1']:.3f}  MOTA {scores['MOTA']:.3f}  "
        f"ID switches {int(scores['IDSW'])}  ({scores['GT_IDs']} vehicles came into view, "
        f"{scores['Pred_IDs']} tracks)  tracking at {summary.get('frames_per_second')} frames/s"
        + (f"\nmedian position error of matched vehicles: {geo['median_m']:.2f} m on the map"
           if geo else "")
    )
    click.echo(f"report:  {run_dir / 'report.html'}")
    click.echo(f"overlay: {run_dir / 'overlay.webm'}")
    click.echo(f"tracks:  {run_dir / 'tracks.csv'} (map: {run_dir / 'tracks.geojson'})")
    click.echo(f"demo finished in {took:.0f} s")


def _check_earlier_demo(out_dir: Path, overwrite: bool) -> None:
    """``--overwrite`` replaces an earlier demo only: a folder holding anything but a demo's
    ``scene/`` and ``run/`` (a ``track`` run's results given as --out by mistake) is refused."""
    from ..errors import OutputError
    from ..io.output import PARTIAL

    p = Path(out_dir)
    if not overwrite or not p.is_dir():
        return
    other = sorted(e.name for e in p.iterdir() if e.name not in ("scene", "run", PARTIAL))
    if other:
        raise OutputError(f"--out {p}: holds {other[0]!r}, so it is not an earlier demo's folder "
                          "(scene/ and run/); give a new or empty folder, or an earlier demo's")
    # and inside them only what synth and track write (a file of the user's in run/ was deleted)
    from ..io.output import is_aerotrack_output

    for sub in ("scene", "run"):
        if (p / sub).is_dir():
            foreign = sorted(e.name for e in (p / sub).iterdir()
                             if not is_aerotrack_output(e.name))
            if foreign:
                raise OutputError(f"--out {p}: {sub}/ holds {foreign[0]!r}, which no demo "
                                  "writes; move it away, or give a new or empty folder")

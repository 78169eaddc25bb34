"""``aerotrack synth``: render a scenario with ground truth."""

from __future__ import annotations

from pathlib import Path

import click

from .common import CleanupOnBadInput, PathArg, check_overwrite, make_progress, root_flags


def parse_size(text: str) -> tuple[int, int]:
    from ..errors import InputError

    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        raise InputError(f"--size {text}: expected WIDTHxHEIGHT, e.g. 640x480") from None
    if not sep:
        raise InputError(f"--size {text}: expected WIDTHxHEIGHT, e.g. 640x480")
    return size


@click.command("synth")
@click.option("--out", "out_dir", required=True, type=PathArg(path_type=Path),
              help="Output folder (new or empty; see --overwrite).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Scene seed.")
@click.option("--frames", type=int, default=900, show_default=True, help="Number of frames.")
@click.option("--scenario", default="default", show_default=True,
              help="default, static, occlusion, exits, convoy or dense.")
@click.option("--size", "size_text", default="640x480", show_default=True,
              help="Frame size WIDTHxHEIGHT.")
@click.option("--fps", type=float, default=30.0, show_default=True, help="Frame rate.")
@click.option("--gsd-scale", type=float, default=1.0, show_default=True,
              help="Fly the same path this many times higher (2: vehicles half as long in "
                   "pixels; 0.5: twice as long). Between 0.125 and 8; where the view is wider "
                   "than the bundled tile (above about 2.5 at 640x480) the ground beyond it is "
                   "the tile mirrored, without traffic.")
@click.option("--overwrite", is_flag=True, help="Replace what is already in --out.")
@click.pass_context
def synth_command(ctx, out_dir, seed, frames, scenario, size_text, fps, gsd_scale, overwrite):
    """Render an aerial video over a real satellite tile, with exact ground truth.

    Vehicles drive the tile's real road centre-lines (turns, stops, U-turns, convoys) under tree
    canopies and an overpass, seen by a UAV camera that moves, yaws and zooms.

    \b
    Writes to --out: frames/000001.jpg..., gt.txt (visible targets), states.csv (every target,
    visible/occluded/outside; its heading_deg is on the map image, from east towards south, not
    a compass bearing), homographies.csv (true frame -> map pixels), map.tif, map_init.txt,
    map_init_gcps.csv, map_init_lonlat.csv, occluders.csv, occluders.geojson (lon/lat),
    roads.geojson, scenario.json.

    \b
    Examples:
      aerotrack synth --out scene/
      aerotrack synth --out scene/ --seed 3 --frames 1800 --scenario exits
      aerotrack synth --out high/ --gsd-scale 2     # from twice as high: small vehicles
      aerotrack track scene/frames --out run/ --map scene/map.tif --map-init scene/map_init.txt
    """
    from ..io.output import OutputDir
    from ..synth import render_to
    from ..synth.scene import Scenario

    size = parse_size(size_text)
    Scenario.validate(frames=frames, size=size, fps=fps, name=scenario, gsd_scale=gsd_scale)
    check_overwrite(out_dir, overwrite)
    cleanup = CleanupOnBadInput(out_dir, always=True)  # before the folder is made; no --resume
    out = OutputDir(out_dir, overwrite=overwrite, stage=True)
    quiet, verbose = root_flags(ctx)
    progress, close = make_progress(frames, "synth", quiet, verbose)
    with cleanup:
        try:
            info = render_to(out, seed=seed, frames=frames, size=size, fps=fps,
                             scenario=scenario, progress=progress, gsd_scale=gsd_scale)
        finally:
            close()
    if not quiet:
        click.echo(f"aerotrack: rendered {frames} frames of scenario {scenario!r} "
                   f"({info['vehicles']} vehicles, {info['gt_rows']} visible boxes) -> {out.path}",
                   err=True)

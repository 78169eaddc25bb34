"""``aerotrack predict``: where were unobserved targets? Motion context on any tracks file."""

from __future__ import annotations

import logging

import click

from ..config import load_config
from ..context.motion import PREDICTION_METHODS
from ..context.predict import run_predict
from .common import PathArg, check_positive, config_option, set_option

log = logging.getLogger(__name__)


@click.command("predict")
@click.argument("tracks", type=PathArg(dir_okay=False))
@click.option("--queries", "queries", required=True, type=PathArg(dir_okay=False),
              help="CSV with a header id,last_seen,horizon: predict track `id` for the `horizon` "
                   "frames after `last_seen`.")
@click.option("--out", "out", required=True, type=PathArg(dir_okay=False),
              help="Output CSV: query,id,frame,x,y (query = 0-based row of the queries file).")
@click.option("--method", type=click.Choice(list(PREDICTION_METHODS)), default=None,
              help="Predictor: context (default: Kalman fused with other objects' paths and "
                   "co-movers), paper (Ali et al. 2007 as written), kalman, constant-velocity.")
@click.option("--fps", type=float, default=30.0, show_default=True, help="Frame rate of the tracks.")
@click.option("--space", type=click.Choice(["image", "map"]), default="image", show_default=True,
              help="Predict box centres (image) or the x,y map columns (map).")
@click.option("--gsd", type=float, default=None,
              help="Metres per coordinate unit. Default: metres (or lon/lat degrees) for --space "
                   "map; for image, the median box's long side is taken as context.image_object_size_m.")
@click.option("--roads", "roads", type=PathArg(dir_okay=False), default=None,
              help="Road centre-lines (GeoJSON LineStrings, any CRS) for --space map: the context "
                   "method predicts targets on a road along it.")
@click.option("--crs", "crs", default=None,
              help="With --roads: CRS of the tracks' x,y columns (default EPSG:4326 when they "
                   "look like lon/lat degrees).")
@click.option("--zero-based", "zero_based", is_flag=True,
              help="TRACKS and the queries number frames from 0 (Santiago's ground truth, SDD); "
                   "the answer does too.")
@click.option("--score", is_flag=True,
              help="Also score the predictions against TRACKS's own rows of each target after "
                   "last_seen (where it has them): MPE_n and Variance_n (Ali et al. section 5) "
                   "at n = 1, 10, 30, 60 frames and the horizon, in metres when the scale is "
                   "known.")
@config_option
@set_option
def predict_command(tracks, queries, out, method, fps, space, gsd, config_path, overrides,
                    roads=None, crs=None, score=False, zero_based=False):
    """Predict the positions of targets after they were last seen (motion context).

    The prediction at frame f uses only the target's rows up to last_seen and the other tracks'
    rows up to f, so it is what an online tracker could have known.

    \b
    Examples:
      aerotrack predict run/tracks.csv --queries q.csv --out p.csv
      aerotrack predict tracks.csv --queries q.csv --out p.csv --method paper --fps 25
      aerotrack predict run/tracks.csv --queries q.csv --out p.csv --space map
      aerotrack predict gt.csv --queries q.csv --out p.csv --score   # MPE_n against gt's rows
    """
    from pathlib import Path

    from ..errors import InputError, OutputError
    from ..io.output import check_writable

    check_positive(fps, "--fps")
    check_positive(gsd, "--gsd")
    if crs is not None and roads is None:
        raise InputError(f"--crs {crs}: only used with --roads (the CRS of the tracks' x,y columns)")
    for label, given in (("TRACKS", tracks), ("--queries", queries)):
        if Path(out).resolve() == Path(given).resolve():  # would replace an input with answers
            raise InputError(f"--out {out}: is the {label} file; write the predictions elsewhere")
    config = load_config(config_path, overrides).context
    check_writable(out, "--out")
    try:
        n = run_predict(tracks, queries, out, method=method or config.method, fps=fps,
                        space=space, config=config, metres_per_unit=gsd, roads=roads, crs=crs,
                        zero_based=zero_based)
    except OutputError as exc:
        raise OutputError(f"--out {exc}") from None
    log.info("wrote %d predicted positions to %s", n, out)
    if score:
        from ..context.predict import score_predictions

        rows, unit = score_predictions(tracks, out, space=space, fps=fps, metres_per_unit=gsd,
                                       zero_based=zero_based)
        click.echo(f"{'n':>6}{'s':>8}{'queries':>9}{'MPE_n':>12}{'Variance_n':>13}  ({unit})")
        for r in rows:
            click.echo(f"{r['n']:>6}{r['seconds']:>8.2f}{r['queries']:>9}{r['MPE']:>12.4f}"
                       f"{r['Variance']:>13.4f}")

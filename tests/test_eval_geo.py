"""Geo error evaluation: metres between matched true and predicted map positions."""

import json

import numpy as np
import pytest

from aerotrack.cli.main import main
from aerotrack.errors import InputError
from aerotrack.evaluation.geo import geo_errors
from aerotrack.io.mot import write_mot


def rows(n=20, x0=-115.232, y0=36.14):
    out = []
    for f in range(1, n + 1):
        out.append([f, 1, 100 + f, 50, 16, 8, 1, x0 + f * 1e-5, y0, -1])
        out.append([f, 2, 300, 200 + f, 16, 8, 1, x0, y0 + f * 1e-5, -1])
    return np.array(out, float)


def test_known_offset_in_lonlat():
    gt = rows()
    pred = gt.copy()
    pred[:, 8] += 1e-5  # 1e-5 degrees of latitude = 1.109 m
    r = geo_errors(gt, pred, "EPSG:4326")
    assert r["matches"] == 40
    assert r["median_m"] == pytest.approx(1.109, abs=0.005)


def test_known_offset_in_projected_feet():
    gt = rows(x0=1000.0, y0=2000.0)
    pred = gt.copy()
    pred[:, 7] += 10.0  # 10 US survey feet
    r = geo_errors(gt, pred, "EPSG:2229")
    assert r["median_m"] == pytest.approx(3.048, abs=0.01)


def test_no_positions_is_an_error():
    gt = rows()
    gt[:, 7:9] = -1
    with pytest.raises(InputError):
        geo_errors(gt, gt, "EPSG:4326")


def test_cli_geo_error(tmp_path, capsys):
    gt = rows()
    pred = gt.copy()
    pred[:, 7] += 2e-5
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", pred)
    main(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred", str(tmp_path / "pred.txt"),
          "--geo-crs", "EPSG:4326", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["geo_error"]["median_m"] == pytest.approx(1.8, abs=0.05)
    assert out["IDF1"] == pytest.approx(1.0)


def test_a_run_on_a_projected_map_scores_against_lonlat(tmp_path, capsys):
    """A run on a UTM map (tracks.csv x, y in metres) scored with --geo-crs EPSG:4326 against
    lon/lat ground truth gave a NaN geo error and --json a traceback (a probe): a run folder's
    tracks.csv is converted from its map's CRS; a bare file of metres is a one-line error."""
    from pyproj import Transformer

    gt = rows()
    write_mot(tmp_path / "gt.txt", gt)
    run = tmp_path / "run"
    run.mkdir()
    pred = gt.copy()
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32611", always_xy=True)
    pred[:, 7], pred[:, 8] = to_utm.transform(pred[:, 7], pred[:, 8] + 1e-5)  # 1.109 m north
    write_mot(run / "tracks.csv", pred)
    (run / "summary.json").write_text(json.dumps({"map_crs": "EPSG:32611"}))
    from conftest import run_cli

    argv = ["eval", "--gt", tmp_path / "gt.txt", "--pred", run / "tracks.csv", "--geo-crs",
            "EPSG:4326", "--json"]
    code, out, err = run_cli(capsys, *argv)
    assert code == 0, err
    assert json.loads(out)["geo_error"]["median_m"] == pytest.approx(1.109, abs=0.01)
    # a file of the user's beside a run's results is not converted (it was: 4053 km)
    (run / "mine.csv").write_bytes((tmp_path / "gt.txt").read_bytes())
    code, out, err = run_cli(capsys, "eval", "--gt", tmp_path / "gt.txt", "--pred",
                             run / "mine.csv", "--geo-crs", "EPSG:4326", "--json")
    assert code == 0 and json.loads(out)["geo_error"]["median_m"] == pytest.approx(0, abs=0.01)
    (run / "summary.json").unlink()
    code, out, err = run_cli(capsys, *argv)
    assert code == 2 and "--pred's x, y are not degrees" in err and "Traceback" not in err, err

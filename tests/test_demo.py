"""`aerotrack demo`, the README's main job, end to end on a short scene."""

from __future__ import annotations

import json

from aerotrack.cli.main import main
from aerotrack.io.mot import read_mot


def test_demo_writes_scored_tracks_report_and_video(tmp_path, capsys):
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--frames", "120", "--seed", "1"])
    printed = capsys.readouterr().out
    assert code in (0, None), printed
    run = out / "run"
    for name in ("tracks.csv", "predicted.csv", "registration.csv", "tracks.geojson",
                 "summary.json", "report.html", "map.png", "spacetime.png"):
        assert (run / name).stat().st_size > 0, name
    assert any(run.glob("overlay.*"))
    assert (out / "scene" / "roads.geojson").exists()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["roads"] == str(out / "scene" / "roads.geojson")
    ev = summary["eval"]
    # the scores printed are the scores of the files written
    assert f"HOTA {ev['HOTA']:.3f}" in printed and f"IDF1 {ev['IDF1']:.3f}" in printed
    # vehicles are found and followed (a broken stage scores ~0 here)
    assert len(read_mot(run / "tracks.csv")) > 0
    assert ev["HOTA"] > 0.25 and ev["IDF1"] > 0.3
    assert ev["geo_error_median_m"] < 1.0


def test_demo_replaces_an_earlier_demo_only(tmp_path, capsys):
    from conftest import run_cli

    run = tmp_path / "run_of_track"
    run.mkdir()
    (run / "tracks.csv").write_text("1,1,0,0,10,10,1,-1,-1,-1\n")  # a `track` run's results
    code, _, err = run_cli(capsys, "demo", "--out", run, "--frames", "60")
    assert code == 2 and "not an earlier demo" in err and "Traceback" not in err, err
    assert (run / "tracks.csv").is_file() and sorted(p.name for p in run.iterdir()) == ["tracks.csv"]
    code, _, err = run_cli(capsys, "demo", "--out", tmp_path / "d", "--seed", "-1")
    assert code == 2 and "--seed" in err and "Traceback" not in err, err
    assert not (tmp_path / "d").exists()
    # a file of the user's inside an earlier demo's run/ was deleted (a probe)
    (tmp_path / "e" / "run").mkdir(parents=True)
    (tmp_path / "e" / "run" / "mine.csv").write_text("precious")
    code, _, err = run_cli(capsys, "demo", "--out", tmp_path / "e", "--frames", "60")
    assert code == 2 and "run/ holds 'mine.csv'" in err, err
    assert (tmp_path / "e" / "run" / "mine.csv").read_text() == "precious"

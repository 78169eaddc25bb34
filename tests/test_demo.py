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

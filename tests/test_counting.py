"""Screen-line counts and turning movements (``aerotrack count``)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from conftest import run_cli
from test_viz import _H, VEGAS, _east_metres_per_px, grey_frames, make_run  # tests on sys.path

from aerotrack.analysis.counting import (
    CountLine,
    compare_counts,
    count_crossings,
    in_view_per_bin,
    line_in_view,
    movement_matrix,
    movements,
    parse_line,
    speed_window_frames,
    tally,
    track_crossings,
)
from aerotrack.errors import InputError
from aerotrack.geo import GeoMap


def _path(n=40, x0=0.0, step=1.0, y=0.0, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    f = np.arange(1, n + 1)
    w = np.column_stack([x0 + step * (f - 1), np.full(n, y)]) + rng.normal(0, jitter, (n, 2))
    return f, w, np.ones(n, bool)


VERTICAL = CountLine("v", (20.0, -10.0), (20.0, 10.0))  # x = 20, drawn downwards (y down)


def test_a_straight_crossing_is_counted_once_where_and_when_it_happens():
    f, w, ob = _path()  # x = 0..39 along y = 0, one unit a frame: at x = 20 in frame 21
    (c,) = track_crossings(f, w, ob, VERTICAL, band=1.0, track_id=7)
    assert c.frame == pytest.approx(21.0) and np.allclose(c.world, [20.0, 0.0])
    assert np.allclose(c.velocity, [1.0, 0.0])
    assert c.id == 7 and c.observed
    # walking down the line (+y on the screen) its right is -x: eastwards is right to left
    assert c.direction == "-"
    (back,) = track_crossings(f, w[::-1].copy(), ob, VERTICAL, band=1.0)
    assert back.direction == "+"


def test_jitter_about_the_line_is_one_crossing_and_a_vehicle_waiting_on_it_none():
    # a vehicle creeping over the line with 0.6-unit jitter: its sign flips many times near it
    f, w, ob = _path(n=200, x0=10.0, step=0.1, jitter=0.6, seed=3)
    raw = np.sum(np.diff(np.sign(w[:, 0] - 20.0)) != 0)
    assert raw > 3  # what counting every sign change would have counted
    assert len(track_crossings(f, w, ob, VERTICAL, band=2.0)) == 1
    # one that waits on the line and drives back where it came from crossed nothing
    x = np.r_[np.linspace(10, 20, 50), np.full(50, 20.0), np.linspace(20, 10, 50)]
    w2 = np.column_stack([x, np.zeros_like(x)]) + np.random.default_rng(1).normal(0, 0.6, (150, 2))
    assert track_crossings(np.arange(1, 151), w2, np.ones(150, bool), VERTICAL, band=2.0) == []


def test_only_the_segment_counts_and_only_between_sightings():
    f, w, ob = _path(y=15.0)  # passes 5 units beyond the line's end
    assert track_crossings(f, w, ob, VERTICAL, band=1.0) == []
    assert len(track_crossings(f, w, ob, VERTICAL, band=6.0)) == 1  # within band of the end
    f, w, ob = _path()
    ob[15:30] = False  # crossed while predicted (under a bridge), seen again after
    (c,) = track_crossings(f, w, ob, VERTICAL, band=1.0)
    assert not c.observed
    ob[15:] = False  # the crossing is in the prediction after the last sighting: a guess
    assert track_crossings(f, w, ob, VERTICAL, band=1.0) == []


def test_tally_movements_and_comparison():
    a = CountLine("a", (20.0, -10.0), (20.0, 10.0))
    b = CountLine("b", (60.0, -10.0), (60.0, 10.0))

    class T:
        def __init__(self, id, frames, world):
            self.id, self.frames, self.world = id, frames, world
            self.observed = np.ones(len(frames), bool)

    f = np.arange(1, 101)
    east = np.column_stack([f - 1.0, np.zeros(100)])
    truth = [T(1, f, east), T(2, f, east + [5.0, 0.0])]  # both cross a (frames ~21, 16), then b
    lines = [a, b]
    tc = count_crossings(truth, lines, 1.0)
    assert [(c.line, c.id) for c in tc] == [("a", 2), ("a", 1), ("b", 2), ("b", 1)]
    assert movement_matrix(movements(tc)) == {("a", "b"): 2}
    rows = tally(tc, lines, fps=10.0, first_frame=1, last_frame=100, bin_s=2.0)
    assert len(rows) == 2 * 2 * 5 and sum(r[4] for r in rows) == 4
    assert ("a", "-", 2.0, 4.0, 1) in rows and ("a", "-", 0.0, 2.0, 1) in rows  # frames 21, 16
    # measured: track 2 lost before b, and a false track crossing a the other way
    measured = [T(1, f, east), T(2, f[:50], east[:50] + [5.0, 0.0]), T(9, f, east[::-1])]
    mc = count_crossings(measured, lines, 1.0)
    cmp = compare_counts(mc, tc, lines, tolerance_frames=10)
    per = {(ln, d): (t, m, k) for ln, d, t, m, k in cmp.per_line}
    assert per[("a", "-")] == (2, 2, 2) and per[("b", "-")] == (2, 1, 1)
    assert per[("a", "+")] == (0, 1, 0) and per[("b", "+")] == (0, 1, 0)
    assert cmp.count_error == pytest.approx(3 / 4)  # |2-2| + |1-2| + |1-0| + |1-0| over 4
    assert cmp.precision == pytest.approx(3 / 5) and cmp.recall == pytest.approx(3 / 4)
    # true OD {a->b: 2}; measured {a->b: 1, b->a: 1}: |1-2| + |1-0| over 2
    assert cmp.movement_error == pytest.approx(1.0)


@pytest.mark.parametrize("text", ["north", "n:1,2,3", "n:1,2,3,x", ":1,2,3,4", "n:1,1,1,1",
                                  "n:1,2,3,nan"])
def test_malformed_lines_are_refused(text):
    with pytest.raises(InputError, match="--line"):
        parse_line(text)


def test_parse_line_keeps_colons_in_names():
    name, pts = parse_line("Av. Sur: lane 1:10,20,30,40")
    assert name == "Av. Sur: lane 1" and pts.tolist() == [[10, 20], [30, 40]]


def test_count_command_on_a_run_folder(tmp_path, capsys):
    # make_run: 3 targets driving east at 3.7 map px a frame; target 2 predicted in frames 20..34.
    # Frame 1 -> map pixels is a translation by (302, 500), so x = 160 in frame 1 is map x 462,
    # which targets 1, 2, 3 (map x 420, 440, 400 + 3.7 f) cross in frames 11.4, 6.0 and 16.8.
    run = make_run(tmp_path, with_map=True, n_frames=60)
    assert np.allclose(_H(1)[:2, 2], [302, 500])
    code, out, err = run_cli(capsys, "count", run, "--line", "x160:160,0,160,200", "--gt",
                             run / "tracks.csv", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["lines"] == {"x160": {"+": 0, "-": 3}}
    assert doc["comparison"]["recall"] == 1.0
    with open(run / "crossings.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["id"]) for r in rows] == [2, 1, 3]
    assert [float(r["frame"]) for r in rows] == pytest.approx([5.946, 11.351, 16.757], abs=0.01)
    assert all(abs(float(r["lon"]) + 115.23) < 0.02 for r in rows)  # the Vegas tile
    # spot speed: 3.7 map px a frame at 10 frames/s eastwards, in metres on the ground
    gm = GeoMap(VEGAS)
    want = 3.7 * 10 * _east_metres_per_px(gm, at=(462.0, 600.0))
    assert [float(r["speed_mps"]) for r in rows] == pytest.approx([want] * 3, rel=0.01)
    import cv2

    # the input is not at hand: drawn on the map around the line and the paths (1 map px = 1 px)
    img = cv2.imread(str(run / "count_lines.png"))
    yellow = np.all(img == (0, 255, 255), axis=2)[: img.shape[0] // 2]  # (the key is below)
    xs = np.flatnonzero(yellow.any(axis=0))
    assert img.shape[:2] != (240, 320) and len(xs) and np.ptp(xs) < 30  # the vertical line
    # a line the predicted stretch of target 2 crosses (map x 440 + 3.7 f = 520 at f ~ 21.6)
    frames = grey_frames(tmp_path / "frames", n=3)
    code, out, err = run_cli(capsys, "count", run, "--line", "p:218,50,218,150", "--out",
                             tmp_path / "c2", "--json", "--input", frames)
    assert code == 0, err
    img = cv2.imread(str(tmp_path / "c2" / "count_lines.png"))
    assert img.shape == (240, 320, 3)
    # the line in yellow (but where the crossings' dots, its arrow and its name cover it)
    assert (img[50:150, 218] == (0, 255, 255)).all(axis=1).mean() > 0.6
    with open(tmp_path / "c2" / "crossings.csv", newline="") as fh:
        rows = {int(r["id"]): r["observed"] for r in csv.DictReader(fh)}
    assert rows == {1: "1", 2: "0", 3: "1"}
    # counted again without a picture: the earlier lines' picture goes (the report showed it
    # beside the new counts)
    code, out, err = run_cli(capsys, "count", run, "--line", "q:100,50,100,150", "--out",
                             tmp_path / "c2", "--no-picture")
    assert code == 0, err
    assert not (tmp_path / "c2" / "count_lines.png").exists()


def test_count_command_refuses_bad_input_in_one_line(tmp_path, capsys):
    run = make_run(tmp_path, with_map=False, n_frames=20)
    for argv, needle in [
        ((run,), "no count lines"),
        ((run, "--line", "a:1,2,3"), "--line"),
        ((run, "--line", "a:1,2,3,4", "--line", "a:5,6,7,8"), "'a' is given to two lines"),
        ((run, "--lines", tmp_path / "l.geojson"), "need a run with a map"),
        ((run, "--line", "a:1,2,3,4", "--band", "-1"), "--band"),
        ((run, "--line", "a:1,2,3,4", "--bin", "0"), "--bin"),
        ((tmp_path / "nothing", "--line", "a:1,2,3,4"), "no such output folder"),
        ((run, "--line", "a:1,2,3,4", "--fix-gt"), "only apply with --gt"),
        ((run, "--line", "a:1,2,3,4", "--gt", tmp_path / "nope.txt"), "--gt"),
        ((run, "--line", "a:1,2,3,4", "--bin", "1e-7"), "shorter than one frame"),
    ]:
        code, _out, err = run_cli(capsys, "count", *argv)
        assert code == 2 and needle in err and "Traceback" not in err, (argv, err)
        assert len(err.strip().splitlines()) == 1, err
    assert not (run / "crossings.csv").exists()


def test_geojson_lines_in_lonlat(tmp_path, capsys):
    run = make_run(tmp_path, with_map=True, n_frames=60)
    gm = GeoMap(VEGAS)
    ll = gm.pixel_to_lonlat(np.array([[462.0, 500.0], [462.0, 700.0]]))  # map x 462, as above
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "x462"},
         "geometry": {"type": "LineString", "coordinates": ll.tolist()}}]}
    (tmp_path / "l.geojson").write_text(json.dumps(doc))
    code, out, err = run_cli(capsys, "count", run, "--lines", tmp_path / "l.geojson", "--json")
    assert code == 0, err
    assert json.loads(out)["lines"] == {"x462": {"+": 0, "-": 3}}
    doc["features"][0]["geometry"]["coordinates"].append(ll[0].tolist())
    (tmp_path / "l.geojson").write_text(json.dumps(doc))
    code, out, err = run_cli(capsys, "count", run, "--lines", tmp_path / "l.geojson")
    assert code == 2 and "exactly 2" in err


def test_count_outputs_do_not_make_a_run_folder_foreign(tmp_path, capsys):
    """count writes into the run folder; track --overwrite and batch refuse folders holding
    files aerotrack did not write, so count's must be known as aerotrack's."""
    from aerotrack.io.output import is_aerotrack_output

    run = make_run(tmp_path, with_map=False, n_frames=20)
    frames = grey_frames(tmp_path / "frames", n=3)
    code, _, err = run_cli(capsys, "count", run, "--line", "a:10,0,10,100", "--input", frames)
    assert code == 0, err
    assert all(is_aerotrack_output(p.name) for p in run.iterdir()), sorted(p.name for p in run.iterdir())


def test_report_shows_the_counts(tmp_path, capsys):
    run = make_run(tmp_path, with_map=True, n_frames=60)
    frames = grey_frames(tmp_path / "frames", n=60)
    code, _, err = run_cli(capsys, "count", run, "--line", "x160:160,0,160,200", "--input", frames)
    assert code == 0, err
    code, _, err = run_cli(capsys, "report", run, "--input", frames, "--no-video")
    assert code == 0, err
    page = (run / "report.html").read_text()
    assert '<section id="counts">' in page and "<td>x160</td><td>0</td><td>3</td>" in page
    assert 'alt="count lines"' in page


def test_line_in_view_is_the_share_of_the_line_inside_each_frame():
    line = CountLine("v", (50.0, -50.0), (50.0, 50.0))  # half above the frame's top edge
    hs = np.stack([np.eye(3), np.array([[1.0, 0, -60.0], [0, 1, 0], [0, 0, 1]])])
    share = line_in_view(line, hs, (100, 100), samples=101)
    assert share[0] == pytest.approx(0.5, abs=0.01)
    assert share[1] == 0.0  # frame 2's pixels start at world x -60: x 50 is past its right edge
    # bins: frames 1-5 see half of it, 6-10 have no registration row (not seen)
    per_bin = in_view_per_bin(np.arange(1, 6), np.full(5, 0.5), fps=5.0, first_frame=1,
                              last_frame=10, bin_s=1.0)
    assert per_bin == pytest.approx([0.5, 0.0])


def test_counts_say_when_the_camera_did_not_see_a_line(tmp_path, capsys):
    # make_run's camera drifts 2 map px a frame east: frame 1's x = 10 (map x 312) leaves the
    # 320-px-wide view after frame 6; x = 160 stays in view for all 60 frames
    run = make_run(tmp_path, with_map=True, n_frames=60)
    code, _, err = run_cli(capsys, "count", run, "--line", "x160:160,0,160,200",
                             "--line", "x10:10,0,10,200", "--bin", "1")
    assert code == 0, err
    assert "'x10' was in view for 10% of the run" in err and "'x160'" not in err
    with open(run / "counts.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["direction"] == "+"]
    seen = {r["line"]: [float(r["in_view"]) for r in rows if r["line"] == r2]
            for r2 in ("x10", "x160") for r in rows if r["line"] == r2}
    assert seen["x160"] == [1.0] * 6
    assert seen["x10"] == pytest.approx([0.6, 0, 0, 0, 0, 0])


def test_speed_window_is_a_time_not_a_number_of_frames(tmp_path):
    # a vehicle at 10 px a frame that stops 5 frames after the line: measured over
    # 0.25 s either side, the speed at the line does not depend on the frame rate's window
    assert speed_window_frames(30.0) == 8 and speed_window_frames(10.0) == 2
    assert speed_window_frames(100.0) == 25 and speed_window_frames(None) == 8
    f = np.arange(1, 41)
    x = np.minimum(f * 10.0, 250.0)  # crosses x 200 at frame 20, stops at frame 25
    w = np.column_stack([x, np.zeros(40)])
    line = CountLine("v", (200.0, -10.0), (200.0, 10.0))
    (c10,) = track_crossings(f, w, np.ones(40, bool), line, band=1.0,
                             speed_window=speed_window_frames(10.0))
    assert c10.velocity[0] == pytest.approx(10.0)  # frames 18..22: before the stop
    (c8,) = track_crossings(f, w, np.ones(40, bool), line, band=1.0, speed_window=8)
    assert c8.velocity[0] < 8.5  # 8 frames at 10 fps (0.8 s) reach into the stop


def test_geojson_names_multilinestrings_and_other_features(tmp_path, capsys):
    run = make_run(tmp_path, with_map=True, n_frames=60)
    gm = GeoMap(VEGAS)
    ll = gm.pixel_to_lonlat(np.array([[462.0, 500.0], [462.0, 700.0]])).tolist()
    pt = {"type": "Point", "coordinates": ll[0]}
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": None}, "id": "gate",
         "geometry": {"type": "MultiLineString", "coordinates": [ll]}},
        {"type": "Feature", "properties": {"name": " "}, "geometry": pt}]}
    (tmp_path / "l.geojson").write_text(json.dumps(doc))
    code, out, err = run_cli(capsys, "count", run, "--lines", tmp_path / "l.geojson", "--json")
    assert code == 0, err
    assert json.loads(out)["lines"] == {"gate": {"+": 0, "-": 3}}
    assert "1 Point feature not count lines, ignored" in err
    doc["features"][0]["geometry"]["coordinates"].append(ll)
    (tmp_path / "l.geojson").write_text(json.dumps(doc))
    code, out, err = run_cli(capsys, "count", run, "--lines", tmp_path / "l.geojson")
    assert code == 2 and "'gate' is a MultiLineString of 2 parts" in err


def test_counts_carry_speeds_travel_times_and_clock_times(tmp_path, capsys):
    # make_run's targets drive east at 3.7 map px a frame (10 frames/s); frame 1's x = 160 and
    # x = 200 are map x 462 and 502: 40 / 3.7 = 10.8 frames = 1.081 s from one line to the other
    run = make_run(tmp_path, with_map=True, n_frames=60)
    code, _, err = run_cli(capsys, "count", run, "--line", "a:160,0,160,200",
                           "--line", "b:200,0,200,200", "--start-time", "2024-05-01T12:30:00+02:00")
    assert code == 0, err
    with open(run / "crossings.csv", newline="") as fh:
        cross = list(csv.DictReader(fh))
    first = min(cross, key=lambda r: float(r["frame"]))
    assert first["time_utc"] == "2024-05-01T10:30:00.495Z"  # frame 5.946: 0.4946 s
    with open(run / "movements.csv", newline="") as fh:
        moves = list(csv.DictReader(fh))
    assert [float(m["travel_time_s"]) for m in moves] == pytest.approx([1.081] * 3, abs=0.002)
    with open(run / "counts.csv", newline="") as fh:
        rows = {(r["line"], r["direction"]): r for r in csv.DictReader(fh)}
    want = 3.7 * 10 * _east_metres_per_px(GeoMap(VEGAS), at=(462.0, 600.0))
    assert float(rows[("a", "-")]["mean_speed_mps"]) == pytest.approx(want, rel=0.01)
    assert rows[("a", "+")]["mean_speed_mps"] == ""  # no crossing, no speed
    assert rows[("a", "-")]["start_utc"] == "2024-05-01T10:30:00.000Z"
    assert rows[("a", "-")]["end_utc"] == "2024-05-01T10:30:06.000Z"
    code, _, err = run_cli(capsys, "count", run, "--line", "a:160,0,160,200",
                           "--start-time", "12:30")
    assert code == 2 and "--start-time" in err

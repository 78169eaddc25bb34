"""Pictures, GIS outputs and the report, made from output folders written to the file contract."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from aerotrack.geo import GeoMap
from aerotrack.io.geojson import tracks_feature_collection, write_tracks_geojson, write_tracks_gpkg
from aerotrack.io.mot import write_mot
from aerotrack.viz import OverlayPainter, OverlayStyle, RunResults, id_bgr, id_rgb, track_stats
from aerotrack.viz.mapplot import figure_png, plot_map, plot_registration, plot_space_time

VEGAS = Path(__file__).resolve().parents[1] / "src/aerotrack/synth/data/vegas_tile.tif"


def _east_metres_per_px(gm: GeoMap, at=(500.0, 600.0)) -> float:
    """Ground length of one map pixel eastwards (the tile's pixels are not square in metres)."""
    from pyproj import Geod

    ll = gm.pixel_to_lonlat(np.array([at, (at[0] + 100.0, at[1])]))
    return Geod(ellps="WGS84").inv(ll[0, 0], ll[0, 1], ll[1, 0], ll[1, 1])[2] / 100.0
FPS = 10.0
W, H = 320, 240


def _H(frame: int) -> np.ndarray:
    """Frame pixels -> map pixels: the camera drifts 2 map px per frame to the east."""
    return np.array([[1.0, 0, 300.0 + 2.0 * frame], [0, 1.0, 500.0], [0, 0, 1]])


def grey_frames(folder: Path, n: int = 12, level=lambda f: 100, size=(W, H)) -> Path:
    """``n`` flat PNG frames ``000001.png``... of grey ``level(frame)``, ``size`` (w, h)."""
    folder.mkdir()
    for f in range(1, n + 1):
        cv2.imwrite(str(folder / f"{f:06d}.png"), np.full((size[1], size[0], 3), level(f), np.uint8))
    return folder


def make_run(tmp: Path, with_map: bool = True, n_frames: int = 60) -> Path:
    """An output folder: 3 targets driving east at 37 map px/s (10 m/s on 0.27 m pixels); target 2
    is out of view (predicted) in frames 20..34 and re-acquired at 35."""
    out = tmp / ("run_map" if with_map else "run_nomap")
    out.mkdir()
    gm = GeoMap(VEGAS) if with_map else None
    tracks, pred, reg = [], [], []
    for f in range(1, n_frames + 1):
        Hf = _H(f)
        reg.append([f, *Hf.ravel(), "ok" if f % 17 else "carried", 200 - f, 0.8, 0.5 + 0.01 * f])
        for tid, (x0, y0) in enumerate([(420.0, 560.0), (440.0, 600.0), (400.0, 640.0)], start=1):
            world = np.array([x0 + 3.7 * f, y0])
            fx, fy = world[0] - Hf[0, 2], world[1] - Hf[1, 2]  # Hf is a translation
            xy = gm.pixel_to_crs(world[None])[0] if gm is not None else (-1, -1)
            row = [f, tid, fx - 8, fy - 4, 16, 8, 0.9, xy[0], xy[1], -1]
            (pred if tid == 2 and 20 <= f < 35 else tracks).append(row)
    write_mot(out / "tracks.csv", tracks)
    write_mot(out / "predicted.csv", pred)
    with open(out / "registration.csv", "w") as fh:
        fh.write("frame,h00,h01,h02,h10,h11,h12,h20,h21,h22,status,inliers,inlier_ratio,error\n")
        fh.writelines(",".join(str(v) for v in r) + "\n" for r in reg)
    summary = {"fps": FPS, "frames": n_frames, "map": str(VEGAS) if with_map else None,
               "timings": {"registration": 1.5, "detection": 2.0}, "frame_size": [W, H]}
    (out / "summary.json").write_text(json.dumps(summary))
    return out


def test_colours_stable_and_distinct():
    assert id_bgr(7) == id_bgr(7)
    hues = [cv2.cvtColor(np.uint8([[id_bgr(i)]]), cv2.COLOR_BGR2HSV)[0, 0, 0] for i in range(1, 11)]
    # neighbouring IDs get clearly different hues (OpenCV hue is 0..179)
    d = [min(abs(int(a) - int(b)), 180 - abs(int(a) - int(b))) for a, b in itertools.pairwise(hues)]
    assert min(d) > 15
    assert all(0 <= c <= 1 for c in id_rgb(12345))


def test_ids_a_few_apart_do_not_share_a_colour():
    """IDs 21 apart (9 and 30 on one road in one Santiago frame) often looked alike: a third of
    such pairs within delta-E 10. No distance up to 40 has more than 6 % of its pairs that close."""
    ids = np.arange(1, 301)
    rgb = np.array([id_rgb(i) for i in ids], np.float32)[None]
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)[0]
    for d in range(1, 41):
        close = np.linalg.norm(lab[d:] - lab[:-d], axis=1)[:240] < 10
        assert close.mean() <= 0.06, (d, close.mean())
    # and readable on the plots' white background: at most a tenth under 1.5:1 contrast
    lin = np.where(rgb[0] <= 0.03928, rgb[0] / 12.92, ((rgb[0] + 0.055) / 1.055) ** 2.4)
    luminance = lin @ np.array([0.2126, 0.7152, 0.0722])
    assert ((1.05 / (luminance + 0.05)) < 1.5).mean() <= 0.10


def test_results_reader_world_and_reacquisition(tmp_path):
    run = make_run(tmp_path)
    res = RunResults.load(run)
    assert res.fps == FPS and res.map_path == VEGAS and res.has_map_xy
    gm = GeoMap(VEGAS)
    views = {tv.id: tv for tv in res.track_views(gm)}
    tv = views[2]
    assert len(tv.frames) == 60 and (~tv.observed).sum() == 15
    assert list(tv.frames[tv.reacquisitions()]) == [35]
    # world from map CRS and world from registration agree (to the 7 decimals of degrees written)
    no_geo = {t.id: t for t in res.track_views(None)}[2]
    np.testing.assert_allclose(tv.world, no_geo.world, atol=0.05)
    np.testing.assert_allclose(no_geo.world[0], [440.0 + 3.7, 600.0], atol=1e-6)


def test_track_stats_speed_and_gaps(tmp_path):
    res = RunResults.load(make_run(tmp_path))
    stats = {s.id: s for s in track_stats(res, GeoMap(VEGAS))}
    true_kmh = 3.7 * FPS * _east_metres_per_px(GeoMap(VEGAS)) * 3.6
    for s in stats.values():
        assert s.unit == "m"
        assert s.mean_speed_kmh == pytest.approx(true_kmh, rel=0.01)
    assert stats[2].reacquisitions == 1 and stats[1].reacquisitions == 0
    assert stats[2].unobserved_s == pytest.approx(15 / FPS)
    assert stats[2].predicted_s == pytest.approx(15 / FPS)
    nomap = {s.id: s for s in track_stats(RunResults.load(make_run(tmp_path, with_map=False)))}
    assert nomap[1].unit == "px" and math.isnan(nomap[1].mean_speed_kmh)


@pytest.mark.parametrize("height", [480, 2160])
def test_overlay_draws_boxes_labels_and_predictions(tmp_path, height):
    run = make_run(tmp_path)
    res = RunResults.load(run)
    painter = OverlayPainter(res, OverlayStyle(trail_s=1.0))
    img = np.full((H, W, 3), 90, np.uint8)
    out = painter.draw(img, 25)  # target 2 predicted in frame 25
    assert out.shape == img.shape and not np.array_equal(out, img)
    b = res.tracks[(res.tracks[:, 0] == 25) & (res.tracks[:, 1] == 1)][0, 2:6]
    x, y = int(b[0]), int(b[1] + b[3] / 2)
    patch = out[y - 1:y + 2, x - 1:x + 2].astype(int)
    assert np.abs(patch - np.array(id_bgr(1))).sum(axis=2).min() < 12  # its box edge, in its colour
    # predicted target: dashed box, so some pixels on its left edge keep the background
    p = res.predicted[(res.predicted[:, 0] == 25) & (res.predicted[:, 1] == 2)][0, 2:6]
    col = out[int(p[1]):int(p[1] + p[3]), int(round(p[0]))]
    assert (col == 90).all(axis=1).any()
    # text scales with the frame: labels at 1.7 % of the height
    big = np.full((height, height * 4 // 3, 3), 90, np.uint8)
    painter.draw(big, 25)  # no error at any size
    assert OverlayStyle().text_height >= 0.015


def test_overlay_video_plays(tmp_path):
    from aerotrack.viz.overlay import render_overlay

    run = make_run(tmp_path, n_frames=20)
    frames = tmp_path / "frames"
    frames.mkdir()
    for f in range(1, 21):
        cv2.imwrite(str(frames / f"{f:06d}.png"), np.full((H, W, 3), 60 + f, np.uint8))
    for ext in ("webm", "mp4"):
        out = render_overlay(frames, run, tmp_path / f"o.{ext}")
        cap = cv2.VideoCapture(str(out))
        n = 0
        while cap.read()[0]:
            n += 1
        cap.release()
        assert n == 20
    from aerotrack.viz.video import ffmpeg_exe

    probe = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(tmp_path / "o.webm")],
                           capture_output=True, text=True, check=False)  # no output file: exit 1
    assert "vp9" in probe.stderr
    probe = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(tmp_path / "o.mp4")],
                           capture_output=True, text=True, check=False)
    assert "h264" in probe.stderr


def test_map_space_time_and_registration_figures(tmp_path):
    run = make_run(tmp_path)
    res = RunResults.load(run)
    gm = GeoMap(VEGAS)
    pngs = [figure_png(fig) for fig in (plot_map(res, gm), plot_space_time(res, gm), plot_registration(res))]
    for png in pngs:
        im = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert im.shape[0] > 300 and im.std() > 10
    nomap = RunResults.load(make_run(tmp_path, with_map=False))
    assert figure_png(plot_map(nomap, background=np.zeros((H, W, 3), np.uint8)))
    # the map figure shows the tracks in their colours
    im = cv2.imdecode(np.frombuffer(pngs[0], np.uint8), cv2.IMREAD_COLOR)
    for tid in (1, 2, 3):
        c = np.array(id_bgr(tid), int)
        assert (np.abs(im.astype(int) - c).sum(axis=2) < 30).sum() > 50


def test_geojson_known_answer_and_pyogrio(tmp_path):
    run = make_run(tmp_path)
    res = RunResults.load(run)
    gm = GeoMap(VEGAS)
    path = write_tracks_geojson(tmp_path / "tracks.geojson", res.tracks, res.predicted, gm, FPS)
    fc = json.loads(path.read_text())
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == 3
    f2 = next(f for f in fc["features"] if f["properties"]["id"] == 2)
    p = f2["properties"]
    assert f2["geometry"]["type"] == "LineString" and len(f2["geometry"]["coordinates"]) == 60
    assert p["frames"] == list(range(1, 61)) and p["times_s"][1] == pytest.approx(0.1)
    assert p["observed"].count(0) == 15 and p["observed"][19] == 0
    lon, lat = f2["geometry"]["coordinates"][0]
    assert -115.3 < lon < -115.1 and 36.0 < lat < 36.2  # RFC 7946: lon, lat order
    speed = 3.7 * FPS * _east_metres_per_px(gm)
    assert np.median(p["speeds_mps"]) == pytest.approx(speed, rel=0.02)
    assert p["length_m"] == pytest.approx(speed * 59 / FPS, rel=0.02)
    # the kinds of observations.csv: the 15 predicted frames are not in-view length
    assert p["kind"].count("predicted") == p["n_predicted"] == 15
    assert p["n_observed"] == 45 and p["n_bridged"] == p["n_stationary"] == 0
    assert p["in_view_length_m"] == pytest.approx(speed * (59 - 16) / FPS, rel=0.02)
    kinds = {(f, 2): "bridged" for f in range(10, 13)}
    fc2 = tracks_feature_collection(res.tracks, res.predicted, gm, FPS, kinds=kinds)
    p2 = next(f for f in fc2["features"] if f["id"] == 2)["properties"]
    assert (p2["n_observed"], p2["n_bridged"], p2["kind"][9]) == (42, 3, "bridged")
    pyogrio = pytest.importorskip("pyogrio")
    info = pyogrio.read_info(path)
    assert info["features"] == 3 and "4326" in info["crs"]
    assert info["geometry_type"] == "LineString"
    # the features themselves read (a JSON list of booleans made pyogrio, and geopandas, fail)
    meta, _, geom, _ = pyogrio.raw.read(path)
    assert len(geom) == 3 and "observed" in list(meta["fields"])
    gpkg = write_tracks_gpkg(tmp_path / "tracks.gpkg", res.tracks, res.predicted, gm, FPS)
    assert pyogrio.read_info(gpkg, layer="tracks")["features"] == 3
    pts = pyogrio.read_info(gpkg, layer="track_points")
    assert pts["features"] == 180 and "4326" in pts["crs"]


def test_geojson_single_vertex_and_no_map(tmp_path):
    gm = GeoMap(VEGAS)
    xy = gm.pixel_to_crs(np.array([[100.0, 100.0]]))[0]
    fc = tracks_feature_collection(np.array([[5, 9, 0, 0, 4, 4, 1, xy[0], xy[1], -1]]), None, gm, 30)
    coords = fc["features"][0]["geometry"]["coordinates"]
    assert len(coords) == 2 and coords[0] == coords[1]
    from aerotrack.errors import GeoreferenceError

    with pytest.raises(GeoreferenceError):
        tracks_feature_collection(np.zeros((0, 10)), None, None, 30)


def test_render_and_report_commands(tmp_path, capsys):
    from aerotrack.cli.main import main

    run = make_run(tmp_path, n_frames=12)
    frames = grey_frames(tmp_path / "frames")
    main(["-q", "render", str(frames), str(run), "--out", str(tmp_path / "o.mp4"), "--trail-s", "0.5"])
    assert (tmp_path / "o.mp4").stat().st_size > 0
    for name in ("map.png", "spacetime.png", "registration.png"):
        assert (run / name).stat().st_size > 1000
    main(["-q", "report", str(run), "--input", str(frames)])
    text = (run / "report.html").read_text()
    assert "data:video/webm;base64," in text and text.count("<tr><td data-v=") >= 3
    with pytest.raises(SystemExit) as exc:
        main(["report", str(tmp_path / "missing")])
    assert exc.value.code == 2
    assert "no such output folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["render", str(frames), str(run), "--out", str(tmp_path / "o.avi")])
    assert exc.value.code == 2


@pytest.mark.parametrize("size", [(640, 480), (3840, 2160)])
def test_label_text_is_at_least_1_5_percent_of_frame_height(size):
    w, h = size
    box = [w * 0.4, h * 0.5, w * 0.02, h * 0.02]
    rows = np.array([[1, 7, *box, 1.0, -1, -1, -1]])
    res = RunResults(Path("."), rows, np.zeros((0, 10)), None, None, {}, {}, 30.0, None)
    out = OverlayPainter(res, OverlayStyle(hud=False)).draw(np.zeros((h, w, 3), np.uint8), 1)
    mask = np.all(out == np.array(id_bgr(7), np.uint8), axis=2)
    rows_filled = np.flatnonzero(mask.sum(axis=1) > 3 * max(1, round(0.0022 * h)))
    label_rows = rows_filled[rows_filled < box[1]]  # the filled label sits above the box
    assert len(label_rows) >= 0.015 * h
    # white or black text was drawn inside the label
    assert (out[label_rows.min():label_rows.max() + 1] != out[label_rows.min()][0]).any()


def test_report_without_input_or_map(tmp_path):
    """A detections-only run (no input video, no map): pictures and table, no player."""
    from aerotrack.viz.report import build_report

    run = make_run(tmp_path, with_map=False, n_frames=20)
    text = build_report(run).read_text()
    assert "<video" not in text and 'id="scrubdata"' not in text
    assert "Tracks on frame 1" in text and text.count('src="data:image/png;base64,') == 3
    assert 'id="tracks"' in text and text.count("<tr><td data-v=") == 3
    assert 'id="hints"' not in text


def test_report_shows_the_runs_warnings(tmp_path):
    """``summary.json`` hints (e.g. vehicles too small for a run without a scale) are shown,
    escaped, under Warnings."""
    from aerotrack.viz.report import build_report

    run = make_run(tmp_path, with_map=False, n_frames=20)
    summary = json.loads((run / "summary.json").read_text())
    summary["hints"] = ["the tracked vehicles are small <9 px>: give --gsd"]
    (run / "summary.json").write_text(json.dumps(summary))
    text = build_report(run).read_text()
    assert '<section id="hints"><h2>Warnings</h2>' in text
    assert "small &lt;9 px&gt;: give --gsd" in text


def test_render_draws_the_frames_the_run_tracked(tmp_path):
    """A ``--frames 4:9`` run is drawn on frames 4..9 by default, not on the whole input."""
    from aerotrack.cli.main import main

    run = make_run(tmp_path, n_frames=12)
    summary = json.loads((run / "summary.json").read_text())
    summary.update(first_frame=4, last_frame=9)
    (run / "summary.json").write_text(json.dumps(summary))
    frames = grey_frames(tmp_path / "frames")
    main(["-q", "render", str(frames), str(run), "--out", str(tmp_path / "o.mp4"), "--no-pictures"])
    cap = cv2.VideoCapture(str(tmp_path / "o.mp4"))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 6
    main(["-q", "render", str(frames), str(run), "--out", str(tmp_path / "all.mp4"),
          "--no-pictures", "--start", "1", "--stop", "12"])
    cap = cv2.VideoCapture(str(tmp_path / "all.mp4"))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 12


def _frames_count(path: Path) -> tuple[int, int]:
    cap = cv2.VideoCapture(str(path))
    n, width = 0, int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    while cap.read()[0]:
        n += 1
    return n, width


def test_report_covers_the_frames_the_run_tracked(tmp_path, capsys):
    """A --frames 4:9 run: the report said "9 frames, 0.9 s", its scrubber and overlay started at
    frame 1 (frames the run never tracked), and --gt scored frames outside the run."""
    import re

    from aerotrack.cli.main import main

    run = make_run(tmp_path, with_map=False, n_frames=12)
    summary = json.loads((run / "summary.json").read_text())
    summary.update(first_frame=4, last_frame=9, frames=6)
    (run / "summary.json").write_text(json.dumps(summary))
    rows = np.loadtxt(run / "tracks.csv", delimiter=",")
    write_mot(run / "tracks.csv", rows[(rows[:, 0] >= 4) & (rows[:, 0] <= 9)])
    write_mot(tmp_path / "gt.txt", rows)  # ground truth of all 12 frames
    frames = grey_frames(tmp_path / "frames", level=lambda f: 20 * f)
    main(["-q", "report", str(run), "--input", str(frames), "--gt", str(tmp_path / "gt.txt")])
    text = (run / "report.html").read_text()
    cards = {k: v for v, k in re.findall(r'<div class="card"><b>([^<]*)</b><span>([^<]*)<',
                                                text)}
    assert cards["frames"] == "6" and cards["duration"] == "0.6 s", cards
    scrub = json.loads(re.search(r'id="scrubdata"[^>]*>(.*?)</script>', text, re.DOTALL).group(1))
    assert [f for f, _ in scrub] == [4, 5, 6, 7, 8, 9]
    assert _frames_count(run / "overlay.webm")[0] == 6
    assert "frames 4-9" in text  # the evaluation is over the run's frames: nothing missed
    assert "frame 4's pixels" in text and "frame 1's" not in text  # the page names frame A too
    with pytest.raises(SystemExit) as exc:  # --start past the run, no --stop: the run's frames
        main(["render", str(frames), str(run), "--out", str(tmp_path / "r.mp4"), "--start", "11",
              "--no-pictures"])
    assert exc.value.code == 2 and "covers frames 4-9" in capsys.readouterr().err
    # the track map without a map is drawn over the run's first frame (grey 80), not frame 1
    from aerotrack.viz import RunResults

    assert RunResults.load(run).reference_image(frames).mean() == pytest.approx(80, abs=1)


def test_report_refuses_another_input_and_respects_video_width(tmp_path, capsys):
    from aerotrack.cli.main import main

    run = make_run(tmp_path, n_frames=12)
    frames = grey_frames(tmp_path / "frames")
    other = grey_frames(tmp_path / "other", size=(W // 2, H // 2))
    with pytest.raises(SystemExit) as exc:
        main(["report", str(run), "--input", str(other)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "160x120" in err and "320x240" in err, err
    assert not (run / "report.html").exists()
    main(["-q", "render", str(frames), str(run), "--no-pictures"])  # a full-width overlay.webm
    before = (run / "overlay.webm").read_bytes()
    main(["-q", "report", str(run), "--input", str(frames), "--video-width", "160"])
    import base64
    import re

    text = (run / "report.html").read_text()
    data = re.search(r'src="data:video/webm;base64,([^"]+)"', text).group(1)
    (tmp_path / "embedded.webm").write_bytes(base64.b64decode(data))
    assert _frames_count(tmp_path / "embedded.webm")[1] == 160  # not the 320-wide overlay
    assert (run / "overlay.webm").read_bytes() == before  # the user's overlay is kept


def test_render_refuses_a_bad_map_before_rendering(tmp_path, capsys):
    from aerotrack.cli.main import main

    run = make_run(tmp_path, n_frames=12)
    frames = grey_frames(tmp_path / "frames")
    (tmp_path / "afile").write_text("not a raster")
    with pytest.raises(SystemExit) as exc:
        main(["render", str(frames), str(run), "--out", str(tmp_path / "x.mp4"), "--map",
              str(tmp_path / "afile")])
    assert exc.value.code == 2 and "afile" in capsys.readouterr().err
    assert not (tmp_path / "x.mp4").exists()


def test_report_takes_a_zero_based_ground_truth(tmp_path, capsys):
    """Santiago's ground truth numbers frames from 0: report --gt refused it and had no option
    for it (the message pointed at eval's)."""
    from aerotrack.cli.main import main

    run = make_run(tmp_path, n_frames=12)
    rows = np.loadtxt(run / "tracks.csv", delimiter=",")
    zero = rows.copy()
    zero[:, 0] -= 1
    (tmp_path / "gt0.txt").write_text("".join(",".join(f"{v:g}" for v in r) + "\n" for r in zero))
    with pytest.raises(SystemExit) as exc:
        main(["report", str(run), "--gt", str(tmp_path / "gt0.txt"), "--no-video"])
    assert exc.value.code == 2 and "--gt-zero-based" in capsys.readouterr().err
    main(["-q", "report", str(run), "--gt", str(tmp_path / "gt0.txt"), "--gt-zero-based",
          "--fix-gt", "--no-video"])
    text = (run / "report.html").read_text()
    assert "(corrected)" in text and "1.000" in text


def test_report_renders_the_whole_run_over_a_partial_overlay(tmp_path, capsys):
    """An overlay.webm rendered over frames 1-10 (`render --start/--stop`) was embedded in the
    report of a 40-frame run as if it were the run's."""
    from conftest import run_cli

    run = make_run(tmp_path, n_frames=40)
    frames = grey_frames(tmp_path / "frames", n=40)
    code, _, err = run_cli(capsys, "render", frames, run, "--start", "1", "--stop", "10",
                           "--no-pictures")
    assert code == 0, err
    code, _, err = run_cli(capsys, "report", run, "--input", frames)
    assert code == 0 and "rendering" in err and "frames 1-40" in err, err
    code, _, err = run_cli(capsys, "report", run)  # no input: embedded, but named as partial
    assert code == 0 and "covers only part" in err, err


def test_an_uncertainty_circle_wider_than_the_frame_is_not_drawn(tmp_path, monkeypatch):
    """truck4, 9.5 s after the truck was last seen: a 737-px circle crossed the whole frame as
    a stray arc."""
    from aerotrack.viz import overlay

    res = RunResults.load(make_run(tmp_path))
    img = np.full((H, W, 3), 90, np.uint8)

    def drawn(uncertainty, max_circle):
        monkeypatch.setattr(overlay, "MAX_CIRCLE", max_circle)
        painter = OverlayPainter(res, OverlayStyle(trail_s=0.0, speed_uncertainty=uncertainty))
        return painter.draw(img.copy(), 25)  # target 2 predicted in frame 25

    assert not np.array_equal(drawn(0.3, 0.35), drawn(0.3, 0.0))  # a small circle is drawn
    assert np.array_equal(drawn(50.0, 0.35), drawn(50.0, 0.0))  # a huge one is not


def test_report_scores_as_eval_does(tmp_path):
    """A ground truth that ends before the run (Santiago's at 98 of 100 frames): the report
    counted the tracks of the unannotated frames as false positives, eval did not."""
    from aerotrack.evaluation import evaluate
    from aerotrack.io.mot import read_mot, write_mot
    from aerotrack.viz.report import _evaluation

    run = make_run(tmp_path, n_frames=60)
    tracks = read_mot(run / "tracks.csv")
    write_mot(tmp_path / "gt.txt", tracks[tracks[:, 0] <= 50])
    ev = _evaluation(RunResults.load(run), tmp_path / "gt.txt")
    metrics, note = ev.metrics, ev.note
    assert metrics == evaluate(read_mot(tmp_path / "gt.txt"), tracks)
    assert metrics["FP"] == 0 and "frames 1-50" in note


def test_an_interrupted_report_leaves_no_pictures(tmp_path, monkeypatch):
    from aerotrack.viz import report

    run = make_run(tmp_path, with_map=False, n_frames=20)

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "_evaluation", ctrl_c)  # after the pictures, before the page
    with pytest.raises(KeyboardInterrupt):
        report.build_report(run)
    assert not [p.name for p in run.glob("*.png")] and not (run / "report.html").exists()
    monkeypatch.undo()
    report.build_report(run)
    assert sorted(p.name for p in run.glob("*.png")) == ["map.png", "registration.png",
                                                          "spacetime.png"]


def test_registration_picture_names_its_unit(tmp_path):
    res = RunResults.load(make_run(tmp_path, with_map=False))
    assert plot_registration(res).axes[-1].get_ylabel() == "motion (frame-1 px / frame)"
    res.summary["metres_per_unit"] = 0.25  # the camera drifts 2 px a frame: 0.5 m
    fig = plot_registration(res)
    assert fig.axes[-1].get_ylabel() == "motion (m / frame)"
    assert np.nanmedian(fig.axes[-1].lines[0].get_ydata()) == pytest.approx(0.5)


def test_space_time_names_each_track(tmp_path):
    fig = plot_space_time(RunResults.load(make_run(tmp_path)), GeoMap(VEGAS))
    assert sorted(t.get_text().strip() for t in fig.axes[0].texts) == ["1", "2", "3"]


def test_report_names_a_stream_input_and_an_interrupted_run(tmp_path):
    from aerotrack.viz.report import build_report

    run = make_run(tmp_path, with_map=False, n_frames=20)
    summary = json.loads((run / "summary.json").read_text())
    summary.update(input="rtsp://10.0.0.2:8554/live", interrupted_at_frame=20)
    (run / "summary.json").write_text(json.dumps(summary))
    text = build_report(run).read_text()
    assert "input rtsp://10.0.0.2:8554/live" in text and "interrupted: frames 1-20 only" in text


def test_an_mp4_overlay_beyond_common_decoders_is_warned(caplog, tmp_path):
    """A 4000x3000 overlay was written as H.264 level 6 with no word (most players show nothing)."""
    import logging

    from aerotrack.cli.render_cmd import warn_large_h264

    with caplog.at_level(logging.WARNING, logger="aerotrack"):
        warn_large_h264(tmp_path / "o.mp4", (4000, 3000), None)
        assert "4000x3000 H.264" in caplog.text
        caplog.clear()
        warn_large_h264(tmp_path / "o.mp4", (4000, 3000), 1920)
        warn_large_h264(tmp_path / "o.webm", (4000, 3000), None)
        warn_large_h264(tmp_path / "o.mp4", (1920, 1080), None)
        assert caplog.text == ""


def test_track_map_without_a_map_shows_tracks_beyond_frame_one():
    """A moving camera's tracks run far beyond its first frame: the track map's view was clamped
    to frame 1 plus 10 %, and a probe found 6 of truck4's 22 tracks missing from map.png."""
    from aerotrack.viz.mapplot import plot_map

    rows = np.array([[f, tid, x0 + 5 * f, 40, 10, 6, 1.0, -1, -1, -1]
                     for tid, x0 in ((1, 20), (2, 900)) for f in range(1, 11)], float)
    res = RunResults(Path("."), rows, np.zeros((0, 10)), None, None, {}, {}, 30.0, None)
    ax = plot_map(res, background=np.zeros((100, 200, 3), np.uint8)).axes[0]
    lo, hi = sorted(ax.get_xlim())
    assert lo <= 25 and hi >= 955, (lo, hi)
    assert "outside" not in ax.get_title()


def test_a_predicted_targets_label_reads_in_a_dark_colour():
    """A predicted target's label is text in its colour on a darkened patch: navy and blue IDs
    (14 here) vanished; the text is lifted towards white, keeping its hue."""
    from aerotrack.viz.overlay import _label

    colour = id_bgr(14)
    assert 0.299 * colour[2] + 0.587 * colour[1] + 0.114 * colour[0] < 60
    img = np.full((200, 400, 3), 40, np.uint8)
    assert _label(img, "14 +1.2s", 100, 100, 130, colour, 1.0, 2, hollow=True)
    luma = img[..., 2] * 0.299 + img[..., 1] * 0.587 + img[..., 0] * 0.114
    assert luma.max() >= 140
    text = img[luma >= 140]
    assert (text[:, 0] > text[:, 2]).all()  # still blue, not white


def test_labels_of_neighbouring_vehicles_do_not_hide_each_other():
    """Dense traffic put every label above its box's left edge, so neighbours' labels covered each
    other and the cars beside them (a probe, Santiago at 1080p): a label now takes the first
    corner that is free of labels and of other boxes. --no-labels draws none."""
    from aerotrack.viz.overlay import _label, _overlap

    img = np.zeros((300, 400, 3), np.uint8)
    boxes = [(100, 100, 140, 120), (112, 100, 152, 120), (100, 70, 140, 90)]
    placed, rects = [], []
    for i, (x0, y0, x1, y1) in enumerate(boxes):
        rects.append(_label(img, str(30 + i), x0, y0, y1, id_bgr(30 + i), 0.6, 1, placed=placed,
                            right=x1, avoid=boxes[:i] + boxes[i + 1:]))
    for i, a in enumerate(rects):
        area = (a[2] - a[0]) * (a[3] - a[1])
        assert all(_overlap(a, b) <= 0.25 * area for b in rects[i + 1:]), rects
    rows = np.array([[1, 7, 100, 100, 40, 20, 1.0, -1, -1, -1]])
    res = RunResults(Path("."), rows, np.zeros((0, 10)), None, None, {}, {}, 30.0, None)
    off = OverlayPainter(res, OverlayStyle(hud=False, labels=False)).draw(
        np.zeros((300, 400, 3), np.uint8), 1)
    on = OverlayPainter(res, OverlayStyle(hud=False)).draw(np.zeros((300, 400, 3), np.uint8), 1)
    assert (off[:99] == 0).all() and (on[:99] != 0).any()  # the label sits above the box


def test_render_names_an_input_that_is_not_the_one_tracked(tmp_path, caplog):
    """A probe rendered 49 of a run's 421 frames, and 60 unrelated frames of the same size, with
    no word: an input shorter than the run, or whose files are not the size the run recorded, is
    named in a warning (the size check stays an error)."""
    from aerotrack.io.frames import open_source
    from aerotrack.io.state import input_fingerprints

    tracked = grey_frames(tmp_path / "tracked", n=12)
    rows = np.array([[f, 1, 10, 10, 8, 6, 1.0, -1, -1, -1] for f in range(1, 13)], float)
    summary = {"input": str(tracked), "frame_size": [W, H], "last_frame": 12,
               "options": {"input_files": input_fingerprints([tracked])}}
    res = RunResults(tmp_path, rows, np.zeros((0, 10)), None, None, summary, {}, 30.0, None)
    other = tmp_path / "other"
    other.mkdir()
    rng = np.random.default_rng(0)
    for f in range(1, 13):
        cv2.imwrite(str(other / f"{f:06d}.png"), rng.integers(0, 255, (H, W, 3), np.uint8))
    short = grey_frames(tmp_path / "short", n=5)
    for folder, expect in ((tracked, None), (other, "not the input the run"),
                           (short, "holds 5 frames")):
        caplog.clear()
        res.check_input(open_source(folder, 30.0), folder)
        warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
        assert (expect is None and not warned) or (expect and expect in " ".join(warned)), warned
    # a file browser's clutter or a note beside the frames is not another input (a reviewer)
    (tracked / ".DS_Store").write_bytes(b"\0" * 10)
    (tracked / "README.txt").write_text("flight 3")
    caplog.clear()
    res.check_input(open_source(tracked, 30.0), tracked)
    assert not [r for r in caplog.records if r.levelname == "WARNING"], caplog.text


def test_registration_picture_of_a_stabilised_run_says_none_was_done(tmp_path):
    """A --stabilised run's chart showed flat zero lines with no word (taken for a failure)."""
    res = RunResults.load(make_run(tmp_path, with_map=False))
    assert "no registration" not in plot_registration(res).axes[0].get_title()
    res.summary["stabilised"] = True
    assert "no registration" in plot_registration(res).axes[0].get_title()


def test_report_names_a_short_input_once(tmp_path, capsys):
    """`report --input` checked the input in the command and again in the report: every warning
    came twice."""
    from conftest import run_cli

    run = make_run(tmp_path, n_frames=60)
    frames = grey_frames(tmp_path / "frames", n=12)
    code, _, err = run_cli(capsys, "report", run, "--input", frames, "--no-video")
    assert code == 0, err
    assert err.count("holds 12 frames") == 1, err

"""The corpus of bad inputs (issue 9): every entry point answers bad input with one line and exit
code 2, or with a documented degraded result; never a traceback, never a half-written output.

Inputs are generated here (small files in tmp_path), not stored.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from conftest import run_cli
from rasterio.transform import from_origin

RESULT_FILES = ("tracks.csv", "predicted.csv", "detections.csv", "summary.json")



def expect_error(capsys, fragments, *argv, out_dir: Path | None = None):
    """Exit 2 with exactly one error line naming the problem; with ``out_dir``, nothing written
    there (a folder the run created is gone again, so the same command works once fixed)."""
    existed = out_dir is not None and out_dir.exists()
    code, _, err = run_cli(capsys, *argv)
    assert code == 2, f"exit {code}: {err}"
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip() and "WARNING" not in ln and "INFO" not in ln]
    assert len(lines) == 1, err
    assert lines[0].startswith("aerotrack: error:"), err
    for f in fragments:
        assert f in err, f"{f!r} not in {err!r}"
    if out_dir is not None:
        for name in RESULT_FILES:
            assert not (out_dir / name).exists(), f"half-written {name}"
        if not existed:
            assert not out_dir.exists(), f"left behind: {sorted(out_dir.rglob('*'))}"
    return err


# -- inputs made here ---------------------------------------------------------------------------
def write_frames(folder: Path, frames: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(frames, start=1):
        cv2.imwrite(str(folder / f"{i:04d}.png"), img)
    return folder


def textured(h=120, w=160, seed=0, shift=(0, 0)):
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 255, (h + 40, w + 40, 3), dtype=np.uint8), (0, 0), 2)
    dy, dx = shift
    return np.ascontiguousarray(base[20 + dy:20 + dy + h, 20 + dx:20 + dx + w])


def write_video(path: Path, frames: list[np.ndarray], fps=10) -> Path:
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    for f in frames:
        vw.write(f)
    vw.release()
    return path


def write_map(path: Path, georef=True) -> Path:
    kw = dict(crs="EPSG:32611", transform=from_origin(660000, 4000000, 0.3, 0.3)) if georef else {}
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", driver="GTiff", width=400, height=300, count=1,
                           dtype="uint16", **kw) as ds:
            ds.write(np.random.default_rng(1).integers(0, 2047, (1, 300, 400), dtype=np.uint16))
    return path


@pytest.fixture
def dets(tmp_path):
    p = tmp_path / "dets.txt"
    p.write_text("1,-1,10,10,8,4,0.9\n2,-1,12,10,8,4,0.9\n")
    return p


@pytest.fixture
def video(tmp_path):
    return write_video(tmp_path / "clip.avi", [textured(shift=(0, i)) for i in range(6)])


# -- track ----------------------------------------------------------------------------------------
def test_a_truncated_map_is_one_line_error(tmp_path, capsys, video):
    """A GeoTIFF cut short (a broken download: its header intact, its pixels not) was opened and
    failed minutes later in a traceback where the map was first drawn on."""
    whole = write_map(tmp_path / "whole.tif")
    cut = tmp_path / "cut.tif"
    cut.write_bytes(whole.read_bytes()[: int(0.6 * whole.stat().st_size)])
    h = tmp_path / "h.txt"
    h.write_text("1 0 100\n0 1 100\n0 0 1\n")
    expect_error(capsys, ["--map", "cut.tif", "truncated"], "track", video, "--out",
                 tmp_path / "o", "--map", cut, "--map-init", h, out_dir=tmp_path / "o")


def test_track_missing_input(tmp_path, capsys):
    expect_error(capsys, ["missing.mp4"], "track", tmp_path / "missing.mp4", "--out", tmp_path / "o",
                 out_dir=tmp_path / "o")


def test_track_folder_without_images(tmp_path, capsys):
    d = tmp_path / "frames"
    d.mkdir()
    (d / "readme.txt").write_text("no images here")
    expect_error(capsys, ["no image files"], "track", d, "--out", tmp_path / "o")


def test_track_zero_length_video(tmp_path, capsys):
    p = tmp_path / "empty.mp4"
    p.write_bytes(b"")
    expect_error(capsys, ["empty.mp4", "empty"], "track", p, "--out", tmp_path / "o")


def test_track_corrupt_video(tmp_path, capsys):
    p = tmp_path / "corrupt.mp4"
    p.write_bytes(np.random.default_rng(0).integers(0, 255, 5000, dtype=np.uint8).tobytes())
    expect_error(capsys, ["corrupt.mp4"], "track", p, "--out", tmp_path / "o")


def test_track_truncated_video(tmp_path, capsys, video):
    data = video.read_bytes()
    p = tmp_path / "truncated.avi"
    p.write_bytes(data[:200])
    expect_error(capsys, ["truncated.avi"], "track", p, "--out", tmp_path / "o")


def test_a_run_of_blank_frames_says_so(tmp_path, capsys):
    """A 16-bit video read at 8 bits is a few grey levels: the run found nothing and said only
    "0 tracks"."""
    rng = np.random.default_rng(0)
    (tmp_path / "f").mkdir()
    for i in range(12):
        cv2.imwrite(str(tmp_path / "f" / f"{i:03d}.png"),
                    (30 + rng.integers(0, 2, (120, 160))).astype(np.uint8))
    code, _, err = run_cli(capsys, "track", tmp_path / "f", "--out", tmp_path / "o")
    assert code == 0 and re.search(r"1[12] of 12 frames are blank", err), err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["counts"]["tracks"] == 0


def test_detections_that_never_form_a_track_are_named(tmp_path, capsys):
    """Boxes jumping about at random: the run wrote 0 tracks and said nothing of the detections."""
    rng = np.random.default_rng(1)
    rows = [f"{f},-1,{x:.1f},{y:.1f},20,10,0.9,-1,-1,-1"
            for f in range(1, 61) for x, y in rng.uniform(0, 1000, (3, 2))]
    (tmp_path / "d.txt").write_text("\n".join(rows) + "\n")
    code, _, err = run_cli(capsys, "track", "--detections", tmp_path / "d.txt", "--out",
                           tmp_path / "o")
    assert code == 0 and "180 detections but no track" in err, err
    assert "180 detections but no track" in " ".join(
        json.loads((tmp_path / "o" / "summary.json").read_text())["hints"])


def test_track_single_image_as_input(tmp_path, capsys):
    p = tmp_path / "one.png"
    cv2.imwrite(str(p), textured())
    expect_error(capsys, ["one.png", "single image"], "track", p, "--out", tmp_path / "o")


def test_track_mixed_sizes_names_file(tmp_path, capsys):
    d = write_frames(tmp_path / "f", [textured(), textured(), textured(h=100)])
    expect_error(capsys, ["0003.png"], "track", d, "--out", tmp_path / "o", out_dir=tmp_path / "o")


@pytest.mark.parametrize("name,text,frag", [
    ("cols", "1,-1,10,10,8\n", "line 1"),
    ("toomany", "1,-1,10,10,8,4,1,1,1,1,1\n", "line 1"),
    ("nan", "1,-1,10,nan,8,4,1\n", "NaN"),
    ("neg", "1,-1,10,10,-8,4,1\n", "negative"),
    ("text", "1,-1,ten,10,8,4,1\n", "non-numeric"),
    # an empty cell (pandas writes NaN so) shifted the later columns: wrong boxes, exit 0
    ("emptyid", "1,,133.9,148.0,104.9,42.5,0.6,-1,-1,-1\n", "line 1: empty field (column 2, id)"),
    ("emptyconf", "1,-1,10,10,8,4,,-1\n", "empty field (column 7, conf)"),
    # a missing conf at the end of the row, as pandas writes NaN: it was read as conf 1.0
    ("emptylast", "1,-1,10,10,8,4,\n", "empty field (column 7, conf)"),
    ("semicolons", "1;-1;10;10;8;4;0.9\n", "separated by ';'?"),
    ("frame0", "0,-1,10,10,8,4,1\n", "frame"),
    ("binary", "\x00\x01\x02garbage\n", "line 1"),
])
def test_track_bad_detections(tmp_path, capsys, name, text, frag):
    p = tmp_path / f"{name}.txt"
    p.write_text(text)
    expect_error(capsys, ["--detections", frag], "track", "--detections", p, "--out",
                 tmp_path / "o", out_dir=tmp_path / "o")


def test_track_empty_detections_is_empty_result(tmp_path, capsys):
    """Documented degraded result: an empty detections file gives empty (but complete) outputs."""
    p = tmp_path / "empty.txt"
    p.write_text("")
    code, _, err = run_cli(capsys, "track", "--detections", p, "--out", tmp_path / "o")
    assert code == 0, err
    assert (tmp_path / "o" / "tracks.csv").read_text() == ""
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["counts"]["tracks"] == 0


def test_track_map_without_georeference(tmp_path, capsys, dets):
    m = write_map(tmp_path / "plain.tif", georef=False)
    h = tmp_path / "h.txt"
    h.write_text("1 0 0\n0 1 0\n0 0 1\n")
    expect_error(capsys, ["plain.tif", "georeference"], "track", "--detections", dets, "--map", m,
                 "--map-init", h, "--out", tmp_path / "o")


def test_track_map_not_a_raster(tmp_path, capsys, dets):
    m = tmp_path / "map.tif"
    m.write_text("not a raster")
    h = tmp_path / "h.txt"
    h.write_text("1 0 0\n0 1 0\n0 0 1\n")
    expect_error(capsys, ["map.tif"], "track", "--detections", dets, "--map", m, "--map-init", h,
                 "--out", tmp_path / "o")


@pytest.mark.parametrize("text,frag", [
    ("frame_x,frame_y,map_x,map_y\n0,0,1,1\n1,0,2,1\n0,1,1,2\n", "at least 4"),
    ("frame_x,frame_y,map_x,map_y\n0,0,0,0\n1,1,1,1\n2,2,2,2\n3,3,3,3\n", "collinear"),
    ("frame_x,frame_y,map_x,map_y\n0,0,0,0\n1,0,a,1\n0,1,1,2\n1,1,2,2\n", "line 3"),
    ("frame_x,frame_y,east,north\n0,0,0,0\n", "header"),
    ("1 0 0\n0 1 0\n0 0 0\n", "singular"),
])
def test_track_bad_map_init(tmp_path, capsys, video, text, frag):
    m = write_map(tmp_path / "m.tif")
    p = tmp_path / "init.csv"
    p.write_text(text)
    expect_error(capsys, ["--map-init", frag], "track", video, "--map", m, "--map-init", p,
                 "--out", tmp_path / "o")


def test_track_map_does_not_overlap_video(tmp_path, capsys, video):
    m = write_map(tmp_path / "m.tif")
    h = tmp_path / "h.txt"
    h.write_text("1 0 50000\n0 1 50000\n0 0 1\n")
    expect_error(capsys, ["does not land on the map"], "track", video, "--map", m, "--map-init", h,
                 "--out", tmp_path / "o")


def test_track_map_init_without_map(tmp_path, capsys, dets):
    h = tmp_path / "h.txt"
    h.write_text("1 0 0\n0 1 0\n0 0 1\n")
    expect_error(capsys, ["--map"], "track", "--detections", dets, "--map-init", h, "--out",
                 tmp_path / "o")


def test_track_unwritable_output(tmp_path, capsys, dets):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    expect_error(capsys, ["--out"], "track", "--detections", dets, "--out", blocker / "sub")


def test_track_output_is_a_file(tmp_path, capsys, dets):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    expect_error(capsys, ["not a folder"], "track", "--detections", dets, "--out", blocker)


def test_track_output_holds_results(tmp_path, capsys, dets):
    o = tmp_path / "o"
    o.mkdir()
    (o / "tracks.csv").write_text("1,1,1,1,1,1,1,-1,-1,-1\n")
    expect_error(capsys, ["--overwrite"], "track", "--detections", dets, "--out", o)
    assert (o / "tracks.csv").read_text().startswith("1,1")


def test_track_overwrite_and_resume_together(tmp_path, capsys, dets):
    expect_error(capsys, ["--overwrite", "--resume"], "track", "--detections", dets, "--out",
                 tmp_path / "o", "--overwrite", "--resume")


@pytest.mark.parametrize("fps", ["0", "-1", "nan", "inf"])
def test_track_bad_fps(tmp_path, capsys, dets, fps):
    expect_error(capsys, ["--fps"], "track", "--detections", dets, "--out", tmp_path / "o",
                 "--fps", fps)


def test_track_bad_config_file(tmp_path, capsys, dets):
    c = tmp_path / "c.toml"
    c.write_text("[association\nwindow_s = 1\n")
    expect_error(capsys, ["c.toml", "TOML"], "track", "--detections", dets, "--out", tmp_path / "o",
                 "--config", c)


def test_track_config_wrong_type(tmp_path, capsys, dets):
    c = tmp_path / "c.toml"
    c.write_text('[association]\nwindow_s = "long"\n')
    expect_error(capsys, ["association.window_s"], "track", "--detections", dets, "--out",
                 tmp_path / "o", "--config", c)


@pytest.mark.parametrize("rng", ["5:2", "a:b", "0:3", "7", "3:", "3:9"])
def test_track_bad_frame_range(tmp_path, capsys, dets, rng):
    expect_error(capsys, ["--frames"], "track", "--detections", dets, "--out", tmp_path / "o",
                 "--frames", rng)


def test_track_black_saturated_noise_frames_degrade(tmp_path, capsys):
    """Documented degraded result: unusable frames are registration failures recorded in
    summary.json and registration.csv; the run completes."""
    rng = np.random.default_rng(3)
    frames = [textured(shift=(0, i)) for i in range(4)]
    frames += [np.zeros((120, 160, 3), np.uint8), np.full((120, 160, 3), 255, np.uint8),
               rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)]
    frames += [textured(shift=(0, 4 + i)) for i in range(4)]
    d = write_frames(tmp_path / "f", frames)
    code, _, err = run_cli(capsys, "track", d, "--out", tmp_path / "o")
    assert code == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["frames"] == len(frames)
    assert summary["counts"]["registration_failures"] >= 1
    bad = {f["frame"] for f in summary["registration_failures"]}
    assert bad & {5, 6, 7}


def test_track_one_frame_video(tmp_path, capsys):
    v = write_video(tmp_path / "one.avi", [textured()])
    code, _, err = run_cli(capsys, "track", v, "--out", tmp_path / "o")
    assert code == 0, err
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["frames"] == 1


# -- detect ---------------------------------------------------------------------------------------
def test_detect_missing_input(tmp_path, capsys):
    expect_error(capsys, ["nope.mp4"], "detect", tmp_path / "nope.mp4", "--out", tmp_path / "o")


def test_detect_corrupt_video(tmp_path, capsys):
    p = tmp_path / "bad.mp4"
    p.write_bytes(b"\x00" * 3000)
    expect_error(capsys, ["bad.mp4"], "detect", p, "--out", tmp_path / "o")


def test_detect_output_holds_results(tmp_path, capsys, video):
    o = tmp_path / "o"
    o.mkdir()
    (o / "detections.csv").write_text("")
    err = expect_error(capsys, ["--overwrite"], "detect", video, "--out", o)
    assert "--resume" not in err  # detect has no --resume
    (o / "tracks.csv").write_text("")
    err = expect_error(capsys, ["--overwrite", "--resume"], "track", video, "--out", o)


@pytest.mark.parametrize("extra,needle", [
    (["--map", "MAP"], "--map needs --map-init"),
    (["--map", "MAP", "--map-init", "INIT", "--stabilised"], "--stabilised"),
    (["--frames", "500:"], "--frames 500:"),
    (["--gsd", "0"], "--gsd"),
])
def test_detect_bad_options(tmp_path, capsys, video, extra, needle):
    """detect takes track's input options and refuses them as track does, leaving no folder."""
    m = tmp_path / "m.tif"
    m.write_bytes(b"not a tiff")
    init = tmp_path / "init.txt"
    init.write_text("1 0 0\n0 1 0\n0 0 1\n")
    extra = [str(m) if e == "MAP" else str(init) if e == "INIT" else e for e in extra]
    expect_error(capsys, [needle], "detect", video, "--out", tmp_path / "o", *extra)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("extra,needle", [
    (["--map", "MAP", "--map-init", "INIT", "--stabilised"], "--stabilised"),
    (["--stabilised", "--detections", "DETS", "--no-input"], "--stabilised"),
])
def test_track_stabilised_refusals(tmp_path, capsys, video, dets, extra, needle):
    m = tmp_path / "m.tif"
    m.write_bytes(b"not a tiff")
    init = tmp_path / "init.txt"
    init.write_text("1 0 0\n0 1 0\n0 0 1\n")
    args = [] if "--no-input" in extra else [video]
    extra = [str(m) if e == "MAP" else str(init) if e == "INIT" else str(dets) if e == "DETS"
             else e for e in extra if e != "--no-input"]
    expect_error(capsys, [needle], "track", *args, "--out", tmp_path / "o", *extra)
    assert not (tmp_path / "o").exists()


# -- eval -----------------------------------------------------------------------------------------
def test_eval_missing_gt(tmp_path, capsys, dets):
    expect_error(capsys, ["nope.txt"], "eval", "--gt", tmp_path / "nope.txt", "--pred", dets)


@pytest.mark.parametrize("text,frag", [
    ("1,1,10,10,-8,4,1\n", "negative"),
    ("1,1,10,10,8,4,1\n1,1,10,10,8,4,1\n", "repeated"),
    ("1,1,10,10\n", "line 1"),
])
def test_eval_bad_pred(tmp_path, capsys, dets, text, frag):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,10,10,8,4,1\n")
    p = tmp_path / "pred.txt"
    p.write_text(text)
    expect_error(capsys, ["--pred", frag], "eval", "--gt", gt, "--pred", p)


def test_eval_gt_flaws_accepted_with_warning(tmp_path, capsys):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,18,14,-8,-4,0.8\n1,2,40,40,8,4,0.9\n1,2,40,40,8,4,0.9\n")
    p = tmp_path / "pred.txt"
    p.write_text("1,7,40,40,8,4,1\n")
    code, out, err = run_cli(capsys, "eval", "--gt", gt, "--pred", p, "--json")
    assert code == 0, err
    assert "warning" in err.lower()
    assert json.loads(out)["GT_Dets"] == 2


# -- predict --------------------------------------------------------------------------------------
@pytest.fixture
def tracks_file(tmp_path):
    rows = [f"{f},1,{10 + 2 * f},20,8,4,1,-1,-1,-1" for f in range(1, 31)]
    p = tmp_path / "tracks.csv"
    p.write_text("\n".join(rows) + "\n")
    return p


def test_predict_missing_tracks(tmp_path, capsys):
    q = tmp_path / "q.csv"
    q.write_text("id,last_seen,horizon\n1,10,5\n")
    expect_error(capsys, ["nope.csv"], "predict", tmp_path / "nope.csv", "--queries", q, "--out",
                 tmp_path / "p.csv")


@pytest.mark.parametrize("text", [
    "ident,last,h\n1,10,5\n",     # bad header
    "id,last_seen,horizon\n99,10,5\n",  # unknown id
    "id,last_seen,horizon\n1,10,0\n",   # horizon 0
    "id,last_seen,horizon\n1,x,5\n",    # non-numeric
    "id,last_seen,horizon\n1,10,100000000000\n",  # was "out of memory" after a long wait
])
def test_predict_bad_queries(tmp_path, capsys, tracks_file, text):
    q = tmp_path / "q.csv"
    q.write_text(text)
    expect_error(capsys, ["--queries"], "predict", tracks_file, "--queries", q, "--out",
                 tmp_path / "p.csv")
    assert not (tmp_path / "p.csv").exists()


def test_predict_unknown_method(tmp_path, capsys, tracks_file):
    q = tmp_path / "q.csv"
    q.write_text("id,last_seen,horizon\n1,10,5\n")
    code, _, err = run_cli(capsys, "predict", tracks_file, "--queries", q, "--out",
                           tmp_path / "p.csv", "--method", "magic")
    assert code == 2 and "Traceback" not in err and "magic" in err


# -- mosaic, batch --------------------------------------------------------------------------------
def test_mosaic_missing_input(tmp_path, capsys):
    expect_error(capsys, ["nope"], "mosaic", tmp_path / "nope", "--out", tmp_path / "m.png")


def test_batch_missing_folder(tmp_path, capsys):
    code, _, err = run_cli(capsys, "batch", tmp_path / "nope", "--out", tmp_path / "o")
    assert code == 2 and "Traceback" not in err and "nope: no such folder" in err, err


# -- every option value, the CLI audit --------------------------------------------------------------
@pytest.mark.parametrize("argv,frag", [
    (["--seed", "abc"], "--seed"),
    (["--seed", "-1"], "--seed"),
    (["--stride", "0"], "--stride"),
    (["--workers", "0"], "--workers"),
    (["--fps", "fast"], "--fps"),
    (["--no-such-option"], "--no-such-option"),
])
def test_track_bad_option_value_is_one_line(tmp_path, capsys, dets, argv, frag):
    """click's own usage errors also give one line naming the option (not click's 4-line usage)."""
    expect_error(capsys, [frag, "aerotrack track --help"], "track", "--detections", dets, "--out",
                 tmp_path / "o", *argv, out_dir=tmp_path / "o")


def test_missing_required_option_is_one_line(tmp_path, capsys, dets):
    expect_error(capsys, ["--out"], "track", "--detections", dets)


@pytest.mark.parametrize("setting", ["detection.window_s=-1", "association.max_speed_mps=-40",
                                     "registration.min_inliers=-5"])
def test_track_negative_config_value(tmp_path, capsys, dets, setting):
    expect_error(capsys, [setting.split("=")[0], ">= 0"], "track", "--detections", dets, "--out",
                 tmp_path / "o", "--set", setting, out_dir=tmp_path / "o")


@pytest.mark.parametrize("setting,frag", [
    ("finish.max_overlap=0", "finish.max_overlap"),
    ("finish.absorbed_ratio=1.5", "finish.absorbed_ratio"),
    ("finish.size_mode=magic", "finish.size_mode"),
    ("linking.partial_model=magic", "linking.partial_model"),
    ("association.split_side_obs=0", "association.split_appearance"),
    ("association.split_max_size_ratio=0.5", "association.split_max_size_ratio"),
    ("association.split_merged_area_ratio=0.5", "association.split_merged_area_ratio"),
])
def test_last_stages_config_errors_come_before_any_frame(tmp_path, capsys, dets, setting, frag):
    """Linking and finishing run after the whole video: their configuration is checked when the
    pipeline is built, so a mistake costs no processing (the association-only run here would
    otherwise associate every frame first)."""
    expect_error(capsys, [frag], "track", "--detections", dets, "--out", tmp_path / "o", "--set",
                 setting, out_dir=tmp_path / "o")
    _, _, err = run_cli(capsys, "-v", "track", "--detections", dets, "--out", tmp_path / "o",
                        "--set", setting)
    assert "frames/s" not in err  # no progress line: no frame was processed


@pytest.mark.parametrize("setting,frag", [
    ("registration.method=magic", "registration.method"),
    ("context.method=magic", "context.method"),
])
def test_track_bad_config_choice_leaves_nothing(tmp_path, capsys, video, setting, frag):
    """A config value a stage rejects once the run has started: no folder is left behind, so the
    same command works once the value is fixed."""
    out = tmp_path / "o"
    expect_error(capsys, [frag, "magic"], "track", video, "--out", out, "--set", setting,
                 out_dir=out)
    code, _, err = run_cli(capsys, "track", video, "--out", out)
    assert code == 0, err


def test_track_bad_input_in_existing_empty_folder_keeps_it_empty(tmp_path, capsys):
    d = write_frames(tmp_path / "f", [textured(), textured(), textured(h=100)])
    out = tmp_path / "o"
    out.mkdir()
    expect_error(capsys, ["0003.png"], "track", d, "--out", out, out_dir=out)
    assert out.is_dir() and not any(out.iterdir())


@pytest.mark.parametrize("row,frag", [
    ("100000000,-1,10,10,8,4,0.9", "not times"),     # a timestamp, not a frame number
    ("1,-1,1e300,10,8,4,0.9", "beyond any image"),
    ("1,-1,10,10,8,4e9,0.9", "beyond any image"),
    ("1,-1,-2e8,10,8,4,0.9", "beyond any image"),
])
def test_track_implausible_detections(tmp_path, capsys, row, frag):
    """Rows no video can have are refused at once (a timestamp used as a frame number made the run
    step through every empty frame up to it)."""
    from aerotrack.errors import InputError
    from aerotrack.io.mot import check_detections, read_mot

    p = tmp_path / "d.txt"
    p.write_text("1,-1,10,10,8,4,0.9\n" + row + "\n")
    with pytest.raises(InputError, match="row 2"):
        check_detections(read_mot(p, strict=True), f"--detections {p}")
    if not row.startswith("100000000"):  # the CLI path (the frame case would hang before the fix)
        expect_error(capsys, ["--detections", "line 2", frag], "track", "--detections", p, "--out",
                     tmp_path / "o", out_dir=tmp_path / "o")


def test_the_api_checks_detections_as_the_command_line_does(caplog):
    """The Python API took a timestamp for a frame number and normalised boxes without a word,
    where --detections refused or warned."""
    import logging

    from aerotrack.errors import InputError
    from aerotrack.pipeline import run

    with pytest.raises(InputError, match="detections: row 2 has frame .* beyond any video"):
        run(detections=np.array([[1, -1, 10, 10, 8, 4, 0.9], [2e9, -1, 10, 10, 8, 4, 0.9]]),
            fps=30)
    rows = np.array([[f, -1, 0.1 * f / 40, 0.5, 0.02, 0.01, 0.9] for f in range(1, 41)])
    with caplog.at_level(logging.WARNING, logger="aerotrack"):
        run(detections=rows, fps=30)
    assert "normalised to [0, 1]" in caplog.text


def test_track_detections_messages_name_the_file_line(tmp_path, capsys):
    """Messages named the row's place after sorting by frame: 'row 3' for line 1 here. A box of
    zero width or height (a detector's degenerate box, in public detection files) is dropped with
    a warning naming its line: it failed the whole run (a batch input) before."""
    from aerotrack.io.mot import read_mot

    p = tmp_path / "d.txt"
    p.write_text("frame,id,x,y,w,h,conf\n3,-1,10,10,8,0,0.9\n1,-1,10,10,8,4,0.9\n"
                 "2,-1,10,10,8,4,0.9\n")
    code, _, err = run_cli(capsys, "track", "--detections", p, "--out", tmp_path / "o")
    assert code == 0 and "1 box(es) of zero width or height dropped (first: line 2)" in err, err
    assert len(read_mot(tmp_path / "o" / "detections.csv")) == 2
    p.write_text("1,-1,10,10,8,-4,0.9\n")  # a negative size is a broken file
    expect_error(capsys, ["line 1: negative box width or height"], "track", "--detections", p,
                 "--out", tmp_path / "o2", out_dir=tmp_path / "o2")


def test_track_detections_from_a_real_detector(tmp_path, capsys, video):
    """What a detector's file holds: class ids in the id column (ignored, as documented: repeated
    (frame, id) pairs were refused), frames from 0 (--detections-zero-based), low-confidence boxes
    (--min-conf drops them: every box was tracked, the option did nothing), confidences in
    percent, boxes of another image size; each odd thing is said."""
    from aerotrack.io.mot import read_mot

    rows = ["0,0,10,10,8,4,0.9", "0,0,40,40,8,4,0.1", "1,0,11,10,8,4,0.9", "1,0,41,40,8,4,0.1",
            "2,0,12,10,8,4,0.9", "2,0,42,40,8,4,0.1"]
    p = tmp_path / "yolo.txt"
    p.write_text("\n".join(rows) + "\n")
    expect_error(capsys, ["a 0-based file?", "track: --detections-zero-based"], "track",
                 "--detections", p, "--out", tmp_path / "o", out_dir=tmp_path / "o")
    code, _, err = run_cli(capsys, "track", "--detections", p, "--detections-zero-based",
                           "--out", tmp_path / "a")
    assert code == 0, err
    dets = read_mot(tmp_path / "a" / "detections.csv")
    assert sorted(set(dets[:, 0])) == [1, 2, 3] and len(dets) == 6
    assert "confidence below 0.25" in err, err  # half of them: said, with the option to use
    code, _, err = run_cli(capsys, "track", "--detections", p, "--detections-zero-based",
                           "--min-conf", "0.5", "--out", tmp_path / "b")
    assert code == 0, err
    assert len(read_mot(tmp_path / "b" / "detections.csv")) == 3
    assert "min_conf = 0.5" in (tmp_path / "b" / "config.toml").read_text()
    expect_error(capsys, ["--min-conf 1.5"], "track", "--detections", p, "--min-conf", "1.5",
                 "--out", tmp_path / "c", out_dir=tmp_path / "c")
    # percent confidences, boxes beyond the frame (the video is 160x120), every 5th frame
    q = tmp_path / "odd.txt"
    q.write_text("".join(f"{f},-1,{500 + f},300,8,4,90\n" for f in range(1, 60, 5)))
    code, _, err = run_cli(capsys, "track", video, "--detections", q, "--out", tmp_path / "d")
    assert code == 0, err
    assert "outside [0, 1]" in err and "outside the 160x120 frame" in err, err
    assert "5 apart" in err, err
    # normalised coordinates
    r = tmp_path / "norm.txt"
    r.write_text("".join(f"{f},-1,0.5,0.5,0.02,0.01,0.9\n" for f in range(1, 4)))
    code, _, err = run_cli(capsys, "track", "--detections", r, "--out", tmp_path / "e")
    assert code == 0 and "normalised" in err, err
    # an empty file: a complete, empty result, said
    e = tmp_path / "empty.txt"
    e.write_text("")
    code, _, err = run_cli(capsys, "track", "--detections", e, "--out", tmp_path / "f")
    assert code == 0 and "no detections in the file" in err, err


def test_track_detections_after_the_video_warn(tmp_path, capsys, video):
    p = tmp_path / "d.txt"
    p.write_text("1,-1,10,10,8,4,0.9\n500,-1,10,10,8,4,0.9\n")
    code, _, err = run_cli(capsys, "track", video, "--detections", p, "--out", tmp_path / "o")
    assert code == 0, err
    assert "after the input's last frame 6" in err


@pytest.mark.parametrize("option", ["--map-init", "--roads"])
def test_track_folder_instead_of_file(tmp_path, capsys, video, option):
    m = write_map(tmp_path / "m.tif")
    h = tmp_path / "h.txt"
    h.write_text("1 0 10\n0 1 10\n0 0 1\n")
    folder = tmp_path / "folder"
    folder.mkdir()
    args = {"--map-init": ["--map-init", folder], "--roads": ["--map-init", h, "--roads", folder]}
    expect_error(capsys, [option, "is a folder"], "track", video, "--map", m, *args[option],
                 "--out", tmp_path / "o", out_dir=tmp_path / "o")


def test_track_intrinsics_folder(tmp_path, capsys, video):
    expect_error(capsys, ["--intrinsics", "is a folder"], "track", video, "--intrinsics",
                 tmp_path, "--out", tmp_path / "o", out_dir=tmp_path / "o")


@pytest.mark.parametrize("argv,frag", [
    (["--fps", "nan"], "--fps"),
    (["--gsd", "nan"], "--gsd"),
    (["--gsd", "-1"], "--gsd"),
    (["--crs", "EPSG:32611"], "--roads"),
])
def test_predict_bad_numbers(tmp_path, capsys, tracks_file, argv, frag):
    q = tmp_path / "q.csv"
    q.write_text("id,last_seen,horizon\n1,10,5\n")
    expect_error(capsys, [frag], "predict", tracks_file, "--queries", q, "--out",
                 tmp_path / "p.csv", *argv)
    assert not (tmp_path / "p.csv").exists()


def test_synth_negative_seed(tmp_path, capsys):
    expect_error(capsys, ["--seed"], "synth", "--out", tmp_path / "s", "--frames", "2", "--seed",
                 "-1", out_dir=tmp_path / "s")


@pytest.mark.parametrize("value", ["0", "-2", "nan", "inf", "9"])
def test_synth_bad_gsd_scale(tmp_path, capsys, value):
    expect_error(capsys, ["--gsd-scale", "between 0.125 and 8"], "synth", "--out", tmp_path / "s",
                 "--frames", "2", "--gsd-scale", value, out_dir=tmp_path / "s")


def test_eval_frames_without_ground_truth(tmp_path, capsys):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,10,10,8,4,1\n2,1,12,10,8,4,1\n")
    expect_error(capsys, ["--frames", "ends at frame 2"], "eval", "--gt", gt, "--pred", gt,
                 "--frames", "50:60")


def test_eval_refuses_detections_as_tracks(tmp_path, capsys, dets):
    """A detections file (id -1) scored as tracks was one track with several boxes a frame:
    HOTA 0.975 and MOTA 1.000 on generated ground truth with no identity at all."""
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,10,10,8,4,1\n2,1,12,10,8,4,1\n")
    expect_error(capsys, ["--pred", "dets.txt line 1", "ids >= 0"], "eval", "--gt", gt,
                 "--pred", dets)


@pytest.fixture
def run_dir(tmp_path, capsys, video):
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "run")
    assert code == 0, err
    return tmp_path / "run"


@pytest.mark.parametrize("argv,frag", [
    (["--trail-s", "nan"], "--trail-s"),
    (["--start", "50"], "--start"),
    (["--text-height", "0.001"], "--text-height"),
    (["--text-height", "nan"], "--text-height"),
])
def test_render_bad_numbers(tmp_path, capsys, video, run_dir, argv, frag):
    out = tmp_path / "overlay.webm"
    expect_error(capsys, [frag], "render", video, run_dir, "--out", out, "--no-pictures", *argv)
    assert not out.exists()


def test_report_bad_video_width(tmp_path, capsys, run_dir):
    expect_error(capsys, ["--video-width"], "report", run_dir, "--video-width", "-5")
    assert not (run_dir / "report.html").exists()


def test_report_out_must_be_html(tmp_path, capsys, run_dir):
    """HTML was written into report.pdf with exit 0 (a probe)."""
    expect_error(capsys, ["--out", "name it .html"], "report", run_dir, "--out",
                 tmp_path / "r.pdf", "--no-video")
    assert not (tmp_path / "r.pdf").exists()


def test_an_output_never_replaces_an_input(tmp_path, capsys, video, run_dir):
    """render --out the input video, report --out the run's tracks.csv, mosaic --out the map or
    a frame of its input folder, mosaic --registration onto its own --out, and track --out a
    folder holding its input (with --overwrite its results replace that folder's content): each
    replaced an input and exited 0. Now each is a one-line error and the input is unchanged."""
    before = video.read_bytes(), (run_dir / "tracks.csv").read_text()
    expect_error(capsys, ["--out", "is the INPUT"], "render", video, run_dir, "--out", video,
                 "--no-pictures")
    expect_error(capsys, ["--out", "the run's own results"], "report", run_dir, "--out",
                 run_dir / "tracks.csv", "--no-video")
    frames = write_frames(tmp_path / "frames", [textured(shift=(0, i)) for i in range(3)])
    expect_error(capsys, ["--out", "inside the INPUT folder"], "mosaic", frames, "--out",
                 frames / "0001.png")
    m = write_map(tmp_path / "m.tif")
    h = tmp_path / "h.txt"
    h.write_text("1 0 100\n0 1 100\n0 0 1\n")
    expect_error(capsys, ["--out", "is the --map"], "mosaic", video, "--out", m, "--map", m,
                 "--map-init", h)
    expect_error(capsys, ["--registration", "is the --out"], "mosaic", video, "--out",
                 tmp_path / "m.png", "--registration", tmp_path / "m.png")
    inside = run_dir / "overlay.mp4"  # (a name aerotrack writes: not a foreign file)
    inside.write_bytes(video.read_bytes())
    expect_error(capsys, ["--out", "holds the INPUT"], "track", inside, "--out", run_dir,
                 "--overwrite")
    assert (video.read_bytes(), (run_dir / "tracks.csv").read_text()) == before
    assert inside.read_bytes() == before[0]


def test_outputs_readable_like_any_new_file(tmp_path, capsys, dets):
    """Results are not private to the user (mkstemp's 0600): another account can score them."""
    import os

    code, _, err = run_cli(capsys, "track", "--detections", dets, "--out", tmp_path / "o")
    assert code == 0, err
    mask = os.umask(0)
    os.umask(mask)
    for name in ("tracks.csv", "summary.json", "config.toml"):
        assert (tmp_path / "o" / name).stat().st_mode & 0o777 == 0o666 & ~mask, name


def test_signals_are_held_off_while_results_are_written():
    """Ctrl-C between frames stops after the frame; while the final files are written it waits."""
    import os
    import signal

    from aerotrack.cli.common import Interrupted
    from aerotrack.cli.track_cmd import GracefulStop

    seen = []
    with GracefulStop() as stop:
        progress = stop.wrap(seen.append)
        progress(1)
        os.kill(os.getpid(), signal.SIGINT)  # first Ctrl-C: only a flag
        with pytest.raises(Interrupted) as info:
            progress(2)
        assert info.value.signum == signal.SIGINT and ".partial" in info.value.note
    with GracefulStop() as stop:
        stop.writing()
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)  # not even a second signal cuts the writing short
        assert stop.stop_signal == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert seen == [1, 2]


@pytest.mark.parametrize("command", ["track", "detect", "synth", "demo"])
def test_overwrite_refuses_a_folder_with_foreign_files(tmp_path, capsys, dets, video, command):
    """``--out ~ --overwrite`` by mistake must not empty a home folder (demo overwrites by
    default)."""
    home = tmp_path / "home"
    home.mkdir()
    (home / "notes.txt").write_text("precious")
    argv = {"track": ["track", "--detections", dets, "--overwrite"],
            "detect": ["detect", video, "--overwrite"],
            "synth": ["synth", "--frames", "2", "--overwrite"],
            "demo": ["demo"]}[command]
    expect_error(capsys, ["notes.txt", "--overwrite"], *argv, "--out", home)
    assert sorted(p.name for p in home.iterdir()) == ["notes.txt"]


def test_resume_refuses_checkpoints_of_another_run(tmp_path, capsys, dets):
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "track", "--detections", dets, "--out", out, "--seed", "1")
    assert code == 0, err
    # make it look interrupted: the checkpoints (with run.json) back in .partial, no results
    (out / "stages").rename(out / ".partial")
    for p in out.iterdir():
        if p.is_file():
            p.unlink()
    assert (out / ".partial" / "run.json").is_file()
    expect_error(capsys, ["--resume", "--seed"], "track", "--detections", dets, "--out", out,
                 "--resume", "--seed", "2")
    expect_error(capsys, ["--resume", "config"], "track", "--detections", dets, "--out", out,
                 "--resume", "--seed", "1", "--set", "association.window_s=2")
    assert list((out / ".partial").glob("chunk_*.npz"))  # kept for the right command
    code, _, err = run_cli(capsys, "track", "--detections", dets, "--out", out, "--resume",
                           "--seed", "1")
    assert code == 0, err
    assert (out / "tracks.csv").is_file() and not (out / ".partial").exists()


def test_track_video_cut_mid_stream_warns_and_completes(tmp_path, capsys):
    """Documented degraded result: the frames before the cut are tracked, with a warning."""
    v = write_video(tmp_path / "clip.avi", [textured(shift=(0, i)) for i in range(9)])
    cut = tmp_path / "cut.avi"
    cut.write_bytes(v.read_bytes()[: v.stat().st_size * 2 // 3])
    code, _, err = run_cli(capsys, "track", cut, "--out", tmp_path / "o")
    assert code == 0, err
    assert "cut.avi: decoding stopped after frame" in err
    frames = json.loads((tmp_path / "o" / "summary.json").read_text())["frames"]
    last = int(re.search(r"decoding stopped after frame (\d+) of the 9", err).group(1))
    assert frames == last < 9  # every decoded frame was tracked, and only those


def test_batch_reports_each_unusable_video_once_and_fails(tmp_path, capsys):
    """An empty video is not skipped silently and a corrupt one is reported once (it was reported
    twice, once as a warning repeating the path); both count as failed (exit 2), and the
    good input is still tracked."""
    inputs = tmp_path / "in"
    write_frames(inputs / "good", [textured(shift=(0, i)) for i in range(4)])
    (inputs / "empty.mp4").write_bytes(b"")
    (inputs / "junk.avi").write_text("not a video\n")
    (inputs / "notes.txt").write_text("not an input at all\n")
    code, _, err = run_cli(capsys, "batch", inputs, "--out", tmp_path / "o", "--gsd", "0.3")
    lines = err.strip().splitlines()
    # (the good input's own warnings, its 4-frame clip, are fine)
    assert code == 2 and "Traceback" not in err, err
    assert not [ln for ln in lines if "WARNING" in ln and ("junk" in ln or "empty" in ln)], err
    assert sum("empty.mp4: failed" in ln and "0 bytes" in ln for ln in lines) == 1, err
    assert sum("junk.avi: failed" in ln for ln in lines) == 1, err
    assert sum("junk.avi" in ln for ln in lines[:-1]) == 1, err  # one line, then the summary
    assert "batch: 1 tracked, 0 skipped, 2 failed" in err
    assert lines[-1].startswith("aerotrack: error: batch: 2 of 3 inputs failed"), err
    assert "notes" not in err
    assert (tmp_path / "o" / "good" / "tracks.csv").is_file()
    # -q still shows the failures (errors), not the progress of the good one
    code, _, err = run_cli(capsys, "-q", "batch", inputs, "--out", tmp_path / "o", "--gsd", "0.3")
    assert code == 2 and "empty.mp4: failed" in err and "junk.avi: failed" in err
    assert "good" not in err


@pytest.mark.parametrize("text,frag", [
    ("id,last_seen,horizon\n99,10,5\n", "line 2 (query 0): unknown id 99"),
    ("id,last_seen,horizon\n1,10,5\n\n1,77,5\n", "line 4 (query 1): track 1 has no row at"),
    ("id,last_seen,horizon\n1,10,0\n", "line 2: horizon must be positive"),
])
def test_predict_errors_name_the_queries_file_and_line(tmp_path, capsys, tracks_file, text, frag):
    q = tmp_path / "my_queries.csv"
    q.write_text(text)
    expect_error(capsys, [f"--queries {q} {frag}"], "predict", tracks_file, "--queries", q,
                 "--out", tmp_path / "p.csv")


def test_predict_refuses_to_overwrite_its_inputs_and_unwritable_out(tmp_path, capsys, tracks_file):
    q = tmp_path / "q.csv"
    q.write_text("id,last_seen,horizon\n1,10,5\n")
    before = tracks_file.read_text()
    expect_error(capsys, ["--out", "TRACKS"], "predict", tracks_file, "--queries", q, "--out",
                 tracks_file)
    expect_error(capsys, ["--out", "--queries"], "predict", tracks_file, "--queries", q, "--out",
                 q)
    assert tracks_file.read_text() == before
    blocker = tmp_path / "file"
    blocker.write_text("")
    expect_error(capsys, ["--out", "cannot write"], "predict", tracks_file, "--queries", q,
                 "--out", blocker / "p.csv")


@pytest.mark.parametrize("command", ["mosaic", "mosaic-registration", "render", "report", "batch",
                                     "predict"])
def test_unwritable_output_refused_first_naming_option(tmp_path, capsys, video, run_dir,
                                                       tracks_file, command):
    """An output under a plain file is refused before any work, in one line naming the option
    and the file in the way (mosaic named --out for its --registration file; batch failed each
    input in turn; render and report only failed after all the work)."""
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    bad = blocker / "x"
    q = tmp_path / "q.csv"
    q.write_text("id,last_seen,horizon\n1,10,5\n")
    argv, option = {
        "mosaic": (["mosaic", video, "--out", f"{bad}.png"], "--out"),
        "mosaic-registration": (["mosaic", video, "--out", tmp_path / "m.png", "--registration",
                                 f"{bad}.csv"], "--registration"),
        "render": (["render", video, run_dir, "--out", f"{bad}.webm", "--no-pictures"], "--out"),
        "report": (["report", run_dir, "--out", f"{bad}.html", "--no-video"], "--out"),
        "batch": (["batch", video.parent, "--out", bad], "--out"),
        "predict": (["predict", tracks_file, "--queries", q, "--out", f"{bad}.csv"], "--out"),
    }[command]
    err = expect_error(capsys, [f"{option} {bad}", "is a file, not a folder"], *argv)
    assert "failed" not in err
    assert not (tmp_path / "m.png").exists()


# -- found by a robustness probe (2026-12-02) ----------------------------------------------------
@pytest.mark.parametrize("setting,frag", [
    ("registration.scale=5", "registration.scale"),
    ("detection.window_s=0", "detection.window_s"),
    ("registration.max_features=0", "registration.max_features"),
    # sizes no vehicle needs, which ran for hours or failed deep in OpenCV (a fuzz probe)
    ("detection.close_px=5000", "detection.close_px"),
    ("detection.residual_sigma_px=1000000", "detection.residual_sigma_px"),
    ("detection.shadow_chroma_px=1000000", "detection.shadow_chroma_px"),
    ("association.min_iters=1000000", "association.min_iters"),
    ("registration.max_features=3000000000", "registration.max_features"),
])
def test_overwrite_with_a_bad_setting_keeps_the_previous_results(tmp_path, capsys, video,
                                                                  setting, frag):
    """Registration and detection settings used to be checked when their stage was built, at the
    first frame: by then ``--overwrite`` had emptied the folder of the results it was to
    replace, and a bad value lost them."""
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "track", video, "--out", out)
    assert code == 0, err
    before = {name: (out / name).read_bytes() for name in RESULT_FILES}
    expect_error(capsys, [frag], "track", video, "--out", out, "--overwrite", "--set", setting)
    assert {name: (out / name).read_bytes() for name in RESULT_FILES} == before
    expect_error(capsys, [frag], "detect", video, "--out", tmp_path / "d", "--set", setting,
                 out_dir=tmp_path / "d")


def test_from_refuses_the_options_it_would_ignore(tmp_path, capsys, video):
    out = tmp_path / "o"
    assert run_cli(capsys, "track", video, "--out", out)[0] == 0
    again = tmp_path / "again"
    expect_error(capsys, ["--from", "INPUT", "--frames"], "track", video, "--from", out,
                 "--frames", "1:3", "--out", again, out_dir=again)
    expect_error(capsys, ["--stride"], "track", "--from", out, "--stride", "2", "--out", again,
                 out_dir=again)
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", again)
    assert code == 0, err


def test_resume_and_overwrite_refused_even_when_finished(tmp_path, capsys, dets):
    out = tmp_path / "o"
    assert run_cli(capsys, "track", "--detections", dets, "--out", out)[0] == 0
    expect_error(capsys, ["--resume", "--overwrite"], "track", "--detections", dets, "--out", out,
                 "--resume", "--overwrite")


def test_folder_of_other_files_says_so(tmp_path, capsys, dets):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    err = expect_error(capsys, ["notes.txt", "did not write"], "track", "--detections", dets,
                       "--out", out)
    assert "--overwrite" not in err  # which would then be refused
    assert (out / "notes.txt").read_text() == "keep me"


def test_frames_beyond_what_a_truncated_video_holds(tmp_path, capsys):
    """The header promises 40 frames, 20 decode: --frames 30:40 is an error, not an empty run."""
    full = write_video(tmp_path / "v.avi", [textured(seed=i) for i in range(40)])
    data = full.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[:len(data) // 2])
    for cmd in ("track", "detect"):
        expect_error(capsys, ["cut.avi", "30:40", "truncated"], cmd, cut, "--frames", "30:40",
                     "--out", tmp_path / cmd, out_dir=tmp_path / cmd)


def jpeg_folder_with_a_truncated_file(folder: Path, n: int, cut: int) -> Path:
    """``n`` JPEG frames, frame ``cut`` cut to a third of its bytes (no end-of-image marker)."""
    folder.mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / f"{i + 1:04d}.jpg"), textured(shift=(0, i)))
    p = folder / f"{cut:04d}.jpg"
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 3])
    return folder


def test_truncated_jpeg_is_named(tmp_path, capsys):
    d = jpeg_folder_with_a_truncated_file(tmp_path / "f", 6, 4)
    code, _, err = run_cli(capsys, "track", d, "--out", tmp_path / "o")
    assert code == 0, err
    warned = [ln for ln in err.splitlines() if "truncated JPEG" in ln]
    assert len(warned) == 1 and "0004.jpg" in warned[0], err


def test_truncated_jpeg_leaves_no_nameless_decoder_message(tmp_path, capfd, caplog):
    """libjpeg prints "Premature end of JPEG file" on descriptor 2 itself; the reader names the
    file in its own warning, so the decoder's line must not reach the terminal (nor with -q)."""
    from aerotrack.io.frames import ImageFolderSource

    d = jpeg_folder_with_a_truncated_file(tmp_path / "f", 3, 2)
    frames = list(ImageFolderSource(d).frames())
    err = capfd.readouterr().err
    assert len(frames) == 3 and frames[1].image.shape == (120, 160, 3)
    assert "Premature end" not in err, err
    assert "0002.jpg: truncated JPEG" in caplog.text
    import sys
    print("still there", file=sys.stderr)  # descriptor 2 restored
    assert "still there" in capfd.readouterr().err


def test_render_refuses_another_input(tmp_path, capsys, video):
    out = tmp_path / "o"
    assert run_cli(capsys, "track", video, "--out", out)[0] == 0
    other = write_frames(tmp_path / "other", [textured(h=90, w=120) for _ in range(3)])
    expect_error(capsys, ["120x90", "160x120"], "render", other, out, "--out",
                 tmp_path / "r.mp4", "--no-pictures")
    assert not (tmp_path / "r.mp4").exists()


def test_detections_with_a_byte_order_mark(tmp_path, capsys):
    p = tmp_path / "bom.txt"
    p.write_bytes("\ufeff1,-1,10,10,8,4,0.9\n2,-1,12,10,8,4,0.9\n".encode())
    code, _, err = run_cli(capsys, "track", "--detections", p, "--out", tmp_path / "o")
    assert code == 0, err
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["counts"]["detections"] == 2


def test_report_with_an_empty_ground_truth(tmp_path, capsys, dets):
    out = tmp_path / "o"
    assert run_cli(capsys, "track", "--detections", dets, "--out", out)[0] == 0
    empty = tmp_path / "gt.txt"
    empty.write_text("")
    expect_error(capsys, ["--gt", "no rows"], "report", out, "--gt", empty)
    assert not (out / "report.html").exists()


def test_batch_checks_settings_once_before_any_input(tmp_path, capsys, video):
    inputs = tmp_path / "in"
    inputs.mkdir()
    (inputs / "a.avi").write_bytes(video.read_bytes())
    expect_error(capsys, ["registration.scale"], "batch", inputs, "--out", tmp_path / "runs",
                 "--set", "registration.scale=5", out_dir=tmp_path / "runs")
    expect_error(capsys, ["--fps"], "batch", inputs, "--out", tmp_path / "runs", "--fps", "0",
                 out_dir=tmp_path / "runs")


def test_map_init_accepts_a_frame_wider_than_the_map():
    """A 4000 x 300 frame over a 1300 px tile (what ``aerotrack synth --size 4000x300`` makes):
    its centre is on the map, its corners far beyond the map's edges; it used to be refused as
    'does not land on the map' with a centre in the middle of the map."""
    from types import SimpleNamespace

    from aerotrack.errors import GeoreferenceError
    from aerotrack.geo.init import check_overlap as _check_overlap

    geomap = SimpleNamespace(width=1300, height=1300)
    H = np.array([[1.2, 0, 650 - 1.2 * 2000], [0, 1.2, 650 - 1.2 * 150], [0, 0, 1]])
    _check_overlap((4000, 300), H, geomap, "h.txt")
    toward_horizon = H.copy()
    toward_horizon[2] = [0, -0.00665, 1 + 0.00665 * 150]  # the bottom row nearly at infinity
    with pytest.raises(GeoreferenceError, match="corner"):
        _check_overlap((4000, 300), toward_horizon, geomap, "h.txt")


def test_resume_of_a_finished_run_refuses_other_options(tmp_path, capsys, video):
    """It compared INPUT, --detections and --seed only: another --frames, --stride or config
    was answered 'already finished, nothing to resume' with exit 0."""
    out = tmp_path / "o"
    assert run_cli(capsys, "track", video, "--out", out)[0] == 0
    code, _, err = run_cli(capsys, "track", video, "--out", out, "--resume")
    assert code == 0 and "already finished" in err
    expect_error(capsys, ["finished run", "--frames"], "track", video, "--out", out, "--resume",
                 "--frames", "2:5")
    expect_error(capsys, ["finished run", "--stride"], "track", video, "--out", out, "--resume",
                 "--stride", "2")
    expect_error(capsys, ["finished run", "config"], "track", video, "--out", out, "--resume",
                 "--set", "detection.threshold_sigma=5")


def test_a_second_signal_while_detect_flushes_keeps_the_finished_frames(tmp_path, capsys,
                                                                        monkeypatch):
    """A second Ctrl-C landing in the detector's flush after the last frame raised
    AttributeError ('Interrupted' object has no attribute 'partial_result') and the output
    folder, finished detections included, was deleted."""
    import signal

    from aerotrack.cli.common import Interrupted
    from aerotrack.pipeline import Pipeline

    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(12)])

    def second_signal(self):
        raise Interrupted(signal.SIGINT, "")

    monkeypatch.setattr(Pipeline, "finish_local", second_signal)
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "detect", frames, "--out", out)
    assert code == 130 and "Traceback" not in err, err
    assert (out / "detections.csv").is_file() and (out / "registration.csv").is_file(), err
    assert len((out / "registration.csv").read_text().splitlines()) == 13  # header + 12 frames


def test_small_messages_found_by_a_probe(tmp_path, capsys):
    """--frames past the end says where the input ends; -q silences mosaic; a frame 0 in a
    1-based file hints at 0-based numbering; debug.mp4 is H.264 at the input's speed."""
    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(8)])
    code, _, err = run_cli(capsys, "detect", frames, "--out", tmp_path / "d", "--frames", "3:50",
                           "--debug-video", "--stride", "2")
    assert code == 0 and "ends at frame 8" in err, err
    cap = cv2.VideoCapture(str(tmp_path / "d" / "debug.mp4"))
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode(errors="replace")
    assert fourcc.lower() in ("avc1", "h264") and cap.get(cv2.CAP_PROP_FPS) == pytest.approx(15.0)  # 30 / 2
    code, out, err = run_cli(capsys, "-q", "mosaic", frames, "--out", tmp_path / "m.png")
    assert code == 0 and out == "" and err == "", (out, err)
    gt = tmp_path / "gt0.txt"
    gt.write_text("0,1,10,10,8,4,1\n")
    expect_error(capsys, ["line 1", "0-based"], "eval", "--gt", gt, "--pred", gt)


def test_batch_names_inputs_finished_with_other_settings(tmp_path, capsys):
    """A re-run with other settings skipped every finished input silently, keeping results made
    with the old ones; now each is named (a warning, also with -q) and --overwrite tracks it
    again."""
    inputs = tmp_path / "in"
    write_frames(inputs / "clip", [textured(shift=(0, i)) for i in range(4)])
    out = tmp_path / "o"
    assert run_cli(capsys, "batch", inputs, "--out", out, "--gsd", "0.3")[0] == 0
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out, "--gsd", "0.3")
    assert code == 0 and "clip: already finished, skipped" in err and "WARNING" not in err, err
    code, _, err = run_cli(capsys, "-q", "batch", inputs, "--out", out, "--gsd", "0.5",
                           "--set", "detection.threshold_sigma=6")
    assert code == 0 and "finished with other --config/--set, --gsd" in err, err
    before = json.loads((out / "clip" / "summary.json").read_text())
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out, "--gsd", "0.5", "--overwrite")
    assert code == 0 and "1 tracked, 0 skipped" in err, err
    after = json.loads((out / "clip" / "summary.json").read_text())
    assert before["gsd"] == 0.3 and after["gsd"] == 0.5


def test_gsd_with_a_map_is_named_as_unused(tmp_path, capsys, dets):
    gm = write_map(tmp_path / "m.tif")
    h = tmp_path / "h.txt"
    h.write_text("1 0 10\n0 1 10\n0 0 1\n")
    code, _, err = run_cli(capsys, "track", "--detections", dets, "--map", gm, "--map-init", h,
                           "--gsd", "0.3", "--out", tmp_path / "o")
    assert code == 0 and "--gsd 0.3: not used with --map" in err, err


def test_a_text_file_is_not_tracked_as_a_video(tmp_path, capsys):
    """FFmpeg draws a text file as frames of text: a detections file given as INPUT (a
    forgotten --detections) was tracked, 927 frames and 75 tracks of glyphs."""
    p = tmp_path / "dets.txt"
    p.write_text("".join(f"{f},-1,10,10,8,4,0.9\n" for f in range(1, 200)))
    expect_error(capsys, ["dets.txt", "text file", "--detections"], "track", p, "--out",
                 tmp_path / "o", out_dir=tmp_path / "o")


def test_an_unreadable_image_mid_folder_is_skipped(tmp_path, capsys):
    """One zero-byte image among 12 ended the run (exit 2) and deleted the work done so far,
    after a warning that called it a truncated JPEG."""
    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(12)])
    (frames / "0006.png").write_bytes(b"")
    code, _, err = run_cli(capsys, "track", frames, "--out", tmp_path / "o")
    assert code == 0, err
    assert "0006.png: empty file (0 bytes); frame 6 skipped" in err
    regs = (tmp_path / "o" / "registration.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in regs] == [1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["skipped_frames"] == [6]  # it was only in the log


def test_frames_too_big_for_memory_are_named(tmp_path, capsys, monkeypatch):
    """6000x4000 frames at 30 fps held 7.1 GB in the detector's window with no word; the run
    now says what the window will hold against the machine's memory (here made 64 MB)."""
    import os

    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(3)])
    real = os.sysconf
    monkeypatch.setattr(os, "sysconf", lambda name: 16384 if name == "SC_PHYS_PAGES"
                        else real(name))
    code, _, err = run_cli(capsys, "detect", frames, "--out", tmp_path / "o", "--fps", "1000")
    assert code == 0 and "window takes about" in err and "--stride 2" in err, err


def test_batch_messages_name_their_input(tmp_path, capsys):
    """A batch's stage messages (linking's scale note, warnings) did not say which input they
    were about; during an input's run every message starts with its name."""
    import logging

    from aerotrack.cli.main import configure_logging
    from aerotrack.parallel import _messages_named

    configure_logging(0, False)
    with _messages_named("clip.mp4"):
        logging.getLogger("aerotrack.pipeline").warning("something about a frame")
    logging.getLogger("aerotrack.pipeline").warning("after")
    err = capsys.readouterr().err
    assert "WARNING: clip.mp4: something about a frame" in err
    assert "WARNING: after" in err


def test_api_detections_below_min_conf_are_dropped(tmp_path, capsys):
    """``detection.min_conf`` applies to given detections in the Python API too (it applied to
    the built-in detector only), and ``track --from`` a detections-only run does not warn about
    colour histograms that run never had."""
    from aerotrack.config import load_config
    from aerotrack.pipeline import run

    rows = np.array([[f, -1, 10 + 3 * f, 10, 8, 4, c, -1, -1, -1]
                     for f in range(1, 31) for c in (0.9, 0.2)], float)
    rows[1::2, 2] += 60  # the low-confidence boxes drive beside the others
    full = run(detections=rows, fps=10)
    kept = run(detections=rows, fps=10, config=load_config(overrides=["detection.min_conf=0.5"]))
    assert sum(len(d) for d in full.detections) == 60
    assert sum(len(d) for d in kept.detections) == 30 and len(kept.tracks) == 1
    p = tmp_path / "d.txt"
    p.write_text("".join(",".join(f"{v:g}" for v in r) + "\n" for r in rows))
    code, _, err = run_cli(capsys, "track", "--detections", p, "--out", tmp_path / "a")
    assert code == 0, err
    code, _, err = run_cli(capsys, "track", "--from", tmp_path / "a", "--out", tmp_path / "b")
    assert code == 0 and "colour histograms" not in err, err
    # --from with a higher --min-conf drops the cached boxes below it (it was ignored)
    code, _, err = run_cli(capsys, "track", "--from", tmp_path / "a", "--out", tmp_path / "c",
                           "--min-conf", "0.5")
    assert code == 0, err
    from aerotrack.io.mot import read_mot

    assert len(read_mot(tmp_path / "c" / "detections.csv")) == 30
    assert len(read_mot(tmp_path / "b" / "detections.csv")) == 60


def test_detections_in_another_order_give_the_same_tracks(tmp_path, capsys, shared_data):
    """The same boxes listed in another order within their frames give the same tracks (the
    sampler followed the file's order: a shuffled UAVDT file scored HOTA 0.919 against 0.925).
    Real UAVDT boxes, jittered, with false alarms (skipped without ../shared)."""
    rows = np.loadtxt(shared_data / "uavdt_gt_only" / "M0101_gt.txt", delimiter=",")
    rows = rows[rows[:, 0] <= 200]
    rng = np.random.default_rng(0)
    rows = rows[rng.random(len(rows)) > 0.1]
    out = [[r[0], -1, r[2] + rng.normal(0, 0.05 * r[4]), r[3] + rng.normal(0, 0.05 * r[5]),
            r[4] * (1 + rng.normal(0, 0.05)), r[5] * (1 + rng.normal(0, 0.05)),
            rng.uniform(0.5, 1)] for r in rows]
    out += [[f, -1, rng.uniform(0, 900), rng.uniform(0, 500), 60, 30, rng.uniform(0.5, 1)]
            for f in range(1, 201) if rng.random() < 0.3]
    out = np.array(out)
    a = out[np.argsort(out[:, 0], kind="stable")]
    b = out[rng.permutation(len(out))]
    b = b[np.argsort(b[:, 0], kind="stable")]
    for rows_, name in ((a, "a"), (b, "b")):
        np.savetxt(tmp_path / f"{name}.txt", rows_, fmt="%.2f", delimiter=",")
        code, _, err = run_cli(capsys, "track", "--detections", tmp_path / f"{name}.txt", "--out",
                               tmp_path / f"o{name}", "--fps", "30")
        assert code == 0, err
    assert (tmp_path / "oa" / "tracks.csv").read_bytes() == \
        (tmp_path / "ob" / "tracks.csv").read_bytes()


def test_detections_with_a_latin1_comment_or_an_odd_header(tmp_path, capsys):
    """A Latin-1 comment line gave a raw codec message, a header with 'conf%' was read as data
    ("non-numeric value 'frame'"); both are read now, and bad bytes in a data row name the line."""
    from aerotrack.io.mot import read_mot

    p = tmp_path / "d.txt"
    p.write_bytes("# détections de la caméra\nframe,id,x,y,w,h,conf%\n1,-1,10,10,8,4,0.9\n"
                  .encode("latin-1"))
    assert len(read_mot(p, option="--detections")) == 1
    h = tmp_path / "h.txt"  # a header whose cells hold spaces; a trailing comma after a row
    h.write_text("frame,id,bb_left (px),bb_top (px),w [px],h [px],score/1\n1,-1,10,10,8,4,0.9,\n")
    assert read_mot(h, option="--detections")[0, 6] == pytest.approx(0.9)
    u = tmp_path / "u16.txt"  # Windows "Unicode" text: UTF-16 with its byte order mark
    u.write_text("1,-1,10,10,8,4,0.9\n2,-1,11,10,8,4,0.9\n", encoding="utf-16")
    assert len(read_mot(u, option="--detections")) == 2
    q = tmp_path / "e.txt"
    q.write_bytes(b"1,-1,10,10,8,4,0.9\n2,-1,1\xe90,10,8,4,0.9\n")
    expect_error(capsys, ["--detections", "line 2", "non-numeric"], "track", "--detections", q,
                 "--out", tmp_path / "o", out_dir=tmp_path / "o")


def test_batch_fps_is_for_image_folders_and_keeps_a_videos_own_rate(tmp_path, capsys):
    """``batch --fps 10`` over a 25 frames/s video and an image folder tracked the video at 10
    frames/s too (speeds and every time window 2.5x off), so no mixed folder could be run right."""
    import cv2

    inputs = tmp_path / "in"
    write_frames(inputs / "seq", [textured(shift=(0, i)) for i in range(4)])
    h, w = textured().shape[:2]
    vw = cv2.VideoWriter(str(inputs / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
    for i in range(4):
        vw.write(textured(shift=(0, i)))
    vw.release()
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out, "--fps", "10")
    assert code == 0, err
    fps = {n: json.loads((out / n / "summary.json").read_text())["fps"] for n in ("seq", "clip")}
    assert fps == {"seq": 10.0, "clip": 25.0}
    assert "tracked at its own 25 frames/s" in err
    # run again with the same settings: both are finished with them, nothing is named
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out, "--fps", "10")
    assert code == 0 and "WARNING" not in err and err.count("already finished") == 2, err


def test_the_frame_rate_assumed_for_an_image_folder_is_named(tmp_path, capsys):
    """A 10 frames/s image sequence tracked without --fps was timed at 30 frames/s without a
    word (speeds and every time window 3x off)."""
    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(4)])
    code, _, err = run_cli(capsys, "detect", frames, "--out", tmp_path / "o")
    assert code == 0 and "timed at 30 frames/s (give --fps" in err, err
    code, _, err = run_cli(capsys, "detect", frames, "--out", tmp_path / "o2", "--fps", "10")
    assert code == 0 and "timed at" not in err, err


def test_resume_with_nothing_to_resume_says_so(tmp_path, capsys):
    """``--resume`` into a folder with no interrupted run (a typo in --out) ran from frame 1
    without a word."""
    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(4)])
    code, _, err = run_cli(capsys, "track", frames, "--out", tmp_path / "typo", "--resume")
    assert code == 0 and "no interrupted run there" in err, err
    assert (tmp_path / "typo" / "tracks.csv").is_file()


def test_track_from_names_stage_settings_it_cannot_apply(tmp_path, capsys):
    """``track --from DIR --set detection.window_s=2`` gave the cached run's tracks with no word
    and wrote window_s 2 into config.toml as if used."""
    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(4)])
    assert run_cli(capsys, "track", frames, "--out", tmp_path / "a")[0] == 0
    code, _, err = run_cli(capsys, "track", "--from", tmp_path / "a", "--out", tmp_path / "b",
                           "--set", "detection.window_s=2", "--set", "linking.max_cost=5")
    assert code == 0 and "detection.window_s differs" in err and "max_cost" not in err, err
    code, _, err = run_cli(capsys, "track", "--from", tmp_path / "a", "--out", tmp_path / "c",
                           "--set", "detection.min_conf=0.3")  # applied to the cached detections
    assert code == 0 and "differ" not in err, err


def test_track_from_a_damaged_stage_names_from_not_resume(tmp_path, capsys):
    """A truncated chunk in a run's stages/ stopped ``track --from`` with "--resume:
    checkpoint ... is unreadable", naming an option the user did not give."""
    frames = write_frames(tmp_path / "f", [textured(shift=(0, i)) for i in range(4)])
    assert run_cli(capsys, "track", frames, "--out", tmp_path / "a")[0] == 0
    (chunk,) = (tmp_path / "a" / "stages").glob("chunk_*.npz")
    chunk.write_bytes(chunk.read_bytes()[:200])
    expect_error(capsys, ["--from: cached stage", chunk.name, "unreadable"],
                 "track", "--from", tmp_path / "a", "--out", tmp_path / "b",
                 out_dir=tmp_path / "b")


def test_batch_never_deletes_inputs_or_files_it_did_not_write(tmp_path, capsys):
    """``batch same --out same`` deleted every image folder's frames (its results replaced
    them) and reported success; and an item's output folder was emptied of a user's notes."""
    inputs = tmp_path / "same"
    write_frames(inputs / "imgs", [textured(shift=(0, i)) for i in range(4)])
    write_frames(inputs / "other", [textured(shift=(i, 0)) for i in range(4)])
    code, _, err = run_cli(capsys, "batch", inputs, "--out", inputs)
    assert code == 2 and "apart from the inputs" in err and "Traceback" not in err, err
    assert len(list((inputs / "imgs").iterdir())) == 4
    out = tmp_path / "o"
    (out / "imgs").mkdir(parents=True)
    (out / "imgs" / "notes.txt").write_text("mine")
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out)
    assert code == 2 and "notes.txt" in err and "Traceback" not in err, err
    assert (out / "imgs" / "notes.txt").read_text() == "mine"
    assert (out / "other" / "summary.json").is_file()  # the other input is tracked
    # a finished folder made from another input of the same name is named, not trusted silently
    elsewhere = tmp_path / "elsewhere"
    write_frames(elsewhere / "other", [textured(shift=(i, i)) for i in range(4)])
    code, _, err = run_cli(capsys, "batch", elsewhere, "--out", out)
    assert code == 0 and "finished with other input" in err, err


def test_a_second_batch_into_the_same_out_is_refused(tmp_path, capsys):
    """Two batches into one --out took each other's running items for interrupted ones, tracked
    everything twice and could leave an item with summary.json but no stages/."""
    from aerotrack.cli.batch_cmd import lock_batch

    inputs = tmp_path / "in"
    write_frames(inputs / "clip", [textured(shift=(0, i)) for i in range(4)])
    out = tmp_path / "o"
    held = lock_batch(out)  # as a running batch holds it
    try:
        code, _, err = run_cli(capsys, "batch", inputs, "--out", out)
        assert code == 2 and "another batch is writing into it" in err, err
        assert not (out / "clip").exists()
    finally:
        held.close()
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out)  # released: it runs
    assert code == 0 and (out / "clip" / "summary.json").is_file(), err
    code, _, err = run_cli(capsys, "batch", inputs, "--out", out, "--overwrite")
    assert code == 0, err  # the lock file is aerotrack's own


def test_a_batch_runs_where_its_folder_cannot_be_locked(tmp_path, capsys, monkeypatch):
    """An NFS mount without a lock daemon raises ENOLCK from flock: the batch ran nothing and
    printed a traceback; it now warns that it is unguarded and runs."""
    import errno
    import fcntl

    def no_locks(fh, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    inputs = tmp_path / "in"
    write_frames(inputs / "clip", [textured(shift=(0, i)) for i in range(4)])
    code, _, err = run_cli(capsys, "batch", inputs, "--out", tmp_path / "o")
    assert code == 0 and "cannot lock .batch.lock (No locks available)" in err, err
    assert (tmp_path / "o" / "clip" / "summary.json").is_file()


def test_a_file_browser_s_clutter_is_not_a_user_s_file(tmp_path, capsys, dets):
    """Opening an output folder in macOS Finder leaves .DS_Store: --overwrite and a batch
    re-run refused the folder as holding a user's files."""
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "track", "--detections", dets, "--out", out)
    assert code == 0, err
    for name in (".DS_Store", "._tracks.csv", "Thumbs.db"):
        (out / name).write_bytes(b"\0\1")
    code, _, err = run_cli(capsys, "track", "--detections", dets, "--out", out, "--overwrite")
    assert code == 0, err
    assert not (out / ".DS_Store").exists()
    inputs = tmp_path / "in"
    write_frames(inputs / "clip", [textured(shift=(0, i)) for i in range(4)])
    (tmp_path / "b" / "clip").mkdir(parents=True)
    (tmp_path / "b" / "clip" / ".DS_Store").write_bytes(b"\0")
    code, _, err = run_cli(capsys, "batch", inputs, "--out", tmp_path / "b")
    assert code == 0 and (tmp_path / "b" / "clip" / "tracks.csv").is_file(), err


def test_ctrl_c_while_the_cli_loads_is_quiet(monkeypatch, capsys):
    """A Ctrl-C in the first second landed in an import and printed its traceback."""
    import sys
    import types

    from aerotrack.__main__ import run

    loading = types.ModuleType("aerotrack.cli.main")

    def interrupted(name):
        raise KeyboardInterrupt

    loading.__getattr__ = interrupted
    monkeypatch.setitem(sys.modules, "aerotrack.cli.main", loading)
    with pytest.raises(SystemExit) as exc:
        run()
    assert exc.value.code == 130 and capsys.readouterr().err == "aerotrack: interrupted\n"


@pytest.mark.parametrize("setting, fragments", [
    ("detection.model_scale=0", ["detection.model_scale", "must be in (0, 1]", "got 0.0"]),
    ("detection.shadow_beta=1.5", ["detection.shadow_beta", "must be in [0, 1]", "got 1.5"]),
    ("detection.sample_every_s=100", ["detection.sample_every_s", "at most detection.window_s"]),
    ("detection.persist_conf=2", ["detection.persist_conf", "must be in [0, 1]"]),
    ("linking.duplicate_overlap=7", ["linking.duplicate_overlap", "must be in [0, 1]"]),
    ("linking.rounds=0", ["linking.rounds", "must be >= 1"]),
    ("linking.stop_decel_mps2=0", ["linking.stop_decel_mps2", "must be > 0"]),
    ("linking.stop_max_turn_deg=200", ["linking.stop_max_turn_deg", "must be in [0, 180]"]),
])
def test_out_of_range_settings_name_their_range_even_with_external_detections(
        capsys, tmp_path, setting, fragments):
    """An out-of-range setting said "out of range (0.0)" without the range; a bad shadow_beta was
    reported as shadow_alpha; detection settings went unchecked with --detections (and with
    persistence off), so the run's config.toml failed when given to a video run; an overlap
    fraction of 7 and 0 linking rounds were taken."""
    dets = tmp_path / "dets.txt"
    dets.write_text("".join(f"{f},-1,{10 + 3 * f},20,12,6,0.9,-1,-1,-1\n" for f in range(1, 30)))
    out = tmp_path / "out"
    expect_error(capsys, fragments, "track", "--detections", dets, "--out", out,
                 "--set", setting, out_dir=out)


@pytest.mark.parametrize("text, extra, fragments", [
    ("frame_x,frame_y,ground_x,ground_y\n0,0,0,0\n10,0,1,0\n20,0,2,0\n30,0,3,0\n", [],
     ["--ground", "collinear"]),
    ("frame_x,frame_y,east,north\n0,0,0,0\n", [], ["--ground", "header must be"]),
    # a homography whose horizon crosses the frame: its far rows would turn inside out
    ("1 0 0\n0 1 0\n0 -0.05 1\n", [], ["--ground", "do not all land on the ground"]),
    ("0.1 0 0\n0 -0.1 0\n0 0 1\n", ["--gsd", "0.1"], ["--ground", "not with --gsd"]),
    ("0.1 0 0\n0 -0.1 0\n0 0 1\n", ["--stabilised"], ["--ground", "not with --stabilised"]),
])
def test_a_bad_ground_plane_is_one_line_before_any_work(capsys, tmp_path, video, text, extra,
                                                        fragments):
    """``--ground`` (an oblique view's ground plane without a map) is checked before --out is
    made: its format, collinear points, a horizon inside the frame, options it excludes."""
    ground = tmp_path / "ground.csv"
    ground.write_text(text)
    out = tmp_path / "out"
    expect_error(capsys, fragments, "track", video, "--out", out, "--ground", ground, *extra,
                 out_dir=out)


def test_a_ground_plane_is_checked_and_its_fit_reported(capsys, tmp_path, video):
    """A probe's wrong ground files ran without a word: frame points read off a 4K still,
    a mirrored plane (x and y swapped: headings off by 73 degrees), one point 3.4 m off the
    others, four points bunched in the middle of the frame. Now: refused, or named in a warning,
    and the fit is in summary.json."""
    def ground(rows):
        p = tmp_path / f"g{len(list(tmp_path.glob('g*.csv')))}.csv"
        p.write_text("frame_x,frame_y,ground_x,ground_y\n"
                     + "".join(f"{a},{b},{c},{d}\n" for a, b, c, d in rows))
        return p

    # 160x120 frames, 0.1 m per pixel, y north
    good = [(0, 0, 0, 12), (160, 0, 16, 12), (160, 120, 16, 0), (0, 120, 0, 0), (80, 60, 8, 6)]
    out = tmp_path / "o"
    expect_error(capsys, ["frame points outside frame 1 (160x120)"], "track", video, "--out", out,
                 "--ground", ground([(x * 4, y * 4, gx, gy) for x, y, gx, gy in good]),
                 out_dir=out)
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "a", "--ground",
                           ground(good))
    assert code == 0 and not any(w in err for w in ("mirrored", "off the plane", "points cover"))
    fit = json.loads((tmp_path / "a" / "summary.json").read_text())["ground_fit"]
    assert fit["points"] == 5 and fit["rms_m"] < 0.01 and fit["frame_cover"] > 0.9
    assert json.loads((tmp_path / "a" / "summary.json").read_text())["registration_mode"] == \
        "ground"
    mirrored = [(x, y, gy, gx) for x, y, gx, gy in good]
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "b", "--ground",
                           ground(mirrored))
    assert code == 0 and "the ground plane is mirrored" in err, err
    blunder = [*good[:4], (80, 60, 11, 6)]
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "c", "--ground",
                           ground(blunder))
    assert code == 0 and "point 5 is" in err and "off the plane the others make" in err, err
    bunched = [(70, 50, 7, 7), (90, 50, 9, 7), (90, 70, 9, 5), (70, 70, 7, 5)]
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "d", "--ground",
                           ground(bunched))
    assert code == 0 and "the points cover 2% of frame 1" in err, err


def test_an_implausible_vehicle_length_questions_the_scale():
    """A ground plane in orthophoto pixels made cars 15 m long and one given the wrong way round
    24-54 m, silently; so would a --gsd off by as much."""
    from types import SimpleNamespace

    from aerotrack.cli.hints import scale_hint
    from aerotrack.types import Track, TrackPoint

    def result(length_m):
        pts = [TrackPoint(frame=f, box=np.zeros(4), world=np.zeros(2), conf=1.0,
                          size_world=np.array([length_m, min(2.0, length_m / 2)]) / 0.5)
               for f in range(60)]
        return SimpleNamespace(metres_per_unit=0.5, tracks=[Track(1, pts)])

    assert scale_hint(result(4.5), "--gsd") is None
    assert "median 15.0 m long" in scale_hint(result(15.0), "--ground")
    assert "median 0.8 m long" in scale_hint(result(0.8), "--gsd")
    assert scale_hint(result(15.0), None) is None  # an estimated scale is not the user's


def test_a_stretch_without_detections_is_named_with_its_cause():
    """A registration reset restarts the background, and frames after it find nothing until it has
    samples: the probe's zoom clip had 11 such frames and no word of them anywhere."""
    from types import SimpleNamespace

    import numpy as np

    from aerotrack.cli.hints import detection_gap_hint
    from aerotrack.config import load_config
    from aerotrack.types import Registration

    class Dets:
        def __init__(self, frame, n):
            self.frame, self.n = frame, n

        def __len__(self):
            return self.n

    def result(zero, resets=()):
        dets = [Dets(f, 0 if f in zero else 5) for f in range(1, 91)]
        regs = {f: Registration(f, np.eye(3), "reset" if f in resets else "ok", 50, 0.9, 0.1,
                                "scene change; new reference" if f in resets else "")
                for f in range(1, 91)}
        return SimpleNamespace(detections=dets, registrations=regs, fps=30.0)

    cfg = load_config()
    hint = detection_gap_hint(result(range(40, 51), resets=(38, 47)), cfg)
    assert hint.startswith("frames 40-50 (11 frames) have no detection")
    assert "at frame 38 (scene change" in hint
    assert "started over" not in detection_gap_hint(result(range(40, 51)), cfg)
    assert detection_gap_hint(result(range(40, 45)), cfg) is None  # 5 frames: under 0.3 s
    assert detection_gap_hint(result(range(1, 30)), cfg) is None  # the first half window
    # an empty start or end (longer) does not hide a stretch in the middle
    both = detection_gap_hint(result([*range(1, 21), *range(40, 52), *range(71, 91)], (38,)), cfg)
    assert both.startswith("frames 40-51 (12 frames)") and "frame 38" in both
    # traffic thinning out to nothing and coming back is not a fault
    quiet = result(range(40, 51))
    for d in quiet.detections:
        if d.frame in (36, 37, 38, 39, 51, 52, 53, 54):
            d.n = 1
    assert detection_gap_hint(quiet, cfg) is None


def test_a_typo_frame_number_in_detections_is_pointed_out_once(tmp_path, capsys, caplog):
    """A detections file whose last row says frame 5000000 was tracked silently, through millions
    of empty frames. Now a warning names the line; and the command line's warnings about a file
    were printed twice (its check, then the pipeline's on the same rows): now once."""
    import logging

    from aerotrack.io.mot import check_detections, read_mot

    p = tmp_path / "dets.txt"
    p.write_text("".join(f"{f},-1,{10 + f},10,8,4,0.9\n" for f in range(1, 21))
                 + "5000000,-1,10,10,8,4,0.9\n")
    rows, lines = read_mot(p, option="--detections", strict=True, detections=True, lines=True)
    with caplog.at_level(logging.WARNING):
        check_detections(rows, f"--detections {p}", None, lines=lines)
        check_detections(rows, "detections", None)  # the same rows again: not warned twice
    jumps = [r.getMessage() for r in caplog.records if "a typo?" in r.getMessage()]
    assert len(jumps) == 1 and "frame 5000000 (line 21)" in jumps[0], jumps
    empty = tmp_path / "empty.txt"
    empty.write_text("")
    code, _, err = run_cli(capsys, "track", "--detections", empty, "--out", tmp_path / "o")
    assert code == 0 and err.count("no detections in the file") == 1, err


def test_a_full_disk_mid_run_is_one_line_error(tmp_path, capsys, monkeypatch):
    """synth (and demo) died with a traceback when the disk filled up while writing frames. The
    disk is filled here by making every frame write fail as a full disk does (ENOSPC): a real
    full file system needs a mount this test cannot make."""
    import errno

    def full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_bytes", full)
    expect_error(capsys, ["No space left on device", "000001.jpg"], "synth", "--out",
                 tmp_path / "s", "--frames", "5", out_dir=tmp_path / "s")


def test_options_that_need_another_are_refused_alone(tmp_path, capsys, video, run_dir, dets):
    """Options accepted without the one they apply to did nothing, silently; and count drew a
    run's lines and tracks over another video's first frame (render and report refused it)."""
    expect_error(capsys, ["--fix-gt", "--gt"], "report", run_dir, "--fix-gt", "--no-video")
    expect_error(capsys, ["--tolerance", "--gt"], "count", run_dir, "--line", "a:0,0,10,10",
                 "--tolerance", "3")
    expect_error(capsys, ["--detections-zero-based", "--detections"], "track", video, "--out",
                 tmp_path / "o", "--detections-zero-based", out_dir=tmp_path / "o")
    other = write_video(tmp_path / "other.avi", [textured(h=96, w=128, shift=(0, i))
                                                 for i in range(3)])
    expect_error(capsys, ["--input", "other.avi", "frames are 128x96"], "count", run_dir,
                 "--line", "a:0,0,10,10", "--input", other)
    expect_error(capsys, ["--input", "other.avi", "frames are 128x96"], "report", run_dir,
                 "--input", other, "--no-video")


def test_a_run_that_cannot_write_all_its_results_leaves_none(tmp_path, capsys, monkeypatch,
                                                             dets):
    """The disk filled up after tracks.csv and links.csv were written: they were left, with no
    summary.json. Results are now moved into --out together, once all are written."""
    from aerotrack.errors import OutputError
    from aerotrack.io.output import OutputDir

    real = OutputDir.write_text

    def full(self, name, text):
        if name == "summary.json":
            raise OutputError(f"{self.path / name}: cannot write (No space left on device)")
        return real(self, name, text)

    monkeypatch.setattr(OutputDir, "write_text", full)
    out = tmp_path / "o"
    code, _, err = run_cli(capsys, "track", "--detections", dets, "--out", out)
    assert code == 2 and "No space left on device" in err, err
    left = sorted(p.name for p in out.iterdir()) if out.exists() else []
    assert left in ([], [".partial"]), left  # no tracks.csv, links.csv, ... without summary.json


def test_a_region_of_interest_off_the_frame_is_pointed_out(tmp_path, capsys, video):
    """An --roi wholly outside the frame (coordinates in the wrong space) dropped every detection
    without a word."""
    roi = tmp_path / "roi.csv"
    roi.write_text("x,y\n10000,10000\n10100,10000\n10100,10100\n")
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "o", "--roi", roi)
    assert code == 0 and "lies wholly outside the 160x120 frame" in err, err
    inside = tmp_path / "in.csv"
    inside.write_text("x,y\n0,0\n100,0\n100,100\n")
    code, _, err = run_cli(capsys, "track", video, "--out", tmp_path / "o2", "--roi", inside)
    assert code == 0 and "wholly outside" not in err, err


def test_a_batch_input_that_fails_leaves_no_folder(tmp_path, capsys):
    """An image folder whose third image has another size failed (reported) but left
    OUT/<name>/.partial behind; `track` leaves nothing for a bad input, and so does batch now."""
    frames = [textured(shift=(0, i)) for i in range(4)]
    frames[2] = cv2.resize(frames[2], (80, 60))
    write_frames(tmp_path / "in" / "g", frames)
    code, _, err = run_cli(capsys, "batch", tmp_path / "in", "--out", tmp_path / "out")
    assert code == 2 and "g: failed:" in err and "expected 160x120" in err, err
    assert not (tmp_path / "out" / "g").exists()


def test_raw_detector_scores_say_what_becomes_of_them(tmp_path, capsys):
    """Raw scores (MOT17's DPM: -0.8 to 3.5) were clipped to [0, 1] with a warning that did not
    say the negative ones then fall under detection.min_conf and are dropped (19% of a file)."""
    p = tmp_path / "raw.txt"
    p.write_text("1,-1,10,10,8,4,-0.5\n1,-1,40,10,8,4,2.5\n2,-1,12,10,8,4,0.9\n")
    code, _, err = run_cli(capsys, "track", "--detections", p, "--out", tmp_path / "o")
    assert code == 0 and "the 1 below 0 become 0 and are dropped by detection.min_conf" in err, err


@pytest.mark.parametrize("argv", [
    ["track", "--detections", "DETS", "--out", ""],
    ["detect", "", "--out", "o"],
    ["eval", "--gt", "", "--pred", "DETS"],
    ["render", "o", "--out", ""],
    ["batch", "", "--out", "o"],
])
def test_an_empty_path_is_refused(tmp_path, capsys, dets, monkeypatch, argv):
    """`--out ""` (a script's unset variable) wrote the run into the current folder, and an empty
    input path was taken for the current folder: both are one-line errors now, nothing written."""
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, *[dets if a == "DETS" else a for a in argv])
    assert code == 2 and "empty path" in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dets.txt"]


def test_a_file_name_that_is_not_utf8_is_read(tmp_path, video):
    """A FAT card's or Windows zip's Latin-1 name ('v\\xeddeo') crashed OpenCV (a segfault, exit
    139, no message; in a batch, every input lost): the video and an image folder holding such a
    name are read like any other. Run in a child process, so that a crash fails the test."""
    import os
    import subprocess
    import sys

    odd = Path(os.fsdecode(b"v\xeddeo.avi"))
    try:
        os.rename(video, tmp_path / odd)
    except OSError:  # a file system that takes UTF-8 names only (macOS APFS)
        pytest.skip("this file system refuses names that are not UTF-8")
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(4):
        name = f"{i:03d}.png" if i != 2 else os.fsdecode(b"002\xf1.png")
        cv2.imwrite(str(tmp_path / "x.png"), textured(shift=(0, i)))
        os.rename(tmp_path / "x.png", folder / name)
    code = ("import sys; from aerotrack.io import open_source\n"
            "for p, fps in ((sys.argv[1], None), (sys.argv[2], 10)):\n"
            "    s = open_source(p, fps)\n"
            "    print(sum(1 for _ in s.frames()), s.size)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    res = subprocess.run([sys.executable, "-c", code, os.fsencode(tmp_path / odd),
                          os.fsencode(folder)], check=False, capture_output=True, env=env,
                         timeout=120)
    assert res.returncode == 0, (res.returncode, res.stderr[-800:])
    assert res.stdout.decode().split("\n")[:2] == ["6 (160, 120)", "4 (160, 120)"], res.stdout
    # and such a name in a report or table is written escaped, not a traceback
    from aerotrack.io.output import atomic_write_text

    atomic_write_text(tmp_path / "r.html", f"<p>{tmp_path / odd}</p>")
    assert b"v\\udceddeo.avi" in (tmp_path / "r.html").read_bytes()
    # threads opening such names at once (a dask worker's) each get their own link
    from concurrent.futures import ThreadPoolExecutor

    from aerotrack.io.frames import cv_path

    names = [tmp_path / os.fsdecode(b"n\xed%d.png" % i) for i in range(40)]
    for p in names:
        p.write_bytes(b"x")
    with ThreadPoolExecutor(4) as pool:
        links = list(pool.map(cv_path, names * 2))
    assert len(set(links)) == 40 and all(os.path.realpath(a) == os.path.realpath(b)
                                          for a, b in zip(links, names * 2))
    # and a map raster with such a name opens (rasterio stopped with a traceback)
    from aerotrack.geo import GeoMap

    m = tmp_path / os.fsdecode(b"m\xe1p.tif")
    os.rename(write_map(tmp_path / "m.tif"), m)
    assert GeoMap(m).width > 0

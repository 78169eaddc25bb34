"""The CLI frame: help, version, and one-line errors with exit code 2 for bad input."""

import json
import subprocess
import sys

import pytest

from aerotrack import __version__


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "aerotrack", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300, check=False)


def assert_one_line_error(res, *fragments):
    assert res.returncode == 2, res.stderr
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    assert "Traceback" not in res.stderr
    assert len(lines) == 1 or lines[-1].startswith(("Error", "aerotrack: error")), res.stderr
    for f in fragments:
        assert f in res.stderr, res.stderr


def test_help_and_version():
    res = run("--help")
    assert res.returncode == 0 and "track" in res.stdout
    res = run("--version")
    assert res.returncode == 0 and __version__ in res.stdout
    res = run("track", "--help")
    assert res.returncode == 0 and "Examples" in res.stdout


def test_track_missing_input(tmp_path):
    assert_one_line_error(run("track", tmp_path / "nope.mp4", "--out", tmp_path / "o"), "nope.mp4")


def test_track_needs_input_or_detections(tmp_path):
    assert_one_line_error(run("track", "--out", tmp_path / "o"), "--detections")


def test_track_map_without_init(tmp_path):
    d = tmp_path / "d.txt"
    d.write_text("1,-1,1,1,5,5,1\n")
    assert_one_line_error(run("track", "--detections", d, "--map", d, "--out", tmp_path / "o"),
                          "--map-init")


@pytest.mark.parametrize("text,frag", [
    ("1,-1,1,1,5\n", "line 1"),
    ("1,-1,1,1,-5,5,1\n", "negative"),
    ("1,-1,x,1,5,5,1\n", "non-numeric"),
    ("1,,1,1,5,5,1\n", "empty field"),
])
def test_track_bad_detections(tmp_path, text, frag):
    d = tmp_path / "d.txt"
    d.write_text(text)
    res = run("track", "--detections", d, "--out", tmp_path / "o")
    assert_one_line_error(res, "--detections", frag)
    assert not (tmp_path / "o" / "tracks.csv").exists()


def test_out_folder_with_results_refused(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "tracks.csv").write_text("")
    d = tmp_path / "d.txt"
    d.write_text("1,-1,1,1,5,5,1\n")
    assert_one_line_error(run("track", "--detections", d, "--out", out), "--overwrite")


def test_unknown_config_parameter(tmp_path):
    d = tmp_path / "d.txt"
    d.write_text("1,-1,1,1,5,5,1\n")
    res = run("track", "--detections", d, "--out", tmp_path / "o", "--set", "detection.bogus=1")
    assert_one_line_error(res, "detection.bogus")


def test_bad_fps(tmp_path):
    d = tmp_path / "d.txt"
    d.write_text("1,-1,1,1,5,5,1\n")
    assert_one_line_error(run("track", "--detections", d, "--out", tmp_path / "o", "--fps", "-3"),
                          "--fps")


def moving_detections(path, n_frames, n_targets=6):
    rows = [f"{f},-1,{20 + k * 90 + (f * 0.7) % 400:.2f},{30 + k * 60},12,6,0.9"
            for f in range(1, n_frames + 1) for k in range(n_targets)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_text_file_as_video_is_one_line(tmp_path):
    """FFmpeg's own complaint ("moov atom not found") is not printed beside ours."""
    v = tmp_path / "notes.mp4"
    v.write_text("not a video\n" * 50)
    res = run("track", v, "--out", tmp_path / "o")
    assert_one_line_error(res, "notes.mp4")
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert not (tmp_path / "o").exists()


def test_progress_only_on_a_terminal_or_with_verbose(tmp_path):
    d = moving_detections(tmp_path / "d.txt", 40)
    res = run("track", "--detections", d, "--out", tmp_path / "a")  # stderr is a pipe here
    assert res.returncode == 0, res.stderr
    assert "frames (" not in res.stderr and "aerotrack: 40 frames" in res.stderr
    res = run("-v", "track", "--detections", d, "--out", tmp_path / "b")
    assert res.returncode == 0 and "track: 40/40 frames (" in res.stderr, res.stderr


def test_sigterm_stops_like_ctrl_c_and_resume_finishes(tmp_path):
    import signal
    import time

    d = moving_detections(tmp_path / "d.txt", 500)
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "aerotrack", "-v", "track", "--detections",
                             str(d), "--out", str(out)], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    line = ""
    while time.time() < deadline and "frames (" not in line:  # the first progress line: 10%
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
    if proc.poll() is not None:
        pytest.skip("the run finished before it could be stopped")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err and "--resume" in err
    assert sorted(p.name for p in out.iterdir()) == [".partial"]  # nothing that looks complete
    assert not list(out.rglob("*.tmp"))
    res = run("-q", "track", "--detections", d, "--out", out, "--resume")
    assert res.returncode == 0, res.stderr
    assert json.loads((out / "summary.json").read_text())["frames"] == 500
    assert not (out / ".partial").exists()


def test_bare_command_shows_the_help():
    res = run()
    assert "Usage: aerotrack" in res.stdout + res.stderr and "track" in res.stdout + res.stderr
    assert "Traceback" not in res.stderr


def _panning_video(path):
    """1500 frames (50 s at 30 frames/s) of a camera panning over blurred noise: a run on it
    lasts long enough to be stopped or raced."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 255, (200, 900, 3), dtype=np.uint8), (0, 0), 2)
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (240, 180))
    for i in range(1500):
        vw.write(np.ascontiguousarray(base[10:190, (i // 3) % 600:(i // 3) % 600 + 240]))
    vw.release()
    return path


def _wait_for_work(out, proc, settle_s: float) -> None:
    """Until the run ``proc`` has made ``out/.partial`` (at most 60 s), then ``settle_s`` more."""
    import time

    deadline = time.time() + 60
    while time.time() < deadline and not (out / ".partial").exists() and proc.poll() is None:
        time.sleep(0.1)
    time.sleep(settle_s)


def test_sigterm_during_detect_keeps_the_finished_frames(tmp_path):
    """detect cannot resume, but an interruption keeps what was final: detections.csv holds the
    frames the detector had finished, written whole (no .partial left), exit 128 + signal."""
    import signal


    video = _panning_video(tmp_path / "v.avi")
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "aerotrack", "detect", str(video), "--out",
                             str(out)], stderr=subprocess.PIPE, text=True)
    _wait_for_work(out, proc, settle_s=1.0)
    if proc.poll() is not None:
        pytest.skip("detect finished before it could be stopped")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err and "interrupted" in err and "finished frames" in err
    assert not (out / ".partial").exists()
    from aerotrack.io.mot import read_mot

    rows = read_mot(out / "detections.csv")
    assert (out / "config.toml").exists() and (out / "registration.csv").exists()
    if len(rows):
        assert rows[:, 0].max() < 1500
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted_at_frame"] < 1500
    assert summary["counts"]["detections"] == len(rows)
    # the finished frames, not the frames read (they said 1-91 with detections to 46: a probe)
    assert summary["frames_read"] == summary["interrupted_at_frame"]
    if len(rows):
        assert summary["last_frame"] >= rows[:, 0].max() and summary["last_frame"] <= \
            summary["frames_read"]


def test_detections_alone_write_identity_registrations(tmp_path, capsys):
    """The contract lists registration.csv for every track run: without frames, every frame of
    the detections is registered by the identity (world = the detections' pixels), flagged as such
    in the file and in summary.json."""
    from conftest import run_cli

    d = tmp_path / "d.txt"
    d.write_text("".join(f"{f},-1,{10 + 3 * f},20,8,4,0.9\n" for f in (1, 2, 3, 5, 6)))
    code, _, err = run_cli(capsys, "-q", "track", "--detections", d, "--out", tmp_path / "o",
                           "--frames", "2:6")
    assert code == 0, err
    lines = (tmp_path / "o" / "registration.csv").read_text().splitlines()
    assert lines[0].startswith("frame,h00,h01,h02,h10,h11,h12,h20,h21,h22,status")
    rows = [ln.split(",") for ln in lines[1:]]
    assert [int(r[0]) for r in rows] == [2, 3, 4, 5, 6]  # every frame processed, gaps included
    for r in rows:
        assert [float(v) for v in r[1:10]] == [1, 0, 0, 0, 1, 0, 0, 0, 1]
        assert r[10] == "identity"
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["registration_mode"] == "identity"
    assert summary["counts"]["registered_frames"] == 0 and not summary["registration_failures"]
    # an empty detections file: no frames, a header-only registration.csv
    e = tmp_path / "e.txt"
    e.write_text("")
    code, _, err = run_cli(capsys, "-q", "track", "--detections", e, "--out", tmp_path / "p")
    assert code == 0, err
    assert (tmp_path / "p" / "registration.csv").read_text().startswith("frame,h00")
    assert json.loads((tmp_path / "p" / "summary.json").read_text())["registration_mode"] == "identity"


@pytest.mark.parametrize("where", ["before", "after"])
def test_verbose_and_quiet_work_after_the_subcommand_too(tmp_path, capsys, where):
    from conftest import run_cli

    d = tmp_path / "d.txt"
    d.write_text("".join(f"{f},-1,{10 + 2 * f},10,8,4,0.9\n" for f in range(1, 21)))

    def track(flag, out):
        argv = ["track", "--detections", d, "--out", tmp_path / out]
        return run_cli(capsys, *([flag, *argv] if where == "before" else [*argv, flag]))

    code, _, err = track("-v", "v")
    assert code == 0 and "INFO: track: 20/20 frames" in err, err  # progress lines off a terminal
    code, _, err = track("-q", "q")
    assert code == 0 and err == "", err
    code, _, err = track("--verbose", "v2")
    assert code == 0 and "INFO" in err, err


def test_opencv_warnings_silenced_unless_vv(tmp_path):
    """OpenCV was imported before logging was set up, so OPENCV_LOG_LEVEL came too late and
    libtiff's warnings about GeoTIFF tags reached stderr on every frame of a GeoTIFF folder."""
    import warnings

    import numpy as np
    import rasterio
    from rasterio.transform import from_origin

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for i in (1, 2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(frames / f"{i:03d}.tif", "w", driver="GTiff", width=96, height=64,
                               count=3, dtype="uint8", crs="EPSG:32611",
                               transform=from_origin(660000, 4000000, 0.3, 0.3)) as ds:
                ds.write(rng.integers(0, 255, (3, 64, 96), dtype=np.uint8))
    import os

    # in-process CLI tests set these in this process; a user's environment does not have them
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENCV_LOG_LEVEL", "OPENCV_FFMPEG_LOGLEVEL")}

    def detect(out, *flags):
        return subprocess.run([sys.executable, "-m", "aerotrack", "detect", str(frames), "--out",
                               str(out), *flags], capture_output=True, text=True, env=env,
                              timeout=300, check=False)

    res = detect(tmp_path / "a")
    # (aerotrack's own warnings, e.g. the clip's hints, are "WARNING:"; OpenCV's "[ WARN")
    assert res.returncode == 0 and "[ WARN" not in res.stderr and "TIFF" not in res.stderr, \
        res.stderr
    res = detect(tmp_path / "b", "-vv")
    assert res.returncode == 0 and "TIFF" in res.stderr, res.stderr  # -vv shows them


def test_verbose_progress_lines_say_the_time_left_and_come_at_least_every_30_s(monkeypatch):
    """``-v`` away from a terminal logged a line every tenth of the run only (one a minute on a
    long one, the first after 75 s) and no time left."""
    import logging

    from aerotrack.cli import common

    clock = [0.0]
    monkeypatch.setattr(common.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(common.sys.stderr, "isatty", lambda: False, raising=False)
    lines = []

    class Keep(logging.Handler):
        def emit(self, record):
            lines.append(record.getMessage())

    handler = Keep()
    logger = logging.getLogger("aerotrack")
    monkeypatch.setattr(logger, "level", logging.INFO)
    logger.addHandler(handler)
    try:
        update, close = common.make_progress(1000, "track", quiet=False, verbose=1)
        for n in range(1, 51):  # 50 frames, 1 s each
            clock[0] = float(n)
            update(n)
        # then 3 s a frame: the time left follows the rate since the last line
        for n in range(51, 111):
            clock[0] = 50.0 + 3.0 * (n - 50)
            update(n)
        close()
    finally:
        logging.getLogger("aerotrack").removeHandler(handler)
    assert lines[0] == "track: 30/1000 frames (1.0 frames/s, about 16 min left)"
    # at frame 110 (230 s, 3 s a frame since the last line): 890 frames at 1/3 frame/s, not at
    # the 0.5 frames/s of the whole run (30 min)
    assert lines[-1] == "track: 110/1000 frames (0.5 frames/s, about 44 min left)"


def test_config_toml_names_the_options_that_repeat_the_run(tmp_path):
    """config.toml alone did not repeat a run made with --seed/--fps/--gsd (a user's --config of it
    gave other tracks): its first line names them, and it still loads as a config."""
    from aerotrack.config import load_config

    d = tmp_path / "d.txt"
    d.write_text("".join(f"{f},-1,{10 + 2 * f},20,8,4,0.9\n" for f in range(1, 20)))
    res = run("track", "--detections", d, "--out", tmp_path / "o", "--fps", "10", "--seed", "3",
              "--gsd", "0.15")
    assert res.returncode == 0, res.stderr
    text = (tmp_path / "o" / "config.toml").read_text()
    assert text.splitlines()[0].startswith("# run with: --seed 3 --fps 10 --gsd 0.15"), text
    load_config(tmp_path / "o" / "config.toml")


def test_config_lists_every_setting_with_its_default_and_meaning(capsys, tmp_path):
    """110 of 289 settings were described only in config.py: ``aerotrack config`` prints each
    with its default and first sentence as a config file that loads back, describes one in full,
    and shows a run's config.toml values."""
    from conftest import run_cli

    from aerotrack.config import Config, config_to_dict, load_config

    code, out, err = run_cli(capsys, "config")
    assert code == 0, err
    every = [f"{s}.{k}" for s, t in config_to_dict(Config()).items() for k in t]
    keys = [ln.split(" = ")[0] for ln in out.splitlines() if " = " in ln and not ln.startswith("#")]
    assert len(keys) == len(every)
    comments = [ln for ln in out.splitlines() if ln.startswith("# ")][1:]
    assert len(comments) == len(every) and all(len(c) > 6 for c in comments)
    (tmp_path / "all.toml").write_text(out)
    assert load_config(tmp_path / "all.toml") == Config()
    code, out, _ = run_cli(capsys, "config", "linking.rounds")
    assert code == 0 and out.startswith("linking.rounds = 2\n") and "relink" in out
    (tmp_path / "mine.toml").write_text("[linking]\nrounds = 3\n")
    code, out, _ = run_cli(capsys, "config", "linking", "--config", tmp_path / "mine.toml")
    assert code == 0 and "\nrounds = 3\n" in out and "[detection]" not in out
    code, _, err = run_cli(capsys, "config", "detection.min_area")
    assert code == 2 and "did you mean detection.min_area_px" in err


def test_memory_warning_counts_every_worker(caplog):
    """Each --workers process holds its own detector window: the warning's estimate is per
    worker times the workers (a 4K survey probe peaked at 6.3 GB with 2 workers, 3.4 GB in one
    process, while the warning, told of neither, estimated 2.5 GB)."""
    import logging
    import os
    from types import SimpleNamespace

    from aerotrack.cli.track_cmd import warn_memory

    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    src = SimpleNamespace(size=(3840, 2160), fps=30.0, path="survey.mp4")
    one = 1.5 * 3840 * 2160 * 3 * 30.0 * 3.0  # bytes held at the peak by one process
    share = 1.5 * one / total  # one process stays under, two go over
    with caplog.at_level(logging.WARNING, logger="aerotrack"):
        warn_memory(src, 3.0, share=share, workers=1)
        assert not caplog.records
        warn_memory(src, 3.0, share=share, workers=2)
    assert len(caplog.records) == 1
    msg = caplog.records[0].getMessage()
    assert "in each of 2 workers" in msg and "fewer --workers" in msg and "survey.mp4" in msg


def test_numba_gets_a_cache_folder_when_the_install_and_home_are_read_only(tmp_path,
                                                                           monkeypatch):
    """A read-only install run with no writable home (a container's ``nobody``): numba raised
    "cannot cache function" at import and ``track`` stopped with a traceback (an ops probe)."""
    import aerotrack

    env = {"HOME": "/nonexistent", "XDG_CACHE_HOME": "/proc/nonexistent"}
    monkeypatch.setattr("os.access", lambda path, mode: False)
    aerotrack._numba_cache_fallback(str(tmp_path), env)
    assert env["NUMBA_CACHE_DIR"].startswith(__import__("tempfile").gettempdir())
    kept = {"NUMBA_CACHE_DIR": "/mine"}
    aerotrack._numba_cache_fallback(str(tmp_path), kept)
    assert kept["NUMBA_CACHE_DIR"] == "/mine"


def test_a_second_run_into_a_folder_being_written_is_refused(tmp_path):
    """A run still going was called "an interrupted run", and its advice (--resume, --overwrite)
    ran two at once into one folder, the first one's results silently replaced (an ops probe).
    Once the first has stopped, its .partial/ is an interrupted run again."""
    import signal


    video = _panning_video(tmp_path / "v.avi")
    out = tmp_path / "o"
    argv = [sys.executable, "-m", "aerotrack", "-q", "track", str(video), "--out", str(out)]
    first = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
    _wait_for_work(out, first, settle_s=0.5)
    if first.poll() is not None:
        pytest.skip("the first run finished before the second started")
    try:
        second = subprocess.run([*argv, "--overwrite"], capture_output=True, text=True,
                                timeout=120, check=False)
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=120)
    assert second.returncode == 2, second.stderr
    assert f"another aerotrack (process {first.pid}) is writing into it" in second.stderr
    again = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert again.returncode == 2 and "holds an interrupted run" in again.stderr, again.stderr

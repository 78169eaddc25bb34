"""The CLI frame: help, version, and one-line errors with exit code 2 for bad input."""

import subprocess
import sys

import pytest

from aerotrack import __version__


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "aerotrack", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


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
    ("1,3,1,1,5,5,1\n1,3,1,1,5,5,1\n", "repeated"),
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

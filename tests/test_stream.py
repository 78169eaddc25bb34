"""A live network stream as INPUT (``aerotrack track rtsp://...``), served here over HTTP on
loopback: FFmpeg reads it as it reads any stream, without seeking and without a length."""

from __future__ import annotations

import contextlib
import functools
import http.server
import threading

import cv2
import pytest
from conftest import run_cli

from aerotrack.io import open_source
from aerotrack.io.frames import StreamSource, is_stream_url


@contextlib.contextmanager
def served(folder):
    """``folder`` over HTTP on 127.0.0.1; yields the base URL."""
    handler = functools.partial(_Quiet, directory=str(folder))
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{srv.server_address[1]}"
    finally:
        srv.shutdown()
        srv.server_close()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # no access log on stderr
        pass


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 90-frame MPEG transport stream of a rendered scene (a stream's container: it plays
    from any point without an index)."""
    from test_parallel import render_scene

    folder = tmp_path_factory.mktemp("stream")
    render_scene(folder / "frames", n=90, n_cars=4)
    frames = sorted((folder / "frames").glob("*.png"))
    first = cv2.imread(str(frames[0]))
    writer = cv2.VideoWriter(str(folder / "clip.ts"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0,
                             (first.shape[1], first.shape[0]))
    for p in frames:
        writer.write(cv2.imread(str(p)))
    writer.release()
    return folder


def test_urls_are_streams_and_paths_are_not():
    assert is_stream_url("rtsp://10.0.0.2:8554/live") and is_stream_url("UDP://@:1234")
    assert not is_stream_url("flight.mp4") and not is_stream_url("C://videos/a.mp4")


def test_a_stream_reads_every_frame_once_in_order(clip):
    with served(clip) as base:
        src = open_source(f"{base}/clip.ts")
        assert isinstance(src, StreamSource) and src.count is None and src.fps == 30.0
        frames = list(src.frames(stop=40, stride=3))
    assert [f.index for f in frames] == list(range(1, 41, 3))
    local = {f.index: f.image for f in open_source(clip / "clip.ts").frames(stop=40)}
    assert all((f.image == local[f.index]).all() for f in frames)


def test_track_on_a_stream_equals_track_on_the_file(tmp_path, capsys, clip):
    with served(clip) as base:
        url = f"{base}/clip.ts"
        code, _, err = run_cli(capsys, "track", url, "--out", tmp_path / "live")
        assert code == 0, err
        for extra, needle in [(("--resume",), "--resume: not with a live stream"),
                              (("--workers", "2"), "--workers: not with a live stream"),
                              (("--frames", "5:20"), "it starts at its first")]:
            code, _, err = run_cli(capsys, "track", url, "--out", tmp_path / "x", *extra)
            assert code == 2 and needle in err, err
    code, _, err = run_cli(capsys, "track", clip / "clip.ts", "--out", tmp_path / "file")
    assert code == 0, err
    live = (tmp_path / "live" / "tracks.csv").read_bytes()
    assert live == (tmp_path / "file" / "tracks.csv").read_bytes() and live.count(b"\n") > 30
    assert '"input": "http://127.0.0.1:' in (tmp_path / "live" / "summary.json").read_text()


def test_a_stream_nobody_sends_is_one_line(tmp_path, capsys):
    code, _, err = run_cli(capsys, "track", "http://127.0.0.1:9/none.ts", "--out", tmp_path / "o")
    assert code == 2 and "cannot open the stream" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_why_a_stream_does_not_open_is_named(tmp_path, capsys):
    """Refused, unknown host, an HTTP error and a server without video were one message."""
    (tmp_path / "notes.txt").write_text("not a video\n" * 50)
    (tmp_path / "junk.bin").write_bytes(bytes(range(256)) * 64)
    with served(tmp_path) as base:
        port = base.rsplit(":", 1)[1]
        for url, needle in [(f"{base}/missing.ts", "answers HTTP 404"),
                            (f"{base}/junk.bin", "answers, but with no video FFmpeg can read"),
                            (f"{base}/notes.txt", "is text (a web page?), not a video stream"),
                            (f"rtsp://127.0.0.1:{port}/live", f"127.0.0.1:{port} answers, but"),
                            ("rtsp://127.0.0.1:9/live", "127.0.0.1:9 refuses the connection"),
                            ("rtmp://no-such-host.invalid/app", "no-such-host.invalid is not known"),
                            ("tcp://127.0.0.1", "names no port")]:
            code, _, err = run_cli(capsys, "track", url, "--out", tmp_path / "o")
            assert code == 2 and needle in err and len(err.strip().splitlines()) == 1, (url, err)
    assert not (tmp_path / "o").exists()


def test_detect_on_a_stream(tmp_path, capsys, clip):
    with served(clip) as base:
        code, _, err = run_cli(capsys, "detect", f"{base}/clip.ts", "--out", tmp_path / "d",
                               "--frames", ":60")
        assert code == 0, err
        code, _, err = run_cli(capsys, "detect", f"{base}/clip.ts", "--out", tmp_path / "e",
                               "--frames", "10:60")
        assert code == 2 and "it starts at its first" in err
    rows = (tmp_path / "d" / "detections.csv").read_text().splitlines()
    assert rows and max(int(r.split(",")[0]) for r in rows) <= 60


def test_a_run_says_when_it_falls_behind_the_feed(clip, monkeypatch):
    import logging
    import time

    from aerotrack.io import frames as frames_mod

    monkeypatch.setattr(frames_mod, "STREAM_LAG_WARN_S", 0.2)
    seen: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            seen.append(record.getMessage())

    log = logging.getLogger("aerotrack.io.frames")
    handler = Keep(level=logging.WARNING)
    log.addHandler(handler)
    try:
        with served(clip) as base:
            for f in open_source(f"{base}/clip.ts").frames(stop=20):
                time.sleep(0.05)  # 20 frames/s of work on a 30 frames/s feed
    finally:
        log.removeHandler(handler)
    assert any("behind real time" in m for m in seen), seen


def test_a_stream_finishes_on_interrupt_by_default(tmp_path, capsys):
    with served(tmp_path) as base:
        code, _, err = run_cli(capsys, "track", f"{base}/x.ts", "--out", tmp_path / "o",
                               "--on-interrupt", "keep")
    assert code == 2 and "--on-interrupt keep: not with a live stream" in err


def test_ctrl_c_on_a_stream_writes_the_results_so_far(tmp_path, capsys, clip, monkeypatch):
    """A stream cannot be resumed: Ctrl-C finishes the run by default (it kept a .partial/ that
    --resume then refused)."""
    import json

    from conftest import ctrl_c_track_at

    ctrl_c_track_at(monkeypatch, 40)
    with served(clip) as base:
        code, _, err = run_cli(capsys, "track", f"{base}/clip.ts", "--out", tmp_path / "o")
    assert code == 0, err
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["interrupted_at_frame"] == 40
    assert (tmp_path / "o" / "tracks.csv").is_file() and not (tmp_path / "o" / ".partial").exists()

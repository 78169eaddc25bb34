"""Interruption and --resume: finished work survives Ctrl-C and the resumed run matches."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from aerotrack.cli.main import main
from aerotrack.io.mot import read_mot, write_mot
from aerotrack.io.output import OutputDir
from aerotrack.pipeline import run


def detections(n_frames=240, n_targets=6, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n_targets):
        p = rng.uniform(50, 400, 2)
        v = rng.uniform(-3, 3, 2)
        for f in range(1, n_frames + 1):
            if rng.random() < 0.1:
                continue
            c = p + v * f + rng.normal(0, 0.5, 2)
            rows.append([f, -1, c[0] - 8, c[1] - 4, 16, 8, 0.9, -1, -1, -1])
    return np.array(rows)


class Stop(Exception):
    pass


def interrupt_at(n):
    def progress(done):
        if done == n:
            raise KeyboardInterrupt

    return progress


def test_resume_after_interrupt_gives_the_same_tracks(tmp_path):
    dets = detections()
    full = run(None, detections=dets, fps=30.0, seed=3)
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        run(None, detections=dets, fps=30.0, seed=3, checkpoint_dir=out.partial,
            checkpoint_every=50, progress=interrupt_at(130))
    chunks = sorted(out.partial.glob("chunk_*.npz"))
    assert len(chunks) >= 2  # periodic checkpoints plus the one written on interrupt
    resumed = run(None, detections=dets, fps=30.0, seed=3, checkpoint_dir=out.partial,
                  checkpoint_every=50, resume=True)

    def rows(result):
        return sorted((t.id, p.frame, round(float(p.world[0]), 6), round(float(p.world[1]), 6))
                      for t in result.tracks for p in t.points)

    assert resumed.frames == full.frames
    assert rows(resumed) == rows(full)


def test_cli_ctrl_c_keeps_partial_and_resume_finishes(tmp_path):
    d = tmp_path / "d.txt"
    write_mot(d, detections(n_frames=3000, n_targets=8))
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "aerotrack", "track", "--detections", str(d),
                             "--out", str(out)], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 240
    while time.time() < deadline and not list((out / ".partial").glob("chunk_*.npz")):
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    if proc.poll() is not None:
        pytest.skip("the run finished before it could be interrupted")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "--resume" in err
    assert not (out / "tracks.csv").exists()  # nothing that looks complete
    assert list((out / ".partial").glob("chunk_*.npz"))
    with pytest.raises(SystemExit) as exc:
        main(["track", "--detections", str(d), "--out", str(out)])
    assert exc.value.code == 2  # refused without --resume
    main(["-q", "track", "--detections", str(d), "--out", str(out), "--resume"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 3000
    assert len(read_mot(out / "tracks.csv")) > 0
    assert not (out / ".partial").exists()


def test_track_from_cached_stages(tmp_path, capsys):
    d = tmp_path / "d.txt"
    write_mot(d, detections(n_frames=150))
    first = tmp_path / "first"
    main(["-q", "track", "--detections", str(d), "--out", str(first)])
    assert list((first / "stages").glob("chunk_*.npz"))
    again = tmp_path / "again"
    main(["-q", "track", "--from", str(first), "--out", str(again)])
    assert (again / "tracks.csv").read_text() == (first / "tracks.csv").read_text()
    other = tmp_path / "other"
    main(["-q", "track", "--from", str(first), "--out", str(other), "--set",
          "association.min_length_s=2.0"])
    assert "min_length_s = 2.0" in (other / "config.toml").read_text()
    assert len(read_mot(other / "tracks.csv")) <= len(read_mot(first / "tracks.csv"))
    with pytest.raises(SystemExit) as exc:
        main(["track", "--from", str(tmp_path / "nothing"), "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    assert "no cached stages" in capsys.readouterr().err


# -- finished tracklets spilled to disk until linking ---------------------------------------------
def _points(tracks):
    """Every field of every point, arrays as (dtype, shape, bytes): equal only when identical."""
    def arr(a):
        if a is None:
            return None
        a = np.asarray(a)
        return (str(a.dtype), a.shape, a.tobytes())

    return [(t.id, [(p.frame, arr(p.box), arr(p.world), p.conf, p.kind, p.det_index,
                     arr(p.size_world), arr(p.hist), arr(p.desc)) for p in t.points])
            for t in tracks]


def test_spilled_tracklets_come_back_exactly(tmp_path):
    from aerotrack.io.checkpoint import TrackletSpill
    from aerotrack.types import Track, TrackPoint

    rng = np.random.default_rng(0)
    tracks = []
    for k in range(7):
        pts = []
        for f in range(10 + k, 30 + 2 * k):
            observed = f % 4 != 0
            pts.append(TrackPoint(
                frame=f, box=rng.normal(size=4), world=rng.normal(size=2), conf=float(rng.random()),
                kind="observed" if observed else ("bridged" if k % 2 else "stationary"),
                det_index=int(rng.integers(0, 9)) if observed else -1,
                size_world=rng.normal(size=2) if f % 3 else None,
                hist=rng.random(12).astype(np.float32) if observed and f % 2 else None,
                desc=rng.random(20) if observed and k == 3 else None))
        tracks.append(Track(k + 1, pts))
    spill = TrackletSpill(tmp_path / "spill", chunk=3)
    spill.extend(tracks)
    assert len(spill) == 7
    assert len(list((tmp_path / "spill").glob("spill_*.npz"))) == 2  # 6 on disk, 1 buffered
    back = spill.load()
    assert _points(back) == _points(tracks)
    spill.close()
    assert not (tmp_path / "spill").exists()


def test_tracks_are_identical_with_and_without_spilling(tmp_path):
    """A real run on rendered frames (appearance included): spilling changes nothing."""
    from test_parallel import FPS, render_scene

    from aerotrack.config import Config
    from aerotrack.io import open_source
    from aerotrack.pipeline import Pipeline

    frames = tmp_path / "frames"
    render_scene(frames, n=80, n_cars=5)
    out = {}
    for spill in (False, True):
        pipe = Pipeline(Config(), FPS, metres_per_unit=0.3, spill=spill)
        if spill:
            pipe.tracklets.chunk = 2  # several files even on a short run
        for frame in open_source(frames, FPS).frames():
            pipe.step(frame)
        out[spill] = pipe.finish()
    assert any(p.hist is not None for t in out[True].tracks for p in t.points)
    assert len(out[True].tracks) >= 3
    assert _points(out[True].tracks) == _points(out[False].tracks)


def test_a_resumed_run_drops_the_spill_files_of_the_interrupted_one(tmp_path):
    from aerotrack.io.checkpoint import TrackletSpill
    from aerotrack.types import Track, TrackPoint

    folder = tmp_path / ".partial" / "tracklets"
    first = TrackletSpill(folder, chunk=1)
    first.append(Track(1, [TrackPoint(1, np.zeros(4), np.zeros(2), 1.0)]))
    assert len(list(folder.glob("spill_*.npz"))) == 1  # interrupted here: never closed
    again = TrackletSpill(folder, chunk=8)
    again.append(Track(2, [TrackPoint(3, np.ones(4), np.ones(2), 0.5)]))
    assert [t.id for t in again.load()] == [2]
    again.close()
    assert not folder.exists()

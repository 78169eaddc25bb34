"""Interruption and --resume: finished work survives Ctrl-C and the resumed run matches."""

from __future__ import annotations

import contextlib
import json
import logging
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
    write_mot(d, detections(n_frames=1500, n_targets=8))
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "aerotrack", "track", "--detections", str(d),
                             "--out", str(out)], stderr=subprocess.PIPE, text=True)
    # interrupt once the run is under way (its manifest is written just before the frames
    # start): waiting for the first periodic checkpoint let a fast run finish first (a skip)
    deadline = time.time() + 240
    while time.time() < deadline and not (out / ".partial" / "run.json").exists():
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    time.sleep(0.5)
    if proc.poll() is not None:
        proc.communicate()  # close the pipe (else a ResourceWarning fails a later test)
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
    # what the run was started with is unreadable: its checkpoints cannot be checked (they were
    # continued with whatever was given, another --seed included)
    manifest = out / ".partial" / "run.json"
    kept = manifest.read_bytes()
    manifest.write_text("{garbage")
    with pytest.raises(SystemExit) as exc:
        main(["-q", "track", "--detections", str(d), "--out", str(out), "--resume", "--seed", "7"])
    assert exc.value.code == 2
    manifest.write_bytes(kept)
    main(["-q", "track", "--detections", str(d), "--out", str(out), "--resume"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 1500
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
                     arr(p.size_world), arr(p.hist), arr(p.desc), p.weak) for p in t.points])
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
                desc=rng.random(20) if observed and k == 3 else None,
                weak=observed and f % 5 == 0))
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


# -- a video run: the stages' working state is saved on interruption -----------------------------
def _video_run(frames, **kw):
    from test_parallel import FPS

    from aerotrack.io import open_source

    return run(open_source(frames, FPS), fps=FPS, metres_per_unit=0.3, seed=3, **kw)


def _everything(result):
    """Tracks, registrations and detections, exactly (floats as bytes)."""
    tracks = sorted((t.id, p.frame, p.kind, np.asarray(p.world).tobytes(),
                     np.asarray(p.box).tobytes()) for t in result.tracks for p in t.points)
    regs = {i: r.H.tobytes() for i, r in result.registrations.items()}
    dets = [(d.frame, np.asarray(d.boxes).tobytes()) for d in result.detections]
    return tracks, regs, dets


@pytest.fixture(scope="module")
def video_frames(tmp_path_factory):
    from test_parallel import render_scene

    folder = tmp_path_factory.mktemp("resume") / "frames"
    render_scene(folder, n=120, n_cars=5)
    return folder


@pytest.mark.parametrize("stop_at", [47, 83])
def test_interrupted_video_run_resumes_exactly(tmp_path, video_frames, stop_at):
    """Registrar keyframe chain, detector window, held vehicles and frames not yet final are all
    saved on Ctrl-C: the resumed run equals the uninterrupted one bit for bit (before the stage
    state was saved, frames after the restart were registered and detected differently)."""
    full = _video_run(video_frames)
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(stop_at))
    assert (out.partial / "state.npz").is_file()
    resumed = _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                         resume=True)
    assert resumed.frames == full.frames == 120
    # the timings cover the frames after the restart (summary.json's rate divided all of them)
    assert full.frames_timed == 120 and resumed.frames_timed == 120 - stop_at
    assert len(full.tracks) >= 3
    a, b = _everything(full), _everything(resumed)
    assert a[1] == b[1]  # registrations
    assert a[2] == b[2]  # detections
    assert a[0] == b[0]  # tracks


def test_video_resume_without_stage_state_restarts_before_the_stop(tmp_path, video_frames):
    """A killed run (no state, periodic checkpoints only) still resumes and covers every frame;
    only the frames after the restart may differ (documented in Pipeline.restore)."""
    full = _video_run(video_frames)
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(83))
    (out.partial / "state.npz").unlink()
    with _aerotrack_warnings() as said:  # it was silent (INFO "resuming from frame 60" only)
        resumed = _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                             resume=True)
    assert any("no working state was saved" in m for m in said), said
    assert resumed.frames == 120 and sorted(resumed.registrations) == list(range(1, 121))
    a, b = _everything(full), _everything(resumed)
    assert [r for i, r in sorted(a[1].items()) if i <= 60] == \
        [r for i, r in sorted(b[1].items()) if i <= 60]  # checkpointed before the stop: kept
    assert len(resumed.tracks) >= 3


@contextlib.contextmanager
def _aerotrack_warnings():
    """The warnings the ``aerotrack`` logger emits meanwhile (it does not propagate once the
    command line has configured it)."""
    said: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            if record.levelno >= logging.WARNING:
                said.append(record.getMessage())

    logger = logging.getLogger("aerotrack")
    handler = Keep()
    logger.addHandler(handler)
    try:
        yield said
    finally:
        logger.removeHandler(handler)


def test_a_second_interrupt_inside_a_frame_says_the_state_was_not_saved(
        tmp_path, video_frames, monkeypatch):
    """A second Ctrl-C lands inside a frame: only the checkpoints are kept, and the message said
    nothing about it (the resumed run then differed silently)."""
    from aerotrack.pipeline import Pipeline

    class Stop(KeyboardInterrupt):
        note = "; finished work is kept"

    step = Pipeline._step

    def interrupted(self, frame):
        if frame.index == 50:
            raise Stop()
        return step(self, frame)

    monkeypatch.setattr(Pipeline, "_step", interrupted)
    out = OutputDir(tmp_path / "o")
    with pytest.raises(Stop) as exc:
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30)
    assert "working state was not saved" in exc.value.note
    assert not (out.partial / "state.npz").exists()


def test_stale_stage_state_is_not_used(tmp_path, video_frames):
    """State saved at an earlier interruption, followed by more checkpoints (a later hard kill),
    no longer matches the checkpoints and is ignored."""
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(20))
    stale = (out.partial / "state.npz").read_bytes()
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30, resume=True,
                   progress=interrupt_at(50))
    (out.partial / "state.npz").write_bytes(stale)
    from test_parallel import FPS

    from aerotrack.config import Config
    from aerotrack.pipeline import Pipeline

    pipe = Pipeline(Config(), FPS, metres_per_unit=0.3, seed=3, checkpoint_dir=out.partial)
    restart = pipe.restore()
    assert not pipe.exact_resume and restart < 70


def test_a_periodic_checkpoint_drops_the_state_it_outdates(tmp_path, video_frames):
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(20))
    assert (out.partial / "state.npz").is_file()

    def killed(done):  # a hard kill: nothing is saved on the way out
        if done == 35:
            raise RuntimeError("killed")

    with pytest.raises(RuntimeError):  # resumed at frame 21, checkpoint after frame 50
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30, resume=True,
                   progress=killed)
    assert not (out.partial / "state.npz").exists()


# -- the state codec ------------------------------------------------------------------------------
def test_state_codec_round_trip(tmp_path):
    from collections import Counter, OrderedDict, deque

    from aerotrack.io.state import apply_state, as_built, load_state, save_state
    from aerotrack.types import Registration

    class Stage:  # stands for a stage: attributes of every supported kind
        def __init__(self):
            self.config = Registration(1, np.eye(3), "ok", 0, 0.5, 0.1, "")  # frozen: as built
            self.big = np.arange(12.0)  # as built and unchanged: not saved
            self.touched = np.zeros(3)
            self.pending = deque()

    Stage.__module__ = "aerotrack.tests_stage"  # only aerotrack classes are rebuilt
    s = Stage()
    built = as_built(s)
    shared = np.ones((2, 2))
    s.touched[1] = 7.0  # changed in place: saved
    s.pending.extend([Registration(5, shared, "carried", 3, np.float32(0.25), np.nan, "why"),
                      (1, "a", None, float("inf"))])
    s.alias = shared
    s.table = OrderedDict([(3, [1, 2]), (1, {"x": np.int64(4)})])
    s.counts = Counter(ok=3)
    s.rng = np.random.default_rng(9)
    s.rng.random(5)
    s.flags = {1, 2}
    save_state(tmp_path, 42, {"stage": (s, built)})
    frame, stages, _ = load_state(tmp_path)
    attrs = stages["stage"][1]
    assert frame == 42 and "big" not in attrs and "config" not in attrs and "touched" in attrs
    t = Stage()
    apply_state(t, attrs)
    assert t.touched.tolist() == [0, 7, 0]
    reg = t.pending[0]
    assert isinstance(reg, Registration) and reg.index == 5 and np.isnan(reg.error)
    assert reg.H is t.alias  # shared arrays stay shared
    assert t.pending[1] == (1, "a", None, float("inf"))
    assert list(t.table) == [3, 1] and t.table[1]["x"] == 4 and t.counts["ok"] == 3
    assert t.rng.random() == s.rng.random() and t.flags == {1, 2}


def test_state_codec_refuses_what_it_cannot_write_and_foreign_classes(tmp_path):
    import json
    import threading

    from aerotrack.errors import InputError
    from aerotrack.io.state import StateNotSaved, load_state, save_state

    class Stage:
        pass

    s = Stage()
    s.lock = threading.Lock()
    with pytest.raises(StateNotSaved, match="stage.lock"):
        save_state(tmp_path, 1, {"stage": (s, {})})
    assert not (tmp_path / "state.npz").exists()
    meta = {"version": 1, "frame": 1, "extra": {}, "stages": {"stage": {"m": "x", "c": "y", "d": {
        "a": {"t": "obj", "n": 0, "m": "subprocess", "c": "Popen", "d": {}}}}}}
    np.savez(tmp_path / "state.npz", __meta__=np.array(json.dumps(meta)))
    with pytest.raises(InputError, match="outside aerotrack"):
        load_state(tmp_path)


def test_resume_of_a_finished_run_does_nothing(tmp_path, capsys):
    """--resume on a finished run (no .partial/) used to run it again from the start; now it
    says so and leaves the files alone, and refuses when the inputs differ."""
    from conftest import run_cli

    d = tmp_path / "d.txt"
    write_mot(d, detections(n_frames=60))
    out = tmp_path / "o"
    assert run_cli(capsys, "-q", "track", "--detections", d, "--out", out)[0] == 0
    stamp = (out / "tracks.csv").stat().st_mtime_ns
    code, _, err = run_cli(capsys, "track", "--detections", d, "--out", out, "--resume")
    assert code == 0 and "already finished" in err, err
    assert (out / "tracks.csv").stat().st_mtime_ns == stamp
    code, _, err = run_cli(capsys, "track", "--detections", d, "--out", out, "--resume",
                           "--seed", "5")
    assert code == 2 and "--seed" in err and "--overwrite" in err, err


# -- what state.npz holds, and resuming from a video ----------------------------------------------
def _state_arrays(partial):
    with np.load(partial / "state.npz", allow_pickle=False) as z:
        meta = json.loads(str(z["__meta__"][()]))
        return meta, {k: z[k] for k in z.files if k != "__meta__"}


def test_stage_state_refers_to_the_frames_it_can_read_again(tmp_path, video_frames):
    """The frames the detector still holds (and their model-resolution copies) are saved as
    references, not pixels: no full frame is in state.npz, and a run interrupted again after a
    resume refers to the frames it re-read too."""
    import cv2

    frame_shape = cv2.imread(str(min(video_frames.iterdir()))).shape
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(47))
    meta, arrays = _state_arrays(out.partial)
    assert meta["frames"] and max(meta["frames"]) == 47
    assert not [k for k, a in arrays.items() if a.shape == frame_shape]
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30, resume=True,
                   progress=interrupt_at(10))
    meta, arrays = _state_arrays(out.partial)
    assert max(meta["frames"]) == 57 and min(meta["frames"]) < 47  # re-read ones among them
    assert not [k for k, a in arrays.items() if a.shape == frame_shape]


def test_interrupted_run_on_a_video_resumes_exactly(tmp_path, video_frames):
    """A video source: the resumed run seeks to the frames it needs again (the ones the stages
    held, then the next one) and equals the uninterrupted run bit for bit."""
    import cv2

    from aerotrack.io import open_source

    files = sorted(video_frames.iterdir())
    h, w = cv2.imread(str(files[0])).shape[:2]
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (w, h))
    if not writer.isOpened():
        pytest.skip("no MJPEG encoder in this OpenCV build")
    for p in files:
        writer.write(cv2.imread(str(p)))
    writer.release()

    def video_run(**kw):
        return run(open_source(video, None), fps=10.0, metres_per_unit=0.3, seed=3, **kw)

    full = video_run()
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        video_run(checkpoint_dir=out.partial, checkpoint_every=30, progress=interrupt_at(83))
    resumed = video_run(checkpoint_dir=out.partial, checkpoint_every=30, resume=True)
    assert resumed.frames == full.frames == 120 and len(full.tracks) >= 3
    assert _everything(full) == _everything(resumed)


def test_frames_that_changed_since_the_interruption_give_the_checkpoint_resume(
        tmp_path, video_frames, caplog):
    """When the input no longer gives the pixels the state was saved with, the state is not
    used (checked by CRC): the run resumes from its checkpoints, with a warning, and covers
    every frame."""
    import shutil

    import cv2

    frames = tmp_path / "frames"
    shutil.copytree(video_frames, frames)
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(83))
    p = sorted(frames.iterdir())[79]  # frame 80: held by the detector at the interruption
    img = cv2.imread(str(p))
    img[:10, :10] = 255 - img[:10, :10]
    cv2.imwrite(str(p), img)
    with caplog.at_level("WARNING", logger="aerotrack.pipeline"):
        resumed = _video_run(frames, checkpoint_dir=out.partial, checkpoint_every=30,
                             resume=True)
    assert "stage state not used" in caplog.text and "differs" in caplog.text
    assert resumed.frames == 120 and sorted(resumed.registrations) == list(range(1, 121))


KILLED_RUN = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from test_resume import _video_run
from aerotrack.io.output import OutputDir

def progress(done):
    if done == 83:
        os.kill(os.getpid(), signal.SIGKILL)

_video_run({frames!r}, checkpoint_dir=OutputDir({out!r}).partial, checkpoint_every=30,
           progress=progress)
"""


def test_a_hard_kill_resumes_from_the_last_periodic_checkpoint(tmp_path, video_frames):
    """SIGKILL at frame 83 with checkpoints every 30 frames: what aerotrack.io.checkpoint
    promises. The chunks hold registrations up to frame 60 and the detections that were final
    then; the resumed run keeps those exactly, redoes registration and detection from a
    background half-window before the first missing detections, and covers every frame."""
    from pathlib import Path

    from aerotrack.io.checkpoint import load_chunks

    out = tmp_path / "o"
    code = KILLED_RUN.format(tests=str(Path(__file__).parent), frames=str(video_frames),
                             out=str(out))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=False, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    partial = out / ".partial"
    assert not (partial / "state.npz").exists()  # nothing is saved on a kill
    regs, dets, _ = load_chunks(partial)
    assert max(regs) == 60  # the last periodic checkpoint: frames 31-83 are redone
    kept = max(d.frame for d in dets)
    assert kept < 60  # the detector's window lags behind registration
    full = _video_run(video_frames)
    resumed = _video_run(video_frames, checkpoint_dir=OutputDir(out, resume=True).partial,
                         checkpoint_every=30, resume=True)
    a, b = _everything(full), _everything(resumed)
    assert resumed.frames == 120 and sorted(b[1]) == list(range(1, 121))
    assert {i: r for i, r in a[1].items() if i <= 60} == {i: r for i, r in b[1].items()
                                                          if i <= 60}
    assert [d for d in a[2] if d[0] <= kept] == [d for d in b[2] if d[0] <= kept]
    assert len(resumed.tracks) >= 3
    assert not (partial / "state.npz").exists()


@pytest.mark.parametrize("damaged", ["state.npz", "chunk_000000.npz"])
def test_a_damaged_checkpoint_is_a_one_line_error(tmp_path, video_frames, capsys, damaged):
    """A truncated state or chunk (a disk fault: aerotrack writes them atomically) stops
    ``--resume`` with exit 2 and one line naming the file, not a traceback."""
    from conftest import run_cli

    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(47))
    path = out.partial / damaged
    path.write_bytes(path.read_bytes()[:300])
    code, _, err = run_cli(capsys, "track", video_frames, "--out", tmp_path / "o", "--fps", "10",
                           "--gsd", "0.3", "--seed", "3", "--resume")
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip() and "WARNING" not in ln]
    assert len(lines) == 1 and damaged in lines[0] and "unreadable" in lines[0], err
    assert "no run.json" in err  # the API wrote these checkpoints: the CLI cannot check them


def test_loaded_checkpoints_hold_each_detection_once(tmp_path):
    """Reading a chunk back holds its detections once: each detection's arrays are its own
    (reading a member per detection once held a copy of the whole chunk's array per detection:
    3.6 GB to resume after 600 frames at 640x480), and they come back exactly."""
    from aerotrack.io.checkpoint import load_chunks, save_chunk
    from aerotrack.types import Detections

    rng = np.random.default_rng(0)
    dets = [Detections(frame=f, boxes=rng.uniform(0, 100, (5, 4)), conf=rng.random(5),
                       world=rng.normal(size=(5, 2)), hist=rng.random((5, 48)),
                       extra={"desc": rng.random((5, 32))}) for f in range(1, 201)]
    save_chunk(tmp_path, 0, [], dets)
    _, back, _ = load_chunks(tmp_path)
    arrays = [a for d in back for a in (d.boxes, d.conf, d.world, d.hist, d.extra["desc"])]
    held = {id(a if a.base is None else a.base): (a if a.base is None else a.base).nbytes
            for a in arrays}
    assert sum(held.values()) == sum(a.nbytes for a in arrays)
    for a, b in zip(dets, back):
        assert np.array_equal(a.boxes, b.boxes) and np.array_equal(a.hist, b.hist)
        assert np.array_equal(a.extra["desc"], b.extra["desc"]) and a.frame == b.frame
    # deflated on disk (12 GB of stages/ per hour of 1080p before), read back exactly as above
    import zipfile

    (chunk,) = tmp_path.glob("chunk_*.npz")
    with zipfile.ZipFile(chunk) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}


def test_exact_resume_takes_association_back_instead_of_replaying_it(tmp_path, video_frames):
    """The state holds association's window and the tracklets it had finished: resuming does
    not run association again over the checkpointed frames (its cost grew with the video), and
    the result still equals the uninterrupted run (test_interrupted_video_run_resumes_exactly)."""
    from test_parallel import FPS

    from aerotrack.config import Config
    from aerotrack.io import open_source
    from aerotrack.pipeline import Pipeline

    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, checkpoint_dir=out.partial, checkpoint_every=30,
                   progress=interrupt_at(83))
    assert (out.partial / "state-tracklets").is_dir()
    pipe = Pipeline(Config(), FPS, metres_per_unit=0.3, seed=3, checkpoint_dir=out.partial)
    calls = []
    step = pipe.associator.step
    pipe.associator.step = lambda dets: calls.append(dets.frame) or step(dets)
    assert pipe.restore(open_source(video_frames, FPS)) == 84 and pipe.exact_resume
    assert not calls and len(pipe.tracklets) > 0
    assert [d.frame for d in pipe.detections] == list(range(1, len(pipe.detections) + 1))
    # the detector's thresholds of the frames before the restart came back (the noise hint had
    # judged a resumed run by the frames after it alone; a review)
    assert set(range(1, len(pipe.detections) + 1)) <= set(pipe.thresholds)
    (out.partial / "state-tracklets").rename(out.partial / "gone")  # e.g. deleted by hand
    again = Pipeline(Config(), FPS, metres_per_unit=0.3, seed=3, checkpoint_dir=out.partial)
    again.restore(open_source(video_frames, FPS))
    assert again.exact_resume and len(again.tracklets) == len(pipe.tracklets)  # replayed


def test_state_codec_keeps_slotted_objects(tmp_path):
    """Objects of aerotrack's slotted classes (association's window tracks) come back with every
    slot that was set, shared arrays still shared."""
    from aerotrack.association.moves import WTrack
    from aerotrack.io.state import apply_state, load_state, save_state

    class Stage:
        pass

    s = Stage()
    t = WTrack.__new__(WTrack)
    t.tid, t.nodes, t.score = 4, np.arange(3), -1.5
    s.tracks = {4: t}
    s.same = t.nodes
    save_state(tmp_path, 7, {"stage": (s, {})})
    back = Stage()
    apply_state(back, load_state(tmp_path)[1]["stage"][1])
    u = back.tracks[4]
    assert type(u) is WTrack and u.tid == 4 and u.score == -1.5 and u.nodes.tolist() == [0, 1, 2]
    assert u.nodes is back.same and not hasattr(u, "xs")  # unset slots stay unset


def test_a_run_resumed_at_its_last_frame_leaves_no_state_behind(tmp_path, video_frames):
    """Interrupted after the last frame was taken (frames with external detections: nothing is
    left pending then), the resumed run has nothing new to checkpoint, and must still not leave
    the spent state among the finished stages."""
    dets = detections(n_frames=120)
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        _video_run(video_frames, detections=dets, checkpoint_dir=out.partial,
                   checkpoint_every=30, progress=interrupt_at(120))
    assert (out.partial / "state.npz").is_file()
    resumed = _video_run(video_frames, detections=dets, checkpoint_dir=out.partial,
                         checkpoint_every=30, resume=True)
    assert resumed.frames == 120
    assert not (out.partial / "state.npz").exists()
    assert not (out.partial / "state-tracklets").exists()


# -- following stopped vehicles (association.follow_stopped) across an interruption ---------------
def _following(**assoc):
    import dataclasses

    from aerotrack.config import Config

    cfg = Config()
    return dataclasses.replace(cfg, association=dataclasses.replace(
        cfg.association, follow_stopped=True, **assoc))


@pytest.fixture(scope="module")
def stop_scene(tmp_path_factory):
    """test_follow's car, lost by its (given) detections while it brakes and stands 2 s."""
    from test_follow import GO_F, _scene, _seen, _stop_and_go, _write_scene

    frames, dets = _scene(_stop_and_go, GO_F + 80, _seen)
    return _write_scene(tmp_path_factory.mktemp("stop"), frames, dets)


def _tracks_csv(result, folder) -> bytes:
    from aerotrack.outputs import write_outputs

    out = OutputDir(folder)
    write_outputs(result, out, config=_following(), geomap=None)
    return (out.path / "tracks.csv").read_bytes()


@pytest.mark.parametrize("stop_at", [135, 170])
def test_an_interrupted_run_goes_on_following_where_it_stopped(tmp_path, stop_scene, stop_at):
    """Interrupted while the car stands lost (followed since about frame 126), the resumed run
    takes the follower's templates and references back and writes the uninterrupted run's
    tracks.csv byte for byte (it restarted following before: the stand was lost)."""
    from test_follow import FPS, GSD

    from aerotrack.io import open_source

    frames, rows = stop_scene

    def follow_run(**kw):
        return run(open_source(frames, FPS), detections=read_mot(rows), config=_following(),
                   fps=FPS, metres_per_unit=GSD, seed=3, **kw)

    full = follow_run()
    assert full.followed >= 50
    out = OutputDir(tmp_path / "o")
    with pytest.raises(KeyboardInterrupt):
        follow_run(checkpoint_dir=out.partial, checkpoint_every=50, progress=interrupt_at(stop_at))
    resumed = follow_run(checkpoint_dir=out.partial, checkpoint_every=50, resume=True)
    assert _tracks_csv(resumed, tmp_path / "b") == _tracks_csv(full, tmp_path / "a")
    assert resumed.followed == full.followed


def test_frames_the_follower_holds_at_an_interruption_are_read_again(tmp_path, video_frames):
    """The built-in detector: at frame 83 the frames of 69-83 wait for their detections, and
    the follower finds a vehicle in 73-77 of them. The state refers to those frames and to the
    grey frames the follower keeps (14 of them: without following the file is no smaller);
    the resumed run reads them again and equals the uninterrupted one."""
    full = _video_run(video_frames, config=_following())
    assert full.followed > 0
    sizes = {}
    for follow in (False, True):
        out = OutputDir(tmp_path / str(follow))
        with pytest.raises(KeyboardInterrupt):
            _video_run(video_frames, config=_following() if follow else None,
                       checkpoint_dir=out.partial, checkpoint_every=30,
                       progress=interrupt_at(83))
        sizes[follow] = (out.partial / "state.npz").stat().st_size
    assert sizes[True] < 1.1 * sizes[False], sizes
    resumed = _video_run(video_frames, config=_following(), checkpoint_dir=out.partial,
                         checkpoint_every=30, resume=True)
    assert _everything(full) == _everything(resumed)
    assert resumed.followed == full.followed


def test_on_interrupt_finish_writes_the_results_of_the_frames_read(tmp_path, capsys, video_frames,
                                                                  monkeypatch):
    """A live feed or a flight cut short: Ctrl-C with --on-interrupt finish ends the run at the
    last frame read and writes every result; they equal a run told to stop there (--frames)."""
    from conftest import ctrl_c_track_at, run_cli

    ctrl_c_track_at(monkeypatch, 60)
    code, _, err = run_cli(capsys, "track", video_frames, "--out", tmp_path / "cut", "--fps", "30",
                           "--on-interrupt", "finish")
    assert code == 0, err
    assert "finishing the run at frame 60" in err and "interrupted: frames 1-60" in err
    summary = json.loads((tmp_path / "cut" / "summary.json").read_text())
    assert summary["interrupted_at_frame"] == 60 and summary["frames"] == 60
    assert not (tmp_path / "cut" / ".partial").exists()
    monkeypatch.undo()
    code, _, err = run_cli(capsys, "track", video_frames, "--out", tmp_path / "to60", "--fps",
                           "30", "--frames", "1:60")
    assert code == 0, err
    cut = (tmp_path / "cut" / "tracks.csv").read_bytes()
    assert cut == (tmp_path / "to60" / "tracks.csv").read_bytes() and cut.count(b"\n") > 60
    code, _, err = run_cli(capsys, "track", video_frames, "--out", tmp_path / "w", "--workers",
                           "2", "--on-interrupt", "finish")
    assert code == 2 and "--on-interrupt finish: one process only" in err


def test_resume_refuses_changed_input_files_and_another_execution_mode(
        tmp_path, capsys, video_frames, monkeypatch):
    """A frame overwritten between Ctrl-C and --resume was silently not read again (the resumed
    tracks matched the old input); resuming a one-process run with --workers started over as a
    Dask run and left stale checkpoints that broke ``track --from``."""
    import shutil

    from conftest import ctrl_c_track_at, run_cli

    frames = tmp_path / "frames"
    shutil.copytree(video_frames, frames)
    ctrl_c_track_at(monkeypatch, 40)
    out = tmp_path / "run"
    code, _, err = run_cli(capsys, "track", frames, "--out", out, "--fps", "30")
    assert code == 130 and (out / ".partial").is_dir(), err
    monkeypatch.undo()
    code, _, err = run_cli(capsys, "track", frames, "--out", out, "--fps", "30")
    assert code == 2 and "holds an interrupted run (.partial/): --resume continues it" in err, err
    code, _, err = run_cli(capsys, "track", frames, "--out", out, "--fps", "30", "--resume",
                           "--workers", "2")
    assert code == 2 and "another --workers/--scheduler" in err, err
    first = sorted(frames.iterdir())[10]
    first.write_bytes(sorted(frames.iterdir())[11].read_bytes() + b"\0")
    code, _, err = run_cli(capsys, "track", frames, "--out", out, "--fps", "30", "--resume")
    assert code == 2 and "another version of frames (size or" in err and "--overwrite" in err, err
    assert (out / ".partial").is_dir()  # still resumable once the input is put back
    shutil.copy2(video_frames / first.name, first)
    code, _, err = run_cli(capsys, "track", frames, "--out", out, "--fps", "30", "--resume")
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["resumed"] == {"from_frame": 41, "exact": True}
    assert summary["environment"]["numpy"] == np.__version__

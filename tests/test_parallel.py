"""Segment-parallel processing: planning, the join (known answers), and real runs on a local Dask
cluster (worker processes on loopback) against the single process."""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
import re
import signal
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from aerotrack.config import Config
from aerotrack.errors import InputError
from aerotrack.parallel import (
    ParallelConfig,
    SegmentResult,
    chain_worlds,
    join_segments,
    make_tasks,
    plan_batch,
    plan_segments,
    run_segment,
    stitch_pairs,
)
from aerotrack.types import Registration, Track, TrackPoint, apply_homography

TILE = Path(__file__).resolve().parents[1] / "src/aerotrack/synth/data/vegas_tile.tif"
FPS = 10.0


# -- a small scene: the map tile under a drifting camera, coloured cars driving straight ----------
def render_scene(folder: Path, n: int = 200, size=(240, 180), n_cars: int = 5, seed: int = 0,
                 ) -> np.ndarray:
    """Write ``n`` frames to ``folder``; returns the ground truth as (M, 10) MOT rows."""
    from aerotrack.geo import GeoMap

    m = GeoMap(TILE).read_image()
    rng = np.random.default_rng(seed)
    W, H = size
    folder.mkdir(parents=True, exist_ok=True)
    cars = [(np.array([520.0, 510.0]) + rng.uniform(-50, 50, 2),
             rng.uniform(8, 14) * np.array([np.cos(a), np.sin(a)]),
             tuple(int(c) for c in rng.integers(0, 256, 3)))
            for a in rng.uniform(0, 2 * np.pi, n_cars)]
    gt = []
    for k in range(n):
        t = k / FPS
        origin = np.array([400 + 4 * t, 420 + 3 * t])  # map pixel of the frame's top-left corner
        Hm = np.array([[1, 0, origin[0]], [0, 1, origin[1]], [0, 0, 1.0]])
        img = cv2.warpPerspective(m, Hm, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        for i, (p0, v, col) in enumerate(cars):
            x, y = p0 + v * t - origin
            if 8 < x < W - 8 and 6 < y < H - 6:
                cv2.rectangle(img, (int(x - 7), int(y - 4)), (int(x + 7), int(y + 4)), col, -1)
                gt.append([k + 1, i + 1, int(x - 7), int(y - 4), 15, 9, 1, 1, 1, -1])
        img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{k + 1:05d}.png"), img)
    return np.asarray(gt, dtype=np.float64)


def straight_detections(seed: int, n_targets: int, n_frames: int, area, max_step: float,
                        size) -> tuple[np.ndarray, np.ndarray]:
    """Targets moving straight at constant velocity (at most ``max_step`` px a frame per axis)
    from random places in ``area`` (x0, y0, x1, y1), boxes of ``size``: (ground truth, the same
    rows as detections with id -1)."""
    rng = np.random.default_rng(seed)
    w, h = size
    rows = []
    for tid in range(1, n_targets + 1):
        p, v = rng.uniform(area[:2], area[2:]), rng.uniform(-max_step, max_step, 2)
        for f in range(1, n_frames + 1):
            q = p + v * f
            rows.append([f, tid, q[0] - w // 2, q[1] - h // 2, w, h, 0.9, -1, -1, -1])
    gt = np.asarray(rows, dtype=np.float64)
    dets = gt.copy()
    dets[:, 1] = -1
    return gt, dets


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> tuple[Path, np.ndarray]:
    folder = tmp_path_factory.mktemp("scene") / "frames"
    return folder, render_scene(folder)


@pytest.fixture(scope="module")
def client():
    pytest.importorskip("distributed")
    from aerotrack.parallel import dask_client

    with dask_client(workers=2) as c:
        c.wait_for_workers(2, timeout=60)
        yield c


# -- planning -------------------------------------------------------------------------------------
@pytest.mark.parametrize("n,stride,min_segments",
                         [(1000, 1, 1), (1000, 3, 2), (97, 1, 4), (30, 1, 2)])
def test_plan_partitions_frames_and_cuts_mid_overlap(n, stride, min_segments):
    fps, overlap_s = 10.0, 4.5
    segs = plan_segments(1, n, fps=fps, stride=stride, segment_s=20.0, overlap_s=overlap_s,
                         min_segments=min_segments)
    grid = list(range(1, n + 1, stride))
    owned = [f for s in segs for f in range(s.own_start, s.own_stop + 1, stride)]
    assert owned == grid  # every frame owned exactly once, in order
    assert segs[0].start == 1 and segs[-1].stop == grid[-1]
    need = overlap_s * fps
    for a, b in itertools.pairwise(segs):
        shared = len(range(b.start, a.stop + 1, stride)) * stride
        assert shared >= need  # neighbours share at least the overlap
        # the cut is in the middle of the overlap
        assert abs((a.own_stop + stride - b.start) - (a.stop + stride - b.own_start)) <= stride
        assert a.own_stop - a.own_start > a.stop - b.start  # frames read by <= 2 segments
    if n == 1000 and stride == 1:
        assert len(segs) == 5  # 100 s in 20 s segments
    if n == 30:
        assert len(segs) == 1  # too short to split


@pytest.mark.parametrize("stride,align", [(1, 3), (2, 7), (3, 1), (1, 24)])
def test_plan_starts_segments_on_the_phase_grid(stride, align):
    segs = plan_segments(5, 2000, fps=10.0, stride=stride, segment_s=30.0, overlap_s=4.5,
                         min_segments=2, align=align)
    assert len(segs) >= 3
    lead, tail = (len(range(0, 45, stride)) - len(range(0, 23, stride)), len(range(0, 23, stride)))
    for a, b in itertools.pairwise(segs):
        assert (b.start - 5) % (align * stride) == 0
        assert b.own_start - b.start == lead * stride  # on the grid without reading more
        assert a.stop - a.own_stop == tail * stride


@pytest.mark.parametrize("n,align", [(1800, 24), (1800, 1), (5000, 7), (700, 24)])
def test_plan_balances_the_frames_each_segment_reads(n, align):
    """The first and last segments lack a lead or a tail: they own more, so that every worker
    reads about as many frames (within the phase grid's step), and the tail is what was asked."""
    segs = plan_segments(1, n, fps=15.0, segment_s=20.0, overlap_s=8.0, tail_s=3.5,
                         min_segments=2, align=align)
    assert len(segs) >= 2
    reads = [s.stop - s.start + 1 for s in segs]
    assert max(reads) - min(reads) <= align + 1
    owned = [s.own_stop - s.own_start + 1 for s in segs]
    if len(segs) > 2:
        assert owned[0] > owned[1] and owned[-1] > owned[1]
    for a, b in itertools.pairwise(segs):
        assert a.stop - a.own_stop == 53  # ceil(3.5 s * 15)
        assert b.own_start - b.start == 120 - 53  # the rest of ceil(8 s * 15)
        assert (b.start - 1) % align == 0


def test_phase_period_follows_the_detector_sampling():
    from dataclasses import replace

    from aerotrack.parallel import phase_period

    config = Config()
    det = replace(config.detection, sample_every_s=0.2, update_every_s=0.3)
    config = replace(config, detection=det,
                     registration=replace(config.registration, keyframe_s=0.2))
    assert phase_period(config, 10.0) == 6  # samples every 2 frames, background every 3
    slow_keys = replace(config, registration=replace(config.registration, keyframe_s=0.5))
    assert phase_period(slow_keys, 10.0) == 30  # and a keyframe every 5
    assert phase_period(config, 10.0, stride=2) == 2  # every grid frame; background every 4
    assert phase_period(config, 10.0, stride=3) == 2  # samples every 6 frames; background every 3
    # on the detector's own grid at rates where a duration is a half frame (a review: at 12.5
    # and 22.5 frames/s the detector rounds halves up and phase_period had rounded to even)
    from aerotrack.detection.detector import MovingObjectDetector

    for fps in (10.0, 12.5, 15.0, 22.5, 25.0, 30.0):
        det = MovingObjectDetector(Config().detection, fps)
        period = phase_period(Config(), fps)
        assert period % det.every == 0 and period % det.update == 0, fps


def test_later_segments_hold_stopped_vehicles_after_half_their_warm_up():
    segs = plan_segments(1, 300, fps=10.0, segment_s=10.0, overlap_s=6.0, min_segments=3)
    tasks = make_tasks(None, config=Config(), fps=10.0, segments=segs)
    assert tasks[0].hold_from is None
    for t in tasks[1:]:
        assert t.hold_from == t.segment.start + round((t.segment.own_start - t.segment.start) / 2)
    tasks = make_tasks(None, config=Config(), fps=10.0, segments=segs, hold_after_s=0.0)
    assert [t.hold_from for t in tasks[1:]] == [s.start for s in segs[1:]]


def test_overlap_defaults_to_the_stage_windows_and_refuses_less():
    config = Config()
    det, assoc = config.detection.window_s, config.association.window_s
    tail = det / 2 + 4 / 3 * assoc  # the last owned frame's background and final association
    assert ParallelConfig().tail(config) == pytest.approx(tail)
    assert ParallelConfig().overlap(config) == pytest.approx(det + assoc + tail)
    with pytest.raises(InputError, match="overlap_s"):
        ParallelConfig(overlap_s=config.detection.window_s / 2).overlap(config)
    with pytest.raises(InputError, match="tail_s"):
        ParallelConfig(overlap_s=det, tail_s=det + 1).overlap(config)
    segs = ParallelConfig(min_segments=2).plan(1, 1800, config, 15.0)
    assert len(segs) == 2
    assert segs[0].stop - segs[0].own_stop == math.ceil(tail * 15)


# -- the join (known answers) ---------------------------------------------------------------------
def _H(tx, ty, th=0.0, s=1.0):
    c, n = np.cos(th) * s, np.sin(th) * s
    return np.array([[c, -n, tx], [n, c, ty], [0, 0, 1.0]])


def test_chain_worlds_recovers_the_world_change():
    # camera: frame pixels -> world 0 is T(f); segment 1's world is its first frame (f = 40)
    T = {f: _H(2.0 * f, -1.0 * f, 0.004 * f, 1 + 0.001 * f) for f in range(1, 80)}
    A_true = T[40]  # world 1 -> world 0
    prev = {f: Registration(f, T[f]) for f in range(1, 61)}
    cur = {f: Registration(f, np.linalg.inv(A_true) @ T[f]) for f in range(40, 80)}
    A, rms = chain_worlds(prev, cur, range(40, 61), (320, 240))
    pts = np.array([[0, 0], [320, 240], [-100, 50.0]])
    assert np.allclose(apply_homography(A, pts), apply_homography(A_true, pts), atol=1e-4)
    assert rms < 1e-4
    # a failed registration in either segment is not used; none usable -> identity, NaN
    bad = {f: Registration(f, T[f], status="carried") for f in range(1, 61)}
    A, rms = chain_worlds(bad, cur, range(40, 61), (320, 240))
    assert np.allclose(A, np.eye(3)) and np.isnan(rms)


def _track(tid, frames, xy0, v, A=None):
    """Points of a target moving at ``v`` px/frame in frame pixels (frame = world 0 here),
    expressed in a segment world related to world 0 by ``A`` (world_k -> world 0; None: identity)."""
    pts = []
    inv = np.eye(3) if A is None else np.linalg.inv(A)
    for f in frames:
        c = np.asarray(xy0, float) + np.asarray(v, float) * f
        pts.append(TrackPoint(f, np.array([c[0] - 5, c[1] - 3, 10, 6]),
                              apply_homography(inv, c[None])[0], 0.9,
                              size_world=np.array([10.0, 6.0])))
    return Track(tid, pts)


def test_join_stitches_tracklets_across_the_cut_and_keeps_each_frame_once():
    segs = plan_segments(1, 100, fps=10.0, segment_s=5.0, overlap_s=2.0, min_segments=2)
    a, b = segs
    A1 = _H(30.0, -12.0, 0.05)  # segment 1's world in world 0
    regs0 = {f: Registration(f, np.eye(3)) for f in range(a.start, a.stop + 1)}
    regs1 = {f: Registration(f, np.linalg.inv(A1)) for f in range(b.start, b.stop + 1)}
    # target 1 crosses the cut (seen by both segments in the overlap); target 2 only before,
    # target 3 only after; segment 1 also sees target 1 a few frames late (starts after b.start)
    left = [_track(1, range(10, a.stop + 1), (20, 20), (1.0, 0.5)),
            _track(2, range(5, 30), (200, 50), (-1.0, 0.0))]
    right = [_track(7, range(b.start + 3, 95), (20, 20), (1.0, 0.5), A1),
             _track(8, range(70, 100), (50, 150), (0.0, -1.0), A1)]
    res = [SegmentResult(a, regs0, [], left, (320, 240)),
           SegmentResult(b, regs1, [], right, (320, 240))]
    regs, _, tracklets, report = join_segments(res)
    assert sorted(regs) == list(range(1, 101))
    assert all(np.allclose(r.H, np.eye(3), atol=1e-5) for r in regs.values())  # world 0 = frame
    assert report.stitched == [1] and report.cut == [0]
    assert len(tracklets) == 3
    t1 = next(t for t in tracklets if t.first == 10)
    assert [p.frame for p in t1.points] == list(range(10, 95))  # one point per frame, no seam
    for p in t1.points:  # every point in world 0
        assert np.allclose(p.world, np.array([20, 20]) + np.array([1.0, 0.5]) * p.frame, atol=1e-3)
    pairs = stitch_pairs(left, right, b.start, a.stop)
    assert pairs == [(0, 0)]


# -- real runs on a local cluster -----------------------------------------------------------------
@pytest.mark.slow  # a single-process run and a parallel run: ~20-30 s on 2 shared cores
def test_segments_on_a_cluster_match_the_single_process(scene, client, tmp_path):
    from aerotrack.evaluation import evaluate
    from aerotrack.io import open_source
    from aerotrack.outputs import track_rows
    from aerotrack.parallel import gather_segments, run_parallel
    from aerotrack.pipeline import run

    folder, gt = scene
    src = open_source(folder, FPS)
    single = run(src, metres_per_unit=0.3)
    done = []
    par, report = run_parallel(src, client=client, metres_per_unit=0.3, with_report=True,
                               parallel=ParallelConfig(segment_s=10.0, min_segments=2),
                               checkpoint_dir=tmp_path, progress=done.append)
    assert done[-1] == 200 and done == sorted(done)
    # finished segments were saved: resuming runs nothing (no client needed)
    segs = ParallelConfig(segment_s=10.0, min_segments=2).plan(1, 200, Config(), FPS)
    assert len(segs) == 2
    tasks = make_tasks(folder, config=Config(), fps=FPS, segments=segs, metres_per_unit=0.3)
    again = gather_segments(None, tasks, checkpoint_dir=tmp_path, resume=True)
    assert [r.segment for r in again] == segs
    assert sorted(again[1].registrations) == list(range(segs[1].start, segs[1].stop + 1))
    assert sorted(par.registrations) == sorted(single.registrations) == list(range(1, 201))
    assert [d.frame for d in par.detections] == [d.frame for d in single.detections]
    assert len(report.world_rms) >= 1 and max(report.world_rms) < 1.0  # px of world 0
    # world coordinates agree after chaining (frame 1 pixels): compare frame corners
    corners = np.array([[0, 0], [240, 0], [240, 180], [0, 180.0]])
    err = max(np.abs(apply_homography(single.registrations[f].H, corners)
                     - apply_homography(par.registrations[f].H, corners)).max()
              for f in single.registrations)
    assert err < 3.0
    # segment 0 reads the same frames from frame 1: its owned frames are identical
    own0 = segs[0]
    for ds, dp in zip(single.detections, par.detections):
        if ds.frame <= own0.own_stop:
            assert np.allclose(ds.boxes, dp.boxes)
    rows_s, rows_p = track_rows(single, None)[0], track_rows(par, None)[0]
    es, ep = evaluate(gt, rows_s), evaluate(gt, rows_p)
    assert abs(es["HOTA"] - ep["HOTA"]) < 0.03
    assert abs(es["IDF1"] - ep["IDF1"]) < 0.03
    # and the tracks themselves: the single process's tracks as ground truth for the segments'
    agree = evaluate(rows_s, rows_p)  # a misaligned world or a bad join would be far below
    assert agree["HOTA"] > 0.7 and agree["IDF1"] > 0.7  # (MCMC seed changes alone: ~0.9)


def test_segments_with_a_map_are_registered_against_it(scene, client):
    from aerotrack.geo import GeoMap
    from aerotrack.io import open_source
    from aerotrack.parallel import run_parallel

    folder, _ = scene
    geomap = GeoMap(TILE)

    def truth(f):  # frame pixels -> map pixels of the rendered camera (render_scene)
        t = (f - 1) / FPS
        return np.array([[1, 0, 400 + 4 * t], [0, 1, 420 + 3 * t], [0, 0, 1.0]])

    par, report = run_parallel(open_source(folder, FPS), client=client, geomap=geomap,
                               H_init=truth(1), with_report=True, stop=120,
                               parallel=ParallelConfig(segment_s=6.0, overlap_s=4.5,
                                                       min_segments=2))
    assert len(report.world_rms) == 1
    corners = np.array([[0, 0], [240, 0], [240, 180], [0, 180.0]])
    err = [np.abs(apply_homography(par.registrations[f].H, corners)
                  - apply_homography(truth(f), corners)).max() for f in sorted(par.registrations)]
    assert max(err) < 3.0  # map pixels, both segments
    cut = report.segments[0].own_stop  # the later segment is refined against the map too
    assert any(r.status == "refined" for f, r in par.registrations.items() if f > cut)
    d = next(d for d in par.detections if d.frame > 100 and len(d))
    assert d.lonlat is not None and np.all(np.isfinite(d.lonlat))  # segment 1 gets map outputs
    tl = report.timeline  # where the wall time went: tasks, their results, join, linking
    assert len(tl["started"]) == len(tl["ended"]) == len(tl["received"]) == 2
    assert all(0 <= a <= b <= c for a, b, c in zip(tl["started"], tl["ended"], tl["received"]))
    assert max(tl["received"]) <= tl["joined"] <= tl["linked"] and tl["client_cpu_s"] > 0


def test_a_segment_whose_worker_dies_is_run_again(scene, client):
    folder, _ = scene
    segs = plan_segments(1, 60, fps=FPS, segment_s=6.0, overlap_s=4.5)
    task = make_tasks(folder, config=Config(), fps=FPS, segments=segs[:1],
                      metres_per_unit=0.3)[0]
    expected = run_segment(task)  # in this process
    from aerotrack.parallel import submit_tasks

    (fut,) = submit_tasks(client, [task], name="kill-test")
    killed = None
    deadline = time.monotonic() + 60
    while killed is None and time.monotonic() < deadline:
        processing = client.processing()
        for addr, keys in processing.items():
            if fut.key in keys:
                pid = client.run(os.getpid, workers=[addr])[addr]
                time.sleep(0.3)  # let the task get under way
                os.kill(pid, signal.SIGKILL)
                killed = pid
                break
        time.sleep(0.02)
    assert killed is not None, "the task never started"
    res = fut.result(timeout=120)
    assert res.pid != killed  # re-run by another (or the restarted) worker process
    suspicious = client.run_on_scheduler(
        lambda dask_scheduler, key=fut.key: dask_scheduler.tasks[key].suspicious
        if key in dask_scheduler.tasks else -1)
    assert suspicious >= 1  # the scheduler saw the worker die holding it
    assert sorted(res.registrations) == sorted(expected.registrations)
    assert [len(d) for d in res.detections] == [len(d) for d in expected.detections]
    assert len(res.tracklets) == len(expected.tracklets)
    client.wait_for_workers(2, timeout=60)  # the nanny restarts the killed worker


def test_missing_dask_names_the_extra(monkeypatch):
    from aerotrack.parallel import dask_client

    monkeypatch.setitem(sys.modules, "distributed", None)  # import now fails
    with pytest.raises(InputError, match=r"pip install 'aerotrack\[dask\]'"), dask_client(workers=1):
        pass


# -- many videos ----------------------------------------------------------------------------------
def test_batch_tracks_each_input_once_and_skips_finished(tmp_path, scene, client):
    from aerotrack.cli.main import cli

    src_frames = sorted(scene[0].iterdir())[:45]
    inp = tmp_path / "in"
    for name in ("flight_a", "flight_b"):
        (inp / name).mkdir(parents=True)
        for p in src_frames:
            (inp / name / p.name).write_bytes(p.read_bytes())
    (inp / "notes.txt").write_text("not a video")
    out = tmp_path / "out"
    (out / "flight_b").mkdir(parents=True)
    (out / "flight_b" / "summary.json").write_text("{}")  # finished earlier
    items = plan_batch(inp, out)
    assert [(i.name, i.done) for i in items] == [("flight_a", False), ("flight_b", True)]
    args = ["batch", str(inp), "--out", str(out), "--gsd", "0.3", "--fps", "10"]
    r = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "flight_a" / "summary.json").read_text())
    assert summary["frames"] == 45 and (out / "flight_a" / "tracks.csv").is_file()
    assert (out / "flight_b" / "summary.json").read_text() == "{}"  # skipped, untouched
    # the same on the cluster engine gives the same files (one segment per 4.5 s video)
    out2 = tmp_path / "out2"
    addr = client.scheduler.address
    r = CliRunner().invoke(cli, args[:3] + [str(out2)] + args[4:] + ["--scheduler", addr],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    for name in ("flight_a", "flight_b"):
        s2 = json.loads((out2 / name / "summary.json").read_text())
        assert s2["frames"] == 45
        assert s2["counts"]["detections"] == summary["counts"]["detections"]
    # each output folder is a `track` folder: its stages/ serve `track --from` (either engine),
    # and summary.json names the input by its absolute path
    assert summary["input"] == str((inp / "flight_a").resolve())
    for folder in (out / "flight_a", out2 / "flight_a"):
        again = tmp_path / f"again_{folder.parent.name}"
        r = CliRunner().invoke(cli, ["track", "--from", str(folder), "--out", str(again),
                                     "--gsd", "0.3"], catch_exceptions=False)
        assert r.exit_code == 0, r.output
        assert (again / "detections.csv").read_text() == (folder / "detections.csv").read_text()


def test_batch_on_a_map_places_each_input_by_the_file_beside_it(tmp_path, scene, capsys,
                                                                 client):
    """``batch --map``: each input is placed by its own ``NAME.map-init.txt`` (or flight log) and
    tracked as ``track --map --map-init`` tracks it; one with no such file fails alone, named
    with the files it needs; one with two is refused; a batch over the same inputs without the
    map names the finished ones as tracked with another --map."""
    from conftest import run_cli

    from aerotrack.cli.main import cli

    inp = tmp_path / "in"
    for name in ("flight_a", "flight_b", "flight_c"):
        (inp / name).mkdir(parents=True)
        for p in sorted(scene[0].iterdir())[:40]:
            (inp / name / p.name).write_bytes(p.read_bytes())
    placement = "1 0 400\n0 1 420\n0 0 1\n"  # frame 1's top-left corner at map pixel 400,420
    (inp / "flight_a.map-init.txt").write_text(placement)
    (inp / "flight_c.map-init.txt").write_text(placement)
    (inp / "flight_c.SRT").write_text("1\n")
    out = tmp_path / "out"
    args = ["batch", str(inp), "--out", str(out), "--map", str(TILE), "--fps", "10"]
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and "Traceback" not in err
    assert "flight_b: nothing places it on --map: put flight_b.map-init.txt" in err
    assert "flight_c.map-init.txt and flight_c.SRT would each place it" in err
    assert not (out / "flight_b").exists() and not (out / "flight_c").exists()
    summary = json.loads((out / "flight_a" / "summary.json").read_text())
    assert summary["registration_mode"] == "map" and summary["map"] == str(TILE.resolve())
    assert summary["options"]["map_init"] == str((inp / "flight_a.map-init.txt").resolve())
    assert (out / "flight_a" / "observations.csv").is_file()
    single = tmp_path / "single"
    r = CliRunner().invoke(cli, ["track", str(inp / "flight_a"), "--out", str(single), "--map",
                                 str(TILE), "--map-init", str(inp / "flight_a.map-init.txt"),
                                 "--fps", "10"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    for name in ("tracks.csv", "observations.csv", "registration.csv"):
        assert (out / "flight_a" / name).read_text() == (single / name).read_text(), name
    assert summary["counts"]["tracks"] > 0
    code, _, err = run_cli(capsys, "batch", inp, "--out", out, "--fps", "10")
    assert "flight_a: finished with other --map" in err
    # on the cluster the segments are placed on the map as one process places them
    out2 = tmp_path / "out2"
    (inp / "flight_c.SRT").unlink()
    code, _, err = run_cli(capsys, *args[:3], out2, *args[4:], "--scheduler",
                           client.scheduler.address)
    assert code == 2, err  # (flight_b still has nothing)
    for name in ("flight_a", "flight_c"):
        assert (out2 / name / "registration.csv").read_text() == \
            (single / "registration.csv").read_text()
    # a placement file edited after the input was tracked is named, not silently kept
    (inp / "flight_a.map-init.txt").write_text("1 0 401\n0 1 420\n0 0 1\n")
    code, _, err = run_cli(capsys, *args)
    assert "flight_a: finished with other placement on the map" in err, err


def test_batch_tracks_each_input_with_its_own_detections(tmp_path, scene, capsys):
    """``batch --detections det/det.txt`` over MOTChallenge sequence folders: each sequence is
    tracked on its own file as ``track SEQ --detections SEQ/det/det.txt`` tracks it (same
    tracks.csv); a sequence without the file fails alone; a {name} pattern names files beside
    videos; a bare path with a video input is refused for that input."""
    from conftest import run_cli

    folder, gt = scene
    bench = tmp_path / "train"
    for k, name in enumerate(("SEQ-01", "SEQ-02")):
        seq = bench / name
        (seq / "img1").mkdir(parents=True)
        for p in sorted(folder.iterdir())[:40]:
            (seq / "img1" / p.name).write_bytes(p.read_bytes())
        (seq / "seqinfo.ini").write_text("[Sequence]\nimDir=img1\nframeRate=10\n")
        if k == 0:
            rows = gt[gt[:, 0] <= 40].copy()
            rows[:, 1] = -1
            (seq / "det").mkdir()
            np.savetxt(seq / "det" / "det.txt", rows, fmt="%g", delimiter=",")
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "batch", bench, "--out", out, "--detections", "det/det.txt")
    assert code == 2 and "SEQ-02: failed: --detections det/det.txt: no " in err, err
    summary = json.loads((out / "SEQ-01" / "summary.json").read_text())
    assert summary["detections"] == str((bench / "SEQ-01" / "det" / "det.txt").resolve())
    assert summary["fps"] == 10.0 and summary["counts"]["tracks"] > 0
    single = tmp_path / "single"
    code, _, err = run_cli(capsys, "track", bench / "SEQ-01", "--out", single, "--detections",
                           bench / "SEQ-01" / "det" / "det.txt")
    assert code == 0, err
    assert (out / "SEQ-01" / "tracks.csv").read_text() == (single / "tracks.csv").read_text()
    code, _, err = run_cli(capsys, "batch", bench, "--out", out)  # without them: named
    assert "SEQ-01: finished with other --detections" in err, err
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "a.avi").write_bytes(b"\0" * 10)
    from aerotrack.parallel import item_detections_path

    assert item_detections_path(videos / "a.avi", str(tmp_path / "d" / "{name}.txt")) == \
        tmp_path / "d" / "a.txt"
    with pytest.raises(InputError, match="is a video, not a folder"):
        item_detections_path(videos / "a.avi", "det/det.txt")


def test_placement_sidecars_are_the_inputs_own(tmp_path):
    """Sidecars match the input's name exactly (suffixes in any case); another input's whose name
    starts the same, or differs in case, are not taken."""
    from aerotrack.geo.init import placement_sidecars

    for name in ("a.mp4", "a.SRT", "a.map-init.csv", "ab.mp4", "ab.map-init.txt",
                 "A.telemetry.csv", "a.notes.txt"):
        (tmp_path / name).write_text("x")
    init, tel = placement_sidecars(tmp_path / "a.mp4")
    assert [p.name for p in init] == ["a.map-init.csv"]
    assert [p.name for p in tel] == ["a.SRT"]
    assert placement_sidecars(tmp_path / "ab.mp4") == ([tmp_path / "ab.map-init.txt"], [])
    # near misses are named, not "put one beside it" when one is there
    from aerotrack.geo.init import sidecar_placement

    (tmp_path / "e.mp4").write_text("x")
    (tmp_path / "E.SRT").write_text("x")
    (tmp_path / "f.mp4").write_text("x")
    (tmp_path / "f.map-init.txt").mkdir()
    with pytest.raises(InputError, match="E.SRT beside it is not named after it"):
        sidecar_placement(tmp_path / "e.mp4", None, None)
    with pytest.raises(InputError, match="f.map-init.txt beside it is a folder"):
        sidecar_placement(tmp_path / "f.mp4", None, None)


def test_track_command_runs_on_the_cluster(tmp_path, scene, client):
    from aerotrack.cli.main import cli

    clip = tmp_path / "clip"
    clip.mkdir()
    for p in sorted(scene[0].iterdir())[:45]:
        (clip / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "run"
    args = ["track", str(clip), "--out", str(out), "--fps", "10", "--gsd", "0.3"]
    r = CliRunner().invoke(cli, args + ["--scheduler", client.scheduler.address],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 45 and summary["counts"]["registered_frames"] == 45
    assert summary["scheduler"] == client.scheduler.address and summary["options"]["on_dask"]
    assert summary["mcmc"]["proposed"] > 0  # the segments' samplers, added up
    assert not (out / ".partial").exists()
    # its stages/ serve `track --from` like a single process's: the same detections come back
    again = tmp_path / "again"
    r = CliRunner().invoke(cli, ["track", "--from", str(out), "--out", str(again), "--fps", "10",
                                 "--gsd", "0.3"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    redone = json.loads((again / "summary.json").read_text())
    assert redone["counts"]["detections"] == summary["counts"]["detections"] > 0
    assert (again / "detections.csv").read_text() == (out / "detections.csv").read_text()
    r = CliRunner().invoke(cli, args + ["--overwrite", "--workers", "2", "--scheduler", "x:1"])
    assert isinstance(r.exception, InputError) and "cannot be used together" in str(r.exception)


def test_segments_of_known_detections_track_like_the_single_process():
    """Association alone (no images): targets with known ids, cut into 2 segments run here."""
    from aerotrack.evaluation import evaluate
    from aerotrack.outputs import track_rows
    from aerotrack.parallel import assemble, gather_segments
    from aerotrack.pipeline import run

    n_frames, fps = 300, 30.0
    gt, dets = straight_detections(4, 6, n_frames, (100, 100, 1100, 600), 3.0, (30, 16))
    single = run(None, detections=dets, fps=fps)
    segs = plan_segments(1, n_frames, fps=fps, segment_s=4.0, overlap_s=4.5, min_segments=2)
    assert len(segs) == 2
    tasks = make_tasks(None, config=Config(), fps=fps, segments=segs, detections=dets)
    par, report = assemble(gather_segments(None, tasks), config=Config(), fps=fps)
    assert report.stitched == [6] and report.cut == [0]  # every target crosses the cut
    es, ep = (evaluate(gt, track_rows(r, None)[0]) for r in (single, par))
    assert ep["IDF1"] > 0.95 and len(par.tracks) == 6  # one track per target across the cut
    assert abs(es["HOTA"] - ep["HOTA"]) <= 0.01 and abs(es["IDF1"] - ep["IDF1"]) <= 0.01


def test_min_speed_without_a_scale_means_metres_per_second_in_segments_too():
    """``--min-speed`` without a map or ``--gsd``: segments, like the single process, convert it
    with the estimated ground scale (30-px boxes taken as 4.5 m: 0.15 m/px), not in pixels/s. A
    target at 0.5 px/frame (15 px/s = 2.25 m/s) is slower than 4 m/s and dropped by both; one at
    2 px/frame (9 m/s) is kept."""
    from aerotrack.parallel import assemble, gather_segments
    from aerotrack.pipeline import run

    n_frames, fps, rows = 300, 30.0, []
    for tid, (p, v) in enumerate([((100, 100), (2.0, 0.0)), ((100, 400), (0.5, 0.0)),
                                  ((800, 200), (0.0, 2.0)), ((900, 500), (-0.5, 0.0))], 1):
        for f in range(1, n_frames + 1):
            q = np.add(p, np.multiply(v, f))
            rows.append([f, tid, q[0] - 15, q[1] - 8, 30, 16, 0.9, -1, -1, -1])
    dets = np.asarray(rows)
    dets[:, 1] = -1
    single = run(None, detections=dets, fps=fps, min_speed_mps=4.0)
    segs = plan_segments(1, n_frames, fps=fps, segment_s=4.0, overlap_s=4.5, min_segments=2)
    tasks = make_tasks(None, config=Config(), fps=fps, segments=segs, detections=dets)
    par, _ = assemble(gather_segments(None, tasks), config=Config(), fps=fps, min_speed_mps=4.0)
    for result in (single, par):
        starts = sorted(float(t.points[0].box[1]) for t in result.tracks)
        assert np.allclose(starts, [92, 194], atol=3), starts  # the fast targets' top edges


def test_client_warm_up_runs_linking_for_real():
    """The client's warm-up runs global linking and the finish stage (a failure there is
    swallowed, so the flag is what shows it worked); a second call does nothing."""
    from aerotrack import parallel

    parallel._LINKING_WARM.clear()
    assert parallel.warm_up_linking() > 0 and parallel._LINKING_WARM.is_set()
    assert parallel.warm_up_linking() == 0.0


def _ctrl_c(cmd: list[str], ready: str, *, wait_s: float = 0.0, again_s: float | None = None,
            timeout: int = 150):
    """Run ``cmd`` in a session of its own, send Ctrl-C to its whole process group (as a terminal
    does) once its stderr shows ``ready`` and ``wait_s`` more seconds passed, and a second one to
    the main process ``again_s`` after; returns (process, stderr before, stderr after)."""
    import subprocess

    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    err = ""
    try:
        t0 = time.time()
        while ready not in err and time.time() - t0 < timeout:
            line = p.stderr.readline()
            if not line:
                break
            err += line
        time.sleep(wait_s)
        os.killpg(p.pid, signal.SIGINT)
        if again_s is not None:
            time.sleep(again_s)
            os.kill(p.pid, signal.SIGINT)
        rest = p.communicate(timeout=timeout)[1]
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        pytest.fail(f"no exit within {timeout} s of Ctrl-C: {err[-500:]}")
    return p, err, rest


@pytest.mark.parametrize("twice", [False, True])
def test_ctrl_c_to_the_whole_process_group_stops_a_workers_run(tmp_path, twice):
    """A terminal's Ctrl-C reaches every process of the foreground group. The local cluster's
    workers used to die of it mid-segment while the main process waited for their results
    forever (a second Ctrl-C then left no finished segment). Now the workers ignore it: the run
    stops with exit code 130 and keeps the finished work for --resume. A second Ctrl-C stops at
    once, and says that only finished segments are kept (it said "finished work is kept", while
    the running segments were lost); one arriving while the process shuts down is ignored (it
    killed the process by SIGINT, exit -2)."""

    frames = tmp_path / "frames"
    render_scene(frames, n=1200, seed=3)  # long enough to be running when Ctrl-C comes
    out = tmp_path / "run"
    p, err, rest = _ctrl_c([sys.executable, "-m", "aerotrack", "-v", "track", str(frames),
                            "--out", str(out), "--fps", str(FPS), "--workers", "2"],
                           "segments of about", wait_s=3, again_s=1 if twice else None,
                           timeout=150)  # once the cluster is up
    if p.returncode == 0:
        pytest.skip("the run finished before it could be interrupted")
    assert p.returncode == 130, err + rest
    assert (out / ".partial").is_dir()
    # it says what it waits for: the running segments, not "this frame"
    assert "when the running segments are finished" in rest, rest
    if twice:
        assert "finished segments are kept" in rest, rest
        assert "finished work is kept" not in rest and "Traceback" not in rest, rest


def test_ctrl_c_stops_a_workers_batch_between_inputs(tmp_path):
    """``batch --workers`` stopped at once on Ctrl-C, losing the input being joined; now it stops
    once that input is written (exit 130) and says what is kept, and the next batch skips it."""
    import subprocess

    inp = tmp_path / "in"
    for i in range(5):
        render_scene(inp / f"v{i}", n=300, seed=i)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "aerotrack", "-v", "batch", str(inp), "--out", str(out),
           "--fps", str(FPS), "--workers", "2"]
    p, err, rest = _ctrl_c(cmd, " frames, ", timeout=300)  # once the first input is written
    if p.returncode == 0:
        pytest.skip("the batch finished before it could be interrupted")
    assert p.returncode == 130, err + rest
    assert "once the input being joined is written" in rest and "Traceback" not in rest, rest
    assert "finished inputs are kept" in rest, rest
    finished = [d.name for d in sorted(out.iterdir()) if (d / "summary.json").is_file()]
    # the first input, and the one being joined then if any (on a loaded machine the next
    # input's segments may still be on the workers when Ctrl-C comes): exactly the inputs the
    # batch reported written are on disk, whole, and it stopped before the last
    reported = sorted(set(re.findall(r"aerotrack: (v\d): \d+ frames, ", err + rest)))
    assert "v0" in finished and finished == reported and len(finished) < 5, (finished, err + rest)
    assert not any((d / "tracks.csv").exists() for d in out.iterdir()
                   if d.is_dir() and d.name not in finished)  # nothing half-written
    again = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("already finished, skipped") == len(finished), again.stderr


def test_a_bad_scheduler_address_is_refused_within_seconds(tmp_path, client):
    """A malformed address raised a traceback; a refused port or unknown host took the
    client's 20 s; an HTTP server (the dashboard's port) hung for ever. Each is now one line
    within seconds, before --out is made; the real scheduler passes."""
    import http.server
    import threading

    from aerotrack.parallel import check_scheduler

    check_scheduler(client.scheduler.address)
    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        for address, needle in (("notanaddress", "not a scheduler address"),
                                ("tcp://127.0.0.1:99999", "not a TCP port"),
                                ("http://127.0.0.1:8787", "not http://"),
                                ("tcp://127.0.0.1:1", "cannot connect"),
                                (f"tcp://127.0.0.1:{server.server_port}", "no Dask scheduler")):
            t0 = time.perf_counter()
            with pytest.raises(InputError, match=needle):
                check_scheduler(address, timeout=2.0)
            assert time.perf_counter() - t0 < 12, address
    finally:
        server.shutdown()
        server.server_close()
    from aerotrack.cli.main import cli

    frames = tmp_path / "frames"
    render_scene(frames, n=10)
    out = tmp_path / "run"
    r = CliRunner().invoke(cli, ["track", str(frames), "--out", str(out), "--scheduler",
                                 "notanaddress"])
    assert isinstance(r.exception, InputError) and "not a scheduler address" in str(r.exception)
    assert not out.exists()


def test_a_stabilised_segment_is_not_registered(scene):
    """``track --workers N --stabilised``: every segment takes identity homographies."""
    folder, _ = scene
    segs = plan_segments(1, 120, fps=FPS, segment_s=6.0, overlap_s=4.5)
    task = make_tasks(folder, config=Config(), fps=FPS, segments=segs[1:2], metres_per_unit=0.3,
                      stabilised=True)[0]
    res = run_segment(task)
    assert res.registrations and all(np.array_equal(r.H, np.eye(3))
                                     for r in res.registrations.values())
    plain = make_tasks(folder, config=Config(), fps=FPS, segments=segs[1:2], metres_per_unit=0.3)[0]
    from aerotrack.parallel import _segment_file

    assert _segment_file(Path("x"), task) != _segment_file(Path("x"), plain)  # not resumed as one


def test_a_later_segment_carries_the_placement_onto_the_map(scene):
    """With a map, a segment after the first carries frame 1's placement to its first frame and
    runs on the map (``map_every_segment``); without, it runs in its first frame's pixels."""
    folder, _ = scene
    H1 = np.array([[1, 0, 400.0], [0, 1, 420.0], [0, 0, 1]])  # render_scene's camera at frame 1
    segs = plan_segments(1, 120, fps=FPS, segment_s=6.0, overlap_s=4.5)
    kw = dict(config=Config(), fps=FPS, segments=segs, map_path=TILE, H_init=H1)
    task = make_tasks(folder, **kw)[1]
    assert task.map_path is not None and task.carry_from == 1
    res = run_segment(task)
    assert res.on_map and res.timings["carry"] > 0
    f = res.segment.own_start
    t = (f - 1) / FPS
    truth = np.array([[1, 0, 400 + 4 * t], [0, 1, 420 + 3 * t], [0, 0, 1.0]])
    corners = np.array([[0, 0], [240, 0], [240, 180], [0, 180.0]])
    err = np.abs(apply_homography(res.registrations[f].H, corners)
                 - apply_homography(truth, corners)).max()
    assert err < 1.5, err  # map pixels
    assert any(r.status == "refined" for r in res.registrations.values())
    chained = make_tasks(folder, **kw, map_every_segment=False)[1]
    assert chained.map_path is None and chained.carry_from is None
    assert not run_segment(chained).on_map


def test_a_first_interrupt_keeps_the_segments_still_running(scene, client, tmp_path):
    """Ctrl-C while two segments run: both are finished and saved before the interrupt goes on
    (the first result's progress call raised it and the other segment's work was dropped)."""
    from aerotrack.parallel import gather_segments

    folder, _ = scene
    segs = plan_segments(1, 120, fps=FPS, segment_s=6.0, overlap_s=4.5)[:2]
    assert len(segs) == 2
    tasks = make_tasks(folder, config=Config(), fps=FPS, segments=segs, metres_per_unit=0.3)

    def progress(n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        gather_segments(client, tasks, checkpoint_dir=tmp_path, progress=progress)
    assert len(list((tmp_path / "segments").glob("segment-*.pkl"))) == 2


def test_the_python_api_carries_frame_1s_placement_to_start(scene):
    """``run``/``detect(start=60, H_init=frame 1's)`` placed frame 60 where frame 1 was (the
    command line carried it itself; the API's docstring promised it): 24 map px off here."""
    from aerotrack.geo import GeoMap
    from aerotrack.io import open_source
    from aerotrack.pipeline import detect, run

    folder, _ = scene
    geomap = GeoMap(TILE)

    def truth(f):
        t = (f - 1) / FPS
        return np.array([[1, 0, 400 + 4 * t], [0, 1, 420 + 3 * t], [0, 0, 1.0]])

    corners = np.array([[0, 0], [240, 0], [240, 180], [0, 180.0]])
    for fn in (run, detect):
        res = fn(open_source(folder, FPS), geomap=geomap, H_init=truth(1), start=60, stop=66)
        err = np.abs(apply_homography(res.registrations[60].H, corners)
                     - apply_homography(truth(60), corners)).max()
        assert err < 1.5, (fn.__name__, err)
    # the command line passes the placement it carried itself
    res = run(open_source(folder, FPS), geomap=geomap, H_init=truth(60), H_init_frame=60,
              start=60, stop=66)
    assert np.abs(apply_homography(res.registrations[60].H, corners)
                  - apply_homography(truth(60), corners)).max() < 1.5


def test_an_interrupted_batch_continues_the_input_it_was_tracking(tmp_path, scene):
    """Ctrl-C in a batch kept nothing of the input being tracked (no run.json, no state) and the
    next batch tracked it again from frame 1; now it resumes it, with the same tracks."""
    from aerotrack.io.mot import read_mot
    from aerotrack.parallel import run_batch

    inp = tmp_path / "in"
    (inp / "a").mkdir(parents=True)
    for p in sorted(scene[0].iterdir())[:120]:
        (inp / "a" / p.name).write_bytes(p.read_bytes())
    whole = run_batch(plan_batch(inp, tmp_path / "whole"), fps=FPS, metres_per_unit=0.3)
    assert not isinstance(whole["a"], BaseException)

    def stop_at_70(n):
        if n == 70:
            raise KeyboardInterrupt

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_batch(plan_batch(inp, out), fps=FPS, metres_per_unit=0.3, progress=stop_at_70)
    partial = out / "a" / ".partial"
    assert (partial / "state.npz").is_file() and (partial / "batch.json").is_file()
    seen = []
    run_batch(plan_batch(inp, out), fps=FPS, metres_per_unit=0.3, progress=seen.append)
    assert len([n for n in seen if n]) == 50  # frames 71-120, not 1-120 (0: between inputs)
    assert (read_mot(out / "a" / "tracks.csv") == read_mot(tmp_path / "whole" / "a" / "tracks.csv")).all()
    # other settings: tracked again from frame 1
    with pytest.raises(KeyboardInterrupt):
        run_batch(plan_batch(inp, tmp_path / "o2"), fps=FPS, metres_per_unit=0.3,
                  progress=stop_at_70)
    seen.clear()
    said = _Said()
    logging.getLogger("aerotrack").addHandler(said)
    try:
        run_batch(plan_batch(inp, tmp_path / "o2"), fps=FPS, metres_per_unit=0.3, seed=4,
                  progress=seen.append)
    finally:
        logging.getLogger("aerotrack").removeHandler(said)
    assert len([n for n in seen if n]) == 120
    # ... and said so (it started again silently)
    assert any("not continued" in m and "settings differ" in m for m in said.lines), said.lines


class _Said(logging.Handler):
    """The messages of the ``aerotrack`` logger, whatever its propagation."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def test_a_ground_plane_runs_on_dask_segments_like_one_process(tmp_path, scene, client):
    """``track --ground`` on segments: every segment carries the plane to its first frame (as
    with a map) instead of running in its own first frame's pixels, whose metres would then be
    wrong; the result scores as the single process's."""
    from aerotrack.cli.main import cli
    from aerotrack.evaluation import evaluate
    from aerotrack.io.mot import read_mot

    folder, gt = scene
    w, h = 240, 180
    ground = tmp_path / "ground.csv"
    ground.write_text("frame_x,frame_y,ground_x,ground_y\n0,0,0,0\n"
                      f"{w},0,{0.3 * w},0\n{w},{h},{0.3 * w},{-0.3 * h}\n0,{h},0,{-0.3 * h}\n")
    scores = {}
    for name, extra in (("one", []), ("dask", ["--scheduler", client.scheduler.address])):
        out = tmp_path / name
        r = CliRunner().invoke(cli, ["-v", "track", str(folder), "--out", str(out), "--fps",
                                     str(FPS), "--ground", str(ground), *extra],
                               catch_exceptions=False)
        assert r.exit_code == 0, r.output
        if name == "dask":
            assert "2 segments" in r.output or "3 segments" in r.output, r.output
        scores[name] = evaluate(gt, read_mot(out / "tracks.csv"))
        assert json.loads((out / "summary.json").read_text())["metres_per_unit"] == 1.0
    assert scores["one"]["HOTA"] > 0.5
    assert abs(scores["dask"]["HOTA"] - scores["one"]["HOTA"]) < 0.03, scores
    assert abs(scores["dask"]["IDF1"] - scores["one"]["IDF1"]) < 0.05, scores


def _malloc_environment():
    import os

    return {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_",
                                           "OMP_NUM_THREADS")}


def test_workers_allocate_frames_as_a_single_process_does(client):
    """Dask's MALLOC_TRIM_THRESHOLD_ of 64 kB turned off glibc's sliding mmap threshold in the
    workers: every frame-sized array was mapped and zeroed anew (9 M page faults and 2.2x the
    wall time on a 1080p scene). The local cluster's workers get the thresholds a single process
    reaches (trim 128 MB, mmap 32 MB), and still one OpenMP thread."""
    envs = client.run(_malloc_environment)
    assert len(envs) == 2
    for env in envs.values():
        assert env == {"MALLOC_TRIM_THRESHOLD_": str(2**27), "MALLOC_MMAP_THRESHOLD_": str(2**25),
                       "OMP_NUM_THREADS": "1"}


def test_segments_of_known_detections_on_a_map_keep_the_still_placement():
    """Detections alone with a map and its placement: every segment places the boxes through
    it, and the joined result keeps it (boxes in frame pixels, the placement in the outputs), as
    the single process does; the segments' run reported identity rows before."""
    from aerotrack.evaluation import evaluate
    from aerotrack.geo import GeoMap
    from aerotrack.outputs import registration_rows, track_rows
    from aerotrack.parallel import assemble, gather_segments
    from aerotrack.pipeline import run

    n_frames, fps = 300, 30.0
    gt, dets = straight_detections(5, 5, n_frames, (60, 60, 500, 400), 0.3, (15, 9))
    geomap = GeoMap(TILE)
    H = np.array([[1.0, 0.0, 300.0], [0.0, 1.0, 250.0], [0.0, 0.0, 1.0]])
    single = run(None, detections=dets, fps=fps, geomap=geomap, H_init=H)
    segs = plan_segments(1, n_frames, fps=fps, segment_s=4.0, overlap_s=4.5, min_segments=2)
    tasks = make_tasks(None, config=Config(), fps=fps, segments=segs, detections=dets,
                       map_path=TILE, H_init=H)
    par, _ = assemble(gather_segments(None, tasks), config=Config(), fps=fps, geomap=geomap,
                      still_H=H)
    for r in (single, par):
        np.testing.assert_array_equal(r.still_H, H)
        assert {g.status for g in registration_rows(r)} == {"still"}
        assert evaluate(gt, track_rows(r, geomap)[0])["HOTA"] > 0.9
        world = np.concatenate([t.world() for t in r.tracks])
        assert world[:, 0].min() > 300  # map pixels, not the detections' own


def test_batch_names_an_input_whose_detections_changed_and_keeps_quiet_on_own_rates(tmp_path,
                                                                                    capsys):
    """A det.txt regenerated in place after its sequence was tracked was skipped silently; and a
    batch run again with --fps warned "finished with other --fps" for sequences that keep their
    own rate whatever --fps says."""
    import os

    from conftest import run_cli

    seq = tmp_path / "bench" / "S1"
    (seq / "img1").mkdir(parents=True)
    (seq / "det").mkdir()
    rng = np.random.default_rng(0)
    for i in range(12):
        cv2.imwrite(str(seq / "img1" / f"{i + 1:06d}.png"),
                    rng.integers(0, 255, (60, 80, 3), dtype=np.uint8))
    (seq / "seqinfo.ini").write_text("[Sequence]\nimDir=img1\nframeRate=30\n")
    det = seq / "det" / "det.txt"
    det.write_text("".join(f"{f},-1,{10 + f},10,8,4,0.9\n" for f in range(1, 13)))
    args = ["batch", tmp_path / "bench", "--out", tmp_path / "out", "--detections", "det/det.txt"]
    code, _, err = run_cli(capsys, *args)
    assert code == 0, err
    code, _, err = run_cli(capsys, *args, "--fps", "30")
    assert "already finished, skipped" in err and "other --fps" not in err, err
    det.write_text("".join(f"{f},-1,{10 + f},10,8,4,0.9\n" for f in range(1, 7)))
    os.utime(det, ns=(det.stat().st_atime_ns, det.stat().st_mtime_ns + 10**9))
    code, _, err = run_cli(capsys, *args)
    assert "S1: finished with other detections (det.txt changed since)" in err, err
    assert "1 skipped (1 of them tracked with other settings)" in err, err  # (the last line too)
    # --min-conf, as track's: every box here is 0.9
    code, _, err = run_cli(capsys, "batch", tmp_path / "bench", "--out", tmp_path / "out2",
                           "--detections", "det/det.txt", "--min-conf", "0.95")
    assert code == 0, err
    assert (tmp_path / "out2" / "S1" / "detections.csv").read_text() == ""


def test_an_interrupt_while_an_input_is_finished_stops_before_the_next(tmp_path, scene):
    """A Ctrl-C that came while an input was being linked and written (after its last frame)
    let the batch start the next input and stop after its first frame, leaving a .partial of
    one frame. Now the batch stops between the two."""
    from aerotrack.parallel import run_batch

    inp = tmp_path / "in"
    for name in ("a", "b"):
        (inp / name).mkdir(parents=True)
        for p in sorted(scene[0].iterdir())[:20]:
            (inp / name / p.name).write_bytes(p.read_bytes())
    items = plan_batch(inp, tmp_path / "out")
    calls = []

    def progress(n):
        calls.append(n)
        if n == 0 and any(c > 0 for c in calls):  # asked between the inputs, after a's frames
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(items, fps=FPS, metres_per_unit=0.3, progress=progress)
    assert (tmp_path / "out" / "a" / "summary.json").is_file()
    assert not (tmp_path / "out" / "b").exists()


def test_batch_writes_each_inputs_hints_as_track_does(tmp_path, scene, capsys):
    """`batch` wrote no hints: a 5-frame clip's "0 tracks" came with no word (summary.json
    `hints` absent), which `track` explains; each input's warnings are now logged under its name
    and written to its summary.json, alike for both."""
    from conftest import run_cli

    folder, _ = scene
    videos = tmp_path / "videos"
    (videos / "short").mkdir(parents=True)
    for p in sorted(folder.iterdir())[:5]:
        (videos / "short" / p.name).write_bytes(p.read_bytes())
    code, _, err = run_cli(capsys, "batch", videos, "--out", tmp_path / "out", "--fps", "30")
    assert code == 0 and "short: the clip is 5 frames" in err, err
    got = json.loads((tmp_path / "out" / "short" / "summary.json").read_text())["hints"]
    code, _, err = run_cli(capsys, "track", videos / "short", "--out", tmp_path / "one",
                           "--fps", "30")
    assert code == 0, err
    assert got == json.loads((tmp_path / "one" / "summary.json").read_text())["hints"]


def test_batch_output_names_apart_on_case_insensitive_disks(tmp_path):
    """Clip.AVI and clip.mkv went to Clip/ and clip/, one folder on macOS, Windows and exFAT:
    stems alike but for case keep their suffixes, as equal stems do."""
    inp = tmp_path / "in"
    inp.mkdir()
    for name in ("Clip.AVI", "clip.mkv", "DJI_0001.MOV", "DJI_0001.MP4", "other.mp4"):
        (inp / name).write_bytes(b"\0" * 10)
    names = sorted(i.name for i in plan_batch(inp, tmp_path / "out"))
    assert names == ["Clip.AVI", "DJI_0001.MOV", "DJI_0001.MP4", "clip.mkv", "other"]
    assert len({n.casefold() for n in names}) == len(names)
    # an earlier batch's Clip/ (by the stem alone) keeps its results (a reviewer)
    (tmp_path / "out" / "Clip").mkdir(parents=True)
    names = sorted(i.name for i in plan_batch(inp, tmp_path / "out"))
    assert "Clip" in names and "Clip.AVI" not in names


def test_batch_of_a_camera_card_names_the_folder_with_the_videos(tmp_path, capsys):
    """`batch DCIM` (videos in DCIM/100MEDIA/) said only "no video files or image folders"."""
    from conftest import run_cli

    (tmp_path / "DCIM" / "100MEDIA").mkdir(parents=True)
    (tmp_path / "DCIM" / "100MEDIA" / "DJI_0001.MP4").write_bytes(b"\0" * 10)
    code, _, err = run_cli(capsys, "batch", tmp_path / "DCIM", "--out", tmp_path / "out")
    assert code == 2 and "sub-folder 100MEDIA: give that folder" in err, err
    hidden = tmp_path / ".cards" / "DCIM" / "100MEDIA"  # a hidden folder above it is fine
    hidden.mkdir(parents=True)
    (hidden / "DJI_0001.MP4").write_bytes(b"\0" * 10)
    code, _, err = run_cli(capsys, "batch", hidden.parent, "--out", tmp_path / "out")
    assert code == 2 and "sub-folder 100MEDIA: give that folder" in err, err


def test_batch_keeps_an_earlier_folder_for_one_input_alike_but_for_case(tmp_path, monkeypatch):
    """On a case-insensitive disk an earlier Clip/ made clip "exist" too, and both inputs went
    back to bare stems, one folder (a reviewer): only the exact name, and only once, is kept."""
    inp = tmp_path / "in"
    inp.mkdir()
    for name in ("Clip.AVI", "clip.mkv"):
        (inp / name).write_bytes(b"\0" * 10)
    (tmp_path / "out" / "Clip").mkdir(parents=True)
    real = Path.exists
    monkeypatch.setattr(Path, "exists", lambda p: real(p) or (  # a case-insensitive disk
        p.parent.is_dir() and p.name.casefold() in {q.casefold() for q in os.listdir(p.parent)}))
    names = sorted(i.name for i in plan_batch(inp, tmp_path / "out"))
    assert names == ["Clip", "clip.mkv"], names

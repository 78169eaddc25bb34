"""Following vehicles that stop where the detector loses them (association/follow.py): real
frames and the real pipeline, detections given from outside so that the loss is known."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from aerotrack.config import Config
from aerotrack.errors import ConfigError
from aerotrack.pipeline import Pipeline
from aerotrack.types import Frame

FPS = 30.0
W, H = 320, 160
CAR = (28, 12)  # px; 0.25 m/px: 7 x 3 m
GSD = 0.25


def _car_texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = rng.integers(40, 230, size=(CAR[1], CAR[0], 3)).astype(np.uint8)
    tex = cv2.GaussianBlur(tex, (3, 3), 0)  # a painted body, not pixel noise
    tex[:, :4] = 250  # a bright front, a dark rear: contrast on any road
    tex[:, -4:] = 20
    return tex


def _scene(x_of, n: int, detected, painted_at=None):
    """Frames of a textured road with one car at ``x_of(f)`` (None: gone), and the detections
    of the frames ``detected(f)`` says it was seen in (MOT rows). ``painted_at``: the car's
    texture also painted on the road there (a fixed pattern)."""
    rng = np.random.default_rng(0)
    road = rng.normal(110, 6, size=(H, W, 3)).clip(0, 255).astype(np.uint8)
    tex = _car_texture(1)
    y = 70
    if painted_at is not None:
        road[y:y + CAR[1], painted_at:painted_at + CAR[0]] = tex
    frames, dets = [], {}
    for f in range(1, n + 1):
        img = road.copy()
        x = x_of(f)
        if x is not None:
            xi = int(round(x))
            img[y:y + CAR[1], xi:xi + CAR[0]] = tex
            if detected(f):
                dets[f] = np.array([[f, -1, xi, y, CAR[0], CAR[1], 1.0]], float)
        frames.append(Frame(f, img, (f - 1) / FPS))
    return frames, dets


def _track(frames, dets, follow: bool, stop_gap: bool = False):
    """Tracked with or without following; the finish stage's stop-and-go fill
    (``finish.stop_gap_speed_mps``), which also reports such a stop, off unless ``stop_gap``."""
    cfg = Config()
    cfg = dataclasses.replace(cfg, association=dataclasses.replace(
        cfg.association, follow_stopped=follow))
    if not stop_gap:
        cfg = dataclasses.replace(cfg, finish=dataclasses.replace(cfg.finish,
                                                                  stop_gap_speed_mps=0.0))
    pipe = Pipeline(cfg, FPS, detections=dets, metres_per_unit=GSD, stabilised=True, seed=0)
    for fr in frames:
        pipe.step(fr)
    return pipe.finish(), pipe


V0 = 8.0 / GSD / FPS  # 8 m/s, px per frame
ACC = 4.0 / GSD / FPS ** 2  # 4 m/s^2, px per frame^2
BRAKE = 80  # the frame it starts braking in
STOP_F = BRAKE + int(round(V0 / ACC))  # the frame it stands from (2 s later)
STOP_X = 10 + V0 * (BRAKE - 60) + V0 * V0 / (2 * ACC)
GO_F = STOP_F + 60  # stands 2 s


def _stop_and_go(f, stand: int = GO_F - STOP_F):
    """Enters at frame 61 at 8 m/s, brakes at 4 m/s^2 from frame 80 to a stop (frame 140), stands
    2 s, then drives off at 4 m/s^2. The first 60 frames show the empty road (following compares
    the place with how it looked 2 s before)."""
    if f <= 60:
        return None
    if f <= BRAKE:
        return 10 + V0 * (f - 60)
    if f <= STOP_F:
        t = f - BRAKE
        return 10 + V0 * (BRAKE - 60) + V0 * t - 0.5 * ACC * t * t
    go = STOP_F + stand
    if f <= go:
        return STOP_X
    x = STOP_X + 0.5 * ACC * (f - go) ** 2
    return x if x + CAR[0] < W else None


def _seen(f):
    """Detected until it creeps under 2 m/s, lost while it stands, detected again once it has
    driven off at 2 m/s."""
    return f <= BRAKE + 45 or f >= GO_F + 15


def _rows_at_stop(result, frames_range):
    """Frames of ``frames_range`` in which some in-view track row overlaps the stopped car."""
    out = set()
    for t in result.tracks:
        for p in t.points:
            if (p.frame in frames_range and p.kind != "predicted" and p.box is not None
                    and abs(p.box[0] - STOP_X) < 4 and abs(p.box[1] - 70) < 4):
                out.add(p.frame)
    return out


def test_a_car_lost_while_stopping_is_followed_while_it_stands_and_not_after():
    frames, dets = _scene(_stop_and_go, GO_F + 80, _seen)
    base, _ = _track(frames, dets, follow=False)
    res, pipe = _track(frames, dets, follow=True)
    standing = range(STOP_F, GO_F)
    assert len(_rows_at_stop(base, standing)) < 10  # without following: the stop is missing
    held = _rows_at_stop(res, standing)
    assert len(held) >= 0.9 * len(standing)
    assert pipe.follower.n_followed >= 50
    # the same identity before, during and after the stop
    ids = {t.id for t in res.tracks for p in t.points
           if p.kind == "observed" and p.frame in (BRAKE, STOP_F + 30, GO_F + 40)}
    assert len(ids) == 1
    # once the car has left its place (4 px by GO_F + 25), nothing is reported there
    assert not _rows_at_stop(res, range(GO_F + 30, GO_F + 80))
    # without following, the finish stage's stop-and-go fill reports the stop too (lost while
    # braking, found again while pulling away), under the same identity
    filled, _ = _track(frames, dets, follow=False, stop_gap=True)
    assert len(_rows_at_stop(filled, standing)) >= 0.9 * len(standing)
    assert len({t.id for t in filled.tracks for p in t.points
                if p.kind == "observed" and p.frame in (BRAKE, GO_F + 40)}) == 1


def test_a_fixed_pattern_is_not_followed():
    # the same car, but its look-alike is painted on the road where it stops: the place looked
    # the same before it arrived, so following cannot tell the car from the road
    frames, dets = _scene(_stop_and_go, GO_F + 80, _seen, painted_at=int(round(STOP_X)))
    _, pipe = _track(frames, dets, follow=True)
    assert pipe.follower.n_followed == 0


def test_a_car_that_stood_before_it_was_lost_is_followed():
    # the detector kept it for 3 s of standing (as hold_stopped does), then lost it for 2 s: the
    # place is compared with how it looked before the car came, not 2 s before it was lost
    stand = 150
    frames, dets = _scene(lambda f: _stop_and_go(f, stand), STOP_F + stand + 60,
                          lambda f: f <= STOP_F + 90 or f >= STOP_F + stand + 15)
    res, pipe = _track(frames, dets, follow=True)
    lost = range(STOP_F + 95, STOP_F + stand)
    assert len(_rows_at_stop(res, lost)) >= 0.9 * len(lost)
    assert pipe.follower.n_followed >= 40


def _write_scene(folder, frames, dets):
    """The frames as PNG files in ``folder/frames`` and the detections as a MOT file: the
    inputs of ``aerotrack track``."""
    from aerotrack.io.mot import write_mot

    (folder / "frames").mkdir(parents=True)
    for fr in frames:
        cv2.imwrite(str(folder / "frames" / f"{fr.index:05d}.png"), fr.image)
    write_mot(folder / "dets.txt", np.vstack([dets[f] for f in sorted(dets)]))
    return folder / "frames", folder / "dets.txt"


def test_summary_counts_the_followed_detections(tmp_path, capsys):
    """summary.json says how many detections the follower added (they are not among the
    detector's: ``counts.detections``), and says nothing of following when it is off."""
    import json

    from conftest import run_cli

    frames, dets = _scene(_stop_and_go, GO_F + 80, _seen)
    folder, rows = _write_scene(tmp_path, frames, dets)
    counts = {}
    for follow in ("false", "true"):
        out = tmp_path / follow
        code, _, err = run_cli(capsys, "-q", "track", folder, "--detections", rows, "--out", out,
                               "--fps", FPS, "--gsd", GSD, "--set",
                               f"association.follow_stopped={follow}")
        assert code == 0, err
        counts[follow] = json.loads((out / "summary.json").read_text())["counts"]
    assert "followed_detections" not in counts["false"]
    assert counts["true"]["followed_detections"] >= 50  # the car through its 2 s stop
    assert counts["true"]["detections"] == counts["false"]["detections"] == len(dets)


def test_a_correlation_above_one_is_refused():
    cfg = Config()
    cfg = dataclasses.replace(cfg, association=dataclasses.replace(
        cfg.association, follow_stopped=True, follow_min_ncc=1.5))
    with pytest.raises(ConfigError, match="follow_min_ncc"):
        Pipeline(cfg, FPS, metres_per_unit=GSD, stabilised=True)


def test_a_follower_counts_only_the_frames_it_is_told_to_and_follows_alike():
    """A segment of a parallel run counts the followed detections of the frames it owns (its
    warm-up and tail belong to its neighbours); what it follows does not change."""
    frames, dets = _scene(_stop_and_go, GO_F + 80, _seen)
    runs = []
    for count in (None, (1, STOP_F + 20), (STOP_F + 21, len(frames))):
        cfg = Config()
        cfg = dataclasses.replace(cfg, association=dataclasses.replace(
            cfg.association, follow_stopped=True))
        pipe = Pipeline(cfg, FPS, detections=dets, metres_per_unit=GSD, stabilised=True, seed=0)
        pipe.follower.count_frames = count
        for fr in frames:
            pipe.step(fr)
        res = pipe.finish()
        runs.append((res.followed, [(p.frame, tuple(p.box)) for t in res.tracks
                                    for p in t.points]))
    (n_all, rows_all), (n_a, rows_a), (n_b, rows_b) = runs
    assert n_all >= 50 and 0 < n_a < n_all and 0 < n_b < n_all and n_a + n_b == n_all
    assert rows_a == rows_all == rows_b


def test_segments_report_the_followed_detections(tmp_path):
    """``--workers`` runs say how many detections the follower added, as one process does."""
    from aerotrack.io import open_source, read_mot
    from aerotrack.parallel import assemble, gather_segments, make_tasks, plan_segments
    from aerotrack.pipeline import run

    frames, dets = _scene(_stop_and_go, GO_F + 80, _seen)
    folder, rows = _write_scene(tmp_path, frames, dets)
    cfg = Config()
    cfg = dataclasses.replace(cfg, association=dataclasses.replace(
        cfg.association, follow_stopped=True))
    det_rows = read_mot(rows)
    single = run(open_source(folder, FPS), config=cfg, fps=FPS, detections=det_rows,
                 metres_per_unit=GSD)
    segs = plan_segments(1, len(frames), fps=FPS, segment_s=100.0, overlap_s=4.5)
    tasks = make_tasks(folder, config=cfg, fps=FPS, segments=segs, detections=det_rows,
                       metres_per_unit=GSD)
    par, _ = assemble(gather_segments(None, tasks), config=cfg, fps=FPS)
    assert single.followed >= 50 and par.followed == single.followed

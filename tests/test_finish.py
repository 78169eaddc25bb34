"""Finishing of final tracks (aerotrack.association.finish): smoothing, one size per vehicle,
border handling and static-track rejection, on tracks with a known truth."""

from __future__ import annotations

import copy
import dataclasses
import logging
import math

import numpy as np
import pytest

from aerotrack.association.finish import (
    TrackFinisher,
    finish_tracks,
    footprint_box,
    is_small,
    is_static,
    oriented_size,
    robust_smooth,
    rts_smooth,
    suppress_overlaps,
    wanders,
    window_sizes,
)
from aerotrack.config import Config, FinishConfig, load_config
from aerotrack.errors import ConfigError
from aerotrack.kalman import ConstantVelocityKF, measurement_noise
from aerotrack.pipeline import link
from aerotrack.types import Registration, Track, TrackPoint, apply_homography

FPS = 30.0
MPU = 0.1  # metres per world unit


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x0 = np.maximum(a[:, 0], b[:, 0])
    y0 = np.maximum(a[:, 1], b[:, 1])
    x1 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y1 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    return inter / (a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter)


def _homography(k: int) -> np.ndarray:
    """Frame k pixels -> world: a slowly rotating, zooming, drifting camera."""
    a = math.radians(20 + 0.1 * k)
    s = 1.0 + 0.001 * k
    return np.array([[s * math.cos(a), -s * math.sin(a), 100 + 0.5 * k],
                     [s * math.sin(a), s * math.cos(a), 50 - 0.3 * k],
                     [0, 0, 1.0]])


def _vehicle(n: int = 120, length_m: float = 4.5, width_m: float = 2.0, seed: int = 0,
             partial: float = 0.25, jitter_px: float = 1.0, wait: int = 0):
    """A vehicle turning through 90 degrees seen by the camera above; observed boxes are the true
    footprint boxes with jitter and a share of partial (shrunk, shifted) boxes.

    Returns (track, registrations, true boxes (n, 4))."""
    rng = np.random.default_rng(seed)
    L, W = length_m / MPU, width_m / MPU
    regs, pts, truth = {}, [], []
    pos, speed = np.array([300.0, 300.0]), 10.0 / MPU / FPS  # 10 m/s in world units per frame
    for k in range(1, n + 1):
        heading = math.radians(min(90.0, max(0.0, (k - 40) * 1.5)))
        if k > wait:
            pos = pos + speed * np.array([math.cos(heading), math.sin(heading)])
        H = _homography(k)
        regs[k] = Registration(index=k, H=H)
        true = footprint_box(np.linalg.inv(H), pos, heading, L, W)
        box = true.copy()
        box[:2] += rng.normal(0, jitter_px, 2)
        if rng.random() < partial:  # half absorbed: one end missing
            cut = rng.uniform(0.2, 0.45)
            box[2] *= 1 - cut
            if rng.random() < 0.5:
                box[0] += true[2] * cut
        centre = box[:2] + box[2:] / 2
        world = apply_homography(H, centre[None])[0]
        pts.append(TrackPoint(frame=k, box=box, world=world, conf=1.0, kind="observed"))
        truth.append(true)
    return Track(id=1, points=pts), regs, np.array(truth)


def _boxes(track: Track) -> np.ndarray:
    return np.array([p.box for p in track.points])


def test_rts_recovers_constant_velocity_line():
    rng = np.random.default_rng(1)
    t = np.arange(60) / FPS
    true = np.column_stack([100 + 50 * t, 20 - 30 * t])
    z = np.column_stack([true + rng.normal(0, 2.0, true.shape), np.full((60, 2), 20.0)])
    kf = ConstantVelocityKF(accel_std=5.0, size_std=1.0, vel_std=100.0)
    R = np.array([measurement_noise(np.array([20.0, 20.0]), 2.0, 0.0, 1.0, 0.0)] * 60)
    xs, _ = rts_smooth(t, z, R, kf)
    raw = np.sqrt(np.mean((z[:, :2] - true) ** 2))
    smooth = np.sqrt(np.mean((xs[:, :2] - true) ** 2))
    assert smooth < 0.5 * raw
    assert np.allclose(xs[:, 4:6].mean(axis=0), [50, -30], atol=3)


def test_rts_predicts_through_missing_observations():
    t = np.arange(30) / FPS
    true = np.column_stack([10 * np.arange(30), np.zeros(30)])
    z = np.column_stack([true, np.full((30, 2), 5.0)])
    z[10:20] = np.nan
    R = np.array([np.eye(4) * 0.01] * 30)
    xs, _ = rts_smooth(t, z, R, ConstantVelocityKF(accel_std=1.0, vel_std=500.0))
    assert np.abs(xs[10:20, 0] - true[10:20, 0]).max() < 1.0


def test_robust_smooth_downweights_an_outlier():
    t = np.arange(40) / FPS
    true = np.column_stack([np.arange(40) * 3.0, np.zeros(40)])
    z = np.column_stack([true, np.full((40, 2), 10.0)])
    z[20, :2] += [0, 30]  # a merged blob pulls one centre 30 units off
    R = np.array([np.eye(4)] * 40)
    kf = ConstantVelocityKF(accel_std=30.0, vel_std=200.0)
    plain, _ = rts_smooth(t, z, R, kf)
    robust, w = robust_smooth(t, z, R, kf, outlier_chi2=9.0, iters=3)
    assert w[20] > 10 and np.all(w[np.arange(40) != 20] < 2)
    assert abs(robust[20, 1]) < 0.3 * abs(plain[20, 1])


def test_oriented_size_recovers_length_and_width():
    rng = np.random.default_rng(2)
    n = 50
    heads = rng.uniform(0, 2 * np.pi, n)
    Js = np.array([[[2 * math.cos(a), -2 * math.sin(a)], [2 * math.sin(a), 2 * math.cos(a)]]
                   for a in rng.uniform(0, 1, n)])
    boxes = np.array([footprint_box(np.vstack([np.hstack([J, [[0], [0]]]), [0, 0, 1]]),
                                    np.zeros(2), h, 45.0, 20.0) for J, h in zip(Js, heads)])
    L, W = oriented_size(boxes, Js, heads, 0.5, 0.45)
    assert L == pytest.approx(45.0, rel=0.01) and W == pytest.approx(20.0, rel=0.02)
    shrunk = boxes.copy()
    shrunk[: n // 3, 2:] *= 0.7  # a third partial
    L2, _ = oriented_size(shrunk, Js, heads, 0.6, 0.45)
    assert L2 == pytest.approx(45.0, rel=0.05)


def test_finisher_improves_boxes_of_a_turning_vehicle_under_a_rotating_camera():
    track, regs, truth = _vehicle()
    before = _iou(_boxes(track), truth).mean()
    out = finish_tracks([track], FinishConfig(size_mode="oriented", size_quantile=0.6), FPS,
                        metres_per_unit=MPU, registrations=regs, frame_size=(4000, 4000))
    after = _iou(_boxes(out[0]), truth).mean()
    assert before < 0.9 and after > before + 0.06
    assert after > 0.92


def test_each_piece_helps_alone():
    track, regs, truth = _vehicle(seed=3)
    base = _iou(_boxes(track), truth).mean()
    scores = {}
    for name, fields in {"smooth": {"size_mode": "detection"},
                         "size": {"smooth": False, "size_mode": "oriented", "size_quantile": 0.6},
                         "window": {"size_mode": "window"}}.items():
        t = Track(id=1, points=[dataclasses.replace(p) for p in track.points])
        cfg = dataclasses.replace(FinishConfig(), **fields)
        (t,) = finish_tracks([t], cfg, FPS, metres_per_unit=MPU, registrations=regs)
        scores[name] = _iou(_boxes(t), truth).mean()
    assert scores["size"] > base + 0.005
    assert scores["smooth"] > base + 0.02
    assert scores["window"] > scores["smooth"]


def test_disabled_leaves_tracks_alone():
    track, regs, _ = _vehicle()
    boxes = _boxes(track).copy()
    out = finish_tracks([track], FinishConfig(enabled=False), FPS, registrations=regs)
    assert np.array_equal(_boxes(out[0]), boxes)


def _parked(seed: int = 0, n: int = 90, jitter_m: float = 0.5) -> Track:
    rng = np.random.default_rng(seed)
    pts = []
    for k in range(1, n + 1):
        c = np.array([500.0, 500.0]) + rng.normal(0, jitter_m / MPU, 2)
        pts.append(TrackPoint(frame=k, box=np.array([c[0] - 22, c[1] - 10, 45, 20]), world=c,
                              conf=1.0, kind="observed"))
    return Track(id=2, points=pts)


def test_static_tracks_are_dropped_and_waiting_vehicles_kept():
    identity = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 200)}
    waiting, _, _ = _vehicle(n=150, wait=90, partial=0.0)  # stands 3 s, then drives 2 m/s... away
    for p in waiting.points:  # in the identity world of these registrations
        p.world = p.box[:2] + p.box[2:] / 2
    cfg = FinishConfig(static_extent_m=4.0)
    out = finish_tracks([_parked(), waiting], cfg, FPS, metres_per_unit=MPU,
                        registrations=identity)
    assert [t.id for t in out] == [1]
    # without registrations the world is the image of a camera that may follow the vehicle
    out = finish_tracks([_parked()], cfg, FPS, metres_per_unit=MPU)
    assert len(out) == 1
    assert not is_static(np.array([[0, 0], [50, 0]]), MPU, 4.0)
    assert is_static(np.array([[0, 0], [30, 0]]), MPU, 4.0)
    # seen for a moment (a short clip): 3 m in 0.67 s is a car at 4.5 m/s, not a parked one
    assert not is_static(np.array([[0, 0], [30, 0]]), MPU, 4.0, 0.67, 3.0)
    assert is_static(np.array([[0, 0], [5, 0]]), MPU, 4.0, 0.67, 3.0)  # 0.5 m of jitter
    assert is_static(np.array([[0, 0], [30, 0]]), MPU, 4.0, 5.0, 3.0)


def test_a_car_crossing_a_short_clip_is_not_dropped_as_parked():
    """A probe's 20-frame clip (0.67 s): cars at 3.4-10 m/s covered less than static_extent_m
    and two of three were dropped as "standing still" (13 of 80 boxes matched, 35 now)."""
    identity = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 200)}
    car, _, _ = _vehicle(n=10, wait=0, partial=0.0)  # 0.33 s at 10 m/s
    for p in car.points:
        p.world = p.box[:2] + p.box[2:] / 2
    span = np.ptp([p.world for p in car.points], axis=0)
    extent = np.hypot(*span) * MPU
    assert extent > 1.0 and extent < 4.0  # inside static_extent_m
    assert len(finish_tracks([car], FinishConfig(), FPS, metres_per_unit=MPU,
                             registrations=identity)) == 1


def _walk(xs_m: np.ndarray, seed: int = 0, jitter_m: float = 0.3, tid: int = 3) -> Track:
    """A track along x (metres per frame in ``xs_m``) with observation jitter."""
    rng = np.random.default_rng(seed)
    pts = []
    for k, x in enumerate(xs_m, start=1):
        c = np.array([500.0 + x / MPU, 500.0]) + rng.normal(0, jitter_m / MPU, 2)
        pts.append(TrackPoint(frame=k, box=np.array([c[0] - 22, c[1] - 10, 45, 20]), world=c,
                              conf=1.0, kind="observed"))
    return Track(id=tid, points=pts)


def test_a_track_that_goes_back_and_forth_over_a_few_metres_is_dropped():
    """The parallax of a tree's edge under a moving camera sweeps over a few metres of ground and
    back; a vehicle creeping in a queue, or waiting and then driving off, covers about as much
    ground but goes one way."""
    identity = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 400)}
    t = np.arange(240) / FPS  # 8 s
    parallax = _walk(3.0 * np.sin(2 * np.pi * t / 4.0), tid=3)  # 6 m sweeps, 4 s period
    creeping = _walk(0.8 * t, tid=4)  # 6.4 m in 8 s
    waiting = _walk(np.where(t < 5, 0.0, 3.0 * (t - 5)), tid=5)  # 5 s standing, then 9 m
    cfg = FinishConfig()
    out = finish_tracks([parallax, creeping, waiting], cfg, FPS, metres_per_unit=MPU,
                        registrations=identity)
    assert sorted(tr.id for tr in out) == [4, 5]
    off = finish_tracks([parallax], dataclasses.replace(cfg, wander_extent_m=0.0), FPS,
                        metres_per_unit=MPU, registrations=identity)
    assert len(off) == 1
    # without registrations the world is the image of a moving camera: kept
    assert len(finish_tracks([parallax], cfg, FPS, metres_per_unit=MPU)) == 1
    line = np.c_[np.linspace(0, 60, 50), np.zeros(50)]
    times = np.arange(50) / 10.0
    assert not wanders(line, times, MPU, 10.0, 2.0, 0.5)  # 6 m one way
    back = np.r_[line, line[::-1], line]
    assert wanders(back, np.arange(150) / 10.0, MPU, 10.0, 2.0, 0.5)  # 6 m there, back, there
    assert not wanders(back[:100], np.arange(100) / 10.0, MPU, 10.0, 2.0, 0.5)  # once back: 2x
    assert not wanders(back * 3, np.arange(150) / 10.0, MPU, 10.0, 2.0, 0.5)  # 18 m: a vehicle


def test_border_boxes_are_rebuilt_and_clipped():
    # a vehicle driving out through the right edge of a 640-px-wide frame (identity camera)
    regs = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 61)}
    L, W = 45.0, 20.0
    pts, truth = [], []
    for k in range(1, 61):
        cx = 500 + 3.0 * k
        true = np.array([cx - L / 2, 300 - W / 2, L, W])
        x0, x1 = true[0], min(true[0] + L, 640.0)
        box = np.array([x0, true[1], x1 - x0, W])
        if box[2] <= 0:
            break
        pts.append(TrackPoint(frame=k, box=box, world=box[:2] + box[2:] / 2, conf=1.0))
        clipped = true.copy()
        clipped[2] = x1 - x0
        truth.append(clipped)
    track = Track(id=1, points=pts)
    raw_world = np.array([p.world for p in pts])
    (out,) = finish_tracks([track], FinishConfig(clip_to_frame=True), FPS, metres_per_unit=MPU,
                           registrations=regs,
                           frame_size=(640, 480))
    boxes = _boxes(out)
    assert np.all(boxes[:, 0] + boxes[:, 2] <= 640 + 1e-9)
    assert _iou(boxes, np.array(truth)).min() > 0.9
    # ground points of the clipped boxes moved back towards the true centres
    world = np.array([p.world for p in out.points])
    true_x = 500 + 3.0 * np.arange(1, len(pts) + 1)
    assert np.abs(world[:, 0] - true_x).mean() < 0.3 * np.abs(raw_world[:, 0] - true_x).mean()


def test_a_vehicle_mostly_past_the_border_is_out_of_view():
    """tracks.csv holds the frames a target is in view; a whole-vehicle box whose centre is past
    the border (more than half the vehicle outside) was written there, a false positive against
    every ground truth (generated scenes call it outside; clipped truth keeps a sliver)."""
    regs = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 61)}
    L, W = 45.0, 20.0
    pts = []
    for k in range(1, 61):
        x0 = 500 + 3.0 * k - L / 2
        w = min(x0 + L, 640.0) - x0
        if w <= 2:
            break
        box = np.array([x0, 300 - W / 2, w, W])
        pts.append(TrackPoint(frame=k, box=box, world=box[:2] + box[2:] / 2, conf=1.0))
    centre_out = 500 + 3.0 * np.arange(1, len(pts) + 1) >= 640
    assert 3 < centre_out.sum() < len(pts) - 10
    for on in (True, False):
        (out,) = finish_tracks([Track(id=1, points=[dataclasses.replace(p) for p in pts])],
                               FinishConfig(centre_out_of_view=on), FPS, metres_per_unit=MPU,
                               registrations=regs, frame_size=(640, 480))
        kinds = np.array([p.kind for p in out.points])
        centres = np.array([p.box[0] + p.box[2] / 2 for p in out.points])
        if on:
            assert np.array_equal(kinds == "predicted", centres >= 640)
            assert abs(int((kinds == "predicted").sum()) - int(centre_out.sum())) <= 1
        else:
            assert (kinds == "observed").all()


def test_bad_size_mode_is_a_config_error():
    with pytest.raises(ConfigError, match="size_mode"):
        TrackFinisher(FinishConfig(size_mode="nope"))
    cfg = load_config(None, ["finish.size_quantile=0.7"])
    assert cfg.finish.size_quantile == 0.7


def test_pipeline_link_finishes_tracks():
    track, regs, truth = _vehicle(seed=4)
    on = link([Track(id=1, points=[dataclasses.replace(p) for p in track.points])], Config(), FPS,
              metres_per_unit=MPU, registrations=regs, frame_size=(4000, 4000))
    off_cfg = load_config(None, ["finish.enabled=false"])
    off = link([track], off_cfg, FPS, metres_per_unit=MPU, registrations=regs,
               frame_size=(4000, 4000))
    obs_on = np.array([p.box for p in on[0].points if p.kind != "predicted"])
    obs_off = np.array([p.box for p in off[0].points if p.kind != "predicted"])
    assert _iou(obs_on, truth).mean() > _iou(obs_off, truth).mean() + 0.05


def test_window_sizes_match_numpy_quantiles():
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 10, 200))
    s = rng.uniform(1, 5, (200, 2))
    valid = rng.random(200) > 0.3
    out = window_sizes(t, s, valid, 1.0, 0.6)
    tv, sv = t[valid], s[valid]
    for i in range(0, 200, 7):
        near = np.abs(tv - t[i]) <= 0.5
        ref = np.quantile(sv[near] if near.any() else sv, 0.6, axis=0)
        assert np.allclose(out[i], ref)


def test_window_sizes_far_from_any_valid_size_take_the_nearest_ones_window():
    """A vehicle drives north (7 x 17 px) for 6 s, turns west (17 x 7) and stands 20 s where the
    detector lost it, filled with held points that give no size, then drives on west. The held
    points took the whole track's quantile, a box of neither heading (8 x 11 on generated
    qstatic:72, IoU under 0.5 with the standing car); now the window of the nearest valid time."""
    t = np.arange(0, 30, 1 / 30)
    north, held = t < 6, (t >= 8) & (t < 28)
    sizes = np.where(north[:, None], [7.0, 17.0], [17.0, 7.0])
    valid = ~held
    out = window_sizes(t, sizes, valid, 2.0, 0.5)
    assert np.allclose(out[held], [17.0, 7.0])
    assert np.allclose(out[t < 0.5], [7.0, 17.0])


def test_window_sizes_pool_only_observations_facing_the_same_way():
    """A 45 x 20 px vehicle comes into view turning through 90 degrees in its first second: its
    box goes from 45 x 20 to 20 x 45 through squarer boxes. At the start of a track the window
    is one-sided, so a plain 2 s window gives the first frames the boxes of after the turn; with
    headings each point's window holds only the boxes of its own heading (modulo 180 degrees:
    driving back the other way is the same box)."""
    t = np.arange(150) / 30.0
    theta = np.clip(t / 1.0, 0.0, 1.0) * np.pi / 2
    c, s_ = np.abs(np.cos(theta)), np.abs(np.sin(theta))
    sizes = np.column_stack([45 * c + 20 * s_, 45 * s_ + 20 * c])
    headings = theta.copy()
    headings[-30:] -= np.pi  # a U-turn at the end: the same box
    valid = np.ones(len(t), bool)
    turn = t < 1.0
    gated = window_sizes(t, sizes, valid, 2.0, 0.5, headings, math.radians(20))
    plain = window_sizes(t, sizes, valid, 2.0, 0.5)
    err_gated = np.abs(gated - sizes)[turn].mean()
    err_plain = np.abs(plain - sizes)[turn].mean()
    assert err_gated < 0.5 * err_plain
    assert np.allclose(gated[~turn], sizes[~turn])
    # unknown headings (NaN, never moving) are pooled with every point
    assert np.allclose(window_sizes(t, sizes, valid, 2.0, 0.5, np.full(len(t), np.nan), 0.3),
                       plain)
    # a point whose heading no other point shares keeps the plain window: never empty
    lone = headings.copy()
    lone[100] = 1.0
    assert np.all(np.isfinite(window_sizes(t, sizes, valid, 2.0, 0.5, lone, math.radians(20))))


def test_short_gaps_between_tracklets_become_bridged():
    track, regs, truth = _vehicle(partial=0.0, n=90)
    for p in track.points[40:49]:  # 9 frames (0.3 s) between two tracklets
        p.kind, p.box = "predicted", np.full(4, np.nan)
    for p in track.points[60:90]:  # 1 s after the last observation: stays predicted
        p.kind, p.box = "predicted", np.full(4, np.nan)
    (out,) = finish_tracks([track], FinishConfig(fill_gaps_s=0.5), FPS, metres_per_unit=MPU,
                           registrations=regs)
    kinds = [p.kind for p in out.points]
    assert kinds[40:49] == ["bridged"] * 9 and kinds[60:] == ["predicted"] * 30
    filled = np.array([p.box for p in out.points[40:49]])
    assert _iou(filled, truth[40:49]).min() > 0.6


def _walker(n: int = 90) -> Track:
    """A pedestrian-sized mover (1.0 x 1.2 m box) walking at 1.5 m/s in the identity world."""
    pts = []
    for k in range(1, n + 1):
        c = np.array([200.0 + 1.5 / MPU / FPS * k, 400.0])
        pts.append(TrackPoint(frame=k, box=np.array([c[0] - 5, c[1] - 6, 10, 12]), world=c,
                              conf=1.0, kind="observed"))
    return Track(id=3, points=pts)


def test_tracks_smaller_than_a_vehicle_are_dropped():
    identity = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 200)}
    car, _, _ = _vehicle(n=90, partial=0.0)
    for p in car.points:  # in the identity world of these registrations
        p.world = p.box[:2] + p.box[2:] / 2
    cfg = FinishConfig(min_size_m=1.5)
    out = finish_tracks([_walker(), car], cfg, FPS, metres_per_unit=MPU, registrations=identity)
    assert [t.id for t in out] == [1]
    # 0 keeps every track; without registrations sizes change with the range: kept too
    assert len(finish_tracks([_walker()], FinishConfig(min_size_m=0.0), FPS, metres_per_unit=MPU,
                             registrations=identity)) == 1
    assert len(finish_tracks([_walker()], cfg, FPS, metres_per_unit=MPU)) == 1
    assert is_small(np.array([[10.0, 12.0], [11.0, 12.0]]), MPU, 1.5)
    assert not is_small(np.array([[45.0, 20.0], [10.0, 12.0], [44.0, 19.0]]), MPU, 1.5)
    assert not is_small(np.zeros((0, 2)), MPU, 1.5)


def _stopping(n_drive: int = 60, n_stand: int = 45, speed_mps: float = 8.0, tid: int = 1,
              y: float = 400.0, start: int = 1) -> Track:
    """A car (4.5 x 2 m) driving at ``speed_mps`` along x in the identity world, braking evenly
    to a stop over its last 30 driving frames, then observed standing for ``n_stand`` frames."""
    v = speed_mps / MPU / FPS  # world units per frame
    pts, x = [], 100.0
    for k in range(n_drive + n_stand):
        if k < n_drive:
            x += v * min(1.0, max(0.0, (n_drive - k) / 30))
        c = np.array([x, y])
        pts.append(TrackPoint(frame=start + k, box=np.array([c[0] - 22.5, c[1] - 10, 45, 20]),
                              world=c, conf=0.9, kind="observed"))
    return Track(id=tid, points=pts)


def _predict_after(track: Track, n: int) -> None:
    """Append ``n`` predicted points (what linking adds after a track's end) at its last place."""
    last = track.points[-1]
    track.points += [TrackPoint(frame=last.frame + k, box=np.full(4, np.nan),
                                world=last.world + [3.0 * k, 0], conf=0.0, kind="predicted")
                     for k in range(1, n + 1)]


IDENT = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 301)}
#: Holding a track's end at its stop is off by default (``FinishConfig.stop_hold_s``); the tests
#: of the rule turn it on.
HOLD = FinishConfig(stop_hold_s=30.0)


def test_a_vehicle_that_stopped_is_held_at_its_stop_until_seen_elsewhere():
    car = _stopping()  # frames 1..105, standing from frame 61
    _predict_after(car, 60)
    stop = car.points[-61].world.copy()
    # another track drives over the stop in frame 200: the place is taken from 2 m before (frame
    # 194), the hold ends there
    other = Track(id=2, points=[TrackPoint(frame=f, box=np.array([0, 0, 45, 20.0]) + [
        stop[0] - 22.5 + 3 * (f - 200), stop[1] - 10, 0, 0], world=stop + [3.0 * (f - 200), 0],
        conf=0.9) for f in range(190, 211)])
    cfg = FinishConfig(stop_hold_s=30.0)
    out = finish_tracks([car, other], cfg, FPS, metres_per_unit=MPU, registrations=IDENT)
    car = next(t for t in out if t.id == 1)
    held = [p for p in car.points if p.kind == "stationary"]
    assert [p.frame for p in held] == list(range(106, 194))
    boxes = np.array([p.box for p in held])
    truth = np.tile([stop[0] - 22.5, stop[1] - 10, 45, 20], (len(held), 1))
    assert _iou(boxes, truth).min() > 0.8
    # the hold is capped
    short = _stopping()
    (out,) = finish_tracks([short], FinishConfig(stop_hold_s=1.0), FPS, metres_per_unit=MPU,
                           registrations=IDENT)
    assert [p.frame for p in out.points if p.kind == "stationary"] == list(range(106, 136))


def test_a_stop_between_two_tracklets_is_stationary_not_predicted():
    car = _stopping()
    stop = car.points[-1].world.copy()
    gap = [TrackPoint(frame=f, box=np.full(4, np.nan), world=stop + [0.5 * (f - 105), 0],
                      conf=0.0, kind="predicted") for f in range(106, 146)]
    off = [TrackPoint(frame=f, box=np.array([stop[0] - 22.5 + 0.1 * (f - 146) ** 2, stop[1] - 10,
                                             45, 20]),
                      world=stop + [0.1 * (f - 146) ** 2, 0], conf=0.9) for f in range(146, 176)]
    car.points += gap + off
    (out,) = finish_tracks([car], FinishConfig(), FPS, metres_per_unit=MPU, registrations=IDENT)
    kinds = {p.frame: p.kind for p in out.points}
    assert all(kinds[f] == "stationary" for f in range(106, 146))
    assert _iou(np.array([out.points[f - 1].box for f in range(106, 146)]),
                np.tile([stop[0] - 22.5, stop[1] - 10, 45, 20], (40, 1))).min() > 0.8


def test_a_stop_and_go_gap_is_stationary_though_neither_end_stood():
    """A queue probe (2026-12-03): the detector loses a car while it brakes (still at 2-4 m/s)
    and finds it again while it pulls away, so neither end of the linked gap stands still and
    the stop was written to predicted.csv as out of view. A gap crossed at under
    ``stop_gap_speed_mps`` on average, seen driving on both sides, is the stop."""
    def stop_and_go() -> Track:
        car = _stopping(n_drive=60, n_stand=0)
        car.points = car.points[:48]  # lost at about 3 m/s, 1.3 m before it stands
        last = car.points[-1].world.copy()
        stop = last + [13.0, 0.0]
        gap = [TrackPoint(frame=f, box=np.full(4, np.nan), world=last + [0.3 * (f - 48), 0],
                          conf=0.0, kind="predicted") for f in range(49, 139)]
        # pulls away from the stop at 2 m/s^2, first seen 1 m on
        off = []
        for f in range(139, 199):
            x = stop[0] + 10.0 + 0.5 * (2.0 / MPU) * ((f - 139) / FPS + 1.0) ** 2 - 0.5 * (2.0 / MPU)
            off.append(TrackPoint(frame=f, box=np.array([x - 22.5, stop[1] - 10, 45, 20]),
                                  world=np.array([x, stop[1]]), conf=0.9))
        car.points += gap + off
        return car

    stop = stop_and_go().points[47].world + [13.0, 0.0]
    (out,) = finish_tracks([stop_and_go()], FinishConfig(), FPS, metres_per_unit=MPU,
                           registrations=IDENT)
    kinds = {p.frame: p.kind for p in out.points}
    assert sum(kinds[f] == "stationary" for f in range(49, 139)) >= 80
    still = np.array([out.points[f - 1].world for f in range(80, 110)])
    assert np.abs(still[:, 0] - stop[0]).max() * MPU < 2.0  # standing near the true stop
    (out,) = finish_tracks([stop_and_go()], FinishConfig(stop_gap_speed_mps=0.0), FPS,
                           metres_per_unit=MPU, registrations=IDENT)
    assert not any(p.kind == "stationary" for p in out.points)
    # the radius rule off leaves this one on (the stage had run only for the radius rule)
    (out,) = finish_tracks([stop_and_go()], FinishConfig(stop_radius_m=0.0), FPS,
                           metres_per_unit=MPU, registrations=IDENT)
    assert sum(p.kind == "stationary" for p in out.points) >= 80


def test_no_hold_for_a_track_that_ends_moving_or_never_moved():
    moving = _stopping(n_stand=0)
    moving.points = moving.points[:40]  # lost while still at full speed
    _predict_after(moving, 30)
    parked = _stopping(n_drive=0, n_stand=90, tid=2, y=600.0)
    out = finish_tracks([moving, parked], HOLD, FPS, metres_per_unit=MPU,
                        registrations=IDENT)
    assert [t.id for t in out] == [1]  # the parked car is static: dropped, not held
    assert not any(p.kind == "stationary" for p in out[0].points)
    # and nothing is held without registered frames (image of a moving camera)
    car = _stopping()
    (out,) = finish_tracks([car], HOLD, FPS, metres_per_unit=MPU)
    assert not any(p.kind == "stationary" for p in out.points)


def test_no_hold_for_two_creeping_pieces_linked_over_a_long_gap():
    """Two pieces of a false alarm that creeps (the parallax of a canopy's edge), each within
    a few metres, linked over 3 s: the track spreads over more than ``static_extent_m`` but was
    never seen driving into its stop, so its end is not held; the same end after a continuous
    drive is."""
    def piece(f0: int, n: int, x0: float) -> list[TrackPoint]:
        return [TrackPoint(frame=f0 + k, box=np.array([x0 + 0.2 * k - 22.5, 390, 45, 20]),
                           world=np.array([x0 + 0.2 * k, 400.0]), conf=0.8)
                for k in range(n)]
    first, second = piece(1, 40, 100.0), piece(131, 40, 140.0)  # 0.8 m each, 4.8 m in all
    gap = [TrackPoint(frame=f, box=np.full(4, np.nan), world=np.array([120.0, 400.0]), conf=0.0,
                      kind="predicted") for f in range(41, 131)]
    false = Track(id=1, points=first + gap + second)
    _predict_after(false, 60)
    assert np.ptp([p.world[0] for p in first + second]) * MPU > FinishConfig().static_extent_m
    (out,) = finish_tracks([false], HOLD, FPS, metres_per_unit=MPU, registrations=IDENT)
    assert not any(p.kind == "stationary" for p in out.points)
    (out,) = finish_tracks([false], dataclasses.replace(HOLD, stop_run_gap_s=0.0), FPS,
                           metres_per_unit=MPU, registrations=IDENT)  # the whole track's spread: held
    assert any(p.kind == "stationary" for p in out.points)
    car = _stopping()
    _predict_after(car, 60)
    (out,) = finish_tracks([car], HOLD, FPS, metres_per_unit=MPU, registrations=IDENT)
    assert any(p.kind == "stationary" for p in out.points)


def test_a_vehicle_that_drives_off_from_a_standstill_is_held_backwards():
    car = _stopping()
    for k, p in enumerate(car.points):  # time reversed: stands, then accelerates away
        p.frame = 200 - k
    car.points.reverse()  # frames 96..200, standing 96..140
    (out,) = finish_tracks([car], FinishConfig(stop_hold_back_s=2.0), FPS, metres_per_unit=MPU,
                           registrations=IDENT)
    assert [p.frame for p in out.points if p.kind == "stationary"] == list(range(36, 96))
    with pytest.raises(ConfigError, match="stop_hold_s"):
        TrackFinisher(FinishConfig(stop_hold_s=-1.0))


def test_persistence_boxes_take_the_vehicles_size_from_its_regular_observations():
    """A vehicle seen by the regular detector, then only by persistence (``weak`` points, faint
    boxes half its size) after a gap: the faint run is reported at the vehicle's size."""
    car = _stopping(n_drive=60, n_stand=0)  # 45 x 20 boxes, frames 1..60
    faint = []
    for p in car.points[40:]:
        c = p.world + [0.0, 0.0]
        faint.append(TrackPoint(frame=p.frame + 30, box=np.array([c[0] - 10, c[1] - 5, 20, 10]),
                                world=c, conf=0.3, kind="observed", weak=True))
    car.points = car.points[:40] + faint  # frames 1..40 regular, 71..90 weak (a gap between)
    out = finish_tracks([car], FinishConfig(fill_gaps_s=0.0, stop_hold_s=0.0, stop_radius_m=0.0),
                        FPS, metres_per_unit=MPU, registrations=IDENT)
    sizes = np.array([p.box[2:] for p in out[0].points if p.weak])
    assert len(sizes) == 20
    assert np.allclose(sizes, [45, 20], atol=1.0)
    # a track of persistence boxes only (no regular detection ever saw it) is dropped; one
    # regular observation keeps it, with its own sizes
    alone = _stopping(n_drive=60, n_stand=0, tid=2)
    alone.points = [dataclasses.replace(p, box=np.array([p.world[0] - 10, p.world[1] - 5, 20, 10]),
                                        weak=True) for p in alone.points[:30]]
    cfg = FinishConfig(fill_gaps_s=0.0, stop_hold_s=0.0, stop_radius_m=0.0, min_size_m=0.0)
    assert finish_tracks([alone], cfg, FPS, metres_per_unit=MPU, registrations=IDENT) == []
    alone.points[0] = dataclasses.replace(alone.points[0], weak=False)
    out = finish_tracks([alone], cfg, FPS, metres_per_unit=MPU, registrations=IDENT)
    assert np.allclose([p.box[2:] for p in out[0].points], [20, 10], atol=1.0)


def _box_track(tid: int, boxes: dict[int, tuple], observed: set[int]) -> Track:
    pts = [TrackPoint(frame=f, box=np.array(b, float), world=np.array([b[0] + b[2] / 2, b[1] + b[3] / 2]),
                      conf=1.0, kind="observed" if f in observed else "bridged")
           for f, b in sorted(boxes.items())]
    return Track(id=tid, points=pts)


def test_a_fragments_track_bridged_beside_the_whole_vehicle_is_suppressed():
    frames = range(1, 41)
    truck = _box_track(1, {f: (100 + f, 50, 30, 18) for f in frames}, set(frames))
    # a fragment of the truck's front, observed every 10th frame and bridged between
    front = _box_track(2, {f: (118 + f, 54, 10, 10) for f in frames}, {1, 10, 20, 30, 40})
    # a car right behind the truck: touching boxes are two vehicles
    car = _box_track(3, {f: (82 + f, 52, 19, 12) for f in frames}, set(frames))
    tracks = [front, truck, car]
    removed = suppress_overlaps(tracks, 0.6)
    assert removed == 40 and front.points == []
    assert len(truck.points) == 40 and len(car.points) == 40
    # one identity per object: the loser gives up all its overlapping frames, including those
    # where it was observed and the winner too
    a = _box_track(1, {f: (0, 0, 20, 10) for f in frames}, set(range(1, 31)))
    b = _box_track(2, {f: (1, 0, 20, 10) for f in frames}, set(range(20, 41)))
    suppress_overlaps([a, b], 0.6)
    assert len(a.points) == 40 and b.points == []
    # 1 disables; through the finisher only on registered frames
    c, d = (_box_track(1, {f: (0, 0, 20, 10) for f in frames}, set(frames)),
            _box_track(2, {f: (2, 0, 8, 8) for f in frames}, {1}))
    assert suppress_overlaps([c, d], 1.0) == 0 and len(d.points) == 40
    kept = finish_tracks([c, d], FinishConfig(smooth=False, static_extent_m=0, min_size_m=0), FPS,
                         metres_per_unit=MPU)
    assert len(kept) == 2
    regs = {f: Registration(index=f, H=np.eye(3)) for f in frames}
    kept = finish_tracks([c, d], FinishConfig(smooth=False, static_extent_m=0, min_size_m=0), FPS,
                         metres_per_unit=MPU, registrations=regs)
    assert [t.id for t in kept] == [1]


def test_a_waiting_vehicle_half_absorbed_keeps_its_size():
    """A car that stops and is then detected only as a fragment (the background window took most
    of it in) is reported at the size it had while it drove; not without registrations (speeds
    in a moving camera's image say nothing), and not when it shrinks while still driving fast."""
    def shrunk(track, frames):
        for k, p in enumerate(track.points):
            if p.frame in frames:
                track.points[k] = dataclasses.replace(
                    p, box=np.array([p.world[0] - 9, p.world[1] - 5, 18, 10]))
        return track

    cfg = FinishConfig(fill_gaps_s=0.0, stop_hold_s=0.0, stop_radius_m=0.0)
    waits = range(70, 106)  # standing from frame 61, a fragment from frame 70
    out = finish_tracks([shrunk(_stopping(), waits)], cfg, FPS, metres_per_unit=MPU,
                        registrations=IDENT)
    sizes = np.array([p.box[2:] for p in out[0].points if p.frame in waits])
    assert len(sizes) == len(waits) and np.allclose(sizes, [45, 20], atol=1.0)
    off = finish_tracks([shrunk(_stopping(), waits)],
                        dataclasses.replace(cfg, absorbed_ratio=0.0), FPS, metres_per_unit=MPU,
                        registrations=IDENT)
    assert np.allclose([p.box[2:] for p in off[0].points if p.frame in waits][-10:], [18, 10],
                       atol=1.0)
    image = finish_tracks([shrunk(_stopping(), waits)], cfg, FPS, metres_per_unit=MPU)
    assert np.allclose([p.box[2:] for p in image[0].points if p.frame in waits][-10:], [18, 10],
                       atol=1.0)
    # a fragment for 2 s (the size window's width) while driving fast stays a fragment
    fast = finish_tracks([shrunk(_stopping(n_drive=120, n_stand=0), range(20, 80))], cfg, FPS,
                         metres_per_unit=MPU, registrations=IDENT)
    assert np.allclose([p.box[2:] for p in fast[0].points if p.frame in range(20, 80)][5:-5],
                       [18, 10], atol=1.0)


def test_an_estimated_scale_judges_small_tracks_by_its_own_threshold():
    """A 1.6 x 2.0 m mover: a small vehicle when the scale is known, below the threshold for a
    scale that global linking estimated from the objects."""
    identity = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 200)}
    t = _walker()
    for p in t.points:
        p.box = np.array([p.world[0] - 8, p.world[1] - 10, 16, 20])  # 1.6 x 2.0 m at MPU 0.1
    cfg = FinishConfig(min_size_m=1.5, min_size_estimated_m=2.0)
    known = finish_tracks([copy.deepcopy(t)], cfg, FPS, metres_per_unit=MPU, registrations=identity)
    estimated = finish_tracks([copy.deepcopy(t)], cfg, FPS, metres_per_unit=MPU,
                              registrations=identity, scale_estimated=True)
    assert len(known) == 1 and estimated == []


def test_tracks_left_out_are_counted_with_their_reason_in_the_log(caplog):
    """An oblique view's far vehicles, judged small on a scale estimated for the whole run,
    vanished at the finish without a word, even with -vv."""
    identity = {k: Registration(index=k, H=np.eye(3)) for k in range(1, 200)}
    t = _walker()
    for p in t.points:
        p.box = np.array([p.world[0] - 8, p.world[1] - 10, 16, 20])
    cfg = FinishConfig(min_size_m=1.5, min_size_estimated_m=2.0)
    with caplog.at_level(logging.INFO, logger="aerotrack"):
        assert finish_tracks([t], cfg, FPS, metres_per_unit=MPU, registrations=identity,
                             scale_estimated=True) == []
    assert ("finish: 1 of 1 tracks left out: 1 smaller than 2 m (finish.min_size_estimated_m"
            in caplog.text), caplog.text


def test_merged_boxes_do_not_pull_the_vehicle_towards_its_neighbour():
    """Every third detection of a car merges it with the car beside it (a box twice as tall,
    its centre 10 px off) and the car leaves through the frame's right edge at the end: the
    reported boxes follow the car's own boxes, not the merged ones' centres; without the size
    test (``size_outlier_ratio`` 0) the smoothed centre sits about 3 px towards the neighbour.
    The border pass at the end must keep the down-weighting too."""
    rng = np.random.default_rng(3)
    L, W = 45.0, 20.0
    pts, truth = [], []
    for k in range(1, 121):
        true = np.array([300 + 3.0 * k - L / 2, 300 - W / 2, L, W])
        box = true.copy()
        box[:2] += rng.normal(0, 0.3, 2)
        if k % 3 == 0:  # merged with the neighbour below it
            box[3] += W
        x1 = min(box[0] + box[2], 640.0)
        box[2] = x1 - box[0]
        if box[2] <= 5:
            break
        pts.append(TrackPoint(frame=k, box=box, world=box[:2] + box[2:] / 2, conf=1.0))
        truth.append(true)
    truth = np.array(truth)
    regs = {k: Registration(index=k, H=np.eye(3)) for k in range(1, len(pts) + 1)}
    cfg = FinishConfig(fill_gaps_s=0.0)
    assert cfg.size_outlier_ratio > 0

    def centre_error(config):
        (out,) = finish_tracks([Track(id=1, points=[dataclasses.replace(p) for p in pts])],
                               config, FPS, metres_per_unit=MPU, registrations=regs,
                               frame_size=(640, 480))
        boxes = _boxes(out)
        inside = truth[:, 0] + L < 630  # the frames before the border
        return np.abs((boxes[:, 1] + boxes[:, 3] / 2) - 300)[inside].mean()

    assert centre_error(cfg) < 1.0
    assert centre_error(dataclasses.replace(cfg, size_outlier_ratio=0.0)) > 2.0
    with pytest.raises(ConfigError, match="size_outlier_ratio"):
        TrackFinisher(FinishConfig(size_outlier_ratio=0.9))

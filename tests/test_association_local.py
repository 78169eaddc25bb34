"""Local association by data-driven MCMC (Yu & Medioni section 4): known answers on synthetic
scenes, partition validity under every move, reproducibility."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aerotrack.association import LocalAssociator, associate
from aerotrack.association.moves import MOVES
from aerotrack.config import AssociationConfig
from aerotrack.errors import InputError
from aerotrack.types import Detections

FPS = 30.0


def _frames(tracks: dict[int, dict[int, tuple[float, float]]], n_frames: int, fp=None,
            hist_of=None, size=(4.5, 2.0)) -> tuple[list[Detections], list[np.ndarray]]:
    """Detections (world = metres, mpu 1) from {id: {frame: (x, y)}}; returns frames and per-frame
    truth ids (-1 for false positives)."""
    frames, truth = [], []
    for f in range(1, n_frames + 1):
        pts, ids = [], []
        for i, path in tracks.items():
            if f in path:
                pts.append(path[f])
                ids.append(i)
        for p in (fp or {}).get(f, []):
            pts.append(p)
            ids.append(-1)
        if not pts:
            frames.append(Detections.empty(f))
            truth.append(np.zeros(0, int))
            continue
        w = np.asarray(pts, float)
        sz = np.tile(size, (len(w), 1))
        hist = None
        if hist_of is not None:
            hist = np.array([hist_of(i) for i in ids])
        frames.append(Detections(frame=f, boxes=np.column_stack([w - sz / 2, sz]),
                                 conf=np.ones(len(w)), world=w, size_world=sz, hist=hist))
        truth.append(np.asarray(ids))
    return frames, truth


def _identities(tracklets, truth) -> dict[int, list[int]]:
    """For each tracklet id, the true ids of its observed points in order."""
    return {t.id: [int(truth[p.frame - 1][p.det_index]) for p in t.points if p.kind == "observed"]
            for t in tracklets}


def _line(x0, y0, vx, vy, frames, rng=None, noise=0.05):
    out = {}
    for f in frames:
        t = (f - 1) / FPS
        e = (0, 0) if rng is None else rng.normal(0, noise, 2)
        out[f] = (x0 + vx * t + e[0], y0 + vy * t + e[1])
    return out


def test_crossing_targets_keep_their_identities():
    """Two vehicles cross at an angle, a third passes through the crossing later: motion alone must
    keep every identity through the crossing (where the two boxes coincide, a one-frame exchange of
    indistinguishable detections is tolerated)."""
    rng = np.random.default_rng(0)
    n = 90
    fr = range(1, n + 1)
    tracks = {1: _line(0, 0, 12, 6, fr, rng), 2: _line(0, 18, 12, -6, fr, rng),
              3: _line(-20, 8, 15, 0, fr, rng)}
    frames, truth = _frames(tracks, n)
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    ids = _identities(out, truth)
    assert len(out) == 3
    majority = set()
    for seq in ids.values():
        vals, counts = np.unique(seq, return_counts=True)
        assert len(seq) == n
        assert counts.max() >= n - 2, seq
        majority.add(int(vals[np.argmax(counts)]))
    assert majority == {1, 2, 3}


def test_dropouts_are_bridged_inside_one_tracklet():
    rng = np.random.default_rng(1)
    n = 80
    missing = set(range(30, 38)) | {50, 51}
    fr = [f for f in range(1, n + 1) if f not in missing]
    tracks = {7: _line(0, 0, 10, 2, fr, rng), 8: _line(0, 30, 9, -1, range(1, n + 1), rng)}
    frames, truth = _frames(tracks, n)
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    assert len(out) == 2
    t7 = next(t for t in out if set(_identities([t], truth)[t.id]) == {7})
    assert [p.frame for p in t7.points] == list(range(1, n + 1))
    bridged = [p for p in t7.points if p.kind == "bridged"]
    assert sorted(p.frame for p in bridged) == sorted(missing)
    # bridged positions are interpolated between the observations around the gap
    p29 = t7.points[28]
    p38 = t7.points[37]
    mid = t7.points[33]
    u = (mid.frame - 29) / 9
    np.testing.assert_allclose(mid.world, (1 - u) * p29.world + u * p38.world)
    assert mid.det_index == -1


def test_isolated_false_positives_are_rejected():
    rng = np.random.default_rng(2)
    n = 60
    tracks = {1: _line(0, 0, 10, 0, range(1, n + 1), rng)}
    fp = {f: [tuple(rng.uniform(-100, 100, 2))] for f in range(1, n + 1)}
    frames, truth = _frames(tracks, n, fp=fp)
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    assert len(out) == 1
    assert set(_identities(out, truth)[out[0].id]) == {1}


def test_appearance_separates_a_swap_that_motion_cannot():
    """Two targets meet, stop side by side and leave: colour histograms (eq. 9) keep them apart."""
    n = 70
    a, b = {}, {}
    for f in range(1, n + 1):
        t = (f - 1) / FPS
        if f <= 30:
            a[f] = (8 * t, 0.0)
            b[f] = (8 * t, 6.0 - 6.0 * t)
    rng = np.random.default_rng(3)
    # after frame 30, both move apart at mirrored angles from nearly the same place
    xa, ya = a[30]
    xb, yb = b[30]
    for f in range(31, n + 1):
        t = (f - 30) / FPS
        a[f] = (xa + 8 * t + rng.normal(0, .05), ya + 4 * t)
        b[f] = (xb + 8 * t + rng.normal(0, .05), yb - 4 * t)
    hists = {1: np.array([.7, .1, .1, .1]), 2: np.array([.1, .1, .1, .7]), -1: np.full(4, .25)}
    frames, truth = _frames({1: a, 2: b}, n, hist_of=lambda i: hists[i])
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    for seq in _identities(out, truth).values():
        assert len(set(seq)) == 1


def test_same_seed_same_tracklets():
    rng = np.random.default_rng(4)
    n = 60
    tracks = {i: _line(*rng.uniform(0, 40, 2), *rng.uniform(-10, 10, 2),
                       [f for f in range(1, n + 1) if rng.random() > 0.15], rng)
              for i in range(12)}
    fp = {f: [tuple(rng.uniform(0, 60, 2))] for f in range(1, n + 1) if rng.random() < 0.5}
    frames, _ = _frames(tracks, n, fp=fp)

    def run(seed):
        out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=seed)
        return [(t.id, [(p.frame, p.det_index, p.kind) for p in t.points]) for t in out]

    assert run(5) == run(5)


def test_tracklets_carry_detection_rows():
    n = 30
    tracks = {1: _line(0, 0, 10, 0, range(1, n + 1))}
    frames, _ = _frames(tracks, n, hist_of=lambda i: np.array([.5, .5]))
    desc = np.ones((1, 6, 8, 8))
    frames = [Detections(frame=d.frame, boxes=d.boxes, conf=d.conf * 0.7, world=d.world,
                         size_world=d.size_world, hist=d.hist, extra={"desc": desc})
              for d in frames]
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0)
    (t,) = out
    assert t.id >= 1
    p = t.points[5]
    assert p.kind == "observed" and p.det_index == 0 and p.conf == pytest.approx(0.7)
    np.testing.assert_allclose(p.box, frames[5].boxes[0])
    np.testing.assert_allclose(p.hist, [.5, .5])
    assert p.desc.shape == (6, 8, 8)


def test_frames_must_increase():
    la = LocalAssociator(AssociationConfig(), FPS, 1.0)
    la.step(Detections.empty(3))
    with pytest.raises(InputError, match="frames must increase"):
        la.step(Detections.empty(2))


def _check_partition(S) -> None:
    """Every detection in at most one track, at most one detection per track per frame, and the
    node arrays agree with the tracks."""
    s = S.store
    seen = set()
    for tid, t in S.tracks.items():
        nodes = t.nodes.tolist()
        assert not (set(nodes) & seen), "a detection is in two tracks"
        seen.update(nodes)
        fr = [S.frame_of(g) for g in nodes]
        assert all(a < b for a, b in itertools.pairwise(fr)), "two detections of a track in one frame"
        if t.prior is not None and nodes:
            assert t.prior.frame < fr[0]
        for k, g in enumerate(nodes):
            assert s.label[g - s.base] == tid
            assert s.idx[g - s.base] == k
            assert s.prev[g - s.base] == (nodes[k - 1] if k else -1)
        assert len(t.xs) == len(nodes) == len(t.links)
    for g in range(s.base, s.next):
        if g not in seen:
            assert s.label[g - s.base] == -1


def _fragmented(frames: list[Detections], rng: np.random.Generator, share: float
                ) -> list[Detections]:
    """The same frames with a ``share`` of the boxes replaced by a part of themselves (a blob
    detector's fragment: smaller, inside the whole, off its centre)."""
    out = []
    for d in frames:
        if not len(d):
            out.append(d)
            continue
        w, sz = np.array(d.world, float), np.array(d.size_world, float)
        part = rng.random(len(d)) < share
        k = rng.uniform(0.35, 0.7, (len(d), 2))
        shift = (1 - k) * sz / 2 * rng.uniform(-1, 1, (len(d), 2))
        w[part] += shift[part]
        sz[part] *= k[part]
        out.append(Detections(frame=d.frame, boxes=np.column_stack([w - sz / 2, sz]),
                              conf=d.conf, world=w, size_world=sz))
    return out


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), n_obj=st.integers(1, 7), fp_rate=st.floats(0, 2),
       fragments=st.booleans())
def test_every_move_keeps_the_partition_valid(seed, n_obj, fp_rate, fragments):
    """Random graphs (targets wandering close together, dropouts, clutter, and with
    ``fragments`` partial boxes with partial links on); after every Metropolis-Hastings step of
    every move type the partition is valid."""
    rng = np.random.default_rng(seed)
    n = 25
    tracks = {}
    for i in range(n_obj):
        fr = [f for f in range(1, n + 1) if rng.random() > 0.2]
        tracks[i] = _line(*rng.uniform(0, 15, 2), *rng.uniform(-15, 15, 2), fr, rng, noise=0.5)
    fp = {f: [tuple(rng.uniform(0, 20, 2)) for _ in range(rng.poisson(fp_rate))]
          for f in range(1, n + 1)}
    frames, _ = _frames(tracks, n, fp=fp)
    if fragments:
        frames = _fragmented(frames, rng, 0.4)
    cfg = AssociationConfig(window_s=0.5, max_gap_s=0.3, min_iters=0, iters_per_ambiguity=0,
                            partial_score=4.0 if fragments else 0.0)
    la = LocalAssociator(cfg, FPS, 1.0, seed=seed)
    for d in frames:
        la.step(d)
        S = la.sampler
        if S is None:  # no detection yet
            continue
        _check_partition(S)
        for _ in range(30):
            S.step_mcmc()
            _check_partition(S)
    assert sum(S.proposed[m] for m in MOVES) > 0
    la.flush()


def test_moves_are_accepted_and_all_tried():
    """On an ambiguous scene every move type is proposed and the sampler accepts some moves."""
    rng = np.random.default_rng(7)
    n = 40
    tracks = {i: _line(*rng.uniform(0, 10, 2), *rng.uniform(-8, 8, 2),
                       [f for f in range(1, n + 1) if rng.random() > 0.25], rng, noise=0.4)
              for i in range(6)}
    frames, _ = _frames(tracks, n)
    la = LocalAssociator(AssociationConfig(iters_per_ambiguity=5), FPS, 1.0, seed=1)
    for d in frames:
        la.step(d)
    S = la.sampler
    assert all(S.proposed[m] > 0 for m in MOVES)
    assert sum(S.accepted.values()) > 0


def test_sampler_visits_partitions_in_proportion_to_the_posterior():
    """Correct Metropolis-Hastings ratios: on a tiny window (two close targets, one dropout) the
    chain's visit frequencies of the most likely partitions follow exp(log posterior)."""
    rng = np.random.default_rng(0)
    n = 4
    tracks = {1: _line(0, 0, 6, 0, range(1, n + 1), rng, noise=0.3),
              2: _line(0, 1.2, 6, 0, [1, 2, 4], rng, noise=0.3)}
    frames, _ = _frames(tracks, n)
    cfg = AssociationConfig(window_s=1.0, max_gap_s=0.2, min_iters=0, iters_per_ambiguity=0,
                            birth_cost=3.0, overlap_lambda=0.0)
    la = LocalAssociator(cfg, FPS, 1.0, seed=0)
    for d in frames:
        la.step(d)
    S = la.sampler
    counts: dict = {}
    scores: dict = {}
    steps = 30000
    for _ in range(steps):
        S.step_mcmc()
        k = tuple(sorted(tuple(t.nodes.tolist()) for t in S.tracks.values()))
        counts[k] = counts.get(k, 0) + 1
        scores[k] = sum(t.score for t in S.tracks.values())
    top = sorted(counts, key=counts.get, reverse=True)[:4]
    best = top[0]
    assert counts[best] / steps > 0.8
    for k in top[1:]:
        if counts[k] / steps < 0.008:
            continue
        observed = np.log(counts[k] / counts[best])
        expected = scores[k] - scores[best]
        assert abs(observed - expected) < 0.6, (k, observed, expected)


def test_a_run_started_later_reproduces_the_whole_run_away_from_the_cut():
    """Segment-parallel runs (aerotrack.parallel) start association at a later frame: each frame's
    MCMC draws from its own stream (seed, frame), tracks are drawn in a canonical order and the
    window is frozen at absolute frames, so once the window has filled the later run gives the
    same tracklets as the whole run (with one random stream for the whole run it does not)."""
    rng = np.random.default_rng(0)
    n = 150
    early = {i: _line(*rng.uniform(0, 20, 2), *rng.uniform(-8, 8, 2),
                      [f for f in range(1, 45) if rng.random() > 0.2], rng, noise=0.3)
             for i in range(6)}
    late = {10 + i: _line(*rng.uniform(0, 20, 2), *rng.uniform(-6, 6, 2),
                          [f for f in range(95 + 3 * i, n + 1) if rng.random() > 0.2], rng,
                          noise=0.3)
            for i in range(8)}
    fp = {f: [tuple(rng.uniform(0, 30, 2)) for _ in range(rng.poisson(0.5))]
          for f in range(1, n + 1)}
    frames, _ = _frames({**early, **late}, n, fp=fp)

    def run(start):
        out = associate(frames[start - 1:], AssociationConfig(), FPS, metres_per_unit=1.0, seed=3)
        return sorted([(p.frame, p.det_index, p.kind) for p in t.points] for t in out
                      if t.points[0].frame >= 95)

    whole, later = run(1), run(50)
    assert len(whole) >= 6
    assert whole == later


def test_a_vehicle_waiting_at_a_light_stays_one_tracklet():
    """A vehicle brakes to a stop, waits 3 s (near-zero velocity, a few missed detections) and
    drives off, while another passes beside it: one tracklet per vehicle, covering every frame of
    the wait (observed or bridged)."""
    rng = np.random.default_rng(2)
    n = 240

    def stop_and_go(f):
        t = (f - 1) / FPS
        if t < 2.0:  # 10 m/s braking at 5 m/s^2 from t = 0 to a stop at t = 2 s
            x = 10 * t - 2.5 * t * t
        elif t < 5.0:
            x = 10.0
        else:
            x = 10.0 + 2.0 * (t - 5.0) ** 2
        return x + rng.normal(0, 0.05), 0.0 + rng.normal(0, 0.05)

    seen = [f for f in range(1, n + 1) if not (80 <= f <= 84 or rng.random() < 0.1)]
    tracks = {1: {f: stop_and_go(f) for f in seen},
              2: _line(-5, 4, 8, 0, range(1, n + 1), rng)}
    frames, truth = _frames(tracks, n)
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    ids = _identities(out, truth)
    assert len(out) == 2
    assert all(len(set(seq)) == 1 for seq in ids.values())
    (waiting,) = [t for t in out if ids[t.id][0] == 1]
    frames_covered = {p.frame for p in waiting.points}
    assert set(range(min(seen), max(seen) + 1)) <= frames_covered


def test_fragments_of_a_vehicle_stay_in_its_tracklet():
    """A blob detector returns a vehicle as a fragment (a smaller box inside the whole, off its
    centre) in runs of frames between runs of whole boxes, beside a whole vehicle in the next
    lane. Under the whole-box model the fragments form a second tracklet interleaved with the
    vehicle's; with partial links they stay in the vehicle's tracklet (as bridged rows between
    its whole observations) and the neighbour is untouched."""
    rng = np.random.default_rng(0)
    n = 90
    frames, part = [], []
    for f in range(1, n + 1):
        t = (f - 1) / FPS
        c = np.array([10.0 * t, 5.0]) + rng.normal(0, 0.05, 2)
        other = np.array([10.0 * t, 12.0]) + rng.normal(0, 0.05, 2)
        is_part = (f // 6) % 2 == 1
        w = np.array([c + [1.0, 0.2] if is_part else c, other])
        sz = np.array([[2.2, 1.4] if is_part else [4.5, 2.0], [4.5, 2.0]])
        frames.append(Detections(frame=f, boxes=np.column_stack([w - sz / 2, sz]),
                                 conf=np.ones(2), world=w, size_world=sz))
        part.append(is_part)
    whole = [f for f in range(1, n + 1) if not part[f - 1]]

    def lanes(cfg):
        out = associate(frames, cfg, FPS, metres_per_unit=1.0, seed=0)
        return [t for t in out if abs(t.points[0].world[1] - 5) < 1.5], out

    mine, out = lanes(AssociationConfig(partial_score=0.0))
    assert len(mine) == 2  # the failure being fixed: fragments make their own tracklet
    mine, out = lanes(AssociationConfig(partial_score=4.0))
    assert len(out) == 2 and len(mine) == 1
    pts = mine[0].points
    assert [p.frame for p in pts if p.kind == "observed"] == whole
    assert [p.frame for p in pts] == list(range(whole[0], whole[-1] + 1))
    # bridged rows over the fragments carry the whole vehicle's size
    assert all(np.allclose(p.size_world, [4.5, 2.0], atol=0.05) for p in pts)


def test_partial_candidates_exclude_a_part_between_two_boxes():
    """A fragment inside one box of the previous frame may be a part; inside two (between two
    vehicles of a queue) it may not; with no previous frame every observation may be."""
    from aerotrack.association.posterior import partial_candidates

    prev = np.array([[0.0, 0.0, 4.5, 2.0], [3.0, 0.0, 4.5, 2.0], [20.0, 0.0, 4.5, 2.0]])
    z = np.array([[20.5, 0.0, 2.0, 1.4],   # inside the third box only
                  [1.5, 0.0, 1.0, 1.0],    # inside the first and the second
                  [10.0, 0.0, 2.0, 1.4],   # inside none
                  [20.0, 0.0, 4.4, 2.0]])  # a whole box (too large to be a part of anything)
    assert partial_candidates(z, prev, 0.8, 0.75).tolist() == [True, False, True, True]
    assert partial_candidates(z, np.zeros((0, 4)), 0.8, 0.75).all()


def test_a_partial_link_keeps_the_predicted_state():
    """A part says that the target is there, not where its centre is: the
    partial link returns the prediction unchanged, so parts on one side of the box, run after
    run, do not drag the track onto a neighbour."""
    from aerotrack.association.posterior import PARTIAL_D2, link_step
    from aerotrack.kalman import (
        ConstantVelocityKF,
        predict_nb,
        process_noise_nb,
        transition_nb,
    )

    cfg = AssociationConfig()
    kf = ConstantVelocityKF(accel_std=cfg.accel_std_mps2, size_std=cfg.size_std_m,
                            pos_std=cfg.pos_std_m, pos_frac=cfg.pos_frac,
                            size_std_obs=cfg.pos_std_m, size_frac=cfg.size_frac,
                            vel_std=0.5 * cfg.max_speed_mps)
    params = np.concatenate([kf.as_array(), [4.0, 0.8, cfg.gate_chi2, 0.75, 15]])
    x = np.array([0.0, 0.0, 4.5, 2.0, 10.0, 0.0])
    P = np.diag([0.05, 0.05, 0.05, 0.05, 0.5, 0.5])
    dt = 1 / FPS
    xp, Pp = predict_nb(x, P, transition_nb(dt), process_noise_nb(dt, params[0], params[1]))
    part = np.array([xp[0] + 1.2, 0.4, 1.6, 1.0])  # the front half, off centre
    xn, Pn, d2, rel = link_step(x, P, dt, part, params, True)
    assert d2 == PARTIAL_D2 and rel == pytest.approx(4.0 - 0.5 * cfg.gate_chi2)
    np.testing.assert_allclose(xn, xp)
    np.testing.assert_allclose(Pn, Pp)
    # without partial links allowed the same observation is a (failing) whole-box link
    _, _, d2_whole, _ = link_step(x, P, dt, part, params, False)
    assert d2_whole > cfg.gate_chi2


def _handover(split: float):
    """Vehicle 1 goes under an occluder at frame 30; vehicle 2, another colour, comes out where
    and when vehicle 1 would have (frame 51); vehicle 1 never comes back."""
    a = _line(0.0, 0.0, 10.0, 0.0, range(1, 31), np.random.default_rng(1))
    b = _line(0.0, 0.0, 10.0, 0.0, range(51, 91), np.random.default_rng(2))
    hists = {1: np.array([.7, .1, .1, .1]), 2: np.array([.1, .1, .1, .7])}
    frames, truth = _frames({1: a, 2: b}, 90, hist_of=lambda i: hists[i])
    cfg = AssociationConfig(split_appearance=split)
    return _identities(associate(frames, cfg, FPS, metres_per_unit=1.0, seed=0), truth)


def test_a_handover_across_a_bridged_gap_is_cut_by_colour():
    mixed = _handover(0.0)
    assert any(len(set(seq)) > 1 for seq in mixed.values())  # the sampler bridges 1 -> 2
    split = _handover(0.3)
    assert sorted(sorted(set(seq)) for seq in split.values()) == [[1], [2]]


def test_split_appearance_jumps_keeps_one_colour_whole():
    from aerotrack.association.local import split_appearance_jumps
    from aerotrack.types import TrackPoint

    def pt(f, h, kind="observed"):
        return TrackPoint(frame=f, box=np.zeros(4), world=np.zeros(2), conf=1.0, kind=kind,
                          hist=None if kind != "observed" else np.asarray(h, float))
    red, blue = [.7, .1, .1, .1], [.1, .1, .1, .7]
    pts = ([pt(f, red) for f in range(1, 6)] + [pt(f, None, "bridged") for f in range(6, 16)]
           + [pt(f, red) for f in range(16, 21)])
    assert split_appearance_jumps(pts, min_gap=3, side=6, threshold=0.3) == [pts]
    pts[-5:] = [pt(f, blue) for f in range(16, 21)]
    pieces = split_appearance_jumps(pts, min_gap=3, side=6, threshold=0.3)
    assert [[p.frame for p in q] for q in pieces] == [list(range(1, 6)), list(range(16, 21))]
    # a gap shorter than min_gap is not checked
    assert split_appearance_jumps(pts, min_gap=12, side=6, threshold=0.3) == [pts]


def test_split_appearance_jumps_cuts_once_per_change():
    """A colour change seen from several neighbouring boundaries is cut once, where it is."""
    from aerotrack.association.local import split_appearance_jumps
    from aerotrack.types import TrackPoint

    red, blue = np.array([.7, .1, .1, .1]), np.array([.1, .1, .1, .7])
    pts = [TrackPoint(frame=f, box=np.zeros(4), world=np.zeros(2), conf=1.0,
                      hist=red if f <= 10 else blue) for f in range(1, 21)]
    pieces = split_appearance_jumps(pts, min_gap=1, side=4, threshold=0.3)
    assert [[p.frame for p in q] for q in pieces] == [list(range(1, 11)), list(range(11, 21))]


def test_split_appearance_jumps_skips_a_change_of_box_size():
    """A colour change where the box also changes size (a trail of road, half behind a tree) is
    not a hand-over when ``max_size_ratio`` says so; at a steady size it is cut."""
    from aerotrack.association.local import split_appearance_jumps
    from aerotrack.types import TrackPoint

    red, blue = np.array([.7, .1, .1, .1]), np.array([.1, .1, .1, .7])
    small, large = np.array([0, 0, 20, 10.0]), np.array([0, 0, 40, 10.0])

    def pts(after_box):
        return ([TrackPoint(frame=f, box=small, world=np.zeros(2), conf=1.0, hist=red)
                 for f in range(1, 6)]
                + [TrackPoint(frame=f, box=after_box, world=np.zeros(2), conf=1.0, hist=blue)
                   for f in range(10, 15)])

    assert len(split_appearance_jumps(pts(large), min_gap=3, side=6, threshold=0.3)) == 2
    assert len(split_appearance_jumps(pts(large), min_gap=3, side=6, threshold=0.3,
                                      max_size_ratio=1.5)) == 1
    assert len(split_appearance_jumps(pts(small * 1.1), min_gap=3, side=6, threshold=0.3,
                                      max_size_ratio=1.5)) == 2


def test_a_short_piece_at_a_turn_starts_the_track_that_goes_on_from_it():
    """A vehicle (4.8 x 2.4 m, 10 m/s) turns: for 10 frames its box is square (rotating), then
    it drives on rotated (2.4 x 4.8 m). The size model cannot follow the box, so the sampler cuts
    the vehicle into three; the middle piece (10 frames, under ``min_length_s``) would be dropped.
    It starts the track that goes on from it instead; with stitching off it is lost."""
    def run(config):
        la = LocalAssociator(config, FPS, metres_per_unit=1.0, seed=0)
        out, x, y = [], 0.0, 0.0
        for f in range(1, 121):
            if f <= 40:
                x, size = x + 10 / FPS, (4.8, 2.4)
            elif f <= 50:
                x, y, size = x + 2 / FPS, y + 10 / FPS, (3.6, 3.6)
            else:
                y, size = y + 10 / FPS, (2.4, 4.8)
            w, s = np.array([[x, y]]), np.array([size])
            out += la.step(Detections(frame=f, boxes=np.column_stack([w - s / 2, s]),
                                      conf=np.ones(1), world=w, size_world=s))
        out += la.flush()
        return [(t.first, t.last) for t in out]

    assert run(AssociationConfig()) == [(1, 40), (41, 120)]
    assert run(AssociationConfig(stitch_dist_m=0.0)) == [(1, 40), (51, 120)]


def test_stitching_compares_headings():
    from aerotrack.association.local import _same_heading, _velocity

    v = _velocity([(1, np.array([0.0, 0.0])), (2, np.array([0.5, 0.1])), (3, np.array([1.0, 0.2]))])
    assert v == pytest.approx([0.5, 0.1])
    assert _velocity([(1, np.array([3.0, 4.0]))]).tolist() == [0.0, 0.0]
    east, north, west = np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([-1.0, 0.0])
    assert _same_heading(east, np.array([1.0, 0.5]), 60.0, 0.1)  # 27 degrees
    assert not _same_heading(east, north, 60.0, 0.1)
    assert not _same_heading(east, west, 60.0, 0.1)  # an oncoming vehicle
    assert _same_heading(east, 0.01 * west, 60.0, 0.1)  # standing: no heading


def _motion_points(xy, first=1):
    from aerotrack.types import TrackPoint

    return [TrackPoint(frame=first + k, box=np.zeros(4), world=np.asarray(p, float), conf=1.0)
            for k, p in enumerate(xy)]


def test_split_motion_jumps_cuts_a_tracklet_that_turns_round_at_speed():
    """Two vehicles passing in opposite lanes: west at 9 m/s, 10 frames on their merged blob
    (half-way between them, standing), then east at 9 m/s on the other vehicle: cut where it
    leaves the first vehicle and where it takes the second (the merged stretch may be a piece of
    its own); one vehicle braking, turning or turning round slowly is left whole."""
    from aerotrack.association.local import split_motion_jumps

    rng = np.random.default_rng(0)
    kw = dict(fps=30.0, metres_per_unit=1.0, side=15, accel_mps2=6.0, slack_mps=2.0)
    west = np.c_[100 - 0.3 * np.arange(60), np.zeros(60)]
    merged = np.tile([west[-1, 0], 1.75], (10, 1))
    east = np.c_[west[-1, 0] + 0.3 * np.arange(60), np.full(60, 3.5)]
    pts = _motion_points(np.vstack([west, merged, east]) + rng.normal(0, 0.1, (130, 2)))
    pieces = split_motion_jumps(pts, **kw)
    assert len(pieces) in (2, 3)
    assert 50 <= pieces[0][-1].frame <= 70 and 61 <= pieces[-1][0].frame <= 85
    assert [p for q in pieces for p in q] == pts
    # braking at 4 m/s^2 from 12 m/s to a stop, then standing
    t = np.arange(150) / 30.0
    s = np.where(t < 3.0, 12 * t - 2 * t * t, 18.0)
    braking = _motion_points(np.c_[s, np.zeros(150)] + rng.normal(0, 0.1, (150, 2)))
    assert len(split_motion_jumps(braking, **kw)) == 1
    # a 90-degree turn at 6 m/s over 1.5 s (60 deg/s)
    heading = np.clip((t - 1.0) / 1.5, 0, 1) * np.pi / 2
    turn = np.cumsum(np.c_[np.cos(heading), np.sin(heading)] * 6 / 30.0, axis=0)
    assert len(split_motion_jumps(_motion_points(turn + rng.normal(0, 0.1, (150, 2))), **kw)) == 1
    # a U-turn at 3 m/s, turning at 150 deg/s (the generator's dead ends)
    heading = np.clip((t - 1.0) / 1.2, 0, 1) * np.pi
    uturn = np.cumsum(np.c_[np.cos(heading), np.sin(heading)] * 3 / 30.0, axis=0)
    assert len(split_motion_jumps(_motion_points(uturn + rng.normal(0, 0.1, (150, 2))), **kw)) == 1


def test_coasting_track_does_not_take_the_vehicle_coming_the_other_way():
    """Vehicle 1 drives east at 5 m/s under an occluder (no detections for 0.7 s) and is not seen
    again; vehicle 2, in the next lane (3.2 m away), creeps out westwards from under it ahead of
    where 1 went in. Within the Kalman gate (accel_std 10 m/s^2) the link 1 -> 2 implies a lane
    change in 0.7 s: it is refused (``gap_accel_mps2``, with a known scale), and taken without
    that test. The same gap bridged by vehicle 1 itself, driving on, is still one tracklet."""
    rng = np.random.default_rng(1)
    one = _line(0, 0, 5, 0, range(1, 41), rng)
    x_in = one[40][0] + 5 * 21 / FPS * 0.5
    two = _line(x_in + 1.0 * 61 / FPS, 3.2, -1.0, 0, range(62, 101), rng)
    frames, truth = _frames({1: one, 2: two}, 100)

    def mixed(config, mpu=1.0):
        out = associate(frames, config, FPS, metres_per_unit=mpu, seed=0)
        return [seq for seq in _identities(out, truth).values() if len(set(seq)) > 1]

    gate = AssociationConfig(gap_accel_mps2=6.0, gap_lateral_mps2=3.0)
    assert mixed(gate) == []
    assert mixed(AssociationConfig(gap_accel_mps2=0.0)) != []
    assert mixed(gate, mpu=None) != []  # only with a known scale

    on = _line(0, 0, 5, 0, [*range(1, 41), *range(62, 101)], rng)
    frames, truth = _frames({1: on}, 100)
    out = associate(frames, gate, FPS, metres_per_unit=1.0, seed=0)
    assert len(out) == 1 and out[0].points[0].frame == 1 and out[0].points[-1].frame == 100


def test_histograms_may_start_after_empty_frames():
    """External detections on a video: the first frames hold no detections (and so no colour
    histograms), later ones carry them. With a known scale association used to fix "no
    histograms" on the first, empty frame and then refused the rest."""
    rng = np.random.default_rng(0)
    frames, _ = _frames({1: _line(0, 0, 8, 0, range(6, 40), rng)}, 40,
                        hist_of=lambda i: np.full(8, 1 / 8))
    assert not len(frames[0]) and frames[0].hist is None and frames[10].hist is not None
    out = associate(frames, AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    assert len(out) == 1 and len(out[0].points) == 34


@pytest.mark.parametrize("first", [1, 2])
def test_every_other_frame_loses_no_tracklet(first):
    """``--stride 2`` feeds every other frame; the associator takes the frames between as empty.
    Tracks ending in one of those used to have their tracklets dropped (the empty frame's
    finished tracks were not returned), so which vehicles survived depended on whether the
    run started on an odd or an even frame."""
    n = 150
    frames_used = list(range(first, n + 1, 2))
    tracks = {0: _line(0, 0, 8, 0, [f for f in frames_used if f <= 60]),
              1: _line(0, 20, 8, 0, [f for f in frames_used if f <= 70]),
              2: _line(0, 40, 8, 0, [f for f in frames_used if f <= 81]),
              3: _line(0, 60, 8, 0, frames_used)}
    frames, truth = _frames(tracks, n)
    la = LocalAssociator(AssociationConfig(), FPS, metres_per_unit=1.0, seed=0)
    out = []
    for d in frames:
        if d.frame in frames_used:
            out += la.step(d)
    out += la.flush()
    ids = _identities(out, truth)
    assert sorted({v for seq in ids.values() for v in seq}) == [0, 1, 2, 3]
    assert len(out) == 4


def test_iou_pairs_are_the_dense_matrix_pairs():
    """The sparse same-frame overlaps equal the (n, n) matrix's upper-triangle pairs, values and
    order (that matrix cost 0.9 s a frame at 3000 detections)."""
    from aerotrack.association.posterior import iou_pairs, iou_xywh_centre

    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 50, 400):
        z = np.column_stack([rng.uniform(0, 300, n), rng.uniform(0, 200, n),
                             rng.uniform(2, 40, n), rng.uniform(2, 20, n)])
        if n > 10:
            z[5] = z[6]  # a duplicate box
            z[7, 2] = 0.0  # a box without width
        dense = np.triu(iou_xywh_centre(z, z), 1) if n else np.zeros((0, 0))
        ii, jj = np.nonzero(dense > 0)
        i, j, v = iou_pairs(z)
        assert np.array_equal(i, ii) and np.array_equal(j, jj), n
        assert np.array_equal(v, dense[ii, jj]), n


def test_sparse_assignment_equals_the_dense_one():
    """Large assignments are solved per connected group of gated pairs: the same matching (its
    gated pairs) as the dense solve on problems with distinct costs."""
    from scipy.optimize import linear_sum_assignment

    from aerotrack.association import local

    rng = np.random.default_rng(5)
    for R, C in ((40, 60), (90, 70), (200, 200)):
        gated = rng.random((R, C)) < 0.02
        cost = np.where(gated, rng.uniform(-10, 5, (R, C)), 1e9)
        ri, ci = linear_sum_assignment(cost)
        keep = cost[ri, ci] < 1e9
        dense = set(zip(ri[keep].tolist(), ci[keep].tolist()))
        old = local.SPARSE_ASSIGNMENT_CELLS
        local.SPARSE_ASSIGNMENT_CELLS = 0
        try:
            si, sj = local._assignment(cost, gated)
        finally:
            local.SPARSE_ASSIGNMENT_CELLS = old
        keep = cost[si, sj] < 1e9
        assert set(zip(si[keep].tolist(), sj[keep].tolist())) == dense, (R, C)
        assert np.all(np.diff(si) > 0)


def test_follow_on_keeps_a_piece_where_an_ended_tracklet_was_going():
    """``association.follow_on_gap_s`` (off by default): a short piece that begins within the gap
    after a finished tracklet's end, where that tracklet's velocity puts it and heading its way,
    is kept; one elsewhere, later, or heading back is not."""
    from dataclasses import replace

    from aerotrack.types import TrackPoint

    def pts(frames, x0, vx):
        return [TrackPoint(frame=f, box=np.array([0.0, 0, 4, 2]),
                           world=np.array([x0 + vx * (f - frames[0]), 50.0]), conf=1.0,
                           kind="observed") for f in frames]

    la = LocalAssociator(replace(AssociationConfig(), follow_on_gap_s=0.2), 30.0, 1.0)
    la._remember_end(pts(range(1, 31), 0.0, 1.0))  # ends at frame 30, x = 29, 1 unit a frame
    assert la._follows_ended(pts(range(33, 38), 32.0, 1.0))  # 3 frames on, where it would be
    assert not la._follows_ended(pts(range(33, 38), 45.0, 1.0))  # 13 units off
    assert not la._follows_ended(pts(range(40, 45), 39.0, 1.0))  # 10 frames on: beyond 0.2 s
    assert not la._follows_ended(pts(range(33, 38), 32.0, -1.0))  # heading back
    off = LocalAssociator(AssociationConfig(), 30.0, 1.0)  # the default: off
    off._remember_end(pts(range(1, 31), 0.0, 1.0))
    assert not off._follows_ended(pts(range(33, 38), 32.0, 1.0))


@pytest.mark.parametrize("fps", [1.0, 2.0, 3.0])
def test_vehicles_filmed_at_wide_area_rates_become_tracklets(fps):
    """Frames 1/3 to 1 s apart (wide-area imagery): an exact link scored near 0 against a
    prediction that wide, no track earned its birth cost and a run wrote 0 tracks."""
    rng = np.random.default_rng(3)
    n = 16
    tracks = {}
    for i, (x0, y0, vx, vy) in enumerate([(0, 0, 12, 0), (0, 20, 9, 2), (80, 40, -10, 0)], 1):
        tracks[i] = {f: (x0 + vx * (f - 1) / fps + rng.normal(0, 0.3),
                         y0 + vy * (f - 1) / fps + rng.normal(0, 0.3)) for f in range(1, n + 1)}
    frames, truth = _frames(tracks, n)
    out = associate(frames, AssociationConfig(), fps, metres_per_unit=1.0, seed=0)
    ids = sorted(sorted(set(v)) for v in _identities(out, truth).values())
    assert ids == [[1], [2], [3]]
    assert sum(len(t.points) for t in out) >= 3 * (n - 2)
    assert LocalAssociator(AssociationConfig(), 10.0).gate2 == AssociationConfig().gate_chi2


def test_every_fifteenth_frame_of_a_video_becomes_tracklets():
    """--stride 15 on a 30 frames/s video: the gate follows the 2 frames/s processed (no track
    was born: the gate was the one for 30)."""
    rng = np.random.default_rng(4)
    step, n = 15, 16
    frames, truth = [], []
    paths = [(0, 0, 12, 0), (0, 20, 9, 2), (80, 40, -10, 0)]
    for k in range(n):
        f = 1 + k * step
        w = np.array([(x0 + vx * (f - 1) / 30 + rng.normal(0, 0.3),
                       y0 + vy * (f - 1) / 30 + rng.normal(0, 0.3)) for x0, y0, vx, vy in paths])
        sz = np.tile((4.5, 2.0), (3, 1))
        frames.append(Detections(frame=f, boxes=np.column_stack([w - sz / 2, sz]),
                                 conf=np.ones(3), world=w, size_world=sz))
        truth.append(np.array([1, 2, 3]))
    la = LocalAssociator(AssociationConfig(), 30.0, metres_per_unit=1.0, seed=0)
    la.set_frame_step(step)
    out = [t for d in frames for t in la.step(d)] + la.flush()
    ids = sorted(sorted({int(truth[(p.frame - 1) // step][p.det_index]) for p in t.points
                         if p.kind == "observed"}) for t in out)
    assert ids == [[1], [2], [3]]

"""Motion context (regression, LCE predictor selection, path following), appearance context,
tracklet descriptor and MPE_n: known answers on synthetic data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aerotrack.config import ContextConfig
from aerotrack.context.appearance import (
    AppearanceContext,
    TrackletDescriptor,
    appearance_likelihood,
    kl_color,
    kl_edge,
)
from aerotrack.context.motion import (
    ContextPredictor,
    PaperPredictor,
    TrackTable,
    affine_regression,
    bridge_gaps,
    fit_constant_velocity,
    get_predictor,
    kalman_start,
    lce,
)
from aerotrack.errors import ConfigError
from aerotrack.evaluation.prediction import (
    mpe_n,
    prediction_errors,
    summarise,
    variance_n,
)

# ---------------------------------------------------------------- regression (Ali et al. 4.1)


def test_regression_recovers_an_exact_affine_flow():
    rng = np.random.default_rng(1)
    start = rng.uniform(-50, 50, size=(6, 2))
    target = np.array([3.0, -7.0])
    for _ in range(5):
        A = np.eye(2) + rng.normal(0, 0.3, size=(2, 2))
        b = rng.normal(0, 20, size=2)
        now = start @ A.T + b
        r = affine_regression(start, now, target)
        np.testing.assert_allclose(r, A @ target + b, atol=1e-9)


def test_regression_refuses_collinear_or_too_few_predictors():
    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 5.0]])
    assert affine_regression(line, line + 1, np.zeros(2)) is None
    assert affine_regression(line[:2], line[:2], np.zeros(2)) is None


# ---------------------------------------------------------------- LCE (eq. 1)


def test_lce_zero_for_identical_motion_and_positive_for_diverging():
    t = np.arange(31, dtype=float)
    Z = np.column_stack([t, np.zeros_like(t)])
    assert lce(Z, Z.copy()) == 0.0
    turn = np.column_stack([t, 0.02 * t**2])  # same start, bends away
    wobble = Z + np.column_stack([np.zeros_like(t), 0.01 * np.sin(t)])  # stays close
    assert lce(Z, turn) > lce(Z, wobble) >= -1.0
    assert lce(Z, turn) > 0.05


def _straight_then(fr0: int, n: int, y: float, turn_at: int | None = None, speed: float = 1.0):
    """A track moving +x at ``speed`` px/frame from frame fr0; after ``turn_at`` frames it heads +y."""
    f = np.arange(fr0, fr0 + n)
    k = f - fr0
    x = speed * np.minimum(k, turn_at if turn_at is not None else n).astype(float)
    yy = np.full(n, y)
    if turn_at is not None:
        yy = yy + speed * np.maximum(k - turn_at, 0)
    return f, np.column_stack([x, yy])


def _table(tracks: dict[int, tuple[np.ndarray, np.ndarray]]) -> TrackTable:
    ids = np.concatenate([np.full(len(f), i) for i, (f, _) in tracks.items()])
    return TrackTable.from_arrays(ids, np.concatenate([f for f, _ in tracks.values()]),
                                  np.concatenate([xy for _, xy in tracks.values()]))


def test_paper_selects_alike_predictors_and_drops_a_diverging_one():
    cfg = ContextConfig(history_s=1.0, lce_alpha=0.02)
    tracks = {
        1: _straight_then(1, 200, 0.0),                 # the predictand
        2: _straight_then(1, 200, 20.0),                # moves alike, in parallel
        3: _straight_then(1, 200, -15.0),               # moves alike
        4: _straight_then(1, 200, 40.0, turn_at=70),    # alike until frame 71, then turns away
        5: _straight_then(1, 200, 60.0, speed=-1.0),    # the other way from the start
    }
    table = _table(tracks)
    pred = PaperPredictor(cfg, fps=30.0)
    first = pred.select(table, 1, 60)
    assert set(first) == {2, 3, 4}
    # maintained frame by frame (the paper's B(i) += 1): after 70 frames the sections of track 4
    # advanced with the predictand's cover its turn, so it is dropped
    later = pred.select(table, 1, 130, previous=first, previous_T=60)
    assert set(later) == {2, 3}
    assert later[2] == first[2] + 70


def test_paper_takes_the_section_whose_lce_is_closest_to_0_not_the_lowest():
    """"The closer the value of gamma is to 0, the more similar" (Ali et al. 4.2.2): a section
    that converges on the predictand (gamma far below 0) is not preferred to one that moves
    exactly alike (gamma 0); the lowest gamma had picked it."""
    cfg = ContextConfig(history_s=1.0, lce_alpha=0.05)
    f, xy = _straight_then(1, 200, 20.0)  # moves exactly alike, in parallel ...
    xy = xy.copy()
    xy[149, 1] += 3.0                      # ... but for one frame's glitch at frame 150
    table = _table({1: _straight_then(1, 200, 0.0), 2: (f, xy)})
    pred = PaperPredictor(cfg, fps=30.0)
    te = pred.select(table, 1, 190)[2]
    # the section starting at frame 149 has the glitch as its second point and ends on the
    # predictand's path: distances 3 then 0, a gamma of about -0.7
    assert te != 179
    Z = np.column_stack([np.arange(te - 30, te + 1) - 1.0, np.zeros(31)])
    sec = xy[te - 31:te] - xy[te - 31] + Z[0]
    assert abs(lce(Z, sec)) <= cfg.lce_alpha


def test_paper_keeps_its_predictors_frame_by_frame_and_drops_one_that_diverged():
    """The set is kept as the paper keeps it: a track that moved alike until frame 71 and then
    turned away is dropped by frame 80 (its advanced section diverges), though a fresh search at
    80 would find its earlier, alike sections."""
    cfg = ContextConfig(history_s=1.0, lce_alpha=0.02)
    tracks = {1: _straight_then(1, 200, 0.0), 2: _straight_then(1, 200, 20.0),
              3: _straight_then(1, 200, -15.0), 4: _straight_then(1, 200, 40.0, turn_at=70)}
    table = _table(tracks)
    pred = PaperPredictor(cfg, fps=30.0)
    assert set(pred.select(table, 1, 80)) == {2, 3, 4}
    assert set(pred.maintained(table, 1, 80)) == {2, 3}
    # a frame the predictand missed (a detection miss) is stepped over, not the end of the set
    f, xy = tracks[1]
    tracks[1] = (f[f != 75], xy[f != 75])
    assert set(pred.maintained(_table(tracks), 1, 80)) == {2, 3}
    f, xy = _straight_then(1, 200, 0.0)
    gap = _table({**tracks, 1: (f[f != 140], xy[f != 140])})
    assert set(pred.maintained(gap, 1, 150)) == {2, 3}


def test_context_uses_predictors_on_the_same_path_not_a_diverging_one():
    """Past objects drove a right turn; one went straight on. The target, arriving on the same road,
    follows the turn; a track heading the other way is never a predictor."""
    cfg = ContextConfig()
    fps = 30.0
    tracks = {}
    # units = metres; speed 0.3 m/frame (9 m/s); road along +x, turning to +y at x = 30
    for i, fr0 in enumerate((1, 40, 80), start=2):
        tracks[i] = _straight_then(fr0, 250, 0.0, turn_at=100, speed=0.3)
    # joined the road from a side street at x = 25 and went straight on at the corner: its path
    # does not pass the target's last positions, so it is no predictor
    f5 = np.arange(120, 370)
    k5 = (f5 - 120) * 0.3
    tracks[5] = (f5, np.column_stack([25.0 + np.maximum(k5 - 20, 0), np.minimum(k5 - 20, 0)]))
    f, xy = _straight_then(150, 160, 0.0, speed=-0.3)                  # oncoming, other direction
    tracks[6] = (f, xy + [60.0, 0.0])
    tracks[1] = _straight_then(300, 90, 0.0, turn_at=100, speed=0.3)  # target, last seen at 389
    table = _table(tracks)
    pred = ContextPredictor(cfg, fps)
    fr, xy = table.track(1)
    p0, v0 = kalman_start(fr[-31:], xy[-31:], fps, 1.0, cfg)
    chosen = {t for t, _, _ in pred.select(table, 1, fr[-31:], xy[-31:], 389, p0, v0)}
    assert chosen == {2, 3, 4}
    # the majority turned: the prediction bends towards +y
    out = pred.predict(table, 1, 389, 60)
    truth = _straight_then(300, 150, 0.0, turn_at=100, speed=0.3)[1][90:]
    cv = get_predictor("constant-velocity", cfg, fps).predict(table, 1, 389, 60)
    e_ctx = prediction_errors(out, truth).mean()
    e_cv = prediction_errors(cv, truth).mean()
    assert e_ctx < 0.6 * e_cv, (e_ctx, e_cv)
    assert out[-1, 1] > 2.0


def test_bridge_gaps_rebuilds_a_hidden_corner_and_u_turn():
    """A chord across a gap is replaced by the entry and exit headings' legs; the rebuilt points
    carry the frame of the row that fixed the exit heading."""
    fr = np.array([0, 5, 10, 25, 30])
    corner = np.array([[0, 0], [5, 0], [10, 0], [20, 10], [20, 15]], float)   # east, hidden, north
    xy, f = bridge_gaps(corner, fr, 7)
    np.testing.assert_allclose(xy, [[0, 0], [5, 0], [10, 0], [20, 0], [20, 10], [20, 15]])
    np.testing.assert_array_equal(f, [0, 5, 10, 30, 30, 30])
    # out at 1 unit/frame, back in the next lane: 15 frames hidden = 15 units driven, 3.6 apart
    uturn = np.array([[0, 0], [5, 0], [10, 0], [10, 3.6], [5, 3.6]], float)
    xy, _ = bridge_gaps(uturn, fr, 7)
    np.testing.assert_allclose(xy[3:5], [[15.7, 0.0], [15.7, 3.6]])
    straight = np.array([[0, 0], [5, 0], [10, 0], [25, 0], [30, 0]], float)
    xy, f = bridge_gaps(straight, fr, 7)
    np.testing.assert_array_equal(xy, straight)


def test_context_follows_predecessors_through_a_hidden_turn():
    """Earlier cars turned left behind an occluder (x in [20, 40]: no rows there); the target enters
    it. Their rebuilt hidden paths bend the prediction; before any of them came out, nothing does."""
    cfg = ContextConfig()
    fps = 30.0

    def hidden(f, xy):
        keep = ~((xy[:, 0] >= 20) & (xy[:, 0] <= 40) & (xy[:, 1] < 20))
        return f[keep], xy[keep]

    tracks = {i: hidden(*_straight_then(fr0, 300, 0.0, turn_at=100, speed=0.3))
              for i, fr0 in enumerate((1, 60, 323), start=2)}  # corner at x = 30
    # (the third comes out of the occluder at frame 490, during the prediction)
    tracks[1] = _straight_then(400, 64, 0.0, turn_at=100, speed=0.3)  # target, last seen at x = 18.9
    table = _table(tracks)
    truth = _straight_then(400, 124, 0.0, turn_at=100, speed=0.3)[1][64:]
    ctx = ContextPredictor(cfg, fps).predict(table, 1, 463, 60)
    kf = get_predictor("kalman", cfg, fps).predict(table, 1, 463, 60)
    e_ctx, e_kf = prediction_errors(ctx, truth)[-1], prediction_errors(kf, truth)[-1]
    assert e_ctx < 0.5 * e_kf, (e_ctx, e_kf)
    # causality: the frames up to f do not depend on rows after f (B_next of a gap included)
    for f in (470, 480, 492, 500, 510):
        cut = {i: (fr[fr <= f], xy[fr <= f]) for i, (fr, xy) in tracks.items()}
        part = ContextPredictor(cfg, fps).predict(_table(cut), 1, 463, 60)
        np.testing.assert_array_equal(part[: f - 463], ctx[: f - 463])
    # the same moment, when the predecessors had not yet come out: the Kalman prediction
    early = {i: hidden(*_straight_then(fr0, 300, 0.0, turn_at=100, speed=0.3))
             for i, fr0 in enumerate((380, 390), start=2)}  # hidden from frame 447 to 547 and on
    early[1] = tracks[1]
    out = ContextPredictor(cfg, fps).predict(_table(early), 1, 463, 60)
    np.testing.assert_allclose(out, kf, atol=1e-3)  # (the flow speed prior nudges it by < 1 mm)


def test_context_takes_a_short_track_speed_from_the_flow():
    """A target seen for two frames (9 m/s) has an unreliable velocity: the Kalman filter's prior
    shrinks it (hard with a 5 m/s prior, a little with the default 15 m/s). Cars seen earlier on
    its lane drove 9 m/s. After a second of its own motion (6 m/s) it keeps its own speed."""
    fps = 30.0
    tracks = {i: _straight_then(fr0, 200, 0.0, speed=0.3) for i, fr0 in enumerate((1, 50), start=2)}
    tracks[1] = (np.array([300, 301]), np.array([[10.0, 0.0], [10.3, 0.0]]))
    for cfg, shrunk in ((ContextConfig(kalman_vel_std_mps=5.0), 0.1), (ContextConfig(), 0.01)):
        pred = ContextPredictor(cfg, fps)
        out = pred.predict(_table(tracks), 1, 301, 30)
        kf = get_predictor("kalman", cfg, fps).predict(_table(tracks), 1, 301, 30)
        e_ctx = abs((out[-1, 0] - 10.3) / 30 - 0.3)
        e_kf = abs((kf[-1, 0] - 10.3) / 30 - 0.3)
        assert e_kf > shrunk and e_ctx < 0.4 * e_kf, (e_ctx, e_kf)  # default: 0.005 vs 0.023
    pred = ContextPredictor(ContextConfig(), fps)
    tracks[1] = _straight_then(270, 32, 0.0, speed=0.2)
    tracks[1] = (tracks[1][0], tracks[1][1] + [4.0, 0.0])
    out = pred.predict(_table(tracks), 1, 301, 30)
    assert abs((out[-1, 0] - out[0, 0]) / 29 - 0.2) < 0.01


def test_constant_velocity_fit_and_unknown_method():
    f = np.arange(10, 20)
    xy = np.column_stack([2.0 * f + 1, -0.5 * f])
    p0, v = fit_constant_velocity(f, xy)
    np.testing.assert_allclose(v, [2.0, -0.5])
    np.testing.assert_allclose(p0, xy[-1])
    with pytest.raises(ConfigError, match="valid: context, paper, kalman, constant-velocity"):
        get_predictor("magic")


def test_kalman_converges_to_the_true_velocity():
    f = np.arange(1, 61)
    xy = np.column_stack([0.5 * f, 0.25 * f])
    p, v = kalman_start(f, xy, 30.0, 1.0, ContextConfig())
    np.testing.assert_allclose(v, [0.5, 0.25], atol=0.02)
    np.testing.assert_allclose(p, xy[-1], atol=0.05)


# ---------------------------------------------------------------- appearance context (4.3)


def _obs(rng, colour, n=12, noise=0.01):
    h = np.clip(np.asarray(colour, float)[None] + rng.normal(0, noise, size=(n, len(colour))), 0, None)
    return h / h.sum(axis=1, keepdims=True)


def test_two_stage_match_picks_the_right_unobserved_target():
    rng = np.random.default_rng(0)
    red, blue, grey = [0.7, 0.1, 0.1, 0.1], [0.1, 0.1, 0.1, 0.7], [0.25, 0.25, 0.25, 0.25]
    ctx = AppearanceContext({1: _obs(rng, red), 2: _obs(rng, blue), 3: _obs(rng, grey)})
    s = _obs(rng, blue, n=1)[0]
    m = ctx.match(s, [1, 2, 3])
    assert m.target == 2 and m.verified
    assert m.intra[2] < m.intra[1] and m.intra[2] < m.intra[3]


def test_verification_rejects_an_object_that_matches_another_class_better():
    rng = np.random.default_rng(3)
    red, pink = [0.7, 0.1, 0.1, 0.1], [0.55, 0.25, 0.1, 0.1]
    # target 1 is red and very consistent; a pinkish newcomer is far outside its intra-class spread
    ctx = AppearanceContext({1: _obs(rng, red, noise=0.003), 2: _obs(rng, pink, noise=0.003)})
    s = _obs(rng, pink, n=1, noise=0.003)[0]
    assert not ctx.verify(s, 1, [1, 2])
    assert ctx.verify(s, 2, [1, 2])


# ---------------------------------------------------------------- descriptor (Yu & Medioni 5.2)


def _stats(rng, ring_colours, n_blobs=5, edge=(1, 2, 3, 3, 2, 1)):
    """Summed ring statistics (6, 8, 8) of blobs whose ring r has colour ring_colours[r]."""
    out = np.zeros((6, 8, 8))
    for _ in range(n_blobs):
        for r in range(6):
            for d in range(8):
                n = 20
                px = np.asarray(ring_colours[r], float)[None] + rng.normal(0, 6, size=(n, 3))
                out[r, d, 0] += n
                out[r, d, 1:4] += px.sum(axis=0)
                out[r, d, 4:7] += (px * px).sum(axis=0)
                out[r, d, 7] += edge[r] * (1 + (d % 2))
    return out


def test_descriptor_is_rotation_invariant_and_discriminative():
    rng = np.random.default_rng(5)
    car = [(200, 30, 30)] * 3 + [(90, 90, 90)] * 3
    van = [(240, 240, 240)] * 6
    a = _stats(rng, car)
    da = TrackletDescriptor.from_stats(a)
    rotated = TrackletDescriptor.from_stats(np.roll(a, 3, axis=1))  # directions shifted by 135 deg
    assert kl_color(da, rotated) == pytest.approx(0.0, abs=1e-12)
    assert kl_edge(da, rotated) == pytest.approx(0.0, abs=1e-12)
    same = TrackletDescriptor.from_stats(_stats(rng, car))
    other = TrackletDescriptor.from_stats(_stats(rng, van, edge=(3, 3, 1, 1, 1, 1)))
    assert kl_color(da, same) < 0.1 * kl_color(da, other)
    assert kl_edge(da, same) < kl_edge(da, other)
    assert appearance_likelihood(da, same) > appearance_likelihood(da, other)
    assert TrackletDescriptor.from_stats(np.zeros((6, 8, 8))) is None


# ---------------------------------------------------------------- MPE_n (Ali et al. 5)


def test_mpe_and_variance_known_answer():
    pred = np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 2.0]])
    truth = np.zeros((3, 2))
    e = prediction_errors(pred, truth)
    np.testing.assert_allclose(e, [0, 5, 2])
    assert mpe_n(e, 2) == pytest.approx(2.5)
    assert variance_n(e, 2) == pytest.approx(6.25)
    assert mpe_n(e, 3) == pytest.approx(7 / 3)
    s = summarise(np.array([e, e * 2]), [1, 3])
    assert s[3]["MPE"] == pytest.approx(3.5) and s[1]["queries"] == 2
    assert math.isnan(summarise(np.zeros((0, 3)), [1])[1]["MPE"])


def test_context_moves_a_hidden_car_with_its_queue():
    """Three cars wait in a queue; the target is hidden while the queue starts moving. Its
    co-movers' observed displacement carries it along; constant velocity leaves it standing."""
    cfg = ContextConfig()
    f = np.arange(1, 201)
    go = np.clip(f - 100, 0, None)
    move = 0.5 * np.minimum(go, 60) ** 2 / 60 / 30 * 6 + np.where(go > 60, (go - 60) * 0.2, 0)  # metres
    tracks = {i: (f, np.column_stack([move - 7.0 * i, np.full(len(f), 0.0)])) for i in (1, 2, 3)}
    tracks[1] = (f[f <= 95], tracks[1][1][f <= 95])  # the target, hidden from frame 96
    table = _table(tracks)
    fps = 30.0
    truth = np.column_stack([move - 7.0, np.zeros(len(f))])[95:195]
    ctx = ContextPredictor(cfg, fps).predict(table, 1, 95, 100)
    assert set(ContextPredictor(cfg, fps).comovers(table, 1, 95)) == {2, 3}
    cv = get_predictor("constant-velocity", cfg, fps).predict(table, 1, 95, 100)
    e_ctx = prediction_errors(ctx, truth).mean()
    e_cv = prediction_errors(cv, truth).mean()
    assert e_ctx < 0.25 * e_cv, (e_ctx, e_cv)


def test_follow_flow_turns_with_the_road_and_keeps_straight_without_support():
    """Earlier objects drove a circle of radius 40 m; following their flow stays near the circle,
    far closer than the straight line; with no earlier objects it is the straight line."""
    from aerotrack.context.motion import PathIndex, follow_flow

    cfg = ContextConfig()
    fps, r, w = 30.0, 40.0, 0.3 / 40.0  # 9 m/s
    tracks = {}
    for i, fr0 in enumerate((1, 100, 200), start=2):
        f = np.arange(fr0, fr0 + 800)
        a = w * (f - fr0)
        tracks[i] = (f, np.column_stack([r * np.cos(a), r * np.sin(a)]))
    p0, v0 = np.array([0.0, r]), np.array([-0.3, 0.0])  # a quarter of the way round
    tracks[1] = (np.array([1000]), p0[None])
    index = PathIndex(_table(tracks), fps, 1.0, cfg)
    gate = math.cos(math.radians(45))
    out = follow_flow(index, p0, v0, 1000, 90, 1, 3.0, gate, 0.01, 1.0, 6)
    radial = np.hypot(out[:, 0], out[:, 1]) - r
    straight = np.hypot(r, 0.3 * 90) - r
    assert abs(radial[-1]) < 0.15 * straight, (radial[-1], straight)
    alone = PathIndex(_table({1: tracks[1]}), fps, 1.0, cfg)
    out = follow_flow(alone, p0, v0, 1000, 90, 1, 3.0, gate, 0.01, 1.0, 6)
    np.testing.assert_allclose(out, p0 + np.arange(1, 91)[:, None] * v0)


def test_lce_of_a_section_ending_where_the_target_s_ends_is_finite():
    """It was minus infinity (with a RuntimeWarning) and ranked first whatever it did between."""
    import warnings

    from aerotrack.context.paper import _lce_batch

    t = np.arange(31.0)
    Z = np.column_stack([t, np.zeros(31)])
    swing = Z.copy()
    swing[:, 1] = 100 * np.sin(np.pi * t / 30)  # away by 100 units and back to the same end
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = _lce_batch(Z, swing[None])
    assert np.isfinite(g).all() and np.isfinite(lce(Z, swing))
    straight = np.column_stack([t * 1.01, np.zeros(31)])
    # ranked like a close follower's at worst, not below everything
    assert g[0] > -1.0 and lce(Z, straight) > 0


def test_predict_says_when_the_paper_method_fell_back(tmp_path, capsys):
    from conftest import run_cli

    rows = "".join(f"{f},1,{f}.0,0,4,2,1,-1,-1,-1\n" for f in range(1, 60))
    (tmp_path / "t.csv").write_text(rows)
    (tmp_path / "q.csv").write_text("id,last_seen,horizon\n1,50,5\n")
    code, _, err = run_cli(capsys, "predict", tmp_path / "t.csv", "--queries", tmp_path / "q.csv",
                           "--out", tmp_path / "p.csv", "--method", "paper")
    assert code == 0 and "1 of 1 queries had fewer than 3 predictors" in err

"""Road-network motion context (aerotrack.context.roads): known answers on small road graphs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import run_cli

from aerotrack.config import ContextConfig
from aerotrack.context.motion import PathIndex, TrackTable, get_predictor
from aerotrack.context.roads import RoadNetwork, branch_probabilities, read_roads, road_prediction
from aerotrack.errors import ConfigError, InputError

FPS = 30.0


def straight_track(start, velocity, frames=31, track_id=1, first=1):
    """A track moving at ``velocity`` m/s from ``start``: (ids, frames, xy)."""
    f = np.arange(first, first + frames)
    xy = np.asarray(start, float) + (f - f[-1])[:, None] / FPS * np.asarray(velocity, float)
    return np.full(frames, track_id), f, xy


def table_of(*tracks):
    ids = np.concatenate([t[0] for t in tracks])
    fr = np.concatenate([t[1] for t in tracks])
    xy = np.vstack([t[2] for t in tracks])
    return TrackTable.from_arrays(ids, fr, xy)


def predict(table, roads, track_id=1, horizon=240, config=None):
    pred = get_predictor("context", config or ContextConfig(), FPS, roads=roads)
    fr, _ = table.track(track_id)
    return pred.predict(table, track_id, int(fr[-1]), horizon)


def test_target_heading_into_an_l_shaped_road_is_predicted_around_the_corner():
    net = RoadNetwork([np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0]])], bounds=(-50, -50, 200, 200))
    table = table_of(straight_track((50.0, 0.0), (10.0, 0.0)))  # 50 m before the corner at 10 m/s
    p = predict(table, net)
    for t, want in [(3.0, (80.0, 0.0)), (6.0, (100.0, 10.0)), (8.0, (100.0, 30.0))]:
        k = round(t * FPS) - 1
        assert np.hypot(*(p[k] - want)) < 1.0, (t, p[k], want)
    # the Kalman filter alone goes straight on past the corner
    kal = get_predictor("kalman", ContextConfig(), FPS).predict(table, 1, 31, 240)
    assert np.hypot(*(kal[-1] - (100.0, 30.0))) > 40


def test_dead_end_gives_a_u_turn_keeping_the_lane_and_an_open_end_goes_straight_on():
    line = np.array([[0.0, 0.0], [100.0, 0.0]])
    c = ContextConfig()
    # 1.5 m right of the centre-line when driving +x (right-hand normal (-t_y, t_x) = +y)
    table = table_of(straight_track((60.0, 1.5), (10.0, 0.0)))
    dead = RoadNetwork([line], bounds=(-50, -50, 200, 200))  # the end at x=100 is inside the map
    p = predict(table, dead, horizon=240, config=c)
    # 4 s to the end, road_uturn_s lost there, then back: at 8 s, 10 * (8 - 4 - 1) = 30 m back
    assert np.hypot(*(p[int(8 * FPS) - 1] - (70.0, -1.5))) < 1.0, p[int(8 * FPS) - 1]
    assert np.hypot(*(p[int(3 * FPS) - 1] - (90.0, 1.5))) < 1.0
    open_end = RoadNetwork([line])  # the lines' own extent: the end is on the map's edge
    q = predict(table, open_end, horizon=240, config=c)
    assert np.hypot(*(q[int(8 * FPS) - 1] - (140.0, 1.5))) < 1.0


def test_an_off_road_target_falls_back_to_the_kalman_prediction_exactly():
    net = RoadNetwork([np.array([[0.0, 0.0], [100.0, 0.0]])], bounds=(-50, -50, 200, 200))
    c = ContextConfig()
    far = table_of(straight_track((50.0, 30.0), (10.0, 0.0)))  # 30 m from the road
    across = table_of(straight_track((50.0, 2.0), (0.0, 10.0)))  # on it, but crossing it
    for table in (far, across):
        with_roads = predict(table, net, config=c)
        without = predict(table, None, config=c)
        kalman = get_predictor("kalman", c, FPS).predict(table, 1, 31, 240)
        assert np.array_equal(with_roads, without)  # bit for bit what it is without roads
        assert np.allclose(with_roads, kalman, rtol=0, atol=1e-9)  # (up to the fusion's rounding)
    assert road_prediction(net, np.array([50.0, 30.0]), np.array([10 / FPS, 0.0]), 10, FPS, c) is None


def test_a_vehicle_glimpsed_for_one_frame_drives_its_lane_at_the_speed_of_the_others():
    # generated scenes: a vehicle seen in one frame (the video's first, or between two
    # occluders) has no velocity; 1.8 m right of the centre-line it drives +x in right-hand
    # traffic, -x in left-hand, at the other vehicles' speed (7 m/s here); right-hand is
    # assumed until three moving vehicles say otherwise
    net = RoadNetwork([np.array([[0.0, 0.0], [200.0, 0.0]])], bounds=(-50, -50, 250, 50))
    other = straight_track((20.0, -1.8), (-7.0, 0.0), track_id=2, first=70)  # last row at 100
    glimpse = (np.array([1]), np.array([100]), np.array([[80.0, 1.8]]))
    table = table_of(glimpse, other)
    p = predict(table, net)
    assert np.hypot(*(p[59] - (94.0, 1.8))) < 0.5, p[59]  # 2 s at 7 m/s
    left = predict(table, net, config=replace(ContextConfig(), road_traffic_side="left"))
    assert np.hypot(*(left[59] - (66.0, 1.8))) < 0.5, left[59]
    # auto (the default) learns the side from the vehicles moving now: three keep left
    lefties = [straight_track((20.0 + 30 * k, -1.8), (7.0, 0.0), track_id=3 + k, first=70)
               for k in range(3)]
    learned = predict(table_of(glimpse, *lefties), net)
    assert np.hypot(*(learned[59] - (66.0, 1.8))) < 0.5, learned[59]
    # alone in the video: the configured typical speed
    alone = predict(table_of(glimpse), net)
    assert np.hypot(*(alone[59] - (80.0 + 2 * ContextConfig().road_glimpse_speed_mps, 1.8))) < 0.5
    # on the centre-line either way is as likely, off the road there is no lane: it stays put,
    # as without roads, and so does a vehicle seen long enough to have a velocity of its own
    for xy in ([80.0, 0.2], [80.0, 20.0]):
        t = table_of((np.array([1]), np.array([100]), np.array([xy])), other)
        assert np.allclose(predict(t, net)[59], predict(t, None)[59])
    parked = table_of(straight_track((80.0, 1.8), (0.0, 0.0), first=70), other)
    assert np.hypot(*(predict(parked, net)[59] - (80.0, 1.8))) < 0.5
    with pytest.raises(ConfigError, match="road_traffic_side"):
        get_predictor("context", replace(ContextConfig(), road_traffic_side="middle"), FPS, roads=net)


def cross_network():
    # a 4-way crossing at (100, 0): west-east road and south-north road
    return RoadNetwork([np.array([[0.0, 0.0], [200.0, 0.0]]), np.array([[100.0, -100.0], [100.0, 100.0]])],
                       bounds=(-50, -150, 250, 150))


def test_at_a_junction_the_learned_road_beats_the_straightest_branch():
    net = cross_network()
    assert len(net.nodes) == 5 and len(net.adjacency[int(np.argmin(np.hypot(*(net.nodes - (100, 0)).T)))]) == 4
    target = straight_track((60.0, 0.0), (10.0, 0.0), first=600)
    # without earlier objects the most likely route is straight on ...
    p = predict(table_of(target), net, horizon=180, config=ContextConfig(road_hedge="none"))
    assert np.hypot(*(p[-1] - (120.0, 0.0))) < 1.0
    # ... but not likelier than the turns: the hedged prediction stays between the three branches
    # (on the straight road's axis by symmetry, past the crossing but short of straight on)
    m = predict(table_of(target), net, horizon=180, config=ContextConfig(road_hedge="median"))
    assert abs(m[-1][1]) < 1e-6 and 100.0 < m[-1][0] < 115.0, m[-1]
    # an earlier car came the same way and turned left (to -y) at the crossing
    f = np.arange(1, 301)
    s = 10.0 * (f - 1) / FPS  # 10 m/s from x = 20
    xy = np.where((s < 80)[:, None], np.column_stack([20 + s, 0 * s]),
                  np.column_stack([np.full_like(s, 100.0), -(s - 80)]))
    earlier = (np.full(len(f), 2), f, xy)
    table = table_of(target, earlier)
    constant = ContextConfig(road_turn_speed_mps=0.0)  # no braking for the turn
    q = predict(table, net, horizon=180, config=constant)
    assert np.hypot(*(q[-1] - (100.0, -20.0))) < 1.5, q[-1]
    # the linker's view: both branches (and the third) are hypotheses, the chosen one first
    pred = get_predictor("context", constant, FPS, roads=net)
    hyps = pred.hypotheses(table, 1, int(target[1][-1]), 180)
    ends = np.array([h[-1] for h in hyps])
    assert np.array_equal(hyps[0], q)
    for want in [(100.0, -20.0), (120.0, 0.0), (100.0, 20.0)]:
        assert np.hypot(*(ends - want).T).min() < 1.5, want


def test_a_vehicle_brakes_for_a_sharp_turn_and_not_for_straight_on():
    net = cross_network()
    target = straight_track((60.0, 0.0), (10.0, 0.0), first=600)
    f = np.arange(1, 301)
    s = 10.0 * (f - 1) / FPS
    turned = np.where((s < 80)[:, None], np.column_stack([20 + s, 0 * s]),
                      np.column_stack([np.full_like(s, 100.0), -(s - 80)]))
    table = table_of(target, (np.full(len(f), 2), f, turned))
    c = ContextConfig(road_turn_speed_mps=5.0, road_turn_decel_mps2=3.0, road_turn_accel_mps2=2.5)
    q = predict(table, net, horizon=180, config=c)
    # 10 -> 5 m/s at 3 m/s^2 brakes over 12.5 m, so from 27.5 m (2.75 s) to the crossing 40 m
    # ahead (at 2.75 + 5/3 s); then 2.5 m/s^2 for the rest of the 6 s
    after = 6.0 - (2.75 + 5.0 / 3.0)
    want_y = -(5.0 * after + 0.5 * 2.5 * after ** 2)
    assert abs(q[-1][0] - 100.0) < 0.5 and abs(q[-1][1] - want_y) < 0.5, (q[-1], want_y)
    assert np.hypot(*(q[int(2.5 * FPS) - 1] - (85.0, 0.0))) < 0.5  # full speed before braking
    # straight on through the crossing keeps the speed
    alone = predict(table_of(target), net, horizon=180, config=replace(c, road_hedge="none"))
    assert np.hypot(*(alone[-1] - (120.0, 0.0))) < 1.0, alone[-1]


def test_branch_probabilities_are_votes_smoothed_by_the_turn_prior():
    cos = np.array([0.0, 1.0, 0.0])  # left, straight on, right
    p = branch_probabilities(np.array([3.0, 1.0, 0.0]), cos, prior_weight=1.0, kappa=0.0)
    assert np.allclose(p, np.array([3 + 1 / 3, 1 + 1 / 3, 1 / 3]) / 5)
    # no votes: the prior alone, uniform for kappa 0, e^kappa : 1 : 1 otherwise
    assert np.allclose(branch_probabilities(np.zeros(3), cos, 1.0, 0.0), 1 / 3)
    assert np.allclose(branch_probabilities(np.zeros(3), cos, 1.0, np.log(3.0)), [0.2, 0.6, 0.2])
    # no prior weight: the voters' frequencies
    assert np.allclose(branch_probabilities(np.array([3.0, 1.0, 0.0]), cos, 0.0, 2.0), [0.75, 0.25, 0])


def drove(track_id, turn):
    """An earlier car at 10 m/s along y = 0 from x = 20 that at the crossing (100, 0) went
    ``turn`` (-1 to -y, 0 straight on, +1 to +y)."""
    f = np.arange(1, 301)
    s = 10.0 * (f - 1) / FPS
    after = np.column_stack([20 + s, 0 * s]) if turn == 0 else \
        np.column_stack([np.full_like(s, 100.0), turn * (s - 80)])
    return np.full(len(f), track_id), f, np.where((s < 80)[:, None], np.column_stack([20 + s, 0 * s]), after)


def test_hedged_prediction_lies_at_the_weighted_centre_of_the_voted_branches():
    from scipy.optimize import minimize

    net = cross_network()
    target = straight_track((60.0, 0.0), (10.0, 0.0), first=600)
    table = table_of(target, drove(2, -1), drove(3, 0))  # one turned left, one went straight on
    p0, v0 = np.array([60.0, 0.0]), np.array([10.0 / FPS, 0.0])
    c = ContextConfig(road_turn_speed_mps=0.0, road_vote_prior=1.0, road_straight_kappa=0.0)
    index = PathIndex(table, FPS, 1.0, c)

    def drive(hedge):
        return road_prediction(net, p0, v0, 180, FPS, replace(c, road_hedge=hedge), index=index,
                               frame=630, exclude_id=1)

    rp = drive("none")
    # votes 1:1 (straight first on the tie), 0 for right; uniform prior worth one vote
    ends = np.array([h[-1] for h in rp.hypotheses])
    assert np.allclose(ends, [(120.0, 0.0), (100.0, -20.0), (100.0, 20.0)], atol=1e-6), ends
    w = np.array([4 / 9, 4 / 9, 1 / 9])
    assert np.allclose(rp.weights, w)
    assert np.array_equal(rp.positions, rp.hypotheses[0])
    assert np.allclose(drive("mean").positions[-1], w @ ends)

    def cost(x):  # expected distance to the truth if it is on one of the branches
        return float(w @ np.hypot(*(ends - x).T))

    best = minimize(cost, w @ ends, method="Nelder-Mead", options={"xatol": 1e-8, "fatol": 1e-10}).x
    med = drive("median").positions
    assert np.hypot(*(med[-1] - best)) < 1e-3, (med[-1], best)
    # off every branch (no branch has half the weight), and cheaper than any
    assert np.hypot(*(ends - med[-1]).T).min() > 2.0 and cost(med[-1]) < min(cost(e) for e in ends)
    # before the crossing (4 s at 10 m/s) every branch is at the same place: no hedge there
    assert np.allclose(med[: int(4 * FPS) - 1], rp.hypotheses[0][: int(4 * FPS) - 1])
    # a majority branch is the median: two left, one straight on -> left
    table = table_of(target, drove(2, -1), drove(3, 0), drove(4, -1))
    index = PathIndex(table, FPS, 1.0, c)
    assert np.allclose(drive("median").positions[-1], (100.0, -20.0), atol=1e-6)


def test_route_weights_multiply_per_junction_and_sum_to_one():
    # a second crossing 15 m past the first on the straight road: the straight route splits
    # again, and its three continuations share its third instead of counting as routes of their own
    net = RoadNetwork([np.array([[0.0, 0.0], [200.0, 0.0]]), np.array([[100.0, -100.0], [100.0, 100.0]]),
                       np.array([[115.0, -100.0], [115.0, 100.0]])], bounds=(-50, -150, 250, 150))
    c = ContextConfig(road_vote_prior=1.0, road_straight_kappa=0.0)
    rp = road_prediction(net, np.array([60.0, 0.0]), np.array([10.0 / FPS, 0.0]), 180, FPS, c)
    assert np.allclose(sorted(rp.weights), [1 / 9, 1 / 9, 1 / 9, 1 / 3, 1 / 3])
    # fewer routes enumerated than there are: the kept ways of a junction share its probability
    few = road_prediction(net, np.array([60.0, 0.0]), np.array([10.0 / FPS, 0.0]), 180, FPS, c,
                          max_routes=3)
    assert len(few.hypotheses) == 3 and abs(few.weights.sum() - 1.0) < 1e-12


def test_an_unknown_hedge_is_refused_naming_the_valid_ones():
    with pytest.raises(ConfigError, match="road_hedge.*valid: none, mean, median"):
        get_predictor("context", ContextConfig(road_hedge="average"), FPS, roads=cross_network())


def test_a_road_ending_near_another_becomes_a_t_junction():
    net = RoadNetwork([np.array([[0.0, 0.0], [200.0, 0.0]]), np.array([[100.0, 3.0], [100.0, 100.0]])],
                      snap_m=5.0, bounds=(-50, -50, 250, 150))
    deg = sorted(len(a) for a in net.adjacency)
    assert deg == [1, 1, 1, 3]
    node = net.nodes[[len(a) for a in net.adjacency].index(3)]
    assert np.allclose(node, (100.0, 0.0))  # on the through road


def test_geojson_in_lonlat_onto_a_map_in_another_crs(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from pyproj import Transformer
    from rasterio.transform import from_origin

    from aerotrack.geo import GeoMap

    # a 2 m/pixel map in UTM 11N, top-left at (660000, 4002000)
    tif = tmp_path / "map.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=200, height=150, count=1, dtype="uint8",
                       crs="EPSG:32611", transform=from_origin(660000, 4002000, 2.0, 2.0)) as ds:
        ds.write(np.zeros((1, 150, 200), np.uint8))
    geomap = GeoMap(tif)
    want_px = np.array([[10.0, 20.0], [190.0, 20.0], [190.0, 140.0]])
    utm = np.column_stack([660000 + 2 * want_px[:, 0], 4002000 - 2 * want_px[:, 1]])
    lon, lat = Transformer.from_crs("EPSG:32611", "EPSG:4326", always_xy=True).transform(*utm.T)
    feats = [{"type": "Feature", "properties": {},
              "geometry": {"type": "MultiLineString", "coordinates": [list(zip(lon, lat))]}}]
    path = tmp_path / "roads.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    net = read_roads(path, geomap=geomap)
    assert len(net.lines) == 1
    assert np.abs(net.lines[0] - want_px).max() < 1e-3
    assert net.mpu == pytest.approx(2.0, rel=0.01)
    # the same lines in Web Mercator with a legacy crs member
    x, y = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lon, lat)
    path.write_text(json.dumps({"type": "FeatureCollection",
                                "crs": {"type": "name", "properties": {"name": "EPSG:3857"}},
                                "features": [{"type": "Feature", "properties": {}, "geometry": {
                                    "type": "LineString", "coordinates": list(zip(x, y))}}]}))
    assert np.abs(read_roads(path, geomap=geomap).lines[0] - want_px).max() < 1e-3


@pytest.mark.parametrize("text, fragment", [
    ("not json", "cannot read as GeoJSON"),
    ('{"type": "FeatureCollection", "features": []}', "no LineString"),
    (('{"type": "LineString", "coordinates": [[0, 0], [1, 1]], "crs": '
      '{"type": "name", "properties": {"name": "EPSG:999999"}}}'), "unknown crs"),
    ('{"type": "LineString", "coordinates": [[0, 0], [1, 1]], "crs": "EPSG:4326"}', "malformed crs"),
    ('{"type": "LineString", "coordinates": [[0, 0], ["a", 1]]}', "malformed coordinates"),
    ('[1, 2]', "not a GeoJSON object"),
])
def test_bad_road_files_raise_one_line_input_errors(tmp_path, text, fragment):
    path = tmp_path / "bad.geojson"
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        read_roads(path, crs="EPSG:3857")
    assert fragment in str(exc.value) and str(path) in str(exc.value)
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match="file not found"):
        read_roads(tmp_path / "missing.geojson")


# -- command line -----------------------------------------------------------------------------------
def l_road_files(tmp_path):
    """An L-shaped road in lon/lat and a target's track in UTM 11N metres heading into it."""
    from pyproj import Transformer

    x0, y0 = 660000.0, 4000000.0
    corner = np.array([[x0, y0], [x0 + 100, y0], [x0 + 100, y0 + 100]])
    lon, lat = Transformer.from_crs("EPSG:32611", "EPSG:4326", always_xy=True).transform(*corner.T)
    roads = tmp_path / "roads.geojson"
    roads.write_text(json.dumps({"type": "Feature", "properties": {}, "geometry": {
        "type": "LineString", "coordinates": list(zip(lon, lat))}}))
    _, f, xy = straight_track((x0 + 50, y0), (10.0, 0.0))
    tracks = tmp_path / "tracks.csv"
    tracks.write_text("".join(f"{a},1,{b[0]:.3f},{b[1]:.3f},4,2,1,{b[0]:.3f},{b[1]:.3f},-1\n"
                              for a, b in zip(f, xy)))
    queries = tmp_path / "q.csv"
    queries.write_text(f"id,last_seen,horizon\n1,{f[-1]},240\n")
    return roads, tracks, queries, (x0 + 100, y0 + 30)


def test_predict_command_follows_the_roads(tmp_path, capsys):
    roads, tracks, queries, want = l_road_files(tmp_path)
    out = tmp_path / "p.csv"
    code, _, err = run_cli(capsys, "predict", tracks, "--queries", queries, "--out", out, "--space", "map",
                        "--roads", roads, "--crs", "EPSG:32611")
    assert code == 0, err
    last = np.array([float(v) for v in out.read_text().splitlines()[-1].split(",")[3:5]])
    assert np.hypot(*(last - want)) < 1.0, last


def test_predict_command_drives_a_glimpse_on_the_right_in_north_up_coordinates(tmp_path, capsys):
    """In a CRS's coordinates y grows northwards: a vehicle keeping right while driving east is
    south of the centre-line (in map pixels, y down, it would be the other way round)."""
    roads, _, _, _ = l_road_files(tmp_path)  # the L's first leg runs east along y = 4000000
    x0, y0 = 660000.0, 4000000.0
    tracks = tmp_path / "glimpses.csv"
    # each seen in frame 1 only (and again long after, which a prediction from frame 1 ignores)
    rows = [(1, 1, x0 + 30, y0 - 1.8), (1, 200, x0 + 40, y0 - 1.8),
            (2, 1, x0 + 60, y0 + 1.8), (2, 200, x0 + 50, y0 + 1.8)]
    tracks.write_text("".join(f"{f},{i},0,0,4,2,1,{x},{y},-1\n" for i, f, x, y in rows))
    queries = tmp_path / "q.csv"
    queries.write_text("id,last_seen,horizon\n1,1,60\n2,1,60\n")
    out = tmp_path / "p.csv"
    code, _, err = run_cli(capsys, "predict", tracks, "--queries", queries, "--out", out, "--space",
                           "map", "--roads", roads, "--crs", "EPSG:32611")
    assert code == 0, err
    rows = [ln.split(",") for ln in out.read_text().splitlines()[1:]]
    end = {int(r[1]): np.array([float(r[3]), float(r[4])]) for r in rows if int(r[2]) == 61}
    speed = ContextConfig().road_glimpse_speed_mps  # nothing else moves
    assert np.hypot(*(end[1] - (x0 + 30 + 2 * speed, y0 - 1.8))) < 0.5, end[1]  # south: east
    assert np.hypot(*(end[2] - (x0 + 60 - 2 * speed, y0 + 1.8))) < 0.5, end[2]  # north: west


def test_bad_roads_options_exit_2_with_one_line_naming_the_file(tmp_path, capsys):
    roads, tracks, queries, _ = l_road_files(tmp_path)
    bad = tmp_path / "bad.geojson"
    bad.write_text('{"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": '
                   '{"type": "Point", "coordinates": [0, 0]}}]}')
    out = tmp_path / "p.csv"
    cases = [
        (("predict", tracks, "--queries", queries, "--out", out, "--space", "map", "--roads", bad,
          "--crs", "EPSG:32611"), [str(bad), "no LineString"]),
        (("predict", tracks, "--queries", queries, "--out", out, "--space", "map", "--roads",
          tmp_path / "missing.geojson", "--crs", "EPSG:32611"), ["missing.geojson", "not found"]),
        (("predict", tracks, "--queries", queries, "--out", out, "--space", "map", "--roads", roads),
         [str(roads), "--crs"]),
        (("predict", tracks, "--queries", queries, "--out", out, "--roads", roads), ["--space map"]),
        (("track", "--detections", tracks, "--out", tmp_path / "run", "--roads", roads),
         [str(roads), "needs --map"]),
    ]
    for argv, fragments in cases:
        code, _, err = run_cli(capsys, *argv)
        assert code == 2, (argv, err)
        assert "Traceback" not in err
        lines = [ln for ln in err.splitlines() if ln.strip() and "WARNING" not in ln and "INFO" not in ln]
        assert len(lines) == 1 and lines[0].startswith(("aerotrack: error:", "Error:")), err
        for frag in fragments:
            assert frag in err, (frag, err)
    assert not out.exists()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from aerotrack.synth import render_to

    out = tmp_path_factory.mktemp("roads") / "scene"
    render_to(out, seed=1, frames=30, size=(320, 240))
    return out


def test_synth_writes_the_roads_its_vehicles_drive(scene):
    from aerotrack.geo import GeoMap

    net = read_roads(scene / "roads.geojson", geomap=GeoMap(scene / "map.tif"))
    assert len(net.lines) == 9
    rows = [ln.split(",") for ln in (scene / "states.csv").read_text().splitlines()[1:]]
    px = np.array([[float(r[3]), float(r[4])] for r in rows])
    # every vehicle drives within its lane (<= 2 m) of a centre-line
    mpp = net.mpu
    from aerotrack.context.motion import polyline_distance

    d = np.min([polyline_distance(px, e.pts) for e in net.edges], axis=0)
    assert d.max() * mpp < 2.5


def test_track_command_takes_roads_on_the_map(scene, tmp_path, capsys):
    out = tmp_path / "run"
    code, _, err = run_cli(capsys, "track", "--detections", scene / "gt.txt", "--map", scene / "map.tif",
                        "--map-init", scene / "map_init.txt", "--roads", scene / "roads.geojson",
                        "--out", out)
    assert code == 0, err
    assert json.loads((out / "summary.json").read_text())["roads"] == str(scene / "roads.geojson")


def test_track_with_roads_on_dask_matches_the_single_process(tmp_path, capsys):
    """--roads reaches linking in a segment-parallel run: its predictions are the single
    process's, and differ from those without roads (so the roads were used)."""
    pytest.importorskip("distributed")
    from aerotrack.synth import render_to

    scene = tmp_path / "scene"
    render_to(scene, seed=1, frames=150, size=(320, 240), scenario="exits")
    args = ["track", "--detections", scene / "gt.txt", "--map", scene / "map.tif",
            "--map-init", scene / "map_init.txt"]
    roads = ["--roads", scene / "roads.geojson"]
    for name, extra in (("one", roads), ("dask", [*roads, "--workers", "1"]), ("plain", [])):
        code, _, err = run_cli(capsys, *args, *extra, "--out", tmp_path / name)
        assert code == 0, err
    read = lambda run, f: (tmp_path / run / f).read_text()
    assert read("dask", "tracks.csv") == read("one", "tracks.csv")
    assert read("dask", "predicted.csv") == read("one", "predicted.csv")
    assert read("plain", "predicted.csv") != read("one", "predicted.csv")


def test_predict_names_a_bad_crs_and_warns_when_roads_are_elsewhere(tmp_path, capsys):
    """A wrong --crs was blamed on --roads, and one that put the roads far from the tracks
    (lon/lat tracks read as UTM) dropped the roads silently."""
    roads, _, _, _ = l_road_files(tmp_path)
    tracks = tmp_path / "t.csv"
    x0, y0 = 660000.0, 4000000.0
    tracks.write_text("".join(f"{f},1,0,0,4,2,1,{x0 + 30 + f},{y0 - 1.8},-1\n" for f in range(1, 11)))
    queries = tmp_path / "q.csv"
    queries.write_text("id,last_seen,horizon\n1,10,5\n")
    out = tmp_path / "p.csv"
    code, _, err = run_cli(capsys, "predict", tracks, "--queries", queries, "--out", out,
                           "--space", "map", "--roads", roads, "--crs", "FOO")
    assert code == 2 and "--crs FOO" in err and not out.exists(), err
    code, _, err = run_cli(capsys, "predict", tracks, "--queries", queries, "--out", out,
                           "--space", "map", "--roads", roads, "--crs", "EPSG:32633")
    assert code == 0 and "no road within" in err, err
    code, _, err = run_cli(capsys, "predict", tracks, "--queries", queries, "--out", out,
                           "--space", "map", "--roads", roads, "--crs", "EPSG:32611")
    assert code == 0 and "no road within" not in err, err
    # UTM tracks with --crs EPSG:4326: the roads read in degrees, rebuilt at the tracks' metres,
    # had no segment left and raised a ValueError traceback
    code, _, err = run_cli(capsys, "predict", tracks, "--queries", queries, "--out", out,
                           "--space", "map", "--roads", roads, "--crs", "EPSG:4326")
    assert code == 2 and "--roads" in err and "same CRS" in err and "Traceback" not in err, err


def test_track_from_keeps_the_runs_roads_and_its_own_folder(scene, tmp_path, capsys):
    """--from re-ran association without the earlier run's --roads (predictions as without
    roads), into its own folder without --overwrite; a bad --out-crs left a half-written
    folder."""
    out = tmp_path / "run"
    code, _, err = run_cli(capsys, "track", "--detections", scene / "gt.txt", "--map",
                           scene / "map.tif", "--map-init", scene / "map_init.txt", "--roads",
                           scene / "roads.geojson", "--out", out)
    assert code == 0, err
    again = tmp_path / "again"
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", again)
    assert code == 0, err
    assert (again / "predicted.csv").read_text() == (out / "predicted.csv").read_text()
    assert json.loads((again / "summary.json").read_text())["roads"] == str(scene / "roads.geojson")
    before = (out / "tracks.csv").read_text()
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", out)
    assert code == 2 and "--overwrite" in err and (out / "tracks.csv").read_text() == before, err
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", out, "--overwrite")
    assert code == 0 and (out / "stages").is_dir(), err
    bad = tmp_path / "bad"
    for crs in ("EPSG:4326", "EPSG:4978"):  # geographic; geocentric (refused at write time,
        # after the work, leaving .partial/ behind)
        code, _, err = run_cli(capsys, "track", "--from", out, "--out", bad, "--out-crs", crs)
        assert code == 2 and "--out-crs" in err and not bad.exists(), err
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", tmp_path / "far", "--out-crs",
                           "EPSG:32633")
    assert code == 0 and "distorted" in err and "area of use is lon" in err, err
    assert "Between" not in err, err  # the CRS's paragraph of places is left out
    # Web Mercator: within its area of use, but its distances are 1.24x the ground's here
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", tmp_path / "wm", "--out-crs",
                           "EPSG:3857")
    assert code == 0 and "1.24x the ground's" in err, err
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", tmp_path / "utm", "--out-crs",
                           "EPSG:32611")
    assert code == 0 and "the ground's" not in err and "distorted" not in err, err


def test_roads_and_regions_off_the_map_are_not_silent(scene, tmp_path, capsys):
    """Swapped lon/lat roads, roads 5 degrees away, NaN or one-vertex lines and an --roi off the
    map were all accepted silently (the roi left an empty result, the roads changed nothing).
    A run with a map and no track still writes observations.csv/.gpkg (empty)."""
    from aerotrack.geo import GeoMap

    net = json.loads((scene / "roads.geojson").read_text())
    feats = net["features"]

    def write(name, features):
        path = tmp_path / name
        path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
        return path

    swapped = write("swapped.geojson", [
        {**f, "geometry": {**f["geometry"], "coordinates": [c[::-1] for c in
                                                             f["geometry"]["coordinates"]]}}
        for f in feats])
    with pytest.raises(InputError, match="not lon/lat"):
        read_roads(swapped, geomap=GeoMap(scene / "map.tif"))
    far = write("far.geojson", [
        {**f, "geometry": {**f["geometry"], "coordinates": [[c[0] + 5, c[1]] for c in
                                                            f["geometry"]["coordinates"]]}}
        for f in feats])
    broken = write("broken.geojson", feats + [
        {"type": "Feature", "properties": {}, "geometry": {"type": "LineString",
                                                           "coordinates": [[-115.1, 36.1]]}}])
    args = ["track", "--detections", scene / "gt.txt", "--map", scene / "map.tif", "--map-init",
            scene / "map_init.txt"]
    code, _, err = run_cli(capsys, *args, "--roads", far, "--out", tmp_path / "far")
    assert code == 0 and "no road crosses the map" in err, err
    code, _, err = run_cli(capsys, *args, "--roads", broken, "--out", tmp_path / "broken")
    assert code == 0 and "1 line left out" in err, err
    roi = tmp_path / "roi.geojson"
    roi.write_text(json.dumps({"type": "Polygon", "coordinates": [[
        [36.1, -115.1], [36.2, -115.1], [36.2, -115.2], [36.1, -115.1]]]}))  # lat, lon swapped
    code, _, err = run_cli(capsys, *args, "--roi", roi, "--out", tmp_path / "roi")
    assert code == 2 and "--roi" in err and ("outside the map" in err or "no vertex" in err), err
    code, _, err = run_cli(capsys, *args, "--ignore-region", roi, "--out", tmp_path / "ign")
    assert code == 0 and "ignores nothing" in err, err
    tiny = tmp_path / "tiny.txt"
    tiny.write_text("1,-1,5,5,2,2,0.9\n")  # one detection: no track
    code, _, err = run_cli(capsys, "track", "--detections", tiny, "--map", scene / "map.tif",
                           "--map-init", scene / "map_init.txt", "--out", tmp_path / "none")
    assert code == 0, err
    assert (tmp_path / "none" / "observations.csv").read_text().startswith("frame,time_s,id,")
    assert (tmp_path / "none" / "observations.gpkg").is_file()


def test_roads_from_a_geopackage_or_shapefile(scene, tmp_path):
    """Road centre-lines in the formats GIS users keep them (a GeoPackage in UTM, with Z; a
    Shapefile) read as the same network as the GeoJSON (they were refused: 'cannot read as
    GeoJSON ('utf-8' codec can't decode ...)')."""
    pyogrio = pytest.importorskip("pyogrio")
    import struct
    import warnings

    from pyproj import Transformer

    from aerotrack.geo import GeoMap

    gm = GeoMap(scene / "map.tif")
    ref = read_roads(scene / "roads.geojson", geomap=gm)
    doc = json.loads((scene / "roads.geojson").read_text())
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32611", always_xy=True)

    def wkb(coords, z):  # LineString Z (ISO 1002) or LineString, little-endian
        pts = [to_utm.transform(*c[:2]) for c in coords]
        if z:
            return struct.pack("<BII", 1, 1002, len(pts)) + b"".join(
                struct.pack("<ddd", x, y, 700.0) for x, y in pts)
        return struct.pack("<BII", 1, 2, len(pts)) + b"".join(struct.pack("<dd", *p) for p in pts)

    lines = [f["geometry"]["coordinates"] for f in doc["features"]
             if f["geometry"]["type"] == "LineString"]
    for name, z, kind in (("roads.gpkg", True, "LineString Z"), ("roads.shp", False, "LineString")):
        geoms = np.array([wkb(c, z) for c in lines], dtype=object)
        pyogrio.raw.write(str(tmp_path / name), geoms, [np.arange(len(lines))], ["fid_"],
                          geometry_type=kind, crs="EPSG:32611")
        net = read_roads(tmp_path / name, geomap=gm)
        assert len(net.lines) == len(ref.lines) == len(lines)
        for a, b in zip(net.lines, ref.lines):
            assert np.abs(np.asarray(a) - np.asarray(b)).max() < 0.01  # map pixels
    nocrs = np.array([wkb(c, False) for c in lines], dtype=object)  # UTM, and no .prj
    with warnings.catch_warnings():  # pyogrio's "crs was not provided": the point here
        warnings.simplefilter("ignore", UserWarning)
        pyogrio.raw.write(str(tmp_path / "nocrs.shp"), nocrs, [np.arange(len(lines))], ["fid_"],
                          geometry_type="LineString")
    with pytest.raises(InputError, match=r"needs its \.prj"):
        read_roads(tmp_path / "nocrs.shp", geomap=gm)
    (tmp_path / "junk.bin").write_bytes(b"\x00\x01garbage")
    with pytest.raises(InputError, match="GDAL vector file"):
        read_roads(tmp_path / "junk.bin", geomap=gm)


def test_start_time_dates_the_geo_outputs(scene, tmp_path, capsys):
    """--start-time gives observations a time_utc column (a date-time in the GeoPackage, a UTC
    timestamp in the Parquet file) and each tracks.geojson feature its start and end times, for
    GIS time sliders (there were seconds since frame 1 only); a time without a UTC offset is
    refused; --from keeps the earlier run's."""
    import csv
    import datetime

    out = tmp_path / "run"
    args = ["track", scene / "frames", "--map", scene / "map.tif", "--map-init",
            scene / "map_init.txt", "--frames", "1:20"]
    code, _, err = run_cli(capsys, *args, "--out", out, "--start-time", "2024-05-01T12:30:00+02:00")
    assert code == 0, err
    assert json.loads((out / "summary.json").read_text())["start_time"] == \
        "2024-05-01T10:30:00.000+00:00"
    with open(out / "observations.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and list(rows[0])[-1] == "time_utc"
    fps = json.loads((out / "summary.json").read_text())["fps"]
    for r in rows:
        t = datetime.datetime.fromisoformat(r["time_utc"])
        want = datetime.datetime(2024, 5, 1, 10, 30, tzinfo=datetime.UTC) \
            + datetime.timedelta(seconds=(int(r["frame"]) - 1) / fps)
        assert abs((t - want).total_seconds()) <= 0.0005, r
    feats = json.loads((out / "tracks.geojson").read_text())["features"]
    assert feats and all(f["properties"]["start_time_utc"].startswith("2024-05-01T10:30:")
                         for f in feats)
    pyogrio = pytest.importorskip("pyogrio")
    fields = pyogrio.read_info(out / "observations.gpkg")
    assert dict(zip(fields["fields"], fields["dtypes"]))["time_utc"].startswith("datetime64")
    again = tmp_path / "again"
    code, _, err = run_cli(capsys, "track", "--from", out, "--out", again)
    assert code == 0, err
    assert json.loads((again / "summary.json").read_text())["start_time"].startswith("2024-05-01")
    code, _, err = run_cli(capsys, *args, "--out", tmp_path / "bad", "--start-time",
                           "2024-05-01T10:30:00")
    assert code == 2 and "UTC offset" in err and not (tmp_path / "bad").exists(), err

"""Motion-context prediction on real trajectories (Stanford Drone Dataset scenes).

Protocol (issue 6, after Ali, Reilly & Shah section 5): 30 fps, F = 30 frames of history, a query
every 0.5 s (frames divisible by 15) for each Car, Bus, Cart, Biker and Skater that moved >= 0.5 m in
its last observed second and whose greatest distance from where that second began, over the second
plus the 3 s horizon, is >= 3 m; `lost` rows dropped (from the truth and from the context alike);
every frame of history and horizon must be present. Constant velocity is least squares over the last
F frames. A window is *curved* when the heading of the true motion (over 0.5 s steps, ignoring
steps shorter than 0.25 m) departs from the heading of the last observed second by more than 30
degrees anywhere in the horizon. Errors in metres with the scene scales of SOURCE.md.

Each method predicts with :meth:`aerotrack.context.motion.MotionPredictor.predict` on the whole
scene's table: the target's rows after `last_seen` and other tracks' rows after each predicted frame
are ignored by construction (tested in tests/test_predict.py).

Generated scenes (``--synth``, issue 6 "prediction on generated scenes"): scenes of
:mod:`aerotrack.synth` (made and cached as ``benchmarks/identity.py`` does, in
/tmp/aerotrack_identity), where convoys and earlier vehicles drive the same roads. The table holds
every vehicle's TRUE position (``states.csv`` map_x, map_y scaled to metres per axis) in the frames
where it is visible; for every gap (a run of >= 0.5 s occluded/outside between two visible stretches)
the target is predicted from its last visible frame, and the error against its true position (known
while hidden) is taken 1, 2 and 4 s into the gap when the gap is still running. Occlusions and exits
are reported apart and together, as ratios to the Kalman filter, and together once more for the
gaps whose target was seen in each of the F frames before (``all, F frames seen``: the paper's
protocol, observe F frames then predict; "all" also has targets glimpsed for a frame or two). The variant ``context+roads`` is
the default method with the scene's road centre-lines (``roads.geojson`` written by ``aerotrack
synth``, else the bundled file it comes from; :mod:`aerotrack.context.roads`), in the same metres.

Pedestrians (``--ethucy``): the ETH (eth, hotel) and UCY (zara01, zara02) trajectories of
``../shared/data/eth_ucy_pedestrians/`` (metres, annotated every 0.4 s) under the field's standard
protocol: every window of 8 observed and 12 predicted consecutive steps of each pedestrian (2.5
frames/s; the other pedestrians' rows up to each predicted step are the context), ADE (mean error
over the 12 steps, MPE_12) and FDE (error at the last step, 4.8 s). A check out of sample: the
context's parameters were chosen on the SDD scenes (vehicles, bikes, 30 fps) and are not changed
here. ``cv-last`` is the last step's velocity, the "constant velocity model" of that literature.

Run: /tmp/venv/bin/python benchmarks/prediction.py [--scenes deathCircle/video4 ...] [--stride 15]
     /tmp/venv/bin/python benchmarks/prediction.py --synth [--synth-scenes occlusion:1 exits:2 ...]
     [--set context.KEY=VALUE ...]
     /tmp/venv/bin/python benchmarks/prediction.py --ethucy
Writes benchmarks/results/prediction.json (the SDD part under ``sdd``, the generated scenes under
``synth``, the pedestrians under ``ethucy``; a run of one part keeps the others' last results).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from aerotrack.config import ContextConfig, load_config
from aerotrack.context.motion import PREDICTION_METHODS, TrackTable, get_predictor
from aerotrack.evaluation.prediction import prediction_errors, summarise

DATA = ROOT.parent / "shared" / "data" / "sdd_stanford_drone_subset"
SCALES = {  # metres per pixel, SOURCE.md
    "nexus/video4": 0.04588, "nexus/video5": 0.04540,
    "gates/video8": 0.04519, "deathCircle/video4": 0.03898,
}
QUERY_CLASSES = {"Car", "Bus", "Cart", "Biker", "Skater"}
FPS, F, H = 30.0, 30, 90
NS = {"1s": 30, "2s": 60, "3s": 90}


def load_sdd(path: Path):
    """(ids, frames, xy centres in px, labels dict) of the non-lost rows."""
    ids, frames, xy, labels = [], [], [], {}
    for line in path.read_text().splitlines():
        p = line.split()
        if len(p) < 10 or p[6] == "1":
            continue
        i = int(p[0])
        x0, y0, x1, y1 = map(float, p[1:5])
        ids.append(i)
        frames.append(int(p[5]) + 1)  # 1-based like every aerotrack file
        xy.append(((x0 + x1) / 2, (y0 + y1) / 2))
        labels[i] = p[9].strip('"')
    return TrackTable.from_arrays(ids, frames, xy), labels


def make_queries(table: TrackTable, labels: dict, mpp: float, stride: int):
    """[(id, last_seen, truth (H, 2), curved)] following the protocol."""
    out = []
    for i in table.track_ids():
        if labels.get(int(i)) not in QUERY_CLASSES:
            continue
        fr, xy = table.track(int(i))
        if len(fr) < F + H + 1:
            continue
        pos = {int(f): k for k, f in enumerate(fr)}
        for T in range(int(fr[0]) + F, int(fr[-1]) - H + 1):
            if T % stride:
                continue
            a, b = pos.get(T - F), pos.get(T + H)
            if a is None or b is None or b - a != F + H:
                continue  # a missing (lost) frame in the window
            seg = xy[a:b + 1]
            if np.hypot(*(seg[F] - seg[0])) * mpp < 0.5:
                continue
            if np.hypot(*(seg - seg[0]).T).max() * mpp < 3.0:
                continue
            h0 = math.atan2(*(seg[F] - seg[0])[::-1])
            curved = False
            for k in range(F + 1, F + H + 1):
                d = seg[k] - seg[k - 15]
                if math.hypot(*d) * mpp < 0.25:
                    continue
                dh = abs((math.atan2(d[1], d[0]) - h0 + math.pi) % (2 * math.pi) - math.pi)
                if dh > math.radians(30):
                    curved = True
                    break
            out.append((int(i), T, seg[F + 1:].copy(), curved))
    return out


def warm_up(config) -> None:
    """Compile the Kalman filter (numba) before anything is timed."""
    get_predictor("kalman", config, FPS).predict(
        TrackTable.from_arrays([1, 1, 1], [1, 2, 3], [[0, 0], [1, 0], [2, 0]]), 1, 3, 2)


def run(scenes, stride, methods, config):
    warm_up(config)
    per = {m: {"curved": [], "straight": []} for m in methods}
    timing = {m: 0.0 for m in methods}
    counts = {}
    for scene in scenes:
        table, labels = load_sdd(DATA / scene / "annotations.txt")
        mpp = SCALES[scene]
        queries = make_queries(table, labels, mpp, stride)
        counts[scene] = {"curved": sum(q[3] for q in queries),
                         "straight": sum(not q[3] for q in queries)}
        for m in methods:
            pred = get_predictor(m, config, FPS, metres_per_unit=mpp)
            t0 = time.perf_counter()
            for i, T, truth, curved in queries:
                p = pred.predict(table, i, T, H)
                per[m]["curved" if curved else "straight"].append(prediction_errors(p, truth) * mpp)
            timing[m] += time.perf_counter() - t0
    return per, timing, counts


SYNTH_SCENES = ([f"default:{i}" for i in range(6)] + [f"exits:{i}" for i in range(8)]
                + [f"occlusion:{i}" for i in range(8)])
SYNTH_AT = {"1s": 30, "2s": 60, "4s": 120}
MIN_GAP = 15  # frames: 0.5 s


def synth_queries(scene: Path, fragment: bool = False):
    """(table of visible true positions in metres, [(id, last_seen, kind, {frame: true xy})]) of a
    generated scene: one query per gap of >= MIN_GAP hidden frames between two visible stretches.

    With ``fragment`` every visible stretch (split at gaps of >= MIN_GAP frames) gets its own id, as
    tracklets do before linking: earlier vehicles' hidden stretches are then unknown."""
    from identity import (  # benchmarks/identity.py: the same gap definition
        gaps_of,
        load_states,
    )

    info = json.loads((scene / "scenario.json").read_text())
    mpp = np.asarray(info["map_metres_per_pixel"], float)
    states = load_states(scene)
    ids, frames, xy = [], [], []
    for tid, st in states.items():
        for f, (state, x, y) in st.items():
            if state == "visible":
                ids.append(tid)
                frames.append(f)
                xy.append((x * mpp[0], y * mpp[1]))
    ids, frames = np.asarray(ids), np.asarray(frames)
    qid = {}
    if fragment:
        piece = np.zeros(len(ids), np.int64)
        for tid in np.unique(ids):
            k = np.flatnonzero(ids == tid)
            k = k[np.argsort(frames[k])]
            cut = np.concatenate([[0], np.cumsum(np.diff(frames[k]) > MIN_GAP)])
            piece[k] = cut
            for f, c in zip(frames[k], cut):
                qid[(int(tid), int(f))] = int(tid) * 1000 + int(c)
        ids = ids * 1000 + piece
    table = TrackTable.from_arrays(ids, frames, xy)
    queries = []
    for tid, a, b, kind in gaps_of(states):
        truth = {a + n: np.array(states[tid][a + n][1:]) * mpp
                 for n in SYNTH_AT.values() if a + n < b and a + n in states[tid]}
        if truth:
            queries.append((qid.get((tid, a), tid), a, kind, truth))
    return table, queries


#: Gaps (occlusions and exits) whose target was seen in each of the F frames before it: the
#: paper's section-5 protocol (observe F frames, then predict), as on the SDD scenes; "all" also
#: holds gaps after a glimpse (a vehicle seen for a few frames, often at the video's start).
SEEN_KIND = "all, F frames seen"
ROAD_VARIANT = "context+roads"
#: Not a predictor: the road hypothesis nearest the truth (MotionPredictor.hypotheses), what a
#: linker gating on the nearest branch can reach.
ROAD_ORACLE = "roads nearest branch (oracle)"


def scene_roads(scene: Path, config):
    """The scene's road network in the benchmark's metres (map pixels x metres per pixel)."""
    from aerotrack.context.roads import RoadNetwork, read_roads
    from aerotrack.geo import GeoMap
    from aerotrack.synth.world import ROADS

    info = json.loads((scene / "scenario.json").read_text())
    mpp = np.asarray(info["map_metres_per_pixel"], float)
    geomap = GeoMap(scene / "map.tif")
    path = scene / "roads.geojson"
    net = read_roads(path if path.exists() else ROADS, geomap=geomap, snap_m=config.roads_snap_m)
    return RoadNetwork([a * mpp for a in net.lines], 1.0, config.roads_snap_m,
                       bounds=(0.0, 0.0, geomap.width * mpp[0], geomap.height * mpp[1]))


def _predictor(m, config, roads=None):
    if m == ROAD_VARIANT:
        return get_predictor("context", config, FPS, metres_per_unit=None, roads=roads)
    return get_predictor(m, config, FPS, metres_per_unit=None)


def run_synth(specs, frames, methods, config, fragment=False):
    """Errors {method: {kind: {"1s": [m...]}}} at 1/2/4 s into every gap, and seconds per query."""
    from identity import make_scene

    warm_up(config)
    extra = [ROAD_ORACLE] if ROAD_VARIANT in methods else []
    # errors per method, kind ("occlusion", "exit", and SEEN_KIND: either, with the paper's F
    # frames observed before the gap) and horizon
    per = {m: {k: {s: [] for s in SYNTH_AT} for k in ("occlusion", "exit", SEEN_KIND)}
           for m in [*methods, *extra]}
    timing = {m: 0.0 for m in methods}
    counts: dict[str, dict[str, int]] = {}
    nq = 0
    for spec in specs:
        scen, seed = spec.split(":")
        scene = make_scene(scen, int(seed), frames, False)
        table, queries = synth_queries(scene, fragment)
        counts[spec] = {k: sum(q[2] == k for q in queries) for k in ("occlusion", "exit")}
        nq += len(queries)
        h = max(SYNTH_AT.values())
        roads = scene_roads(scene, config) if ROAD_VARIANT in methods else None
        for m in methods:
            pred = _predictor(m, config, roads)
            t0 = time.perf_counter()
            out = [pred.predict(table, i, T, h) for i, T, _, _ in queries]
            timing[m] += time.perf_counter() - t0
            for (i, T, kind, truth), p in zip(queries, out):
                fr = table.track(i)[0]
                kinds = (kind, SEEN_KIND) if np.sum((fr > T - F) & (fr <= T)) >= F else (kind,)
                for s, n in SYNTH_AT.items():
                    if T + n in truth:
                        for k in kinds:
                            per[m][k][s].append(float(np.hypot(*(p[n - 1] - truth[T + n]))))
                if m == ROAD_VARIANT:
                    hyps = pred.hypotheses(table, i, T, h)
                    for s, n in SYNTH_AT.items():
                        if T + n in truth:
                            for k in kinds:
                                per[ROAD_ORACLE][k][s].append(
                                    min(float(np.hypot(*(q[n - 1] - truth[T + n]))) for q in hyps))
    return per, {m: t / max(nq, 1) for m, t in timing.items()}, counts


def synth_report(specs, frames, methods, config, fragment=False) -> dict:
    per, timing, counts = run_synth(specs, frames, methods, config, fragment)
    res = {"protocol": {"scenes": specs, "frames": frames, "fps": FPS, "min_gap_frames": MIN_GAP,
                        "fragment": fragment,
                        "at": SYNTH_AT, "gaps": counts,
                        "source": "aerotrack.synth true positions of visible vehicles, metres"},
           "MPE_m": {}, "ratio_to_kalman": {}, "n": {}, "seconds_per_query": timing}
    print(f"generated scenes {specs}: gaps {counts}")
    print(f"{'method':<18} {'gaps':<10} " + " ".join(f"{k:>16}" for k in SYNTH_AT))
    for m in per:
        res["MPE_m"][m], res["ratio_to_kalman"][m] = {}, {}
        for kind in ("occlusion", "exit", "all", SEEN_KIND):
            kinds = ("occlusion", "exit") if kind == "all" else (kind,)
            row, rrow, nrow = {}, {}, {}
            for s in SYNTH_AT:
                e = [x for k in kinds for x in per[m][k][s]]
                ek = [x for k in kinds for x in per["kalman"][k][s]]
                row[s] = float(np.mean(e)) if e else float("nan")
                rrow[s] = row[s] / float(np.mean(ek)) if ek and np.mean(ek) > 0 else float("nan")
                nrow[s] = len(e)
            res["MPE_m"][m][kind], res["ratio_to_kalman"][m][kind] = row, rrow
            res["n"][kind] = nrow
            print(f"{m:<18} {kind:<10} " + " ".join(
                f"{row[s]:6.2f}m {rrow[s]:4.2f}x" + f"({nrow[s]:>3})" for s in SYNTH_AT))
    print("predict time per query: " + ", ".join(f"{m} {t * 1e3:.2f} ms" for m, t in timing.items()))
    return res


ETHUCY = ROOT.parent / "shared" / "data" / "eth_ucy_pedestrians"
#: Video frames between two annotations (SOURCE.md): every annotation is 0.4 s apart.
ETHUCY_STEP = {"seq_eth": 6, "seq_hotel": 10, "zara01": 10, "zara02": 10}
ETHUCY_OBS, ETHUCY_PRED, ETHUCY_FPS = 8, 12, 2.5


def load_obsmat(path: Path, step: int) -> TrackTable:
    """An ETH/UCY ``obsmat.txt`` as a table of annotation steps (frame 1, 2, ... 0.4 s apart).

    Video frame numbers are mapped to steps by rounding the differences between the annotated
    frames to multiples of ``step`` (seq_eth's annotated frames have three offsets modulo 6)."""
    a = np.loadtxt(path, ndmin=2)
    u = np.unique(a[:, 0])
    idx = 1 + np.concatenate([[0], np.cumsum(np.round(np.diff(u) / step))]).astype(int)
    return TrackTable.from_arrays(a[:, 1].astype(int), idx[np.searchsorted(u, a[:, 0])], a[:, [2, 4]])


def ethucy_report(methods, config) -> dict:
    """ADE / FDE per sequence and over all windows (8 observed, 12 predicted steps)."""
    warm_up(config)
    methods = list(dict.fromkeys(["constant-velocity", "kalman", *methods, "cv-last"]))
    per = {m: {} for m in methods}
    timing = {m: 0.0 for m in methods}
    counts = {}
    OBS_PRED = ETHUCY_OBS + ETHUCY_PRED
    n_all = 0
    for seq, step in ETHUCY_STEP.items():
        table = load_obsmat(ETHUCY / seq / "obsmat.txt", step)
        queries = []
        for i in table.track_ids():
            fr, xy = table.track(int(i))
            for k in range(len(fr) - OBS_PRED + 1):
                if fr[k + OBS_PRED - 1] - fr[k] == OBS_PRED - 1:
                    queries.append((int(i), int(fr[k + ETHUCY_OBS - 1]),
                                    xy[k + ETHUCY_OBS - 2:k + OBS_PRED]))
        counts[seq] = len(queries)
        n_all += len(queries)
        steps = np.arange(1, ETHUCY_PRED + 1, dtype=np.float64)[:, None]
        for m in methods:
            t0 = time.perf_counter()
            if m == "cv-last":
                out = [w[1] + steps * (w[1] - w[0]) for _, _, w in queries]
            else:
                pred = get_predictor(m, config, ETHUCY_FPS, metres_per_unit=1.0)
                out = [pred.predict(table, i, T, ETHUCY_PRED) for i, T, _ in queries]
            timing[m] += time.perf_counter() - t0
            per[m][seq] = np.array([prediction_errors(p, w[2:]) for p, (_, _, w) in zip(out, queries)])
    res = {"protocol": {"fps": ETHUCY_FPS, "observed_steps": ETHUCY_OBS,
                        "predicted_steps": ETHUCY_PRED, "windows": counts,
                        "source": "ETH/UCY obsmat.txt (metres), every window of 20 consecutive steps"},
           "ADE_m": {}, "FDE_m": {}, "ratio_to_cv_last": {},
           "seconds_per_query": {m: t / max(n_all, 1) for m, t in timing.items()}}
    print(f"ETH/UCY windows: {counts}")
    print(f"{'method':<18} " + " ".join(f"{s:>13}" for s in [*ETHUCY_STEP, "all"]) + "   (ADE/FDE m)")
    for m in methods:
        ade = {s: float(e.mean()) for s, e in per[m].items()}
        fde = {s: float(e[:, -1].mean()) for s, e in per[m].items()}
        allv = np.concatenate(list(per[m].values()))
        ade["all"], fde["all"] = float(allv.mean()), float(allv[:, -1].mean())
        res["ADE_m"][m], res["FDE_m"][m] = ade, fde
        print(f"{m:<18} " + " ".join(f"{ade[s]:5.3f}/{fde[s]:5.3f}" for s in ade))
    ref = res["ADE_m"]["cv-last"]["all"], res["FDE_m"]["cv-last"]["all"]
    for m in methods:
        res["ratio_to_cv_last"][m] = {"ADE": res["ADE_m"][m]["all"] / ref[0],
                                      "FDE": res["FDE_m"][m]["all"] / ref[1]}
    print("predict time per query: " + ", ".join(
        f"{m} {t * 1e3:.2f} ms" for m, t in res["seconds_per_query"].items()))
    return res


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCALES))
    ap.add_argument("--stride", type=int, default=15, help="frames between queries (15 = 0.5 s)")
    ap.add_argument("--methods", nargs="+", default=list(PREDICTION_METHODS))
    ap.add_argument("--synth", action="store_true", help="generated scenes instead of SDD")
    ap.add_argument("--ethucy", action="store_true",
                    help="ETH/UCY pedestrians (8 observed / 12 predicted steps) instead of SDD")
    ap.add_argument("--synth-scenes", nargs="+", default=SYNTH_SCENES, help="scenario:seed ...")
    ap.add_argument("--synth-frames", type=int, default=900)
    ap.add_argument("--fragment", action="store_true",
                    help="--synth: one id per visible stretch (tracklets), stored as synth_fragmented")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="context.KEY=VALUE (as aerotrack's --set), repeatable")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "prediction.json"))
    args = ap.parse_args(argv)
    config = load_config(None, args.overrides).context if args.overrides else ContextConfig()
    out = Path(args.out)
    old = json.loads(out.read_text()) if out.exists() else {}
    if old and "sdd" not in old and "synth" not in old:
        old = {"sdd": old}
    if args.ethucy:
        if not ETHUCY.is_dir():
            sys.exit(f"prediction.py: {ETHUCY} not found (the shared data sits beside the checkout)")
        old["ethucy"] = ethucy_report(args.methods, config)
        old["ethucy"]["config"] = {k: getattr(config, k) for k in config.__dataclass_fields__}
    elif args.synth:
        methods = list(dict.fromkeys(["kalman", "constant-velocity", *args.methods, ROAD_VARIANT]))
        key = "synth_fragmented" if args.fragment else "synth"
        old[key] = synth_report(args.synth_scenes, args.synth_frames, methods, config, args.fragment)
        old[key]["config"] = {k: getattr(config, k) for k in config.__dataclass_fields__}
    else:
        old["sdd"] = sdd_report(args, config)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(old, indent=2))
    return old


def sdd_report(args, config) -> dict:
    methods = list(dict.fromkeys(["constant-velocity", *args.methods]))
    per, timing, counts = run(args.scenes, args.stride, methods, config)
    nq = sum(c["curved"] + c["straight"] for c in counts.values())
    res = {"protocol": {"fps": FPS, "F": F, "horizon": H, "stride": args.stride,
                        "scenes": args.scenes, "queries": counts},
           "config": {k: getattr(config, k) for k in config.__dataclass_fields__},
           "MPE_m": {}, "ratio_to_cv": {}, "Variance_n_m2": {}, "seconds": timing,
           "seconds_per_query": {m: t / max(nq, 1) for m, t in timing.items()}}
    cv = per["constant-velocity"]
    print(f"queries: {counts}")
    print(f"{'method':<18} {'window':<9} {'n':>4} " + " ".join(f"{k:>13}" for k in NS))
    for m in methods:
        res["MPE_m"][m], res["ratio_to_cv"][m] = {}, {}
        for w in ("curved", "straight"):
            e = np.array(per[m][w]).reshape(-1, H)
            ecv = np.array(cv[w]).reshape(-1, H)
            row, rrow = {}, {}
            for k, n in NS.items():
                mpe = float(e[:, :n].mean()) if len(e) else float("nan")
                ref = float(ecv[:, :n].mean()) if len(ecv) else float("nan")
                row[k], rrow[k] = mpe, mpe / ref if ref else float("nan")
            res["MPE_m"][m][w], res["ratio_to_cv"][m][w] = row, rrow
            sm = summarise(e, list(NS.values()))  # Ali et al. sec. 5: per-query MPE_n, Variance_n
            res["Variance_n_m2"].setdefault(m, {})[w] = {k: sm[n]["Variance"] for k, n in NS.items()}
            print(f"{m:<18} {w:<9} {len(e):>4} " +
                  " ".join(f"{row[k]:6.2f}m {rrow[k]:4.2f}x" for k in NS))
    print("predict time per query: " + ", ".join(
        f"{m} {t * 1e3:.2f} ms" for m, t in res["seconds_per_query"].items()))
    return res


if __name__ == "__main__":
    main()

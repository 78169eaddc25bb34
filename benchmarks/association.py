"""Local association (MCMC tracklets) on UAVDT-derived detections and synthetic scenes, vs peers.

Usage::

    /tmp/venv/bin/python benchmarks/association.py [--seed 0] [--no-peers] [--no-speed]
        [--sizes 20 50 150] [--frames 300] [--cpu-time] [--set association.KEY=VALUE ...]

1. **UAVDT** (issue 5 protocol, ``benchmarks/uavdt_dets.py``): detections synthesised from the
   ground truth of the three sequences (image coordinates, 30 fps, no frames so no appearance);
   aerotrack's ``LocalAssociator`` (observed + bridged rows) beside the Roboflow peers (SORT,
   ByteTrack, OC-SORT, BoT-SORT, default and 2 s buffers) and the oracle, all scored with
   TrackEval over the three sequences combined.
2. **Speed**: frames/s of association alone at 20, 50 and 150 objects per frame
   (``common.synthetic_dets``), beside ByteTrack and OC-SORT in the same run, as ratios;
   ``--cpu-time`` counts CPU seconds of the process instead of wall time (on a loaded machine).
3. ``--seeds-ablation VARIANT ...`` (instead of 1 and 2): each variant (comma-separated
   ``SECTION.KEY=VALUE`` items) against the defaults, mean and sd of HOTA / IDF1 / IDSW over
   MCMC seeds (``--seeds``, default 3), association and linking re-run on one cached detection
   run per source: Santiago end to end (own detector, corrected ground truth, frames 2..98) and
   generated scenes default:0, convoy:2 (600 frames), convoy:1 (900); writes
   ``benchmarks/results/association-seeds.json``. The MCMC varies with the seed by about
   0.005-0.01 HOTA on Santiago: judge a change over seeds, not one run.

Prints tables and writes ``benchmarks/results/association.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import UAVDT_SEQS, WORK, write_results

from aerotrack.association import LocalAssociator
from aerotrack.config import AssociationConfig, load_config
from aerotrack.types import Detections, Track

UAVDT_FPS = 30.0


def rows_to_detections(rows: np.ndarray) -> list[Detections]:
    """MOT rows (N, >=7) -> one Detections per frame from 1 to the last (image coordinates: the
    world point is the box centre, sizes in pixels; no histograms)."""
    rows = np.asarray(rows, float)
    last = int(rows[:, 0].max()) if len(rows) else 0
    order = np.argsort(rows[:, 0], kind="stable")
    rows = rows[order]
    starts = np.searchsorted(rows[:, 0], np.arange(1, last + 2))
    out = []
    for f in range(1, last + 1):
        r = rows[starts[f - 1]:starts[f]]
        if not len(r):
            out.append(Detections.empty(f))
            continue
        boxes = r[:, 2:6].copy()
        out.append(Detections(frame=f, boxes=boxes, conf=r[:, 6].copy(),
                              world=boxes[:, :2] + boxes[:, 2:] / 2,
                              size_world=boxes[:, 2:].copy()))
    return out


def tracks_to_rows(tracks: list[Track]) -> np.ndarray:
    """Tracklets -> MOT rows (observed and bridged points)."""
    rows = [[p.frame, t.id, *p.box, p.conf, -1, -1, -1] for t in tracks for p in t.points
            if p.kind in ("observed", "bridged")]
    if not rows:
        return np.zeros((0, 10))
    rows = np.asarray(rows, float)
    return rows[np.lexsort((rows[:, 1], rows[:, 0]))]


def run_aerotrack(dets: list[Detections], config: AssociationConfig, fps: float, seed: int = 0
                  ) -> tuple[list[Track], float]:
    """Tracklets of a sequence and the seconds spent in ``step``/``flush``."""
    la = LocalAssociator(config, fps, None, seed)
    out: list[Track] = []
    t0 = time.perf_counter()
    for d in dets:
        out.extend(la.step(d))
    out.extend(la.flush())
    return out, time.perf_counter() - t0


def uavdt(config: AssociationConfig, seed: int, peers: bool) -> dict:
    from uavdt_dets import load_uavdt_mot, make_detections

    from aerotrack.evaluation import evaluate_sequences
    from aerotrack.io.mot import read_mot, write_mot

    def runner(seq, dets_file, out_file, fps):
        rows = read_mot(dets_file, strict=False)
        tracks, seconds = run_aerotrack(rows_to_detections(rows), config, fps, seed)
        write_mot(out_file, tracks_to_rows(tracks))
        return {"seconds": seconds, "frames": int(rows[:, 0].max())}

    if peers:
        from peers import uavdt_table
        return uavdt_table(seed, workdir=WORK / "association", extra={"aerotrack": runner})
    table = {}
    gts, orc, pred = {}, {}, {}
    seconds = frames = 0
    for seq in UAVDT_SEQS:
        dets, oracle = make_detections(seq, seed)
        gts[seq], orc[seq] = load_uavdt_mot(seq, "gt"), oracle
        tracks, s = run_aerotrack(rows_to_detections(dets), config, UAVDT_FPS, seed)
        pred[seq] = tracks_to_rows(tracks)
        seconds += s
        frames += int(dets[:, 0].max())
    table["oracle"] = {**evaluate_sequences({s: (gts[s], orc[s]) for s in UAVDT_SEQS}),
                       "fps": None}
    table["aerotrack"] = {**evaluate_sequences({s: (gts[s], pred[s]) for s in UAVDT_SEQS}),
                          "fps": frames / seconds, "seconds": seconds}
    return table


def speed(config: AssociationConfig, sizes, n_frames: int, peers: bool, cpu: bool = False
          ) -> dict:
    from common import synthetic_dets

    def ours(dets, fps):
        run_aerotrack(rows_to_detections(dets), config, fps)

    if cpu:
        return speed_cpu(ours, sizes, n_frames, peers)
    if peers:
        from peers import speed_table
        return speed_table(tuple(sizes), n_frames, extra={"aerotrack": ours})
    out = {}
    for n in sizes:
        rows = synthetic_dets(n, n_frames)
        rows[:, 1] = -1
        dets = rows_to_detections(rows)
        _, s = run_aerotrack(dets, config, 30.0)
        out[str(n)] = {"aerotrack": n_frames / s}
    return out


def speed_cpu(ours, sizes, n_frames: int, peers: bool, repeats: int = 2) -> dict:
    """:func:`speed` in CPU seconds of this process (``time.process_time``) instead of wall time:
    on a shared machine the wall clock also measures the other processes' load, the CPU time of
    a single-threaded tracker much less. Each tracker's call (building its inputs, every frame's
    update, collecting its output) is timed whole, fastest of ``repeats``."""
    from common import synthetic_dets
    from peers import PEER_LABELS, track_rows

    def cpu_fps(fn, *args) -> float:
        best = math.inf
        for _ in range(repeats):
            t0 = time.process_time()
            fn(*args)
            best = min(best, time.process_time() - t0)
        return n_frames / best

    out: dict = {}
    for n in sizes:
        dets = synthetic_dets(n, n_frames)
        dets[:, 1] = -1
        row = {}
        if peers:
            for name in ("bytetrack", "ocsort"):
                row[PEER_LABELS[name]] = cpu_fps(track_rows, name, dets, 30.0)
        row["aerotrack"] = cpu_fps(ours, dets, 30.0)
        out[str(n)] = row
    return out


#: ``--seeds-ablation`` sources: Santiago end to end and generated scenes (scenario, seed, frames).
ABLATION_SCENES = (("default", 0, 600), ("convoy", 2, 600), ("convoy", 1, 900))


def _cached_run(name: str, track_args: list[str]) -> Path:
    """``aerotrack track ARGS --out WORK/association/NAME`` once (registration and detection
    cached in its stages/ for ``--from`` runs)."""
    import subprocess

    out = WORK / "association" / name
    if not (out / "stages").is_dir():
        subprocess.run([sys.executable, "-m", "aerotrack", "track", *track_args, "--out",
                        str(out), "--overwrite"], check=True, capture_output=True)
    return out


def seeds_ablation(variants: list[str], seeds: int) -> dict:
    """HOTA / IDF1 / IDSW (mean and sd over MCMC seeds 0..seeds-1) of each ``--set`` variant
    against the defaults, association and linking re-run (``track --from``) on one detection run
    per source: Santiago (own detector, corrected ground truth, frames 2..98) and the generated
    scenes of :data:`ABLATION_SCENES`."""
    import json

    from common import SANTIAGO_DIR

    from aerotrack.evaluation.mot import evaluate, fix_ground_truth
    from aerotrack.evaluation.santiago import SANTIAGO_FRAMES, load_santiago
    from aerotrack.io.mot import read_mot
    from aerotrack.outputs import track_rows
    from aerotrack.pipeline import run_cached

    sources = {}
    gt, _ = load_santiago(SANTIAGO_DIR)
    sources["santiago"] = (_cached_run("santiago", [
        str(SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4")]), fix_ground_truth(gt)[0],
        SANTIAGO_FRAMES)
    for scen, sd, n in ABLATION_SCENES:
        scene = WORK / "association" / f"scene-{scen}{sd}-{n}"
        if not (scene / "gt.txt").exists():
            import subprocess
            subprocess.run([sys.executable, "-m", "aerotrack", "synth", "--out", str(scene),
                            "--seed", str(sd), "--frames", str(n), "--scenario", scen,
                            "--overwrite"], check=True, capture_output=True)
        run = _cached_run(f"run-{scen}{sd}-{n}", [str(scene / "frames"), "--map",
                                                  str(scene / "map.tif"), "--map-init",
                                                  str(scene / "map_init.txt")])
        sources[f"{scen}:{sd}"] = (run, read_mot(scene / "gt.txt"), None)
    out: dict = {}
    for src, (run, gt, frames) in sources.items():
        summ = json.loads((run / "summary.json").read_text())
        geomap = None
        if summ.get("map"):
            from aerotrack.geo import GeoMap
            geomap = GeoMap(summ["map"])
        mpu = None if geomap else summ.get("metres_per_unit")
        out[src] = {}
        for v in ["defaults", *variants]:
            config = load_config(None, [] if v == "defaults" else v.split(","))
            scores = []
            for seed in range(seeds):
                res = run_cached(run / "stages", config=config, fps=summ["fps"], seed=seed,
                                 geomap=geomap, frame_size=tuple(summ["frame_size"]),
                                 metres_per_unit=mpu)
                scores.append(evaluate(gt, track_rows(res, geomap)[0], frames=frames))
            m = {k: (float(np.mean([x[k] for x in scores])), float(np.std([x[k] for x in scores])))
                 for k in ("HOTA", "IDF1", "IDSW")}
            out[src][v] = m
            print(f"{src:10s} {v:45s} " + "  ".join(f"{k} {a:.3f}±{b:.3f}" for k, (a, b)
                                                      in m.items()), flush=True)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-peers", action="store_true", help="aerotrack and the oracle only")
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--no-uavdt", action="store_true")
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 50, 150])
    ap.add_argument("--frames", type=int, default=300, help="frames per speed measurement")
    ap.add_argument("--cpu-time", action="store_true",
                    help="speed in CPU seconds of this process, not wall time (shared machine)")
    ap.add_argument("--set", action="append", default=[], metavar="association.KEY=VALUE")
    ap.add_argument("--seeds-ablation", nargs="*", default=None, metavar="SECTION.KEY=VALUE,...",
                    help="instead: each variant (comma-separated --set items) against the "
                         "defaults over MCMC seeds on Santiago and generated scenes; writes "
                         "results/association-seeds.json")
    ap.add_argument("--seeds", type=int, default=3, help="seeds of --seeds-ablation")
    args = ap.parse_args(argv)
    if args.seeds_ablation is not None:
        res = seeds_ablation(args.seeds_ablation, args.seeds)
        path = write_results("association-seeds", {"seeds": args.seeds, "results": res})
        print(f"\nwrote {path}")
        return
    config = load_config(None, args.set).association
    result: dict = {"config": config.__dict__}
    if not args.no_uavdt:
        table = uavdt(config, args.seed, not args.no_peers)
        from peers import format_table
        print("UAVDT association (M0101, M0206, M1005 combined)")
        print(format_table(table, baseline="ByteTrack" if not args.no_peers else "aerotrack"))
        result["uavdt"] = {k: {"combined": v["combined"], "fps": v.get("fps"),
                               "sequences": v.get("sequences")} for k, v in table.items()}
    if not args.no_speed:
        sp = speed(config, args.sizes, args.frames, not args.no_peers, args.cpu_time)
        print("\nSpeed, frames/s" + (" of CPU time" if args.cpu_time else "")
              + " (synthetic, objects per frame)")
        for n, row in sp.items():
            base = row.get("ByteTrack")
            cells = "  ".join(f"{k} {v:8.1f}" + (f" ({v / base:.2f}x BT)" if base else "")
                              for k, v in row.items())
            print(f"{n:>5}: {cells}")
        result["speed"] = sp
        result["speed_clock"] = "cpu" if args.cpu_time else "wall"
    path = write_results("association", result)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()

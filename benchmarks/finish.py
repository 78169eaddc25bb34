"""What ``tracks.csv`` reports for each final track: ablation of :mod:`aerotrack.association.finish`.

Each source is tracked once with the finishing step off (``finish.enabled=false``: the tracks as
global linking makes them, detection boxes); the same final tracks are then finished with each
variant below and scored (HOTA, IDF1, MOTA, IDSW, LocA):

* ``santiago``: the real nadir clip end to end with aerotrack's own detector, against the corrected
  ground truth, frames 2..98 (``aerotrack track VIDEO`` once, cached in WORK/finish/santiago);
* ``uavdt``: association on the three UAVDT sequences' synthetic detections
  (``benchmarks/uavdt_dets.py``, seed 0), combined;
* ``synth-gt`` / ``synth-full``: generated scenes (``benchmarks/identity.py``'s scenes and cached
  tracklets, 900 frames, in WORK/finish/identity) with noisy ground-truth detections and with
  aerotrack's detector; mean over scenes.

Variants (``VARIANTS``): ``off`` (linking's boxes), ``smooth`` (RTS-smoothed ground points, each
detection's own box size), ``size`` (robust per-track size, no smoothing), ``smooth+size``,
``+static`` (static-track rejection), ``default`` (the configured defaults) and a few settings.

Run: /tmp/venv/bin/python benchmarks/finish.py [--sources santiago uavdt synth-gt synth-full]
     [--scenes default:0 ...] [--set finish.KEY=VALUE ...]
Writes benchmarks/results/finish.json.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from common import (
    SANTIAGO_DIR,
    UAVDT_DIR,
    UAVDT_SEQS,
    WORK,
    require_data,
    write_results,
)

from aerotrack.association.finish import finish_tracks
from aerotrack.config import Config, load_config
from aerotrack.evaluation.mot import evaluate, evaluate_sequences, fix_ground_truth
from aerotrack.evaluation.santiago import SANTIAGO_FRAMES, load_santiago
from aerotrack.io.mot import read_mot
from aerotrack.outputs import track_rows
from aerotrack.pipeline import Result, link, run, run_cached

BENCH = WORK / "finish"
SANTIAGO_VIDEO = SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4"
DEFAULT_SCENES = ["default:0", "default:2", "occlusion:1", "exits:1", "exits:2"]

#: Ablation: finish-section overrides on top of the configured defaults.
VARIANTS: dict[str, dict | None] = {
    "off": None,
    "smooth": {"size_mode": "detection", "static_extent_m": 0.0},
    "size": {"smooth": False, "static_extent_m": 0.0},
    "smooth+size": {"static_extent_m": 0.0},
    "smooth+size oriented": {"size_mode": "oriented", "static_extent_m": 0.0},
    "static only": {"smooth": False, "size_mode": "detection"},
    "default": {},
    "default oriented": {"size_mode": "oriented"},
    "default clip": {"clip_to_frame": True},
    "static 2.5 m": {"static_extent_m": 2.5},
    "static 6 m": {"static_extent_m": 6.0},
    "window 2 s": {"size_window_s": 2.0},
    "quantile 0.6": {"size_quantile": 0.6},
    "accel 1": {"accel_std_mps2": 1.0},
    "accel 4": {"accel_std_mps2": 4.0},
    "no robust": {"robust_iters": 0},
    "fill gaps 0.5 s": {"fill_gaps_s": 0.5},
    "fill gaps 1.2 s": {"fill_gaps_s": 1.2},
}
KEYS = ("HOTA", "IDF1", "MOTA", "IDSW", "LocA", "DetA", "AssA")


def _score(d: dict) -> dict:
    return {k: float(d[k]) for k in KEYS if k in d}


def finished(res: Result, fin) -> Result:
    """``res`` with its tracks finished by the FinishConfig ``fin`` (None: unchanged)."""
    tracks = copy.deepcopy(res.tracks)
    if fin is not None:
        tracks = finish_tracks(tracks, fin, res.fps, metres_per_unit=res.metres_per_unit,
                               registrations=res.registrations or None, frame_size=res.frame_size)
    return dataclasses.replace(res, tracks=tracks)


# -- sources: each returns (list of Results tracked with finishing off, scorer) ------------------

def santiago(config: Config):
    require_data(SANTIAGO_VIDEO)
    run_dir = BENCH / "santiago"
    if not (run_dir / "stages").is_dir():
        subprocess.run([sys.executable, "-m", "aerotrack", "track", str(SANTIAGO_VIDEO), "--out",
                        str(run_dir), "--overwrite"], check=True, capture_output=True)
    prev = json.loads((run_dir / "summary.json").read_text())
    res = run_cached(run_dir / "stages", config=config, fps=prev["fps"],
                     frame_size=tuple(prev["frame_size"]))
    gt, _ = load_santiago(SANTIAGO_DIR)
    gt, _ = fix_ground_truth(gt)

    def score(results):
        rows, _ = track_rows(results[0], None)
        return _score(evaluate(gt, rows, frames=SANTIAGO_FRAMES))

    return [res], score


def uavdt(config: Config):
    dets_dir = WORK / "uavdt_dets"
    if not all((dets_dir / f"{s}_dets.txt").exists() for s in UAVDT_SEQS):
        subprocess.run([sys.executable, str(Path(__file__).parent / "uavdt_dets.py"), "--out",
                        str(dets_dir)], check=True, capture_output=True)
    results = [run(None, config=config, fps=30.0, detections=read_mot(dets_dir / f"{s}_dets.txt"))
               for s in UAVDT_SEQS]
    gts = [read_mot(require_data(UAVDT_DIR / f"{s}_gt.txt")) for s in UAVDT_SEQS]

    def score(rs):
        seqs = {s: (g, track_rows(r, None)[0]) for s, g, r in zip(UAVDT_SEQS, gts, rs)}
        return _score(evaluate_sequences(seqs)["combined"])

    return results, score


def synth(config: Config, mode: str, scenes: list[str]):
    import identity

    identity.CACHE = BENCH / "identity"
    identity.CACHE.mkdir(parents=True, exist_ok=True)
    results, gts = [], []
    for spec in scenes:
        scen, seed = spec.split(":")
        scene = identity.make_scene(scen, int(seed), 900, False)
        # finishing works after linking: any cached tracklets of the scene will do (others'
        # association changes alter the cache key without changing what is measured here)
        cached = sorted(identity.CACHE.glob(f"{scene.name}_{mode}_*.pkl"),
                        key=lambda q: q.stat().st_mtime)
        r = pickle.loads(cached[-1].read_bytes()) if cached else \
            identity.local_tracklets(scene, mode, config, False)
        tracks = link(copy.deepcopy(r["tracklets"]), config, r["fps"], metres_per_unit=r["mpu"],
                      frame_size=r["frame_size"], registrations=r["registrations"])
        results.append(Result(tracks=tracks, registrations=r["registrations"],
                              detections=r["detections"], fps=r["fps"],
                              frame_size=r["frame_size"], metres_per_unit=r["mpu"],
                              frames=r["frames"]))
        gts.append(read_mot(scene / "gt.txt"))

    def score(rs):
        s = [_score(evaluate(g, track_rows(r, None)[0])) for g, r in zip(gts, rs)]
        return {k: float(np.mean([x[k] for x in s])) for k in s[0]}

    return results, score


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sources", nargs="+", default=["santiago", "uavdt", "synth-gt", "synth-full"])
    ap.add_argument("--scenes", nargs="+", default=DEFAULT_SCENES)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS))
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="SECTION.KEY=VALUE override of the defaults every variant starts from")
    args = ap.parse_args(argv)
    BENCH.mkdir(parents=True, exist_ok=True)
    base = load_config(None, args.overrides)
    off = dataclasses.replace(base, finish=dataclasses.replace(base.finish, enabled=False))
    table: dict[str, dict[str, dict]] = {}
    for src in args.sources:
        t0 = time.perf_counter()
        if src == "santiago":
            results, score = santiago(off)
        elif src == "uavdt":
            results, score = uavdt(off)
        elif src in ("synth-gt", "synth-full"):
            results, score = synth(off, "gt-dets" if src == "synth-gt" else "full", args.scenes)
        else:
            sys.exit(f"benchmark: unknown source {src!r}")
        table[src] = {}
        for name in args.variants:
            fields = VARIANTS[name]
            fin = None if fields is None else dataclasses.replace(base.finish, **fields)
            t1 = time.perf_counter()
            rs = [finished(r, fin) for r in results]
            secs = time.perf_counter() - t1
            table[src][name] = {**score(rs), "finish_s": round(secs, 3),
                                "tracks": int(sum(len(r.tracks) for r in rs))}
            m = table[src][name]
            print(f"{src:11s} {name:22s} HOTA {m['HOTA']:.3f} IDF1 {m['IDF1']:.3f} "
                  f"MOTA {m['MOTA']:.3f} IDSW {m['IDSW']:5.0f} LocA {m['LocA']:.3f} "
                  f"tracks {m['tracks']:4d} ({secs:.1f} s)", flush=True)
        print(f"  {src}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(f"\n{'variant':22s}" + "".join(f"{s:>24s}" for s in table))
    print(f"{'':22s}" + "".join(f"{'HOTA  IDF1  MOTA':>24s}" for _ in table))
    for name in args.variants:
        print(f"{name:22s}" + "".join(
            f"{t[name]['HOTA']:>10.3f}{t[name]['IDF1']:6.3f}{t[name]['MOTA']:8.3f}"
            for t in table.values()))
    write_results("finish", {"protocol": {"sources": args.sources, "scenes": args.scenes,
                                          "overrides": args.overrides,
                                          "variants": {k: v for k, v in VARIANTS.items()
                                                       if k in args.variants}},
                             "results": table})


if __name__ == "__main__":
    main()

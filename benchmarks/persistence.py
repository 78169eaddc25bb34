"""Benchmark of multi-frame persistence (``detection.persist``, issues 4.3 and 6): on against off.

The checks that decide whether persistence can be on by default, each with both settings in
one run (``--set`` overrides apply to both):

* Santiago (identity registrations, as ``benchmarks/detection.py``): per-frame precision and
  recall at IoU 0.5; what the persistence detections are (matched, or the cause of the false
  ones as in ``detection.santiago_breakdown``); the frames in which ground-truth vehicles 10
  (standing in frames 1-23) and 24 (standing at the light from frame ~64) are missed at IoU 0.3
  and those in which a persistence box finds them.
* Santiago end to end (``aerotrack track`` on the video, association and linking re-run for MCMC
  seeds 0-2 on the cached detections): HOTA, IDF1 and the frames of vehicles 10 and 24 covered
  by a track at IoU 0.5.
* UAV123 truck4 (moving camera, 10 fps, no map, no initial box) end to end: the best single
  track ID's share of the 421 frames at IoU 0.3 (``identity.truck4_coverage``; issue 6 goal
  0.80), seeds 0-2.
* Generated scenes (``detection.synth`` protocol, seeds 0-2, 150 frames each): precision and
  recall at IoU 0.5.
* Detection CPU time per frame at 1280x720 and 1920x1080 (truck4 frames, registered), on/off
  ratio, two repetitions interleaved.

Usage: ``/tmp/venv/bin/python benchmarks/persistence.py [--set SECTION.KEY=VALUE ...]``; prints a
table and writes ``benchmarks/results/persistence.json``. About 15 CPU-minutes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import detection as D
from common import SANTIAGO_DIR, WORK, write_results
from identity import TRUCK4, truck4_coverage, truck4_gt

from aerotrack.config import load_config
from aerotrack.evaluation.mot import evaluate, fix_ground_truth
from aerotrack.evaluation.santiago import SANTIAGO_FRAMES, load_santiago
from aerotrack.outputs import track_rows
from aerotrack.pipeline import run_cached

SEEDS = (0, 1, 2)
#: Santiago ground-truth vehicles that stand still for a while (issue 4.3).
STANDING = (10, 24)


def _santiago_ids() -> np.ndarray:
    """Ground-truth rows (1-based frames, positive sizes) with their ids."""
    rows = np.loadtxt(D.SANTIAGO / "dfs_ground_truth.csv", delimiter=",")
    rows[:, 0] += 1
    for j in (4, 5):
        neg = rows[:, j] < 0
        rows[neg, j - 2] += rows[neg, j]
        rows[neg, j] *= -1
    return rows


def santiago_detection(config) -> dict:
    frames, fps = D.load_frames(D.SANTIAGO / "video_sift_estabilizado_filtrado.mp4")
    gts = D.santiago_gt()
    dets, out, _ = D.run_detector(frames, fps, config)
    res = D.score(dets, gts, sorted(gts))
    labels = D.santiago_labels()
    kinds: dict[str, int] = {}
    by_frame = {d.frame: d for d in out}
    for f in sorted(gts):
        d = by_frame.get(f)
        if d is None or not d.extra["persistent"].any():
            continue
        boxes, g = d.boxes, gts[f]
        used = np.zeros(len(boxes), bool)
        if len(g):
            io = D.iou_matrix(boxes, g)
            r, c = D.linear_sum_assignment(-io)
            used[r[io[r, c] >= 0.5]] = True
        seen = [{"id": i, "box": b} for i, b in enumerate(g)]
        for k in np.flatnonzero(d.extra["persistent"]):
            kind = "matched" if used[k] else D.classify_false(boxes[k], seen)
            lab = labels.get(f, np.zeros((0, 4)))
            if kind.startswith("no vehicle") and len(lab):
                il = D.iou_matrix(boxes[k][None], lab)[0] + D.centre_in_box(boxes[k][None], lab)[0]
                if il.max() >= 0.3:
                    kind = ("moving vehicle absent from the ground truth"
                            if D.label_moves(labels, f, lab[int(np.argmax(il))]) else "parked vehicle")
            kinds[kind] = kinds.get(kind, 0) + 1
    res["persistent_detections"] = kinds
    rows = _santiago_ids()
    for gid in STANDING:
        missed, found = [], []
        for f, _, x, y, w, h, *_ in rows[rows[:, 1] == gid]:
            d = by_frame.get(int(f))
            if d is None or not len(d.boxes):
                missed.append(int(f))
                continue
            io = D.iou_matrix(d.boxes, np.array([[x, y, w, h]]))[:, 0]
            if io.max() < 0.3:
                missed.append(int(f))
            elif (io[d.extra["persistent"]] >= 0.3).any():
                found.append(int(f))
        res[f"gt{gid}"] = {"missed_iou0.3": missed, "found_by_persistence": found}
    return res


def _track(name: str, args: list[str], overrides: list[str]) -> Path:
    out = WORK / "persistence" / name
    cmd = [sys.executable, "-m", "aerotrack", "track", *args, "--out", str(out), "--overwrite"]
    for o in overrides:
        cmd += ["--set", o]
    subprocess.run(cmd, check=True, capture_output=True)
    return out


def _seeds(run: Path, overrides: list[str], score) -> list:
    summ = json.loads((run / "summary.json").read_text())
    config = load_config(None, overrides)
    out = []
    for seed in SEEDS:
        r = run_cached(run / "stages", config=config, fps=summ["fps"], seed=seed,
                       frame_size=tuple(summ["frame_size"]),
                       metres_per_unit=summ.get("metres_per_unit"))
        out.append(score(track_rows(r, None)[0]))
    return out


def santiago_tracking(name: str, overrides: list[str]) -> dict:
    run = _track(f"santiago-{name}", [str(SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4")],
                 overrides)
    gt = fix_ground_truth(load_santiago(SANTIAGO_DIR)[0])[0]

    def score(rows):
        e = evaluate(gt, rows, frames=SANTIAGO_FRAMES)
        out = {k: float(e[k]) for k in ("HOTA", "IDF1", "IDSW")}
        for gid in STANDING:
            g = gt[gt[:, 1] == gid]
            covered, ids = 0, set()
            for f, _, x, y, w, h, *_ in g:
                p = rows[rows[:, 0] == f]
                if len(p):
                    io = D.iou_matrix(p[:, 2:6], np.array([[x, y, w, h]]))[:, 0]
                    if io.max() >= 0.5:
                        covered += 1
                        ids.add(int(p[int(np.argmax(io)), 1]))
            out[f"gt{gid}_frames_covered"] = covered
            out[f"gt{gid}_ids"] = len(ids)
        return out

    per_seed = _seeds(run, overrides, score)
    return {"per_seed": per_seed,
            "mean": {k: float(np.mean([s[k] for s in per_seed])) for k in per_seed[0]}}


def truck4_tracking(name: str, overrides: list[str]) -> dict:
    run = _track(f"truck4-{name}", [str(TRUCK4 / "frames"), "--fps", "10"], overrides)
    gt = truck4_gt()
    per_seed = _seeds(run, overrides, lambda rows: truck4_coverage(rows, gt))
    return {"best_fraction": [s["best_fraction"] for s in per_seed],
            "any_fraction": [s["any_fraction"] for s in per_seed]}


def synth(config) -> dict:
    """Generated scenes as in ``detection.synth --quick`` with ``config`` instead of the
    defaults."""
    from aerotrack.synth import Scenario

    orig = D.MovingObjectDetector
    D.MovingObjectDetector = lambda _config, fps, **kw: orig(config, fps, **kw)
    try:
        tp = n_target = n_det = 0
        for seed in D.SYNTH_SEEDS:
            r = D._synth_one(Scenario(seed=seed, frames=150, size=(640, 480), fps=30.0,
                                      name="default"), 150)
            tp, n_target, n_det = tp + r["tp"], n_target + r["targets"], n_det + r["detections"]
    finally:
        D.MovingObjectDetector = orig
    return {"precision_iou0.5": tp / max(n_det, 1), "recall_iou0.5": tp / max(n_target, 1)}


def speed(base) -> dict:
    from aerotrack.config import RegistrationConfig
    from aerotrack.registration import FrameRegistrar

    frames, _ = D.load_frames(D.TRUCK / "frames", stop=90)
    cases = {"1280x720": frames,
             "1920x1080": [D.Frame(f.index, D.cv2.resize(f.image, (1920, 1080)), f.time)
                           for f in frames]}
    out = {}
    for name, fr in cases.items():
        registrar = FrameRegistrar(RegistrationConfig(), 30.0)
        regs = [registrar.step(f) for f in fr]
        rates: dict[str, list[float]] = {"off": [], "on": []}
        for _ in range(2):
            for key, on in (("off", False), ("on", True)):
                rates[key].append(D.run_detector(fr, 30.0, dataclasses.replace(base, persist=on),
                                                 regs)[2])
        out[name] = {"fps_off": rates["off"], "fps_on": rates["on"],
                     "cpu_ratio_on_off": float(np.mean(rates["off"]) / np.mean(rates["on"]))}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="SECTION.KEY=VALUE applied to both settings (repeatable)")
    args = ap.parse_args(argv)
    results: dict = {"overrides": args.overrides, "seeds": list(SEEDS)}
    base = load_config(None, args.overrides).detection
    for key, on in (("off", False), ("on", True)):
        sets = [*args.overrides, f"detection.persist={str(on).lower()}"]
        r = {"santiago_detection": santiago_detection(dataclasses.replace(base, persist=on)),
             "santiago_tracking": santiago_tracking(key, sets),
             "truck4": truck4_tracking(key, sets),
             "synth": synth(dataclasses.replace(base, persist=on))}
        results[key] = r
        sd, st, t4 = r["santiago_detection"], r["santiago_tracking"]["mean"], r["truck4"]
        print(f"persist {key}: Santiago P/R@IoU0.5 {sd['iou']['precision']:.3f}/"
              f"{sd['iou']['recall']:.3f}; HOTA {st['HOTA']:.4f} IDF1 {st['IDF1']:.4f} "
              f"(mean of seeds {list(SEEDS)}); GT 24 covered {st['gt24_frames_covered']:.1f} "
              f"frames, GT 10 {st['gt10_frames_covered']:.1f}; truck4 best ID "
              + "/".join(f"{v:.3f}" for v in t4["best_fraction"])
              + f"; generated scenes P/R {r['synth']['precision_iou0.5']:.3f}/"
              f"{r['synth']['recall_iou0.5']:.3f}", flush=True)
        if on:
            print(f"  persistence detections on Santiago: {sd['persistent_detections']}")
            for gid in STANDING:
                g = sd[f"gt{gid}"]
                print(f"  GT {gid}: missed at IoU 0.3 in {len(g['missed_iou0.3'])} frames; found by "
                      f"persistence in {g['found_by_persistence']}")
    results["speed"] = speed(base)
    for name, s in results["speed"].items():
        print(f"detection CPU time {name}: on/off {s['cpu_ratio_on_off']:.2f} "
              f"(frames per CPU-second off {np.mean(s['fps_off']):.1f}, on {np.mean(s['fps_on']):.1f})")
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"wrote {write_results('persistence', results)}")


if __name__ == "__main__":
    main()

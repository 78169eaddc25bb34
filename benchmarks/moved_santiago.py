"""Santiago's real frames under camera motion and at other resolutions: what the pipeline keeps of
its score when the same traffic is filmed by a moving camera or at lower resolution.

The clip (``../shared/data/santiago_intersection_dfs``, 1920x1080, 30 frames/s, stabilised) has
multi-vehicle ground truth but a still camera. Each variant re-renders its 100 frames (PNG, no
second compression) and maps the ground truth through the same transform:

* ``moved``: a 1600x900 window that pans (up to 120 px sideways, 60 px down), rotates (0 -> 4
  degrees) and zooms in (1 -> 1.12) over the clip; every pixel is real imagery. The transform is
  known, so the registration's error is measured too (median / max over a grid, in pixels).
* ``still``: the same 1600x900 window held at its first position (the moved variant's baseline:
  the same crop size cuts the same kind of vehicles at its edges).
* ``720p`` and ``540p``: the whole frame downscaled (INTER_AREA) to 1280x720 and 960x540.
* ``original``: the clip itself (its MP4 and ground truth, nothing re-rendered): the README's
  Santiago figures.

Ground-truth boxes are the axis-aligned boxes of the transformed corners (negative sizes
reflected first, as ``aerotrack eval --fix-gt`` does); boxes wholly outside a frame are left out.
Each variant is tracked with ``aerotrack track FRAMES --fps 30 --seed S`` (no map) and scored with
``aerotrack eval --gt-zero-based --frames 2:98 --fix-gt`` (the clip's published protocol).
As a diagnosis, each run is scored again without the tracks that never overlap an annotated
vehicle at IoU 0.5 (:func:`unannotated_tracks`; the ground truth leaves some movers out).

    python benchmarks/moved_santiago.py [--variants original moved still 720p 540p] [--seeds 0] [--set K=V]

Frames are cached under ``$AEROTRACK_BENCH_WORK/moved_santiago``; results go to
``benchmarks/results/moved_santiago.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from common import SANTIAGO_DIR, WORK, aerotrack, require_data, write_results

VARIANTS = ("original", "moved", "still", "720p", "540p")
KEYS = ("HOTA", "IDF1", "MOTA", "DetA", "AssA", "LocA", "IDSW", "GT_IDs", "Pred_IDs")
CROP = (1600, 900)


def window(k: int, n: int, moving: bool) -> np.ndarray:
    """3x3 map from crop pixels to source pixels for frame index ``k`` (0-based) of ``n``."""
    W, H = CROP
    t = k / max(n - 1, 1) if moving else 0.0
    ang, s = np.deg2rad(4.0 * t), 1.0 + 0.12 * t
    cx = 960 + 120 * np.sin(2 * np.pi * 0.7 * t) - 60
    cy = 540 + 60 * t - 30
    c, sn = np.cos(ang) / s, np.sin(ang) / s
    rot = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    to_centre = np.array([[1.0, 0.0, -W / 2], [0.0, 1.0, -H / 2], [0.0, 0.0, 1.0]])
    to_src = np.array([[1.0, 0.0, cx], [0.0, 1.0, cy], [0.0, 0.0, 1.0]])
    return to_src @ rot @ to_centre


def transforms(variant: str, n: int) -> tuple[list[np.ndarray], tuple[int, int]]:
    """Per frame the 3x3 map source -> variant pixels, and the variant's (W, H)."""
    if variant in ("moved", "still"):
        return [np.linalg.inv(window(k, n, variant == "moved")) for k in range(n)], CROP
    W, H = {"720p": (1280, 720), "540p": (960, 540)}[variant]
    S = np.diag([W / 1920.0, H / 1080.0, 1.0])
    return [S] * n, (W, H)


def render(variant: str, out: Path) -> list[np.ndarray]:
    """Write the variant's frames and gt.csv under ``out`` (once); return the transforms."""
    cap = cv2.VideoCapture(str(SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4"))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    Ts, (W, H) = transforms(variant, len(frames))
    done = out / "gt.csv"
    if not done.exists():
        (out / "frames").mkdir(parents=True, exist_ok=True)
        for k, (f, T) in enumerate(zip(frames, Ts), start=1):
            if variant in ("720p", "540p"):
                img = cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA)
            else:
                img = cv2.warpPerspective(f, np.linalg.inv(T), (W, H),
                                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
            cv2.imwrite(str(out / "frames" / f"{k:06d}.png"), img)
        gt = np.loadtxt(SANTIAGO_DIR / "dfs_ground_truth.csv", delimiter=",")
        for a, b in ((2, 4), (3, 5)):
            neg = gt[:, b] < 0
            gt[neg, a] += gt[neg, b]
            gt[neg, b] *= -1
        rows = []
        for r in gt:
            x, y, w, h = r[2:6]
            P = np.array([[x, y, 1], [x + w, y, 1], [x, y + h, 1], [x + w, y + h, 1.0]]) @ Ts[int(r[0])].T
            P = P[:, :2] / P[:, 2:]
            (x0, y0), (x1, y1) = P.min(0), P.max(0)
            if x1 <= 0 or y1 <= 0 or x0 >= W or y0 >= H:
                continue
            rows.append([r[0], r[1], x0, y0, x1 - x0, y1 - y0, r[6], -1, -1, -1])
        tmp = out / "gt.csv.tmp"
        np.savetxt(tmp, np.array(rows), delimiter=",", fmt="%.3f")
        tmp.replace(done)
    return Ts


def registration_error(run: Path, Ts: list[np.ndarray], size: tuple[int, int]) -> dict:
    """Median and max distance (variant pixels) between the registration's frame -> frame-1 map
    and the true one, over a 9x5 grid of every frame."""
    W, H = size
    R = np.genfromtxt(run / "registration.csv", delimiter=",", skip_header=1, usecols=range(10))
    g = np.stack(np.meshgrid(np.linspace(0, W, 9), np.linspace(0, H, 5)), -1).reshape(-1, 2)
    G = np.c_[g, np.ones(len(g))]
    errs = []
    for row in R:
        k = int(row[0]) - 1
        true = Ts[0] @ np.linalg.inv(Ts[k])
        est = row[1:10].reshape(3, 3)
        pt, pe = G @ true.T, G @ est.T
        errs.append(np.hypot(*(pt[:, :2] / pt[:, 2:] - pe[:, :2] / pe[:, 2:]).T))
    e = np.concatenate(errs)
    return {"median_px": float(np.median(e)), "max_px": float(e.max())}


def unannotated_tracks(tracks: np.ndarray, gt_path: Path, frames: tuple[int, int]) -> list[int]:
    """Ids of the tracks none of whose rows in ``frames`` (1-based, inclusive) overlaps a
    ground-truth box of its frame at IoU >= 0.5 (the ground truth 0-based, negative sizes
    reflected): :func:`aerotrack.evaluation.santiago.unannotated_movers` without its motion test.
    On Santiago these are movers its ground truth leaves out (cars creeping in the queues, a car
    leaving a car park, a vehicle leaving the view; ``benchmarks/santiago_gt.py``): removing them
    shows what the score is on the annotated vehicles alone, as a diagnosis, not as a score."""
    from aerotrack.evaluation.santiago import unannotated_movers

    gt = np.loadtxt(gt_path, delimiter=",", ndmin=2)
    for a, b in ((2, 4), (3, 5)):
        neg = gt[:, b] < 0
        gt[neg, a] += gt[neg, b]
        gt[neg, b] *= -1
    gt[:, 0] += 1
    return unannotated_movers(gt, tracks, frames=frames, min_iou=0.5, min_move_lengths=0.0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="SECTION.KEY=VALUE for every run (as aerotrack's --set), repeatable")
    ap.add_argument("--out", default="moved_santiago", help="results name (benchmarks/results/NAME.json)")
    args = ap.parse_args(argv)
    require_data(SANTIAGO_DIR)
    sets = [a for kv in args.overrides for a in ("--set", kv)]
    results: dict = {"overrides": args.overrides, "variants": {}}
    for v in args.variants:
        folder = WORK / "moved_santiago" / v
        if v == "original":
            Ts, size = None, (1920, 1080)
            frames, gt = SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4", \
                SANTIAGO_DIR / "dfs_ground_truth.csv"
        else:
            Ts = render(v, folder)
            size = CROP if v in ("moved", "still") else {"720p": (1280, 720), "540p": (960, 540)}[v]
            frames, gt = folder / "frames", folder / "gt.csv"
        per_seed = {}
        for seed in args.seeds:
            run = folder / f"run_{seed}"
            aerotrack("-q", "track", str(frames), "--fps", "30", "--out", str(run),
                      "--seed", str(seed), "--overwrite", *sets)
            e = json.loads(aerotrack("eval", "--gt", str(gt), "--pred",
                                     str(run / "tracks.csv"), "--gt-zero-based", "--frames", "2:98",
                                     "--fix-gt", "--json"))
            e = e.get("combined", e)
            per_seed[str(seed)] = {k: e[k] for k in KEYS}
            tracks = np.loadtxt(run / "tracks.csv", delimiter=",", ndmin=2)
            drop = unannotated_tracks(tracks, gt, (2, 98))
            kept = folder / f"tracks_annotated_only_{seed}.csv"
            np.savetxt(kept, tracks[~np.isin(tracks[:, 1], drop)], delimiter=",", fmt="%.3f")
            a = json.loads(aerotrack("eval", "--gt", str(gt), "--pred", str(kept), "--gt-zero-based",
                                     "--frames", "2:98", "--fix-gt", "--json"))
            a = a.get("combined", a)
            per_seed[str(seed)]["unannotated_tracks"] = len(drop)
            per_seed[str(seed)]["without_unannotated"] = {k: a[k] for k in ("HOTA", "IDF1", "MOTA",
                                                                             "LocA")}
            if v == "moved":
                per_seed[str(seed)]["registration_error"] = registration_error(run, Ts, size)
            r = per_seed[str(seed)]
            w = r["without_unannotated"]
            reg = r.get("registration_error")
            print(f"{v:6s} seed {seed}: HOTA {r['HOTA']:.3f} IDF1 {r['IDF1']:.3f} MOTA {r['MOTA']:.3f} "
                  f"IDSW {r['IDSW']}; {r['unannotated_tracks']} tracks on no annotated vehicle, "
                  f"without them HOTA {w['HOTA']:.3f} IDF1 {w['IDF1']:.3f}"
                  + (f"  registration error median {reg['median_px']:.2f} px, max {reg['max_px']:.2f} px"
                     if reg else ""), flush=True)
        results["variants"][v] = {"size": list(size), "per_seed": per_seed,
                                  "mean": {k: float(np.mean([s[k] for s in per_seed.values()]))
                                           for k in ("HOTA", "IDF1", "MOTA")}}
    path = write_results(args.out, results)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

"""What Santiago's ground truth leaves out: the score with and without tracks of vehicles it does
not annotate.

Santiago's ground truth (``dfs_ground_truth.csv``) is said to hold "the moving vehicles", but
some vehicles that visibly drive through the clip have no box in it; a tracker that follows them
is charged a false positive for every frame. This benchmark tracks the clip as a user would
(``aerotrack track VIDEO --seed S`` for MCMC seeds 0-2), scores ``tracks.csv`` under the
published protocol (corrected ground truth, frames 2..98), then again without the tracks
:func:`aerotrack.evaluation.santiago.unannotated_movers` lists (no box overlapping a ground-truth
box at IoU 0.3 in any scored frame, and a centre that moves at least one box length). The
published YOLOv8 + SORT / ByteTrack tracks are scored the same way. It also draws each listed
track of seed 0 at its first, middle and last box (``docs/images/santiago_unannotated.png``) so
that anyone can check they are vehicles.

The second score is a diagnostic, not a result: it says how much of the distance to a goal is
the ground truth's and how much the tracker's.

    python benchmarks/santiago_gt.py [--seeds 0 1 2] [--no-picture]

Writes ``benchmarks/results/santiago_gt.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from common import SANTIAGO_DIR, WORK, aerotrack, require_data, write_results

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("HOTA", "DetA", "AssA", "LocA", "IDF1", "MOTA", "Pred_IDs")
PICTURE = ROOT / "docs" / "images" / "santiago_unannotated.png"


def score_both(gt: np.ndarray, pred: np.ndarray) -> dict:
    """The scores as published and without the unannotated movers' tracks."""
    from aerotrack.evaluation.mot import evaluate
    from aerotrack.evaluation.santiago import SANTIAGO_FRAMES, unannotated_movers

    movers = unannotated_movers(gt, pred)
    kept = pred[~np.isin(pred[:, 1], movers)]
    a = evaluate(gt, pred, frames=SANTIAGO_FRAMES)
    b = evaluate(gt, kept, frames=SANTIAGO_FRAMES)
    return {"scored": {k: a[k] for k in KEYS}, "without_unannotated": {k: b[k] for k in KEYS},
            "unannotated_track_ids": movers,
            "unannotated_rows_in_window": int(np.isin(pred[:, 1], movers).sum())}


def picture(pred: np.ndarray, ids: list[int], out: Path) -> None:
    """Each listed track at its first, middle and last box (red), ground-truth boxes in green."""
    import cv2

    from aerotrack.evaluation.mot import fix_ground_truth
    from aerotrack.evaluation.santiago import load_santiago
    from aerotrack.io.frames import open_source
    from aerotrack.io.output import atomic_write_bytes

    gt, _ = load_santiago(SANTIAGO_DIR)
    gt, _ = fix_ground_truth(gt)
    src = open_source(SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4")
    frames = {f.index: f.image for f in src.frames()}
    R, K = 40, 3
    tiles = []
    for tid in ids:
        rows = pred[pred[:, 1] == tid]
        rows = rows[np.argsort(rows[:, 0])]
        for r in (rows[0], rows[len(rows) // 2], rows[-1]):
            f = int(r[0])
            img = cv2.copyMakeBorder(frames[f], R, R, R, R, cv2.BORDER_CONSTANT)
            cx, cy = int(r[2] + r[4] / 2), int(r[3] + r[5] / 2)
            x0, y0 = cx - R, cy - R
            big = cv2.resize(img[y0 + R:y0 + 3 * R, x0 + R:x0 + 3 * R], (2 * R * K, 2 * R * K),
                             interpolation=cv2.INTER_NEAREST)

            boxes = [(g[2:6], (0, 200, 0)) for g in gt[gt[:, 0] == f]] + [(r[2:6], (0, 0, 255))]
            for b, colour in boxes:
                cv2.rectangle(big, (int((b[0] - x0) * K), int((b[1] - y0) * K)),
                              (int((b[0] + b[2] - x0) * K), int((b[1] + b[3] - y0) * K)), colour, 1)
            cv2.putText(big, f"track {tid} frame {f}", (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                        (255, 255, 255), 1, cv2.LINE_AA)
            tiles.append(big)
    if not tiles:
        return
    rows_img = [np.hstack(tiles[i:i + 3]) for i in range(0, len(tiles), 3)]
    grid = [np.hstack(rows_img[i:i + 2]) if i + 1 < len(rows_img) else
            np.hstack([rows_img[i], np.zeros_like(rows_img[i])]) for i in range(0, len(rows_img), 2)]
    ok, buf = cv2.imencode(".png", np.vstack(grid))
    if ok:
        atomic_write_bytes(out, buf.tobytes())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--no-picture", action="store_true")
    args = ap.parse_args(argv)
    require_data(SANTIAGO_DIR)
    sys.path.insert(0, str(ROOT / "src"))
    from aerotrack.evaluation.mot import fix_ground_truth
    from aerotrack.evaluation.santiago import load_santiago
    from aerotrack.io.mot import read_mot

    gt, _ = load_santiago(SANTIAGO_DIR)
    gt, _ = fix_ground_truth(gt)
    video = SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4"
    out: dict = {"protocol": "corrected ground truth, frames 2..98 (1-based), IoU 0.5; "
                             "unannotated: no box at IoU >= 0.3 with a ground-truth box in any "
                             "scored frame and a centre moving >= one box length"}
    runs = {}
    for seed in args.seeds:
        run = WORK / "santiago_gt" / f"seed{seed}"
        aerotrack("-q", "track", str(video), "--out", str(run), "--seed", str(seed), "--overwrite")
        runs[seed] = read_mot(run / "tracks.csv")
        out[f"aerotrack seed {seed}"] = score_both(gt, runs[seed])
    for name in ("sort", "bytetrack"):
        _, pred = load_santiago(SANTIAGO_DIR, name)
        out[f"YOLOv8 + {name} (published)"] = score_both(gt, pred)
    ours = [out[f"aerotrack seed {s}"] for s in args.seeds]
    out["aerotrack mean"] = {part: {k: float(np.mean([o[part][k] for o in ours])) for k in KEYS}
                             for part in ("scored", "without_unannotated")}
    print(f"{'tracks':32s} {'HOTA':>13s} {'IDF1':>13s} {'MOTA':>13s} {'LocA':>6s} unannotated")
    for name, r in out.items():
        if not isinstance(r, dict) or "scored" not in r:
            continue
        a, b = r["scored"], r["without_unannotated"]
        n = len(r.get("unannotated_track_ids", [])) if "unannotated_track_ids" in r else "-"
        print(f"{name:32s} " + " ".join(f"{a[k]:.3f}->{b[k]:.3f}" for k in ("HOTA", "IDF1", "MOTA"))
              + f" {a['LocA']:6.3f} {n}")
    if not args.no_picture and args.seeds:
        s0 = args.seeds[0]
        picture(runs[s0], out[f"aerotrack seed {s0}"]["unannotated_track_ids"], PICTURE)
        print(f"picture: {PICTURE.relative_to(ROOT)}")
    print(f"wrote {write_results('santiago_gt', out)}")


if __name__ == "__main__":
    main()

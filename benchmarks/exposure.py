"""Santiago's real frames under a camera's auto-exposure swing: what ``detection.exposure_tolerance``
(background samples brought to one exposure before the window's median) keeps of the score.

Each swing multiplies every pixel of frame k (time t = (k - 1) / 30 s) by
``1 + amplitude * sin(2 pi t / period)``, clipped to 0-255, and writes the 100 frames as PNG (no
second compression); the ground truth is the clip's own. Each swing, and the unmodified frames, is
tracked with ``aerotrack track FRAMES --fps 30 --seed S`` with the default configuration and with
``--set detection.exposure_tolerance=0`` (off), and scored with ``aerotrack eval --gt-zero-based
--frames 2:98 --fix-gt`` (the clip's published protocol).

    python benchmarks/exposure.py [--seeds 0]

Frames are cached under ``$AEROTRACK_BENCH_WORK/exposure``; results go to
``benchmarks/results/exposure.json``.
"""

from __future__ import annotations

import argparse
import json
import math

import cv2
import numpy as np
from common import SANTIAGO_DIR, WORK, aerotrack, require_data, write_results

SWINGS = {"none": (0.0, 3.0), "10pct_3s": (0.10, 3.0), "25pct_1.3s": (0.25, 1.3)}
KEYS = ("HOTA", "IDF1", "MOTA", "DetA", "AssA", "IDSW", "Pred_IDs")
CONFIGS = {"default": [], "off": ["--set", "detection.exposure_tolerance=0"]}


def render(name: str) -> str:
    """The clip's frames under swing ``name`` (cached); returns the folder."""
    from aerotrack.io import open_source

    amp, period = SWINGS[name]
    folder = WORK / "exposure" / name / "frames"
    if folder.is_dir() and len(list(folder.glob("*.png"))) == 100:
        return str(folder)
    folder.mkdir(parents=True, exist_ok=True)
    src = open_source(SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4", None)
    for f in src.frames():
        g = 1.0 + amp * math.sin(2 * math.pi * ((f.index - 1) / 30.0) / period)
        img = np.clip(f.image.astype(np.float32) * g, 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{f.index:06d}.png"), img)
    return str(folder)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    args = ap.parse_args(argv)
    require_data(SANTIAGO_DIR)
    gt = str(SANTIAGO_DIR / "dfs_ground_truth.csv")
    results: dict = {"swings": {k: {"amplitude": a, "period_s": p} for k, (a, p) in SWINGS.items()},
                     "runs": {}}
    for name in SWINGS:
        frames = render(name)
        for cfg, sets in CONFIGS.items():
            for seed in args.seeds:
                run = WORK / "exposure" / name / f"run_{cfg}_{seed}"
                aerotrack("-q", "track", frames, "--fps", "30", "--out", str(run), "--seed",
                          str(seed), "--overwrite", *sets)
                e = json.loads(aerotrack("eval", "--gt", gt, "--pred", str(run / "tracks.csv"),
                                         "--gt-zero-based", "--frames", "2:98", "--fix-gt",
                                         "--json"))
                e = e.get("combined", e)
                r = {k: e[k] for k in KEYS}
                results["runs"][f"{name}/{cfg}/{seed}"] = r
                print(f"{name:11s} {cfg:8s} seed {seed}: HOTA {r['HOTA']:.3f} IDF1 {r['IDF1']:.3f} "
                      f"MOTA {r['MOTA']:.3f} IDSW {r['IDSW']}", flush=True)
    print(f"wrote {write_results('exposure', results)}")


if __name__ == "__main__":
    main()

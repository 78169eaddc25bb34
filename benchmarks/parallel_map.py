"""Segments with a map (issue 8): registration error against the generator's truth and HOTA/IDF1,
single process against ``--workers 2`` with every segment on the map (the default) and with later
segments chained into map pixels (``ParallelConfig.map_every_segment=False``, as before
2026-12-02).

The scene is made with ``aerotrack synth`` (its ``homographies.csv`` is the true frame -> map);
each mode reports the corner error of every frame's registration against it (median and max, and
over the second half of the video, which the second segment owns), the carry's seconds, the wall
time and HOTA/IDF1/MOTA against ``gt.txt``. MCMC seeds move single runs by a few hundredths: use
several scenes and seeds before reading the tracking columns.

Usage::

    /tmp/venv/bin/python benchmarks/parallel_map.py --seed 8 --frames 1500 [--mcmc-seed 0]
        [--out benchmarks/results/parallel-map.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def corner_errors(registrations, truth, size) -> dict:
    from aerotrack.types import apply_homography

    w, h = size
    c = np.array([[0, 0], [w, 0], [w, h], [0, float(h)]])
    frames = np.array(sorted(registrations))
    e = np.array([np.abs(apply_homography(registrations[f].H, c)
                         - apply_homography(truth[f], c)).max() for f in frames])
    late = frames > frames.max() / 2
    return {"median_px": float(np.median(e)), "max_px": float(e.max()),
            "median_px_2nd_half": float(np.median(e[late])), "max_px_2nd_half": float(e[late].max())}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=8, help="scene seed")
    ap.add_argument("--frames", type=int, default=1500)
    ap.add_argument("--mcmc-seed", type=int, default=0)
    ap.add_argument("--modes", default="single,dask-chain,dask-map")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)

    from aerotrack import io
    from aerotrack.evaluation import evaluate
    from aerotrack.geo import GeoMap, read_map_init
    from aerotrack.outputs import track_rows
    from aerotrack.parallel import ParallelConfig, dask_client, run_parallel
    from aerotrack.pipeline import run

    work = Path(tempfile.mkdtemp(prefix="parallel-map-"))
    scene = work / "scene"
    subprocess.run([sys.executable, "-m", "aerotrack", "-q", "synth", "--out", str(scene),
                    "--seed", str(args.seed), "--frames", str(args.frames)], check=True)
    geomap = GeoMap(scene / "map.tif")
    H1 = read_map_init(scene / "map_init.txt", geomap)
    rows = np.loadtxt(scene / "homographies.csv", delimiter=",", skiprows=1)
    truth = {int(r[0]): r[1:].reshape(3, 3) for r in rows}
    gt = io.read_mot(scene / "gt.txt", strict=False)
    out = {"scene_seed": args.seed, "frames": args.frames, "mcmc_seed": args.mcmc_seed, "modes": {}}
    for mode in args.modes.split(","):
        src = io.open_source(scene / "frames")
        t0 = time.perf_counter()
        if mode == "single":
            res = run(src, geomap=geomap, H_init=H1, seed=args.mcmc_seed)
        else:
            with dask_client(workers=2) as client:
                res = run_parallel(src, client=client, geomap=geomap, H_init=H1,
                                   seed=args.mcmc_seed, parallel=ParallelConfig(
                                       min_segments=2, map_every_segment=mode == "dask-map"))
        wall = time.perf_counter() - t0
        s = evaluate(gt, track_rows(res, geomap)[0])
        out["modes"][mode] = {"wall_s": round(wall, 1), "carry_s": round(res.timings.get("carry", 0.0), 1),
                              **{k: round(v, 3) for k, v in corner_errors(res.registrations, truth,
                                                                          src.size).items()},
                              **{k: round(float(s[k]), 3) for k in ("HOTA", "IDF1", "MOTA")}}
        print(mode, out["modes"][mode], flush=True)
    if args.out:
        args.out.write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()

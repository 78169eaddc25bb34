"""Benchmark of the scenario generator (``aerotrack synth``, issue 2 item 4).

Measures, in one process, for a 640x480 scene of N frames (default 900):

* ``stream``: ``Scenario(...).frames()`` (simulation + rendering + ground truth, no disk);
* ``render_to``: the whole ``aerotrack synth`` output (JPEG frames, gt.txt, states, map.tif ...);
* ``baseline``: the naive floor, one ``cv2.warpPerspective`` of the map + one ``cv2.imencode`` JPEG
  per frame with the same homographies (no vehicles, occluders, noise or ground truth).

Speeds are frames per second of process CPU time (the machine is shared, so wall time is also
printed but not compared) and as ratios to the baseline of the same run. Peak memory (max RSS) is
reported after streaming a long scene (``--long`` frames, default 1800) to show it stays bounded.

Usage: ``/tmp/venv/bin/python benchmarks/synth.py [--frames N] [--long N]``; prints a table and
writes benchmarks/results/synth.json.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from aerotrack.synth import Scenario, render_to

RESULTS = Path(__file__).resolve().parent / "results" / "synth.json"


def timed(fn):
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - w0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=900)
    ap.add_argument("--long", type=int, default=1800)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    n = args.frames

    hs = []

    def stream():
        for _frame, H, _truth in Scenario(seed=args.seed, frames=n).frames():
            hs.append(H)
        return len(hs)

    _, c_stream, w_stream = timed(stream)

    sc = Scenario(seed=args.seed, frames=1)
    image = sc.world.image

    def baseline():
        for H in hs:
            f = cv2.warpPerspective(image, np.linalg.inv(H), (640, 480), flags=cv2.INTER_LINEAR)
            cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 90])

    _, c_base, w_base = timed(baseline)

    with tempfile.TemporaryDirectory() as tmp:
        info, c_disk, w_disk = timed(lambda: render_to(Path(tmp) / "scene", seed=args.seed,
                                                       frames=n))

    def long_stream():
        k = 0
        for _ in Scenario(seed=args.seed, frames=args.long).frames():
            k += 1
        return k

    _, c_long, _ = timed(long_stream)
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    rows = {
        "baseline (warp + JPEG)": (c_base, w_base),
        "stream (Scenario.frames)": (c_stream, w_stream),
        "render_to (all files)": (c_disk, w_disk),
    }
    print(f"scenario default, {n} frames 640x480, seed {args.seed}")
    print(f"{'what':28s} {'cpu s':>7s} {'wall s':>7s} {'fps(cpu)':>9s} {'x baseline':>10s}")
    res = {"frames": n, "size": [640, 480], "seed": args.seed, "rows": {}}
    for name, (c, w) in rows.items():
        fps = n / c
        ratio = c / c_base
        print(f"{name:28s} {c:7.2f} {w:7.2f} {fps:9.1f} {ratio:10.2f}")
        res["rows"][name] = {"cpu_s": c, "wall_s": w, "fps_cpu": fps, "cpu_ratio_to_baseline": ratio}
    print(f"long stream: {args.long} frames in {c_long:.1f} cpu s; peak RSS {rss_mb:.0f} MB")
    res["long"] = {"frames": args.long, "cpu_s": c_long, "peak_rss_mb": rss_mb}
    res["scene"] = {k: info[k] for k in ("vehicles", "gt_rows", "states", "occluders")}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()

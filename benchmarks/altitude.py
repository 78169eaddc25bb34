"""Vehicle size in pixels: the same generated scenes flown lower and higher, through the CLI.

A user's footage may show cars 8 px long (a high or wide-angle flight) or 120 px long (a low
one). ``aerotrack synth --gsd-scale K`` renders the same scene (vehicles, routes, camera path)
with the camera's ground sample distance times K; this script renders two scenes at several K,
tracks each as a user would (``aerotrack track`` with the map and its frame-1 anchor, with
``--gsd`` only, and with neither), and scores ``tracks.csv`` with ``aerotrack eval --json``.

Scenes: ``dense`` seed 3 at 1280x720 and ``default`` seed 12 at 640x480, 600 frames each (seeds
no other benchmark tunes on). K 0.25 / 1 / 1.43 / 2: cars about 64, 16, 11 and 8 px long. The
``--gsd`` value is the true metres per pixel at frame 1's centre.

    python benchmarks/altitude.py [--scales 0.25 1 1.43 2] [--modes map gsd nomap] [--jobs 2]
                                  [--set K=V] [--out altitude]
                                  [--scenes SCENARIO:SEED:WxH ...] [--frames N]

Other scenes and lengths (the low-flight scenes of ``detection.close_resolved_px``):

    python benchmarks/altitude.py --scales 0.3 --modes map --frames 450 --out altitude-low \
        --scenes convoy:33:1280x720 convoy:44:1280x720 dense:42:1280x720 dense:43:1280x720 \
                 dense:48:1280x720 exits:46:1280x720 occlusion:34:1280x720 occlusion:47:1280x720

Scenes are cached under ``$AEROTRACK_BENCH_WORK/altitude`` with the generator's source hash;
results go to ``benchmarks/results/altitude.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from common import WORK, aerotrack, generator_version, rendered_scene, write_results

#: (scenario, seed, frame size)
SCENES = (("dense", 3, "1280x720"), ("default", 12, "640x480"))
FRAMES = 600
KEYS = ("HOTA", "IDF1", "MOTA", "DetA", "AssA", "LocA", "IDSW", "GT_IDs", "Pred_IDs")


def scene(folder: Path, scenario: str, seed: int, size: str, k: float,
          frames: int = FRAMES) -> Path:
    """The rendered scene, rendered again when the generator's code changed."""
    name = f"{scenario}_{seed}_{size}_x{k:g}" + ("" if frames == FRAMES else f"_f{frames}")
    return rendered_scene(folder, name,
                          ("--seed", str(seed), "--scenario", scenario, "--size", size,
                           "--frames", str(frames), "--gsd-scale", f"{k:g}"))


def metres_per_pixel(d: Path) -> float:
    """True metres per frame pixel at frame 1's centre (map scale times the anchor's)."""
    from aerotrack.geo import GeoMap, read_map_init
    from aerotrack.types import local_scale

    w, h = json.loads((d / "scenario.json").read_text())["size"]
    H = read_map_init(d / "map_init.txt")
    return GeoMap(d / "map.tif").metres_per_pixel * local_scale(H, np.array([w / 2, h / 2]))


def vehicle_length_px(d: Path) -> float:
    gt = np.loadtxt(d / "gt.txt", delimiter=",", ndmin=2)
    return float(np.median(np.maximum(gt[:, 4], gt[:, 5]))) if len(gt) else float("nan")


def run_one(folder: Path, spec: tuple, k: float, mode: str, overrides: list[str],
            frames: int = FRAMES) -> dict:
    scenario, seed, size = spec
    d = scene(folder, scenario, seed, size, k, frames)
    out = d.parent / f"{d.name}.{mode}.run"
    mpp = metres_per_pixel(d)
    geo = {"map": ["--map", str(d / "map.tif"), "--map-init", str(d / "map_init.txt")],
           "gsd": ["--gsd", f"{mpp:.4f}"], "nomap": []}[mode]
    sets = [a for kv in overrides for a in ("--set", kv)]
    t0 = time.perf_counter()
    aerotrack("-q", "track", str(d / "frames"), "--out", str(out), *geo, "--seed", "0",
              "--overwrite", *sets)
    wall = time.perf_counter() - t0
    e = json.loads(aerotrack("eval", "--gt", str(d / "gt.txt"), "--pred",
                             str(out / "tracks.csv"), "--json"))
    e = e.get("combined", e)
    return {"scene": f"{scenario}:{seed} {size}", "gsd_scale": k, "mode": mode,
            "metres_per_px": mpp, "car_length_px": vehicle_length_px(d),
            **{key: e[key] for key in KEYS}, "track_wall_s": wall}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", nargs="+", type=float, default=[0.25, 1.0, 1.43, 2.0])
    ap.add_argument("--modes", nargs="+", default=["map", "gsd", "nomap"],
                    choices=["map", "gsd", "nomap"])
    ap.add_argument("--jobs", type=int, default=2, help="runs at once")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="SECTION.KEY=VALUE for every run (as aerotrack's --set), repeatable")
    ap.add_argument("--out", default="altitude", help="results name (benchmarks/results/NAME.json)")
    ap.add_argument("--scenes", nargs="+", default=None, metavar="SCENARIO:SEED:WxH",
                    help="scenes to fly (default: dense:3:1280x720 default:12:640x480)")
    ap.add_argument("--frames", type=int, default=FRAMES, help="frames per scene")
    args = ap.parse_args(argv)
    scenes = SCENES
    if args.scenes:
        try:
            scenes = tuple((a, int(b), c) for a, b, c in (s.split(":") for s in args.scenes))
        except ValueError:
            ap.error("--scenes: give SCENARIO:SEED:WxH, e.g. dense:3:1280x720")
    folder = WORK / "altitude"
    folder.mkdir(parents=True, exist_ok=True)
    # render first (two at a time), then track
    specs = [(s, k) for s in scenes for k in args.scales]
    with ThreadPoolExecutor(max(1, args.jobs)) as ex:
        list(ex.map(lambda sk: scene(folder, *sk[0], sk[1], args.frames), specs))
    jobs = [(s, k, m) for s, k in specs for m in args.modes]
    with ThreadPoolExecutor(max(1, args.jobs)) as ex:
        rows = list(ex.map(lambda j: run_one(folder, *j, args.overrides, args.frames), jobs))
    print(f"{'scene':<24}{'K':>6}{'m/px':>7}{'car px':>8}  {'mode':<6}"
          f"{'HOTA':>7}{'IDF1':>7}{'MOTA':>7}{'IDSW':>6}")
    for r in rows:
        print(f"{r['scene']:<24}{r['gsd_scale']:>6g}{r['metres_per_px']:>7.2f}"
              f"{r['car_length_px']:>8.1f}  {r['mode']:<6}{r['HOTA']:>7.3f}{r['IDF1']:>7.3f}"
              f"{r['MOTA']:>7.3f}{r['IDSW']:>6d}")
    means = {}
    for m in args.modes:
        for k in args.scales:
            sel = [r for r in rows if r["mode"] == m and r["gsd_scale"] == k]
            means[f"{m} x{k:g}"] = {key: float(np.mean([r[key] for r in sel]))
                                    for key in ("HOTA", "IDF1", "MOTA", "DetA", "AssA")}
            print(f"mean {m:<6} x{k:<5g}" + "".join(f" {key} {v:.3f}"
                                                  for key, v in means[f"{m} x{k:g}"].items()))
    path = write_results(args.out, {"frames": args.frames, "scenes": [list(s) for s in scenes],
                                    "overrides": args.overrides, "generator": generator_version(),
                                    "runs": rows, "mean": means})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

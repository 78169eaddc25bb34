"""Held-out generated scenes through the command line: every scenario, seeds the other benchmarks
do not use, scored as a user would score them.

For each scenario (default, occlusion, exits, convoy, dense, static) and seed: ``aerotrack synth``
renders the scene (900 frames, 640x480, JPEG frames as on disk), ``aerotrack track`` tracks it with
the map and its frame-1 anchor and the default configuration (``--seed 0``, or
``--track-seed``), and ``aerotrack eval
--json`` scores ``tracks.csv`` against ``gt.txt``. Nothing is tuned on these seeds (11, 12 and 21
by default); the point is to catch what the tuned benchmarks do not (a false alarm held for
seconds on convoy:5, dark vehicles' shadows in their boxes on static scenes).

    python benchmarks/scenarios.py [--seeds 11 12 21] [--scenarios ...] [--jobs 2] [--set K=V]
                                   [--no-map] [--relink] [--track-seed N]

``--no-map`` tracks the same frames as a user without a map or ``--gsd`` would (registered to
frame 1, the metric scale estimated from the objects): ``results/scenarios-nomap.json``.

``--relink`` is for association, linking and finishing changes: it re-runs only those stages
(``aerotrack track --from``) on the registrations and detections the last full run of each scene
cached (``SCENE.run``; run once without ``--relink`` first, with the detection settings wanted),
into ``SCENE.relink``, in about a minute instead of four; detection and registration overrides
have no effect there. Its results go to ``results/scenarios-relink.json`` unless ``--out``.

Scenes are cached under ``$AEROTRACK_BENCH_WORK/scenarios`` with the generator's source hash;
results go to ``benchmarks/results/scenarios.json`` (per scene and the mean per scenario and
overall).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from common import WORK, aerotrack, generator_version, rendered_scene, write_results

SCENARIOS = ("default", "occlusion", "exits", "convoy", "dense", "static")
KEYS = ("HOTA", "IDF1", "MOTA", "DetA", "AssA", "LocA", "IDSW", "GT_IDs", "Pred_IDs")


def scene(folder: Path, scenario: str, seed: int) -> Path:
    """The rendered scene, rendered again when the generator's code changed."""
    return rendered_scene(folder, f"{scenario}_{seed}", ("--seed", str(seed), "--scenario", scenario))


def run_one(folder: Path, scenario: str, seed: int, overrides: list[str],
            use_map: bool = True, relink: bool = False, track_seed: int = 0) -> dict:
    out = folder / f"{scenario}_{seed}.{'run' if use_map else 'nomap.run'}"
    sets = [a for kv in overrides for a in ("--set", kv)]
    if relink:
        if not (out / "stages").is_dir():
            print(f"scenarios.py --relink: {out} has no cached stages; run the benchmark once "
                  "without --relink first", file=sys.stderr)
            raise SystemExit(2)
        sets = ["--from", str(out), *sets]
        out = out.with_suffix(".relink")
    d = scene(folder, scenario, seed)
    # --from takes the earlier run's inputs (the frames and --map-init are refused with it; the map
    # it reads from that run's summary)
    inputs = [] if relink else [str(d / "frames")] + (
        ["--map", str(d / "map.tif"), "--map-init", str(d / "map_init.txt")] if use_map else [])
    t0 = time.perf_counter()
    aerotrack("-q", "track", *inputs, "--out", str(out), "--seed", str(track_seed), "--overwrite",
              *sets)
    wall = time.perf_counter() - t0
    e = json.loads(aerotrack("eval", "--gt", str(d / "gt.txt"), "--pred", str(out / "tracks.csv"),
                             "--json"))
    e = e.get("combined", e)
    return {"scene": f"{scenario}:{seed}", **{k: e[k] for k in KEYS}, "track_wall_s": wall}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument("--seeds", nargs="+", type=int, default=[11, 12, 21])
    ap.add_argument("--jobs", type=int, default=2, help="scenes tracked at once")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="configuration override for aerotrack track, SECTION.KEY=VALUE")
    ap.add_argument("--no-map", action="store_true",
                    help="track without the map (frames alone, no --map/--gsd)")
    ap.add_argument("--relink", action="store_true",
                    help="re-run association, linking and finishing only, on the detections the "
                         "last full run cached (aerotrack track --from)")
    ap.add_argument("--track-seed", type=int, default=0,
                    help="aerotrack track --seed (the sampler's; the scenes' seeds are --seeds): "
                         "a few of them tell a change's effect from the sampler's spread")
    ap.add_argument("--out", default=None,
                    help="results name (benchmarks/results/NAME.json; default scenarios, or "
                         "scenarios-nomap with --no-map)")
    args = ap.parse_args(argv)
    out_name = args.out or ("scenarios-nomap" if args.no_map else "scenarios") + \
        ("-relink" if args.relink and not args.out else "")
    folder = WORK / "scenarios"
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(s, n) for n in args.seeds for s in args.scenarios]
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        rows = list(pool.map(lambda j: run_one(folder, j[0], j[1], args.overrides,
                                               use_map=not args.no_map, relink=args.relink,
                                               track_seed=args.track_seed),
                             jobs))
    print(f"{'scene':14s} " + " ".join(f"{k:>8s}" for k in KEYS))
    for r in rows:
        print(f"{r['scene']:14s} " + " ".join(
            f"{r[k]:8.3f}" if isinstance(r[k], float) else f"{r[k]:8d}" if isinstance(r[k], int)
            else f"{'-':>8s}" for k in KEYS))  # null: undefined (eval --json)
    means = {}
    for name in [*args.scenarios, "all"]:
        sel = [r for r in rows if name == "all" or r["scene"].split(":")[0] == name]
        means[name] = {k: float(np.mean([r[k] for r in sel])) for k in ("HOTA", "IDF1", "MOTA")}
        means[name]["IDSW"] = int(sum(r["IDSW"] for r in sel))
        print(f"mean {name:9s} HOTA {means[name]['HOTA']:.3f} IDF1 {means[name]['IDF1']:.3f} "
              f"MOTA {means[name]['MOTA']:.3f} IDSW {means[name]['IDSW']}")
    path = write_results(out_name, {"seeds": args.seeds, "scenarios": args.scenarios,
                                    "map": not args.no_map, "relink": args.relink,
                                    "overrides": args.overrides, "track_seed": args.track_seed,
                                    "generator": generator_version(),
                                    "scenes": rows, "mean": means})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

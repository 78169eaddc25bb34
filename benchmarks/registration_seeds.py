"""Santiago end to end: how far HOTA/IDF1 move with no change to the method (a noise floor).

Three sources of run-to-run variation, measured separately and together:

* the MCMC seed of local association (``--seed``): the same registrations and detections,
  association and linking re-run (``aerotrack track --from``, which reuses them);
* sub-pixel registration jitter: registration settings nudged by a few percent
  (``registration.max_features`` 400 -> 380/420, ``registration.ransac_threshold_px``
  2.0 -> 1.9/2.1), each a full run (registration, detection, association, linking), then the
  same seeds on its detections;
* the detection threshold one grey level either side of the default (``detection.min_threshold``
  10, which Santiago's noise level makes the threshold: the residual is whole grey levels, so 9.7
  lets 10 through, 11 and 12 need 12 and 13), each a full run, then the same seeds: how sharp a
  peak the defaults sit on (2026-12-01: HOTA 0.670 at 10 against 0.639-0.648 beside it).

A change to the method whose effect on Santiago is inside these spreads cannot be told from noise
by one run; compare means over several seeds instead (the standard error of a mean over ``n``
seeds is the seed spread / sqrt(n)).

Usage::

    /tmp/venv/bin/python benchmarks/registration_seeds.py [--seeds 5] [--variants ...]

Prints a table and writes benchmarks/results/registration_seeds.json. Runs go to
``$AEROTRACK_BENCH_WORK/registration_seeds`` (``/tmp/aerotrack-bench`` by default).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

from common import SANTIAGO_DIR, WORK, require_data, write_results

VIDEO = "video_sift_estabilizado_filtrado.mp4"
GT = "dfs_ground_truth.csv"
#: name -> ``--set`` overrides of one full run (registration nudged a few percent).
VARIANTS = {
    "default": [],
    "features380": ["registration.max_features=380"],
    "features420": ["registration.max_features=420"],
    "ransac1.9": ["registration.ransac_threshold_px=1.9"],
    "ransac2.1": ["registration.ransac_threshold_px=2.1"],
    "threshold9.7": ["detection.min_threshold=9.7"],
    "threshold11": ["detection.min_threshold=11"],
    "threshold12": ["detection.min_threshold=12"],
}


def _fail(message: str) -> None:
    """One line on standard error, exit code 2 (bad input or a failed run)."""
    print(f"registration_seeds.py: {message}", file=sys.stderr)
    raise SystemExit(2)


def aerotrack(*args: str) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "aerotrack", *args], capture_output=True, text=True,
                       check=False)
    if r.returncode != 0:
        _fail(f"aerotrack {' '.join(args[:2])}: {r.stderr.strip().splitlines()[-1:]}")
    return r


def score(run_dir) -> dict:
    """HOTA/IDF1 of ``run_dir/tracks.csv`` on Santiago's scored frames (the README's command)."""
    r = aerotrack("eval", "--gt", str(SANTIAGO_DIR / GT), "--pred", str(run_dir / "tracks.csv"),
                  "--gt-zero-based", "--frames", "2:98", "--fix-gt", "--json")
    data = json.loads(r.stdout)
    row = data[0] if isinstance(data, list) else data
    row = row.get("combined", row) if isinstance(row, dict) else row
    return {"HOTA": float(row["HOTA"]), "IDF1": float(row["IDF1"])}


def spread(values: list[float]) -> dict:
    return {"mean": round(statistics.fmean(values), 4),
            "sd": round(statistics.stdev(values), 4) if len(values) > 1 else 0.0,
            "min": round(min(values), 4), "max": round(max(values), 4), "n": len(values)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="MCMC seeds 0..N-1 per variant.")
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help=f"Comma-separated subset of {', '.join(VARIANTS)}.")
    a = ap.parse_args()
    require_data(SANTIAGO_DIR / VIDEO)
    work = WORK / "registration_seeds"
    work.mkdir(parents=True, exist_ok=True)
    names = [v for v in a.variants.split(",") if v]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        _fail(f"--variants: unknown {', '.join(unknown)}; valid: {', '.join(VARIANTS)}")
    scores: dict[str, dict[int, dict]] = {}
    load = []
    t_start = time.perf_counter()
    for name in names:
        sets = [x for s in VARIANTS[name] for x in ("--set", s)]
        base = work / f"{name}-seed0"
        load.append(os.getloadavg()[0])
        aerotrack("track", str(SANTIAGO_DIR / VIDEO), "--out", str(base), "--overwrite",
                  "--seed", "0", *sets)
        scores[name] = {0: score(base)}
        for seed in range(1, a.seeds):
            out = work / f"{name}-seed{seed}"
            aerotrack("track", "--from", str(base), "--out", str(out), "--overwrite",
                      "--seed", str(seed), *sets)
            scores[name][seed] = score(out)
        print(f"{name:12} " + "  ".join(f"s{s} {v['HOTA']:.3f}/{v['IDF1']:.3f}"
                                          for s, v in scores[name].items()), flush=True)
    summary = {}
    reg = [n for n in names if not n.startswith("threshold")]
    thr = [n for n in names if n.startswith("threshold") or n == "default"]
    for metric in ("HOTA", "IDF1"):
        seed_only = [v[metric] for v in scores.get("default", {}).values()]
        per_variant = {n: spread([v[metric] for v in scores[n].values()]) for n in names}
        everything = [v[metric] for n in names for v in scores[n].values()]
        summary[metric] = {
            "seeds_default_registration": spread(seed_only) if seed_only else None,
            "registration_variants_seed0":
                spread([scores[n][0][metric] for n in reg]) if reg else None,
            "all_runs": spread(everything),
            "per_variant_over_seeds": per_variant,
            # between-variant spread of the seed means: registration jitter with MCMC averaged out
            "registration_variants_seed_means":
                spread([per_variant[n]["mean"] for n in reg]) if reg else None,
            # the same for the detection threshold one grey level either side of the default
            "threshold_variants_seed_means":
                spread([per_variant[n]["mean"] for n in thr]) if len(thr) > 1 else None,
        }
    print(f"\nSantiago, {a.seeds} seeds x {len(names)} variants "
          f"(1-min load {min(load):.1f}-{max(load):.1f}):")
    print(f"{'spread of':42} {'HOTA mean':>9} {'sd':>6} {'min-max':>13} {'IDF1 mean':>9} "
          f"{'sd':>6} {'min-max':>13}")
    for key, label in (("seeds_default_registration", "MCMC seeds (default registration)"),
                       ("registration_variants_seed0", "registration variants (seed 0)"),
                       ("registration_variants_seed_means", "registration variants (seed means)"),
                       ("threshold_variants_seed_means", "threshold 9.7-12 (seed means)"),
                       ("all_runs", "all runs")):
        h, i = summary["HOTA"][key], summary["IDF1"][key]
        if h is None:
            continue
        print(f"{label:42} {h['mean']:9.3f} {h['sd']:6.3f} {h['min']:6.3f}-{h['max']:.3f} "
              f"{i['mean']:9.3f} {i['sd']:6.3f} {i['min']:6.3f}-{i['max']:.3f}")
    payload = {"seeds": a.seeds, "variants": {n: VARIANTS[n] for n in names},
               "scores": {n: {str(s): v for s, v in d.items()} for n, d in scores.items()},
               "summary": summary, "load_avg_1min_at_starts": [round(x, 2) for x in load],
               "wall_s": round(time.perf_counter() - t_start, 1),
               "note": "seeds 1.. re-run association and linking on the seed-0 run's "
                       "registrations and detections (track --from); eval as in the README "
                       "(--gt-zero-based --frames 2:98 --fix-gt)"}
    print(f"wrote {write_results('registration_seeds', payload)}")


if __name__ == "__main__":
    main()

"""Screen-line counts and turning movements (``aerotrack count``) against the ground truth.

What a traffic study gets from the tracks: vehicles per line and direction, and each vehicle's way
through the lines. Each run is counted with ``aerotrack count RUN --gt GT --json``, which counts the
ground truth's boxes the same way (through the run's own registration) and reports:

* count error: ``sum |counted - true| / sum true`` over lines and directions (the error of the
  totals a study would publish);
* crossing precision and recall: crossings paired one to one with a true crossing of the same
  line and direction within 1 s;
* turning-movement error: ``sum |OD counted - OD true| / sum OD true`` over the cells of the
  origin-destination matrix (first line crossed -> last line crossed, per vehicle).

Inputs:

* the held-out generated scenes of ``benchmarks/scenarios.py`` (their scenes and runs, cached in
  ``$AEROTRACK_BENCH_WORK/scenarios``; run that benchmark first). Lines are placed from the scene's
  road centre-lines, not by hand: across every road stretch the camera sees in at least 60% of the
  frames, 16 m or longer, at its middle, at least 12 m from any other road (no junction), 14 m
  long, perpendicular to the road;
* Santiago (real, 3.3 s, 30 vehicles): a line across each of the junction's four approaches,
  drawn on its first frame (tracked into ``$AEROTRACK_BENCH_WORK/counting/santiago``). Its ground
  truth leaves out vehicles waiting in the queues, so counted queue vehicles that move score as
  false crossings there.

    python benchmarks/counting.py [--scenes DIR] [--no-santiago]

Writes ``benchmarks/results/counting.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from common import SANTIAGO_DIR, WORK, aerotrack, write_results

#: Santiago's approaches in its first frame's pixels (1920x1080): name, x1, y1, x2, y2.
SANTIAGO_LINES = ("west:470,550,540,750", "east:1300,360,1300,520", "south:1030,900,1260,690",
                  "north:680,280,880,160")


def road_lines(scene: Path, min_in_view: float = 0.6, min_stretch_m: float = 16.0,
               clear_m: float = 12.0, half_m: float = 7.0) -> dict:
    """A GeoJSON FeatureCollection of count lines (lon/lat) for a generated scene."""
    from aerotrack.context.roads import read_roads
    from aerotrack.geo import GeoMap

    gm = GeoMap(scene / "map.tif")
    net = read_roads(scene / "roads.geojson", geomap=gm)
    mpp = gm.metres_per_pixel
    hs = np.loadtxt(scene / "homographies.csv", delimiter=",", skiprows=1)
    Hinv = np.linalg.inv(hs[:, 1:].reshape(-1, 3, 3))  # map pixels -> frame pixels
    W, H = 640, 480
    roads = [np.asarray(r, float) for r in net.lines]
    feats = []
    for k, pts in enumerate(roads):
        seg = np.diff(pts, axis=0)
        cum = np.r_[0, np.cumsum(np.hypot(*seg.T))]
        s = np.arange(0, cum[-1], 2.0 / mpp)
        xy = np.column_stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])])
        q = np.einsum("fij,nj->fni", Hinv, np.column_stack([xy, np.ones(len(xy))]))
        px = q[..., :2] / q[..., 2:3]
        inside = ((px[..., 0] > 20) & (px[..., 0] < W - 20) & (px[..., 1] > 20)
                  & (px[..., 1] < H - 20)).mean(axis=0) >= min_in_view
        others = [r for j, r in enumerate(roads) if j != k]
        if others:
            op = np.vstack([_densify(r, 1.0 / mpp) for r in others])
            d = np.min(np.hypot(*(xy[:, None, :] - op[None]).transpose(2, 0, 1)), axis=1) * mpp
            inside &= d >= clear_m
        run_start = None
        for i in range(len(s) + 1):
            on = i < len(s) and inside[i]
            if on and run_start is None:
                run_start = i
            elif not on and run_start is not None:
                if (s[i - 1] - s[run_start]) * mpp >= min_stretch_m:
                    m = (run_start + i - 1) // 2
                    t = np.interp(s[m] + 1e-3, cum, pts[:, 0]) - xy[m, 0], \
                        np.interp(s[m] + 1e-3, cum, pts[:, 1]) - xy[m, 1]
                    t = np.array(t) / np.hypot(*t)
                    n = np.array([-t[1], t[0]]) * half_m / mpp
                    ends = gm.pixel_to_lonlat(np.array([xy[m] - n, xy[m] + n]))
                    feats.append({"type": "Feature", "properties": {"name": f"r{k}_{m}"},
                                  "geometry": {"type": "LineString", "coordinates": ends.tolist()}})
                run_start = None
    return {"type": "FeatureCollection", "features": feats}


def _densify(pts: np.ndarray, step: float) -> np.ndarray:
    seg = np.diff(pts, axis=0)
    cum = np.r_[0, np.cumsum(np.hypot(*seg.T))]
    s = np.arange(0, cum[-1] + step, step)
    return np.column_stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])])


def count(run: Path, gt: Path, *args: str) -> dict:
    return json.loads(aerotrack("-q", "count", str(run), "--gt", str(gt), "--json",
                                "--out", str(run.with_suffix(".count")), *args))


def pooled(comparisons: list[dict]) -> dict:
    """The comparisons' crossings and movements added up: count error, precision, recall and
    turning-movement error over all lines of all scenes."""
    per = [p for c in comparisons for p in c["per_line"]]
    true, counted = sum(p["true"] for p in per), sum(p["measured"] for p in per)
    matched = sum(p["matched"] for p in per)
    od_true = sum(c["movements_true"] for c in comparisons)
    od_err = sum((c["movement_error"] or 0.0) * c["movements_true"] for c in comparisons)
    return {"scenes": len(comparisons), "lines": sum(c["lines"] for c in comparisons),
            "true_crossings": true, "counted": counted, "matched": matched,
            "count_error": sum(abs(p["measured"] - p["true"]) for p in per) / max(true, 1),
            "precision": matched / max(counted, 1), "recall": matched / max(true, 1),
            "movements_true": od_true,
            "movement_error": od_err / od_true if od_true else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=Path, default=WORK / "scenarios",
                    help="Folder of benchmarks/scenarios.py's scenes and runs.")
    ap.add_argument("--no-santiago", action="store_true")
    args = ap.parse_args()
    out: dict = {"scenes": {}}
    for run in sorted(args.scenes.glob("*.run")):
        scene = run.with_suffix("")
        if not (scene / "roads.geojson").is_file() or not (run / "tracks.csv").is_file():
            continue
        lines = road_lines(scene)
        if not lines["features"]:
            print(f"{scene.name}: no road stretch in view long enough for a line")
            continue
        path = run.with_suffix(".lines.geojson")
        path.write_text(json.dumps(lines))
        c = count(run, scene / "gt.txt", "--lines", str(path))["comparison"]
        c["lines"] = len(lines["features"])
        out["scenes"][scene.name] = c
        print(f"{scene.name}: {json.dumps({k: v for k, v in c.items() if k != 'per_line'})}",
              flush=True)
    if not args.no_santiago and SANTIAGO_DIR.is_dir():
        run = WORK / "counting" / "santiago"
        if not (run / "tracks.csv").is_file():
            aerotrack("-q", "track", str(SANTIAGO_DIR / "video_sift_estabilizado_filtrado.mp4"),
                      "--out", str(run), "--seed", "0", "--overwrite")
        argv = [a for t in SANTIAGO_LINES for a in ("--line", t)]
        c = count(run, SANTIAGO_DIR / "dfs_ground_truth.csv", "--gt-zero-based", "--fix-gt",
                  *argv)["comparison"]
        out["santiago"] = c
        print(f"santiago: {json.dumps(c)}")
    sc = list(out["scenes"].values())
    if sc:
        out["scenes_pooled"] = pooled(sc)
        print("held-out scenes, pooled:", json.dumps(out["scenes_pooled"]))
    print(f"wrote {write_results('counting', out)}")


if __name__ == "__main__":
    main()

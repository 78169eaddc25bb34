"""The benchmark suite of issue 8: speed per stage and frame size, association beside peers,
peak memory against video length, a naive OpenCV floor and the Dask speed-up, in one run.

Usage::

    /tmp/venv/bin/python benchmarks/suite.py [--quick] [--only speed,association,memory,dask]
        [--minutes 1,5,10] [--memory-fps 2] [--update]

Every measurement runs in a fresh child process (this file with ``--child``), so peak RSS and
warm caches do not leak from one to the next. Frames come from :class:`aerotrack.synth.Scenario`
rendered directly at each size (no disk); the pipeline is the push API
(:class:`aerotrack.pipeline.Pipeline`) against the scene's own map, as ``aerotrack track --map``
runs on ``aerotrack synth`` output.

1. **Speed per stage** at 640x480, 1280x720, 1920x1080 and 4000x3000 (30 frames/s): the frames are
   rendered into memory first (rendering is not timed), then one ``Pipeline.step``/``finish``
   run; per-stage frames/s are frames / seconds in that stage (``Pipeline.timings``: registration,
   detection, association, linking), full pipeline = frames / wall time of the whole run; the
   same per CPU second (``Pipeline.cpu_timings``, the process's CPU time) is the number to read
   when others load the machine. The floor
   is a naive OpenCV pipeline on the same frames (MOG2 background subtraction, 3x3 opening and 5x5
   closing, connected components with an area gate): ratio = our full pipeline frames/s / its
   frames/s (goal >= 0.5). Pipeline and floor run alternately twice (once at 4000x3000) and the
   best wall time of each counts, so that a burst of load from other processes does not decide the
   ratio; the ratio of CPU seconds (all threads) is given beside it.
2. **Association** frames/s at 20/50/150 objects per frame (``common.synthetic_dets``) beside
   ByteTrack and OC-SORT in the same run (``association.speed`` -> ``peers.speed_table``).
3. **Peak memory** (``ru_maxrss`` of a fresh child, and RSS sampled along the run) for 1, 5 and 10
   minutes of 960x540 video streamed from the generator into the pipeline, at ``--memory-fps``
   (default 2 frames/s so that 10 minutes stay affordable on a shared 2-core machine: the minutes
   are real minutes of scene time and of every time-based window, only the frame count is lower),
   plus one 60 s run at 30 frames/s for the < 1.5 GB goal and the generator alone as the floor of
   RSS. Each run also reports what the pipeline holds at the end (``Pipeline.detections``,
   ``registrations``, ``tracklets`` and their bytes), to show where memory grows with length.
4. **Dask**: ``benchmarks/parallel.py``'s modes (single process, single process with one thread,
   Dask with 1 and 2 workers) on its generated video, each in a fresh process.

Speeds are also given as ratios to the baselines measured in the same run (naive OpenCV, ByteTrack,
the single process with one thread). Prints a table and writes ``benchmarks/results/suite.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, WORK, write_results

SIZES = {"640x480": 150, "1280x720": 120, "1920x1080": 90, "4000x3000": 24}
QUICK_SIZES = {"640x480": 45, "1280x720": 30}
FPS = 30.0


# -- helpers --------------------------------------------------------------------------------------
def _scene(seed: int, n: int, size: tuple[int, int], fps: float):
    """A scenario and its map (the world's own colour image, as ``aerotrack synth`` writes it)."""
    from aerotrack.synth import Scenario

    sc = Scenario(seed=seed, frames=n, size=size, fps=fps)
    geomap = sc.world.geomap
    geomap._image = sc.world.image  # the map ``aerotrack synth`` writes is this image
    return sc, geomap


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def naive_opencv(frames) -> tuple[float, int]:
    """The floor: MOG2 background subtraction, 3x3 opening, 5x5 closing, connected components
    (area >= 20 px) on each frame. Returns (wall seconds, blobs found)."""
    import cv2

    mog = cv2.createBackgroundSubtractorMOG2(history=int(3 * FPS), detectShadows=False)
    k_open = cv2.getStructuringElement(cv2.MORPH_RECT, (3, 3))
    k_close = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))
    blobs = 0
    t0 = time.perf_counter()
    for f in frames:
        fg = mog.apply(f.image)
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, k_open)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, k_close)
        _, _, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        blobs += int((stats[1:, cv2.CC_STAT_AREA] >= 20).sum())
    return time.perf_counter() - t0, blobs


def held_bytes(pipe) -> dict:
    """What a :class:`~aerotrack.pipeline.Pipeline` holds that grows with the video: detections
    (and the arrays in them), registrations and tracklet points."""
    def nbytes(d) -> int:
        total = 0
        for v in vars(d).values():
            if isinstance(v, np.ndarray):
                total += v.nbytes
            elif isinstance(v, dict):
                total += sum(a.nbytes for a in v.values() if isinstance(a, np.ndarray))
        return total

    det_bytes = sum(nbytes(d) for d in pipe.detections)
    n_det = sum(len(d) for d in pipe.detections)
    per_field: dict[str, int] = {}
    for d in pipe.detections:
        for k, v in vars(d).items():
            if isinstance(v, np.ndarray):
                per_field[k] = per_field.get(k, 0) + v.nbytes
            elif isinstance(v, dict):
                for kk, a in v.items():
                    if isinstance(a, np.ndarray):
                        per_field[f"{k}.{kk}"] = per_field.get(f"{k}.{kk}", 0) + a.nbytes
    # finished tracklets: in memory, or spilled to disk (aerotrack.io.checkpoint.TrackletSpill)
    # but for the few not written yet
    spill = pipe.tracklets if hasattr(pipe.tracklets, "load") else None
    held = spill._buffer if spill is not None else pipe.tracklets
    points = sum(len(t.points) for t in held)
    # appearance rows kept in tracklet points (views of the detections' arrays when not copied)
    app = sum((p.hist.nbytes if p.hist is not None else 0) + (p.desc.nbytes if p.desc is not None
              else 0) for t in held for p in t.points)
    regs = sum(sum(v.nbytes for v in vars(r).values() if isinstance(v, np.ndarray))
               for r in pipe.registrations.values())
    return {"tracklet_appearance_mb": round(app / 2**20, 2),
            "registrations_array_mb": round(regs / 2**20, 2),"detections_frames": len(pipe.detections), "detections": n_det,
            "detections_array_mb": round(det_bytes / 2**20, 2),
            "detections_array_mb_by_field": {k: round(v / 2**20, 2) for k, v in per_field.items()},
            "registrations": len(pipe.registrations), "tracklets": len(pipe.tracklets),
            "tracklets_in_memory": len(held), "tracklet_points_in_memory": points}


# -- children -------------------------------------------------------------------------------------
def child_speed(size: str, n: int, seed: int = 0, repeats: int | None = None) -> dict:
    """One frame size: render ``n`` frames, warm up (imports, numba compilation) on the first 10,
    then run the pipeline and the naive floor alternately ``repeats`` times (2 below 4000x3000)
    and keep the best run of each: on a shared machine a burst of load then does not decide the
    ratio. Wall and CPU seconds (``process_time``, all threads) are both recorded."""
    from aerotrack.config import Config
    from aerotrack.pipeline import Pipeline

    W, H = (int(v) for v in size.split("x"))
    repeats = repeats or (1 if W * H > 1920 * 1080 else 2)
    sc, geomap = _scene(seed, n, (W, H), FPS)
    t0 = time.perf_counter()
    frames, H1 = [], None
    for frame, Hm, _ in sc.frames():
        frames.append(frame)
        H1 = Hm if H1 is None else H1
    render_s = time.perf_counter() - t0
    warm = Pipeline(Config(), FPS, geomap=geomap, H_init=H1)  # imports, numba JIT, caches
    for f in frames[:10]:
        warm.step(f)
    warm.finish()
    del warm
    best = naive_best = None
    walls, naive_walls = [], []
    for _ in range(repeats):
        pipe = Pipeline(Config(), FPS, geomap=geomap, H_init=H1)
        t0, c0 = time.perf_counter(), time.process_time()
        for f in frames:
            pipe.step(f)
        res = pipe.finish()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        walls.append(wall)
        if best is None or wall < best[0]:
            best = (wall, cpu, res)
        c0 = time.process_time()
        naive_s, blobs = naive_opencv(frames)
        naive_walls.append(naive_s)
        if naive_best is None or naive_s < naive_best[0]:
            naive_best = (naive_s, time.process_time() - c0, blobs)
        del pipe, res
    wall, cpu, res = best
    naive_s, naive_cpu, blobs = naive_best
    st = res.timings
    out = {"frames": n, "render_s_per_frame": render_s / n, "repeats": repeats,
           "fps": {k: (n / st[k] if st.get(k) else None)
                   for k in ("registration", "detection", "association", "linking")},
           "stage_s": st, "wall_s": wall, "wall_s_runs": walls, "cpu_s": cpu,
           "detections": sum(len(d) for d in res.detections),
           "tracks": len(res.tracks), "naive_opencv_s": naive_s, "naive_opencv_s_runs": naive_walls,
           "naive_opencv_cpu_s": naive_cpu, "naive_opencv_blobs": blobs,
           "peak_rss_mb": _peak_mb()}
    out["fps"]["pipeline"] = n / wall
    out["fps"]["naive_opencv"] = n / naive_s
    # frames per CPU second: what a core gives each stage, whatever else runs on the machine
    cst = getattr(res, "cpu_timings", {}) or {}
    out["stage_cpu_s"] = cst
    out["fps_cpu"] = {k: (n / cst[k] if cst.get(k) else None)
                      for k in ("registration", "detection", "association", "linking")}
    out["fps_cpu"]["pipeline"] = n / cpu
    out["fps_cpu"]["naive_opencv"] = n / naive_cpu if naive_cpu > 0 else None
    out["pipeline_vs_naive"] = out["fps"]["pipeline"] / out["fps"]["naive_opencv"]
    out["pipeline_vs_naive_cpu"] = naive_cpu / cpu
    return out


def child_memory(minutes: float, fps: float, seed: int = 0, generator_only: bool = False) -> dict:
    """Stream ``minutes`` of 960x540 video from the generator into the pipeline (nothing on
    disk); peak RSS, RSS at each tenth of the run, and what the pipeline holds at the end."""
    from aerotrack.config import Config
    from aerotrack.pipeline import Pipeline

    n = round(minutes * 60 * fps)
    sc, geomap = _scene(seed, n, (960, 540), fps)
    samples = []
    start_rss = _rss_mb()
    pipe = None
    t0 = time.perf_counter()
    for frame, Hm, _ in sc.frames():
        if not generator_only:
            if pipe is None:
                pipe = Pipeline(Config(), fps, geomap=geomap, H_init=Hm)
            pipe.step(frame)
        if frame.index % max(1, n // 10) == 0:
            samples.append({"frame": frame.index, "minutes": round(frame.index / fps / 60, 3),
                            "rss_mb": round(_rss_mb(), 1)})
    out = {"minutes": minutes, "fps": fps, "frames": n, "rss_start_mb": round(start_rss, 1),
           "rss_samples": samples}
    if pipe is not None:
        before = _rss_mb()
        out["held_before_linking"] = held_bytes(pipe)
        out["rss_before_finish_mb"] = round(before, 1)
        out["peak_rss_before_finish_mb"] = round(_peak_mb(), 1)
        try:  # others edit the stages while this runs: keep the streaming numbers if linking fails
            res = pipe.finish()
        except Exception as exc:  # noqa: BLE001 - recorded, not hidden
            out["finish_error"] = f"{type(exc).__name__}: {exc}"
            out["stage_s"] = pipe.timings
        else:
            out["rss_after_finish_mb"] = round(_rss_mb(), 1)
            out["tracks"] = len(res.tracks)
            out["stage_s"] = res.timings
    out["wall_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = round(_peak_mb(), 1)
    return out


def child_association(sizes: list[int], n_frames: int) -> dict:
    from association import speed

    from aerotrack.config import AssociationConfig

    return speed(AssociationConfig(), sizes, n_frames, peers=True)


def _child(kind: str, args: dict, env: dict | None = None) -> dict:
    """Run ``kind`` in a fresh interpreter; returns its JSON (or an error record)."""
    WORK.mkdir(parents=True, exist_ok=True)
    out = WORK / f"suite-{kind}-{os.getpid()}.json"
    cmd = [sys.executable, __file__, "--child", kind, "--args", json.dumps(args), "--out", str(out)]
    load = os.getloadavg()[0]
    r = subprocess.run(cmd, env={**os.environ, **(env or {})}, capture_output=True, text=True,
                       check=False)
    if r.returncode != 0:
        msg = (r.stderr.strip().splitlines() or ["?"])[-1]
        print(f"  {kind} {args}: FAILED: {msg}", file=sys.stderr)
        return {"error": msg, "load_avg_1min_at_start": load}
    d = json.loads(out.read_text())
    out.unlink()
    d["load_avg_1min_at_start"] = load
    return d


# -- parts ----------------------------------------------------------------------------------------
def part_speed(sizes: dict[str, int]) -> dict:
    out = {}
    for size, n in sizes.items():
        print(f"speed {size} ({n} frames)...", file=sys.stderr, flush=True)
        out[size] = _child("speed", {"size": size, "n": n})
    return out


def part_association(quick: bool) -> dict:
    print("association vs peers...", file=sys.stderr, flush=True)
    sizes, n = ([20, 50], 100) if quick else ([20, 50, 150], 300)
    return _child("association", {"sizes": sizes, "n_frames": n})


def part_memory(minutes: list[float], fps: float, quick: bool) -> dict:
    out = {"fps": fps, "size": "960x540", "runs": {}}
    if not quick:
        print("memory: 60 s at 30 frames/s...", file=sys.stderr, flush=True)
        out["60s_at_30fps"] = _child("memory", {"minutes": 1.0, "fps": 30.0})
        print("memory: generator alone, 1 min...", file=sys.stderr, flush=True)
        out["generator_only_1min"] = _child("memory", {"minutes": 1.0, "fps": fps,
                                                       "generator_only": True})
    for m in minutes:
        print(f"memory: {m:g} min at {fps:g} frames/s...", file=sys.stderr, flush=True)
        out["runs"][f"{m:g}"] = _child("memory", {"minutes": m, "fps": fps})
    runs = [r for r in out["runs"].values() if "peak_rss_mb" in r]
    if len(runs) >= 2:
        out["growth_first_to_last"] = runs[-1]["peak_rss_mb"] / runs[0]["peak_rss_mb"] - 1
    return out


def part_dask(frames: int, size: str, fps: float, gsd: float = 0.3) -> dict:
    """``benchmarks/parallel.py``'s four modes, once each, in fresh processes (its own functions:
    ``make_video`` and ``--run MODE``)."""
    from parallel import MODES, THREAD_ENV, make_video

    wh = tuple(int(v) for v in size.split("x"))
    folder = WORK / f"parallel-synth-{frames}-{wh[0]}x{wh[1]}-{fps:g}"
    print(f"dask: video {frames} frames {size}...", file=sys.stderr, flush=True)
    info = make_video(folder, frames, wh, fps)
    out = {"video": info, "modes": {}}
    for mode in MODES:
        print(f"dask: {mode}...", file=sys.stderr, flush=True)
        res = folder / f"suite-run-{mode}.json"
        env = dict(os.environ)
        if mode != "single":
            env.update(THREAD_ENV)
        load = os.getloadavg()[0]
        cmd = [sys.executable, str(Path(__file__).parent / "parallel.py"), "--run", mode,
               "--input", str(folder / "frames"), "--out", str(res), "--fps", str(fps),
               "--gsd", str(gsd)]
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        if r.returncode != 0:
            out["modes"][mode] = {"error": (r.stderr.strip().splitlines() or ["?"])[-1]}
            continue
        d = json.loads(res.read_text())
        out["modes"][mode] = {"wall_s": d["wall_s"], "startup_s": d["startup_s"],
                              "frames_per_s": frames / d["wall_s"],
                              "segments": d["join"]["segments"], "load_avg_1min_at_start": load}
    base = out["modes"].get("single-1t", {}).get("wall_s")
    for d in out["modes"].values():
        if base and "wall_s" in d:
            d["wall_vs_single_1t"] = d["wall_s"] / base
            d["speedup_vs_single_1t"] = base / d["wall_s"]
    return out


# -- table ----------------------------------------------------------------------------------------
def _f(v, fmt="6.1f") -> str:
    if isinstance(v, (int, float)):
        return format(v, fmt)
    width = int(re.match(r"\d*", fmt).group() or 1)
    return "-".rjust(width)


def print_table(results: dict) -> None:
    sp = results.get("speed")
    if sp:
        print("\nSpeed, frames/s (wall clock, best of the repeats; generated 30 frames/s scene "
              "against its map; cpu ratio = naive CPU s / pipeline CPU s)")
        print(f"{'size':10} {'frames':>6} {'reg':>6} {'det':>6} {'assoc':>7} {'link':>7} "
              f"{'PIPE':>6} {'naive':>6} {'pipe/naive':>10} {'cpu ratio':>9} {'load':>5}")
        def area(kv):
            w, h = kv[0].split("x")
            return int(w) * int(h)

        for size, r in sorted(sp.items(), key=area):
            if "error" in r:
                print(f"{size:10} failed: {r['error']}")
                continue
            f = r["fps"]
            print(f"{size:10} {r['frames']:6d} {_f(f['registration'])} {_f(f['detection'])} "
                  f"{_f(f['association'], '7.0f')} {_f(f['linking'], '7.0f')} {_f(f['pipeline'])} "
                  f"{_f(f['naive_opencv'])} {r['pipeline_vs_naive']:10.2f} "
                  f"{_f(r.get('pipeline_vs_naive_cpu'), '9.2f')} {r['load_avg_1min_at_start']:5.1f}")
        if any("fps_cpu" in r for r in sp.values()):
            print("\nSpeed, frames per CPU second (CPU seconds of the process in each stage: "
                  "the single-core rate, whatever the load)")
            print(f"{'size':10} {'reg':>6} {'det':>6} {'assoc':>7} {'link':>7} {'PIPE':>6} "
                  f"{'naive':>6} {'pipe/naive':>10}")
            for size, r in sorted(sp.items(), key=area):
                if "fps_cpu" not in r:
                    continue
                f = r["fps_cpu"]
                print(f"{size:10} {_f(f['registration'])} {_f(f['detection'])} "
                      f"{_f(f['association'], '7.0f')} {_f(f['linking'], '7.0f')} "
                      f"{_f(f['pipeline'])} {_f(f['naive_opencv'])} "
                      f"{_f(r.get('pipeline_vs_naive_cpu'), '10.2f')}")
    a = results.get("association")
    if a and "error" not in a:
        print("\nAssociation alone, frames/s (ratio to ByteTrack in brackets)")
        labels = list(next(iter(v for k, v in a.items() if k.isdigit())))
        print(f"{'objects':>8} " + " ".join(f"{lab:>18}" for lab in labels))
        for n, row in sorted(((k, v) for k, v in a.items() if k.isdigit()),
                             key=lambda kv: int(kv[0])):
            bt = row.get("ByteTrack")
            cells = [f"{row[lab]:9.0f} ({row[lab] / bt:5.2f})" if bt else f"{row[lab]:18.0f}"
                     for lab in labels]
            print(f"{n:>8} " + " ".join(f"{c:>18}" for c in cells))
    m = results.get("memory")
    if m:
        print(f"\nPeak memory, 960x540 streamed from the generator ({m['fps']:g} frames/s)")
        print(f"{'video':22} {'frames':>7} {'peak MB':>8} {'RSS pre-link':>12} {'dets held':>9} "
              f"{'det MB':>7} {'regs':>6} {'wall s':>7}")
        rows = [(f"{k} min", v) for k, v in sorted(m["runs"].items(),
                                                    key=lambda kv: float(kv[0]))]
        if "60s_at_30fps" in m:
            rows.insert(0, ("60 s at 30 frames/s", m["60s_at_30fps"]))
        if "generator_only_1min" in m:
            rows.insert(0, ("generator alone 1 min", m["generator_only_1min"]))
        for name, r in rows:
            if "error" in r:
                print(f"{name:22} failed: {r['error']}")
                continue
            h = r.get("held_before_linking", {})
            print(f"{name:22} {r['frames']:7d} {r['peak_rss_mb']:8.0f} "
                  f"{_f(r.get('rss_before_finish_mb'), '12.0f')} {_f(h.get('detections'), '9d')} "
                  f"{_f(h.get('detections_array_mb'), '7.1f')} {_f(h.get('registrations'), '6d')} "
                  f"{r['wall_s']:7.0f}")
        if "growth_first_to_last" in m:
            print(f"growth of peak RSS, first to last length: {100 * m['growth_first_to_last']:.1f} %"
                  " (goal < 10 % from 1 to 10 min)")
    d = results.get("dask")
    if d:
        print(f"\nDask ({d['video']['frames']} frames {d['video']['size'][0]}x"
              f"{d['video']['size'][1]} at {d['video']['fps']:g} frames/s; ratio to single-1t)")
        for mode, r in d["modes"].items():
            if "error" in r:
                print(f"{mode:10} failed: {r['error']}")
                continue
            print(f"{mode:10} wall {r['wall_s']:6.1f} s  x{r.get('wall_vs_single_1t', 0):5.2f}  "
                  f"{r['frames_per_s']:5.1f} frames/s  segments {r['segments']}  "
                  f"load {r['load_avg_1min_at_start']:.1f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="640x480 and 1280x720 only, few frames, 2 association sizes, memory at "
                         "0.5 and 1 min, no Dask (a couple of minutes)")
    ap.add_argument("--only", default="speed,association,memory,dask")
    ap.add_argument("--minutes", default=None, help="video lengths for memory (default 1,5,10)")
    ap.add_argument("--memory-fps", type=float, default=2.0)
    ap.add_argument("--dask-frames", type=int, default=600)
    ap.add_argument("--update", action="store_true",
                    help="Re-run only the --only parts into the existing suite.json")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--args", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        fn = {"speed": child_speed, "memory": child_memory,
              "association": child_association}[a.child]
        Path(a.out).write_text(json.dumps(fn(**json.loads(a.args)), default=float))
        return
    parts = a.only.split(",")
    minutes = ([float(v) for v in a.minutes.split(",")] if a.minutes
               else ([0.5, 1.0] if a.quick else [1.0, 5.0, 10.0]))
    results: dict = {"quick": a.quick, "cpu_count": os.cpu_count(),
                     "started_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())}
    previous = RESULTS / "suite.json"
    if a.update and previous.exists():
        results = {**json.loads(previous.read_text()), "updated_utc": results["started_utc"]}
    def save() -> Path:
        if a.quick:  # keep the committed full results; the quick subset goes to scratch
            WORK.mkdir(parents=True, exist_ok=True)
            path = WORK / "suite-quick.json"
            path.write_text(json.dumps(results, indent=2, sort_keys=True, default=float) + "\n")
            return path
        return write_results("suite", results)

    if "speed" in parts:
        results["speed"] = part_speed(QUICK_SIZES if a.quick else SIZES)
        save()
    if "association" in parts:
        results["association"] = part_association(a.quick)
        save()
    if "memory" in parts:
        mem = part_memory(minutes, a.memory_fps, a.quick)
        if a.update and "memory" in results and results["memory"]["fps"] != mem["fps"]:
            mem["previous_stream"] = {k: results["memory"][k] for k in ("fps", "runs")}
        elif a.update and "memory" in results:
            old = results["memory"]
            for k in set(old["runs"]) - set(mem["runs"]):  # kept, but measured by an earlier run
                old["runs"][k]["from_earlier_suite_run"] = True
            old["runs"].update(mem["runs"])
            old.update({k: mem[k] for k in ("60s_at_30fps", "generator_only_1min") if k in mem})
            old["runs"] = dict(sorted(old["runs"].items(), key=lambda kv: float(kv[0])))
            ok = [r for r in old["runs"].values() if "peak_rss_mb" in r]
            if len(ok) >= 2:
                old["growth_first_to_last"] = ok[-1]["peak_rss_mb"] / ok[0]["peak_rss_mb"] - 1
            mem = old
        results["memory"] = mem
        save()
    if "dask" in parts and not a.quick:
        results["dask"] = part_dask(a.dask_frames, "480x270", 15.0)
    results["load_avg_1min_at_end"] = os.getloadavg()[0]
    path = save()
    print_table(results)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()

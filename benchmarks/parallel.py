"""Segment-parallel speed-up on Dask against the single process, with HOTA/IDF1 of each (issue 8).

On one long generated video (``aerotrack synth`` when available, else a built-in scene: the bundled
map tile under a drifting camera with cars driving straight), each configuration runs in a fresh
process:

* ``single``: the single process as it runs by default (OpenCV/BLAS thread pools as they come);
* ``single-1t``: the single process with OpenCV/OpenMP/BLAS/numba limited to one thread (the
  baseline of the speed ratios);
* ``dask-1``, ``dask-2``: ``aerotrack.parallel`` on a LocalCluster of 1 and 2 worker processes, one
  thread each, at least one segment per worker (``dask-2-sym``, on request: the earlier symmetric
  overlap).

Wall time counts reading, every stage, the join and linking; for Dask it excludes starting the
cluster (reported apart, ``cluster_startup_s``, with the workers' and the client's warm-up), and for
the single process the same warm-up (imports and numba code loaded, ``cluster_startup_s`` too), so
that neither pays for loading code. ``total_vs_single_1t_median`` compares start-up plus run. HOTA/IDF1 are against the generator's ground truth, and "agreement" is
HOTA/IDF1 of each run's tracks taking ``single-1t``'s tracks as ground truth.

Usage::

    /tmp/venv/bin/python benchmarks/parallel.py [--frames 1800] [--size 480x270] [--fps 15] \
        [--repeat 2] [--video mp4|frames]

The input is an MPEG-4 video encoded from the generated frames (``--video mp4``, the default: what
users process; segments seek into it) or the folder of JPEG frames (``--video frames``).
For Dask runs, ``timeline`` in the JSON (and the "where the time goes" lines) splits the wall time:
task start on the workers, each segment's end, its result's arrival, the client's join and linking.

Each mode runs ``--repeat`` times, interleaved, and the fastest run counts: on a shared machine
other processes only ever slow a run down. With Linux's autogroup scheduling (``autogroup`` in the
JSON) every session gets an equal share of the CPU however many processes it runs, so while other
sessions keep the cores busy two workers get no more CPU than one process and wall ratios say
nothing about the parallelism (measured at load 7.5-13.6: dask-2 1.03x single-1t, while the CPU
critical path was 0.633x); ``cpu x 1t`` (the slowest segment's CPU seconds plus the join and
linking, against the single process's CPU seconds) is then the estimate of the wall ratio on an
idle machine. The 1-minute load average at each run's start is
recorded, since on a loaded 2-core machine two workers cannot get two cores.

Prints a table and writes benchmarks/results/parallel.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from common import REPO, WORK, generator_version, write_results

if TYPE_CHECKING:  # numpy is imported where used (the parent process stays light)
    import numpy as np

THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "NUMEXPR_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
MODES = ("single", "single-1t", "dask-1", "dask-2")
#: Extra modes (``--modes``), dask-N-NAME: dask-N with other overlaps. ``sym``: the earlier
#: symmetric overlap (4.5 s each side of the cut instead of a 4.5 s lead and a 3.5 s tail), to
#: measure what the shorter tail costs; ``lead6``: a 6 s lead (does a longer warm-up matter?).
OVERLAPS = {"sym": {"overlap_s": 9.0, "tail_s": 4.5}, "lead6": {"overlap_s": 9.5, "tail_s": 3.5}}
TILE = REPO / "src/aerotrack/synth/data/vegas_tile.tif"


# -- the video ------------------------------------------------------------------------------------
def make_video(folder: Path, n: int, size: tuple[int, int], fps: float,
               scenario: str = "default", seed: int = 0) -> dict:
    """Frames and ground truth in ``folder`` (reused when already there and made by the same
    generator code); returns how they were made."""
    meta = folder / "bench-meta.json"
    version = generator_version()
    if meta.exists():
        info = json.loads(meta.read_text())
        if (info.get("frames") == n and info.get("size") == list(size) and info.get("fps") == fps
                and info.get("scenario", "default") == scenario
                and info.get("scene_seed", 0) == seed and info.get("generator_version") == version):
            return info
    if folder.exists():  # another scene, or made by other generator code; synth --overwrite
        shutil.rmtree(folder)  # would refuse the benchmark's own files (video.mp4, run-*.json)
    folder.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "aerotrack", "synth", "--out", str(folder), "--frames", str(n),
           "--size", f"{size[0]}x{size[1]}", "--fps", f"{fps:g}", "--scenario", scenario,
           "--seed", str(seed)]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if r.returncode != 0 or not (folder / "frames").is_dir() or not (folder / "gt.txt").is_file():
        # No stand-in scene: a fallback with other content made accuracy columns meaningless.
        sys.exit(f"benchmark: aerotrack synth failed for {folder}: "
                 + (r.stderr.strip().splitlines() or ["no message"])[-1][:200])
    generator = "aerotrack synth"
    info = {"frames": n, "size": list(size), "fps": fps, "generator": generator,
            "scenario": scenario, "scene_seed": seed, "generator_version": version}
    meta.write_text(json.dumps(info))
    return info


# -- one configuration, in its own process ---------------------------------------------------------
def encode_mp4(frames: Path, out: Path, fps: float) -> Path:
    """``frames`` (a folder of images) as an MPEG-4 part 2 video ``out`` (reused when there)."""
    import cv2

    if out.is_file() and out.stat().st_size > 0:
        return out
    files = sorted(p for p in frames.iterdir() if p.suffix.lower() in (".jpg", ".png"))
    h, w = cv2.imread(str(files[0])).shape[:2]
    tmp = out.with_suffix(".tmp.mp4")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        sys.exit(f"benchmark: cannot encode {tmp} (no MPEG-4 encoder); use --video frames")
    for p in files:
        writer.write(cv2.imread(str(p)))
    writer.release()
    tmp.rename(out)
    return out


def run_mode(mode: str, frames: Path, fps: float, gsd: float, out: Path, seed: int = 0) -> None:
    import cv2

    if mode != "single":
        cv2.setNumThreads(1)
    from aerotrack.io import open_source
    from aerotrack.outputs import track_rows

    src = open_source(frames, fps)
    startup = 0.0
    if mode.startswith("dask"):
        from aerotrack.parallel import ParallelConfig, dask_client, run_parallel

        workers = int(mode.split("-")[1])
        parallel = ParallelConfig(min_segments=workers,
                                  **OVERLAPS.get(mode.split("-")[-1], {}))
        t0 = time.perf_counter()
        with dask_client(workers=workers) as client:
            client.wait_for_workers(workers)
            startup = time.perf_counter() - t0
            t0 = time.perf_counter()
            result, report = run_parallel(src, client=client, metres_per_unit=gsd, seed=seed,
                                          with_report=True, parallel=parallel)
            wall = time.perf_counter() - t0
        join = {"segments": len(report.world_rms) + 1, "world_rms": report.world_rms,
                "stitched": report.stitched, "cut": report.cut,
                "plan": [[g.start, g.stop, g.own_start, g.own_stop] for g in report.segments],
                "segment_wall_s": report.segment_wall_s, "segment_cpu_s": report.segment_cpu_s,
                "timeline": report.timeline}
        # CPU seconds on the critical path: the slowest segment, then the client's join and
        # linking (a wall-time estimate for an idle machine with a core per worker)
        cpu = max(report.segment_cpu_s) + result.timings["join"] + result.timings["linking"]
    else:
        from aerotrack.parallel import warm_up_linking, warm_up_worker
        from aerotrack.pipeline import run

        # measured the same way as Dask, whose workers and client warm up while the cluster
        # starts: imports and numba's compiled code (recompiled when a numba function's source
        # changed since the last run: then seconds) are loaded before the clock starts
        t0 = time.perf_counter()
        warm_up_worker()
        warm_up_linking()
        startup = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        result = run(src, metres_per_unit=gsd, seed=seed)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        join = {"segments": 1}
    rows = track_rows(result, None)[0]
    dets = [[d.frame] + [round(float(v), 2) for v in d.boxes.ravel()] for d in result.detections]
    out.write_text(json.dumps({"wall_s": wall, "cpu_path_s": cpu, "startup_s": startup,
                               "timings": result.timings,
                               "join": join, "rows": rows.tolist(), "detections": dets}))


def _match_ids(base: np.ndarray, rows: np.ndarray, iou_min: float = 0.5) -> dict:
    """(frame, base id) -> id of ``rows`` for boxes matched in the same frame (Hungarian on IoU)."""
    import numpy as np
    from scipy.optimize import linear_sum_assignment

    out = {}
    by_frame: dict[int, list] = {}
    for r in rows:
        by_frame.setdefault(int(r[0]), []).append(r)
    for f in np.unique(base[:, 0]).astype(int):
        a = base[base[:, 0] == f]
        b = np.asarray(by_frame.get(int(f), []))
        if not len(b):
            continue
        x0 = np.maximum(a[:, None, 2], b[None, :, 2])
        y0 = np.maximum(a[:, None, 3], b[None, :, 3])
        x1 = np.minimum(a[:, None, 2] + a[:, None, 4], b[None, :, 2] + b[None, :, 4])
        y1 = np.minimum(a[:, None, 3] + a[:, None, 5], b[None, :, 3] + b[None, :, 5])
        inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
        union = (a[:, None, 4] * a[:, None, 5] + b[None, :, 4] * b[None, :, 5] - inter)
        iou = inter / np.maximum(union, 1e-9)
        ri, ci = linear_sum_assignment(-iou)
        for i, j in zip(ri, ci):
            if iou[i, j] >= iou_min:
                out[(int(f), int(a[i, 1]))] = int(b[j, 1])
    return out


def _identity_changes(base, rows, frame: int, w: int) -> tuple[int, int]:
    """Tracks of ``base`` seen within ``w`` frames on both sides of ``frame`` whose matched id in
    ``rows`` changes there (split), and the reverse (merged: one id of ``rows`` over two of
    ``base``)."""
    import numpy as np

    def changes(a, b):
        m = _match_ids(a, b)
        n = 0
        for tid in np.unique(a[:, 1]).astype(int):
            before = [m[(f, tid)] for f in range(frame - w, frame + 1) if (f, tid) in m]
            after = [m[(f, tid)] for f in range(frame + 1, frame + w + 1) if (f, tid) in m]
            if before and after and max(set(before), key=before.count) != max(
                    set(after), key=after.count):
                n += 1
        return n

    lo, hi = frame - w, frame + w
    a = base[(base[:, 0] >= lo) & (base[:, 0] <= hi)]
    b = rows[(rows[:, 0] >= lo) & (rows[:, 0] <= hi)]
    if not len(a) or not len(b):
        return 0, 0
    return changes(a, b), changes(b, a)


def join_differences(base: dict, run: dict, fps: float, window_s: float = 5.0) -> dict:
    """Where a segmented run differs from the single process (``base``), per join.

    For each cut (the last frame a segment owns): tracks split there (one track of the single
    process, two ids in the run within ``window_s`` either side) and merged there (the reverse);
    the same at the middle of each segment's owned range, as the rate away from joins. Detections:
    frames whose boxes differ from the single process's in each segment, and the first such frame
    after the segment's start.
    """
    import numpy as np

    brows = np.asarray(base["rows"]).reshape(-1, 10)
    rows = np.asarray(run["rows"]).reshape(-1, 10)
    w = max(1, round(window_s * fps))
    plan = run["join"].get("plan") or []
    bdet = {int(d[0]): d[1:] for d in base.get("detections", [])}
    rdet = {int(d[0]): d[1:] for d in run.get("detections", [])}
    differ = sorted(f for f in set(bdet) | set(rdet) if bdet.get(f) != rdet.get(f))
    out = {"joins": [], "segments": []}
    for k, (start, stop, own0, own1) in enumerate(plan):
        mid = (own0 + own1) // 2
        split, merged = _identity_changes(brows, rows, mid, w)
        mine = [f for f in differ if own0 <= f <= own1]
        out["segments"].append({
            "reads": [start, stop], "owns": [own0, own1],
            "frames_with_other_detections": len(mine),
            "first_other_detections_s_after_own_start":
                round((mine[0] - own0) / fps, 2) if mine else None,
            "mid_frame": mid, "split_at_mid": split, "merged_at_mid": merged})
        if k + 1 < len(plan):
            split, merged = _identity_changes(brows, rows, own1, w)
            out["joins"].append({"cut": own1, "split": split, "merged": merged,
                                 "stitched": run["join"]["stitched"][k],
                                 "cut_unmatched": run["join"]["cut"][k]})
    return out


def where_time_goes(run: dict, single_1t_wall: float | None, frames: int) -> dict:
    """One Dask run's wall time split along its timeline (seconds): planning and submitting,
    the slowest segment's task, how much earlier the other segment ended (imbalance), the last
    result's transfer to the client, the join, global linking; ``ideal_s``: the single process's
    wall time scaled to the frames the largest segment reads (perfect parallelism, no join)."""
    tl = run["join"].get("timeline") or {}
    if not tl.get("ended"):
        return {}
    plan = run["join"].get("plan") or []
    reads = max((stop - start + 1 for start, stop, _, _ in plan), default=frames)
    last_end, last_recv = max(tl["ended"]), max(tl["received"])
    return {
        "before_tasks_s": round(run["wall_s"] - tl["linked"] + min(tl["started"]), 3),
        "slowest_task_s": round(last_end - min(tl["started"]), 3),
        "imbalance_s": round(last_end - min(tl["ended"]), 3),
        "result_transfer_s": round(last_recv - last_end, 3),
        "join_s": round(tl["joined"] - last_recv, 3),
        "linking_s": round(tl["linked"] - tl["joined"], 3),
        "client_cpu_s": tl.get("client_cpu_s"),
        "largest_segment_reads_frames": reads,
        "ideal_s": round(single_1t_wall * reads / frames, 3) if single_1t_wall else None}


def association_parity(frames: int = 450, fps: float = 30.0) -> dict:
    """Segments against the single process on known detections (association and linking alone):
    ``common.synthetic_dets`` with 10 and 30 targets, 2 segments run in this process (the engine
    does not change results), HOTA/IDF1 against the true ids; the single process with another
    MCMC seed shows how much the random stream alone moves them."""
    from common import synthetic_dets

    from aerotrack.config import Config
    from aerotrack.evaluation import evaluate
    from aerotrack.outputs import track_rows
    from aerotrack.parallel import ParallelConfig, assemble, gather_segments, make_tasks, phase_period, plan_segments
    from aerotrack.pipeline import run

    out = {}
    config = Config()
    for n in (10, 30):
        gt = synthetic_dets(n, n_frames=frames, size=(1280, 720))
        dets = gt.copy()
        dets[:, 1] = -1
        single = run(None, detections=dets, fps=fps, config=config)
        segs = plan_segments(1, frames, fps=fps, segment_s=frames / fps / 2,
                             overlap_s=ParallelConfig().overlap(config),
                             tail_s=ParallelConfig().tail(config), min_segments=2,
                             align=phase_period(config, fps))
        tasks = make_tasks(None, config=config, fps=fps, segments=segs, detections=dets)
        par, report = assemble(gather_segments(None, tasks), config=config, fps=fps)
        other = run(None, detections=dets, fps=fps, config=config, seed=1)
        es, ep, eo = (evaluate(gt, track_rows(r, None)[0]) for r in (single, par, other))
        out[f"{n}_targets"] = {
            "segments": len(segs), "stitched": report.stitched, "cut": report.cut,
            "single": {"HOTA": round(es["HOTA"], 4), "IDF1": round(es["IDF1"], 4)},
            "segments_run": {"HOTA": round(ep["HOTA"], 4), "IDF1": round(ep["IDF1"], 4)},
            "delta_HOTA": round(ep["HOTA"] - es["HOTA"], 4),
            "delta_IDF1": round(ep["IDF1"] - es["IDF1"], 4),
            "single_seed1": {"HOTA": round(eo["HOTA"], 4), "IDF1": round(eo["IDF1"], 4)}}
        print(f"association alone, {n} targets: single HOTA {es['HOTA']:.3f} IDF1 {es['IDF1']:.3f}"
              f" | 2 segments HOTA {ep['HOTA']:.3f} IDF1 {ep['IDF1']:.3f}"
              f" | single, seed 1: HOTA {eo['HOTA']:.3f} IDF1 {eo['IDF1']:.3f}")
    return out


def _autogroup() -> bool | None:
    """Whether the kernel shares the CPU per session (autogroup) rather than per process."""
    try:
        return Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip() == "1"
    except OSError:
        return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1800,
                    help="Video length; the stages now run at ~80 frames/s at 480x270, so a "
                         "shorter video is bound by Dask's fixed costs (~2-3 s).")
    ap.add_argument("--size", default="480x270")
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--gsd", type=float, default=0.3)
    ap.add_argument("--scenario", default="default",
                    help="aerotrack synth scenario (default, dense, ...); results of another "
                         "scenario go to parallel-SCENARIO.json")
    ap.add_argument("--scene-seed", type=int, default=0,
                    help="aerotrack synth --seed of the scene; results of another scene go to "
                         "parallel[-SCENARIO]-sceneN.json. The segments' accuracy differences come "
                         "from detections that differ after a segment's warm-up, which MCMC seeds "
                         "(--vary-seed) do not vary: compare several scenes.")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--video", choices=("mp4", "frames"), default="mp4",
                    help="Input: an MPEG-4 video encoded from the generated frames (default), or "
                         "the folder of JPEG frames.")
    ap.add_argument("--vary-seed", action="store_true",
                    help="Repetition k runs every mode with MCMC seed k: HOTA/IDF1 are then also "
                         "reported as means over seeds (one seed's difference between two runs "
                         "is as large as the segments' own; see registration_seeds.py).")
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--repeat", type=int, default=2,
                    help="Runs of each mode, interleaved; the fastest counts (a shared machine's "
                         "load only ever slows a run down).")
    ap.add_argument("--no-association", dest="association", action="store_false",
                    help="Skip the association-alone parity table.")
    ap.add_argument("--run", help=argparse.SUPPRESS)  # internal: one mode in a child process
    ap.add_argument("--input", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.run:
        run_mode(a.run, Path(a.input), a.fps, a.gsd, Path(a.out), a.seed)
        return
    import numpy as np

    from aerotrack.evaluation import evaluate

    size = tuple(int(v) for v in a.size.lower().split("x"))
    tag = ("" if a.scenario == "default" else f"-{a.scenario}") \
        + ("" if a.scene_seed == 0 else f"-scene{a.scene_seed}")
    folder = WORK / f"parallel-synth{tag}-{a.frames}-{size[0]}x{size[1]}-{a.fps:g}"
    info = make_video(folder, a.frames, size, a.fps, a.scenario, a.scene_seed)
    source = folder / "frames"
    if a.video == "mp4":
        source = encode_mp4(source, folder / "video.mp4", a.fps)
    info = dict(info, input=a.video)
    gt = np.loadtxt(folder / "gt.txt", delimiter=",", ndmin=2)
    runs: dict[str, dict] = {}
    walls: dict[str, list[float]] = {}
    load = []
    per_rep: list[dict[str, float]] = []
    load_end = []
    by_rep: dict[int, dict[str, dict]] = {}
    for rep in range(a.repeat):
        per_rep.append({})
        for mode in a.modes.split(","):
            out = folder / f"run-{mode}.json"
            env = dict(os.environ)
            if mode != "single":
                env.update(THREAD_ENV)
            cmd = [sys.executable, __file__, "--run", mode, "--input", str(source),
                   "--out", str(out), "--fps", str(a.fps), "--gsd", str(a.gsd),
                   "--seed", str(rep if a.vary_seed else 0)]
            load.append(os.getloadavg()[0])
            subprocess.run(cmd, check=True, env=env)
            r = json.loads(out.read_text())
            walls.setdefault(mode, []).append(r["wall_s"])
            per_rep[-1][mode] = r["wall_s"]
            per_rep[-1][mode + ":cpu"] = r.get("cpu_path_s", float("nan"))
            load_end.append(os.getloadavg()[0])
            by_rep.setdefault(rep, {})[mode] = r
            if mode not in runs or (r["wall_s"] < runs[mode]["wall_s"] and not a.vary_seed):
                runs[mode] = r  # seed 0's run with --vary-seed (same seed as the baseline's)
            print(f"{mode} (run {rep + 1}): {r['wall_s']:.1f} s", file=sys.stderr)
    base = runs.get("single-1t") or next(iter(runs.values()))
    base_rows = np.asarray(base["rows"]).reshape(-1, 10)
    table = {}
    joins = {}
    for mode, r in runs.items():
        if r["join"].get("plan"):
            joins[mode] = join_differences(base, r, a.fps)
        rows = np.asarray(r["rows"]).reshape(-1, 10)
        e = evaluate(gt, rows)
        ag = evaluate(base_rows, rows)
        paired = [p[mode] / p["single-1t"] for p in per_rep if "single-1t" in p and mode in p]
        paired_default = [p[mode] / p["single"] for p in per_rep if "single" in p and mode in p]
        seeds = {k: evaluate(gt, np.asarray(v[mode]["rows"]).reshape(-1, 10))
                 for k, v in by_rep.items() if mode in v} if a.vary_seed else {}
        table[mode] = {
            "HOTA_per_seed": {k: round(v["HOTA"], 4) for k, v in seeds.items()},
            "IDF1_per_seed": {k: round(v["IDF1"], 4) for k, v in seeds.items()},
            "HOTA_mean_over_seeds": round(float(np.mean([v["HOTA"] for v in seeds.values()])), 4)
            if seeds else None,
            "IDF1_mean_over_seeds": round(float(np.mean([v["IDF1"] for v in seeds.values()])), 4)
            if seeds else None,
            "wall_s": round(min(walls[mode]), 2), "cluster_startup_s": round(r["startup_s"], 2),
            "wall_s_all_runs": [round(w, 2) for w in walls[mode]],
            "wall_vs_single_1t": round(min(walls[mode]) / min(walls["single-1t"]), 3)
            if "single-1t" in walls else None,
            "wall_vs_single": round(min(walls[mode]) / min(walls["single"]), 3)
            if "single" in runs else None,
            # each repetition's ratio (runs of one repetition are close in time, so they share
            # the machine's load more than the fastest runs of each mode do)
            "wall_vs_single_1t_per_rep": [round(x, 3) for x in paired],
            "wall_vs_single_1t_median": round(float(np.median(paired)), 3) if paired else None,
            "total_vs_single_1t_median": round(float(np.median(
                [(v[mode]["wall_s"] + v[mode]["startup_s"])
                 / (v["single-1t"]["wall_s"] + v["single-1t"]["startup_s"])
                 for v in by_rep.values() if mode in v and "single-1t" in v])), 3)
            if "single-1t" in runs else None,
            "wall_vs_single_median": round(float(np.median(paired_default)), 3)
            if paired_default else None,
            # load-independent: CPU seconds on the critical path (single: the process; Dask: the
            # slowest segment's worker, then join and linking), median over repetitions
            "cpu_path_s_all_runs": [round(p[mode + ":cpu"], 2) for p in per_rep
                                    if mode + ":cpu" in p],
            "cpu_path_vs_single_1t_median": round(float(np.median(
                [p[mode + ":cpu"] / p["single-1t:cpu"] for p in per_rep
                 if "single-1t:cpu" in p and mode + ":cpu" in p])), 3)
            if "single-1t" in runs else None,
            "frames_per_s": round(a.frames / min(walls[mode]), 2),
            "HOTA": round(e["HOTA"], 4), "IDF1": round(e["IDF1"], 4),
            "agreement_HOTA": round(ag["HOTA"], 4), "agreement_IDF1": round(ag["IDF1"], 4),
            "tracks": int(len(np.unique(rows[:, 1]))) if len(rows) else 0,
            "join": r["join"], "stage_s": {k: round(v, 2) for k, v in r["timings"].items()},
        }
    head = (f"{'mode':10} {'wall s':>8} {'x 1t':>6} {'x 1t med':>8} {'x def':>6} {'fr/s':>6} "
            f"{'cpu x 1t':>8} {'start s':>7} {'tot x 1t':>8} {'HOTA':>6} {'IDF1':>6} {'agrHOTA':>7} "
            f"{'agrIDF1':>7} {'tracks':>6} segs")
    print(f"video: {a.frames} frames {size[0]}x{size[1]} at {a.fps:g} fps ({info['generator']}); "
          f"1-min load average at run starts {min(load):.1f}-{max(load):.1f} on {os.cpu_count()} "
          "cores; x 1t: fastest run / fastest single-1t, x 1t med: median over repetitions of "
          "run / single-1t of the same repetition, x def: fastest / fastest single, cpu x 1t: "
          "CPU seconds on the critical path / single-1t's, median over repetitions. Wall times "
          "exclude the start (start s: Dask's cluster start with its workers' and client's "
          "warm-up; the single process's own warm-up); tot x 1t: (start + wall) / single-1t's, "
          "median over repetitions")
    print(head)
    for mode, t in table.items():
        med = t["wall_vs_single_1t_median"]
        vdef = t["wall_vs_single"]
        print(f"{mode:10} {t['wall_s']:8.1f} {t['wall_vs_single_1t']:6.3f} "
              f"{med if med is not None else float('nan'):8.3f} "
              f"{vdef if vdef is not None else float('nan'):6.3f} {t['frames_per_s']:6.1f} "
              f"{t['cpu_path_vs_single_1t_median'] or float('nan'):8.3f} "
              f"{t['cluster_startup_s']:7.2f} {t['total_vs_single_1t_median'] or float('nan'):8.3f} "
              f"{t['HOTA']:6.3f} {t['IDF1']:6.3f} {t['agreement_HOTA']:7.3f} "
              f"{t['agreement_IDF1']:7.3f} {t['tracks']:6d} {t['join']['segments']}")
    if a.vary_seed:
        print("HOTA / IDF1 per MCMC seed (repetition k: seed k), and the mean over seeds:")
        for mode, t in table.items():
            print(f"{mode:12} " + "  ".join(f"s{k} {t['HOTA_per_seed'][k]:.3f}/"
                                            f"{t['IDF1_per_seed'][k]:.3f}"
                                            for k in t["HOTA_per_seed"])
                  + f"  mean {t['HOTA_mean_over_seeds']:.3f}/{t['IDF1_mean_over_seeds']:.3f}")
    print("where the Dask wall time goes (median over repetitions, s; the cluster's start is "
          "excluded from every wall time above and reported apart): ideal = single-1t's wall "
          "scaled to the frames the largest segment reads")
    for mode, t in table.items():
        parts = [where_time_goes(v[mode], v.get("single-1t", {}).get("wall_s"), a.frames)
                 for v in by_rep.values() if mode in v]
        parts = [x for x in parts if x]
        if not parts:
            continue
        med = {k: round(float(np.median([x[k] for x in parts if x[k] is not None])), 3)
               for k in parts[0] if any(x[k] is not None for x in parts)}
        t["where_time_goes_median"] = med
        t["where_time_goes_per_rep"] = parts
        print(f"{mode:10} start {t['cluster_startup_s']:.2f} | " + ", ".join(
            f"{k.removesuffix('_s')} {v:g}" for k, v in med.items()))
    for mode, j in joins.items():
        print(f"{mode}: per join (cut frame: tracks split / merged there, within 5 s) "
              + "; ".join(f"{x['cut']}: {x['split']}/{x['merged']}" for x in j["joins"])
              + " | mid-segment: " + "; ".join(f"{x['mid_frame']}: {x['split_at_mid']}/"
                                               f"{x['merged_at_mid']}" for x in j["segments"])
              + " | frames with other detections per segment: "
              + ", ".join(str(x["frames_with_other_detections"]) for x in j["segments"]))
    assoc = association_parity() if a.association else {}
    payload = {"video": info, "cpu_count": os.cpu_count(), "repeat": a.repeat,
               "vary_seed": a.vary_seed,
               "association_alone": assoc,
               "load_avg_1min_at_starts": [round(v, 2) for v in load],
               "load_avg_1min_at_ends": [round(v, 2) for v in load_end], "runs": table,
               "autogroup": _autogroup(),
               "joins": joins,
               "note": "wall_vs_single_1t: wall time / single process limited to one thread; "
                       "Dask wall excludes cluster start-up (cluster_startup_s)"}
    path = write_results("parallel" + tag + ("" if a.video == "mp4" else "-frames"), payload)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

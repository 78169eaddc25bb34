"""Peer trackers (Roboflow ``trackers`` 2.6.1: SORT, ByteTrack, OC-SORT, BoT-SORT) on MOT detections.

``trackers`` 2.6.1 needs no PyTorch (its default dependencies are numpy, scipy, opencv-python,
supervision, rich, requests, pydeprecate; nothing conflicts with aerotrack's), so it is the ``bench``
extra (``pip install -e .[bench]``) and runs in-process. When it is not importable here,
:func:`run_peer` runs this file with the interpreter named by ``AEROTRACK_PEERS_PYTHON`` (default
``/tmp/venv-peers/bin/python``) instead.

Library use (other benchmarks)::

    from peers import PEERS, run_peer, uavdt_table
    info = run_peer("botsort", "dets.txt", "tracks.txt", fps=30, buffer_s=2.0)  # -> frames/s etc.
    table = uavdt_table(extra={"aerotrack": my_runner})   # my_runner(seq, dets_file, out_file, fps)

Script::

    /tmp/venv/bin/python benchmarks/peers.py                       # the UAVDT table (issue 5)
    /tmp/venv/bin/python benchmarks/peers.py run botsort DETS OUT --fps 30 --buffer-s 2

Settings: each peer's defaults (their lost-track buffer is 30 frames at 30 frames/s, 1 s), and the
same with a 2 s buffer (``lost_track_buffer`` is counted in 30-frames/s frames, so 2 s = 60). No
frames are given, so BoT-SORT's camera-motion compensation is skipped (it needs images). Rows of
unconfirmed tracks (``tracker_id == -1``) are not written: they are not tracker output.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
from common import UAVDT_FPS, UAVDT_SEQS, WORK, write_results

#: Registered peer names -> ``trackers`` class names.
PEERS = {"sort": "SORTTracker", "bytetrack": "ByteTrackTracker", "ocsort": "OCSORTTracker",
         "botsort": "BoTSORTTracker"}
PEER_LABELS = {"sort": "SORT", "bytetrack": "ByteTrack", "ocsort": "OC-SORT", "botsort": "BoT-SORT"}


def _load_dets(path: str | Path) -> np.ndarray:
    from aerotrack.io.mot import read_mot

    return read_mot(path, option="dets", strict=False)


def track_rows(name: str, dets: np.ndarray, fps: float, buffer_s: float | None = None
               ) -> tuple[np.ndarray, float, int]:
    """Run one peer on detection rows in memory.

    Parameters
    ----------
    name : str
        One of :data:`PEERS`.
    dets : (N, >=7) float array
        MOT rows ``frame, id, x, y, w, h, conf`` (frame pixels, 1-based frames; id ignored).
    fps : float
        Frame rate passed to the tracker.
    buffer_s : float, optional
        Lost-track buffer in seconds (default: the peer's own, 1 s).

    Returns
    -------
    tracks : (M, 10) float array
        MOT rows of confirmed tracks.
    seconds : float
        Wall time spent in the tracker (building its inputs and ``update``), file I/O excluded.
    n_frames : int
        Frames processed (1 .. last detection frame, empty frames included).
    """
    if name not in PEERS:
        raise ValueError(f"unknown peer {name!r}; choose from {', '.join(PEERS)}")
    import supervision as sv
    import trackers

    kwargs: dict = {"frame_rate": float(fps)}
    if buffer_s is not None:
        kwargs["lost_track_buffer"] = int(round(buffer_s * 30.0))  # counted in 30 fps frames
    tracker = getattr(trackers, PEERS[name])(**kwargs)
    dets = np.asarray(dets, float)
    n_frames = int(dets[:, 0].max()) if len(dets) else 0
    order = np.argsort(dets[:, 0], kind="stable")
    dets = dets[order]
    bounds = np.searchsorted(dets[:, 0], np.arange(1, n_frames + 2))
    out = []
    t0 = time.perf_counter()
    for f in range(1, n_frames + 1):
        d = dets[bounds[f - 1]:bounds[f]]
        if len(d):
            xyxy = np.column_stack([d[:, 2], d[:, 3], d[:, 2] + d[:, 4], d[:, 3] + d[:, 5]])
            det = sv.Detections(xyxy=xyxy, confidence=d[:, 6].copy(),
                                class_id=np.zeros(len(d), int))
        else:
            det = sv.Detections.empty()
        res = tracker.update(det)
        if len(res) and res.tracker_id is not None:
            ok = res.tracker_id >= 0
            if ok.any():
                b = res.xyxy[ok]
                conf = res.confidence[ok] if res.confidence is not None else np.ones(ok.sum())
                out.append(np.column_stack([
                    np.full(ok.sum(), f), res.tracker_id[ok], b[:, 0], b[:, 1], b[:, 2] - b[:, 0],
                    b[:, 3] - b[:, 1], conf, -np.ones((ok.sum(), 3))]))
    seconds = time.perf_counter() - t0
    tracks = np.vstack(out) if out else np.zeros((0, 10))
    return tracks, seconds, n_frames


def _can_import_trackers() -> bool:
    try:
        import supervision  # noqa: F401
        import trackers  # noqa: F401
    except ImportError:
        return False
    return True


def _peer_runner(name: str, buf: float | None) -> Runner:
    """A runner (seq, dets, out, fps) of peer ``name`` with track buffer ``buf`` seconds."""
    return lambda seq, d, o, fps: run_peer(name, d, o, fps, buf)


def run_peer(name: str, dets_file: str | Path, out_file: str | Path, fps: float,
             buffer_s: float | None = None) -> dict:
    """Run a peer tracker on a MOT detections file and write its tracks as MOT rows.

    Parameters
    ----------
    name : str
        ``sort``, ``bytetrack``, ``ocsort`` or ``botsort``.
    dets_file, out_file : path
        MOT detections in (id ignored), MOT tracks out (10 columns, confirmed tracks only).
    fps : float
        Frame rate of the sequence.
    buffer_s : float, optional
        Lost-track buffer in seconds; None keeps the peer's default (30 frames at 30 fps).

    Returns
    -------
    dict
        ``{"peer", "buffer_s", "frames", "seconds", "fps"}``; ``fps`` = frames per second of
        tracker time (file I/O excluded).
    """
    if not _can_import_trackers():
        py = os.environ.get("AEROTRACK_PEERS_PYTHON", "/tmp/venv-peers/bin/python")
        cmd = [py, str(Path(__file__).resolve()), "run", name, str(dets_file), str(out_file),
               "--fps", str(fps)] + ([] if buffer_s is None else ["--buffer-s", str(buffer_s)])
        done = subprocess.run(cmd, check=True, capture_output=True, text=True)
        return json.loads(done.stdout.strip().splitlines()[-1])
    from aerotrack.io.mot import write_mot

    tracks, seconds, n = track_rows(name, _load_dets(dets_file), fps, buffer_s)
    write_mot(out_file, tracks)
    return {"peer": name, "buffer_s": buffer_s, "frames": n, "seconds": seconds,
            "fps": n / seconds if seconds > 0 else float("inf")}


# --------------------------------------------------------------------------- the UAVDT table

Runner = Callable[[str, Path, Path, float], object]


def uavdt_table(seed: int = 0, *, workdir: Path | None = None,
                extra: Mapping[str, Runner] | None = None, peers: bool = True) -> dict:
    """Score the peers, the oracle and any ``extra`` trackers on the three UAVDT sequences.

    Parameters
    ----------
    seed : int
        Seed of :func:`uavdt_dets.make_detections`.
    workdir : path, optional
        Where detections and tracks are written (default ``$TMPDIR/aerotrack-bench/uavdt_peers``).
    extra : mapping label -> callable(seq, dets_file, out_file, fps)
        Further trackers to run on the same detection files; each must write MOT tracks to
        ``out_file``. Their wall time (file I/O included) is reported.
    peers : bool
        Run the four peers with default and 2 s buffers.

    Returns
    -------
    dict
        ``{label: {"combined": {...}, "sequences": {...}, "fps": frames/s, "seconds": s}}``,
        scores from :func:`aerotrack.evaluation.evaluate_sequences` against ``SEQ_gt.txt``.
    """
    from uavdt_dets import load_uavdt_mot, make_detections

    from aerotrack.evaluation import evaluate_sequences
    from aerotrack.io.mot import read_mot, write_mot

    workdir = Path(workdir or WORK / "uavdt_peers")
    workdir.mkdir(parents=True, exist_ok=True)
    gts, oracle, det_files = {}, {}, {}
    for seq in UAVDT_SEQS:
        dets, orc = make_detections(seq, seed)
        det_files[seq] = workdir / f"{seq}_dets.txt"
        write_mot(det_files[seq], dets)
        gts[seq], oracle[seq] = load_uavdt_mot(seq, "gt"), orc
    table = {"oracle": {**evaluate_sequences({s: (gts[s], oracle[s]) for s in UAVDT_SEQS}),
                        "fps": None, "seconds": None}}
    runners: dict[str, Runner] = {}
    if peers:
        for name in PEERS:
            for buf in (None, 2.0):
                label = f"{PEER_LABELS[name]}" + (" 2s" if buf else "")
                runners[label] = _peer_runner(name, buf)
    runners.update(extra or {})
    for label, fn in runners.items():
        preds, frames, seconds, inner = {}, 0, 0.0, True
        for seq in UAVDT_SEQS:
            out = workdir / f"{seq}_{label.replace(' ', '_')}.txt"
            t0 = time.perf_counter()
            info = fn(seq, det_files[seq], out, UAVDT_FPS)
            wall = time.perf_counter() - t0
            if isinstance(info, dict) and "seconds" in info:
                seconds += info["seconds"]
                frames += info["frames"]
            else:
                inner = False
                seconds += wall
                frames += int(gts[seq][:, 0].max())
            preds[seq] = read_mot(out, option=label, strict=True)
        res = evaluate_sequences({s: (gts[s], preds[s]) for s in UAVDT_SEQS})
        table[label] = {**res, "seconds": seconds, "fps": frames / seconds if seconds else None,
                        "timing": "tracker only" if inner else "wall, file I/O included"}
    return table


def speed_table(sizes: tuple[int, ...] = (20, 50, 150), n_frames: int = 300, repeats: int = 2, *,
                names: tuple[str, ...] = ("bytetrack", "ocsort"),
                extra: Mapping[str, Callable[[np.ndarray, float], object]] | None = None) -> dict:
    """Frames/s of peers (and ``extra`` trackers) at several objects per frame, in one run.

    Parameters
    ----------
    sizes : tuple of int
        Objects per frame (:func:`common.synthetic_dets`, 1920x1080 frames, 30 frames/s).
    n_frames : int
        Frames per measurement.
    repeats : int
        Each measurement is repeated and the fastest kept (the machine is shared: the slower runs
        measure other people's load).
    names : tuple of str
        Peers to time.
    extra : mapping label -> callable(dets, fps)
        Further trackers; each gets MOT rows (id column = -1) and the frame rate, and its wall
        time is measured around the call.

    Returns
    -------
    dict
        ``{str(size): {label: frames_per_second}}``.
    """
    from common import synthetic_dets

    out: dict = {}
    for n in sizes:
        dets = synthetic_dets(n, n_frames)
        dets[:, 1] = -1
        row = {}
        for name in names:
            best = min(track_rows(name, dets, 30.0)[1] for _ in range(repeats))
            row[PEER_LABELS[name]] = n_frames / best
        for label, fn in (extra or {}).items():
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                fn(dets, 30.0)
                times.append(time.perf_counter() - t0)
            row[label] = n_frames / min(times)
        out[str(n)] = row
    return out


def format_table(table: Mapping[str, dict], baseline: str = "ByteTrack") -> str:
    """Rows: label, IDF1, HOTA, MOTA, IDSW, frames/s, speed ratio to ``baseline``."""
    base = table.get(baseline, {}).get("fps")
    lines = [(f"{'tracker':16} {'IDF1':>6} {'HOTA':>6} {'MOTA':>6} {'IDSW':>5} {'Frag':>5} "
              f"{'FP':>5} {'FN':>6} {'fr/s':>8} {'x ' + baseline:>12}")]
    for label, r in table.items():
        c = r["combined"]
        fps = r.get("fps")
        sp = f"{fps:8.0f}" if fps else f"{'-':>8}"
        ratio = f"{fps / base:12.2f}" if fps and base else f"{'-':>12}"
        lines.append(f"{label:16} {c['IDF1']:6.3f} {c['HOTA']:6.3f} {c['MOTA']:6.3f} "
                     f"{c['IDSW']:5d} {c['Frag']:5d} {c['FP']:5d} {c['FN']:6d} {sp} {ratio}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Peer trackers on MOT detections (Roboflow trackers).")
    sub = ap.add_subparsers(dest="cmd")
    r = sub.add_parser("run", help="run one peer on one detections file")
    r.add_argument("name", choices=list(PEERS))
    r.add_argument("dets", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--fps", type=float, default=30.0)
    r.add_argument("--buffer-s", type=float, default=None)
    t = sub.add_parser("table", help="the UAVDT table (default)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--no-speed", action="store_true", help="skip the objects-per-frame speed table")
    args = ap.parse_args(argv)
    if args.cmd == "run":
        print(json.dumps(run_peer(args.name, args.dets, args.out, args.fps, args.buffer_s)))
        return
    table = uavdt_table(getattr(args, "seed", 0))
    print("UAVDT M0101+M0206+M1005, detections from ground truth (benchmarks/uavdt_dets.py), "
          "combined scores; fr/s = tracker frames per second")
    print(format_table(table))
    speed = None
    if not getattr(args, "no_speed", False):
        speed = speed_table(names=tuple(PEERS))
        print("\nframes/s at N objects per frame (synthetic, 300 frames)")
        labels = list(next(iter(speed.values())))
        print(f"{'N':>5} " + " ".join(f"{lab:>10}" for lab in labels))
        for n, row in speed.items():
            print(f"{n:>5} " + " ".join(f"{row[lab]:10.0f}" for lab in labels))
    write_results("peers", {"seed": getattr(args, "seed", 0), "table": table, "speed": speed})


if __name__ == "__main__":
    main(sys.argv[1:])

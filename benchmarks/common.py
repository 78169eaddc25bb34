"""Small helpers shared by the benchmark scripts (paths to ../shared/data, result files, timing).

Run benchmarks from the repository root with ``/tmp/venv/bin/python benchmarks/NAME.py``; each
prints a table and writes ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Self

REPO = Path(__file__).resolve().parents[1]
#: ../shared/data beside the checkout (override with AEROTRACK_SHARED=/path/to/shared).
SHARED_DATA = Path(os.environ.get("AEROTRACK_SHARED", REPO.parent / "shared")) / "data"
RESULTS = REPO / "benchmarks" / "results"
UAVDT_DIR = SHARED_DATA / "uavdt_gt_only"
#: The three public UAVDT sequences in ../shared (30 frames/s, 1024x540 frames).
UAVDT_SEQS = ("M0101", "M0206", "M1005")
UAVDT_FPS = 30.0
UAVDT_SIZE = (1024, 540)
SANTIAGO_DIR = SHARED_DATA / "santiago_intersection_dfs"
#: Scratch space for intermediate files (detections, tracks) that should not land in the checkout.
WORK = Path(os.environ.get("AEROTRACK_BENCH_WORK", Path(tempfile.gettempdir()) / "aerotrack-bench"))

if str(Path(__file__).resolve().parent) not in sys.path:  # benchmarks import each other
    sys.path.insert(0, str(Path(__file__).resolve().parent))


def require_data(path: Path) -> Path:
    """Exit with a one-line message when a shared data folder is missing."""
    if not path.exists():
        sys.exit(f"benchmark: {path} not found (set AEROTRACK_SHARED to the folder holding data/)")
    return path


def generator_version() -> str:
    """Hash of the scenario generator's source (``src/aerotrack/synth``): benchmarks cache the
    scenes they render, and a scene made by other generator code must be made again (a stale
    cache once made a prediction figure that the committed code could not reproduce)."""
    import hashlib

    h = hashlib.sha1()
    for f in sorted((REPO / "src" / "aerotrack" / "synth").rglob("*.py")):
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def rendered_scene(folder: Path, name: str, synth_args: tuple[str, ...] = ()) -> Path:
    """``folder/name``: a scene rendered by ``aerotrack synth --out folder/name SYNTH_ARGS``,
    rendered again when the generator's code changed (``folder/name.generator`` holds the
    :func:`generator_version` it was made with)."""
    import shutil

    d = folder / name
    marker = folder / f"{name}.generator"
    version = generator_version()
    if not (d / "gt.txt").exists() or not marker.exists() or marker.read_text() != version:
        shutil.rmtree(d, ignore_errors=True)
        aerotrack("-q", "synth", "--out", str(d), *synth_args)
        marker.write_text(version)
    return d


def source_version(exclude: tuple[str, ...] = ()) -> str:
    """Hash of the package's source (``src/aerotrack``) but the files and folders in ``exclude``
    (paths relative to the package, e.g. ``"context"``, ``"association/linking.py"``): a cache of
    a stage's output (the identity benchmark's tracklets) is valid only for the code that made
    it; keying it on the configuration alone once answered a detector change from tracklets of
    the code before. Excluding the stages after it keeps their experiments cheap."""
    import hashlib

    pkg = REPO / "src" / "aerotrack"
    h = hashlib.sha1()
    for f in sorted(pkg.rglob("*.py")):
        rel = f.relative_to(pkg).as_posix()
        if any(rel == e or rel.startswith(e.rstrip("/") + "/") for e in exclude):
            continue
        h.update(rel.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def write_results(name: str, payload: dict) -> Path:
    """Write ``benchmarks/results/NAME.json`` (pretty, sorted keys) and return its path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"{name}.json"
    out.write_text(json.dumps(payload, indent=2, sort_keys=True, default=float) + "\n")
    return out


class Timer:
    """``with Timer() as t: ...`` then ``t.seconds`` (wall clock, perf_counter)."""

    def __enter__(self) -> Self:
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self._t0


def synthetic_dets(n_objects: int, n_frames: int = 300, seed: int = 0,
                   size: tuple[int, int] = (1920, 1080)):
    """Detections of ``n_objects`` vehicles always in view, for speed measurements.

    Each target drives at a constant velocity (1-4 px/frame, random heading) and bounces off the
    image border; boxes are 30x16 px with N(0, 1 px) jitter, conf uniform in [0.5, 1], 5 % of
    detections missed at random. Returns (N, 10) MOT rows with the true id in column 1.
    """
    import numpy as np

    rng = np.random.default_rng([seed, n_objects])
    W, H = size
    pos = rng.uniform([50, 50], [W - 50, H - 50], (n_objects, 2))
    ang = rng.uniform(0, 2 * np.pi, n_objects)
    vel = rng.uniform(1, 4, n_objects)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    rows = []
    for f in range(1, n_frames + 1):
        pos += vel
        out = (pos < 20) | (pos > [W - 20, H - 20])
        vel[out] *= -1
        keep = rng.random(n_objects) > 0.05
        n = int(keep.sum())
        c = pos[keep] + rng.normal(0, 1, (n, 2))
        rows.append(np.column_stack([np.full(n, f), np.flatnonzero(keep) + 1, c[:, 0] - 15,
                                     c[:, 1] - 8, np.full(n, 30.0), np.full(n, 16.0),
                                     rng.uniform(0.5, 1, n), -np.ones((n, 3))]))
    return np.vstack(rows)


def aerotrack(*args: str) -> str:
    """Run the CLI (``python -m aerotrack ARGS``) in a child process and return its standard
    output; a failure raises RuntimeError with the end of its standard error."""
    p = subprocess.run([sys.executable, "-m", "aerotrack", *args], capture_output=True, text=True,
                       check=False)
    if p.returncode:
        raise RuntimeError(f"aerotrack {' '.join(args[:2])}: {p.stderr.strip()[-400:]}")
    return p.stdout

"""Small helpers shared by the benchmark scripts (paths to ../shared/data, result files, timing).

Run benchmarks from the repository root with ``/tmp/venv/bin/python benchmarks/NAME.py``; each
prints a table and writes ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

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


def write_results(name: str, payload: dict) -> Path:
    """Write ``benchmarks/results/NAME.json`` (pretty, sorted keys) and return its path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"{name}.json"
    out.write_text(json.dumps(payload, indent=2, sort_keys=True, default=float) + "\n")
    return out


class Timer:
    """``with Timer() as t: ...`` then ``t.seconds`` (wall clock, perf_counter)."""

    def __enter__(self) -> "Timer":
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self._t0

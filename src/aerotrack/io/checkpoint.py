"""Checkpoints of finished work in ``DIR/.partial/``, so an interrupted run can ``--resume``.

Every chunk is one ``.npz`` file (written atomically, loaded with ``allow_pickle=False``: nothing is
ever unpickled from disk) holding the registrations and the final detections produced since the
previous chunk. On resume the chunks are read back in order; the pipeline replays association on
the stored detections and restarts registration and detection just before where they stopped.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Detections, Registration
from .output import atomic_write

CHUNK_RE = re.compile(r"^chunk_(\d{6})\.npz$")
_OPTIONAL = ("mapxy", "lonlat", "hist", "size_world")


def save_chunk(folder: Path, number: int, registrations: list[Registration],
               detections: list[Detections]) -> Path:
    """Write chunk ``number`` (registrations and detections since the last chunk)."""
    arrays: dict[str, np.ndarray] = {
        "reg_index": np.array([r.index for r in registrations], dtype=np.int64),
        "reg_H": np.array([r.H for r in registrations], dtype=np.float64).reshape(-1, 3, 3),
        "reg_status": np.array([r.status for r in registrations], dtype="U16"),
        "reg_inliers": np.array([r.inliers for r in registrations], dtype=np.int64),
        "reg_ratio": np.array([r.inlier_ratio for r in registrations], dtype=np.float64),
        "reg_error": np.array([r.error for r in registrations], dtype=np.float64),
        "reg_reason": np.array([r.reason for r in registrations], dtype="U200"),
        "det_frames": np.array([d.frame for d in detections], dtype=np.int64),
        "det_counts": np.array([len(d) for d in detections], dtype=np.int64),
    }
    if detections:
        arrays["det_boxes"] = np.concatenate([np.asarray(d.boxes, float).reshape(-1, 4)
                                              for d in detections])
        arrays["det_conf"] = np.concatenate([np.asarray(d.conf, float).reshape(-1)
                                             for d in detections])
        arrays["det_world"] = np.concatenate([np.asarray(d.world, float).reshape(-1, 2)
                                              for d in detections])
        for name in _OPTIONAL:
            parts = [getattr(d, name) for d in detections if len(d)]
            if parts and all(p is not None for p in parts):
                arrays[f"det_{name}"] = np.concatenate([np.asarray(p, float) for p in parts])
        keys = set.intersection(*[set(d.extra) for d in detections if len(d)] or [set()])
        for k in sorted(keys):
            parts = [np.asarray(d.extra[k]) for d in detections if len(d)]
            if all(p.dtype != object for p in parts):
                arrays[f"extra_{k}"] = np.concatenate(parts)
    path = Path(folder) / f"chunk_{number:06d}.npz"
    with atomic_write(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def load_chunks(folder: Path) -> tuple[dict[int, Registration], list[Detections], int]:
    """Read every chunk in ``folder``: (registrations by frame, detections in order, next number)."""
    regs: dict[int, Registration] = {}
    dets: list[Detections] = []
    files = sorted(p for p in Path(folder).glob("chunk_*.npz") if CHUNK_RE.match(p.name))
    for p in files:
        try:
            z = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"--resume: checkpoint {p} is unreadable ({exc})") from None
        with z:
            for i in range(len(z["reg_index"])):
                idx = int(z["reg_index"][i])
                regs[idx] = Registration(
                    index=idx, H=z["reg_H"][i], status=str(z["reg_status"][i]),
                    inliers=int(z["reg_inliers"][i]), inlier_ratio=float(z["reg_ratio"][i]),
                    error=float(z["reg_error"][i]), reason=str(z["reg_reason"][i]))
            start = 0
            for frame, n in zip(z["det_frames"], z["det_counts"]):
                sl = slice(start, start + int(n))
                start += int(n)
                if n == 0:
                    dets.append(Detections.empty(int(frame)))
                    continue
                opt = {name: (z[f"det_{name}"][sl] if f"det_{name}" in z else None)
                       for name in _OPTIONAL}
                extra = {k[6:]: z[k][sl] for k in z.files if k.startswith("extra_")}
                dets.append(Detections(frame=int(frame), boxes=z["det_boxes"][sl],
                                       conf=z["det_conf"][sl], world=z["det_world"][sl],
                                       extra=extra, **opt))
    return regs, dets, len(files)

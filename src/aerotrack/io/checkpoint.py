"""Checkpoints of finished work in ``DIR/.partial/``, so an interrupted run can ``--resume``.

Every chunk is one ``.npz`` file (written atomically, loaded with ``allow_pickle=False``: nothing is
ever unpickled from disk) holding the registrations and the final detections produced since the
previous chunk. On resume the chunks are read back in order; the pipeline replays association on
the stored detections and restarts registration and detection just before where they stopped.

When chunks are written: every ``N`` frames taken (``Pipeline(checkpoint_every=N)``, 300 for
``aerotrack track``: 10 s of a 30 frames/s video), and once more on Ctrl-C or SIGTERM, which also
save the stages' working state (:mod:`aerotrack.io.state`) so that ``--resume`` is exact.

What a hard kill leaves (SIGKILL, the out-of-memory killer, a power cut: nothing runs on the way
out). Say the run was killed after frame ``k`` and its last chunk was written after frame ``m``
(the last multiple of ``N`` frames taken, so ``k - m < N``); ``w = detection.detector.frames_for(window_s / 2, fps)``
is the detector's half window (``detection.window_s``; 45 frames at 3 s and 30 frames/s):

* ``.partial/`` holds the chunks up to ``m``, the run's manifest and perhaps tracklets spilled
  since (dropped on resume). No final file exists: they are written, each atomically, only
  once every frame is done. A ``state.npz`` left by an earlier Ctrl-C is stale (the periodic
  checkpoint after it deleted it, or its frame is not the last chunk's) and is ignored;
* registrations of frames up to ``m`` and detections of frames up to ``d``, the last frame
  final at ``m`` (``m - w`` with the centred window, less in the first ``2w`` frames of the
  video or after a lost registration), are kept exactly; association is replayed on the kept
  detections as the first run did it (its random choices are seeded by frame number);
* registration and detection restart at ``r = d + 1 - (ceil(window_s * fps / 2) + 1)``
  (about ``m - 2w``; the registered frame at or before it), from frame ``r``'s saved
  registration, with a new keyframe chain and a background window that starts at ``r``: frames
  after ``d`` can be registered and detected slightly differently from an uninterrupted run
  (sub-pixel drift of the chain, a borderline blob kept or lost), and a track crossing frame
  ``d`` can be cut or linked differently. Frames ``r`` to ``k`` are processed twice: at most
  ``N + 2w + 1`` frames of work are lost (390 frames, 13 s of video, at the defaults);
* the resumed run covers every frame once, and its outputs have the same form as any run's.
  ``tests/test_resume.py`` kills a run with SIGKILL and checks these points.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Detections, Registration, Track, TrackPoint
from .output import atomic_write
from .state import UNREADABLE

CHUNK_RE = re.compile(r"^chunk_(\d{6})\.npz$")
_OPTIONAL = ("mapxy", "lonlat", "hist", "size_world")


def save_chunk(folder: Path, number: int, registrations: list[Registration],
               detections: list[Detections], thresholds: dict | None = None) -> Path:
    """Write chunk ``number`` (registrations and detections since the last chunk, and the
    detector's residual thresholds of their frames: ``Result.thresholds``)."""
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
    if thresholds:
        arrays["thr_frame"] = np.array(sorted(thresholds), dtype=np.int64)
        arrays["thr_value"] = np.array([thresholds[f] for f in sorted(thresholds)], np.float64)
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
        savez_deflated(fh, arrays)
    return path


def savez_deflated(fh, arrays: dict[str, np.ndarray]) -> None:
    """``np.savez`` with each array deflated at zlib level 1, read back by ``np.load`` as any
    ``.npz``. A run's ``stages/`` held 12.8 MB for 100 frames of Santiago (1080p, 30 vehicles:
    the detections' colour histograms and ring descriptors in float64), 12 GB per hour of such
    video; level 1 makes it 3.3 MB in 0.24 s (level 6, ``np.savez_compressed``: 3.0 MB in 0.87 s,
    4% of the run's time)."""
    import zipfile

    with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for name, value in arrays.items():
            with z.open(f"{name}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)


def load_chunks(folder: Path, what: str = "--resume: checkpoint"
                ) -> tuple[dict[int, Registration], list[Detections], int]:
    """Read every chunk in ``folder``: (registrations by frame, detections in order, next number).
    ``what`` names a chunk in the error for an unreadable one (``track --from`` reads a run's
    ``stages/``, not checkpoints of a run to resume)."""
    regs: dict[int, Registration] = {}
    dets: list[Detections] = []
    files = sorted(p for p in Path(folder).glob("chunk_*.npz") if CHUNK_RE.match(p.name))
    for p in files:
        try:
            with open(p, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # closed if damaged
                # each member read once: ``z[name]`` decompresses the whole member again on every
                # access (a detection's slice then cost a copy of the chunk's array: resuming after
                # 600 frames at 640x480 held 3.6 GB and spent most of its time there)
                _read_chunk({k: z[k] for k in z.files}, regs, dets)
        except UNREADABLE as exc:
            raise InputError(f"{what} {p} is unreadable "
                             f"({exc or type(exc).__name__})") from None
    return regs, dets, len(files)


def load_thresholds(folder: Path, what: str = "--resume: checkpoint") -> dict[int, float]:
    """The detector's residual thresholds by frame saved in ``folder``'s chunks (empty for
    chunks written before they were kept, or by runs on given detections); ``what`` as
    :func:`load_chunks`'s."""
    out: dict[int, float] = {}
    for p in sorted(p for p in Path(folder).glob("chunk_*.npz") if CHUNK_RE.match(p.name)):
        try:
            with open(p, "rb") as fh, np.load(fh, allow_pickle=False) as z:
                if "thr_frame" in z.files:
                    out.update(zip(z["thr_frame"].tolist(), z["thr_value"].tolist()))
        except UNREADABLE as exc:
            raise InputError(f"{what} {p} is unreadable "
                             f"({exc or type(exc).__name__})") from None
    return out


def _read_chunk(z: dict[str, np.ndarray], regs: dict[int, Registration],
                dets: list[Detections]) -> None:
    """Add one chunk's registrations and detections (arrays by name) to ``regs`` and ``dets``;
    each detection gets its own arrays, as in the run that saved them."""
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
        opt = {name: (z[f"det_{name}"][sl].copy() if f"det_{name}" in z else None)
               for name in _OPTIONAL}
        extra = {k[6:]: v[sl].copy() for k, v in z.items() if k.startswith("extra_")}
        dets.append(Detections(frame=int(frame), boxes=z["det_boxes"][sl].copy(),
                               conf=z["det_conf"][sl].copy(), world=z["det_world"][sl].copy(),
                               extra=extra, **opt))


# -- finished tracklets, spilled until global linking ---------------------------------------------
_KINDS = ("observed", "bridged", "stationary", "predicted")


_MAX_DIMS = 4


def _shapes(arrays: list) -> np.ndarray:
    """(N, 1 + _MAX_DIMS) rows ``[ndim, d0, d1, ...]`` of optional arrays (ndim -1 for None)."""
    out = np.full((len(arrays), 1 + _MAX_DIMS), -1, dtype=np.int64)
    for i, a in enumerate(arrays):
        if a is not None:
            s = np.shape(a)
            if len(s) > _MAX_DIMS:
                raise ValueError(f"tracklet point array of shape {s}: at most {_MAX_DIMS}-D "
                                 "can be spilled")
            out[i, 0] = len(s)
            out[i, 1:1 + len(s)] = s
    return out


def pack_tracks(tracks: list[Track]) -> dict[str, np.ndarray]:
    """Tracks as flat arrays (no objects, so ``np.savez`` needs no pickle); inverse of
    :func:`unpack_tracks`.

    Every field of every :class:`~aerotrack.types.TrackPoint` is kept exactly: positions as
    float64, appearance arrays (``hist``, ``desc``) in their own dtype (float32 or float64, stored
    as float64 and cast back: exact), None as an ndim of -1.
    """
    pts = [p for t in tracks for p in t.points]
    n = len(pts)
    kinds = [p.kind for p in pts]
    extra_kinds = sorted(set(kinds) - set(_KINDS))
    names = list(_KINDS) + extra_kinds
    code = {k: i for i, k in enumerate(names)}
    arrays: dict[str, np.ndarray] = {
        "t_id": np.array([t.id for t in tracks], dtype=np.int64),
        "t_count": np.array([len(t.points) for t in tracks], dtype=np.int64),
        "kind_names": np.array(names, dtype="U32"),
        "p_frame": np.array([p.frame for p in pts], dtype=np.int64),
        "p_world": np.array([np.asarray(p.world, np.float64).reshape(2) for p in pts],
                            dtype=np.float64).reshape(n, 2),
        "p_conf": np.array([p.conf for p in pts], dtype=np.float64),
        "p_kind": np.array([code[k] for k in kinds], dtype=np.int16),
        "p_det": np.array([p.det_index for p in pts], dtype=np.int64),
        "p_weak": np.array([p.weak for p in pts], dtype=bool),
    }
    for name in ("box", "size_world", "hist", "desc"):
        vals = [getattr(p, name) for p in pts]
        arrays[f"p_{name}_shape"] = _shapes(vals)
        arrays[f"p_{name}_f32"] = np.array([v is not None and np.asarray(v).dtype == np.float32
                                            for v in vals], dtype=bool)
        flat = [np.asarray(v, np.float64).ravel() for v in vals if v is not None]
        arrays[f"p_{name}"] = np.concatenate(flat) if flat else np.zeros(0)
    return arrays


def unpack_tracks(z) -> list[Track]:
    """The tracks of :func:`pack_tracks` (``z``: its dict, or an open ``.npz``)."""
    names = [str(k) for k in z["kind_names"]]
    frame, world, conf = z["p_frame"], z["p_world"], z["p_conf"]
    kind, det = z["p_kind"], z["p_det"]
    weak = z["p_weak"] if "p_weak" in z else np.zeros(len(frame), bool)
    opt = {}
    for name in ("box", "size_world", "hist", "desc"):
        shape, f32, flat = z[f"p_{name}_shape"], z[f"p_{name}_f32"], z[f"p_{name}"]
        vals: list[np.ndarray | None] = []
        pos = 0
        for s, is32 in zip(shape, f32):
            if s[0] < 0:
                vals.append(None)
                continue
            shp = tuple(int(d) for d in s[1:1 + int(s[0])])
            size = int(np.prod(shp))
            v = flat[pos:pos + size].reshape(shp)
            pos += size
            vals.append(v.astype(np.float32) if is32 else v.copy())
        opt[name] = vals
    out, start = [], 0
    for tid, count in zip(z["t_id"], z["t_count"]):
        points = [TrackPoint(frame=int(frame[i]), box=opt["box"][i], world=world[i].copy(),
                             conf=float(conf[i]), kind=names[int(kind[i])],
                             det_index=int(det[i]), size_world=opt["size_world"][i],
                             hist=opt["hist"][i], desc=opt["desc"][i], weak=bool(weak[i]))
                  for i in range(start, start + int(count))]
        start += int(count)
        out.append(Track(int(tid), points))
    return out


class TrackletSpill:
    """Finished tracklets on disk until global linking needs them (a long run's memory then does
    not grow with the tracklets it found).

    Tracklets are buffered and written ``chunk`` at a time as ``spill_NNNNNN.npz`` (no pickle) in
    ``folder`` (a run's ``.partial/tracklets`` work area, or a temporary folder removed by
    :meth:`close`); :meth:`load` gives every tracklet back, in the order added, exactly as it was.

    Parameters
    ----------
    folder : path, optional
        Work folder (emptied of earlier spill files); None makes a temporary one.
    chunk : int
        Tracklets per file.
    """

    def __init__(self, folder: Path | None = None, chunk: int = 64) -> None:
        self.folder = None if folder is None else Path(folder)
        self.chunk = max(1, int(chunk))
        self._tmp = None
        self._buffer: list[Track] = []
        self._files: list[Path] = []
        self._count = 0
        if self.folder is not None and self.folder.is_dir():  # an interrupted run's
            for p in self.folder.glob("spill_*.npz"):
                p.unlink()

    def _folder(self) -> Path:
        """The work folder, made on first use."""
        if self.folder is None:
            import tempfile

            self._tmp = tempfile.TemporaryDirectory(prefix="aerotrack-spill-")
            self.folder = Path(self._tmp.name)
        self.folder.mkdir(parents=True, exist_ok=True)
        return self.folder

    def __len__(self) -> int:
        return self._count

    def append(self, track: Track) -> None:
        self._buffer.append(track)
        self._count += 1
        if len(self._buffer) >= self.chunk:
            self.flush()

    def extend(self, tracks) -> None:
        for t in tracks:
            self.append(t)

    def flush(self) -> None:
        """Write the buffered tracklets now."""
        if not self._buffer:
            return
        path = self._folder() / f"spill_{len(self._files):06d}.npz"
        with atomic_write(path, "wb") as fh:
            savez_deflated(fh, pack_tracks(self._buffer))
        self._files.append(path)
        self._buffer = []

    def link_into(self, folder: Path) -> dict:
        """Write the buffer, and put the spill files in ``folder`` too (hard links, or copies
        where the file system has none): what :meth:`adopt` takes back. Returns their names and
        the number of tracklets, for the caller to store."""
        self.flush()
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for p in self._files:
            _link_or_copy(p, folder / p.name)
        return {"files": [p.name for p in self._files], "count": self._count}

    def adopt(self, folder: Path, saved: dict | None) -> bool:
        """Continue from the spill files :meth:`link_into` put in ``folder`` (``saved``: what it
        returned), instead of an empty spill. False, and nothing changed, when they are not all
        there or this spill is not empty."""
        if not saved or self._count or self._buffer:
            return False
        files = [Path(folder) / name for name in saved["files"]]
        if not all(p.is_file() for p in files):
            return False
        own = self._folder()
        self._files = []
        for p in files:
            _link_or_copy(p, own / p.name)
            self._files.append(own / p.name)
        self._count = int(saved["count"])
        return True

    def load(self) -> list[Track]:
        """Every tracklet, in the order added."""
        out: list[Track] = []
        for p in self._files:
            with open(p, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # closed if damaged
                out.extend(unpack_tracks(z))
        out.extend(self._buffer)
        return out

    def close(self) -> None:
        """Delete the spill files and their folder when that is left empty."""
        for p in self._files:
            p.unlink(missing_ok=True)
        if (self._tmp is None and self.folder is not None and self.folder.is_dir()
                and not any(self.folder.iterdir())):
            self.folder.rmdir()
        self._files = []
        self._buffer = []
        self._count = 0
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None


def _link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` becomes ``src``'s content: a hard link (no copy), or a copy where the file system
    has no links."""
    dst.unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)

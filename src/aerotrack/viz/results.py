"""Read an output folder (the file contract) into arrays the pictures and the report use.

Everything in :mod:`aerotrack.viz` works from the files of an output folder ``DIR``, never from the
pipeline's objects, so the pictures can be made for any run, old or new, by any tracker that writes
the contract: ``tracks.csv``, ``predicted.csv``, ``registration.csv``, ``summary.json``.

Coordinate frames
-----------------
* box columns: that frame's pixels;
* ``x, y`` columns: map CRS (``-1`` without a map);
* world: map pixels (col, row) with a map, frame 1's pixels without, obtained from ``x, y`` through
  the map's affine transform or, failing that, from the box centre through that frame's
  homography in ``registration.csv``.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError, InputError
from ..io.mot import read_mot

log = logging.getLogger("aerotrack")

H_COLUMNS = ("h00", "h01", "h02", "h10", "h11", "h12", "h20", "h21", "h22")


@dataclass
class RegistrationTable:
    """``registration.csv`` as arrays.

    Attributes
    ----------
    frames : ndarray, shape (N,), int64
        1-based frame numbers, sorted.
    H : ndarray, shape (N, 3, 3), float64
        Frame pixels -> world (map pixels with a map, frame 1's pixels without).
    extra : dict of str -> ndarray, shape (N,)
        The optional columns (``status`` as str, ``inliers``, ``inlier_ratio``, ``error``, ...)
        as float arrays where numeric.
    """

    frames: np.ndarray
    H: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {int(f): i for i, f in enumerate(self.frames)}

    def __len__(self) -> int:
        return len(self.frames)

    def get(self, frame: int) -> np.ndarray | None:
        """The 3x3 homography of ``frame``, or None when the frame has no row."""
        i = self._index.get(int(frame))
        return None if i is None else self.H[i]

    @classmethod
    def read(cls, path: str | Path) -> RegistrationTable:
        """Parse ``registration.csv``.

        Raises
        ------
        FormatError
            Missing ``frame``/``h..`` columns or a non-numeric homography entry (names the line).
        """
        p = Path(path)
        with open(p, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise FormatError(f"{p}: empty file, expected a header frame,h00,...,h22") from None
            missing = [c for c in ("frame", *H_COLUMNS) if c not in header]
            if missing:
                raise FormatError(f"{p} line 1: missing column(s) {', '.join(missing)}")
            col = {h: i for i, h in enumerate(header)}
            others = [h for h in header if h not in ("frame", *H_COLUMNS)]
            frames, hs, extra = [], [], {h: [] for h in others}
            for lineno, row in enumerate(reader, start=2):
                if not row or not "".join(row).strip():
                    continue
                try:
                    frames.append(int(float(row[col["frame"]])))
                    hs.append([float(row[col[c]]) for c in H_COLUMNS])
                except (ValueError, IndexError):
                    raise FormatError(f"{p} line {lineno}: bad frame number or homography entry") from None
                for h in others:
                    extra[h].append(row[col[h]].strip() if col[h] < len(row) else "")
        order = np.argsort(frames, kind="stable")
        H = np.asarray(hs, dtype=np.float64).reshape(-1, 3, 3)[order]
        out_extra: dict[str, np.ndarray] = {}
        for h, vals in extra.items():
            vals = [vals[i] for i in order]
            try:
                out_extra[h] = np.array([float(v) if v != "" else math.nan for v in vals])
            except ValueError:
                out_extra[h] = np.array(vals, dtype=object)
        return cls(np.asarray(frames, dtype=np.int64)[order], H, out_extra)


@dataclass
class TrackView:
    """One track: its in-view rows and its predicted rows, merged and sorted by frame.

    Attributes
    ----------
    id : int
    frames : ndarray, shape (N,), int64
    boxes : ndarray, shape (N, 4)
        Frame pixels, ``bb_left, bb_top, bb_width, bb_height``.
    conf : ndarray, shape (N,)
    mapxy : ndarray, shape (N, 2)
        Map CRS (NaN without a map).
    world : ndarray, shape (N, 2)
        Map pixels with a map, frame 1's pixels without (NaN where unknown).
    observed : ndarray, shape (N,), bool
        True for rows of ``tracks.csv`` (in view), False for ``predicted.csv`` rows.
    """

    id: int
    frames: np.ndarray
    boxes: np.ndarray
    conf: np.ndarray
    mapxy: np.ndarray
    world: np.ndarray
    observed: np.ndarray

    @property
    def centres(self) -> np.ndarray:
        """(N, 2) box centres in each row's frame pixels."""
        return self.boxes[:, :2] + self.boxes[:, 2:] / 2.0

    def stretches(self) -> list[tuple[int, int]]:
        """Index ranges ``[i, j)`` of runs of consecutive in-view frames."""
        idx = np.flatnonzero(self.observed)
        if not len(idx):
            return []
        f = self.frames[idx]
        breaks = np.flatnonzero(np.diff(f) > 1)
        starts = np.r_[0, breaks + 1]
        ends = np.r_[breaks + 1, len(idx)]
        return [(int(idx[s]), int(idx[e - 1]) + 1) for s, e in zip(starts, ends)]

    def reacquisitions(self) -> np.ndarray:
        """Indices of the rows where the track is seen again after a gap in view."""
        st = self.stretches()
        return np.array([s for s, _ in st[1:]], dtype=np.int64)


@dataclass
class RunResults:
    """The files of one output folder.

    Attributes
    ----------
    path : Path
    tracks : ndarray, shape (N, 10)
        ``tracks.csv`` rows (1-based frames).
    predicted : ndarray, shape (M, 10)
        ``predicted.csv`` rows (empty when absent).
    detections : ndarray, shape (K, 10) or None
    registration : RegistrationTable or None
    summary : dict
    fps : float
    map_path : Path or None
        The map raster named by ``summary.json`` (``"map"``), when it exists.
    """

    path: Path
    tracks: np.ndarray
    predicted: np.ndarray
    detections: np.ndarray | None
    registration: RegistrationTable | None
    summary: dict[str, Any]
    config: dict[str, Any]
    fps: float
    map_path: Path | None

    @property
    def has_map_xy(self) -> bool:
        """Whether the rows carry map CRS positions (``x, y`` not -1)."""
        rows = self.tracks if len(self.tracks) else self.predicted
        return bool(len(rows)) and bool(np.any((rows[:, 7] != -1) | (rows[:, 8] != -1)))

    @property
    def metres_per_unit(self) -> float | None:
        """Metres per world unit from ``summary.json`` (``metres_per_unit``), when known."""
        v = self.summary.get("metres_per_unit")
        return float(v) if isinstance(v, (int, float)) and v > 0 else None

    @property
    def input_path(self) -> Path | None:
        """The run's input (``summary.json`` ``"input"``) when it still exists."""
        v = self.summary.get("input")
        if isinstance(v, dict):
            v = v.get("path")
        if not isinstance(v, str) or not v:
            return None
        for cand in (Path(v), self.path / v):
            if cand.exists():
                return cand
        return None

    @property
    def timings(self) -> dict[str, float]:
        """Per-stage seconds from ``summary.json`` (``timings_s`` or ``timings``)."""
        t = self.summary.get("timings_s", self.summary.get("timings"))
        if not isinstance(t, dict):
            return {}
        return {str(k): float(v) for k, v in t.items() if isinstance(v, (int, float))}

    @property
    def first_frame(self) -> int:
        """The run's first frame (``--frames A:B`` starts at A; its world without a map is frame
        A's pixels)."""
        n = self.summary.get("first_frame")
        if isinstance(n, (int, float)) and n >= 1:
            return int(n)
        parts = [a[:, 0].min() for a in (self.tracks,) if len(a)]
        if self.registration is not None and len(self.registration):
            parts.append(self.registration.frames.min())
        return int(min(parts)) if parts else 1

    @property
    def n_frames(self) -> int:
        """Frames the run processed (``summary.json`` ``frames``; else its frame span)."""
        n = self.summary.get("frames")
        if isinstance(n, (int, float)) and n >= 0:
            return int(n)
        last = self.last_frame
        return last - self.first_frame + 1 if last else 0

    def reference_image(self, input_path) -> np.ndarray | None:
        """The image of the run's first frame from ``input_path`` (the background of the track
        map without a map: the world is that frame's pixels), or None."""
        if input_path is None:
            return None
        from ..io.frames import open_source

        first = self.first_frame
        frame = next(iter(open_source(input_path, self.fps).frames(start=first, stop=first)),
                     None)
        return None if frame is None else frame.image

    def check_input(self, source, input_path, option: str = "INPUT") -> None:
        """Refuse an input whose frames are not the size the run tracked (its summary.json);
        warn when it holds fewer frames than the run tracked, or its files are not the size
        (bytes, and file count of a folder) the run recorded for its input: a probe rendered 49
        of a run's 421 frames, and 60 unrelated frames, with no word."""
        from ..errors import InputError
        from ..io.state import input_fingerprints

        size = self.summary.get("frame_size")
        if size and tuple(size) != tuple(source.size):
            raise InputError(f"{option} {input_path}: frames are {source.size[0]}x"
                             f"{source.size[1]}, but the run in {self.path} tracked {size[0]}x"
                             f"{size[1]} frames (its summary.json): give the input that run "
                             "tracked")
        count, last = getattr(source, "count", None), self.last_frame
        if count and last and count < last:
            log.warning("%s %s: holds %d frames, but the run in %s tracked frames up to %d: the "
                        "later ones are left out", option, input_path, count, self.path, last)
            return
        tracked = self.summary.get("input")
        recorded = ((self.summary.get("options") or {}).get("input_files") or {})
        if not tracked or not isinstance(recorded, dict) or "://" in str(input_path):
            return
        try:
            old = recorded.get(str(Path(tracked).resolve())) or recorded.get(str(tracked))
        except OSError:
            return
        new = next(iter(input_fingerprints([input_path]).values()), None)
        if old and new and len(old) == len(new) and list(old[:-1]) != list(new[:-1]):
            what = ("{} files, {} bytes" if len(new) == 3 else "{} bytes").format
            log.warning("%s %s: not the input the run in %s tracked (%s: %s; this one: %s); the "
                        "boxes may not match its frames", option, input_path, self.path, tracked,
                        what(*old[:-1]), what(*new[:-1]))

    @property
    def last_frame(self) -> int:
        """The run's last frame (``summary.json``; else the last frame any file holds)."""
        n = self.summary.get("last_frame")
        if isinstance(n, (int, float)) and n >= 1:
            return int(n)
        parts = [a[:, 0].max() for a in (self.tracks, self.predicted) if len(a)]
        if self.registration is not None and len(self.registration):
            parts.append(self.registration.frames.max())
        n = self.summary.get("last_frame", self.summary.get("frames"))
        if isinstance(n, (int, float)):
            parts.append(n)
        return int(max(parts)) if parts else 0

    def track_views(self, geomap=None) -> list[TrackView]:
        """Every track, sorted by ID (see :class:`TrackView`).

        Parameters
        ----------
        geomap : aerotrack.geo.GeoMap, optional
            Used to turn map CRS ``x, y`` into map pixels; without it, world positions come from
            ``registration.csv`` (or the frame pixels when there is none).
        """
        rows = [np.column_stack([self.tracks, np.ones(len(self.tracks))])]
        if len(self.predicted):
            rows.append(np.column_stack([self.predicted, np.zeros(len(self.predicted))]))
        allr = np.vstack(rows) if rows else np.zeros((0, 11))
        out = []
        for tid in np.unique(allr[:, 1]).astype(int):
            r = allr[allr[:, 1] == tid]
            # one row per frame; an in-view row wins over a predicted one for the same frame
            r = r[np.lexsort((-r[:, 10], r[:, 0]))]
            keep = np.r_[True, np.diff(r[:, 0]) != 0]
            r = r[keep]
            frames = r[:, 0].astype(np.int64)
            boxes = r[:, 2:6].copy()
            has_xy = (r[:, 7] != -1) | (r[:, 8] != -1)
            mapxy = np.where(has_xy[:, None], r[:, 7:9], np.nan)
            world = self._world(frames, boxes, mapxy, geomap)
            out.append(TrackView(int(tid), frames, boxes, r[:, 6].copy(), mapxy, world,
                                 r[:, 10].astype(bool)))
        return out

    def boxes_world(self, frames: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(N, 2) world positions of box centres (frame pixels, ``bb_left, bb_top, bb_width,
        bb_height``) through this run's ``registration.csv``: map pixels with a map, the first
        frame's pixels without (NaN in frames it did not register; the boxes themselves without
        a registration file). For boxes from elsewhere, e.g. a ground truth."""
        frames = np.asarray(frames, dtype=np.int64).reshape(-1)
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        return self._world(frames, boxes, np.full((len(frames), 2), np.nan), None)

    def _world(self, frames, boxes, mapxy, geomap) -> np.ndarray:
        centres = boxes[:, :2] + boxes[:, 2:] / 2.0
        world = np.full((len(frames), 2), np.nan)
        if geomap is not None:
            ok = np.all(np.isfinite(mapxy), axis=1)
            if ok.any():
                world[ok] = geomap.crs_to_pixel(mapxy[ok])
        reg = self.registration
        todo = ~np.all(np.isfinite(world), axis=1)
        if reg is None or not len(reg):
            if geomap is None:
                world[todo] = centres[todo]
            return world
        idx = np.flatnonzero(todo)
        pos = np.searchsorted(reg.frames, frames[idx])
        pos = np.minimum(pos, len(reg.frames) - 1)
        has = reg.frames[pos] == frames[idx]
        idx, pos = idx[has], pos[has]
        if len(idx):
            p = np.column_stack([centres[idx], np.ones(len(idx))])
            h = np.einsum("nij,nj->ni", reg.H[pos], p)
            with np.errstate(divide="ignore", invalid="ignore"):
                world[idx] = h[:, :2] / h[:, 2:3]
        return world

    @classmethod
    def load(cls, path: str | Path, *, option: str = "DIR") -> RunResults:
        """Read an output folder.

        Raises
        ------
        InputError
            The folder or its ``tracks.csv`` is missing.
        FormatError
            A malformed file (the message names it and the line).
        """
        p = Path(path)
        if not p.is_dir():
            raise InputError(f"{option} {p}: no such output folder")
        tpath = p / "tracks.csv"
        if not tpath.is_file():
            raise InputError(f"{option} {p}: holds no tracks.csv (not an aerotrack output folder?)")
        tracks = read_mot(tpath, strict=False)
        ppath = p / "predicted.csv"
        predicted = read_mot(ppath, strict=False) if ppath.is_file() else np.zeros((0, 10))
        dpath = p / "detections.csv"
        detections = read_mot(dpath, strict=False) if dpath.is_file() else None
        rpath = p / "registration.csv"
        registration = RegistrationTable.read(rpath) if rpath.is_file() else None
        summary: dict[str, Any] = {}
        spath = p / "summary.json"
        if spath.is_file():
            try:
                summary = json.loads(spath.read_text(encoding="utf-8"))
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise FormatError(f"{spath}: not valid JSON ({exc})") from None
            if not isinstance(summary, dict):
                summary = {}
        config: dict[str, Any] = {}
        cpath = p / "config.toml"
        if cpath.is_file():
            try:
                config = tomllib.loads(cpath.read_text(encoding="utf-8"))
            except (tomllib.TOMLDecodeError, UnicodeDecodeError):
                config = {}
        fps = summary.get("fps")
        fps = float(fps) if isinstance(fps, (int, float)) and fps > 0 else 30.0
        map_path = _map_path(summary.get("map"), p)
        return cls(p, tracks, predicted, detections, registration, summary, config, fps, map_path)


def _map_path(value: Any, base: Path) -> Path | None:
    if isinstance(value, dict):
        value = value.get("path")
    if not isinstance(value, str) or not value:
        return None
    q = Path(value)
    for cand in (q, base / q):
        if cand.is_file():
            return cand
    return None

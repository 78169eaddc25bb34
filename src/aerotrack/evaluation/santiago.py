"""The published evaluation protocol of the Santiago intersection clip (``santiago_intersection_dfs``).

The upstream notebook scored its trackers with py-motmetrics at IoU 0.5 on the 0-based frames 1..97
of ``dfs_ground_truth.csv`` (its loop skips frame 0). Its files are 0-based; aerotrack is 1-based, so
:func:`read_zero_based_mot` adds 1 to every frame and :data:`SANTIAGO_FRAMES` is the window 2..98.
Published numbers (SOURCE.md): YOLOv8 + SORT MOTA 0.673 / IDF1 0.837, YOLOv8 + ByteTrack MOTA
0.682 / IDF1 0.842 on ``baseline_tracks/*_filtered.csv``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..io.mot import read_mot
from .mot import evaluate

log = logging.getLogger(__name__)

#: Inclusive 1-based scoring window of the published protocol (0-based frames 1..97).
SANTIAGO_FRAMES = (2, 98)
#: Published baseline tracks, by short name.
SANTIAGO_BASELINES = {
    "sort": "baseline_tracks/yolo_sort_detections_filtered.csv",
    "bytetrack": "baseline_tracks/yolo_bytetrack_detections_filtered.csv",
}


def read_zero_based_mot(path: str | Path, *, option: str | None = None, strict: bool = False,
                        tracks: bool = False) -> np.ndarray:
    """Read a MOT file whose frames are 0-based, returning 1-based rows (N, 10) sorted by frame, id
    (:func:`aerotrack.io.mot.read_mot` with ``zero_based=True``; ``strict`` and ``tracks`` as
    there)."""
    return read_mot(path, option=option, strict=strict, zero_based=True, tracks=tracks)


def load_santiago(folder: str | Path, tracks: str | Path | np.ndarray | None = None, *,
                  zero_based: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Load Santiago's ground truth (0-based on disk) and, optionally, tracks, as 1-based rows.

    Parameters
    ----------
    folder : path
        ``.../santiago_intersection_dfs``.
    tracks : str, path or array, optional
        ``"sort"`` or ``"bytetrack"`` (the published baselines), a 0-based MOT file (as the
        published ones are), or an (M, >=6) array of 1-based rows, e.g.
        ``read_mot("run/tracks.csv")`` of aerotrack's own output on the clip (video frame n is
        1-based frame n, i.e. 0-based frame n - 1 of the ground truth).
    zero_based : bool
        Whether a ``tracks`` file numbers frames from 0; False for aerotrack's own ``tracks.csv``
        (1-based). A file that overlaps the ground truth clearly better one frame off draws a
        warning (aerotrack's tracks read as 0-based lost 0.09 HOTA, silently).

    Returns
    -------
    gt : (N, 10) array
        Every row of ``dfs_ground_truth.csv``, flaws included (negative sizes, one duplicate).
    pred : (M, 10) array or None
    """
    folder = Path(folder)
    gt = read_zero_based_mot(folder / "dfs_ground_truth.csv")
    if tracks is None:
        return gt, None
    if isinstance(tracks, np.ndarray):
        return gt, tracks
    path = folder / SANTIAGO_BASELINES[tracks] if str(tracks) in SANTIAGO_BASELINES else Path(tracks)
    pred = (read_zero_based_mot(path) if zero_based
            else read_mot(path, option="tracks", strict=True, tracks=True))
    from .mot import frame_offset_overlap

    at = {d: frame_offset_overlap(gt, pred, d) for d in (-1, 0, 1)}
    best = max((-1, 1), key=lambda d: at[d])
    if at[best] > 0.1 and at[best] > 1.15 * at[0]:
        log.warning("%s overlaps the ground truth better one frame %s (mean best IoU %.2f against "
                    "%.2f): read with zero_based=%s?", path, "later" if best > 0 else "earlier",
                    at[best], at[0], not zero_based)
    return gt, pred


def evaluate_santiago(folder: str | Path, tracks: str | Path | np.ndarray, *,
                      fix_gt: bool = False, zero_based: bool = True) -> dict:
    """Score tracks on Santiago under the published protocol (window :data:`SANTIAGO_FRAMES`).

    ``tracks`` and ``zero_based`` as in :func:`load_santiago` (False for aerotrack's own
    ``tracks.csv``). ``fix_gt`` scores against the corrected ground truth
    (:func:`~.mot.fix_ground_truth`); returns :func:`~.mot.evaluate`'s dict.
    """
    from .mot import fix_ground_truth

    gt, pred = load_santiago(folder, tracks, zero_based=zero_based)
    if fix_gt:
        gt, _ = fix_ground_truth(gt)
    return evaluate(gt, pred, frames=SANTIAGO_FRAMES)


def unannotated_movers(gt: np.ndarray, pred: np.ndarray, *,
                       frames: tuple[int, int] = SANTIAGO_FRAMES, min_iou: float = 0.3,
                       min_move_lengths: float = 1.0) -> list[int]:
    """Predicted tracks on vehicles the ground truth leaves out: a diagnostic, not a score.

    Santiago's ground truth annotates "the moving vehicles", but not all of them: tracks of
    vehicles that visibly drive through the clip have no ground-truth box at all (checked by eye
    on aerotrack's output; ``docs/DESIGN.md``, "What Santiago's ground truth leaves out"), and
    every one of their boxes counts as a false positive. A track is listed when, within
    ``frames``, none of its boxes overlaps a ground-truth box of the same frame at ``min_iou`` or
    more, and its box centre moves at least ``min_move_lengths`` times its median box's longer
    side between its first and last box (it drives; a parked car stays put). Scoring without
    these tracks tells how much of a gap to a goal is the ground truth's, not the tracker's.

    Parameters
    ----------
    gt, pred : (N, >=6) arrays of 1-based MOT rows (``frame, id, x, y, w, h``; ``gt`` with
        positive sizes, e.g. after :func:`~.mot.fix_ground_truth`).

    Returns
    -------
    list of int
        The track ids, ascending.
    """
    from .mot import _box_ious

    lo, hi = frames
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    pred = pred[(pred[:, 0] >= lo) & (pred[:, 0] <= hi)]
    gt = gt[(gt[:, 0] >= lo) & (gt[:, 0] <= hi)]
    touched: set[int] = set()
    for f in np.unique(pred[:, 0]):
        p, g = pred[pred[:, 0] == f], gt[gt[:, 0] == f]
        if not len(g):
            continue
        hit = (_box_ious(g[:, 2:6], p[:, 2:6]) >= min_iou).any(axis=0)
        touched.update(int(i) for i in p[hit, 1])
    out = []
    for tid in np.unique(pred[:, 1]):
        if int(tid) in touched:
            continue
        rows = pred[pred[:, 1] == tid]
        rows = rows[np.argsort(rows[:, 0])]
        centres = rows[:, 2:4] + rows[:, 4:6] / 2
        length = float(np.median(np.max(rows[:, 4:6], axis=1)))
        if float(np.hypot(*(centres[-1] - centres[0]))) >= min_move_lengths * length:
            out.append(int(tid))
    return out

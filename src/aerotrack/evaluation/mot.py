"""Class-agnostic MOT scoring with TrackEval's metric classes (HOTA, CLEAR, Identity).

TrackEval's ``MotChallenge2DBox`` dataset class is not used: it keeps only pedestrians, casts the
ground truth's 7th column (confidence) to int, which turns confidences such as 0.8 into 0 and drops
the rows, and refuses a ground truth with a repeated (frame, id). Here the rows are loaded by
:func:`aerotrack.io.mot.read_mot` and turned into TrackEval's per-timestep arrays directly, so every
ground-truth row counts whatever its confidence and every class is one class.

All boxes are ``bb_left, bb_top, bb_width, bb_height`` in frame pixels; frames are 1-based.

Scoring window
--------------
A sequence is scored over the frames ``first..last`` (default ``1..`` the ground truth's last frame):
prediction rows outside the window are dropped. Scoring prediction frames past the ground truth's
last frame would count them all as false positives although nobody annotated them (on Santiago it
moves MOTA by more than 0.005).

Ground-truth flaws
------------------
Published ground truths have flaws. Exact duplicate rows (same frame, id and box) are always dropped
with a warning (their effect on Santiago is < 0.001). Boxes with a negative width or height are kept
as they are (TrackEval gives them zero IoU with everything, so they count as misses), because the
published protocols keep them; :func:`fix_ground_truth` reflects them instead (``--fix-gt``).
"""

from __future__ import annotations

import contextlib
import io
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..io.mot import repeated_frame_id

log = logging.getLogger(__name__)

#: Keys of the contract's ``eval --json`` object, in print order.
METRIC_KEYS = ("HOTA", "DetA", "AssA", "LocA", "MOTA", "MOTP", "IDF1", "IDSW", "Frag",
               "GT_IDs", "Pred_IDs", "GT_Dets", "Pred_Dets")
#: Further counts returned beside the contract's keys.
EXTRA_KEYS = ("TP", "FP", "FN", "MT", "PT", "ML", "IDP", "IDR", "HOTA(0)")


# --------------------------------------------------------------------------- ground-truth fixes

@dataclass(frozen=True)
class GroundTruthFix:
    """What :func:`fix_ground_truth` (or duplicate removal alone) changed.

    Attributes
    ----------
    reflected_rows : int
        Rows whose negative width and/or height was reflected.
    reflected_ids : tuple of int
        Their target ids.
    duplicates : tuple of (int, int)
        ``(frame, id)`` of every dropped exact duplicate row.
    """

    reflected_rows: int = 0
    reflected_ids: tuple[int, ...] = ()
    duplicates: tuple[tuple[int, int], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.reflected_rows or self.duplicates)

    def describe(self, frame_offset: int = 0) -> str:
        """One line saying what changed, e.g. for the CLI; ``frame_offset`` -1 names frames as a
        0-based file numbers them."""
        parts = []
        if self.reflected_rows:
            parts.append(f"reflected {self.reflected_rows} boxes with a negative width or height "
                         f"(x += w, w = -w; likewise y, h) of ids "
                         f"{', '.join(map(str, self.reflected_ids))}")
        if self.duplicates:
            keys = ", ".join(f"frame {f + frame_offset} id {i}" for f, i in self.duplicates[:5])
            if frame_offset:  # as the warning without --fix-gt names them: both numberings
                keys += f"; frames as in the file, {-frame_offset:+d} counted from 1"
            more = f" and {len(self.duplicates) - 5} more" if len(self.duplicates) > 5 else ""
            n = len(self.duplicates)
            parts.append(f"dropped {n} exact duplicate row{'s' if n > 1 else ''} ({keys}{more})")
        return "; ".join(parts) if parts else "nothing to change"


def drop_exact_duplicates(rows: np.ndarray, label: str = "ground truth"
                          ) -> tuple[np.ndarray, tuple[tuple[int, int], ...]]:
    """Drop rows that repeat an earlier row's frame, id and box exactly.

    Parameters
    ----------
    rows : (N, >=6) float array
        MOT rows.
    label : str
        Names the rows in the error (``--gt FILE``).

    Returns
    -------
    kept : (M, >=6) float array
        The rows without the repeats, in their original order.
    dropped : tuple of (frame, id)
        One entry per dropped row.

    Raises
    ------
    InputError
        A (frame, id) occurs twice with different boxes: that is not a harmless duplicate and no
        metric is defined for it.
    """
    rows = _as_rows(rows, label)
    if len(rows) == 0:
        return rows, ()
    _, first = np.unique(rows[:, :6], axis=0, return_index=True)
    keep = np.zeros(len(rows), bool)
    keep[first] = True
    dropped = tuple((int(r[0]), int(r[1])) for r in rows[~keep])
    kept = rows[keep]
    rep = repeated_frame_id(kept)
    if len(rep):
        f, i = kept[rep[0], :2]
        raise InputError(f"{label}: (frame, id) = ({int(f)}, {int(i)}) occurs twice with "
                         "different boxes")
    return kept, dropped


def fix_ground_truth(rows: np.ndarray, label: str = "ground truth"
                     ) -> tuple[np.ndarray, GroundTruthFix]:
    """Correct a flawed ground truth: reflect negative boxes and drop exact duplicates.

    A box stored with a negative width is taken to have been written from its right edge:
    ``x += w; w = -w`` (likewise ``y``, ``h``), which covers the same pixels with a positive size.

    Parameters
    ----------
    rows : (N, >=6) float array
        MOT rows (frame pixels).

    Returns
    -------
    fixed : (M, >=6) float array
    fix : GroundTruthFix
        What changed; ``fix.describe()`` says it in one line.
    """
    rows, dups = drop_exact_duplicates(rows, label)
    rows = np.array(rows, copy=True)
    neg_w = rows[:, 4] < 0
    neg_h = rows[:, 5] < 0
    rows[neg_w, 2] += rows[neg_w, 4]
    rows[neg_w, 4] *= -1
    rows[neg_h, 3] += rows[neg_h, 5]
    rows[neg_h, 5] *= -1
    neg = neg_w | neg_h
    ids = tuple(int(i) for i in np.unique(rows[neg, 1]))
    return rows, GroundTruthFix(int(neg.sum()), ids, dups)


# --------------------------------------------------------------------------- ignore regions

def drop_ignored(pred: np.ndarray, ignore: np.ndarray, *, min_overlap: float = 0.5
                 ) -> tuple[np.ndarray, int]:
    """Drop predicted boxes that fall in an ignore region of their frame.

    A box is dropped when its centre lies inside an ignore region of the same frame, or when more
    than ``min_overlap`` of its area does (UAVDT's ``*_gt_ignore.txt`` marks areas, such as distant
    parking lots, whose vehicles were not annotated).

    Parameters
    ----------
    pred : (N, >=6) float array
        Predicted MOT rows, frame pixels.
    ignore : (M, >=6) float array
        Ignore regions as MOT rows (``frame, id, x, y, w, h, ...``; id unused), frame pixels.
    min_overlap : float
        Fraction of a box's area inside one region above which the box is dropped.

    Returns
    -------
    kept : (K, >=6) float array
    n_dropped : int
    """
    pred = np.asarray(pred, dtype=np.float64)
    ignore = np.asarray(ignore, dtype=np.float64)
    if len(pred) == 0 or len(ignore) == 0:
        return pred, 0
    drop = np.zeros(len(pred), bool)
    by_frame: dict[int, np.ndarray] = {}
    for f in np.unique(ignore[:, 0]).astype(int):
        by_frame[int(f)] = ignore[ignore[:, 0] == f, 2:6]
    for f in np.unique(pred[:, 0]).astype(int):
        regions = by_frame.get(int(f))
        if regions is None:
            continue
        idx = np.flatnonzero(pred[:, 0] == f)
        b = pred[idx, 2:6]
        cx, cy = b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2
        rx0, ry0 = regions[:, 0], regions[:, 1]
        rx1, ry1 = rx0 + regions[:, 2], ry0 + regions[:, 3]
        centre_in = ((cx[:, None] >= rx0) & (cx[:, None] <= rx1)
                     & (cy[:, None] >= ry0) & (cy[:, None] <= ry1)).any(1)
        iw = np.clip(np.minimum(b[:, 0:1] + b[:, 2:3], rx1) - np.maximum(b[:, 0:1], rx0), 0, None)
        ih = np.clip(np.minimum(b[:, 1:2] + b[:, 3:4], ry1) - np.maximum(b[:, 1:2], ry0), 0, None)
        area = np.maximum(b[:, 2] * b[:, 3], 1e-12)
        ioa = (iw * ih / area[:, None]).max(1)
        drop[idx] = centre_in | (ioa > min_overlap)
    return pred[~drop], int(drop.sum())


def has_consider_flag(gt: np.ndarray) -> bool:
    """Whether the ground truth's 7th column is MOTChallenge's 0/1 "consider" flag: it holds only
    0 and 1, and both (MOT16/17's and VisDrone's ``gt.txt``; a confidence column of 1 everywhere,
    as UAVDT's, of 0 everywhere, or of 0.8 and 0.9, as Santiago's, is not)."""
    gt = np.asarray(gt, dtype=np.float64)
    if gt.ndim != 2 or gt.shape[1] < 7 or not len(gt):
        return False
    flag = gt[:, 6]
    return bool(np.isin(flag, (0.0, 1.0)).all() and (flag == 0).any() and (flag == 1).any())


def drop_unconsidered(gt: np.ndarray, pred: np.ndarray, *, min_iou: float = 0.5
                      ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Leave out the ground-truth rows flagged 0 ("not to be considered") and the predictions
    that match them.

    In each frame predictions and all ground-truth boxes are matched one to one (Hungarian on IoU,
    pairs of at least ``min_iou``), as TrackEval matches MOTChallenge's distractors; predictions
    matched to a flagged box are dropped, so tracking an object the ground truth does not score
    costs nothing, and the flagged rows are dropped. (TrackEval's MOT17 preprocessing does this
    for the pedestrian classes it calls distractors and counts predictions on other flagged
    classes, such as cars, as false positives; for a class-agnostic vehicle benchmark a flagged
    row is one not to score, whatever its class.)

    Returns
    -------
    gt, pred : arrays
        The rows kept.
    n_gt, n_pred : int
        Flagged ground-truth rows and predictions dropped.
    """
    flagged = gt[:, 6] == 0
    gt, pred, n_pred = drop_distractors(gt, pred, flagged, min_iou=min_iou)
    return gt, pred, int(flagged.sum()), n_pred


def drop_distractors(gt: np.ndarray, pred: np.ndarray, distractor: np.ndarray, *,
                     min_iou: float = 0.5) -> tuple[np.ndarray, np.ndarray, int]:
    """Leave out the ground-truth rows marked ``distractor`` (bool per row) and the predictions
    matched to them: in each frame predictions and all ground-truth boxes are matched one to one
    (Hungarian on IoU, pairs of at least ``min_iou``), as TrackEval matches MOTChallenge's
    distractors. Returns ``(gt kept, pred kept, predictions dropped)``."""
    from scipy.optimize import linear_sum_assignment

    flagged = np.asarray(distractor, bool)
    drop = np.zeros(len(pred), bool)
    if len(pred):
        for f in np.unique(gt[flagged, 0]):
            gi = np.flatnonzero(gt[:, 0] == f)
            pi = np.flatnonzero(pred[:, 0] == f)
            if not len(pi):
                continue
            iou = _box_ious(gt[gi, 2:6], pred[pi, 2:6])
            score = np.where(iou >= min_iou - np.finfo(float).eps, iou, 0.0)
            r, c = linear_sum_assignment(-score)
            hit = (score[r, c] > 0) & flagged[gi[r]]
            drop[pi[c[hit]]] = True
    return gt[~flagged], pred[~drop], int(drop.sum())


def split_ignore_classes(gt: np.ndarray, ignore: np.ndarray | None, ignore_classes,
                         column: int, suffix: str = "") -> tuple[np.ndarray, np.ndarray | None]:
    """``(gt, ignore)`` with the ground-truth rows of ``ignore_classes`` moved to the ignore
    regions (first 6 columns)."""
    regions = class_rows(gt, ignore_classes, column, "--ignore-classes")
    if not regions.any():
        return gt, ignore
    given = [] if ignore is None else [_as_rows(ignore, "ignore regions" + suffix)[:, :6]]
    return gt[~regions], np.vstack([*given, gt[regions][:, :6]])


def class_rows(gt: np.ndarray, classes, column: int, label: str = "--classes") -> np.ndarray:
    """Bool per ground-truth row: its class (1-based ``column``) is one of ``classes``. An
    :class:`InputError` when the rows have no such column."""
    if column < 8:
        raise InputError(f"--class-column {column}: the class column comes after the box and "
                         "the confidence (the 7th): 8 or more")
    if gt.shape[1] < column:
        raise InputError(f"{label}: the ground truth has {gt.shape[1]} columns, no class in "
                         f"column {column}")
    return np.isin(np.round(gt[:, column - 1]), np.asarray(sorted(classes), dtype=np.float64))


def frame_offset_overlap(gt: np.ndarray, pred: np.ndarray, offset: int, *,
                         max_frames: int = 300) -> float:
    """Mean over ground-truth boxes of their best IoU with a prediction ``offset`` frames later
    (predicted frame ``f + offset`` against true frame ``f``), on at most ``max_frames`` true
    frames spread over the sequence. Comparing offsets -1, 0 and 1 tells a frame numbering
    mistake (0- against 1-based) from a tracker's error: moving objects overlap best in the
    right frame."""
    gt = np.asarray(gt, dtype=np.float64)
    pred = np.asarray(pred, dtype=np.float64)
    if not len(gt) or not len(pred):
        return 0.0
    frames = np.unique(gt[:, 0])
    if len(frames) > max_frames:
        frames = frames[np.linspace(0, len(frames) - 1, max_frames).round().astype(int)]
    total, n = 0.0, 0
    for f in frames:
        g = gt[gt[:, 0] == f, 2:6]
        p = pred[pred[:, 0] == f + offset, 2:6]
        n += len(g)
        if len(p):
            g, p = g.copy(), p.copy()
            g[:, 2:4], p[:, 2:4] = np.maximum(g[:, 2:4], 0), np.maximum(p[:, 2:4], 0)
            total += float(np.nan_to_num(_box_ious(g, p)).max(axis=1).sum())
    return total / max(n, 1)


# --------------------------------------------------------------------------- TrackEval adapters

def _box_ious(gt_boxes: np.ndarray, pred_boxes: np.ndarray) -> np.ndarray:
    from trackeval.datasets._base_dataset import _BaseDataset

    return _BaseDataset._calculate_box_ious(gt_boxes, pred_boxes, box_format="xywh")


def _as_rows(rows: np.ndarray, label: str) -> np.ndarray:
    """``rows`` as an (N, >=6) float array of MOT rows: finite boxes, frames integers >= 1."""
    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{label}: expected an (N, >=6) array of MOT rows") from None
    if a.size == 0:
        return np.zeros((0, 10))
    if a.ndim != 2 or a.shape[1] < 6:
        raise InputError(f"{label}: expected MOT rows of at least 6 columns, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a[:, :6]).all(axis=1))
    if len(bad):
        raise InputError(f"{label}: row {bad[0]} holds NaN or infinity in its first 6 columns")
    bad = np.flatnonzero((a[:, 0] < 1) | (a[:, 0] != np.round(a[:, 0])))
    if len(bad):
        raise InputError(f"{label}: row {bad[0]} has frame {a[bad[0], 0]:g}; frames are 1-based "
                         "integers (add 1 to 0-based ones)")
    bad = np.flatnonzero(a[:, 1] != np.round(a[:, 1]))
    if len(bad):  # TrackEval truncates such ids: 1000.3 and 1000 would silently be one track
        raise InputError(f"{label}: row {bad[0]} has id {a[bad[0], 1]:g}; ids are integers")
    return a


def _check_tracks(pred: np.ndarray, label: str) -> None:
    """Predicted rows must be tracks: ids >= 0, one row per (frame, id), no negative sizes."""
    if not len(pred):
        return
    bad = np.flatnonzero(pred[:, 1] < 0)
    if len(bad):
        raise InputError(f"{label}: row {bad[0]} has id {pred[bad[0], 1]:g}; tracks need ids >= 0 "
                         "(detections with id -1 are not tracks)")
    bad = np.flatnonzero((pred[:, 4] < 0) | (pred[:, 5] < 0))
    if len(bad):
        raise InputError(f"{label}: row {bad[0]} has a negative box width or height")
    rep = repeated_frame_id(pred)
    if len(rep):
        f, i = pred[rep[0], :2]
        raise InputError(f"{label}: repeated (frame, id) = ({int(f)}, {int(i)})")


def sequence_data(gt: np.ndarray, pred: np.ndarray, *, frames: tuple[int, int] | None = None
                  ) -> dict:
    """Turn MOT rows into TrackEval's per-sequence data dict (one class, ids relabelled 0..n-1).

    Parameters
    ----------
    gt, pred : (N, >=6) float arrays
        MOT rows, 1-based frames, boxes in frame pixels. ``gt`` must hold no repeated (frame, id).
    frames : (int, int), optional
        Inclusive 1-based scoring window; default ``(1, last ground-truth frame)``. Rows of
        either array outside it are dropped.

    Returns
    -------
    dict
        ``num_timesteps, gt_ids, tracker_ids, similarity_scores, num_gt_dets, num_tracker_dets,
        num_gt_ids, num_tracker_ids`` as TrackEval's metrics expect.
    """
    gt, pred = _as_rows(gt, "ground truth"), _as_rows(pred, "prediction")
    if frames is None:
        last = int(gt[:, 0].max()) if len(gt) else (int(pred[:, 0].max()) if len(pred) else 1)
        frames = (1, last)
    first, last = int(frames[0]), int(frames[1])
    if first < 1 or last < first:
        raise InputError(f"scoring window {first}..{last}: expected 1 <= first <= last")
    in_gt = (gt[:, 0] >= first) & (gt[:, 0] <= last)
    in_pred = (pred[:, 0] >= first) & (pred[:, 0] <= last)
    if (~in_pred).any():
        log.info("dropped %d prediction rows outside the scoring frames %d..%d",
                 int((~in_pred).sum()), first, last)
    gt, pred = gt[in_gt], pred[in_pred]
    gt_uid, gt_lab = np.unique(gt[:, 1], return_inverse=True)
    pr_uid, pr_lab = np.unique(pred[:, 1], return_inverse=True)
    T = last - first + 1
    # Only frames holding a true or a predicted box are handed over: TrackEval's metrics skip a
    # frame with neither (CLEAR's "previous frame" survives it), and a window of 50 million
    # frames (one stray frame number) would otherwise take minutes and gigabytes.
    # ``num_timesteps`` stays the window's length (reported as frames).
    gt_f, pr_f = gt[:, 0].astype(np.int64), pred[:, 0].astype(np.int64)
    occupied = np.union1d(gt_f, pr_f)
    gt_ids, tr_ids, sims = [], [], []
    g_order, p_order = np.argsort(gt_f, kind="stable"), np.argsort(pr_f, kind="stable")
    g_lo = np.searchsorted(gt_f[g_order], occupied, "left")
    g_hi = np.searchsorted(gt_f[g_order], occupied, "right")
    p_lo = np.searchsorted(pr_f[p_order], occupied, "left")
    p_hi = np.searchsorted(pr_f[p_order], occupied, "right")
    for k in range(len(occupied)):
        gi = g_order[g_lo[k]:g_hi[k]]
        pi = p_order[p_lo[k]:p_hi[k]]
        gt_ids.append(gt_lab[gi].astype(int))
        tr_ids.append(pr_lab[pi].astype(int))
        if len(gi) and len(pi):
            sims.append(_box_ious(gt[gi, 2:6], pred[pi, 2:6]))
        else:
            sims.append(np.zeros((len(gi), len(pi))))
    return {
        "num_timesteps": T, "gt_ids": gt_ids, "tracker_ids": tr_ids, "similarity_scores": sims,
        "num_gt_dets": int(len(gt)), "num_tracker_dets": int(len(pred)),
        "num_gt_ids": int(len(gt_uid)), "num_tracker_ids": int(len(pr_uid)),
        "seq": "seq", "cls": "vehicle",
    }


def _metrics(iou_threshold: float) -> dict:
    from trackeval.metrics import CLEAR, HOTA, Count, Identity

    cfg = {"THRESHOLD": float(iou_threshold), "PRINT_CONFIG": False}
    with contextlib.redirect_stdout(io.StringIO()):  # TrackEval prints; library code must not
        return {"HOTA": HOTA(), "CLEAR": CLEAR(cfg), "Identity": Identity(cfg), "Count": Count()}


def _check_iou(iou_threshold: float) -> None:
    if not 0.0 < float(iou_threshold) <= 1.0:
        raise InputError(f"--iou: threshold must be in (0, 1], got {iou_threshold}")


def _prepare_gt(gt: np.ndarray, label: str, quiet: bool = False) -> np.ndarray:
    gt, dups = drop_exact_duplicates(_as_rows(gt, label), label)
    if quiet:
        return gt
    if dups:
        log.warning("%s: dropped %s (frames counted from 1)", label,
                    GroundTruthFix(duplicates=dups).describe().removeprefix("dropped "))
    neg = (gt[:, 4] < 0) | (gt[:, 5] < 0) if len(gt) else np.zeros(0, bool)
    if neg.any():
        ids = ", ".join(str(int(i)) for i in np.unique(gt[neg, 1]))
        log.warning("%s: %d boxes with a negative width or height (ids %s) are kept as published "
                    "(they match nothing); --fix-gt reflects them", label, int(neg.sum()), ids)
    zero = (gt[:, 4] == 0) | (gt[:, 5] == 0) if len(gt) else np.zeros(0, bool)
    if zero.any():  # Santiago has 4: a perfect prediction then scores HOTA 0.997, not 1
        ids = ", ".join(str(int(i)) for i in np.unique(gt[zero, 1]))
        log.warning("%s: %d boxes with a zero width or height (ids %s) count as objects no box can "
                    "match (IoU 0)", label, int(zero.sum()), ids)
    return gt


@dataclass
class SequenceScore:
    """Raw TrackEval results of one sequence (kept so sequences can be combined)."""

    name: str
    raw: dict
    ignored: int = 0
    summary: dict = field(default_factory=dict)


def scored_rows(gt: np.ndarray, pred: np.ndarray, *, ignore: np.ndarray | None = None,
                frames: tuple[int, int] | None = None, name: str = "", quiet: bool = False,
                drop_flagged: bool = False, classes=None, ignore_classes=None,
                class_column: int = 8
                ) -> tuple[np.ndarray, np.ndarray, int, tuple[int, int]]:
    """The rows a sequence is scored on: ``(gt, pred, predictions dropped in ignore regions,
    scoring window)``.

    The ground truth loses exact duplicates (with a warning); both lose boxes in ``ignore``
    regions (:func:`drop_ignored`; annotated boxes too, or a perfect prediction would lose them)
    and rows outside the scoring window ``frames`` (default ``1..`` the ground truth's last
    frame). With ``drop_flagged``, a ground truth whose 7th column is MOTChallenge's 0/1
    "consider" flag (:func:`has_consider_flag`) loses its rows flagged 0 and the predictions
    matching them (:func:`drop_unconsidered`); by default every row counts, whatever its
    confidence (the file contract). ``ignore_classes``: ground-truth rows of these classes (in
    1-based ``class_column``; VisDrone's 0, "ignored regions") are ignore regions, added to
    ``ignore``. ``classes``: only rows of these classes are scored; the others (pedestrians
    beside vehicles) are distractors, dropped with the predictions matching them
    (:func:`drop_distractors`), so a class-agnostic tracker is scored on the classes asked for.
    That is a class-agnostic protocol, not MOT17's: TrackEval frees only predictions on its
    distractor classes (2, 7, 8, 12) and counts those on other classes (cars, for a pedestrian
    benchmark) as false positives.
    Predictions must be tracks (ids >= 0, one row per frame and id, no negative size).
    ``eval --geo-crs`` measures its distances on the same rows.
    """
    suffix = f" {name}" if name else ""
    if ignore_classes:  # before the duplicate check: regions have no identity (VisDrone's id 0)
        gt, ignore = split_ignore_classes(_as_rows(gt, "ground truth" + suffix), ignore,
                                          ignore_classes, class_column, suffix)
    gt = _prepare_gt(gt, "ground truth" + suffix, quiet)
    pred = _as_rows(pred, "prediction" + suffix)
    _check_tracks(pred, "prediction" + suffix)
    if frames is None:
        frames = (1, int(gt[:, 0].max()) if len(gt) else
                  (int(pred[:, 0].max()) if len(pred) else 1))
    first, last = int(frames[0]), int(frames[1])
    if first < 1 or last < first:
        raise InputError(f"scoring window {first}..{last}: expected 1 <= first <= last")
    in_pred = (pred[:, 0] >= first) & (pred[:, 0] <= last)
    if (~in_pred).any() and not quiet:
        log.info("%sdropped %d prediction rows outside the scoring frames %d..%d",
                 f"{name}: " if name else "", int((~in_pred).sum()), first, last)
    gt, pred = gt[(gt[:, 0] >= first) & (gt[:, 0] <= last)], pred[in_pred]
    if classes:
        other = ~class_rows(gt, classes, class_column)
        gt, pred, n_pred = drop_distractors(gt, pred, other)
        if not quiet and other.any():
            log.info("%s: %d ground-truth rows of other classes than %s (column %d) are not "
                     "scored, nor the %d predictions matching them", name or "ground truth",
                     int(other.sum()), ",".join(str(c) for c in sorted(classes)), class_column,
                     n_pred)
    if drop_flagged and has_consider_flag(gt):
        gt, pred, n_gt, n_pred = drop_unconsidered(gt, pred)
        if not quiet:
            log.info("%s: %d ground-truth rows flagged 0 in the 7th column (MOTChallenge's "
                     "'consider' flag) are not scored, nor the %d predictions matching them",
                     name or "ground truth", n_gt, n_pred)
    n_ignored = 0
    if ignore is not None:  # after the window: the counts are of the scored frames
        ignore = _as_rows(ignore, "ignore regions" + suffix)
        pred, n_ignored = drop_ignored(pred, ignore)
        gt, n_gt = drop_ignored(gt, ignore)
        if n_gt and not quiet:
            log.info("%s: %d ground-truth boxes in ignore regions dropped", name or "ground truth",
                     n_gt)
    return gt, pred, n_ignored, (first, last)


def _score_sequence(name: str, gt: np.ndarray, pred: np.ndarray, *, iou_threshold: float,
                    ignore: np.ndarray | None, frames: tuple[int, int] | None,
                    drop_flagged: bool = False, **classes) -> SequenceScore:
    gt, pred, n_ignored, frames = scored_rows(gt, pred, ignore=ignore, frames=frames, name=name,
                                              drop_flagged=drop_flagged, **classes)
    data = sequence_data(gt, pred, frames=frames)
    raw = {k: m.eval_sequence(data) for k, m in _metrics(iou_threshold).items()}
    s = SequenceScore(name, raw, n_ignored)
    s.summary = summarise(raw)
    s.summary["ignored_pred"] = n_ignored
    return s


def summarise(raw: Mapping[str, Mapping]) -> dict:
    """The contract's numbers from TrackEval results ``{"HOTA": .., "CLEAR": .., "Identity": ..,
    "Count": ..}`` of one sequence or a combination.

    HOTA, DetA, AssA and LocA are averaged over TrackEval's 19 localisation thresholds (alpha =
    0.05..0.95); MOTP is the mean IoU of CLEAR's matches; rates are fractions.
    """
    h, c, i, n = raw["HOTA"], raw["CLEAR"], raw["Identity"], raw["Count"]
    out = {
        "HOTA": float(np.mean(h["HOTA"])), "DetA": float(np.mean(h["DetA"])),
        "AssA": float(np.mean(h["AssA"])),
        # TrackEval reports LocA 1 when nothing matched (0/0 guarded by 1e-10): undefined here
        "LocA": float(np.mean(h["LocA"])) if np.sum(h["HOTA_TP"]) > 0 else float("nan"),
        "MOTA": float(c["MOTA"]),
        # mean IoU of the matches: undefined without any (TrackEval says 0)
        "MOTP": float(c["MOTP"]) if c["CLR_TP"] > 0 else float("nan"), "IDF1": float(i["IDF1"]),
        "IDSW": int(c["IDSW"]), "Frag": int(c["Frag"]),
        "GT_IDs": int(n["GT_IDs"]), "Pred_IDs": int(n["IDs"]),
        "GT_Dets": int(n["GT_Dets"]), "Pred_Dets": int(n["Dets"]),
        "TP": int(c["CLR_TP"]), "FP": int(c["CLR_FP"]), "FN": int(c["CLR_FN"]),
        "MT": int(c["MT"]), "PT": int(c["PT"]), "ML": int(c["ML"]),
        "IDP": float(i["IDP"]), "IDR": float(i["IDR"]), "HOTA(0)": float(h["HOTA(0)"]),
    }
    return out


def evaluate(gt: np.ndarray, pred: np.ndarray, *, iou_threshold: float = 0.5,
             ignore: np.ndarray | None = None, frames: tuple[int, int] | None = None,
             drop_flagged: bool = False, classes=None, ignore_classes=None,
             class_column: int = 8) -> dict:
    """Score one sequence's predicted tracks against its ground truth (class-agnostic boxes).

    Parameters
    ----------
    gt : (N, >=6) float array
        Ground-truth MOT rows (``frame, id, bb_left, bb_top, bb_width, bb_height, ...``), 1-based
        frames, frame pixels. Every row counts whatever its confidence, unless
        ``drop_flagged``: then a 7th column holding only 0 and 1 is MOTChallenge's "consider"
        flag, and rows flagged 0 are not scored, nor the predictions matching them
        (:func:`drop_unconsidered`). Exact duplicate rows are dropped with a warning; negative sizes are kept
        (see the module docstring).
    pred : (M, >=6) float array
        Predicted MOT rows in the same frame and pixel convention.
    iou_threshold : float
        IoU a match needs in CLEAR (MOTA, IDSW, Frag) and Identity (IDF1). HOTA always integrates
        over its own thresholds 0.05..0.95.
    ignore : (K, >=6) float array, optional
        Ignore regions as MOT rows; predicted (and ground-truth) boxes inside one are dropped
        first (:func:`drop_ignored`).
    frames : (int, int), optional
        Inclusive scoring window, default ``1..`` the ground truth's last frame.
    classes, ignore_classes : iterable of int, optional
        Score only ground-truth rows of these classes (others are distractors); rows of
        ``ignore_classes`` are ignore regions (:func:`scored_rows`). Classes are read from the
        1-based ``class_column`` (8: MOTChallenge, VisDrone; 9 in UAVDT's ``*_gt_whole.txt``).

    Returns
    -------
    dict
        The contract's keys :data:`METRIC_KEYS` (HOTA family averaged over alpha, MOTP as mean IoU,
        fractions) plus :data:`EXTRA_KEYS` and ``ignored_pred``.
    """
    _check_iou(iou_threshold)
    return _score_sequence("", gt, pred, iou_threshold=iou_threshold, ignore=ignore,
                           frames=frames, drop_flagged=drop_flagged, classes=classes,
                           ignore_classes=ignore_classes, class_column=class_column).summary


def evaluate_sequences(sequences: Mapping[str, Sequence], *, iou_threshold: float = 0.5,
                       frames: Mapping[str, tuple[int, int]] | None = None,
                       drop_flagged: bool = False, classes=None, ignore_classes=None,
                       class_column: int = 8) -> dict:
    """Score several sequences and combine them as TrackEval does.

    Parameters
    ----------
    sequences : mapping name -> (gt, pred) or (gt, pred, ignore)
        Arrays as in :func:`evaluate`; ``ignore`` may be None.
    iou_threshold : float
        As in :func:`evaluate`.
    frames : mapping name -> (first, last), optional
        Per-sequence scoring windows.
    drop_flagged : bool
        Leave out ground-truth rows flagged 0 in a MOTChallenge "consider" column
        (:func:`evaluate`).
    classes, ignore_classes, class_column
        As in :func:`evaluate`.

    Returns
    -------
    dict
        ``{"combined": {...}, "sequences": {name: {...}}}``. Combined counts are sums; HOTA's
        DetA/AssA/LocA, MOTA, MOTP and IDF1 are recomputed from the summed counts (TrackEval's
        ``combine_sequences``), so longer, busier sequences weigh more.
    """
    _check_iou(iou_threshold)
    if not sequences:
        raise InputError("no sequences to evaluate")
    scores = {}
    for name, entry in sequences.items():
        if not isinstance(entry, Sequence) or not 2 <= len(entry) <= 3:
            raise InputError(f"sequence {name!r}: expected (gt, pred) or (gt, pred, ignore)")
        gt, pred = entry[0], entry[1]
        ign = entry[2] if len(entry) > 2 else None
        scores[name] = _score_sequence(name, gt, pred, iou_threshold=iou_threshold, ignore=ign,
                                       frames=(frames or {}).get(name),
                                       drop_flagged=drop_flagged, classes=classes,
                                       ignore_classes=ignore_classes, class_column=class_column)
    metrics = _metrics(iou_threshold)
    combined_raw = {k: m.combine_sequences({n: s.raw[k] for n, s in scores.items()})
                    for k, m in metrics.items()}
    combined = summarise(combined_raw)
    combined["ignored_pred"] = sum(s.ignored for s in scores.values())
    return {"combined": combined, "sequences": {n: s.summary for n, s in scores.items()}}

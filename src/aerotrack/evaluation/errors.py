"""Where tracks go wrong against a ground truth: CLEAR-MOT's matching, box by box.

The scores say how much is wrong; this says what and where. :func:`clear_matching` repeats
TrackEval's CLEAR matching frame by frame (the same rule, so its counts are the scores'
TP, FP, FN and IDSW) and keeps every box's outcome:

* ``match``: a true box matched by a predicted one (IoU >= the threshold);
* ``switch``: a match whose track is not the one that last matched this target (an ID switch);
* ``miss``: a true box no prediction matched (a false negative);
* ``false``: a predicted box that matched no true box (a false positive).

The rule, as TrackEval's ``CLEAR.eval_sequence``: in each frame holding a true and a predicted box,
pairs below the IoU threshold are impossible, a pair that continues the match of the previous such
frame is preferred above everything (weight 1000), then IoU is maximised (Hungarian). A switch is
counted against the track that matched the target last, however long ago. Frames with only true
or only predicted boxes neither break nor continue a match (TrackEval's quirk, kept so the counts
agree).

:func:`target_summaries` condenses the matching per true target (found fraction, the tracks that
covered it, switches, the longest run of misses): the table a user reads to see which vehicle was
lost and for how long.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .mot import _box_ious

KINDS = ("match", "switch", "miss", "false")
#: ``eval --errors``' columns (:func:`error_rows_csv`)
CSV_COLUMNS = ("sequence", "frame", "kind", "gt_id", "track_id", "previous_id", "x", "y", "w", "h",
               "iou", "near_id", "near_iou")
MATCH, SWITCH, MISS, FALSE = range(4)
_EPS = np.finfo(float).eps


@dataclass(frozen=True)
class Matching:
    """Every scored box of one sequence and what became of it; parallel arrays of length N.

    Attributes
    ----------
    frame : (N,) int64
        1-based frame.
    kind : (N,) int8
        Index into :data:`KINDS` (``match``, ``switch``, ``miss``, ``false``).
    gt_id : (N,) int64
        The true target (-1 for ``false``).
    track_id : (N,) int64
        The predicted track (-1 for ``miss``).
    previous_id : (N,) int64
        For ``switch``: the track that matched the target before; -1 otherwise.
    box : (N, 4) float64
        ``x, y, w, h`` in frame pixels: the true box, or the predicted one for ``false``.
    pred_box : (N, 4) float64
        The matched predicted box of ``match`` and ``switch`` rows; NaN otherwise.
    iou : (N,) float64
        IoU of a match or switch; NaN otherwise.
    near_id : (N,) int64
        For ``miss``: the predicted track whose box overlaps the true box most (IoU > 0, below
        the threshold or taken by another target); for ``false``: the true target overlapping
        the predicted box most. -1 when nothing overlaps, and for matches. A miss and a false
        box that are each other's nearest are one loose or shifted box, not a lost vehicle and
        a ghost.
    near_iou : (N,) float64
        That overlap's IoU; NaN with ``near_id`` -1.
    """

    frame: np.ndarray
    kind: np.ndarray
    gt_id: np.ndarray
    track_id: np.ndarray
    previous_id: np.ndarray
    box: np.ndarray
    pred_box: np.ndarray
    iou: np.ndarray
    near_id: np.ndarray
    near_iou: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)

    @property
    def errors(self) -> np.ndarray:
        """Boolean mask of the rows that are errors (switch, miss, false)."""
        return self.kind != MATCH

    def counts(self) -> dict[str, int]:
        """``TP, FP, FN, IDSW`` as CLEAR counts them (a switch is also a true positive)."""
        k = self.kind
        return {"TP": int(np.sum((k == MATCH) | (k == SWITCH))), "FP": int(np.sum(k == FALSE)),
                "FN": int(np.sum(k == MISS)), "IDSW": int(np.sum(k == SWITCH))}


def _rows(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return a if a.ndim == 2 and a.shape[1] >= 6 else a.reshape(0, 6)


def clear_matching(gt: np.ndarray, pred: np.ndarray, *, iou_threshold: float = 0.5) -> Matching:
    """CLEAR-MOT's per-frame matching of ``pred`` to ``gt`` (see the module docstring).

    Parameters
    ----------
    gt, pred : (N, >=6) float arrays
        MOT rows (``frame, id, x, y, w, h, ...``, 1-based frames, frame pixels) as scored: the
        scoring window, ignore regions and ground-truth corrections already applied
        (:func:`aerotrack.evaluation.mot.scored_rows`). One row per (frame, id) in each.
    iou_threshold : float
        IoU a match needs.

    Returns
    -------
    Matching
        Rows ordered by frame; within a frame, true boxes in file order, then false positives.
    """
    gt, pred = _rows(gt), _rows(pred)
    gf, pf = gt[:, 0].astype(np.int64), pred[:, 0].astype(np.int64)
    g_order, p_order = np.argsort(gf, kind="stable"), np.argsort(pf, kind="stable")
    frames = np.union1d(gf, pf)
    g_lo, g_hi = np.searchsorted(gf[g_order], frames), np.searchsorted(gf[g_order], frames, "right")
    p_lo, p_hi = np.searchsorted(pf[p_order], frames), np.searchsorted(pf[p_order], frames, "right")
    last_track: dict[int, int] = {}  # the track that matched each target last (for switches)
    step_track: dict[int, int] = {}  # ... in the previous frame holding both kinds of box
    cols: dict[str, list] = {k: [] for k in ("frame", "kind", "gt", "tr", "prev", "box", "pbox",
                                             "iou", "near", "near_iou")}

    def add(frame, kind, g, t, prev, box, pbox, iou, near=-1, near_iou=np.nan):
        for k, v in (("frame", frame), ("kind", kind), ("gt", g), ("tr", t), ("prev", prev),
                     ("box", box), ("pbox", pbox), ("iou", iou), ("near", near),
                     ("near_iou", near_iou)):
            cols[k].append(v)

    nan4 = np.full(4, np.nan)
    for k, f in enumerate(frames.tolist()):
        gi = g_order[g_lo[k]:g_hi[k]]
        pi = p_order[p_lo[k]:p_hi[k]]
        g_ids = gt[gi, 1].astype(np.int64)
        p_ids = pred[pi, 1].astype(np.int64)
        matched_g: dict[int, tuple[int, float]] = {}
        sim = np.zeros((len(gi), len(pi)))
        if len(gi) and len(pi):
            sim = _box_ious(gt[gi, 2:6], pred[pi, 2:6])
            prev = np.array([step_track.get(int(g), -(2 ** 62)) for g in g_ids])
            score = 1000.0 * (p_ids[None, :] == prev[:, None]) + sim
            score[sim < iou_threshold - _EPS] = 0.0
            rows, cs = linear_sum_assignment(-score)
            keep = score[rows, cs] > _EPS
            rows, cs = rows[keep], cs[keep]
            matched_g = {int(r): (int(c), float(sim[r, c])) for r, c in zip(rows, cs)}
            step_track = {int(g_ids[r]): int(p_ids[c]) for r, c in zip(rows, cs)}
        for r in range(len(gi)):
            g = int(g_ids[r])
            box = gt[gi[r], 2:6]
            if r in matched_g:
                c, iou = matched_g[r]
                t = int(p_ids[c])
                before = last_track.get(g)
                switched = before is not None and before != t
                add(f, SWITCH if switched else MATCH, g, t, before if switched else -1, box,
                    pred[pi[c], 2:6], iou)
                last_track[g] = t
            else:
                near = int(np.argmax(sim[r])) if len(pi) and sim[r].max() > 0 else -1
                add(f, MISS, g, -1, -1, box, nan4, np.nan, int(p_ids[near]) if near >= 0 else -1,
                    float(sim[r, near]) if near >= 0 else np.nan)
        used = {c for c, _ in matched_g.values()}
        for c in range(len(pi)):
            if c not in used:
                near = int(np.argmax(sim[:, c])) if len(gi) and sim[:, c].max() > 0 else -1
                add(f, FALSE, -1, int(p_ids[c]), -1, pred[pi[c], 2:6], nan4, np.nan,
                    int(g_ids[near]) if near >= 0 else -1,
                    float(sim[near, c]) if near >= 0 else np.nan)
    n = len(cols["frame"])
    return Matching(
        frame=np.asarray(cols["frame"], dtype=np.int64),
        kind=np.asarray(cols["kind"], dtype=np.int8),
        gt_id=np.asarray(cols["gt"], dtype=np.int64),
        track_id=np.asarray(cols["tr"], dtype=np.int64),
        previous_id=np.asarray(cols["prev"], dtype=np.int64),
        box=np.asarray(cols["box"], dtype=np.float64).reshape(n, 4),
        pred_box=np.asarray(cols["pbox"], dtype=np.float64).reshape(n, 4),
        iou=np.asarray(cols["iou"], dtype=np.float64),
        near_id=np.asarray(cols["near"], dtype=np.int64),
        near_iou=np.asarray(cols["near_iou"], dtype=np.float64),
    )


@dataclass(frozen=True)
class TargetSummary:
    """What the tracks made of one true target.

    Attributes
    ----------
    gt_id : int
    first_frame, last_frame : int
        Its first and last annotated frames (scored ones).
    frames : int
        Frames it is annotated in.
    found : int
        Of those, frames a track matched it.
    tracks : tuple of (int, int)
        The tracks that matched it, ``(track id, frames)``, in the order they first did.
    switches : int
        ID switches on it (CLEAR's IDSW).
    longest_miss : int
        The longest run of its annotated frames that no track matched.
    """

    gt_id: int
    first_frame: int
    last_frame: int
    frames: int
    found: int
    tracks: tuple[tuple[int, int], ...]
    switches: int
    longest_miss: int

    @property
    def found_fraction(self) -> float:
        return self.found / self.frames if self.frames else float("nan")

    @property
    def found_percent(self) -> str:
        """``found`` in whole percent, rounded down: 399 of 400 frames is 99 %, not 100 %."""
        return f"{100 * self.found // self.frames} %" if self.frames else "–"


def target_summaries(matching: Matching) -> list[TargetSummary]:
    """One :class:`TargetSummary` per true target of ``matching``, by ground-truth id."""
    out = []
    on_target = matching.gt_id >= 0
    for g in np.unique(matching.gt_id[on_target]).tolist():
        sel = np.flatnonzero(matching.gt_id == g)  # rows are in frame order
        kind, frames = matching.kind[sel], matching.frame[sel]
        hit = kind != MISS
        tracks: dict[int, int] = {}
        for t in matching.track_id[sel][hit].tolist():
            tracks[t] = tracks.get(t, 0) + 1
        longest = run = 0
        for h in hit.tolist():
            run = 0 if h else run + 1
            longest = max(longest, run)
        out.append(TargetSummary(
            gt_id=int(g), first_frame=int(frames[0]), last_frame=int(frames[-1]),
            frames=int(len(sel)), found=int(hit.sum()), tracks=tuple(tracks.items()),
            switches=int(np.sum(kind == SWITCH)), longest_miss=int(longest)))
    return out


def error_rows_csv(matchings: dict[str, Matching], *, frame_offset: int = 0) -> str:
    """The errors of each sequence's matching as CSV text (header :data:`CSV_COLUMNS`: the true
    box, the predicted one for ``false``); ``frame_offset`` is added to the frames (-1 writes
    them 0-based, as the files were given)."""
    lines = [",".join(CSV_COLUMNS)]
    for name, m in matchings.items():
        seq = name.replace('"', '""')
        seq = f'"{seq}"' if any(ch in seq for ch in ',"\n') else seq
        for i in np.flatnonzero(m.errors).tolist():
            x, y, w, h = (f"{v:.2f}" for v in m.box[i])
            iou = "" if np.isnan(m.iou[i]) else f"{m.iou[i]:.3f}"
            near = "" if np.isnan(m.near_iou[i]) else f"{m.near_iou[i]:.3f}"
            lines.append(f"{seq},{int(m.frame[i]) + frame_offset},{KINDS[m.kind[i]]},"
                         f"{int(m.gt_id[i])},{int(m.track_id[i])},{int(m.previous_id[i])},"
                         f"{x},{y},{w},{h},{iou},{int(m.near_id[i])},{near}")
    return "\n".join(lines) + "\n"


def false_tracks(matching: Matching) -> list[tuple[int, int, int]]:
    """``(track id, scored boxes, boxes that matched no target)`` of every track with a false
    positive, most false boxes first: tracks of vehicles the ground truth leaves out (parked
    ones, a mover the annotators skipped), ghosts, and the ends of tracks that outlive their
    target."""
    on = matching.track_id >= 0
    ids, total = np.unique(matching.track_id[on], return_counts=True)
    false = matching.kind[on] == FALSE
    n_false = np.bincount(np.searchsorted(ids, matching.track_id[on][false]), minlength=len(ids))
    order = np.lexsort((ids, -n_false))
    return [(int(ids[i]), int(total[i]), int(n_false[i])) for i in order if n_false[i]]

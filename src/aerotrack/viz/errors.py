"""Pictures of a run's errors against a ground truth (:mod:`aerotrack.evaluation.errors`).

* :func:`plot_errors`: misses and false positives per frame, ID switches marked, and one row per
  true target coloured by the track that covered it (grey where it was missed): which vehicle was
  lost, when, and to which ID it went.
* :func:`draw_errors`: one frame with its true boxes (thin green when found, thick yellow when
  missed, magenta at a switch) and the false positives (red), labelled.
* :func:`worst_frames`: the frames to look at first (most errors, spread over the run).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..evaluation.errors import FALSE, MATCH, MISS, SWITCH, Matching, target_summaries
from .colours import id_rgb
from .mapplot import _figure

MAX_TARGET_ROWS = 60

#: BGR colours of :func:`draw_errors` (and the legend of the report)
FOUND_BGR, MISS_BGR, SWITCH_BGR, FALSE_BGR = (60, 180, 60), (0, 215, 255), (255, 0, 255), (40, 40, 230)


def plot_errors(matching: Matching, fps: float, *, first_frame: int = 1):
    """The error timeline and the per-target coverage chart of ``matching``; None without any
    true or predicted box.

    Targets are ordered by their first frame; past :data:`MAX_TARGET_ROWS` only the least found
    are drawn (the title says how many are left out). Times are seconds from ``first_frame``.
    """
    if not len(matching):
        return None
    t0 = first_frame
    frames = np.arange(int(matching.frame.min()), int(matching.frame.max()) + 1)
    idx = matching.frame - frames[0]
    n_miss = np.bincount(idx[matching.kind == MISS], minlength=len(frames))
    n_false = np.bincount(idx[matching.kind == FALSE], minlength=len(frames))
    sw = matching.kind == SWITCH
    t = (frames - t0) / fps
    summaries = target_summaries(matching)
    shown = summaries
    if len(shown) > MAX_TARGET_ROWS:  # those with switches first, then the least found
        shown = sorted(shown, key=lambda s: (-min(s.switches, 1), s.found_fraction,
                                             s.gt_id))[:MAX_TARGET_ROWS]
    shown = sorted(shown, key=lambda s: (s.first_frame, s.gt_id))
    rows = max(len(shown), 1)
    fs = 10.0  # points: the rows are a fixed height, so are the labels
    fig = _figure(12.0, 2.4 + 0.2 * rows, layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True,
                               gridspec_kw={"height_ratios": [2.0, max(1.0, 0.2 * rows)]})
    top.step(t, n_miss, where="mid", color="#d08a00", lw=1.3, label="missed true boxes")
    top.step(t, n_false, where="mid", color="#d62728", lw=1.3, label="false positives")
    if sw.any():  # ticks along the top, not lines through the curves
        ts = (matching.frame[sw] - t0) / fps
        top.plot(ts, np.full(len(ts), 1.0), "v", color="#c000c0", ms=5, alpha=0.8,
                 transform=top.get_xaxis_transform(), clip_on=False, label="ID switch")
    top.set_ylabel("boxes", fontsize=fs)
    top.legend(fontsize=fs * 0.9, loc="upper left", bbox_to_anchor=(0, -0.02, 1, 1), ncol=3,
               frameon=False, mode=None)
    top.grid(alpha=0.3)
    counts = matching.counts()
    left_out = len(summaries) - len(shown)
    top.set_title(f"{counts['FN']} missed, {counts['FP']} false, {counts['IDSW']} ID "
                  f"switch{'' if counts['IDSW'] == 1 else 'es'}", fontsize=fs + 1)
    bottom.set_title("each true target coloured by the track that found it; grey: missed; "
                     "white: not annotated" + (f"; {left_out} targets without a switch and best "
                                              "found not drawn" if left_out else ""),
                     fontsize=fs)
    half = 0.5 / fps
    for row, s in enumerate(shown):
        sel = matching.gt_id == s.gt_id
        tt = (matching.frame[sel] - t0) / fps
        tracks, kinds = matching.track_id[sel], matching.kind[sel]
        colours = [(0.72, 0.72, 0.72) if k == MISS else id_rgb(int(i))
                   for k, i in zip(kinds.tolist(), tracks.tolist())]
        # one bar per run of equal colour, so a long run is one rectangle
        start = 0
        for j in range(1, len(tt) + 1):
            if j == len(tt) or colours[j] != colours[start] or tt[j] - tt[j - 1] > 1.5 / fps:
                bottom.broken_barh([(tt[start] - half, tt[j - 1] - tt[start] + 2 * half)],
                                   (row - 0.4, 0.8), facecolors=[colours[start]])
                start = j
        for ts in tt[kinds == SWITCH]:
            bottom.plot([ts, ts], [row - 0.5, row + 0.5], color="#c000c0", lw=1.6)
    bottom.set_yticks(range(len(shown)))
    bottom.set_yticklabels([f"gt {s.gt_id}" for s in shown], fontsize=fs * 0.8)
    bottom.tick_params(axis="y", length=0)
    bottom.set_ylim(len(shown) - 0.5, -0.5)
    bottom.set_xlabel("time (s)", fontsize=fs)
    for ax in (top, bottom):
        ax.tick_params(axis="x", labelsize=fs * 0.9)
    return fig


def worst_frames(matching: Matching, fps: float, count: int = 4) -> list[int]:
    """Up to ``count`` frames with the most errors (ties: the earliest), at least a second apart,
    in frame order."""
    err = matching.errors
    if not err.any():
        return []
    frames, n = np.unique(matching.frame[err], return_counts=True)
    order = np.lexsort((frames, -n))
    picked: list[int] = []
    gap = max(1, int(round(fps)))
    for i in order.tolist():
        f = int(frames[i])
        if all(abs(f - p) >= gap for p in picked):
            picked.append(f)
            if len(picked) == count:
                break
    return sorted(picked)


def draw_errors(image: np.ndarray, matching: Matching, frame: int, *,
                width: int | None = None) -> np.ndarray:
    """``image`` (BGR, the frame's pixels) with ``frame``'s true and false boxes drawn, resized to
    at most ``width`` pixels first (so the labels keep their size); a new array.

    Labels go where they cover no other box or label (:func:`aerotrack.viz.overlay._label`),
    switches first, then misses, then false positives (skipped when no place is free). A miss
    or a false box that overlaps a box of the other kind names it ("near id 5"): one loose box,
    not a lost vehicle and a ghost.
    """
    from .overlay import _label, _Rects

    h0, w0 = image.shape[:2]
    k = 1.0
    if width is not None and w0 > width:
        k = width / w0
        out = cv2.resize(image, (width, max(1, int(round(h0 * k)))), interpolation=cv2.INTER_AREA)
    else:
        out = image.copy()
    h, w = out.shape[:2]
    thick = max(1, int(round(min(h, w) / 500)))
    scale = max(0.4, min(h, w) / 1300)
    sel = np.flatnonzero(matching.frame == frame)
    boxes = np.round(matching.box[sel] * k).astype(np.int64)
    corners = np.c_[boxes[:, :2], boxes[:, :2] + boxes[:, 2:]]
    style = {MATCH: (FOUND_BGR, thick), SWITCH: (SWITCH_BGR, thick + 1),
             MISS: (MISS_BGR, thick + 1), FALSE: (FALSE_BGR, thick + 1)}
    for j, i in enumerate(sel.tolist()):
        colour, lw = style[int(matching.kind[i])]
        cv2.rectangle(out, tuple(corners[j, :2].tolist()), tuple(corners[j, 2:].tolist()), colour,
                      lw, cv2.LINE_AA)
    placed = _Rects()
    for kind in (SWITCH, MISS, FALSE):
        for j in np.flatnonzero(matching.kind[sel] == kind).tolist():
            i = int(sel[j])
            g, t, near = int(matching.gt_id[i]), int(matching.track_id[i]), int(matching.near_id[i])
            if kind == SWITCH:
                text = f"gt {g}: id {int(matching.previous_id[i])}->{t}"
            elif kind == MISS:
                text = f"gt {g} missed" + (f" (near id {near})" if near >= 0 else "")
            else:
                text = f"id {t} false" + (f" (near gt {near})" if near >= 0 else "")
            x0, y0, x1, y1 = corners[j].tolist()
            _label(out, text, x0, y0, y1, style[kind][0], scale, 1, placed=placed,
                   optional=kind == FALSE, right=x1, avoid=np.delete(corners, j, axis=0))
    return out

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
from .mapplot import _figure, _font_pt

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
    if len(shown) > MAX_TARGET_ROWS:
        shown = sorted(shown, key=lambda s: (s.found_fraction, s.gt_id))[:MAX_TARGET_ROWS]
    shown = sorted(shown, key=lambda s: (s.first_frame, s.gt_id))
    rows = max(len(shown), 1)
    fig = _figure(12.0, 2.6 + 0.22 * rows, layout="constrained")
    fs = max(_font_pt(fig, 0.012), 10.0)
    top, bottom = fig.subplots(2, 1, sharex=True,
                               gridspec_kw={"height_ratios": [2.2, max(1.0, 0.22 * rows)]})
    top.step(t, n_miss, where="mid", color="#d08a00", lw=1.3, label="missed true boxes")
    top.step(t, n_false, where="mid", color="#d62728", lw=1.3, label="false positives")
    for ts in np.unique((matching.frame[sw] - t0) / fps):
        top.axvline(ts, color="#c000c0", lw=1.0, alpha=0.8)
    if sw.any():
        top.plot([], [], color="#c000c0", lw=1.0, label="ID switch")
    top.set_ylabel("boxes", fontsize=fs)
    top.legend(fontsize=fs * 0.85, loc="upper right", ncol=3, frameon=False)
    top.grid(alpha=0.3)
    counts = matching.counts()
    left_out = len(summaries) - len(shown)
    top.set_title(f"errors: {counts['FN']} missed, {counts['FP']} false, {counts['IDSW']} ID "
                  f"switches; below, each true target coloured by the track that found it "
                  f"(grey: missed){f'; {left_out} best-found targets not drawn' if left_out else ''}",
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
    bottom.set_ylim(len(shown) - 0.5, -0.5)
    bottom.set_xlabel("time (s)", fontsize=fs)
    for ax in (top, bottom):
        ax.tick_params(labelsize=fs * 0.85)
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


def draw_errors(image: np.ndarray, matching: Matching, frame: int) -> np.ndarray:
    """``image`` (BGR, the frame's pixels) with ``frame``'s true and false boxes drawn (a copy)."""
    out = image.copy()
    h, w = out.shape[:2]
    thick = max(1, int(round(min(h, w) / 400)))
    font = max(0.35, min(h, w) / 1400)
    sel = np.flatnonzero(matching.frame == frame)
    for i in sel.tolist():
        k = int(matching.kind[i])
        x, y, bw, bh = matching.box[i]
        p0, p1 = (int(round(x)), int(round(y))), (int(round(x + bw)), int(round(y + bh)))
        if k == MATCH:
            cv2.rectangle(out, p0, p1, FOUND_BGR, thick, cv2.LINE_AA)
            continue
        g, t = int(matching.gt_id[i]), int(matching.track_id[i])
        colour, label = {MISS: (MISS_BGR, f"gt {g} missed"),
                         SWITCH: (SWITCH_BGR, f"gt {g}: {int(matching.previous_id[i])}->{t}"),
                         FALSE: (FALSE_BGR, f"id {t} false")}[k]
        cv2.rectangle(out, p0, p1, colour, thick + 1, cv2.LINE_AA)
        (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, font, 1)
        ty = p0[1] - 3 if p0[1] - th - 4 >= 0 else min(h - 2, p1[1] + th + 3)
        tx = min(max(0, p0[0]), max(0, w - tw - 1))
        cv2.rectangle(out, (tx - 1, ty - th - 2), (tx + tw + 1, ty + base - 1), (0, 0, 0), -1)
        cv2.putText(out, label, (tx, ty - 1), cv2.FONT_HERSHEY_SIMPLEX, font, colour, 1,
                    cv2.LINE_AA)
    return out

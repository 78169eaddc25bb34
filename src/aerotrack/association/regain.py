"""Detections regained inside a linked track's gaps.

Global linking joins a target's tracklets across a gap and reports the frames between as
predicted (believed out of view). Often the target was in view for some of them and the detector
saw it: local association had left those detections out (a run too short to be a tracklet, a
blob it could not explain). Once both ends of the gap are known, the target's path through it is
well constrained (interpolated between its last sighting before and its first after), so a
detection lying on that path, which no other track claims, is the target itself.

Not in the papers: an offline tracker's second pass over its own gaps (tracklet interpolation
with re-detection). Measured on the 18 held-out generated scenes, where 585 missed true boxes
had a detection at IoU >= 0.5 but no track box (most of them inside a track's predicted gap).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable

import numpy as np

from ..types import Detections, Registration, Track, TrackPoint, apply_homography, box_iou

log = logging.getLogger(__name__)

IN_VIEW = ("observed", "bridged", "stationary")


#: observed points at a track's end that give its velocity for :func:`regain_gap_detections`'
#: ``end_s``
EDGE_POINTS = 5
#: a larger step between two of them ends the run the velocity is fitted over (processed frames)
END_RUN_GAP = 3


def regain_gap_detections(tracks: list[Track], detections: Iterable[Detections], *,
                          fps: float, max_gap_s: float, min_iou: float, end_s: float = 0.0,
                          registrations: dict[int, Registration] | None = None,
                          still_H: np.ndarray | None = None) -> int:
    """Claim, in place, the detections that lie on a track's path through its gaps.

    For every gap of at most ``max_gap_s`` between two sightings (observed points) of a track,
    at each frame of the gap where the track is not in view (a predicted point, or none; local
    association's bridged misses are its own decision), the box is interpolated: the ground point linearly in time between
    the two sightings' (world coordinates), seen through that frame's registration, and the
    width and height linearly between theirs (frame pixels). A detection of that frame whose
    box overlaps it at IoU >= ``min_iou`` (the best one) becomes an observed point of the track,
    unless another track's in-view box of that frame is on it (IoU > 0.3: it holds it, or has
    claimed it here).

    Parameters
    ----------
    tracks : list of Track
        Linked tracks (world coordinates: map pixels, frame-1 pixels, or frame pixels without
        registrations).
    detections : iterable of Detections
        The run's detections (frame pixels), any order.
    registrations : dict frame -> Registration, optional
        Frame -> world homographies; without them world is frame pixels, or the map placement
        ``still_H`` (detections alone on a map).

    ``end_s``: past a track's last in-view frame (and before its first), for up to this long,
    the track is carried on at the velocity of its last (first) :data:`EDGE_POINTS`
    observations, frame by frame, claiming detections the same way until a frame has none.

    Returns
    -------
    int
        Detections claimed.
    """
    if (max_gap_s <= 0 and end_s <= 0) or not tracks:
        return 0
    detections = list(detections)
    by_frame = {int(d.frame): d for d in detections if len(d)}
    if not by_frame:
        return 0
    frames_run = sorted({int(d.frame) for d in detections})  # (with --stride, every N-th)
    stride = max(1, int(np.median(np.diff(frames_run)))) if len(frames_run) > 1 else 1
    max_frames = int(round(max_gap_s * fps))
    end_frames = int(round(end_s * fps))
    # what the tracks hold, by box: a point's ``det_index`` indexes the detections local
    # association saw, which need not be these (split merged blobs, followed vehicles, an
    # overlay's or a region's detections dropped after association)
    boxes_at: dict[int, list[tuple[int, np.ndarray]]] = {}
    for t in tracks:
        for p in t.points:
            if p.kind in IN_VIEW and p.box is not None and np.all(np.isfinite(p.box)):
                boxes_at.setdefault(p.frame, []).append((t.id, np.asarray(p.box, np.float64)))
    inv_still = np.linalg.inv(still_H) if still_H is not None else None

    def to_frame(f: int) -> np.ndarray | None | bool:
        """World -> frame f pixels (None: identity); False when frame f has no registration."""
        if registrations is None:
            return inv_still
        reg = registrations.get(f)
        return False if reg is None else np.linalg.inv(reg.H)

    def claim(t: Track, f: int, w: np.ndarray, size: np.ndarray) -> TrackPoint | None:
        """The best free detection of frame ``f`` on the box of ground point ``w`` and pixel
        ``size``, as an observed point of ``t`` (marked held), or None."""
        d = by_frame.get(f)
        H = to_frame(f)
        if d is None or H is False:
            return None
        c = w if H is None else apply_homography(H, w[None])[0]
        box = np.array([c[0] - size[0] / 2, c[1] - size[1] / 2, size[0], size[1]])
        iou = box_iou(box, d.boxes)[0]
        others = np.array([q for tid, q in boxes_at.get(f, []) if tid != t.id]).reshape(-1, 4)
        for k in np.argsort(-iou):
            if iou[k] < min_iou:
                return None
            if len(others) and box_iou(d.boxes[k], others).max() > 0.3:
                continue  # held by another track (or on its box)
            boxes_at.setdefault(f, []).append((t.id, np.asarray(d.boxes[k], np.float64)))
            return TrackPoint(
                frame=f, box=np.asarray(d.boxes[k], np.float64).copy(),
                world=np.asarray(d.world[k], np.float64).copy(), conf=float(d.conf[k]),
                kind="observed", det_index=int(k),
                size_world=None if d.size_world is None else
                np.asarray(d.size_world[k], np.float64).copy(),
                hist=None if d.hist is None else d.hist[k])
        return None

    claimed = 0
    for t in tracks:
        seen = [p for p in t.points if p.kind == "observed" and p.box is not None
                and np.all(np.isfinite(p.box))]
        # frames local association already decided (its bridged misses) are left to it: it
        # weighed those detections with the motion and appearance of the whole window
        in_view = {p.frame for p in t.points if p.kind in IN_VIEW}
        new_points: dict[int, TrackPoint] = {}
        for a, b in itertools.pairwise(seen):
            gap = b.frame - a.frame - 1
            if gap < 1 or gap > max_frames:
                continue
            wa, wb = np.asarray(a.world, np.float64), np.asarray(b.world, np.float64)
            sa, sb = np.asarray(a.box, np.float64)[2:], np.asarray(b.box, np.float64)[2:]
            for f in range(a.frame + 1, b.frame):
                if f in in_view:
                    continue
                u = (f - a.frame) / (b.frame - a.frame)
                p = claim(t, f, (1 - u) * wa + u * wb, (1 - u) * sa + u * sb)
                if p is not None:
                    new_points[f] = p
        if end_frames > 0 and len(seen) >= 2:
            first = min(p.frame for p in t.points if p.kind in IN_VIEW)
            last = max(p.frame for p in t.points if p.kind in IN_VIEW)
            for ends, step in ((seen[::-1], 1), (seen, -1)):  # after the end, before the start
                if ends[0].frame != (last if step > 0 else first):
                    continue  # the track ends bridged or standing: not where it was seen going
                run = _end_run(ends, stride)
                if len(run) < 2:
                    continue
                fr = np.array([p.frame for p in run], np.float64)
                xy = np.array([p.world for p in run], np.float64)
                tt = fr - fr.mean()
                v = tt @ (xy - xy.mean(axis=0)) / float(tt @ tt)  # world units per frame
                w = xy.mean(axis=0) + v * (fr[0] - fr.mean())  # the fitted line at the end
                f0, size = int(fr[0]), np.asarray(ends[0].box, np.float64)[2:]
                ahead = [f for f in frames_run if 0 < (f - f0) * step <= end_frames]
                for f in (ahead if step > 0 else ahead[::-1]):  # the frames the run processed
                    p = claim(t, f, w + v * (f - f0), size)
                    if p is None:
                        break
                    new_points[f] = p
                    w, f0 = np.asarray(p.world, np.float64), f  # on from what it saw
                if step > 0 and f0 != int(fr[0]):
                    _shift_tail(t, f0, w)
        if new_points:
            kept = [p for p in t.points if p.frame not in new_points]
            t.points = sorted(kept + list(new_points.values()), key=lambda p: p.frame)
            claimed += len(new_points)
    if claimed:
        log.debug("regained %d detections in tracks' gaps and past their ends", claimed)
    return claimed


def _end_run(ends: list[TrackPoint], stride: int = 1) -> list[TrackPoint]:
    """The first :data:`EDGE_POINTS` of ``ends`` (observed points from a track's end inwards)
    that follow one another without a gap of more than :data:`END_RUN_GAP` processed frames
    (``stride`` frames each): a velocity across a linked gap averaged a wait and a drive."""
    run = ends[:1]
    for p in ends[1:EDGE_POINTS]:
        if abs(p.frame - run[-1].frame) > END_RUN_GAP * stride:
            break
        run.append(p)
    return run


def _shift_tail(t: Track, frame: int, world: np.ndarray) -> None:
    """Move the predicted points after ``frame`` (the track's new end) by where it now ends
    against where the old prediction had it at that frame (in place): the tail was predicted
    from the old end, and jumped where the claimed detections ended."""
    ref = next((p for p in t.points if p.frame == frame and p.kind == "predicted"), None)
    if ref is None:
        return
    offset = np.asarray(world, np.float64) - np.asarray(ref.world, np.float64)
    if not np.all(np.isfinite(offset)):
        return
    for p in t.points:
        if p.frame > frame and p.kind == "predicted":
            p.world = np.asarray(p.world, np.float64) + offset
            p.box = np.full(4, np.nan)  # rebuilt around the moved ground point (outputs)

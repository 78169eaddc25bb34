"""Detections regained inside a linked track's gaps (association/regain.py)."""

from __future__ import annotations

import numpy as np

from aerotrack.association.regain import regain_gap_detections
from aerotrack.types import Detections, Registration, Track, TrackPoint

FPS = 30.0


def _point(f, x, kind="observed"):
    box = np.array([x - 10.0, 95.0, 20.0, 10.0])
    return TrackPoint(frame=f, box=box if kind != "predicted" else None,
                      world=np.array([x, 100.0]), conf=1.0, kind=kind,
                      det_index=0 if kind == "observed" else -1)


def _dets(f, xs, shift=0.0):
    """Boxes centred at frame x ``xs``; their world x is ``x + shift`` (a camera panned by
    ``shift``)."""
    boxes = np.array([[x - 10.0, 95.0, 20.0, 10.0] for x in xs]).reshape(-1, 4)
    return Detections(frame=f, boxes=boxes, conf=np.full(len(xs), 0.9),
                      world=np.c_[np.asarray(xs, float) + shift, np.full(len(xs), 100.0)])


def _track():
    """Seen at frames 1-10 and 31-40 (x = 2 px a frame), predicted in between, except frames
    11-12 which local association bridged."""
    pts = [_point(f, 2.0 * f) for f in range(1, 11)]
    pts += [_point(f, 2.0 * f, "bridged") for f in (11, 12)]
    pts += [_point(f, 2.0 * f, "predicted") for f in range(13, 31)]
    pts += [_point(f, 2.0 * f) for f in range(31, 41)]
    return Track(id=1, points=pts)


def test_a_detection_on_the_path_through_a_gap_becomes_an_observation():
    t = _track()
    other = Track(id=2, points=[_point(f, 2.0 * f + 1.0) for f in (20,)])  # holds frame 20's
    dets = [_dets(f, [2.0 * f]) for f in range(1, 41)]  # the target, every frame
    dets[24] = _dets(25, [2.0 * 25 + 14.0])  # frame 25: only a box 14 px off its path
    regs = {f: Registration(index=f, H=np.eye(3)) for f in range(1, 41)}
    n = regain_gap_detections([t, other], dets, fps=FPS, max_gap_s=4.0, min_iou=0.5,
                              registrations=regs)
    kinds = {p.frame: p.kind for p in t.points}
    regained = sorted(f for f in range(13, 31) if kinds[f] == "observed")
    assert regained == [f for f in range(13, 31) if f not in (20, 25)] and n == len(regained)
    assert kinds[11] == kinds[12] == "bridged"  # local association's decision kept
    assert kinds[20] == kinds[25] == "predicted"
    p = next(p for p in t.points if p.frame == 17)
    assert np.allclose(p.box, [24.0, 95.0, 20.0, 10.0]) and p.conf == 0.9
    assert [q.frame for q in t.points] == list(range(1, 41))


def test_long_gaps_and_a_moving_camera():
    """Past max_gap_s nothing is claimed; through registrations the path is projected into each
    frame (a camera panning 3 px a frame: the detections sit at x - 3f in the frame)."""
    t = _track()
    regs = {f: Registration(index=f, H=np.array([[1, 0, 3.0 * f], [0, 1, 0], [0, 0, 1]]))
            for f in range(1, 41)}
    dets = [_dets(f, [2.0 * f - 3.0 * f], shift=3.0 * f) for f in range(1, 41)]
    assert regain_gap_detections([t], dets, fps=FPS, max_gap_s=0.5, min_iou=0.5,
                                 registrations=regs) == 0
    assert regain_gap_detections([t], dets, fps=FPS, max_gap_s=4.0, min_iou=0.5,
                                 registrations=regs) == 18
    p = next(p for p in t.points if p.frame == 17)
    assert np.allclose(p.world, [2.0 * 17, 100.0]) and np.allclose(p.box[0], 2.0 * 17 - 51 - 10)


def test_a_track_is_carried_past_its_ends_while_detections_follow_its_path():
    """Seen at frames 11-20 (x = 2 px a frame); the detector keeps seeing the vehicle at 21-25
    and from 5 to 10, local association did not: those are claimed at the track's velocity, up
    to ``end_s``, and not past a frame without a detection on the path."""
    t = Track(id=1, points=[_point(f, 2.0 * f) for f in range(11, 21)])
    dets = {f: _dets(f, []) for f in range(1, 41)}  # every frame processed, most with none
    dets.update({f: _dets(f, [2.0 * f]) for f in list(range(5, 11)) + list(range(21, 26))})
    dets[8] = _dets(8, [2.0 * 8 + 15.0])  # frame 8: off the path (the walk back stops at 9)
    dets[30] = _dets(30, [60.0])  # after a frame without one: not reached
    n = regain_gap_detections([t], list(dets.values()), fps=FPS, max_gap_s=4.0, min_iou=0.5,
                              end_s=0.5)
    assert [p.frame for p in t.points] == list(range(9, 26)) and n == 7
    t2 = Track(id=2, points=[_point(f, 2.0 * f) for f in range(11, 21)])
    assert regain_gap_detections([t2], list(dets.values()), fps=FPS, max_gap_s=4.0,
                                 min_iou=0.5, end_s=0.1) == 5  # 3 frames each way at most
    assert [p.frame for p in t2.points] == list(range(9, 24))


def test_two_tracks_never_claim_one_detection():
    """What a track holds is judged by its boxes (a point's det_index may index another list of
    detections: split blobs, followed vehicles); a box one track claimed is held for the next."""
    a, b = _track(), _track()
    b.id = 2
    for p in b.points:  # another vehicle 1 px below, seen in the same frames
        p.world = p.world + [0.0, 1.0]
        if p.box is not None:
            p.box = p.box + [0.0, 1.0, 0.0, 0.0]
            p.det_index = 7
    dets = [_dets(f, [2.0 * f]) for f in range(13, 31)]
    n = regain_gap_detections([a, b], dets, fps=FPS, max_gap_s=4.0, min_iou=0.5)
    claimed = [sum(p.kind == "observed" and 13 <= p.frame <= 30 for p in t.points) for t in (a, b)]
    assert n == 18 and sorted(claimed) == [0, 18]
    # frame 20 holds the target's detection (row 0) and a far vehicle's (row 1), which a third
    # track holds with det_index 0 (an index into the detections before a merged blob was
    # split): the target's own is free
    t, far = _track(), Track(id=3, points=[_point(20, 300.0)])
    far.points[0].det_index = 0
    dets = [_dets(f, [2.0 * f] + ([300.0] if f == 20 else [])) for f in range(13, 31)]
    regain_gap_detections([t, far], dets, fps=FPS, max_gap_s=4.0, min_iou=0.5)
    assert next(p for p in t.points if p.frame == 20).kind == "observed"


def test_end_extension_with_a_stride_and_a_tail_that_follows():
    """--stride 2 processes every other frame: the extension walks those (it stopped at the
    first unprocessed frame); the predicted tail after the new end moves with it."""
    pts = [_point(f, 2.0 * f) for f in range(11, 31, 2)]
    pts += [_point(f, 2.0 * f, "predicted") for f in range(31, 61, 2)]
    t = Track(id=1, points=pts)
    dets = [_dets(f, [2.0 * f + (3.0 if f > 30 else 0.0)] if 31 <= f <= 39 else [])
            for f in range(1, 61, 2)]  # the vehicle drifts 3 px off the old prediction
    assert regain_gap_detections([t], dets, fps=FPS, max_gap_s=4.0, min_iou=0.5,
                                 end_s=1.0) == 5
    p41 = next(p for p in t.points if p.frame == 41)
    assert p41.kind == "predicted" and abs(p41.world[0] - (2.0 * 41 + 3.0)) < 0.5

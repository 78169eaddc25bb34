"""Splitting a detection that holds several tracked vehicles (association/merged.py)."""

from __future__ import annotations

import numpy as np

from aerotrack.association.merged import split_merged
from aerotrack.types import Detections

H = np.diag([0.5, 0.5, 1.0])  # world = half the pixels


def _dets(boxes, hist=None):
    boxes = np.asarray(boxes, float)
    c = boxes[:, :2] + boxes[:, 2:] / 2
    return Detections(frame=7, boxes=boxes, conf=np.full(len(boxes), 0.8), world=c * 0.5,
                      size_world=boxes[:, 2:] * 0.5, hist=hist)


def test_two_tracks_in_one_blob_give_two_boxes():
    # a blob 40 x 10 px holding two 18 x 10 px cars, bumper to bumper; a third car elsewhere
    dets = _dets([[100, 50, 40, 10], [300, 50, 18, 10]], hist=np.array([[.5, .5], [1., 0.]]))
    centres = np.array([[109, 55], [131, 55], [309, 55]]) * 0.5
    sizes = np.array([[18, 10], [18, 10], [18, 10]]) * 0.5
    hists = [np.array([.9, .1]), np.array([.1, .9]), np.array([1., 0.])]
    out, n = split_merged(dets, centres, sizes, H, hists=hists)
    assert n == 1 and len(out) == 3
    parts = out.boxes[:2]
    np.testing.assert_allclose(sorted(parts[:, 0]), [100, 122])
    np.testing.assert_allclose(parts[:, 2:], [[18, 10], [18, 10]])
    np.testing.assert_allclose(out.world[:2], (parts[:, :2] + parts[:, 2:] / 2) * 0.5)
    np.testing.assert_allclose(out.conf[:2], 0.72)
    assert {tuple(h) for h in out.hist[:2]} == {(.9, .1), (.1, .9)}  # each part its track's colour
    np.testing.assert_array_equal(out.boxes[2], [300, 50, 18, 10])  # the lone car is untouched
    assert out.conf[2] == 0.8


def test_one_vehicle_is_not_cut():
    dets = _dets([[100, 50, 40, 10]])
    sizes = np.array([[18, 10], [18, 10]]) * 0.5
    # one track inside only
    out, n = split_merged(dets, np.array([[109, 55], [400, 55]]) * 0.5, sizes, H)
    assert n == 0 and out is dets
    # two tracks on the same vehicle (their predictions overlap)
    out, n = split_merged(dets, np.array([[118, 55], [122, 55]]) * 0.5, sizes, H)
    assert n == 0
    # the blob is hardly larger than the tracks' vehicles: a whole vehicle, stale neighbours
    big = np.array([[30, 10], [30, 10]]) * 0.5
    out, n = split_merged(dets, np.array([[106, 55], [134, 55]]) * 0.5, big, H)
    assert n == 0
    out, n = split_merged(dets, np.array([[106, 55], [134, 55]]) * 0.5, big, H, area_ratio=1.3)
    assert n == 1  # the same with a looser ratio: the rule above is what kept it whole

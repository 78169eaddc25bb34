"""The vectorised blob joins and the cropped attachment of unseeded parts give exactly the
results of the plain double loops and the whole-frame distance transform they replaced (kept
here as the reference)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from aerotrack.detection.blobs import (
    Blob,
    _attach_unseeded,
    box_gap,
    box_gaps,
    join_cabs,
    join_fragments,
    join_vehicle_parts,
    merge_blobs,
    oriented_sides,
)


def ref_join_fragments(blobs, *, gap, max_length, fragment_ratio=0.35):
    blobs = list(blobs)
    changed = True
    while changed:
        changed = False
        order = sorted(range(len(blobs)), key=lambda i: blobs[i].area)
        for i in order:
            a = blobs[i]
            best, best_gap = -1, gap + 1e-9
            for j, b in enumerate(blobs):
                if j == i or a.area >= fragment_ratio * b.area:
                    continue
                g = box_gap(a.box, b.box)
                if g <= best_gap:
                    ux0, uy0 = min(a.box[0], b.box[0]), min(a.box[1], b.box[1])
                    ux1 = max(a.box[0] + a.box[2], b.box[0] + b.box[2])
                    uy1 = max(a.box[1] + a.box[3], b.box[1] + b.box[3])
                    if max(ux1 - ux0, uy1 - uy0) <= max_length:
                        best, best_gap = j, g
            if best >= 0:
                blobs[best] = merge_blobs(a, blobs[best])
                del blobs[i]
                changed = True
                break
    return blobs


def ref_join_vehicle_parts(blobs, *, gap, max_long, max_short):
    blobs = list(blobs)
    while len(blobs) > 1:
        best, best_gap = None, gap + 1e-9
        for i in range(len(blobs)):
            for j in range(i + 1, len(blobs)):
                g = box_gap(blobs[i].box, blobs[j].box)
                if g <= best_gap:
                    u = merge_blobs(blobs[i], blobs[j])
                    pts = np.column_stack(np.nonzero(u.mask)[::-1]).astype(np.float32)
                    (_, _), (rw, rh), _ = cv2.minAreaRect(pts)
                    if max(rw, rh) <= max_long and min(rw, rh) <= max_short:
                        best, best_gap = (i, j, u), g
        if best is None:
            break
        i, j, u = best
        blobs[i] = u
        del blobs[j]
    return blobs


def ref_join_cabs(blobs, *, gap, long_t, max_long, cab_ratio=0.8, width_tol=1.25):
    blobs = list(blobs)
    sides = [oriented_sides(b) for b in blobs]
    changed = True
    while changed and len(blobs) > 1:
        changed = False
        best = None
        for i in range(len(blobs)):
            if sides[i][0] >= cab_ratio * long_t:
                continue
            for j in range(len(blobs)):
                if j == i or sides[j][0] <= sides[i][0]:
                    continue
                g = box_gap(blobs[i].box, blobs[j].box)
                if g > gap or (best is not None and g >= best[0]):
                    continue
                u = merge_blobs(blobs[i], blobs[j])
                lo, sh = oriented_sides(u)
                if lo <= max_long and sh <= width_tol * max(sides[i][1], sides[j][1]):
                    best = (g, i, j, u)
        if best is not None:
            _, i, j, u = best
            blobs[j], sides[j] = u, oriented_sides(u)
            del blobs[i], sides[i]
            changed = True
    return blobs


def ref_attach_unseeded(labels, stats, seeded, gap):
    n = len(stats)
    owner = np.arange(n)
    seed_mask = np.isin(labels, np.flatnonzero(seeded)).astype(np.uint8)
    dist, near = cv2.distanceTransformWithLabels(1 - seed_mask, cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(near.max()) + 1, np.int32)
    lut[near[seed_mask > 0]] = labels[seed_mask > 0]
    for k in np.flatnonzero(~seeded[1:]) + 1:
        x, y, w, h = (int(v) for v in stats[k, :4])
        sub = labels[y:y + h, x:x + w] == k
        d = dist[y:y + h, x:x + w][sub]
        i = int(np.argmin(d))
        if d[i] <= gap + 1.0:
            owner[k] = lut[near[y:y + h, x:x + w][sub][i]]
    return owner


def random_blobs(rng: np.random.Generator, n: int, extent: int = 120) -> list[Blob]:
    """Blobs of vehicle-like and fragment-like sizes, many near each other, some ragged."""
    out = []
    for _ in range(n):
        w, h = (int(v) for v in rng.integers(2, 22, 2))
        x, y = (int(v) for v in rng.integers(0, extent, 2))
        mask = rng.random((h, w)) < 0.85
        mask[h // 2, :] = True
        mask[:, w // 2] = True
        out.append(Blob((x, y, w, h), mask))
    return out


def same(a: list[Blob], b: list[Blob]) -> bool:
    return len(a) == len(b) and all(p.box == q.box and np.array_equal(p.mask, q.mask)
                                    for p, q in zip(a, b))


def test_box_gaps_equal_box_gap_pair_by_pair():
    rng = np.random.default_rng(3)
    boxes = [tuple(int(v) for v in b) for b in rng.integers(0, 40, (30, 4))]
    g = box_gaps(np.array(boxes))
    for i, a in enumerate(boxes):
        for j, b in enumerate(boxes):
            assert g[i, j] == box_gap(a, b)


@pytest.mark.parametrize("seed", range(12))
def test_joins_equal_the_plain_loops(seed):
    rng = np.random.default_rng(seed)
    blobs = random_blobs(rng, int(rng.integers(5, 45)))
    gap = float(rng.choice([1.0, 2.5, 4.0, 6.0]))
    assert same(join_fragments(blobs, gap=gap, max_length=30),
                ref_join_fragments(blobs, gap=gap, max_length=30))
    assert same(join_vehicle_parts(blobs, gap=2 * gap, max_long=24, max_short=12),
                ref_join_vehicle_parts(blobs, gap=2 * gap, max_long=24, max_short=12))
    assert same(join_cabs(blobs, gap=gap, long_t=14, max_long=40, cab_ratio=0.9),
                ref_join_cabs(blobs, gap=gap, long_t=14, max_long=40, cab_ratio=0.9))


@pytest.mark.parametrize("seed", range(8))
def test_attaching_unseeded_parts_in_crops_equals_the_whole_frame_transform(seed):
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((90, 140)).astype(np.float32), (0, 0), 1.5)
    m = (noise > np.quantile(noise, 0.8)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    seeded = rng.random(n) < 0.3
    seeded[0] = False
    for gap in (1.0, 3.0, 7.5):
        assert np.array_equal(_attach_unseeded(labels, stats, seeded, gap),
                              ref_attach_unseeded(labels, stats, seeded, gap))

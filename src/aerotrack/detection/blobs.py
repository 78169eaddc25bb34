"""From a thresholded residual to vehicle-sized blobs: hysteresis, morphology, connected
components, splitting of merged vehicles and joining of fragments.

All functions work on one image in one pixel frame (the caller chooses model or full resolution)
and return blobs as ``(x, y, w, h)`` integer boxes (pixel indices, inclusive-exclusive) with
a boolean mask cropped to the box.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from .appearance import median_u8


@dataclass
class Blob:
    """One connected foreground region.

    Attributes
    ----------
    box : (int, int, int, int)
        ``x, y, w, h`` in the pixels of the image it was found in.
    mask : ndarray, shape (h, w) bool
        The region inside ``box``.
    """

    box: tuple[int, int, int, int]
    mask: np.ndarray
    area: int = -1

    def __post_init__(self) -> None:
        if self.area < 0:
            self.area = int(np.count_nonzero(self.mask))


def _disk(r: float) -> np.ndarray:
    """Disk of radius ~r with an odd side, so that its anchor is its centre (an even kernel
    would shift every opening/closing by half a pixel... rounded to a whole one)."""
    k = 2 * max(0, int(round(r))) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))


def open2(mask: np.ndarray) -> np.ndarray:
    """Opening by a 2x2 square without a shift (removes isolated pixels and 1-pixel lines).

    ``cv2.morphologyEx(MORPH_OPEN)`` with an even kernel uses one anchor for the erosion and the
    dilation, which moves the result by one pixel down and right; anchoring the two at opposite
    corners cancels it."""
    k = np.ones((2, 2), np.uint8)
    return cv2.dilate(cv2.erode(mask, k, anchor=(1, 1)), k, anchor=(0, 0))


def close(mask: np.ndarray, radius: float) -> np.ndarray:
    """Morphological closing with a disk that treats the outside of the image as background.

    (OpenCV's default border lets the erosion keep whatever the dilation pushed against the
    image edge, which would grow blobs that touch a crop's border.)"""
    k = _disk(radius)
    p = k.shape[0]
    m = cv2.copyMakeBorder(mask, p, p, p, p, cv2.BORDER_CONSTANT, value=0)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    return m[p:-p, p:-p]


def hysteresis_blobs(low: np.ndarray, high: np.ndarray, *, close_radius: float,
                     min_area: float, attach_gap: float | None = None) -> list[Blob]:
    """Connected components of ``low`` (after a 2x2 opening and a closing) that contain a pixel of
    ``high``, each with the unseeded components within ``attach_gap`` pixels of it.

    Parameters
    ----------
    low, high : ndarray, shape (H, W) bool or uint8
        Pixels above the threshold, and above the seed threshold.
    close_radius : float
        Closing radius in pixels: joins fragments of one vehicle; too large merges neighbours.
    min_area : float
        Smallest blob area in pixels (with its attached parts).
    attach_gap : float, optional
        A component without a seed pixel joins the seeded component whose pixels are nearest,
        when at most this many background pixels lie between them (default ``2 close_radius + 1``, the gap the closing
        leaves open); 0 drops every unseeded component (plain hysteresis). Larger keeps more of
        low-contrast vehicles but can attach a neighbour's faint parts.
    """
    m = (np.asarray(low) > 0).astype(np.uint8)
    m = open2(m)
    if close_radius >= 0.5:
        m = close(m, close_radius)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return []
    seeded = np.zeros(n, bool)
    seeded[np.unique(labels[(np.asarray(high) > 0) & (m > 0)])] = True
    seeded[0] = False
    if attach_gap is None:
        attach_gap = 2.0 * close_radius + 1.0
    owner = np.arange(n)
    if attach_gap >= 1.0 and seeded.any() and not seeded[1:].all():
        owner = _attach_unseeded(labels, stats, seeded, attach_gap)
    out = []
    for k in np.flatnonzero(seeded):
        parts = np.flatnonzero(owner == k)
        x0 = int(stats[parts, cv2.CC_STAT_LEFT].min())
        y0 = int(stats[parts, cv2.CC_STAT_TOP].min())
        x1 = int((stats[parts, cv2.CC_STAT_LEFT] + stats[parts, cv2.CC_STAT_WIDTH]).max())
        y1 = int((stats[parts, cv2.CC_STAT_TOP] + stats[parts, cv2.CC_STAT_HEIGHT]).max())
        area = int(stats[parts, cv2.CC_STAT_AREA].sum())
        if area < min_area:
            continue
        crop = labels[y0:y1, x0:x1]
        mask = crop == k if len(parts) == 1 else np.isin(crop, parts)
        out.append(Blob((x0, y0, x1 - x0, y1 - y0), mask, area))
    return out


def _attach_unseeded(labels: np.ndarray, stats: np.ndarray, seeded: np.ndarray,
                     gap: float) -> np.ndarray:
    """Owner label of every component: itself for a seeded one; for an unseeded one the seeded
    component nearest to it when at most ``gap`` background pixels lie between them (itself,
    i.e. dropped, if none).

    A vehicle whose residual barely passes the threshold (dark on dark asphalt) breaks into
    parts of which only one holds a seed pixel; the others are kept as part of it instead of
    being dropped with the noise, which left boxes covering half a vehicle."""
    n = len(stats)
    owner = np.arange(n)
    H, W = labels.shape
    seed_mask = seeded[labels].astype(np.uint8)
    # Each unseeded component looks for seeds in its box grown by ``reach``: the chamfer distance
    # is at least the chessboard distance, so a seed outside lies farther than ``gap + 1``, and
    # the best chamfer path between two points stays in their bounding box, so the distances
    # and nearest seeds inside are those of a transform over the whole frame.
    reach = int(math.ceil(gap + 1.0)) + 1
    for k in np.flatnonzero(~seeded[1:]) + 1:
        x, y, w, h = (int(v) for v in stats[k, :4])
        x0, y0, x1, y1 = max(0, x - reach), max(0, y - reach), min(W, x + w + reach), min(H, y + h + reach)
        seeds = seed_mask[y0:y1, x0:x1]
        if not seeds.any():
            continue
        # Distance of every pixel to the nearest seeded pixel, and which seeded pixel that is.
        dist, near = cv2.distanceTransformWithLabels(1 - seeds, cv2.DIST_L2, 5,
                                                     labelType=cv2.DIST_LABEL_PIXEL)
        lab = labels[y0:y1, x0:x1]
        sub = lab[y - y0:y - y0 + h, x - x0:x - x0 + w] == k
        d = dist[y - y0:y - y0 + h, x - x0:x - x0 + w][sub]
        i = int(np.argmin(d))
        if d[i] <= gap + 1.0:  # at most ``gap`` background pixels in between
            lut = np.zeros(int(near.max()) + 1, np.int32)
            lut[near[seeds > 0]] = lab[seeds > 0]
            owner[k] = lut[near[y - y0:y - y0 + h, x - x0:x - x0 + w][sub][i]]
    return owner


def nearest_seed(seeds: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Each pixel of ``mask`` labelled with its nearest seed (``seeds`` > 0, int labels; L2
    distance): (h, w) int32, 0 outside ``mask``."""
    # the distance transform labels every zero (seed) pixel; map those labels to the seeds'
    _, nearest = cv2.distanceTransformWithLabels(
        (seeds == 0).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(nearest.max()) + 1, np.int32)
    lut[nearest[seeds > 0]] = seeds[seeds > 0]
    return lut[nearest] * (mask > 0)


def split_blob(blob: Blob, *, min_area: float, max_radius: int) -> list[Blob]:
    """Split a blob that merges several vehicles.

    The mask is eroded with growing disks (radius 1..``max_radius``) until it falls apart into
    two or more cores; every pixel then goes to its nearest core. The split is kept only when
    each part has at least ``min_area`` pixels, so a vehicle whose residual has a thin waist
    (a roof that matches the road) is not cut in two unless both halves are vehicle-sized.

    Returns
    -------
    list of Blob
        ``[blob]`` when it does not split.
    """
    x0, y0 = blob.box[:2]
    m = cv2.copyMakeBorder(blob.mask.astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    for r in range(1, max_radius + 1):
        core = cv2.erode(m, _disk(r))
        n, labels, stats, _ = cv2.connectedComponentsWithStats(core, connectivity=8)
        if n <= 1:
            break
        big = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= 2]
        if len(big) < 2:
            continue
        seeds = np.zeros_like(labels)
        for i, k in enumerate(big, start=1):
            seeds[labels == k] = i
        owner = nearest_seed(seeds, m)  # every pixel to its nearest core
        parts = []
        for i in range(1, len(big) + 1):
            pm = owner == i
            if pm.sum() < min_area:
                parts = []
                break
            ys, xs = np.nonzero(pm)
            bx0, by0, bx1, by1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
            parts.append(Blob((x0 + int(bx0) - 1, y0 + int(by0) - 1, int(bx1 - bx0), int(by1 - by0)),
                              pm[by0:by1, bx0:bx1]))
        if parts:
            return parts
    return [blob]


def box_gap(a: tuple, b: tuple) -> float:
    """Largest of the horizontal and vertical gaps between two ``x, y, w, h`` boxes (0 if they
    touch or overlap)."""
    gx = max(a[0] - (b[0] + b[2]), b[0] - (a[0] + a[2]), 0)
    gy = max(a[1] - (b[1] + b[3]), b[1] - (a[1] + a[3]), 0)
    return float(max(gx, gy))


def box_gaps(boxes: np.ndarray, others: np.ndarray | None = None) -> np.ndarray:
    """:func:`box_gap` of every box in ``boxes`` (n, 4) against every box in ``others`` (m, 4,
    default ``boxes``): an (n, m) float64 array, the same values pair by pair."""
    a = np.asarray(boxes, np.int64).reshape(-1, 4)
    b = a if others is None else np.asarray(others, np.int64).reshape(-1, 4)
    ax0, ay0 = a[:, 0:1], a[:, 1:2]
    ax1, ay1 = ax0 + a[:, 2:3], ay0 + a[:, 3:4]
    bx0, by0 = b[None, :, 0], b[None, :, 1]
    bx1, by1 = bx0 + b[None, :, 2], by0 + b[None, :, 3]
    gx = np.maximum(np.maximum(ax0 - bx1, bx0 - ax1), 0)
    gy = np.maximum(np.maximum(ay0 - by1, by0 - ay1), 0)
    return np.maximum(gx, gy).astype(np.float64)


def _union_extent(boxes: np.ndarray, i: int) -> np.ndarray:
    """Longer side of the union of box ``i`` with every box (integer pixels), shape (n,)."""
    x0 = np.minimum(boxes[:, 0], boxes[i, 0])
    y0 = np.minimum(boxes[:, 1], boxes[i, 1])
    x1 = np.maximum(boxes[:, 0] + boxes[:, 2], boxes[i, 0] + boxes[i, 2])
    y1 = np.maximum(boxes[:, 1] + boxes[:, 3], boxes[i, 1] + boxes[i, 3])
    return np.maximum(x1 - x0, y1 - y0)


def oriented_sides(blob: Blob) -> tuple[float, float]:
    """Longer and shorter side of the blob mask's minimum-area rectangle, pixels."""
    pts = np.column_stack(np.nonzero(blob.mask)[::-1]).astype(np.float32)
    if len(pts) < 3:
        return float(max(blob.box[2:])), float(min(blob.box[2:]))
    (_, _), (rw, rh), _ = cv2.minAreaRect(pts)
    return float(max(rw, rh)) + 1.0, float(min(rw, rh)) + 1.0


def typical_sides(blobs: list[Blob], min_count: int = 5) -> tuple[float, float] | None:
    """Median oriented length and width of a frame's blobs, pixels; None with fewer than
    ``min_count`` blobs. Without a vehicle model, the frame's typical blob is the best guess
    of one vehicle."""
    if len(blobs) < min_count:
        return None
    sides = np.array([oriented_sides(b) for b in blobs])
    return float(np.median(sides[:, 0])), float(np.median(sides[:, 1]))


def join_fragments(blobs: list[Blob], *, gap: float, max_length: float,
                   fragment_ratio: float = 0.35) -> list[Blob]:
    """Join a small fragment to a bigger blob within ``gap`` pixels.

    Only pairs whose smaller area is under ``fragment_ratio`` of the larger are joined, and only
    when the union's longer side stays within ``max_length``: two vehicles of similar size that
    queue bumper to bumper stay apart.
    """
    blobs = list(blobs)
    limit = gap + 1e-9
    while len(blobs) > 1:
        boxes = np.array([b.box for b in blobs], np.int64)
        areas = np.array([b.area for b in blobs], np.float64)
        gaps = box_gaps(boxes)
        merged = False
        for i in sorted(range(len(blobs)), key=lambda k: blobs[k].area):
            ok = (areas[i] < fragment_ratio * areas) & (gaps[i] <= limit)
            ok[i] = False
            if not ok.any():
                continue
            ok &= _union_extent(boxes, i) <= max_length
            if not ok.any():
                continue
            # the nearest, the last of equal gaps (as a scan keeping each j with gap <= best)
            cand = np.flatnonzero(ok)
            g = gaps[i, cand]
            best = int(cand[np.flatnonzero(g == g.min())[-1]])
            blobs[best] = merge_blobs(blobs[i], blobs[best])
            del blobs[i]
            merged = True
            break
        if not merged:
            break
    return blobs


def join_vehicle_parts(blobs: list[Blob], *, gap: float, max_long: float,
                       max_short: float) -> list[Blob]:
    """Join pairs of blobs (of any relative size) whose union still has the size of one vehicle.

    A light vehicle whose dark windscreen and roof match the road leaves its bonnet and boot as
    two similar blobs, which :func:`join_fragments` (small to big only) keeps apart. Two blobs
    within ``gap`` pixels are joined, closest pair first, when the union's oriented extent (its
    minimum-area rectangle) is at most ``max_long`` x ``max_short``: two whole vehicles queueing
    bumper to bumper make a union about twice a vehicle's length and stay apart.
    """
    blobs = list(blobs)
    keys = list(range(len(blobs)))  # a key per blob, so unions already tested are not redone
    next_key = len(blobs)
    tested: dict[tuple[int, int], Blob | None] = {}
    limit = gap + 1e-9
    while len(blobs) > 1:
        gaps = box_gaps(np.array([b.box for b in blobs], np.int64))
        best, best_gap = None, limit
        ii, jj = np.nonzero(np.triu(gaps <= limit, 1))  # row-major: the order of a double loop
        for i, j in zip(ii.tolist(), jj.tolist()):
            g = gaps[i, j]
            if g > best_gap:
                continue
            key = (keys[i], keys[j])
            if key not in tested:
                u = merge_blobs(blobs[i], blobs[j])
                pts = np.column_stack(np.nonzero(u.mask)[::-1]).astype(np.float32)
                (_, _), (rw, rh), _ = cv2.minAreaRect(pts)
                tested[key] = u if max(rw, rh) <= max_long and min(rw, rh) <= max_short else None
            if tested[key] is not None:
                best, best_gap = (i, j, tested[key]), g
        if best is None:
            break
        i, j, u = best
        blobs[i], keys[i] = u, next_key
        next_key += 1
        del blobs[j], keys[j]
    return blobs


def join_cabs(blobs: list[Blob], *, gap: float, long_t: float, max_long: float,
              cab_ratio: float = 0.8, width_tol: float = 1.25) -> list[Blob]:
    """Join an articulated vehicle's cab to its trailer.

    Seen from above a tractor-trailer is a short cab and a long trailer one gap apart; the gap
    splits the residual into two blobs, and the pair is longer than :func:`join_vehicle_parts`
    admits for one vehicle. A blob shorter than ``cab_ratio`` x the typical length ``long_t``
    (a cab is shorter than a car) within ``gap`` pixels of a longer blob is joined to it when
    the two are in line, one behind the other: the union's oriented width at most ``width_tol``
    x the wider part's, and its length at most ``max_long``. Two cars in a queue are both about
    the typical length and stay apart; a small blob beside a vehicle widens the union and stays.
    """
    blobs = list(blobs)
    sides = [oriented_sides(b) for b in blobs]
    keys = list(range(len(blobs)))  # a key per blob, so unions already tested are not redone
    next_key = len(blobs)
    tested: dict[tuple[int, int], Blob | None] = {}
    while len(blobs) > 1:
        gaps = box_gaps(np.array([b.box for b in blobs], np.int64))
        long_sides = np.array([s[0] for s in sides])
        cab = long_sides < cab_ratio * long_t
        ok = cab[:, None] & (long_sides[None, :] > long_sides[:, None]) & (gaps <= gap)
        ii, jj = np.nonzero(ok)
        # the nearest pair that passes, the first in scan order among equal gaps
        best = None
        for k in np.lexsort((jj, ii, gaps[ii, jj])).tolist():
            i, j = int(ii[k]), int(jj[k])
            key = (keys[i], keys[j])
            if key not in tested:
                u = merge_blobs(blobs[i], blobs[j])
                lo, sh = oriented_sides(u)
                passes = lo <= max_long and sh <= width_tol * max(sides[i][1], sides[j][1])
                tested[key] = u if passes else None
            if tested[key] is not None:
                best = (i, j, tested[key])
                break
        if best is None:
            break
        i, j, u = best
        blobs[j], sides[j], keys[j] = u, oriented_sides(u), next_key
        next_key += 1
        del blobs[i], sides[i], keys[i]
    return blobs


def drop_small(blobs: list[Blob], *, area_ratio: float, near: float = 0.0,
               min_count: int = 5, norm: Callable[[Blob], float] | None = None) -> list[Blob]:
    """Blobs without those much smaller than the frame's typical one.

    Run after splitting and joining: a blob under ``area_ratio`` x the median blob area that
    joined no vehicle is a leftover fragment of a vehicle detected beside it (the part of a
    dark or slow car the background half absorbed), a pedestrian, debris blown about or
    noise. Left in, each became a false detection and often a short false track. Without a
    vehicle model (no metric scale) the frame's median blob is the best guess of one vehicle,
    so nothing is dropped in a frame with fewer than ``min_count`` blobs.

    Parameters
    ----------
    blobs : list of Blob
        One frame's blobs, any pixel frame.
    area_ratio : float
        Fraction of the median blob area under which a blob is dropped; 0 keeps all. Raising
        it removes more debris and fragments but also small or partly seen vehicles.
    near : float
        With ``near`` > 0 a small blob is dropped only when its box lies within ``near`` x the
        typical blob length (:func:`typical_sides`) of a blob that is not small: only leftover
        fragments go, isolated small movers stay. 0 drops small blobs anywhere.
    min_count : int
        Fewest blobs for a median to be trusted.
    norm : callable, optional
        Blob -> the area a vehicle has at its place relative to mid-frame (an oblique view with
        a map or ``--ground``: :meth:`.moving.SizeGates.at`'s scale squared); areas are compared
        divided by it.

    Returns
    -------
    list of Blob
    """
    if area_ratio <= 0 or len(blobs) < min_count:
        return list(blobs)
    areas = _normed_areas(blobs, norm)
    limit = area_ratio * float(np.median(areas))
    big = [b for b, a in zip(blobs, areas) if a >= limit]
    if near <= 0:
        return big
    reach = near * typical_sides(blobs, min_count)[0]
    return [b for b, a in zip(blobs, areas) if a >= limit
            or not any(box_gap(b.box, o.box) <= reach for o in big)]


def _normed_areas(blobs: list[Blob], norm: Callable[[Blob], float] | None) -> np.ndarray:
    areas = np.array([b.area for b in blobs], np.float64)
    if norm is not None and len(blobs):
        areas /= np.array([norm(b) for b in blobs], np.float64)
    return areas


def regrow_small(blobs: list[Blob], faint: np.ndarray, *, area_ratio: float,
                 close_radius: float, min_ratio: float = 0.0, max_ratio: float = 1.5,
                 min_count: int = 5, norm: Callable[[Blob], float] | None = None
                 ) -> tuple[list[Blob], list[bool]]:
    """Small blobs regrown through a lower threshold when they grow into one whole vehicle.

    A dark vehicle on dark asphalt differs from the road by little more than the threshold: its
    bright or contrasting parts (windows, rims) seed a blob, its body stays below, and the blob
    is a fragment that :func:`drop_small` would drop. Each blob under ``area_ratio`` x the
    frame's median area is grown inside ``faint`` (pixels above a lower threshold, opened and
    closed as the main mask), within one typical blob length of its box and never into another
    blob (nor the pixel ring around it). The grown blob replaces the fragment only when it is no
    longer small and its oriented sides stay within ``max_ratio`` x the typical blob's and its
    area within ``max_ratio`` x the median: a cast shadow or a road texture that leaks keeps
    growing and is refused. Everything else is returned unchanged.

    Parameters
    ----------
    blobs : list of Blob
        One frame's blobs after splitting and joining.
    faint : ndarray, shape (H, W) bool
        Pixels above the lower threshold, same pixel frame as the blobs.
    area_ratio : float
        As :func:`drop_small`: blobs under this fraction of the median area are candidates.
    close_radius : float
        Closing radius applied to ``faint`` before growing (the main mask's).
    min_ratio : float
        Smallest grown area relative to the median (at least ``area_ratio``).
    max_ratio : float
        Largest grown size relative to the typical blob (sides and area).
    min_count : int
        Fewest blobs for a median to be trusted (nothing is regrown below it).
    norm : callable, optional
        As :func:`drop_small`'s: areas are compared divided by it.

    Returns
    -------
    blobs : list of Blob
    grown : list of bool
        True where the blob was regrown (its pixels need the lower threshold at full resolution).
    """
    blobs = list(blobs)
    grown = [False] * len(blobs)
    if area_ratio <= 0 or len(blobs) < min_count:
        return blobs, grown
    areas = _normed_areas(blobs, norm)
    median = float(np.median(areas))
    limit = area_ratio * median
    long_t, short_t = typical_sides(blobs, min_count)
    H, W = faint.shape
    reach = int(math.ceil(long_t))
    taken = np.zeros((H, W), np.uint8)
    for b in blobs:
        x, y, w, h = b.box
        taken[y:y + h, x:x + w] |= b.mask.astype(np.uint8)
    taken = cv2.dilate(taken, np.ones((3, 3), np.uint8))
    for i, b in enumerate(blobs):
        if areas[i] >= limit:
            continue
        k = norm(b) if norm is not None else 1.0
        x, y, w, h = b.box
        x0, y0 = max(0, x - reach), max(0, y - reach)
        x1, y1 = min(W, x + w + reach), min(H, y + h + reach)
        own = np.zeros((y1 - y0, x1 - x0), np.uint8)
        own[y - y0:y - y0 + h, x - x0:x - x0 + w] = b.mask
        others = taken[y0:y1, x0:x1] & (cv2.dilate(own, np.ones((3, 3), np.uint8)) == 0)
        m = open2(faint[y0:y1, x0:x1].astype(np.uint8))
        m = (m | own) & (others == 0)
        if close_radius >= 0.5:
            m = close(m, close_radius) & (others == 0)
        _, labels = cv2.connectedComponents(m, connectivity=8)
        ids = np.unique(labels[own > 0])
        ids = ids[ids > 0]
        if len(ids) == 0:
            continue
        region = np.isin(labels, ids)
        area = int(region.sum())
        if area < k * max(limit, min_ratio * median) or area > k * max_ratio * median:
            continue
        ys, xs = np.nonzero(region)
        cand = Blob((int(xs.min()) + x0, int(ys.min()) + y0,
                     int(xs.max() - xs.min()) + 1, int(ys.max() - ys.min()) + 1),
                    region[ys.min():ys.max() + 1, xs.min():xs.max() + 1].copy(), area)
        lo, sh = oriented_sides(cand)
        if lo > max_ratio * long_t * math.sqrt(k) or sh > max_ratio * short_t * math.sqrt(k):
            continue
        blobs[i], grown[i] = cand, True
    return blobs, grown


def merge_blobs(a: Blob, b: Blob) -> Blob:
    """The union of two blobs (mask of both, box around both)."""
    x0, y0 = min(a.box[0], b.box[0]), min(a.box[1], b.box[1])
    x1 = max(a.box[0] + a.box[2], b.box[0] + b.box[2])
    y1 = max(a.box[1] + a.box[3], b.box[1] + b.box[3])
    m = np.zeros((y1 - y0, x1 - x0), bool)
    for bl in (a, b):
        bx, by, bw, bh = bl.box
        m[by - y0:by - y0 + bh, bx - x0:bx - x0 + bw] |= bl.mask
    return Blob((x0, y0, x1 - x0, y1 - y0), m)


def edge_extent(residual: np.ndarray, mask: np.ndarray, *, level: float,
                floor: float = 0.0) -> tuple[int, int, int, int] | None:
    """Extent of a blob at the half-contrast edge: the box around the pixels of ``mask`` whose
    residual reaches ``level`` x the blob's median residual (and ``floor``).

    A blob thresholded at a fixed residual level reaches out to pixels that the vehicle covers
    only in part, and how far depends on the vehicle's contrast: a white car on dark asphalt
    passes the noise threshold where it covers a tenth of a pixel, and blur from the optics,
    the compression and the warps widens it further, while a dark car is cut inside its edge.
    A symmetric blur leaves a straight edge where the signal is half of its plateau, so placing
    the box edges at half of the vehicle's own contrast (``level`` 0.5) removes the contrast
    dependence. The median over the blob stands for the plateau: it is robust to a dark
    windscreen or a roof that matches the road (those pixels lower it little and do not set the
    box, which only the outermost passing pixels do).

    Parameters
    ----------
    residual : ndarray, shape (h, w)
        Residual of the blob's crop (any pixel frame; the caller's full resolution).
    mask : ndarray, shape (h, w) bool
        The blob's pixels in the crop.
    level : float
        Fraction of the blob's median residual at which the edge is placed. Higher gives
        tighter boxes (0.5: where the vehicle covers half a pixel); lower keeps more of the
        blurred rim, as annotators who box everything visible do.
    floor : float
        Smallest residual kept whatever the contrast (the caller's noise threshold, so a
        low-contrast blob is never grown by this).

    Returns
    -------
    (x0, y0, x1, y1) or None
        Inclusive-exclusive pixel extent in the crop; None when no pixel passes.
    """
    vals = residual[mask]
    if not len(vals):
        return None
    med = median_u8(vals) if vals.dtype == np.uint8 else float(np.median(vals))
    edge = mask & (residual >= max(floor, level * med))
    ys, xs = np.nonzero(edge)
    if not len(xs):
        return None
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1

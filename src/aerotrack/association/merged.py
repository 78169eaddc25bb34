"""Detections that hold several tracked vehicles, split where the tracks expect them.

Vehicles that touch (a queue bumper to bumper, two lanes side by side, a convoy) leave one blob:
the background residual has no gap between them and the detector's own splitting
(:func:`aerotrack.detection.blobs.split_blob`) needs a waist. A blob detector cannot tell such a
blob from one long vehicle, but local association can: two tracks that were seen apart a moment
ago both expect their vehicle inside it. Before a frame's detections go to the sampler, a
detection is replaced by one box per such track when

* at least two confirmed tracks (``min_obs`` observations, the last within ``max_age_s``) have
  their predicted centre inside it and at least ``min_inside`` of their predicted box in it,
* those predicted boxes overlap each other by less than ``max_mutual_iou`` (two vehicles, not two
  tracks on one), and
* the detection is at least ``area_ratio`` times larger than the largest of them (a vehicle seen
  whole is not cut by a neighbour's stale prediction).

Each part is the track's predicted box moved inside the detection; it keeps the detection's
confidence (scaled by ``conf_factor``) and descriptor (the blob's, shared: the parts' own pixels
are not separated), and its track's latest colour histogram. Yu & Medioni's sampler has no such move (an
observation belongs to one track; eq. 10 penalises overlaps); this step is ours.
"""

from __future__ import annotations

import numpy as np

from ..types import Detections, apply_homography, local_scales
from .posterior import inside_fraction, iou_xywh_centre

__all__ = ["split_merged"]


def split_merged(dets: Detections, centres_world: np.ndarray, sizes_world: np.ndarray,
                 H: np.ndarray, *, hists: list | None = None, geomap=None, min_inside: float = 0.6,
                 max_mutual_iou: float = 0.3, area_ratio: float = 1.4,
                 conf_factor: float = 0.9) -> tuple[Detections, int]:
    """``dets`` with each detection that holds several tracks' vehicles replaced by one box per
    track (see the module docstring).

    Parameters
    ----------
    dets : Detections
        One frame's detections (frame pixels; world through ``H``).
    centres_world, sizes_world : ndarray, shape (K, 2)
        The tracks' predicted centres and sizes in this frame, world units
        (:meth:`~aerotrack.association.local.LocalAssociator.predictions`).
    H : ndarray, shape (3, 3)
        Frame pixels -> world of this frame.
    hists : list of (ndarray or None), optional
        Each track's latest colour histogram: a part takes its track's (the blob's pixels are
        not separated between the vehicles); else the blob's.
    geomap : GeoMap, optional
        Gives the parts' map and lon/lat coordinates when ``dets`` has them.

    Returns
    -------
    (Detections, int)
        The detections (``dets`` itself when nothing is split) and the number of detections
        split.
    """
    n = len(dets)
    if n == 0 or len(centres_world) < 2:
        return dets, 0
    H = np.asarray(H, dtype=np.float64)
    centres = apply_homography(np.linalg.inv(H), np.asarray(centres_world, float))
    scale = local_scales(H, centres)
    ok = np.isfinite(centres).all(axis=1) & (scale > 0)
    wh = np.asarray(sizes_world, float) / np.where(scale > 0, scale, 1.0)[:, None]
    pred = np.column_stack([centres - wh / 2, wh])[ok]
    track_hist = [h for h, k in zip(hists or [None] * len(ok), ok) if k]
    if len(pred) < 2:
        return dets, 0
    boxes = np.asarray(dets.boxes, float)
    rows: list[tuple[int, np.ndarray, np.ndarray | None]] = []
    n_split = 0
    centred = np.column_stack([pred[:, :2] + pred[:, 2:] / 2, pred[:, 2:]])  # centre x, y, w, h
    mutual = np.triu(iou_xywh_centre(centred, centred), 1)  # (K, K), pairs once
    for i, b in enumerate(boxes):
        c = centred[:, :2]
        centre_in = ((c[:, 0] >= b[0]) & (c[:, 0] <= b[0] + b[2])
                     & (c[:, 1] >= b[1]) & (c[:, 1] <= b[1] + b[3]))
        bc = np.array([b[0] + b[2] / 2, b[1] + b[3] / 2, b[2], b[3]])
        inside = np.array([inside_fraction(z, bc, np.inf) for z in centred])
        members = np.flatnonzero(centre_in & (inside >= min_inside))
        parts = pred[members]
        if (len(parts) < 2
                or b[2] * b[3] < area_ratio * float(np.max(parts[:, 2] * parts[:, 3]))
                or mutual[np.ix_(members, members)].max() >= max_mutual_iou):
            rows.append((i, b, None))
            continue
        n_split += 1
        for m, p in zip(members, parts):  # moved inside the detection, no larger than it
            w, h = min(p[2], b[2]), min(p[3], b[3])
            x = min(max(p[0], b[0]), b[0] + b[2] - w)
            y = min(max(p[1], b[1]), b[1] + b[3] - h)
            rows.append((i, np.array([x, y, w, h]), track_hist[m]))
    if not n_split:
        return dets, 0
    idx = np.array([r[0] for r in rows])
    new = np.array([r[1] for r in rows])
    split = np.bincount(idx, minlength=n)[idx] > 1
    world = np.asarray(dets.world, float)[idx].copy()
    size_world = None if dets.size_world is None else np.asarray(dets.size_world, float)[idx].copy()
    cen = new[split, :2] + new[split, 2:] / 2
    world[split] = apply_homography(H, cen)
    if size_world is not None:
        size_world[split] = new[split, 2:] * local_scales(H, cen)[:, None]
    conf = np.asarray(dets.conf, float)[idx] * np.where(split, conf_factor, 1.0)
    extra = {k: (np.asarray(v)[idx] if isinstance(v, np.ndarray) and len(v) == n else v)
             for k, v in dets.extra.items()}
    mapxy = lonlat = None
    if dets.mapxy is not None:
        mapxy = np.asarray(dets.mapxy, float)[idx].copy()
        lonlat = None if dets.lonlat is None else np.asarray(dets.lonlat, float)[idx].copy()
        if geomap is not None:
            mapxy[split] = geomap.pixel_to_crs(world[split])
            if lonlat is not None:
                lonlat[split] = geomap.crs_to_lonlat(mapxy[split])
    hist = None
    if dets.hist is not None:
        hist = np.asarray(dets.hist, float)[idx].copy()
        for k, r in enumerate(rows):
            if r[2] is not None and len(r[2]) == hist.shape[1]:
                hist[k] = r[2]
    return Detections(frame=dets.frame, boxes=new, conf=conf, world=world, mapxy=mapxy,
                      lonlat=lonlat, hist=hist, size_world=size_world, extra=extra), n_split

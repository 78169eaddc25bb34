"""Geo error: how far a tracker's map positions are from the true ones, in metres.

Both files are MOTChallenge rows whose x, y columns (8 and 9) hold ground points in one CRS (the
contract's ``tracks.csv`` with a map; the ground truth written the same way, e.g. from a
generator's states). Boxes are matched per frame by IoU (Hungarian); the error of a match is the
distance between the two x, y points: geodesic on WGS 84 when the CRS is geographic, else the
Euclidean distance in the CRS's linear unit converted to metres.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import InputError
from ..types import box_iou


def matched_positions(gt: np.ndarray, pred: np.ndarray, *, iou_threshold: float = 0.5
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) true and (N, 2) predicted x, y of the boxes matched at ``iou_threshold``."""
    t, p = [], []
    for f in np.intersect1d(gt[:, 0], pred[:, 0]):
        g, q = gt[gt[:, 0] == f], pred[pred[:, 0] == f]
        m = box_iou(g[:, 2:6], q[:, 2:6])
        ri, ci = linear_sum_assignment(-m)
        ok = m[ri, ci] >= iou_threshold
        t.append(g[ri[ok], 7:9])
        p.append(q[ci[ok], 7:9])
    if not t:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.vstack(t), np.vstack(p)


def geo_errors(gt: np.ndarray, pred: np.ndarray, crs: str, *, iou_threshold: float = 0.5) -> dict:
    """Median, mean and 90th percentile of the metres between matched true and predicted points.

    Raises
    ------
    InputError
        Unknown CRS, or files whose x, y are -1 (no map positions).
    """
    from pyproj import CRS, Geod
    from pyproj.exceptions import CRSError

    try:
        c = CRS.from_user_input(crs)
    except CRSError:
        raise InputError(f"--geo-crs {crs}: unknown CRS") from None
    t, p = matched_positions(gt, pred, iou_threshold=iou_threshold)
    valid = np.all((t != -1) & (p != -1) & np.isfinite(t) & np.isfinite(p), axis=1)
    t, p = t[valid], p[valid]
    if not len(t):
        raise InputError("--geo-crs: no matched boxes carry map positions (x, y columns are -1)")
    if c.is_geographic:
        _, _, d = Geod(ellps="WGS84").inv(t[:, 0], t[:, 1], p[:, 0], p[:, 1])
        d = np.abs(d)
    else:
        unit = c.axis_info[0].unit_conversion_factor if c.axis_info else 1.0
        d = np.hypot(*(t - p).T) * unit
    return {"matches": int(len(d)), "median_m": float(np.median(d)), "mean_m": float(d.mean()),
            "p90_m": float(np.percentile(d, 90))}

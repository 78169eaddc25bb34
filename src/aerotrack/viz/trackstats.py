"""Per-track numbers for the report's table: length, distance, mean speed, time unobserved,
re-acquisitions.

Distances are measured on the in-view rows only (``tracks.csv``): predicted positions are guesses.
Box centres jitter by a pixel or two from frame to frame, and summing raw steps would count that
jitter as distance (a parked car would "drive" metres), so positions are first averaged over a
short window (``smooth_s``) before the steps are summed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .results import RunResults, TrackView


@dataclass(frozen=True)
class TrackStats:
    """One row of the track table.

    Attributes
    ----------
    id : int
    first_frame, last_frame : int
        First and last frame in view (1-based).
    frames_in_view : int
        Rows in ``tracks.csv``.
    duration_s : float
        Seconds from the first to the last frame in view.
    distance : float
        Path length of the smoothed in-view positions, in ``unit``.
    unit : str
        ``m`` (from a map CRS, or world units times a known scale) or ``px`` (frame 1's pixels).
    mean_speed_kmh : float
        ``distance / time in view``, km/h (NaN when the unit is not metres).
    unobserved_s : float
        Seconds between the first and last in-view frames during which the target was out of view.
    predicted_s : float
        Seconds of ``predicted.csv`` rows.
    reacquisitions : int
        Times the target was seen again after a gap in view.
    """

    id: int
    first_frame: int
    last_frame: int
    frames_in_view: int
    duration_s: float
    distance: float
    unit: str
    mean_speed_kmh: float
    unobserved_s: float
    predicted_s: float
    reacquisitions: int


def metric_positions(track: TrackView, geomap=None, metres_per_unit: float | None = None):
    """(N, 2) positions in metres east/north in a local frame (azimuthal equidistant about the map
    centre for lon/lat maps, the map CRS itself for projected ones), or world units (frame 1's
    pixels) when no scale is known.

    Returns
    -------
    xy : ndarray, shape (N, 2)
    unit : str
        ``m`` or ``px``.
    """
    if geomap is not None and np.isfinite(track.mapxy).any():
        from pyproj import CRS, Transformer

        crs = CRS.from_user_input(geomap.crs.to_wkt())
        xy = track.mapxy
        if crs.is_geographic:
            ll = geomap.crs_to_lonlat(np.nan_to_num(xy))
            ok = np.all(np.isfinite(xy), axis=1)
            # one origin for every track (the map's centre), so positions are comparable
            lon0, lat0 = geomap.pixel_to_lonlat(np.array([[geomap.width / 2, geomap.height / 2]]))[0]
            local = CRS.from_proj4(f"+proj=aeqd +lat_0={lat0} +lon_0={lon0} +datum=WGS84 +units=m")
            t = Transformer.from_crs(CRS.from_epsg(4326), local, always_xy=True)
            x, y = t.transform(ll[:, 0], ll[:, 1])
            out = np.column_stack([x, y])
            out[~ok] = np.nan
            return out, "m"
        factor = crs.axis_info[0].unit_conversion_factor if crs.axis_info else 1.0
        return xy * factor, "m"
    if geomap is not None:
        return track.world * geomap.metres_per_pixel, "m"
    if metres_per_unit:
        return track.world * float(metres_per_unit), "m"
    return track.world, "px"


def _stretch_length(xy: np.ndarray, k: int) -> tuple[float, int]:
    """Path length of one run of consecutive positions (N, 2), after a k-point moving average.

    The average is taken where the window fits ('valid' mode: N - k + 1 points, N - k steps), and
    the length is scaled to the whole run's N - 1 steps, so smoothing neither adds jitter nor
    shortens the run. Runs of k points or fewer use the straight distance between their ends.
    Returns (length, steps).
    """
    n = len(xy)
    if n <= k or k <= 1:
        if k <= 1:
            return float(np.sum(np.hypot(*np.diff(xy, axis=0).T))), n - 1
        return float(np.hypot(*(xy[-1] - xy[0]))), n - 1
    kernel = np.ones(k) / k
    sm = np.column_stack([np.convolve(xy[:, d], kernel, mode="valid") for d in range(2)])
    d = float(np.sum(np.hypot(*np.diff(sm, axis=0).T)))
    return d * (n - 1) / (n - k), n - 1


def track_stats(results: RunResults, geomap=None, *, metres_per_unit: float | None = None,
                smooth_s: float = 0.5) -> list[TrackStats]:
    """Compute :class:`TrackStats` for every track of a run, sorted by ID.

    Parameters
    ----------
    results : RunResults
    geomap : GeoMap, optional
        Gives metres from the map CRS (geodesic through a local azimuthal equidistant projection
        when the CRS is lon/lat).
    metres_per_unit : float, optional
        Scale of frame 1's pixels without a map (e.g. from a known ground sample distance).
    smooth_s : float
        Positions are averaged over this many seconds before summing steps. Longer removes more
        jitter but cuts corners of sharp turns.
    """
    fps = results.fps
    metres_per_unit = metres_per_unit or results.metres_per_unit
    k = max(1, int(round(smooth_s * fps)))
    out = []
    for tv in results.track_views(geomap):
        obs = np.flatnonzero(tv.observed)
        n_pred = int((~tv.observed).sum())
        if not len(obs):
            out.append(TrackStats(tv.id, -1, -1, 0, 0.0, 0.0, "px", float("nan"), 0.0,
                                  n_pred / fps, 0))
            continue
        xy, unit = metric_positions(tv, geomap, metres_per_unit)
        dist, moving_s = 0.0, 0.0
        for s, e in tv.stretches():
            seg = xy[s:e]
            seg = seg[np.all(np.isfinite(seg), axis=1)]
            if len(seg) >= 2:
                d, _ = _stretch_length(seg, k)
                dist += d
                moving_s += (len(seg) - 1) / fps
        f_obs = tv.frames[obs]
        first, last = int(f_obs[0]), int(f_obs[-1])
        speed = dist / moving_s * 3.6 if unit == "m" and moving_s > 0 else float("nan")
        out.append(TrackStats(
            id=tv.id, first_frame=first, last_frame=last, frames_in_view=len(obs),
            duration_s=(last - first) / fps, distance=dist, unit=unit, mean_speed_kmh=speed,
            unobserved_s=((last - first + 1) - len(obs)) / fps, predicted_s=n_pred / fps,
            reacquisitions=len(tv.reacquisitions()),
        ))
    return out

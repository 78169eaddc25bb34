"""Writes a :class:`~aerotrack.pipeline.Result` as the CLI contract's files.

``tracks.csv`` holds the frames in which a target is believed in view (observed, bridged, standing
still); ``predicted.csv`` the frames in which it is believed out of view, with the predicted box in
that frame's pixels. x, y are the ground point in the map CRS with a map, else -1.
"""

from __future__ import annotations

import json
import logging

import numpy as np

from . import __version__
from .config import Config, dumps_config
from .geo import GeoMap
from .io.mot import write_mot
from .io.output import OutputDir
from .pipeline import STILL, STILL_REASON, Result
from .types import Registration, apply_homography, local_scale

log = logging.getLogger(__name__)

IN_VIEW = ("observed", "bridged", "stationary")


def track_rows(result: Result, geomap: GeoMap | None) -> tuple[np.ndarray, np.ndarray]:
    """(tracks rows, predicted rows) as (N, 10) MOT arrays sorted by frame and id."""
    regs = result.registrations
    still = getattr(result, "still_H", None)
    if not regs and still is not None:  # detections alone on a map: boxes through its placement
        regs = _StillRegistrations(still)
    inview, predicted = [], []
    for t in result.tracks:
        last_size = None
        for p in t.points:
            box = None if p.box is None else np.asarray(p.box, dtype=np.float64)
            if box is not None and np.all(np.isfinite(box)) and box[2] > 0 and box[3] > 0:
                last_size = box[2:]
            else:
                box = _box_from_world(p, regs.get(p.frame), last_size)
                if box is None:
                    continue
            x = y = -1.0
            if geomap is not None:
                x, y = geomap.pixel_to_crs(np.asarray(p.world, dtype=np.float64)[None])[0]
            row = [p.frame, t.id, *box, float(p.conf), x, y, -1.0]
            (inview if p.kind in IN_VIEW else predicted).append(row)
    return _sorted(inview), _sorted(predicted)


#: ``links.csv``'s columns (:func:`links_csv`).
LINK_COLUMNS = ("id", "lost_frame", "found_frame", "gap_s", "kind", "cost", "motion",
                "appearance", "descriptor")


def links_csv(result: Result) -> str:
    """``links.csv``: one row per gap that global linking bridged inside a track (the target's
    identity carried from ``lost_frame``, its last observation before the gap, to
    ``found_frame``), with how the link was made and its cost (``linking.max_cost`` the most a
    link may cost) and cues (NaN: the cue was not available; an inserted piece's rows carry the
    link it was put in). A re-acquisition's cost says how sure it was: on generated exit scenes (a probe,
    2026-12-03) right links after more than 5 s had a median cost of 2.4 and wrong ones 4.3."""
    rows = [",".join(LINK_COLUMNS)]
    fps = float(result.fps or 30.0)
    for t in sorted(result.tracks, key=lambda t: t.id):
        for r in sorted(getattr(t, "links", None) or [], key=lambda r: r["lost"]):
            vals = [str(t.id), str(r["lost"]), str(r["found"]),
                    f"{(r['found'] - r['lost']) / fps:.3f}", r["kind"]]
            vals += [f"{r[k]:.3f}" if k in r else "" for k in LINK_COLUMNS[5:]]
            rows.append(",".join(vals))
    return "\n".join(rows) + "\n"


def _box_from_world(p, reg: Registration | None, size) -> np.ndarray | None:
    """A box in frame pixels around the point's world position (predicted points)."""
    if reg is None:
        if size is None:
            return None
        c = np.asarray(p.world, dtype=np.float64)
    else:
        c = apply_homography(np.linalg.inv(reg.H), np.asarray(p.world)[None])[0]
    if size is None and p.size_world is not None and reg is not None:
        # world sides over the frame's local scale there (as the detector made them)
        size = np.asarray(p.size_world, dtype=np.float64) / max(local_scale(reg.H, c), 1e-12)
    if size is None or not np.all(np.isfinite(c)):
        return None
    return np.array([c[0] - size[0] / 2, c[1] - size[1] / 2, size[0], size[1]])


def _sorted(rows: list) -> np.ndarray:
    if not rows:
        return np.zeros((0, 10))
    a = np.asarray(rows, dtype=np.float64)
    return a[np.lexsort((a[:, 1], a[:, 0]))]


def detection_rows(result: Result) -> np.ndarray:
    rows = []
    for d in result.detections:
        for b, c in zip(np.asarray(d.boxes).reshape(-1, 4), np.asarray(d.conf).reshape(-1)):
            rows.append([d.frame, -1, *b, c, -1, -1, -1])
    return _sorted(rows)


#: ``registration.csv`` status of a run without frames (``--detections`` alone).
IDENTITY = "identity"


def registration_rows(result: Result) -> list[Registration]:
    """The rows of ``registration.csv``: every registration the run used, by frame.

    Association alone (``--detections`` without INPUT, or ``track --from`` such a run) registers
    nothing: world coordinates are the detections' own pixels, i.e. the identity homography for
    every frame. Those frames get identity rows with status ``identity`` and a reason, so the
    contract's file is there and says what was used (``summary.json``: ``registration_mode``
    ``identity``, ``counts.registered_frames`` 0).
    """
    regs = result.registrations
    if regs or result.frame_size is not None:
        return [regs[i] for i in sorted(regs)]
    frames = sorted({d.frame for d in result.detections})
    if getattr(result, "still_H", None) is not None:  # on a map: its placement, every frame
        return [Registration(f, np.asarray(result.still_H, dtype=np.float64), STILL, 0,
                             float("nan"), float("nan"), STILL_REASON) for f in frames]
    why = "no frames (--detections alone): world = the detections' pixels"
    return [Registration(f, np.eye(3), IDENTITY, 0, float("nan"), float("nan"), why)
            for f in frames]


class _StillRegistrations(dict):
    """Every frame's :class:`Registration` the still placement ``H`` (``registrations.get``)."""

    def __init__(self, H: np.ndarray) -> None:
        super().__init__()
        self.H = np.asarray(H, dtype=np.float64)

    def get(self, frame, default=None):
        return Registration(int(frame), self.H, STILL, 0, float("nan"), float("nan"), STILL_REASON)


def _homographies(result: Result) -> dict[int, np.ndarray]:
    """Each frame's frame pixels -> world homography, for the observation tables: the
    registrations, or with detections alone the rows :func:`registration_rows` reports."""
    if result.registrations:
        return {i: r.H for i, r in result.registrations.items()}
    return {r.index: r.H for r in registration_rows(result)}


def write_outputs(result: Result, out: OutputDir, *, config: Config, geomap: GeoMap | None,
                  run_info: dict | None = None, out_crs: str | None = None) -> dict:
    """Write every contract file into ``out`` (atomically) and return the summary dict.

    ``run_info["start_time"]`` (ISO 8601 with a UTC offset, ``track --start-time``) dates the
    geo outputs: ``observations``' ``time_utc`` and ``tracks.geojson``'s start and end times."""
    start_time = None
    if (run_info or {}).get("start_time"):
        import datetime

        start_time = datetime.datetime.fromisoformat(run_info["start_time"])
    tracks, predicted = track_rows(result, geomap)
    write_mot(out.file("tracks.csv"), tracks)
    out.write_text("links.csv", links_csv(result))
    write_mot(out.file("predicted.csv"), predicted)
    write_mot(out.file("detections.csv"), detection_rows(result))
    from .registration import write_registration_csv

    used = registration_rows(result)
    write_registration_csv(out.file("registration.csv"), used)
    if geomap is not None:
        kinds = {(p.frame, t.id): p.kind for t in result.tracks for p in t.points
                 if p.kind in IN_VIEW}
        try:
            from .io.geojson import write_tracks_geojson
        except ImportError:
            log.warning("GeoJSON writer unavailable; tracks.geojson not written")
        else:
            write_tracks_geojson(out.file("tracks.geojson"), tracks, predicted, geomap, result.fps,
                                 start_time, kinds)
        # written with no track too (a header, an empty layer): scripts and GIS projects
        # expect the files of a run with a map
        from .io.geotable import write_observation_table

        homs = _homographies(result)
        write_observation_table(out.file("observations.csv"), tracks, geomap, result.fps,
                                out_crs, predicted=predicted, homographies=homs, kinds=kinds,
                                start_time=start_time)
    elif result.metres_per_unit and (result.registrations or result.frame_size is None):
        # --gsd without a map: the same table in metres on frame 1's ground plane (no lon/lat,
        # CSV only); a traffic study needs speeds, which were nowhere in such a run's outputs.
        # Detections alone (no frames): the detections' pixels at --gsd
        from .io.geotable import write_local_observation_table

        homs = _homographies(result)
        kinds = {(p.frame, t.id): p.kind for t in result.tracks for p in t.points
                 if p.kind in IN_VIEW}
        write_local_observation_table(out.file("observations.csv"), tracks, result.fps,
                                      result.metres_per_unit, predicted=predicted,
                                      homographies=homs, kinds=kinds, start_time=start_time,
                                      ground=bool((run_info or {}).get("ground")))
    # the run's options that are not configuration, so that `--config config.toml` is known to
    # need them (a run with --seed 3 --fps 10 --gsd 0.15 was not repeated by the file alone)
    info = run_info or {}
    opts = ([f"--seed {info['seed']}"] if info.get("seed") is not None else []) \
        + [f"--fps {result.fps:g}"] \
        + ([f"--ground {info['ground']}"] if info.get("ground") else
           [f"--gsd {result.metres_per_unit:g}"]
           if geomap is None and result.metres_per_unit else [])
    out.write_text("config.toml", f"# run with: {' '.join(opts)} (inputs and the other options: "
                                  "summary.json); --config of this file with them repeats it\n"
                   + dumps_config(config))
    n_ids = len(np.unique(tracks[:, 1])) if len(tracks) else 0
    links = [r for t in result.tracks for r in (getattr(t, "links", None) or [])]
    summary = run_summary(result, geomap, info, tracked={
        "tracks": n_ids, "track_rows": int(len(tracks)), "predicted_rows": int(len(predicted)),
        "links": len(links),
        "links_after_5s": sum((r["found"] - r["lost"]) / float(result.fps or 30.0) > 5
                              for r in links)})
    out.write_text("summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def run_summary(result: Result, geomap: GeoMap | None, run_info: dict | None,
                tracked: dict | None = None) -> dict:
    """``summary.json`` of a run: what ran on what, counts, timings and registration failures.

    ``tracked``: the track counts (``tracks``, ``track_rows``, ``predicted_rows``) of a run that
    tracked; ``aerotrack detect`` has none."""
    info = run_info or {}
    failures = [
        {"frame": i, "status": r.status, "reason": r.reason}
        for i, r in sorted(result.registrations.items()) if r.status not in ("ok", "refined")
    ]
    total = sum(result.timings.values())
    return {
        "aerotrack_version": __version__,
        **info,
        "fps": result.fps,
        "frames": result.frames,
        "first_frame": result.first_frame,
        "last_frame": result.last_frame,
        "frame_size": list(result.frame_size) if result.frame_size else None,
        "metres_per_unit": result.metres_per_unit,
        # detections alone on a map: the placement every frame was given (track --from needs it)
        **({"still_placement": np.asarray(result.still_H, dtype=np.float64).ravel().tolist()}
           if getattr(result, "still_H", None) is not None else {}),
        # the CRS of tracks.csv's and predicted.csv's x, y (with a map): they were not named
        # anywhere but in the map file itself
        **({"map_crs": _crs_name(geomap)} if geomap is not None else {}),
        "registration_mode": (IDENTITY if not result.registrations and result.frame_size is None
                              and getattr(result, "still_H", None) is None
                              else "map" if geomap is not None
                              else "ground" if info.get("ground") else "frame1"),
        "counts": {
            "detections": int(sum(len(d) for d in result.detections)),
            **(tracked or {}),
            "registered_frames": len(result.registrations),
            "registration_failures": len(failures),
            # with association.follow_stopped (single process): what the stop follower added
            **({} if result.followed is None else {"followed_detections": result.followed}),
        },
        # how much the local sampler changed: most proposals are rejected, but the accepted
        # ones matter (Santiago with it off: HOTA/IDF1 0.670/0.891 -> 0.639/0.846)
        # (null for a run whose association never started: no detection)
        **({"mcmc": mcmc_summary(result.mcmc) if getattr(result, "mcmc", None) else None}
           if tracked is not None else {}),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        # of the frames this run's timings cover (a resumed run's said 17-22 for 6-10)
        "frames_per_second": (round((result.frames_timed or result.frames) / total, 2)
                              if total > 0 else None),
        "registration_failures": failures,
    }



def mcmc_summary(counts: dict) -> dict:
    """``summary.json`` ``mcmc``: proposals and acceptances in all and per move
    (``[accepted, proposed]``)."""
    pro, acc = counts["proposed"], counts["accepted"]
    n_pro, n_acc = sum(pro.values()), sum(acc.values())
    return {"proposed": n_pro, "accepted": n_acc,
            "acceptance": round(n_acc / n_pro, 4) if n_pro else None,
            "by_move": {m: [int(acc.get(m, 0)), int(pro[m])] for m in pro}}


def _crs_name(geomap) -> str | None:
    """The map's CRS as ``AUTH:CODE`` (or a PROJ string), for summary.json."""
    from pyproj import CRS

    from .io.geotable import crs_label

    try:
        return crs_label(CRS.from_user_input(geomap.crs.to_wkt()))
    except Exception:  # noqa: BLE001  a name for people: never fail the outputs over it
        return None

"""``aerotrack track``: the whole pipeline from frames (or detections) to the contract's files."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Self

import click

from .common import (
    CleanupOnBadInput,
    InputParam,
    Interrupted,
    PathArg,
    check_overwrite,
    check_positive,
    config_option,
    detections_zero_based_option,
    frames_option,
    ground_option,
    gsd_option,
    ignore_option,
    intrinsics_option,
    make_progress,
    map_init_option,
    min_conf_option,
    roi_option,
    root_flags,
    seed_option,
    set_option,
    stride_option,
    telemetry_default_option,
    telemetry_option,
    track_fps_option,
)
from .hints import clip_hints, noise_hint, run_hints

log = logging.getLogger("aerotrack")


class GracefulStop:
    """Ctrl-C and SIGTERM stop a run between two frames, where finished work can be checkpointed.

    A signal arriving inside compiled code (numba, OpenCV) can surface as another exception; so
    the first Ctrl-C (or SIGTERM) only sets a flag that the per-frame progress callback turns into
    :class:`~aerotrack.cli.common.Interrupted` at a safe point; the pipeline then checkpoints into
    ``.partial/``. A second signal interrupts at once. While the final files are written
    (:meth:`writing`), signals are held off until every file is in place, so an interrupted run
    leaves either the complete set of results or none. Handlers are only installed from the main
    thread and are restored on exit.
    """

    NOTE = ("; finished work is kept in the output folder's .partial/ "
            "(continue with --resume)")

    def __init__(self, note: str | None = None, until: str = "after this frame") -> None:
        #: completes the line ``aerotrack: interrupted`` of a second, immediate signal
        self.note = self.NOTE if note is None else note
        #: when the run stops after a first signal, for its message ("after this frame"; a
        #: ``--workers`` run stops once the segments running on the cluster are finished)
        self.until = until
        self.stop_signal: int | None = None
        self.phase = "frames"
        self._previous: dict[int, object] = {}

    def __enter__(self) -> Self:
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc) -> bool:
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        return False

    def _handler(self, signum, frame) -> None:
        if self.phase == "writing":
            if self.stop_signal is None:
                log.warning("interrupt: writing the results; stopping once every file is in place")
            self.stop_signal = signum
            return
        if self.stop_signal is not None:
            raise Interrupted(signum, self.note)
        import signal

        self.stop_signal = signum
        again = "Ctrl-C" if signum == signal.SIGINT else "the signal"
        log.warning("interrupt: stopping %s (%s again to stop at once)", self.until, again)

    def wrap(self, progress):
        """The progress callback, raising :class:`Interrupted` after the frame a signal came in."""

        def wrapped(n: int) -> None:
            progress(n)
            if self.stop_signal is not None:
                raise Interrupted(self.stop_signal, self.note)

        return wrapped

    def writing(self, partial: bool = False) -> None:
        """From now on hold signals off: the files are being written (the complete results, or
        with ``partial`` those of the frames finished before an interruption)."""
        if self.stop_signal is not None and not partial:
            log.warning("interrupt came after the last frame: writing the complete results")
        self.phase = "writing"


def load_inputs(input_path, detections_path, map_path, map_init_path, fps, gsd,
                telemetry_path=None, intrinsics_path=None, start: int = 1, config=None,
                telemetry_defaults=(), detections_zero_based: bool = False, ground_path=None,
                workers: int = 1):
    """Open and validate every input before any work starts (so bad input fails fast).

    With ``start`` > 1 (``--frames A:B``) the map placement returned is frame A's: the
    telemetry's at that frame, or ``--map-init`` (frame 1's) carried to frame A by registering
    the frames before it (:func:`~aerotrack.registration.registrar.carry_placement`, with
    ``config``'s registration settings)."""
    from ..errors import InputError
    from ..geo import GeoMap, read_map_init
    from ..geo.init import check_overlap
    from ..io import open_source
    from ..io.mot import check_detections, read_mot

    if input_path is None and detections_path is None:
        raise InputError("give INPUT (a video or image folder) or --detections FILE")
    if map_path is not None and map_init_path is None and telemetry_path is None:
        raise InputError("--map needs --map-init (or --telemetry) to place frame 1 on it")
    if map_path is None and (map_init_path is not None or telemetry_path is not None):
        raise InputError("--map-init and --telemetry need --map")
    if map_init_path is not None and telemetry_path is not None:
        raise InputError("give either --map-init or --telemetry, not both")
    if telemetry_defaults and telemetry_path is None:
        raise InputError("--telemetry-default: only used with --telemetry")
    if telemetry_path is not None and input_path is None:
        raise InputError("--telemetry needs INPUT frames to lock on to the map")
    check_positive(gsd, "--gsd", "a positive number of metres per pixel")
    if gsd is not None and map_path is not None:
        log.warning("--gsd %g: not used with --map (the map gives the scale)", gsd)
    if fps is not None and not (fps > 0 and fps < 1e4):
        raise InputError(f"--fps {fps}: must be a positive number")
    source = open_source(input_path, fps) if input_path is not None else None
    dets = None
    if detections_path is not None:
        dets, lines = read_mot(detections_path, option="--detections", strict=True,
                               zero_based=detections_zero_based, detections=True, lines=True)
        check_detections(dets, f"--detections {detections_path}", source, lines=lines,
                         min_conf=config.detection.min_conf if config is not None else None)
    undistort = None
    if intrinsics_path is not None:
        from ..geo.lens import Undistorter, read_intrinsics

        undistort = Undistorter(read_intrinsics(intrinsics_path))
    geomap = H_init = None
    notes = {}
    if map_path is not None:
        geomap = GeoMap(map_path)
        if telemetry_path is not None:
            from ..geo.telemetry import (
                parse_telemetry_defaults,
                read_telemetry,
                telemetry_map_init,
            )

            tel = read_telemetry(telemetry_path, fps=source.fps,
                                 defaults=parse_telemetry_defaults(telemetry_defaults))
            first = next(iter(source.frames(start=start, stop=start)), None)
            if first is None:
                raise InputError(f"{input_path}: frame {start} cannot be read")
            if undistort is not None:
                first = undistort(first)
            H_init, notes["telemetry"] = telemetry_map_init(tel, first, geomap, source.fps)
            init_label = f"--telemetry {telemetry_path}"
        else:
            H_init = read_map_init(map_init_path, geomap)
            init_label = f"--map-init {map_init_path}"
        if source is not None:
            check_overlap(source.size, H_init, geomap, init_label)
            if start > 1 and telemetry_path is None:
                from ..config import Config
                from ..registration.registrar import carry_placement

                log.info("--frames from %d: registering frames 1-%d to carry --map-init (frame "
                         "1's placement) to frame %d", start, start - 1, start)
                H_init = carry_placement(source, H_init, start, geomap, source.fps,
                                         (config or Config()).registration, undistort)
    if ground_path is not None:
        from ..geo.init import read_ground

        H_init = read_ground(ground_path)
        if source is not None:
            _check_ground(source.size, H_init, f"--ground {ground_path}")
            notes["ground_fit"] = ground_fit(ground_path, source.size, H_init)
            if start > 1:
                from ..config import Config
                from ..registration.registrar import carry_placement

                log.info("--frames from %d: registering frames 1-%d to carry --ground (frame "
                         "1's) to frame %d", start, start - 1, start)
                H_init = carry_placement(source, H_init, start, None, source.fps,
                                         (config or Config()).registration, undistort)
    if source is not None and dets is None:
        warn_memory(source, (config.detection.window_s if config is not None else 3.0),
                    workers=workers)
    irregular = getattr(source, "timing_irregularity", None)
    spread = irregular() if irregular is not None else None
    if spread is not None:
        log.warning("%s: variable frame rate (frames %.0f-%.0f ms apart): frames are numbered in "
                    "decoding order and timed at %g frames/s, so speeds and times are off where "
                    "the rate differs; re-encode at a constant rate for exact ones (ffmpeg -i IN "
                    "-fps_mode cfr -r %g OUT)", source.path, spread[0], spread[1], source.fps,
                    round(source.fps))
    return source, dets, geomap, H_init, undistort, notes


def check_stream_options(input_path, frame_range, telemetry_path, resume: bool = False,
                         workers=None, scheduler=None) -> None:
    """Options a live stream as INPUT cannot take, refused in one line: it is read once, as it
    arrives (:class:`~aerotrack.io.frames.StreamSource`)."""
    from ..errors import InputError
    from ..io.frames import is_stream_url

    if not is_stream_url(input_path):
        return
    if resume or workers is not None or scheduler is not None:
        what = "--resume" if resume else "--workers" if workers is not None else "--scheduler"
        raise InputError(f"{what}: not with a live stream as INPUT ({input_path}): a stream "
                         "cannot be read again (record it to a file for that)")
    if telemetry_path is not None:
        raise InputError(f"--telemetry: not with a live stream as INPUT ({input_path}): "
                         "its frames cannot be matched to the log's times (use --map-init)")
    if parse_frame_range(frame_range)[0] > 1:
        raise InputError(f"--frames {frame_range}: a live stream's frames are numbered as "
                         "they arrive; it starts at its first (give --frames :B)")


def warn_memory(source, window_s: float, share: float = 0.5, workers: int = 1) -> None:
    """Warn when the detector's window of full-size frames (it holds about ``window_s`` seconds
    of them: a frame is final half a window later, and boxes are refined on it at full size),
    in each of ``workers`` processes (``--workers``: every segment holds its own), would take more
    than ``share`` of this machine's memory: 6000x4000 frames at 30 fps held 7.1 GB. A run's
    peak is about 1.5 times the window's frames (a generated 3840x2160 survey at 30 fps: 3.4 GB
    against 2.2 GB of frames; 6.3 GB with 2 workers)."""
    import os

    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        return
    w, h = source.size
    n = max(1, int(workers or 1))
    need = 1.5 * w * h * 3 * source.fps * window_s * n
    if need > share * total:
        log.warning("%s: %dx%d frames at %g fps: the detector's %g s window%s takes about %.1f GB "
                    "at the peak, this machine has %.1f GB; --stride 2 halves it, "
                    "--set detection.window_s=1.5 too (fewer background samples)%s", source.path,
                    w, h, source.fps, window_s, f" in each of {n} workers" if n > 1 else "",
                    need / 1e9, total / 1e9, ", fewer --workers too" if n > 1 else "")


def where(path) -> str | None:
    """An input's place for ``summary.json``: absolute, so that ``--from``, ``render`` and
    ``report`` find it from any folder (a stream's URL as given)."""
    from ..io.frames import is_stream_url

    if path is not None and is_stream_url(path):
        return path
    return str(Path(path).resolve()) if path is not None else None


def check_ground(ground_path, input_path, others: dict) -> None:
    """``--ground`` refused with the options given in ``others`` (name -> value) and without
    INPUT, before any work."""
    from ..errors import InputError

    if ground_path is None:
        return
    given = [n for n, v in others.items() if v]
    if given:
        raise InputError(f"--ground {ground_path}: not with {', '.join(given)} (it is the "
                         "ground plane and its scale)")
    if input_path is None:
        raise InputError(f"--ground {ground_path}: needs INPUT frames (it places frame 1)")


def ground_fit(path, size, H) -> dict:
    """How well ``--ground``'s control points fit its plane, and how they cover frame 1, for
    the log and ``summary.json``; refuses frame points outside frame 1 (points read off a
    still of another size) and warns of a mirrored plane, of a point off by more than 1 m and
    of points covering under a quarter of the frame (the scale away from them is a guess: one
    lane rectangle in the middle of the frame gave 0.3x-7x across it and HOTA 0.33)."""
    import cv2
    import numpy as np

    from ..errors import GeoreferenceError
    from ..geo.init import ground_points
    from ..types import apply_homography

    w, h = size
    A = np.asarray(H, np.float64)
    out: dict = {"homography": [[round(float(v), 9) for v in row] for row in A]}
    centre = np.array([w / 2, h / 2])
    d = 1.0
    p0, px, py = apply_homography(A, np.array([centre, centre + (d, 0), centre + (0, d)]))
    (ax, ay), (bx, by) = px - p0, py - p0
    if ax * by - ay * bx > 0:
        log.warning("%s: the ground plane is mirrored (x and y swapped, or y pointing south): "
                    "speeds are right, headings are not (ground y must be 90 degrees "
                    "anticlockwise from x, as north from east)", path)
        out["mirrored"] = True
    pts = ground_points(path)
    if pts is None:
        return out
    f = pts[:, :2]
    if (f[:, 0] < -0.01 * w).any() or (f[:, 0] > 1.01 * w).any() or (f[:, 1] < -0.01 * h).any() \
            or (f[:, 1] > 1.01 * h).any():
        raise GeoreferenceError(f"--ground {path}: frame points outside frame 1 ({w}x{h}): "
                                "frame_x, frame_y must be frame 1's pixels")
    res = np.hypot(*(apply_homography(A, f) - pts[:, 2:]).T)
    hull = cv2.convexHull(f.astype(np.float32))
    cover = float(cv2.contourArea(hull)) / float(w * h)
    out.update({"points": int(len(pts)), "rms_m": round(float(np.sqrt(np.mean(res ** 2))), 3),
                "max_m": round(float(res.max()), 3), "frame_cover": round(cover, 3)})
    log.info("%s: %d points, fit RMS %.2f m, largest %.2f m (point %d), covering %.0f%% of "
             "frame 1", path, len(pts), out["rms_m"], out["max_m"], int(res.argmax()) + 1,
             100 * cover)
    if res.max() > 1.0:
        log.warning("%s: point %d is %.1f m off the plane the others make: a mismeasured "
                    "point?", path, int(res.argmax()) + 1, float(res.max()))
    if cover < 0.25:
        log.warning("%s: the points cover %.0f%% of frame 1: the scale away from them is "
                    "extrapolated; spread them over the frame (near and far)", path, 100 * cover)
    return out


def _check_ground(size, H, label: str) -> None:
    """Frame 1 placed on a ground plane must stay in front of the camera: every corner finite,
    on the same side of the horizon (a homography through the horizon turns the far rows
    inside out), and a plausible size (0.5 m to 100 km across)."""
    import numpy as np

    from ..errors import GeoreferenceError

    w, h = size
    corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float) @ np.asarray(H).T
    if not (np.all(np.isfinite(corners)) and (np.all(corners[:, 2] > 0)
                                              or np.all(corners[:, 2] < 0))):
        raise GeoreferenceError(f"{label}: frame 1's corners do not all land on the ground (the "
                                "horizon or the sky is in the frame, or the points are wrong)")
    xy = corners[:, :2] / corners[:, 2:]
    span = float(np.hypot(*np.ptp(xy, axis=0)))
    if not 0.5 <= span <= 1e5:
        raise GeoreferenceError(f"{label}: frame 1 spans {span:.3g} m of ground: are the ground "
                                "coordinates in metres?")


def load_regions(roi_paths, ignore_paths, geomap, frame_size=None) -> list:
    """The ``--roi`` (include) and ``--ignore-region`` regions, in that order. An ``--roi``
    that cannot hold anything the run sees (wholly outside the ``frame_size`` frame, for one in
    frame pixels, or off the map) is named in a warning: every detection would be dropped."""
    if not roi_paths and not ignore_paths:
        return []
    import numpy as np

    from ..geo.roi import read_region

    regions = ([read_region(p, geomap, mode="include", option="--roi") for p in roi_paths]
               + [read_region(p, geomap, mode="ignore", option="--ignore-region")
                  for p in ignore_paths])
    for path, r in zip(roi_paths, regions):
        if r.space == "frame" and frame_size is not None:
            w, h, where = frame_size[0], frame_size[1], f"the {frame_size[0]}x{frame_size[1]} frame"
        elif r.space == "world" and geomap is not None:
            w, h, where = geomap.width, geomap.height, "the map"
        else:  # (frame-1 pixels on a moving camera: it may come into view later)
            continue
        pts = np.vstack([ring for poly in r.polygons for ring in poly[:1]]) if r.polygons \
            else np.zeros((0, 2))
        if len(pts) and (pts[:, 0].max() < 0 or pts[:, 1].max() < 0 or pts[:, 0].min() > w
                         or pts[:, 1].min() > h):
            log.warning("--roi %s: lies wholly outside %s, so every detection is dropped: "
                        "are its coordinates in the right space (frame pixels, or the map's "
                        "CRS)?", path, where)
    return regions


def check_frame_range(frame_range: str | None, start: int, last: int,
                      stop: int | None = None) -> None:
    """Refuse a ``--frames`` range that starts after the input's ``last`` frame (0: unknown);
    say so when it ends after it (the run is cut at ``last``)."""
    from ..errors import InputError

    if frame_range is not None and last and start > last:
        raise InputError(f"--frames {frame_range}: starts after the input's last frame ({last})")
    if frame_range is not None and last and stop is not None and stop > last:
        log.warning("--frames %s: the input ends at frame %d; frames %d-%d are processed",
                    frame_range, last, start, last)


def no_frames_read(input_path, frame_range: str | None, count: int) -> str:
    """The error for a run that read no frame: a truncated video whose header promises more
    frames than its data holds, asked for frames beyond what decodes."""
    asked = f" of --frames {frame_range}" if frame_range else ""
    return (f"{input_path}: no frame{asked} could be read (the header says {count} frames; "
            "the file may be truncated)")


def parse_frame_range(text: str | None) -> tuple[int, int | None]:
    """``A:B`` -> (A, B) 1-based inclusive; empty ends mean the first / last frame."""
    from ..errors import InputError

    if text is None:
        return 1, None
    a, sep, b = text.partition(":")
    try:
        start = int(a) if a.strip() else 1
        stop = int(b) if b.strip() else None
    except ValueError:
        raise InputError(f"--frames {text}: expected A:B with 1-based frame numbers") from None
    if not sep or start < 1 or (stop is not None and stop < start):
        raise InputError(f"--frames {text}: expected A:B with 1 <= A <= B")
    return start, stop


@click.command("track")
@click.argument("input_path", metavar="[INPUT]", required=False, type=InputParam(path_type=Path))
@click.option("--out", "out_dir", required=True, type=PathArg(path_type=Path),
              help="Output folder (new, or empty; see --overwrite/--resume).")
@click.option("--detections", "detections_path", type=PathArg(path_type=Path), default=None,
              help="MOTChallenge detections (frame,id,x,y,w,h,conf; 1-based; the id column is "
                   "ignored) replacing the built-in detector. Without INPUT: association alone "
                   "in image coordinates.")
@detections_zero_based_option
@min_conf_option
@click.option("--map", "map_path", type=PathArg(path_type=Path), default=None,
              help="Georeferenced raster of the area (GeoTIFF, VRT, or any raster GDAL reads with "
                   "a world file and CRS): tracking happens on the map.")
@map_init_option
@gsd_option
@ground_option
@track_fps_option
@seed_option
@config_option
@set_option
@telemetry_option
@telemetry_default_option
@intrinsics_option
@roi_option
@ignore_option
@click.option("--roads", "roads_path", type=PathArg(path_type=Path), default=None,
              help="Road centre-lines (GeoJSON LineStrings, any CRS, or a GeoPackage, "
                   "Shapefile, ... with pyogrio; needs --map): unobserved vehicles are predicted "
                   "along the roads.")
@click.option("--min-speed", "min_speed", type=float, default=None,
              help="Drop tracks never faster than this many m/s (parked vehicles).")
@click.option("--start-time", "start_time", metavar="TIME", default=None,
              help="Wall-clock time of frame 1, ISO 8601 with a UTC offset (2024-05-01T10:30:00Z): "
                   "observations get a time_utc column and tracks.geojson start and end times, "
                   "for GIS time sliders.")
@click.option("--out-crs", "out_crs", default=None,
              help="Projected CRS of observations.csv/.gpkg and track_segments.gpkg (default: the "
                   "local UTM zone).")
@frames_option
@stride_option
@click.option("--stabilised", is_flag=True,
              help="Frames are already registered to each other (a stabilised video, a fixed "
                   "camera): skip registration and use identity homographies (not with --map).")
@click.option("--from", "from_dir", type=PathArg(path_type=Path), default=None,
              help="Reuse the registrations and detections cached by an earlier run in this folder "
                   "(its stages/): only association and linking run again.")
@click.option("--overwrite", is_flag=True,
              help="Replace the results already in --out (a folder holding other files is "
                   "refused, not emptied).")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted run in --out from its .partial/ (give the same "
                   "inputs and options).")
@click.option("--on-interrupt", "on_interrupt", type=click.Choice(["keep", "finish"]),
              default=None,
              help="What Ctrl-C (or SIGTERM) does: keep the finished work in .partial/ for "
                   "--resume, or finish: end the run there as if the video ended, and write "
                   "every result for the frames read (a live feed, a flight cut short). "
                   "Default: keep, finish for a stream (which cannot be resumed).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Split the video into overlapping segments processed by N local worker "
                   "processes (Dask; pip install 'aerotrack[dask]'). Default: one process.")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run the segments on an existing Dask cluster (tcp://host:8786).")
@click.pass_context
def track_command(ctx, input_path, out_dir, detections_path, map_path, map_init_path, gsd, fps,
                  seed, config_path, overrides, telemetry_path, telemetry_defaults,
                  intrinsics_path, roi_paths, ignore_paths, min_speed, out_crs, frame_range, stride,
                  overwrite, resume, workers, scheduler, from_dir=None, roads_path=None,
                  stabilised=False, detections_zero_based=False, min_conf=None,
                  start_time=None, on_interrupt=None, ground_path=None):
    """Track every moving vehicle: registration, detection, local and global association.

    \b
    Writes to --out: tracks.csv, predicted.csv, links.csv, detections.csv, registration.csv,
    tracks.geojson and observations.csv (with a map; with the gis extra also
    observations.gpkg/.parquet and track_segments.gpkg), config.toml, summary.json,
    stages/ (cached registrations and detections for --from).

    \b
    Examples:
      aerotrack track flight.mp4 --out run/
      aerotrack track frames/ --out run/ --map ortho.tif --map-init h.txt --fps 30
      aerotrack track --detections yolo.txt --out run/          # association alone
      aerotrack track flight.mp4 --detections yolo.txt --out run/ --seed 3
      aerotrack track far.mp4 --out run/ --set detection.persist=true
        --set detection.stopping_share=0                    # tiny, faint targets
      aerotrack track rtsp://192.168.1.10:8554/live --out run/ --on-interrupt finish
        --set detection.causal=true                # a live feed: Ctrl-C writes the results

    \b
    Settings worth knowing (README "Fitting it to your footage"): --gsd or --map for a
    metric scale; detection.persist=true with detection.stopping_share=0 for vehicles a few
    pixels long (slower);
    finish.static_extent_m, wander_extent_m, min_size_m and min_size_estimated_m set to 0
    keep pedestrians and objects that linger; detection.causal=true for live use.
    """
    from ..config import dumps_config, given_settings, load_config, unused_settings
    from ..errors import InputError
    from ..io.output import OutputDir
    from ..outputs import write_outputs
    from ..pipeline import check_config, run

    given_config = load_config(config_path, overrides)
    given = given_settings(config_path, overrides)
    if min_conf is not None:
        if not 0.0 <= min_conf <= 1.0:
            raise InputError(f"--min-conf {min_conf}: must be a confidence between 0 and 1")
        if "detection.min_conf" in given and given_config.detection.min_conf != min_conf:
            log.warning("--min-conf %g: used instead of detection.min_conf %g from --config/--set "
                        "(an option beats the config)", min_conf, given_config.detection.min_conf)
        overrides = (*overrides, f"detection.min_conf={min_conf!r}")
    config = load_config(config_path, overrides)
    if resume and overwrite:
        raise InputError("--resume and --overwrite: give one (continue the run in --out, or "
                         "start it again)")
    if detections_zero_based and detections_path is None and from_dir is None:
        raise InputError("--detections-zero-based: only with --detections")
    if from_dir is not None:
        given = [name for name, value in (
            ("INPUT", input_path), ("--detections", detections_path), ("--frames", frame_range),
            ("--stride", stride != 1), ("--map-init", map_init_path),
            ("--telemetry", telemetry_path), ("--telemetry-default", telemetry_defaults),
            ("--intrinsics", intrinsics_path),
            ("--roi", roi_paths), ("--ignore-region", ignore_paths), ("--resume", resume),
            ("--workers", workers), ("--scheduler", scheduler), ("--stabilised", stabilised),
            ("--detections-zero-based", detections_zero_based), ("--ground", ground_path))
            if value]
        if given:
            raise InputError(f"--from {from_dir}: re-runs association on that run's cached "
                             f"registrations and detections, so {', '.join(given)} cannot be "
                             "given with it (they were the earlier run's)")
        return _track_from_cache(ctx, from_dir, out_dir, config, map_path, seed, gsd, fps,
                                 min_speed, out_crs, overwrite, roads_path=roads_path,
                                 start_time=start_time)
    if stabilised and map_path is not None:
        raise InputError("--stabilised: not with --map (frames are registered to the map)")
    if stabilised and input_path is None:
        raise InputError("--stabilised: needs an INPUT video or folder (without one, --detections "
                         "are associated in image coordinates already)")
    check_stream_options(input_path, frame_range, telemetry_path, resume=resume, workers=workers,
                         scheduler=scheduler)
    from ..io.frames import is_stream_url

    stream = is_stream_url(input_path)
    if stream and on_interrupt == "keep":
        raise InputError(f"--on-interrupt keep: not with a live stream as INPUT ({input_path}): "
                         "what it keeps is for --resume, which a stream cannot take")
    on_interrupt = on_interrupt or ("finish" if stream else "keep")
    if on_interrupt == "finish" and (workers is not None or scheduler is not None):
        raise InputError("--on-interrupt finish: one process only (with --workers or "
                         "--scheduler an interruption keeps the finished segments for --resume)")
    start, stop = parse_frame_range(frame_range)
    if min_speed is not None and not (min_speed >= 0 and min_speed < float("inf")):
        raise InputError(f"--min-speed {min_speed}: must be >= 0 m/s")
    check_ground(ground_path, input_path, {"--map": map_path, "--gsd": gsd,
                                           "--stabilised": stabilised})
    source, dets, geomap, H_init, undistort, notes = load_inputs(
        input_path, detections_path, map_path, map_init_path, fps, gsd, telemetry_path,
        intrinsics_path, start=start, config=config, telemetry_defaults=telemetry_defaults,
        detections_zero_based=detections_zero_based, ground_path=ground_path,
        workers=workers if workers and not scheduler else 1)
    metres_per_unit = 1.0 if ground_path is not None else (None if geomap else gsd)
    roads = load_roads(roads_path, geomap, config)
    regions = load_regions(roi_paths, ignore_paths, geomap,
                           getattr(source, "size", None) if source is not None else None)
    check_out_crs(out_crs, geomap)
    start_time = parse_start_time(start_time, geomap)
    last = source.count if source is not None else (int(dets[:, 0].max()) if len(dets) else 0)
    check_frame_range(frame_range, start, last, stop)
    check_config(config, fps)  # before --out is touched
    for why in unused_settings(given, config,
                               metric_scale=geomap is not None or metres_per_unit is not None,
                               detector=dets is None):
        log.warning("%s", why)
    if scheduler is not None:
        from ..parallel import check_scheduler

        if workers is not None:
            raise InputError("--workers and --scheduler cannot be used together")
        check_scheduler(scheduler)

    manifest = {
        "input": where(input_path), "detections": where(detections_path), "map": where(map_path),
        "map_init": where(map_init_path), "telemetry": where(telemetry_path),
        "telemetry_defaults": sorted(telemetry_defaults),
        "intrinsics": where(intrinsics_path), "roi": [where(r) for r in roi_paths],
        "ignore_region": [where(r) for r in ignore_paths], "roads": where(roads_path),
        "fps": fps, "gsd": gsd, "seed": seed, "frames": [start, stop], "stride": stride,
        **({"ground": where(ground_path)} if ground_path is not None else {}),
        "min_speed": min_speed, "config": dumps_config(config),
        **({"stabilised": True} if stabilised else {}),  # absent: run.json of earlier runs match
        **({"detections_zero_based": True} if detections_zero_based else {}),
        # a run interrupted in one mode and resumed in the other started over silently and
        # left stale checkpoints that broke `track --from`
        **({"on_dask": True} if workers is not None or scheduler is not None else {}),
    }
    # the input files as they were (size, modification time): a resume over a changed frame
    # had silently kept the results of the old one
    from ..io.state import input_fingerprints

    manifest["input_files"] = input_fingerprints(
        [input_path, detections_path, map_path, map_init_path, telemetry_path, intrinsics_path,
         *roi_paths, *ignore_paths, roads_path, ground_path])
    check_overwrite(out_dir, overwrite)
    from ..io.output import check_outside

    check_outside(out_dir, "--out", [
        ("INPUT", input_path), ("--detections", detections_path), ("--map", map_path),
        ("--map-init", map_init_path), ("--telemetry", telemetry_path),
        ("--intrinsics", intrinsics_path), ("--roads", roads_path), ("--ground", ground_path),
        *(("--roi", r) for r in roi_paths), *(("--ignore-region", r) for r in ignore_paths)])
    if resume and finished_run(out_dir, input_path, detections_path, seed, manifest):
        if not root_flags(ctx)[0]:
            click.echo(f"aerotrack: {out_dir}: the run is already finished; nothing to resume "
                       "(--overwrite runs it again)", err=True)
        return
    from ..io.output import PARTIAL

    if resume and not (Path(out_dir) / PARTIAL).is_dir():
        log.warning("--resume %s: no interrupted run there (no %s/): tracking from the first "
                    "frame", out_dir, PARTIAL)
    cleanup = CleanupOnBadInput(out_dir, resume=resume)  # before the folder is made
    out = OutputDir(out_dir, overwrite=overwrite, resume=resume, resumable=True, stage=True)
    with cleanup:
        resume_manifest(out.partial, manifest, resume)
    quiet, verbose = root_flags(ctx)
    total = last
    if total:
        total = len(range(start, min(stop or total, total) + 1, stride))
    progress, close = make_progress(total, "track", quiet, verbose)
    t0 = time.perf_counter()
    if workers is not None or scheduler is not None:  # segments on Dask (aerotrack.parallel)
        from functools import partial

        from ..parallel import run_on_dask

        run = partial(run_on_dask, workers=workers, scheduler=scheduler)
    on_dask = workers is not None or scheduler is not None
    until = "when the running segments are finished (they are kept)" if on_dask \
        else "after this frame"
    # a second signal drops the running segments: only the finished ones are kept
    note = ("; finished segments are kept in the output folder's .partial/ (continue with "
            "--resume: segments not finished are tracked again)") if on_dask else None
    if on_interrupt == "finish":
        until = "after this frame and finishing the run there"
    with cleanup, GracefulStop(until=until, note=note) as stopper:
        try:
            result = run(source, config=config, fps=fps, geomap=geomap, H_init=H_init, seed=seed,
                         detections=dets, metres_per_unit=metres_per_unit,
                         progress=stopper.wrap(progress), checkpoint_dir=out.partial,
                         resume=resume, start=start, stop=stop, stride=stride,
                         undistort=undistort, regions=regions, min_speed_mps=min_speed,
                         stabilised=stabilised, H_init_frame=start,  # carried (load_inputs)
                         **({"roads": roads} if roads is not None else {}))
        except Interrupted as exc:
            if on_interrupt != "finish" or getattr(exc, "pipeline", None) is None \
                    or not getattr(exc, "between_frames", False):
                raise
            close()
            result = _finish_interrupted(exc.pipeline, stopper, stream)
            notes = {**notes, "interrupted_at_frame": result.last_frame}
        finally:
            close()
        if source is not None and not result.frames:
            raise InputError(no_frames_read(input_path, frame_range, source.count))
        stopper.writing(partial="interrupted_at_frame" in notes)
        warn_if_never_refined(result, geomap, config,
                              f"--telemetry {telemetry_path}" if telemetry_path is not None
                              else f"--map-init {map_init_path}" if map_init_path else None)
        hints = run_hints(result, config, detections_given=dets is not None,
                          input_path=input_path, fps=fps,
                          geomap=geomap, metres_per_unit=metres_per_unit, gsd=gsd,
                          ground=ground_path is not None)
        for hint in hints:
            log.warning(hint)
        if hints:
            notes = {**notes, "hints": hints}
        skipped = sorted(getattr(source, "skipped_frames", None) or ())
        if skipped:  # unreadable images of a folder (in this process: not a --workers run's)
            notes = {**notes, "skipped_frames": skipped}
        info = {
            # absolute, so that --from, render and report find them from any folder
            "input": where(input_path),
            "detections": where(detections_path),
            "map": where(map_path),
            "roads": where(roads_path),
            **({"ground": where(ground_path)} if ground_path is not None else {}),
            "min_speed": min_speed,
            "seed": seed,
            **({"stabilised": True} if stabilised else {}),
            **({"start_time": start_time} if start_time else {}),
            "wall_time_s": round(time.perf_counter() - t0, 3),
            # every option of the command (--frames, --stride, --roi, --map-init, ...), so that
            # config.toml and this file repeat the run (they were only in stages/run.json)
            "options": {k: v for k, v in manifest.items() if k != "config"},
            # a resumed run's results may differ a little from an uninterrupted one's (not
            # exact: continued from the last checkpoint after a hard kill)
            **({"resumed": result.resumed} if getattr(result, "resumed", None) else {}),
            **({"workers": workers} if workers is not None else {}),
            **({"scheduler": scheduler} if scheduler is not None else {}),
            "environment": environment(),
            **notes,
        }
        summary = write_outputs(result, out, config=config, geomap=geomap, run_info=info,
                                out_crs=out_crs)
        if workers is not None or scheduler is not None:
            # A Dask run's stages/ holds segment results; the joined registrations and detections
            # go there as one chunk too, so that `track --from` re-associates it like any run.
            from ..io.checkpoint import save_chunk

            save_chunk(out.partial, 0, [result.registrations[k] for k in sorted(result.registrations)],
                       list(result.detections), result.thresholds)
            if result.overlay_mask is not None:  # for --from, as a single process keeps it
                from ..detection.overlay import OVERLAY_FILE, write_mask

                write_mask(out.partial / OVERLAY_FILE, result.overlay_mask)
        out.finish(keep_as="stages")
    c = summary["counts"]
    warn_blank_frames(summary, input_path)
    if not quiet:
        cut = (f" (interrupted: frames {result.first_frame}-{result.last_frame})"
               if "interrupted_at_frame" in notes else "")
        import shlex

        def n(k, what):
            return f"{k} {what}{'s' * (k != 1)}"

        # (the command is quoted: a path with spaces pasted into a shell failed)
        click.echo(
            f"aerotrack: {n(result.frames, 'frame')}{cut}, {n(c['detections'], 'detection')}, "
            f"{n(c['tracks'], 'track')} "
            f"-> {out.path}/tracks.csv ({summary['frames_per_second']} frames/s); to look at "
            f"them: aerotrack report {shlex.quote(str(out.path))}", err=True)


#: Share of a run's frames that may be blank (no contrast) before the run warns.
BLANK_SHARE_WARN = 0.5


def warn_blank_frames(summary: dict, input_path) -> None:
    """Warn when most frames were blank to registration: a run of blank frames finds nothing, and
    its few INFO lines and "0 tracks" did not say why (a 16-bit video read as its top 8 bits)."""
    blank = sum(1 for f in summary.get("registration_failures") or []
                if str(f.get("reason", "")).startswith("blank frame"))
    frames = summary.get("frames") or 0
    if frames and blank > BLANK_SHARE_WARN * frames:
        log.warning("%s: %d of %d frames are blank (almost no contrast), so little or nothing can "
                    "be found there; is the input dark, over-exposed, or of more than 8 bits per "
                    "pixel (a video is read at 8 bits; give 16-bit frames as a folder of PNG or "
                    "TIFF images)?", input_path, blank, frames)


def _finish_interrupted(pipe, stopper: GracefulStop, stream: bool = False):
    """``--on-interrupt finish``: end an interrupted run as if its video ended at the last frame
    read (the detector's last half window is decided with the frames it has, as at the end of
    any video), link, and hand back the result. A further signal stops this at once, keeping
    ``.partial/`` for ``--resume`` as an interruption does by default; with a live stream, which
    cannot be resumed, further signals wait until the results are written (a second Ctrl-C
    threw the whole run away)."""
    if stream:
        log.warning("interrupt: finishing the run at frame %d; the results follow in a few "
                    "seconds (a stream cannot be read again, so further Ctrl-C wait for them)",
                    pipe.last_frame)
        stopper.phase = "writing"
    else:
        log.warning("interrupt: finishing the run at frame %d (Ctrl-C again to stop at once and "
                    "keep .partial/ for --resume)", pipe.last_frame)
    stopper.note = GracefulStop.NOTE
    return pipe.finish()


def environment() -> dict[str, str]:
    """The versions results depend on (an OpenCV or NumPy update moved one generated scene's
    HOTA 0.629 -> 0.687), for ``summary.json``."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    from .. import __version__

    out = {"aerotrack": __version__, "python": platform.python_version()}
    for name, dist in (("numpy", "numpy"), ("scipy", "scipy"), ("opencv", "opencv-python-headless"),
                       ("numba", "numba")):
        try:
            out[name] = version(dist)
        except PackageNotFoundError:
            if name == "opencv":
                import cv2

                out[name] = cv2.__version__
    return out


MANIFEST = "run.json"
#: Manifest entries written only when they differ from these values (so that the run.json of
#: runs made before the option existed still match).
_MANIFEST_DEFAULTS = {"stabilised": False, "on_dask": False}


def finished_run(out_dir, input_path, detections_path, seed, manifest: dict | None = None
                 ) -> bool:
    """``--resume`` on a folder whose run finished (``summary.json``, no ``.partial/``): True when
    it was made from the same INPUT, --detections and --seed (there is nothing to continue);
    refused when from others (resuming cannot change what a finished run used)."""
    import json

    from ..errors import InputError
    from ..io.output import PARTIAL

    out = Path(out_dir)
    summary = out / "summary.json"
    if not summary.is_file() or (out / PARTIAL).exists() or not (out / "tracks.csv").is_file():
        return False
    try:
        before = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(before, dict):
        return False
    now = {"input": input_path, "detections": detections_path, "seed": seed}
    changed = [k for k, v in now.items() if k in before and (
        before[k] != v if k == "seed" else
        (before[k] is None) != (v is None) or (v is not None
                                               and Path(before[k]).resolve() != Path(v).resolve()))]
    if changed:
        names = ", ".join("INPUT" if k == "input" else f"--{k}" for k in changed)
        raise InputError(f"--resume {out}: holds a finished run made with another {names}; "
                         "use --overwrite to run again")
    # everything else it was started with (its .partial/run.json, kept in stages/)
    started = _read_manifest(out / "stages" / MANIFEST) if manifest is not None else None
    if started is not None:
        names = _changed_options(started, manifest)
        if names:
            raise InputError(f"--resume {out}: holds a finished run made with another "
                             f"{names}; use --overwrite to run again")
    return True


def _read_manifest(path: Path) -> dict | None:
    """A run's manifest (``run.json``), or None when missing or unreadable."""
    import json

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _changed_options(before: dict, manifest: dict) -> str:
    """The options (as the user names them) whose values differ between two run manifests."""
    import json

    now = json.loads(json.dumps(manifest))  # tuples -> lists, as read back
    for key, default in _MANIFEST_DEFAULTS.items():  # written only when not the default
        before, now = {key: default, **before}, {key: default, **now}
    changed = [k for k in now if k in before and before[k] != now[k]]
    label = {"input": "INPUT", "config": "config (--config, --set or defaults)",
             "on_dask": "--workers/--scheduler (one process against Dask segments)"}
    names = [label.get(k, "--" + k.replace("_", "-")) for k in changed if k != "input_files"]
    if "input_files" in changed and not names:  # the same paths, other contents
        files = [Path(f).name for f in {*before["input_files"], *now["input_files"]}
                 if before["input_files"].get(f) != now["input_files"].get(f)]
        names.append("version of " + ", ".join(sorted(files)[:3])
                     + (" and more" if len(files) > 3 else "")
                     + " (size or modification time)")
    return ", ".join(names)


def resume_manifest(partial: Path, manifest: dict, resume: bool) -> None:
    """Record what a run was started with in ``.partial/run.json``; on ``--resume`` refuse to
    continue checkpoints made from other inputs, settings or seed (they would be mixed silently).

    ``manifest`` holds JSON values only (resolved paths, numbers, the config as TOML text).
    """
    import json

    from ..errors import InputError
    from ..io.output import atomic_write_text

    path = Path(partial) / MANIFEST
    if resume and path.is_file():
        before = _read_manifest(path)
        if before is not None:
            names = _changed_options(before, manifest)
            if names:
                raise InputError(f"--resume {path.parent.parent}: the interrupted run was started "
                                 f"with another {names}; give the same inputs and options, or "
                                 "use --overwrite to start again")
            return
    if resume and any(p.name != MANIFEST for p in Path(partial).glob("*")):
        # checkpoints whose inputs cannot be checked would be mixed with these silently (a
        # seed-0 state continued with --seed 7 wrote tracks matching neither run)
        if path.is_file():
            raise InputError(f"--resume {path.parent.parent}: {path} (what the interrupted run "
                             "was started with) is unreadable, so its checkpoints cannot be "
                             "checked against these inputs; use --overwrite to start again")
        log.warning("--resume %s: no %s (checkpoints written through the Python API, or it was "
                    "deleted): the inputs and options cannot be checked against the interrupted "
                    "run's; give the same ones", path.parent.parent, MANIFEST)
    atomic_write_text(path, json.dumps(manifest, indent=1) + "\n")


def warn_if_never_refined(result, geomap, config, placed_by: str | None) -> None:
    """With a map, a run none of whose frames was refined against it (mutual information never
    found the map under the frame) keeps whatever placement ``--map-init`` or ``--telemetry``
    gave: a heading in radians or an altitude in feet put every position tens to hundreds of
    metres off with every frame ``ok``. Say so."""
    if geomap is None or not result.registrations or not config.registration.refine_every_s > 0:
        return
    if any(r.status == "refined" for r in result.registrations.values()):
        return
    hint = (" (telemetry: heading in degrees clockwise from north, altitude in metres above "
            "the ground, hfov in degrees)" if placed_by and placed_by.startswith("--telemetry")
            else "")
    log.warning("no frame could be matched to the map: positions rest on %s alone and may be "
                "off by as much as it is%s", placed_by or "the initial placement", hint)


def parse_start_time(text: str | None, geomap=None) -> str | None:
    """``--start-time``: ISO 8601 with a UTC offset, as normalised ISO text (UTC), or None.
    A time without an offset is refused (local time or UTC? a drone's clock is often local)."""
    if text is None:
        return None
    import datetime

    from ..errors import InputError

    try:
        t = datetime.datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(f"--start-time {text}: not an ISO 8601 time (e.g. "
                         "2024-05-01T10:30:00Z or 2024-05-01T12:30:00+02:00)") from None
    if t.tzinfo is None or t.utcoffset() is None:
        raise InputError(f"--start-time {text}: give its UTC offset (Z for UTC, or +02:00): a "
                         "time without one could be local time or UTC")
    if geomap is None:
        log.warning("--start-time %s: without --map there are no geo outputs to date; kept in "
                    "summary.json", text)
    return t.astimezone(datetime.UTC).isoformat(timespec="milliseconds")


def check_out_crs(out_crs: str | None, geomap=None) -> None:
    """``--out-crs``: a projected CRS pyproj knows; a warning when the map lies outside the area
    the CRS is defined for (UTM 33N for Las Vegas: x of -4 000 km, distances distorted)."""
    if out_crs is None:
        return
    from ..io.geotable import projected_crs

    crs = projected_crs(out_crs)  # a bad one is refused first, with or without a map
    if geomap is None:  # said: it was ignored silently
        log.warning("--out-crs %s: without --map there is no observations.csv; ignored", out_crs)
        return
    import numpy as np

    lon, lat = geomap.pixel_to_lonlat(np.array([[geomap.width / 2, geomap.height / 2]]))[0]
    area = crs.area_of_use
    margin = 1.0  # degrees: a map just across a zone border is fine
    if area is not None and not (area.west - margin <= lon <= area.east + margin
                                 and area.south - margin <= lat <= area.north + margin):
        # (area.name is a paragraph of places: "Between 114°W and 108°W, ... Canada - Alberta; ...")
        log.warning("--out-crs %s: its area of use is lon %.0f..%.0f, lat %.0f..%.0f, but the "
                    "map is at lon %.3f, lat %.3f: its coordinates there are distorted", out_crs,
                    area.west, area.east, area.south, area.north, lon, lat)
        return
    try:
        from pyproj import Proj

        f = Proj(crs).get_factors(float(lon), float(lat))
        scale = max(f.meridional_scale, f.parallel_scale, key=lambda k: abs(k - 1.0))
    except Exception:  # noqa: BLE001 - a CRS pyproj cannot give factors for: nothing to say
        return
    if np.isfinite(scale) and abs(scale - 1.0) > 0.02:
        # Web Mercator at 36 degrees north: 1.24 (accepted without a word)
        log.warning("--out-crs %s: distances between its x, y are %.2fx the ground's at the map "
                    "(lat %.1f); speed_mps and length_m are measured on the ground all the same "
                    "(the default, the local UTM zone, is within 0.1%%)", out_crs, scale, lat)


def load_roads(roads_path, geomap, config):
    """``--roads``: the road network on the map (world = map pixels), or None."""
    if roads_path is None:
        return None
    from ..context.roads import read_roads
    from ..errors import InputError

    if geomap is None:
        raise InputError(f"--roads {roads_path}: needs --map (the roads are placed on the map)")
    return read_roads(roads_path, geomap=geomap, snap_m=config.context.roads_snap_m)


#: Detection settings ``track --from`` still applies (to the cached detections).
FROM_APPLIED = {("detection", "min_conf")}


def _stage_settings(from_dir: Path, config):
    """``config`` with the --from run's registration and detection settings, which made the
    cached stages (``detection.min_conf`` applies again, at least the earlier run's): what this
    run's ``config.toml`` records. The settings given (not at their defaults) that differ from
    them are named in a warning, since they change nothing (a ``--set detection.window_s=2``
    was accepted, gave the same tracks, and was written into ``config.toml`` as if used)."""
    import dataclasses

    from ..config import Config, load_config
    from ..errors import ConfigError

    path = Path(from_dir) / "config.toml"
    if not path.is_file():
        return config
    try:
        before = load_config(path)
    except (ConfigError, OSError, ValueError):
        return config
    names = []
    for section in ("registration", "detection"):
        a, b = getattr(before, section), getattr(config, section)
        d = getattr(Config(), section)  # settings left at their defaults were not asked for
        names += [f"{section}.{f.name}" for f in dataclasses.fields(a)
                  if (section, f.name) not in FROM_APPLIED
                  and getattr(a, f.name) != getattr(b, f.name) != getattr(d, f.name)]
    if names:
        log.warning("--from %s: %s differ%s from that run's, but its cached registrations and "
                    "detections are used as they are: %s change%s nothing here (track the input "
                    "again for them)", from_dir, ", ".join(names[:4])
                    + (f" and {len(names) - 4} more" if len(names) > 4 else ""),
                    "s" if len(names) == 1 else "", "it" if len(names) == 1 else "they",
                    "s" if len(names) == 1 else "")
    min_conf = max(before.detection.min_conf, config.detection.min_conf)
    return dataclasses.replace(config, registration=before.registration,
                               detection=dataclasses.replace(before.detection, min_conf=min_conf))


def _track_from_cache(ctx, from_dir: Path, out_dir: Path, config, map_path, seed, gsd, fps,
                      min_speed, out_crs, overwrite, roads_path=None, start_time=None) -> None:
    """``track --from DIR``: association and linking on DIR/stages."""
    import json

    import numpy as np

    from ..errors import InputError
    from ..geo import GeoMap
    from ..io.output import OutputDir
    from ..outputs import write_outputs
    from ..pipeline import check_config, run_cached

    check_positive(fps, "--fps")
    check_positive(gsd, "--gsd", "a positive number of metres per pixel")
    stages = Path(from_dir) / "stages"
    summary_path = Path(from_dir) / "summary.json"
    if not stages.is_dir() or not summary_path.is_file():
        raise InputError(f"--from {from_dir}: no cached stages (stages/ and summary.json) there; "
                         "run `aerotrack track` into that folder first")
    try:
        prev = json.loads(summary_path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"--from {from_dir}: unreadable summary.json ({exc})") from None
    map_path = map_path or prev.get("map")
    geomap = GeoMap(map_path) if map_path else None
    if gsd is not None and geomap is not None:
        log.warning("--gsd %g: not used: the run of --from %s is on a map (the map gives the "
                    "scale)", gsd, from_dir)
    if gsd is not None and prev.get("ground"):
        raise InputError(f"--gsd {gsd}: the run of --from {from_dir} is on the ground plane of "
                         f"--ground {prev['ground']} (its metres); --gsd cannot be given with it")
    fps = fps or prev.get("fps") or 30.0
    mpu = None if geomap else (gsd or prev.get("metres_per_unit"))
    if roads_path is None and prev.get("roads"):  # the earlier run's roads, as its other inputs
        if Path(prev["roads"]).is_file():
            roads_path = prev["roads"]
        else:
            log.warning("--from %s: its roads %s are gone; predictions without roads (give "
                        "--roads)", from_dir, prev["roads"])
    roads = load_roads(roads_path, geomap, config)
    if min_speed is None:
        min_speed = prev.get("min_speed")
    check_out_crs(out_crs, geomap)
    # the earlier run's start time unless another is given
    start_time = parse_start_time(start_time, geomap) or prev.get("start_time")
    check_config(config, fps)  # before --out is touched
    config = _stage_settings(from_dir, config)
    same = Path(out_dir).resolve() == Path(from_dir).resolve()
    if same and not overwrite:
        raise InputError(f"--out {out_dir}: is the --from folder; its results are replaced only "
                         "with --overwrite (its stages/ are kept)")
    # a damaged stage is found once the folder is made: leave none behind (never the --from one)
    cleanup = CleanupOnBadInput(out_dir, resume=same)
    out = OutputDir(out_dir, overwrite=overwrite and not same, resume=same, stage=True)
    t0 = time.perf_counter()
    with cleanup:
        still = prev.get("still_placement")
        result = run_cached(stages, config=config, fps=fps, geomap=geomap, seed=seed,
                            metres_per_unit=mpu, frame_size=tuple(prev["frame_size"])
                            if prev.get("frame_size") else None, min_speed_mps=min_speed,
                            roads=roads, still_H=np.asarray(still, dtype=np.float64).reshape(3, 3)
                            if still and geomap is not None else None)
    info = {"input": prev.get("input"), "detections": prev.get("detections"),
            "map": str(Path(map_path).resolve()) if map_path else None, "seed": seed,
            "from": str(from_dir), "min_speed": min_speed,
            "roads": str(Path(roads_path).resolve()) if roads_path else None,
            **({"stabilised": True} if prev.get("stabilised") else {}),  # the cached stages'
            **({"ground": prev["ground"]} if prev.get("ground") else {}),  # (its metres)
            **({"start_time": start_time} if start_time else {}),
            "wall_time_s": round(time.perf_counter() - t0, 3), "environment": environment()}
    # "N detections but no track" (a --set that gated everything away said nothing here)
    hints = [h for h in clip_hints(result, config, builtin_detector=False) if h]
    if not prev.get("detections") and (noise := noise_hint(result, config)):
        hints.append(noise)  # (the cached run's thresholds: its detector judged the frames)
    for hint in hints:
        log.warning(hint)
    if hints:
        info["hints"] = hints
    summary = write_outputs(result, out, config=config, geomap=geomap, run_info=info,
                            out_crs=out_crs)
    if not same:
        import shutil

        shutil.copytree(stages, out.file("stages"), dirs_exist_ok=True)
    out.finish()
    quiet, _ = root_flags(ctx)
    if not quiet:
        click.echo(f"aerotrack: association and linking on cached stages of {from_dir}: "
                   f"{summary['counts']['tracks']} tracks -> {out.path}/tracks.csv", err=True)

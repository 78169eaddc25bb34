"""``aerotrack detect``: moving-vehicle detections of a video, without a trained detector."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import click

from .common import (
    CleanupOnBadInput,
    InputParam,
    Interrupted,
    PathArg,
    check_overwrite,
    config_option,
    fps_option,
    frames_option,
    ground_option,
    ignore_option,
    intrinsics_option,
    make_progress,
    map_init_option,
    roi_option,
    root_flags,
    set_option,
    stride_option,
    telemetry_default_option,
    telemetry_option,
)

log = logging.getLogger("aerotrack")


@click.command("detect")
@click.argument("input_path", metavar="INPUT", type=InputParam(path_type=Path))
@click.option("--out", "out_dir", required=True, type=PathArg(path_type=Path),
              help="Output folder (new, or empty; see --overwrite).")
@click.option("--map", "map_path", type=PathArg(path_type=Path), default=None,
              help="Georeferenced raster (GeoTIFF) of the area: size gates in metres, as in "
                   "`track`.")
@map_init_option
@telemetry_option
@telemetry_default_option
@click.option("--gsd", type=float, default=None,
              help="Metres per frame pixel when no map is given: the size gates become metric.")
@ground_option
@fps_option
@config_option
@set_option
@intrinsics_option
@roi_option
@ignore_option
@frames_option
@stride_option
@click.option("--stabilised", is_flag=True,
              help="Frames are already registered to each other (a stabilised video): skip "
                   "registration and use identity homographies (not with --map).")
@click.option("--debug-video", is_flag=True,
              help="Also write debug.mp4: each frame with its boxes beside the residual image.")
@click.option("--overwrite", is_flag=True, help="Replace results already in --out.")
@click.pass_context
def detect_command(ctx, input_path, out_dir, map_path, map_init_path, telemetry_path,
                   telemetry_defaults, gsd, fps,
                   config_path, overrides, intrinsics_path, roi_paths, ignore_paths, frame_range,
                   stride, stabilised, debug_video, overwrite, ground_path=None):
    """Detect moving vehicles (Yu & Medioni section 3) and write DIR/detections.csv.

    Frames are registered to each other (and to --map), a sliding-window background is built on
    the registered frames and moving blobs become boxes: the same stages, with the same options,
    as in `aerotrack track`, whose detections.csv this equals (--debug-video is detect's own).
    detections.csv has MOTChallenge
    rows ``frame,-1,x,y,w,h,conf,-1,-1,-1`` (1-based frames, frame pixels); registration.csv,
    config.toml and summary.json (as track's, without track counts) go beside it.

    \b
    Examples:
      aerotrack detect clip.mp4 --out det/ --debug-video
      aerotrack detect frames/ --out det/ --fps 10 --set detection.window_s=2
      aerotrack detect clip.mp4 --out det/ --map ortho.tif --map-init h.txt --frames 1:900
    """
    from ..config import load_config
    from ..errors import InputError
    from ..io.output import OutputDir
    from ..pipeline import check_config
    from .track_cmd import (
        check_frame_range,
        check_ground,
        check_stream_options,
        load_inputs,
        load_regions,
        parse_frame_range,
        where,
    )

    config = load_config(config_path, overrides)
    check_stream_options(input_path, frame_range, telemetry_path)
    if stabilised and map_path is not None:
        raise InputError("--stabilised: not with --map (frames are registered to the map)")
    check_ground(ground_path, input_path, {"--map": map_path, "--gsd": gsd,
                                           "--stabilised": stabilised})
    start, stop = parse_frame_range(frame_range)
    source, _, geomap, H_init, undistort, _ = load_inputs(
        input_path, None, map_path, map_init_path, fps, gsd, telemetry_path, intrinsics_path,
        start=start, config=config, telemetry_defaults=telemetry_defaults,
        ground_path=ground_path)
    check_frame_range(frame_range, start, source.count, stop)
    regions = load_regions(roi_paths, ignore_paths, geomap, source.size)
    check_config(config, fps)  # before --out is touched
    check_overwrite(out_dir, overwrite)
    from ..io.output import check_outside

    check_outside(out_dir, "--out", [
        ("INPUT", input_path), ("--map", map_path), ("--map-init", map_init_path),
        ("--telemetry", telemetry_path), ("--intrinsics", intrinsics_path),
        ("--ground", ground_path), *(("--roi", r) for r in roi_paths),
        *(("--ignore-region", r) for r in ignore_paths)])
    cleanup = CleanupOnBadInput(out_dir, always=True)  # before the folder is made; no --resume
    out = OutputDir(out_dir, overwrite=overwrite, stage=True)
    with cleanup:
        info = {"command": "detect", "input": where(input_path), "map": where(map_path),
                **({"ground": where(ground_path)} if ground_path is not None else {}),
                **({"stabilised": True} if stabilised else {}),
                # every option of the command, as `track` records them, so that summary.json and
                # config.toml repeat the run
                "options": {
                    "map_init": where(map_init_path), "telemetry": where(telemetry_path),
                    "telemetry_defaults": sorted(telemetry_defaults),
                    "intrinsics": where(intrinsics_path), "roi": [where(r) for r in roi_paths],
                    "ignore_region": [where(r) for r in ignore_paths], "fps": fps, "gsd": gsd,
                    "frames": [start, stop], "stride": stride,
                    **({"debug_video": True} if debug_video else {})}}
        _detect(ctx, source, out, config, info, geomap=geomap, H_init=H_init,
                gsd=1.0 if ground_path is not None else None if geomap else gsd,
                undistort=undistort, regions=regions,
                start=start, stop=stop, stride=stride, stabilised=stabilised,
                debug_video=debug_video,
                placed_by=(f"--telemetry {telemetry_path}" if telemetry_path is not None
                           else f"--map-init {map_init_path}" if map_init_path else None))


def _detect(ctx, source, out, config, info: dict, *, geomap, H_init, gsd, undistort, regions, start, stop,
            stride, stabilised: bool, debug_video: bool, placed_by: str | None = None) -> None:
    from ..config import dumps_config
    from ..detection.moving import oblique_hint
    from ..io.mot import write_mot
    from ..outputs import detection_rows, registration_rows, run_summary
    from ..pipeline import detect
    from ..registration import write_registration_csv
    from .hints import clip_hints
    from .track_cmd import GracefulStop, environment

    writer = None
    debug_tmp = out.partial / "debug.mp4"

    def debug(item) -> None:
        nonlocal writer
        # a --stride N video plays at the speed of the input
        writer = _write_debug(writer, debug_tmp, source.fps / stride, *item)

    t0 = time.perf_counter()
    total = source.count
    if total:
        total = len(range(start, min(stop or total, total) + 1, stride))
    progress, close = make_progress(total, "detect", *root_flags(ctx))
    stopper = GracefulStop(note="")
    interrupted = None
    with stopper:
        try:
            result = detect(source, config=config, geomap=geomap, H_init=H_init,
                            metres_per_unit=gsd, start=start, stop=stop, stride=stride,
                            undistort=undistort, regions=regions, stabilised=stabilised,
                            H_init_frame=start,  # carried to frame start (load_inputs)
                            progress=stopper.wrap(progress),
                            debug=debug if debug_video else None)
        except Interrupted as exc:  # keep what is final: the frames the detector finished
            if getattr(exc, "partial_result", None) is None:
                raise
            interrupted, result = exc, exc.partial_result
        finally:
            close()
        if interrupted is None and not result.frames:
            from ..errors import InputError
            from .track_cmd import no_frames_read

            raise InputError(no_frames_read(getattr(source, "path", "INPUT"),
                                            f"{start}:{stop}" if stop else None, source.count))
        stopper.writing(partial=interrupted is not None)
        if interrupted is None:
            from .track_cmd import warn_if_never_refined

            warn_if_never_refined(result, geomap, config, placed_by)
        rows = detection_rows(result)
        write_mot(out.file("detections.csv"), rows)
        # identity rows with --stabilised, as `track --stabilised` writes them
        write_registration_csv(out.file("registration.csv"), registration_rows(result))
        out.write_text("config.toml", dumps_config(config))
        hints = clip_hints(result, config, tracked=False)
        if geomap is None and "ground" not in info:  # (with either, the detector models it)
            hints.append(oblique_hint(result.detections, gsd))
        hints = [h for h in hints if h]
        for hint in hints:
            log.warning(hint)
        notes = {"interrupted_at_frame": result.last_frame} if interrupted is not None else {}
        info = {**info, "wall_time_s": round(time.perf_counter() - t0, 3),
                "environment": environment(), **notes, **({"hints": hints} if hints else {})}
        summary = run_summary(result, geomap, info)
        if interrupted is not None:
            # the frames detections.csv holds: frames read after the last final one have no
            # detections yet (summary.json said frames 1-91 with detections to 46: an ops probe)
            done = max((d.frame for d in result.detections), default=None)
            summary["frames_read"] = summary.get("frames")
            summary["last_frame"] = done if done is not None else summary.get("first_frame", 1) - 1
            summary["frames"] = sum(1 for d in result.detections)
        out.write_text("summary.json", json.dumps(summary, indent=2) + "\n")
        if writer is not None:
            writer.release()
            debug_tmp.replace(out.file("debug.mp4"))
        out.finish()
    if interrupted is not None:
        done = max((d.frame for d in result.detections), default=None)
        kept = f"frames up to {done}" if done is not None else "no frame finished"
        why = "" if config.detection.causal or done == result.last_frame else \
            ": the last half background window was not final yet"
        raise Interrupted(interrupted.signum,
                          f"; {out.path}/detections.csv holds the finished frames ({kept}{why})")
    dt = time.perf_counter() - t0
    log.info("detect: %d frame%s, %d detections, %.1f frames/s -> %s", result.frames,
             "s" * (result.frames != 1), len(rows),
             result.frames / max(dt, 1e-9), out.path)


def _write_debug(writer, path: Path, fps: float, index, image, residual, boxes, stationary):
    import cv2
    import numpy as np

    vis = image.copy()
    for (x, y, w, h), st in zip(boxes, stationary):
        colour = (255, 0, 255) if st else (0, 0, 255)
        cv2.rectangle(vis, (int(x), int(y)), (int(x + w), int(y + h)), colour, 2)
    cv2.putText(vis, str(index), (10, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (0, 255, 255), 2)
    res = cv2.resize(residual, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_NEAREST)
    res = cv2.applyColorMap(np.clip(res.astype(np.int32) * 4, 0, 255).astype(np.uint8),
                            cv2.COLORMAP_INFERNO)
    pair = np.hstack([vis, res])
    scale = min(1.0, 1920.0 / pair.shape[1])
    if scale < 1:
        pair = cv2.resize(pair, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    if writer is None:
        writer = _DebugVideo(path, (pair.shape[1], pair.shape[0]), fps)
    writer.write(pair)
    return writer


class _DebugVideo:
    """``debug.mp4`` in H.264 (browsers play it; OpenCV's own MP4 writer makes MPEG-4 part 2,
    which they do not), through the overlay's encoder; ``release()`` finishes the file."""

    def __init__(self, path: Path, size: tuple[int, int], fps: float) -> None:
        from ..viz.video import VideoEncoder

        self._enc = VideoEncoder(path, size, fps).__enter__()

    def write(self, image) -> None:
        self._enc.write(image)

    def release(self) -> None:
        self._enc.__exit__(None, None, None)

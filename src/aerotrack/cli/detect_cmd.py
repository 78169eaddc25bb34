"""``aerotrack detect``: moving-vehicle detections of a video, without a trained detector."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import click

from .common import (
    CleanupOnBadInput,
    check_overwrite,
    config_option,
    fps_option,
    make_progress,
    root_flags,
    set_option,
)

log = logging.getLogger("aerotrack")


@click.command("detect")
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Output folder (new, or empty; see --overwrite).")
@fps_option
@config_option
@set_option
@click.option("--stabilised", is_flag=True,
              help="Frames are already registered to each other (a stabilised video): skip "
                   "registration and use identity homographies.")
@click.option("--debug-video", is_flag=True,
              help="Also write debug.mp4: each frame with its boxes beside the residual image.")
@click.option("--overwrite", is_flag=True, help="Replace results already in --out.")
@click.pass_context
def detect_command(ctx, input_path, out_dir, fps, config_path, overrides, stabilised, debug_video,
                   overwrite):
    """Detect moving vehicles (Yu & Medioni section 3) and write DIR/detections.csv.

    Frames are registered to each other, a sliding-window background is built on the registered
    frames and moving blobs become boxes. detections.csv has MOTChallenge rows
    ``frame,-1,x,y,w,h,conf,-1,-1,-1`` (1-based frames, frame pixels); config.toml beside it
    repeats the run.

    \b
    Examples:
      aerotrack detect clip.mp4 --out det/ --debug-video
      aerotrack detect frames/ --out det/ --fps 10 --set detection.window_s=2
    """
    from ..config import load_config
    from ..io import open_source
    from ..io.output import OutputDir

    config = load_config(config_path, overrides)
    source = open_source(input_path, fps)
    check_overwrite(out_dir, overwrite)
    cleanup = CleanupOnBadInput(out_dir, always=True)  # before the folder is made; no --resume
    out = OutputDir(out_dir, overwrite=overwrite)
    with cleanup:
        _detect(ctx, source, out, config, stabilised, debug_video)


def _detect(ctx, source, out, config, stabilised: bool, debug_video: bool) -> None:
    import numpy as np

    from ..config import dumps_config
    from ..detection import MovingObjectDetector
    from ..io.mot import write_mot
    from ..types import Registration

    detector = MovingObjectDetector(config.detection, source.fps)
    detector.keep_debug = debug_video
    registrar = None
    if not stabilised:
        from ..registration import FrameRegistrar

        registrar = FrameRegistrar(config.registration, source.fps)
    writer = None
    debug_tmp = out.partial / "debug.mp4"
    rows: list[list[float]] = []
    t0 = time.perf_counter()
    n = 0

    def consume(final) -> None:
        nonlocal writer
        for d in final:
            for (x, y, w, h), c in zip(d.boxes, d.conf):
                rows.append([d.frame, -1, x, y, w, h, c, -1, -1, -1])
        if debug_video:
            for item in detector.debug_frames:
                writer = _write_debug(writer, debug_tmp, source.fps, *item)
            detector.debug_frames.clear()

    progress, close = make_progress(source.count, "detect", *root_flags(ctx))
    try:
        for frame in source:
            reg = (registrar.step(frame) if registrar is not None
                   else Registration(frame.index, np.eye(3)))
            consume(detector.step(frame, reg))
            n += 1
            progress(n)
    finally:
        close()
    consume(detector.flush())
    write_mot(out.file("detections.csv"), np.asarray(rows, np.float64).reshape(-1, 10))
    out.write_text("config.toml", dumps_config(config))
    if writer is not None:
        writer.release()
        debug_tmp.replace(out.file("debug.mp4"))
    out.finish()
    dt = time.perf_counter() - t0
    log.info("detect: %d frames, %d detections, %.1f frames/s -> %s", n, len(rows),
             n / max(dt, 1e-9), out.path)


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
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                 (pair.shape[1], pair.shape[0]))
    writer.write(pair)
    return writer

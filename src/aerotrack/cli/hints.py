"""What a run says about its clip: warnings for the log and ``summary.json`` ``hints``, from
the run's result (``track`` and ``detect``)."""

from __future__ import annotations


def clip_hints(result, config, *, builtin_detector: bool = True,
               tracked: bool = True, image_folder: bool = False) -> list[str]:
    """Warnings about the clip itself, each a line for the log and ``summary.json`` ``hints``:
    a clip shorter than the shortest track kept (``association.min_length_s``: 10 frames at 30 fps
    gave 0 tracks and no word), one shorter than the background window (a wrong frame-rate tag:
    Santiago tagged 59.94 fps lost 0.22 HOTA), and frames that repeat the one before (a recorder
    that dropped frames: 6 repeated frames cost 0.04 HOTA and 4 ID switches). ``tracked`` False
    (``aerotrack detect``): no hint about tracks. ``image_folder``: the frames came from image
    files, read at 30 frames/s unless told."""
    hints = []
    fps = float(result.fps or 30.0)
    # the clip's length, not the frames processed (--stride k processes every k-th)
    seconds = (result.last_frame - result.first_frame + 1) / fps if result.frames else 0.0
    shortest = max(config.association.min_length_s, config.linking.min_edge_track_s)
    if tracked and result.frames and not result.tracks and seconds < 2 * shortest:
        # (the hint named association.min_length_s alone; setting it changed nothing, as the
        # linking gates drop such tracks too: a probe)
        hints.append(
            f"the clip is {round(seconds * fps)} frame{'s' * (round(seconds * fps) != 1)} "
            f"({seconds:.2f} s at {fps:g} frames/s), and tracks shorter than "
            f"association.min_length_s ({config.association.min_length_s:g} s) and "
            f"linking.min_edge_track_s ({config.linking.min_edge_track_s:g} s, for tracks the "
            "clip's ends cut) are dropped: is --fps right?"
            + (" (an image folder is read at 30 unless told)" if image_folder else "")
            + " To track a clip this short anyway (expect more false tracks): --set "
              "association.min_length_s=0.1 --set linking.min_edge_track_s=0.1 --set "
              "linking.min_track_s=0.2")
    elif builtin_detector and result.frames and seconds < config.detection.window_s:
        hints.append(f"the clip ({round(seconds * fps)} frames, {seconds:.1f} s at {fps:g} frames/s) is "
                     f"shorter than the background window detection.window_s "
                     f"({config.detection.window_s:g} s), so the background has few samples: is "
                     f"--fps right?")
    n_dets = sum(len(d) for d in (result.detections or []))
    if tracked and result.frames and not result.tracks and n_dets >= 10 and not hints:
        hints.append(f"{n_dets} detections but no track: none was seen consistently enough to be "
                     f"one (too few frames a second, {fps:g}; detections that jump; or the "
                     f"gates, see association.gate_chi2 and birth_cost)")
    for x, y, w, h in getattr(result, "overlay_held", None) or []:
        hints.append(f"a mark stays put in the middle of the screen while the camera moves (frame "
                     f"pixels x {x}-{x + w}, y {y}-{y + h}) and was left in: a crosshair? "
                     f"--set detection.overlay_mask=all (or an --ignore-region) leaves it out. A "
                     f"vehicle the camera keeps centred looks the same: then keep it")
    gap = detection_gap_hint(result, config)
    if gap:
        hints.append(gap)
    noise = noise_hint(result, config) if builtin_detector else None
    if noise:
        hints.append(noise)
    rep = getattr(result, "repeated_frames", None) or []
    if rep:
        shown = ", ".join(str(f) for f in rep[:5]) + (", ..." if len(rep) > 5 else "")
        hints.append(f"{len(rep)} frame{'s' * (len(rep) != 1)} repeat the one before exactly "
                     f"(frame{'s' * (len(rep) != 1)} {shown}): a recorder that dropped frames? "
                     f"The tracker sees each as a stop and then a jump")
    return hints


def default_rate_folder(input_path, fps) -> bool:
    """Whether ``input_path`` is an image folder read at the default 30 frames/s: a folder, no
    ``--fps``, not a MOTChallenge sequence (whose seqinfo.ini names its rate)."""
    from pathlib import Path

    from ..errors import InputError
    from ..io.frames import mot_sequence

    if input_path is None or fps is not None or not Path(input_path).is_dir():
        return False
    try:
        return mot_sequence(input_path) is None
    except InputError:
        return False


def run_hints(result, config, *, detections_given: bool = False, input_path=None,
              fps: float | None = None, geomap=None, metres_per_unit: float | None = None, gsd: float | None = None,
              ground: bool = False) -> list[str]:
    """Every warning about a tracking run's clip and results (``track`` and each input of
    ``batch``, which wrote none: a 5-frame clip's "0 tracks" came with no word, and an oblique
    folder lost the warning ``track`` gives): :func:`clip_hints`, small vehicles and an oblique
    view (built-in detector, no map), and the scale. ``input_path`` and ``fps`` (the rate
    given, or None) tell an image folder read at the default rate."""
    import numpy as np

    from ..detection.moving import oblique_hint, small_vehicles_hint

    hints = clip_hints(result, config, builtin_detector=not detections_given,
                       image_folder=default_rate_folder(input_path, fps))
    if not detections_given and geomap is None and metres_per_unit is None:
        hints.append(small_vehicles_hint(result.tracks, result.frame_size, config.detection,
                                         result.frames))
    if not detections_given and geomap is None and not ground:
        # (with a map or a ground plane the detector models the view)
        observed = [p.box for t in result.tracks for p in t.points
                    if p.kind == "observed" and p.box is not None]
        hints.append(oblique_hint(None, gsd, boxes=np.asarray(observed, float)))
    hints.append(scale_hint(result, "--ground" if ground else
                            "--map/--map-init" if geomap is not None else
                            "--gsd" if gsd is not None else None))
    return [h for h in hints if h]


#: The noise hint: in at least NOISE_SHARE of the frames the threshold is NOISE_RATIO times
#: ``detection.min_threshold`` or more.
NOISE_RATIO = 1.5
NOISE_SHARE = 0.5


def threshold_summary(thresholds: dict, floor: float) -> dict | None:
    """The median residual threshold over the frames (grey levels), the floor
    (``detection.min_threshold``) and the share of frames whose noise set it at NOISE_RATIO x the
    floor or more; None without thresholds (detections given)."""
    import numpy as np

    if not thresholds:
        return None
    v = np.fromiter(thresholds.values(), float)
    return {"median": round(float(np.median(v)), 2), "floor": float(floor),
            "noise_set_share": round(float(np.mean(v >= NOISE_RATIO * floor)), 3)}


def noise_hint(result, config) -> str | None:
    """A warning when the frames' noise, not ``detection.min_threshold``, set the residual
    threshold in most frames: noisy, dark or heavily compressed footage, where low-contrast
    vehicles stay under it (a probe, 2026-12-03: Santiago darkened, threshold 21 grey levels,
    detection recall 0.89 -> 0.38, and no word from the run). Clean Santiago's median is 10.1
    (1% of frames at 1.5x the floor); UAV123 truck4's JPEG frames 17 (62%), where it fires too. A
    resumed run has its earlier frames' thresholds from the checkpoints, ``track --from`` the
    cached run's.

    Only for a still camera (:func:`camera_motion_px` under :data:`STILL_CAMERA_PX`): a moving
    camera's residual also holds the warps' interpolation, which lifts the threshold of clean
    footage as much (generated survey, hover and pan scenes: medians 17-20 grey levels, moving
    0.5-0.9 px a frame; the hint fired on every one of them, a probe 2026-12-03). Santiago and
    its degraded copies move 0.03-0.15 px a frame (a stabilised video), a still generated scene
    0.005."""
    floor = float(config.detection.min_threshold)
    s = threshold_summary(getattr(result, "thresholds", None) or {}, floor)
    if s is None or floor <= 0 or s["noise_set_share"] < NOISE_SHARE:
        return None
    motion = camera_motion_px(result)
    if motion is None or motion > STILL_CAMERA_PX:
        return None
    return (f"the frames' noise set the detection threshold at {NOISE_RATIO:g}x "
            f"detection.min_threshold ({floor:g} grey levels) or more in "
            f"{100 * s['noise_set_share']:.0f}% of frames (median over all frames "
            f"{s['median']:.0f}): noisy, dark or heavily compressed footage, where low-contrast "
            f"vehicles can stay under it (README, Noisy, dark or heavily compressed footage)")


#: The noise hint speaks only when the camera moves less than this (pixels a frame, median).
STILL_CAMERA_PX = 0.3


def camera_motion_px(result) -> float | None:
    """Median over consecutive registered frames of how far the frame's centre and corners move
    from one to the next, per frame between them (pixels, through the two registrations); None
    with fewer than two registered frames (``--detections`` alone)."""
    import itertools

    import numpy as np

    regs = result.registrations or {}
    size = getattr(result, "frame_size", None)
    if len(regs) < 2 or not size:
        return None
    W, H = size
    pts = np.array([[W / 2, 0, W, 0, W], [H / 2, 0, 0, H, H], [1, 1, 1, 1, 1]], float)
    fr = sorted(regs)
    moved = []
    for a, b in itertools.pairwise(fr):  # (every k-th frame with --stride k: per frame)
        q = np.linalg.solve(regs[a].H, regs[b].H @ pts)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.hypot(q[0] / q[2] - pts[0], q[1] / q[2] - pts[1])
        moved.append(float(np.mean(d)) / (b - a) if np.all(np.isfinite(d)) else np.inf)
    return float(np.median(moved))


#: A stretch of frames without a detection is named when it lasts this long (seconds) in a clip
#: whose other frames hold a median of at least GAP_MIN_MEDIAN detections.
GAP_MIN_S = 0.3
GAP_MIN_MEDIAN = 3


def detection_gap_hint(result, config) -> str | None:
    """A warning naming the longest stretch of frames with no detection in a clip whose other
    frames have several each, with its likely cause when it follows a registration reset (the
    background restarts there and needs frames before it finds anything): a zoom taken for a scene
    change left 11 frames without detections and no word in the log or ``summary.json`` (a probe,
    2026-12-03). Without a reset it speaks only when the 5 frames on each side have a median of
    :data:`GAP_MIN_MEDIAN` or more detections (an abrupt stop, not traffic thinning out)."""
    import numpy as np

    dets = list(result.detections or [])
    if len(dets) < 10:
        return None
    frames = np.array([d.frame for d in dets])
    counts = np.array([len(d) for d in dets])
    if not (counts > 0).any() or np.median(counts[counts > 0]) < GAP_MIN_MEDIAN:
        return None
    fps = float(result.fps or 30.0)
    best, start = (0, 0, 0), None
    for k, c in enumerate(np.append(counts, 1)):
        if c == 0 and start is None:
            start = k
        elif c != 0 and start is not None:
            # a stretch at the clip's first or last frames (the first half window, an empty
            # road at the start) is expected, and must not hide one in the middle
            if k - start > best[0] and start > 0 and k < len(counts):
                best = (k - start, start, k - 1)
            start = None
    n, a, b = best
    if n == 0 or (frames[b] - frames[a] + 1) / fps < GAP_MIN_S:
        return None
    first, last = int(frames[a]), int(frames[b])
    regs = result.registrations or {}
    window = int(round(config.detection.window_s * fps))
    resets = [i for i, r in sorted(regs.items())
              if r.status in ("reset", "reanchored") and first - window <= i <= last]
    before = [i for i in resets if i <= first]
    at = before[-1] if before else resets[0] if resets else None
    if at is None:
        # without a restart, only an abrupt stop is named: traffic that thins out to nothing
        # (a quiet road between platoons) is not a fault
        around = [counts[max(0, a - 5):a], counts[b + 1:b + 6]]
        if any(len(c) == 0 or np.median(c) < GAP_MIN_MEDIAN for c in around):
            return None
    why = (f": registration started over at frame {at} ({regs[at].reason}), and the background "
           f"with it" if at is not None else "")
    return (f"frames {first}-{last} ({last - first + 1} frames) have no detection while the others "
            f"have a median of {int(np.median(counts[counts > 0]))}{why}")


#: :func:`scale_hint` speaks when the tracked objects' median length in metres is outside this.
PLAUSIBLE_LENGTH_M = (1.5, 12.0)


def scale_hint(result, given: str | None) -> str | None:
    """A warning when the scale the user gave (``given``: the option) makes the tracked objects'
    median length implausible for vehicles: a ground plane given in orthophoto pixels made cars
    13.6 m long, one given the wrong way round 54 m, and tracking fell to HOTA 0.03 without a
    word (a probe, 2026-12-03). None without a given scale or 50 observed boxes."""
    import numpy as np

    mpu = result.metres_per_unit
    if given is None or not mpu:
        return None
    lengths = [float(np.max(np.abs(p.size_world))) * mpu for t in result.tracks for p in t.points
               if p.kind == "observed" and p.size_world is not None]
    if len(lengths) < 50:
        return None
    median = float(np.median(lengths))
    lo, hi = PLAUSIBLE_LENGTH_M
    if lo <= median <= hi:
        return None
    return (f"the tracked objects are a median {median:.1f} m long: if they are vehicles, the "
            f"scale of {given} is off (metres? the right way round?)")

"""Configuration: one frozen, documented dataclass per stage, loaded from TOML.

Every parameter can be set in a TOML file (``--config FILE``), one table per stage::

    [detection]
    window_s = 3.0

and overridden on the command line (``--set detection.window_s=2``). The resolved configuration is
written as ``config.toml`` beside every output so a run can be repeated exactly.

Time-based settings are in seconds and distances in metres (or world units where no scale is known),
never in frames: a config means the same thing at 10 and at 60 frames/s.

Each stage owns its section; add a parameter by adding a documented field to that section.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from .errors import ConfigError


@dataclass(frozen=True)
class RegistrationConfig:
    """Frame-to-frame and frame-to-map registration (Yu & Medioni section 2).

    Attributes
    ----------
    method : str
        Feature tracker for frame-to-frame motion: ``lk`` (corners tracked by pyramidal sparse
        optical flow, reused from frame to frame) or ``orb`` (ORB features matched by descriptor).
        ``lk`` is several times faster; ``orb`` copes with large jumps. Whatever the choice, a
        failed estimate is retried once with ``orb`` before it counts as a failure.
    max_features : int
        Features tracked per frame. Raising it steadies the estimate on low texture but costs time.
    scale : float
        Frames are downscaled by this factor for feature tracking (1 = full resolution). Lower is
        faster; too low loses fine texture and sub-pixel precision.
    min_track_width_px : int
        The downscaled image is never narrower than this (small frames are tracked at a larger
        scale, up to full resolution).
    polish : bool
        After the first estimate, warp the previous frame by it and re-track the inliers (sub-pixel
        residual motion, no zoom or rotation left): removes the bias optical flow has under zoom,
        which chaining turns into drift. Done on the frames that become keyframes or start a map
        refinement (the only ones chained into later frames), so it costs little.
    keyframe_s : float
        Frames are registered against a keyframe at most this old (0: against the previous frame).
        Longer keyframes chain fewer homographies (less drift) but track over larger motions and
        see more parallax and appearance change.
    keyframe_grid : bool
        Keyframes fall on a fixed time grid (each multiple of ``keyframe_s`` from the video's
        start) and start from fresh corners, so a frame's registration depends only on the frames
        since the last grid keyframe, not on the whole history: a Dask segment or a resumed run
        then registers frames as one uninterrupted process does (an early keyframe, taken when
        the overlap drops, no longer shifts every later one). False: every ``keyframe_s`` after
        the previous keyframe, features carried over and topped up. Measured (benchmarks/
        parallel.py, generated scene 0, 2 segments): a segment's frame-to-frame registrations
        differed from the single process's by 0.045 px (median; corners of a 5-frame relative
        homography), 0.032 with this, 2e-13 with this and ``mask_detections`` false, and the
        segment's frames whose detections differ went 78 -> 72 -> 23. Accuracy with both (this on,
        ``mask_detections`` off) against the defaults: Santiago HOTA/IDF1 (seeds 0-2) 0.634/0.851
        -> 0.637/0.853; truck4 best ID 0.589 either way; generated identity scenes (detector)
        IDF1 0.784 -> 0.781, 18 -> 23 ID switches, occlusions 17 -> 19 of 31, exits 4 -> 3 of 7;
        the demo scene IDF1 0.826 -> 0.787. Off by default: no accuracy gain, and without the
        mask a queue of vehicles moving together can pull the estimate.
    mask_detections : bool
        Keep features off the latest final detections (moving vehicles must not pull the
        estimate). They come from the detector, half a background window behind, so they tie a
        frame's registration to the run's history: with ``keyframe_grid``, turning this off
        makes a segment's registrations equal the single process's (see ``keyframe_grid``), at
        the risk of a queue of vehicles moving together pulling the estimate.
    keyframe_min_overlap : float
        A new keyframe is taken when fewer than this fraction of its features are still inliers.
    keyframe_blur_ratio : float
        A frame whose sharpness (mean absolute Laplacian at the tracking scale) is under this
        fraction of the median of the last 9 registered frames' is not made the keyframe when
        one falls due, until ``2 x keyframe_s`` after the last keyframe: a motion-blurred frame
        loses features, which called for a new keyframe, and as one it passed its 2 px
        registration error on to every later frame (a probe, 2026-12-03: Santiago with 3
        motion-blurred frames, error 0.3 -> 2.3 px for the rest of the clip; with this 0.3 px).
        Against the recent frames, not the keyframe: a pan blurred throughout is its own
        baseline (against the keyframe's sharpness, such a pan was refused keyframes while its
        features left the view, and a 12-16 px a frame pan failed and reset; a review). A
        keyframe due for the scale change, or with ``keyframe_grid``, is never held back. 0
        disables.
    ransac_threshold_px : float
        RANSAC inlier threshold, in full-resolution frame pixels.
    estimator : str
        Robust homography estimator: ``ransac`` or ``magsac`` (OpenCV USAC_MAGSAC).
    min_inliers : int
        Fewer inliers than this is a registration failure.
    min_inlier_ratio : float
        Inliers / tentative correspondences below this is a failure (a moving crowd or noise).
    max_scale_change : float
        Largest area ratio between a frame and the frame it is registered against; beyond it the
        homography is called degenerate. Raising it admits fast zooms but also wrong estimates.
    max_condition : float
        Largest condition number of the normalised homography's 2x2 linear part (shear/skew).
    refine_every_s : float
        Seconds between map refinements (0 disables periodic refinement).
    refine_on_inlier_ratio : float
        A frame-to-frame inlier ratio under this triggers an immediate map refinement.
    refine_search_px : float
        How far (map pixels) the mutual-information patch search looks around the rough alignment.
        Larger tolerates more drift but costs time quadratically and admits false peaks. On a map
        more than 3x finer than the frames, this and the other ``refine_*_px`` are pixels of the
        map downsampled to about the frames' ground resolution (docs/DESIGN.md, Registration).
    refine_patch_px : int
        Side of the square patches matched against the map by mutual information, map pixels.
    refine_patches : int
        Patches tried per refinement (a grid over the frame's footprint; textureless ones skipped).
    refine_bins : int
        Grey-level bins of the mutual-information joint histogram. More bins resolve finer
        structure but need bigger patches to fill the histogram.
    refine_max_correction_px : float
        A refinement that moves the frame's corners by more than this (map pixels) is rejected.
    carry_s : float
        After a failed frame the last motion is carried forward for at most this long, then the
        position is held.
    reset_after_s : float
        After this long without a successful registration against the last good frame, the current
        frame becomes the new reference (status ``reset``; with a map, a re-anchoring is tried).
    cut_frames : int
        A scene change (an edited clip's cut, a camera switch, a video link that drops and comes
        back elsewhere) is declared after this many consecutive frames that fail against the
        reference but each register against the frame before them: the view is consistent, just
        not the old one. The last of them becomes the new reference at once (status ``reset``,
        reason ``scene change``) instead of after ``reset_after_s``. 0 waits for
        ``reset_after_s`` (the old behaviour). Measured on truck4 with a cut spliced in (frames
        1-40, then 301-340 at 10 frames/s): without it frames 41-70 were carried and the new
        view was detected in nothing for 3 s; with 3, frames 41-42 are carried, 43 resets.
    min_contrast : float
        Grey-level standard deviation (0-255) under which a frame is blank.
    max_saturated : float
        Fraction of saturated pixels above which a frame is overexposed.
    min_neighbour_corr : float
        Correlation between horizontally adjacent pixels under which a frame is noise.
    """

    method: str = "lk"
    max_features: int = 400
    scale: float = 0.5
    min_track_width_px: int = 480
    polish: bool = True
    keyframe_s: float = 0.5
    keyframe_min_overlap: float = 0.6
    keyframe_blur_ratio: float = 0.5
    keyframe_grid: bool = False
    mask_detections: bool = True
    ransac_threshold_px: float = 2.0
    estimator: str = "ransac"
    min_inliers: int = 20
    min_inlier_ratio: float = 0.25
    max_scale_change: float = 1.5
    max_condition: float = 4.0
    refine_every_s: float = 1.0
    refine_on_inlier_ratio: float = 0.5
    refine_search_px: float = 12.0
    refine_patch_px: int = 48
    refine_patches: int = 48
    refine_bins: int = 16
    refine_max_correction_px: float = 40.0
    carry_s: float = 1.0
    reset_after_s: float = 3.0
    cut_frames: int = 3
    min_contrast: float = 4.0
    max_saturated: float = 0.6
    min_neighbour_corr: float = 0.3


@dataclass(frozen=True)
class DetectionConfig:
    """Moving-object detection on registered frames (Yu & Medioni section 3).

    Attributes
    ----------
    window_s : float
        Length of the sliding background window in seconds (the paper: 91 frames = 3 s at 30 fps).
        Longer absorbs fewer slow vehicles but costs memory and fails more with parallax.
        Measured 2026-11-27: 4.5 s gave the 18 held-out generated scenes HOTA/IDF1 0.685/0.836
        and 58 ID switches, against 0.700/0.858 and 37 at 3 s. Re-measured 2026-12-02, 4.5 s
        with ``sample_every_s`` 0.3 (the same 15 samples): held-out HOTA/IDF1/MOTA over MCMC
        seeds 0-2 0.715/0.860/0.826 -> 0.714/0.862/0.832, detection P/R at IoU 0.5
        0.822/0.825 -> 0.827/0.832; UAV123 truck4's truck, which takes about 2 s to cross its
        own length, detected from frame ~73 instead of ~134 (any ID covering it 0.663 -> 0.767)
        but split, its best single ID 0.663 -> 0.504; Santiago (seed 0, a clip shorter than
        the window) 0.669/0.891 -> 0.655/0.877. Hence 3 s.
    causal : bool
        False: the window is centred on the frame (detections are final half a window later, the
        paper's method). True: the window ends at the frame (delay 0, for live use); a vehicle
        that waits is absorbed twice as fast, which ``hold_stopped`` compensates.
    full_window_at_ends : bool
        With a centred window, the frames of the first (last) half window of a video or
        registration segment use the whole window shifted inside it instead of the half that
        exists: a vehicle waiting at the start then covers a share of a full window and is not
        absorbed. Costs the first frames a delay of a whole window instead of half of one.
    sample_every_s : float
        Spacing of the frames kept as background samples (the paper uses every frame). Wider is
        faster and lighter (the median network grows as n log^2 n) but a slow vehicle covers a
        larger share of fewer samples.
    update_every_s : float
        How often the window median is recomputed; in between, the last background is warped to
        the frame. Longer is faster; the background then lags the lighting by that much. On a
        moving camera each warp re-interpolates the background (bilinear blur, largest at
        half-pixel offsets), so the residual noise and the threshold climb between updates
        (generated default:0: 13.4 -> 19.5 grey levels over 5 frames) and faint vehicles are
        found mostly on update frames. Measured (2026-11-26, generated scenes, 3 x 300 frames):
        every frame (1/fps) recall 0.840 -> 0.864, precision 0.910 -> 0.905, ~7 ms more per
        640x480 frame; every 2 frames 0.854 / 0.911. Tracking did not gain (identity benchmark
        IDF1 0.814 -> 0.798 at every 2 frames, Santiago HOTA 0.650 -> 0.641 over seeds 0-2),
        so 0.2 s stays. A sharper warp in between (bicubic instead of bilinear, 2026-12-02)
        looked better on those three scenes with their true homographies (0.840 -> 0.862 /
        0.895 -> 0.903) but on the 18 held-out scenes through ``aerotrack track`` it lost
        precision (0.821 -> 0.780) and HOTA/IDF1/MOTA (0.721/0.871/0.829 -> 0.693/0.841/0.810):
        the bilinear blur is part of what the background tolerates.
    refresh_uncovered : float
        Between updates, the background is recomputed at once when the frame shows more than
        this share of its area that the last background's frame did not (new ground entering
        under a fast pan): warped, the last background has no value there, so nothing could be
        detected in the strip until the next update (a probe, 2026-12-03: a pan of 30% of the
        width a second found 0.31 of the vehicles within 50 px of the incoming edges, against
        0.84 at the edges of the same view held still). 0 disables.
    model_scale : float
        Resolution of the background model relative to the frame (boxes are refined at full
        resolution). Lower is faster but loses vehicles under about 4/model_scale pixels. With a
        map or ``--gsd`` it is used as given; without, it is the scale for a frame of
        ``pixel_gates_reference_px`` diagonal (1080p) and other sizes keep 1080p's model pixels
        per vehicle: divided by the frame's diagonal / that reference, at most 1 (720p 0.75,
        540p 1.0, 4K 0.25; ``detector.model_scale_for``). Santiago downscaled to 960x540 scored
        HOTA/IDF1 0.549/0.704 at 0.5 with the 1080p gates, 0.637/0.855 with both following the
        frame size (0.658/0.874 at 1080p); at 1280x720 0.587/0.786 -> 0.636/0.848; truck4's best
        ID covered 0.594 -> 0.667 of its frames.
    model_pixel_max_m : float
        With a map or ``--gsd``: metres a model pixel may cover at most, in the first frame's
        centre. Where ``model_scale`` would make them coarser (small vehicles: a high or zoomed-out
        flight) the model's resolution is raised to this, at most to the frame's. At 0.65 m a
        4.5 m car spans about 7 model pixels. Generated scenes (cars 0.28 m/px, 16 x 7 px, which
        ``model_scale`` 0.5 already models at 0.56 m) are unchanged; rendered zoomed out,
        tracked with their map (HOTA, seed-3 dense 1280x720 and seed-12 default 640x480 scenes,
        600 frames, model scale 0.5 / 0.6 / 0.75 / 0.875 / 1.0): at 0.56 m/px (cars 8 x 3 px)
        0.54 / 0.62 / 0.65 / 0.68 / 0.63 and 0.49 / 0.63 / 0.71 / 0.68 / 0.68; at 0.40 m/px 0.62
        / 0.70 / 0.70 / - / 0.71 and 0.66 / 0.71 / 0.75 / - / 0.73. At 0.28 m/px finer models
        did not help (0.5 / 0.6 / 0.75: 0.747 / 0.710 / 0.734 and 0.750 / 0.754 / 0.763; the
        held-out scenes lose 0.02 HOTA at 1.0). The price is detection time where it applies: at
        0.56 m/px detection took 2.0x / 1.7x as long (default 640x480 / dense 1280x720), the
        whole run 1.36x / 1.29x (two runs at a time on 2 cores). 0 keeps ``model_scale`` as
        given.
    min_valid_samples : int
        Fewer samples that saw a pixel (inside the view and not under a detection) than this and
        the pixel's background is held from before, or the pixel is not tested.
    threshold_sigma : float
        Residual threshold as a multiple of the frame's residual noise (its 0.9 quantile over the
        half-normal's, since the median of the registration-tolerant residual is 0).
        Raising it removes noise blobs but loses low-contrast vehicles.
    min_threshold : float
        Lower bound of the residual threshold, grey levels (0-255).
    seed_ratio : float
        A blob must contain a pixel above ``seed_ratio`` x threshold (hysteresis).
    seed_sigma : float
        ... and above ``seed_sigma`` x the frame's residual noise; 0 disables. With it the
        extent threshold (``threshold_sigma``) can sit nearer the noise, so that dark vehicles
        on dark asphalt are found whole, while noise seldom seeds a blob. Measured with
        threshold_sigma 5 and seed_sigma 12 (box edges at half contrast): generated scenes
        detection P/R at IoU 0.5 0.892/0.825 -> 0.888/0.856, tracking HOTA (mean of seeds 0-2)
        default:0 0.630 -> 0.608, convoy:2 0.576 -> 0.626; truck4 detected 0.54 -> 0.59 of
        frames; Santiago per-frame detection unchanged with identity registrations (its
        threshold is at ``min_threshold``) but, registered by the pipeline, its noise is higher:
        P/R 0.759/0.865 -> 0.735/0.873 and HOTA/IDF1 0.633/0.850 -> 0.617/0.816. Hence off.
        threshold_sigma 6 / seed_sigma 12, HOTA: Santiago 0.633 -> 0.612, default:0 0.630 ->
        0.614, convoy:2 0.576 -> 0.601, convoy:1 0.502 -> 0.520.
    residual_sigma_px : float
        Gaussian (full-resolution pixels) applied to the signed frame - background difference
        before thresholding: averages out per-pixel noise so low-contrast (dark on dark)
        vehicles pass a threshold that noise does not; 0 disables. Measured with the quantile
        noise threshold: 1.0 px changed Santiago P/R at IoU 0.5 from 0.673/0.835 to 0.660/0.832
        and lowered generated-scene recall (0.67 -> 0.64, 0.77 -> 0.64), hence off. On noisy
        footage 2 px helps where the noise is pixel-to-pixel (a probe, 2026-12-03, HOTA: Santiago
        darkened to 0.35x with noise sigma 6, 0.418 -> 0.491; as JPEG quality 15, 0.580 -> 0.626)
        and hurts where it is not (UAV123 truck4's best single ID 0.677 -> 0.439).
    gain_block_px : float
        Side (full-resolution pixels) of the blocks over which the frame's local gain against
        the background is estimated and divided out (illumination changes, auto-exposure).
        0 disables the normalisation.
    exposure_tolerance : float
        Each background sample whose exposure differs from the frame the background is built
        for by more than this fraction is brought to that frame's exposure before the window's
        median (:func:`aerotrack.detection.background.exposure_gain`: the median over blocks of
        the ratio of their mean grey levels). Without it a camera's auto-exposure swing ranks
        the samples by their exposure rather than by their noise, the median is one sample's
        noisy value, and the threshold, which follows the residual's noise, rises (Santiago
        with +-10% every 3 s: 11-17 grey levels instead of 10-11). Within the tolerance a
        sample is used as it is, so footage without exposure changes is not touched (truck4's
        camera varies by up to 3%: at 2%, 11% of its samples were rescaled and one missed
        stretch split its truck's track). 0 disables. Measured (``docs/DESIGN.md``,
        "Exposure changes"): Santiago with +-25% every 1.3 s HOTA/IDF1 0.579/0.749 ->
        0.623/0.822 (``benchmarks/exposure.py``); generated scenes' detection (their gain drifts +-6% over 17 s) recall
        0.845 -> 0.840 and precision 0.899 -> 0.895 at IoU 0.5, tracking within their MCMC
        noise.
    close_m, close_px : float
        Radius of the morphological closing that joins fragments of one vehicle: metres when a
        scale is known, full-resolution pixels otherwise. Without a scale it is always
        ``close_px * model_scale`` = 2 model pixels (the pixel gates and the model's resolution
        follow the frame size together); with one, 0.8 m is 1.3-1.7 model pixels at the usual
        altitude (0.25-0.3 m per frame pixel). Where it would be more than those 2 model pixels
        (model pixels finer than 0.4 m: a low flight, cars 30 px long and more) the vehicles are
        resolved, the gaps the closing should bridge are still noise a pixel or two wide, and
        0.8 m (5-6 model pixels at 0.08 m per frame pixel) closed the 0.5-1.5 m between queued
        cars: there the radius is ``close_resolved_px`` model pixels.
    close_resolved_px : float
        Closing radius, in model pixels, where ``close_m`` spans more than ``close_px *
        model_scale`` of them (see above); 0 uses ``close_px * model_scale`` there. Measured
        against the metric radius alone, with the scale given (MCMC seed 0 unless said):
        Santiago with ``--gsd 0.125`` (its cars are 36 px, 0.8 m is 3.2 model pixels), seeds
        0 / 1: HOTA 0.609 / 0.619 -> 0.657 / 0.648 at 2, 0.630 / 0.628 at 1 (detection recall
        at IoU 0.5 0.875 at 2, 0.835 at 1; without any scale the clip scores 0.665). New
        generated scenes with their map (1280x720, 450 frames): 8 at 0.3x the altitude (0.075-
        0.09 m per pixel, cars about 60 px): HOTA / IDF1 / MOTA 0.670 / 0.806 / 0.699 -> 0.674
        / 0.792 / 0.783 at 2 (one 4-vehicle scene drew two wrong links across an exit: 0.820 ->
        0.608; the other seven gained) and 0.730 / 0.864 / 0.829 at 1; 5 at 0.6x (0.15-0.18 m
        per pixel, cars about 30 px): 0.773 / 0.881 -> 0.791 / 0.893 at 2 and 0.791 / 0.903 at
        1. The generator's vehicles are flat-coloured and crisp; the real clip's fragment more,
        so 2 is the default and 1 a setting for close-up footage of plain vehicles. A 3 x 3
        closing at the usual altitude too was mixed (18 held-out scenes HOTA 0.700 -> 0.7005,
        convoy:21 0.748 -> 0.679, exits:12 0.777 -> 0.751): there the rule does not apply and
        those scenes, the demo and the identity benchmark are unchanged.
    join_gap_m, join_gap_px : float
        Boxes closer than this are merged when the union still fits ``max_length``. With a
        scale the gap is at most what it is without one in model pixels (``join_gap_px *
        model_scale``, 2.5; 1.0 m is 1.6-2.3 model pixels at the usual altitude, where this
        does not apply). Santiago with ``--gsd 0.125`` (1.0 m is 4 model pixels), MCMC seeds
        0-2: HOTA / IDF1 0.652 / 0.860 -> 0.654 / 0.876, detection precision / recall 0.791 /
        0.875 -> 0.802 / 0.884; the generated low-flight scenes of ``close_resolved_px``: 8 at
        0.3x 0.674 / 0.792 -> 0.680 / 0.801, 5 at 0.6x 0.791 / 0.893 -> 0.788 / 0.889.
    min_area_m2, min_area_px : float
        Smallest accepted blob area (metres^2 with a scale, full-resolution pixels^2 without).
    max_length_m, max_length_px : float
        Longest accepted box side; longer blobs are split, or dropped when they cannot be.
    min_width_m, min_width_px : float
        Smallest accepted blob thickness (twice its largest inscribed radius at full
        resolution): the residual of a parallax edge (an overpass or wall side, which the
        ground homography does not register) is a thin line however long. 0 disables.
    pixel_gates_reference_px : float
        The ``*_px`` gates above (used without a map or ``--gsd``) are for frames of this
        diagonal (2203 px: 1920x1080); on other frames they follow the diagonal (areas its
        square; at least a quarter, exactly as given within 1% of the reference), since the same
        flight filmed at 4K shows every vehicle twice as long in pixels as at 1080p, and at 540p
        half as long: a 4K bus is no longer over ``max_length_px``, 4K compression noise no
        longer passes ``min_area_px``, and at 540p the closing no longer joins neighbours.
        Measured on truck4's frames 150-200 upscaled to 3840x2160 (MJPEG): 44.6 detections per
        frame before, as against 3.9 at the original 1280x720. The model's resolution follows
        the same factor (``model_scale``). 0 keeps the gates and the model scale as given at
        every size.
    split_blobs : bool
        Split blobs that merge several vehicles (erosion until they fall apart).
    split_area_ratio : float
        Only blobs larger than this multiple of the frame's median blob area are split (needs 5
        blobs in the frame), and each part must reach half the median area. Lower splits more
        merged pairs but also cuts single long vehicles.
    split_full_ratio : float
        A blob whose full-resolution mask (after shadow removal, before the closing) falls into
        two or more pieces of at least this fraction of the frame's typical blob area (and
        ``min_width`` thick) is that many vehicles (``moving.separate_pieces``): cars passing
        in opposite lanes, queues and junction crossings, whose bodies are a few pixels apart
        but whose shadows and the model's coarser pixels join them; only blobs of at least
        ``split_area_ratio`` x the typical area are candidates. 0 disables. Measured at 0.4
        (2026-11-26, generated scenes with yielding traffic): detection P/R at IoU 0.5
        0.900/0.845 -> 0.905/0.886, but tracking on eighteen held-out scenes unchanged (HOTA/IDF1
        0.681/0.835 -> 0.679/0.835: local association already bridges the few frames of a
        passing), and on Santiago (seed 0) HOTA/IDF1/MOTA 0.664/0.885/0.757 -> 0.656/0.859/0.722
        (real vehicles fall into pieces at their windscreens, and separated pieces exposed a
        pedestrian and a waiting car its ground truth omits; 0.6 and 1.0 x typical no better).
        Hence off. Re-measured 2026-12-04 with two guards, ``split_full_sides`` 0.6 and
        ``split_full_shadow`` (the pieces Santiago lost precision to were mostly vehicles'
        cast shadows split off as vehicles), detection P (precision) and R (recall) at IoU 0.5
        on generated seeds 0-2 and Santiago: off 0.895/0.840 and 0.776/0.891; 0.4 alone
        0.903/0.873 and 0.754/0.894; 0.4 with both guards 0.900/0.864 and 0.7756/0.8946. But
        tracking did not gain. 18 held-out scenes, mean of MCMC seeds 0-2, HOTA/IDF1/MOTA/IDSW
        0.724/0.878/0.828/39.3 -> 0.719/0.871/0.829/38.7. UAV123 truck4's best single ID
        0.665 -> 0.437 at seeds 0-2: a per-frame split cut its truck in a few frames, and
        each cut started a new track. Still off.
    split_full_sides : float
        With ``split_full_ratio``: each separated piece must also be shaped like a whole vehicle,
        its oriented length and width (minimum-area rectangle) at least this fraction of the
        frame's typical blob's (``blobs.typical_sides``); pieces that are not (a bonnet cut off
        at the windscreen, a strip of cast shadow) go to the nearest vehicle piece instead. 0
        disables the shape test.
    split_full_shadow : bool
        With ``split_full_ratio``: a blob whose pieces are one darker than the ground and one
        lighter, the dark one no larger, is a vehicle with its own cast shadow (which the
        colour test of ``shadow_suppression`` missed), not two vehicles, and is not separated
        (``moving.cast_shadow_pieces``).
    split_colour_dist : float
        A refined blob of at least ``split_area_ratio`` x the typical area whose pixels fall into
        two colour clusters at least this far apart (CIE Lab, OpenCV's 8-bit scale), each one
        compact, car-sized piece, is two touching vehicles (``moving.split_by_colour``): a dark
        car beside a white van in the next lane, or behind it in a queue. 0 (the default)
        disables; 40 is the measured setting. Off because tracking did not gain: on the 18
        held-out generated scenes detection P/R at IoU 0.5 rose 0.8159/0.8211 -> 0.8170/0.8238,
        but HOTA/IDF1 (MCMC seed 0) went 0.700/0.858 -> 0.695/0.852 (with ``gap_accel_mps2``
        6, seeds 0-2: +0.001/+0.001), the identity benchmark's IDF1 (seeds 0-2) 0.866 ->
        0.863 and Santiago's (seeds 0-2) HOTA/IDF1 0.666/0.887 -> 0.662/0.879 (docs/DESIGN.md,
        "Colour split").
    join_parts_ratio : float
        Two blobs within twice the join gap are joined, closest first, when their union's
        oriented extent is at most this multiple of the frame's median blob length and width
        (needs 5 blobs): the bonnet and boot of a car whose roof matches the road. 0 disables.
    join_cab_ratio : float
        A blob shorter than this multiple of the median blob length within the join gap of a
        longer blob, in line with it (``blobs.join_cabs``), is an articulated vehicle's cab and
        is joined to its trailer. 0 disables. Measured against 0: Santiago detection P/R@IoU0.5
        0.759/0.865 -> 0.778/0.872 (fragments 75 -> 39), tracking over seeds 0-2 HOTA 0.643 ->
        0.650, IDF1 0.863 -> 0.871, MOTA 0.723 -> 0.728; generated scenes P/R unchanged
        (0.910/0.841); identity benchmark IDF1 0.811 -> 0.814, HOTA 0.613 -> 0.620, ID switches
        15 -> 21 (over MCMC seeds 0-2: IDF1 0.819 -> 0.818, HOTA 0.618 -> 0.620, switches 13.7 ->
        18 per run); demo HOTA 0.630 -> 0.647, IDF1 0.823 -> 0.818. 0.8 scored alike per frame.
    shadow_suppression : bool
        Remove moving cast shadows (Prati et al.'s deterministic non-model-based HSV test) from
        blobs before boxing them.
    shadow_alpha, shadow_beta : float
        A shadow darkens the background value V by a ratio in [alpha, beta].
    shadow_tau_s : float
        Largest saturation change of a shadow pixel (S in [0, 1]).
    shadow_tau_h : float
        Largest hue change of a shadow pixel, degrees.
    shadow_min_core : float
        Shadow-like pixels are removed from a blob only when at least this fraction of it is
        left (a cast shadow lies beside the vehicle that casts it); otherwise the blob is a dark
        vehicle, which passes the pixel test like a shadow, and is kept whole. 0: pixel test only.
    shadow_trim : bool
        A dark vehicle kept whole keeps its own shadow, and its box is the vehicle's grown by
        the sun's offset on the shadow's sides (generated scenes: +2 to +4 px on the right and
        bottom of vehicles of mean colour under 90, IoU with their true boxes 0.46-0.68 where
        light vehicles reach 0.86-0.93). With this on, the frame's median growth of the boxes
        of vehicles whose shadows were removed is taken off the dark vehicles' boxes
        (``shadows.trim_shadow_side``); with no shadows removed in the frame nothing changes.
        Measured with the area-exact generator on twelve held-out scenes (six scenarios x seeds
        11, 12, ``aerotrack track`` on the JPEG frames, MCMC seed 0): HOTA/IDF1 0.677/0.836 ->
        0.696/0.862; Santiago seeds 0-2 unchanged.
    shadow_trim_share : float
        A blob is a dark vehicle with its shadow when at least this share of its pixels is
        shadow-like and was kept (``shadow_min_core``).
    shadow_trim_pool_s : float
        ``shadow_trim`` measures the sun's offset in each frame and needs two lighter vehicles
        whose shadows were removed there; in frames with fewer (a quiet road, mostly dark cars:
        half the frames with a dark car on generated static:52) the dark car's box kept its
        shadow and doubled its area. With this > 0 the offsets measured over the last this
        many seconds are pooled on the registered plane (``shadows.ShadowOffsets``, through
        the homography's derivative, so a yawing or zooming camera turns them with the view)
        and, once five are pooled, their median trims the dark boxes of frames short of
        samples. 0 disables (each frame alone). Measured against 0 (2026-12-02, MCMC seed 0
        unless said): twelve fresh generated scenes (seeds 51, 52, every scenario) HOTA/IDF1/
        MOTA 0.722/0.843/0.788 -> 0.736/0.862/0.832 (static:51 +0.055 HOTA, static:52 +0.038,
        convoy:51 +0.036, none lower by over 0.001), twelve more (seeds 61, 62)
        0.650/0.781/0.702 -> 0.654/0.783/0.711; the 18 held-out scenes, seeds 0-2,
        0.713/0.862/0.824 -> 0.715/0.860/0.826 (static camera MOTA 0.809 -> 0.823); identity
        benchmark IDF1/HOTA 0.880/0.738 -> 0.883/0.741; the demo 0.749/0.885/0.870 ->
        0.748/0.887/0.873; Santiago's detections and truck4's coverage (0.663) unchanged.
    shadow_chroma_px : int
        The shadow test's colour terms (saturation, hue) may pass anywhere within this many
        pixels (``shadows.shadow_mask``): compressed video keeps colour at half resolution
        (4:2:0), so beside a coloured vehicle its shadow takes the vehicle's colour for a pixel
        or two and is kept as part of it (a blue car's box +2 px on its shadow's sides). 1
        raised the twelve generated scenes (with ``shadow_trim``) to HOTA/IDF1 0.717/0.859 but
        cost Santiago (seeds 0-2) 0.654/0.875 -> 0.647/0.863, whose ground-truth boxes are wider
        than the vehicles; 0 (the default) tests each pixel alone, as Prati et al. Edges from
        the luma residual for vehicles that stand out in it (sharp in 4:2:0), and a one-pixel
        erosion of colour-only vehicles' residual, added nothing on the generated scenes
        (0.718/0.863) and cost Santiago seed 0 0.644 -> 0.629 HOTA; not kept.
    overlay_mask : str
        On-screen overlays (burned-in text, crosshairs, logos: fixed on the screen while a
        moving camera's ground moves under them) found and their pixels left out of detection,
        as an ``--ignore-region``'s are (:mod:`aerotrack.detection.overlay`): ``edges`` (only
        marks near the frame's edges: captions, time stamps, logos; a mark in the middle is
        reported, as it may be a vehicle the camera keeps centred), ``all`` (central crosshairs
        too), ``off``. A fixed camera gives no evidence and nothing is left out.
    overlay_min_s : float
        Seconds of camera motion before any pixel is called an overlay.
    overlay_share : float
        Share of the frames in which the camera moved that a pixel must stay unchanged on the
        screen while changing against the registered ground.
    hold_stopped : bool
        Keep the background from absorbing a vehicle after it was detected: pixels under recent
        detections are left out of the window median, and where every sample is left out the
        previous background is kept. A vehicle that stops at a light keeps being reported (with
        ``extra["stationary"]``); a parked vehicle never seen moving is never held. Persistence
        detections (``persist``) are not held: too faint to pass the stationary test, they were
        all taken for stopped vehicles.
    max_hold_s : float
        A pixel is held at most this long, so a false detection cannot freeze the background.
    stationary_lag_s : float
        A detection whose pixels match the frame this many seconds earlier is flagged stationary.
    protect_changed : float
        With ``hold_stopped``, a detection of which less than this fraction of pixels changed
        over ``stationary_lag_s`` is kept out of the background whole; of one that moved more,
        only the changed pixels are (the rest is uncovered road or a ghost; keeping it out
        made ghosts hold themselves and boxes trail backwards).
    ghost_part_ratio : float
        Of a moving detection, the changed pixels that already look as they will a lag ahead
        are kept out of the samples ahead only when their outline carries at least this ratio
        of the frame's to the background's gradient energy (a vehicle stopping there, not the
        ghost of one that left). Measured: 0.6 and 1.0 kept generated-scene trails, 1.5 and
        2.5 scored the same on Santiago and the generated scenes; 0 keeps every such part out.
    stopping_share : float
        ... except when at least this share of the detection's changed pixels look as they will
        a lag ahead (no part of it is about to move on: a vehicle coming to a stop, not a
        vehicle driving off its imprint), their outline ratio is at least
        ``stopping_outline_ratio`` and at least ``stopping_halfway_share`` of them also look so
        half a lag ahead: then they are kept out too. 0 disables. At this scale the outline
        test alone cannot tell a stopping vehicle from a ghost: the centred window already holds
        the vehicle that will stand there, so its outline is an edge of the background as well
        (generated exits:21, a car braking to a stop: ratio 1.06-1.17 over its last second of
        motion, then absorbed into the background for its whole 4.5 s stop). Measured (0 ->
        0.9): held-out generated scenes, detection recall of standing vehicles (<= 0.3 m/s)
        0.442 -> 0.528, all 0.848 -> 0.851, precision 0.8202 -> 0.8206; see docs/DESIGN.md
        for tracking. ``ghost_part_ratio`` 1.0 instead, for comparison: the same standing
        vehicles found, but Santiago HOTA/IDF1 0.670/0.892 -> 0.662/0.878 (a car departing from
        the light left its imprint held in the background and its track standing on it).
    stopping_outline_ratio : float
        See ``stopping_share``: the ratio at which the frame has as much edge on the outline as
        the background (a ghost's outline is the background's alone, below 1).
    stopping_halfway_share : float
        See ``stopping_share``. A queue of alike cars a second apart passes the same test a lag
        ahead (the next car stands where this one is), but not half a lag ahead (the gap between
        them is there). Without it (0) the demo lost HOTA/IDF1/MOTA 0.749/0.885/0.870 ->
        0.742/0.878/0.856 (one track's boxes shrank below IoU 0.5 for 33 frames, another lost
        16 frames); 0.9 kept the demo but gave back most of the standing vehicles (recall
        0.454); 0.5 and 0.25 keep both.
    ghost_ratio : float
        A blob whose frame pixels carry less than this fraction of the background's gradient
        energy is a ghost (a vehicle imprinted on the background, not in the frame) and dropped.
        0 disables the test; raising it removes more ghosts but also smooth, low-contrast vehicles.
    structure_ncc : float
        A refined blob whose frame pixels correlate with the background's at least this much
        (``moving.same_structure``, normalised cross-correlation of grey levels) is the
        background's own structure seen with another contrast or sharpness (a thin bright wall
        beside its shadow, sharper in the frame than in the warped samples), or a shadow the
        colour test missed, not a vehicle, and is dropped. 0 (the default) disables; 0.8 is
        the measured setting. Measured against 0 (2026-12-02): detection precision at IoU 0.5
        on the 18 held-out generated scenes through ``aerotrack track`` 0.822 -> 0.841 (recall
        0.825 -> 0.822; convoy:21 0.54 -> 0.76, whose walls gave 739 detections on nothing),
        on twelve fresh ones (seeds 61, 62) 0.783 -> 0.813 (recall 0.770 both), but tracking
        did not gain: held-out HOTA/IDF1/MOTA over MCMC seeds 0-2 0.715/0.860/0.826 ->
        0.714/0.860/0.825, fresh seeds 51, 52 0.736/0.861/0.832 -> 0.740/0.863/0.828, seeds
        61, 62 0.654/0.783/0.711 -> 0.649/0.775/0.705 (seed 0), identity benchmark IDF1
        0.883 -> 0.877 (occlusions 23/31 -> 22/31), truck4 0.663 both, and Santiago (seeds
        0-2), where it dropped 5 of 3044 detections (a fast car's dark rear, fill at the frame
        edge), 0.670/0.892 -> 0.658/0.873: local association and the finish stage already
        reject most such false alarms, and a detection less moves the sampler elsewhere.
    drop_small_ratio : float
        After splitting and joining, a blob under this fraction of the frame's median blob area
        (needs 5 blobs) is dropped (``blobs.drop_small``): leftover fragments of a vehicle
        detected beside it, pedestrians, blown debris, noise. Raising it removes more of them
        but also small or partly seen vehicles; 0 disables. Measured (0 -> 0.4): Santiago
        detection P/R@IoU0.5 0.668/0.868 -> 0.756/0.863, tracking HOTA/IDF1 over seeds 0-2
        0.632/0.825 -> 0.636/0.838; generated scenes P/R 0.845/0.829 -> 0.882/0.816,
        identity benchmark (5 scenes x 300 frames) IDF1/HOTA 0.795/0.583 -> 0.840/0.601.
    regrow_ratio : float
        A blob that ``drop_small_ratio`` would drop is first regrown through the residual above
        this fraction of the threshold (``blobs.regrow_small``), inside one typical blob length
        and never into another blob; when it becomes one typical-sized vehicle it is kept (its
        box refined at the lower threshold). Dark vehicles on dark asphalt leave only their
        contrasting parts above the threshold. 0 disables. 0.5 is the default since the
        generator draws vehicles area-exact (f3a44e0) and dark vehicles lose their shadow's
        growth (``shadow_trim``); measured then against 0: identity benchmark (MCMC seeds 0-2)
        IDF1 0.862/0.830/0.822 -> 0.864/0.829/0.849 (mean 0.838 -> 0.847), HOTA mean 0.691 ->
        0.699, exits re-acquired 4/5/5 -> 6/5/5 of 7; six other scenes IDF1 0.820 -> 0.814;
        eighteen held-out scenes (``benchmarks/scenarios.py``) HOTA 0.668 both, IDF1 0.817 ->
        0.815, MOTA 0.768 -> 0.772, switches 59 -> 56; Santiago seeds 0-2 HOTA 0.654 -> 0.659,
        IDF1 0.875 -> 0.877, MOTA 0.735 -> 0.748 (seed 1: 0 -> 3 switches); generated detection
        recall 0.845 -> 0.869 at precision 0.910; truck4 unchanged. Earlier history: 0.5 raised per-frame
        detection recall (Santiago P/R 0.759/0.865 -> 0.763/0.885, generated scenes
        0.910/0.841 -> 0.909/0.868) but not tracking (Santiago seeds 0-2 HOTA 0.642 -> 0.643,
        IDF1 0.862 -> 0.850; identity benchmark IDF1 0.784 -> 0.781), so it stays an option.
        With the cab joining and duplicate handling of 2026-11-26 the generated scenes gain
        (identity benchmark IDF1 0.814 -> 0.833, HOTA 0.620 -> 0.627, occlusions re-acquired
        16 -> 20 of 31) but Santiago still loses (seeds 0-2 HOTA 0.650 -> 0.645, IDF1 0.871 ->
        0.848, 0 -> 3 ID switches per run: regrown fragments of queued cars take in the faint
        residual between them); capping the regrown size at 1.25 x the typical blob made
        Santiago worse (IDF1 0.838). Re-measured at 22e9b97 with ``regrow_ghost_ratio``
        (below): Santiago seeds 0-2 HOTA 0.650/0.654/0.658 -> 0.663/0.650/0.666, IDF1 0.876 ->
        0.878, MOTA 0.739 -> 0.751 (mean), but the identity benchmark (MCMC seeds 0-2) IDF1
        0.826/0.832/0.813 -> 0.838/0.823/0.780, HOTA 0.628/-/- -> 0.635/0.624/0.599: still an
        option.
    regrow_ghost_ratio : float
        A regrown blob (``regrow_ratio``) must pass the ghost test (``ghost_ratio``) at this
        stricter ratio: it is mostly faint residual, and the faint imprint a vehicle leaves on the
        background where it waited (the ghost once it drives off) regrows as readily as a dark
        vehicle; a vehicle shows its outline in the frame (ratio > 1), a ghost only in the
        background. 0 applies ``ghost_ratio`` alone. Found on Santiago with ``regrow_ratio``
        0.5: a van waited, drove off, and its regrown ghost on the marked asphalt (outline ratio
        between 0.6 and 1) kept the van's track while the van got a new one. Measured there
        (``regrow_ratio`` 0.5, seeds 0-2): 0 -> 1.0 HOTA 0.646/0.653/0.666 -> 0.663/0.650/0.666,
        IDF1 0.868 -> 0.878 (mean), ID switches 5 -> 3; identity benchmark seed 0 unchanged.
    drop_small_near : float
        With > 0, such a small blob is dropped only within this many typical blob lengths of a
        bigger blob (leftover fragments only); 0 drops small blobs anywhere.
    box_edge_level : float
        Box edges are placed where a blob's full-resolution residual falls to this fraction of
        its median (``blobs.edge_extent``) instead of at the noise threshold, which reaches
        further out the higher the vehicle's contrast (anti-aliased rims, blur). 0 disables;
        higher gives tighter boxes. Measured (0 -> 0.5), detection P/R at IoU 0.5: generated
        scenes 0.882/0.816 -> 0.892/0.825 (mean IoU of matched boxes 0.706 -> 0.768);
        Santiago 0.756/0.863 -> 0.754/0.860 (0.741 -> 0.733: its ground-truth boxes, made by a
        commercial tool at one size per track, are about 2 px wider than the vehicles); truck4
        unchanged.
    min_conf : float
        Detections with a lower confidence are dropped: the built-in detector's, and the boxes
        of ``--detections`` (their conf column clipped to [0, 1]; ``track --min-conf``).
    persist : bool
        Multi-frame persistence for small, faint movers (``detection.persistence``): a
        motion-compensated leaky sum of each frame's weak residual reports targets whose
        evidence keeps coming back at reachable places although no single frame has a blob
        that passes the gates. Off by default: at 63c86d3 it raises truck4's best single ID
        0.59 -> 0.78 (the issue 6 goal is 0.80) and keeps Santiago's GT 24 while it waits at
        the light (55 instead of 44 frames), but costs Santiago precision 0.754 -> 0.732 and
        IDF1 0.851 -> 0.833 (mostly small real movers that are not annotated) and 1.17-1.27x
        detection CPU time; ``benchmarks/persistence.py`` measures it, and
        ``detection/persistence.py`` lists what was tried.
    persist_tau_s : float
        Time constant of the sum, seconds (decay ``exp(-dt / tau)``). Longer averages more noise
        away but smears a target that changes speed and delays its first report.
    persist_window_s, persist_min_support : float
        A peak is reported only when at least ``persist_min_support`` of the frames of the last
        ``persist_window_s`` seconds had a peak or a detection within reach of its world
        position (travel at the maximum speed plus one target length). 0 disables the test.
    persist_support_level : float
        Peaks of the sum above this fraction of the threshold count as support for later
        frames (an M-of-N test's first threshold); lower lets a target that fades for a few
        frames keep its support, and lets clutter lend support too.
    persist_max_speed_mps, persist_max_speed_px_s : float
        Largest speed of a target relative to the ground (metres/s with a scale, full-resolution
        pixels/s without): the sum is grey-dilated by this distance each frame. Higher follows
        faster targets but lets more clutter add up.
    persist_max_length_m, persist_max_length_px : float
        Largest side of a persistence box (small targets only; larger ones are found by the
        regular blobs).
    persist_min_area_ratio, persist_typical_s : float
        A persistence box must cover at least this fraction of the median area of the regular
        detections of the last ``persist_typical_s`` seconds (when there are 5 or more): the
        typical detection is the best guess of a vehicle's size, so persistence finds far,
        small vehicles among small detections but not pedestrians beside large ones. 0 disables.
        Measured (persistence on): 0.25 -> 0.5 raised Santiago precision 0.680 -> 0.732 and the
        best truck4 ID's coverage 0.641 -> 0.777 (fewer clutter tracks), generated scenes
        unchanged (P/R 0.855/0.801 -> 0.858/0.801).
    persist_threshold : float
        Reporting threshold on the sum in steady-state units: a target whose capped, locally
        normalised evidence is ``e`` in every frame scores ``e`` (1 = at the single-frame
        threshold over its whole patch). Lower finds fainter targets and more clutter.
    persist_noise_ratio : float
        The threshold is at least this multiple of the sum's 0.99 quantile over the frame: where
        clutter (or a large speed-times-memory search area) lifts every maximum, only what
        stands out is reported. 0 keeps ``persist_threshold`` alone.
    persist_edge_px : float
        No peak within this many full-resolution pixels of an untrusted background pixel
        (view edges, pixels entering the view).
    persist_min_evidence : float
        The current frame's evidence at the peak (same units) must reach this: the target is
        here now, not only its trail.
    persist_cap : float
        Per-pixel evidence cap, in single-frame thresholds.
    persist_blur_px : float
        Side (full-resolution pixels) of the box average of the evidence: about a small
        target's size.
    persist_noise_block_px : float
        Side (full-resolution pixels) of the blocks whose evidence RMS, where above the frame's,
        scales the evidence down (textured ground, foliage, parallax). 0 disables.
    persist_box_ratio : float
        A persistence box spans the current frame's evidence above this fraction of its value
        at the peak (connected to the peak).
    persist_exclude_px, persist_exclude_length : float
        Peaks within ``max(persist_exclude_px, persist_exclude_length x its longer side)``
        full-resolution pixels of a regular detection are not reported: near a detection
        persistence mostly finds the other part of a vehicle the blobs split in two.
    persist_max_per_frame : int
        At most this many persistence detections per frame (strongest first).
    persist_conf : float
        Confidence of a persistence detection at score ``persist_threshold``; it rises towards
        1 with the score.
    """

    window_s: float = 3.0
    causal: bool = False
    full_window_at_ends: bool = True
    sample_every_s: float = 0.2
    update_every_s: float = 0.2
    refresh_uncovered: float = 0.03
    model_scale: float = 0.5
    model_pixel_max_m: float = 0.65
    min_valid_samples: int = 3
    threshold_sigma: float = 7.0
    min_threshold: float = 10.0
    seed_ratio: float = 1.5
    seed_sigma: float = 0.0
    residual_sigma_px: float = 0.0
    gain_block_px: float = 96.0
    exposure_tolerance: float = 0.04
    close_m: float = 0.8
    close_px: float = 4.0
    close_resolved_px: float = 2.0
    join_gap_m: float = 1.0
    join_gap_px: float = 5.0
    min_area_m2: float = 2.0
    min_area_px: float = 60.0
    max_length_m: float = 25.0
    max_length_px: float = 300.0
    min_width_m: float = 1.2
    min_width_px: float = 5.0
    pixel_gates_reference_px: float = 2203.0
    split_blobs: bool = True
    split_area_ratio: float = 1.7
    join_parts_ratio: float = 1.5
    split_full_ratio: float = 0.0
    split_colour_dist: float = 0.0
    split_full_sides: float = 0.6
    split_full_shadow: bool = True
    join_cab_ratio: float = 0.9
    shadow_suppression: bool = True
    shadow_alpha: float = 0.4
    shadow_beta: float = 0.9
    shadow_tau_s: float = 0.15
    shadow_tau_h: float = 50.0
    shadow_min_core: float = 0.4
    shadow_trim: bool = True
    shadow_chroma_px: int = 0
    shadow_trim_share: float = 0.5
    shadow_trim_pool_s: float = 60.0
    structure_ncc: float = 0.0
    overlay_mask: str = "edges"
    overlay_min_s: float = 1.0
    overlay_share: float = 0.5
    hold_stopped: bool = True
    max_hold_s: float = 120.0
    stationary_lag_s: float = 1.0
    protect_changed: float = 0.2
    ghost_part_ratio: float = 1.5
    stopping_share: float = 0.9
    stopping_outline_ratio: float = 1.0
    stopping_halfway_share: float = 0.5
    ghost_ratio: float = 0.6
    drop_small_ratio: float = 0.4
    drop_small_near: float = 0.0
    regrow_ratio: float = 0.5
    regrow_ghost_ratio: float = 1.0
    box_edge_level: float = 0.5
    min_conf: float = 0.05
    persist: bool = False
    persist_tau_s: float = 0.5
    persist_window_s: float = 1.0
    persist_min_support: float = 0.6
    persist_support_level: float = 0.5
    persist_max_speed_mps: float = 15.0
    persist_max_speed_px_s: float = 20.0
    persist_max_length_m: float = 8.0
    persist_max_length_px: float = 40.0
    persist_min_area_ratio: float = 0.5
    persist_typical_s: float = 10.0
    persist_threshold: float = 0.5
    persist_noise_ratio: float = 1.4
    persist_edge_px: float = 16.0
    persist_min_evidence: float = 0.5
    persist_cap: float = 2.0
    persist_blur_px: float = 6.0
    persist_noise_block_px: float = 64.0
    persist_box_ratio: float = 0.35
    persist_exclude_px: float = 8.0
    persist_exclude_length: float = 1.0
    persist_max_per_frame: int = 10
    persist_conf: float = 0.3


@dataclass(frozen=True)
class AssociationConfig:
    """Local data association by data-driven MCMC (Yu & Medioni section 4).

    Attributes
    ----------
    window_s : float
        Sliding association window in seconds (the paper: 45 frames = 1.5 s at 30 fps). Decisions
        about observations older than the window are final. Longer resolves longer ambiguities but
        delays output and costs time.
    max_speed_mps : float
        Maximum target speed in metres per second: the graph's edges (eq. 3) join observations no
        farther apart than this times their time gap plus a quarter of the box's width + height
        (``posterior.py``: the detector's box jitter, which at 30 frames/s is most of an edge's
        reach, so a very low value does not stop a car). It is a reach, not a speed limit; the
        Kalman gate (``gate_chi2``) decides a link. In image coordinates it must also cover the
        camera's apparent motion.
    max_gap_s : float
        Longest run of missed detections a tracklet may bridge (an edge's largest time gap). Longer
        keeps identities through occlusions but risks joining two different targets. Measured
        (2026-11-27, 1.2 -> 0.8 / 0.6 s): Santiago's five variants (seeds 0-2, own detector)
        gain, most with the moving camera (moved crop HOTA/IDF1 0.612/0.813 -> 0.615/0.821 /
        0.621/0.839, ID switches 6 -> 3 / 1: a queued car's tracklet no longer coasts into the
        next lane); UAVDT's detections with their runs of misses lose (local association IDF1
        0.810 -> 0.788 / 0.782); the 18 held-out generated scenes HOTA/IDF1 0.700/0.857 ->
        0.699/0.857 / 0.696/0.852 (ID switches 38 -> 44 / 49); truck4's tiny truck, detected in
        scattered frames, best single ID 0.663 -> 0.423 at either. Kept at 1.2 s; lower it for
        queues filmed from a moving camera when the detector rarely misses.
    target_size_m : float
        When ``metres_per_unit`` is unknown (image coordinates), the scale is estimated from the
        median detection size assuming this typical target size (square root of width x height;
        a car is about 2.8 m). 0 treats world units as metres.
    accel_std_mps2 : float
        Kalman process noise: white-noise acceleration, m/s^2 (eq. 6). Raising it follows sharp
        manoeuvres and camera shake, but widens the gate so that neighbours get confused.
    size_std_m : float
        Kalman random walk of the target size after one second, metres.
    pos_std_m, pos_frac : float
        Kalman observation noise of the position (eq. 7): absolute in metres, plus a fraction of the
        box size (large blobs have imprecise centres).
    size_frac : float
        Observation noise of the box size, as a fraction of the size.
    gate_chi2 : float
        Gate on the squared Mahalanobis distance of a link (4 degrees of freedom). A link scores
        ``0.5 * (gate_chi2 - d^2)``: larger admits sloppier links and rewards good ones more.
    gap_accel_mps2, gap_lateral_mps2, gap_min_s, gap_size_change : float
        A link bridging at least ``gap_min_s`` of missed detections is refused when the
        observation lies farther from the constant-velocity prediction, along the track's
        heading or across it, than these accelerations reach over the gap (``a t^2 / 2``, plus
        one standard deviation of the prediction; ``posterior.gap_motion_ok``): a vehicle does
        not turn round or change lanes in under a second, but the Kalman gate, as wide as
        ``accel_std_mps2`` makes it, let a track that coasted under an occluder take the vehicle
        coming the other way in the next lane. An observation whose box area differs from the
        track's by more than ``gap_size_change`` (a share) is not tested: a part of a vehicle
        coming out from under a tree, whose centre runs ahead of it (0 tests every link;
        with the gate on, seeds 0-2: identity IDF1 0.848 -> 0.863, occlusions 20-22 -> 22-23
        of 31, held-out HOTA/IDF1 0.698/0.857 -> 0.695/0.853, against 0.866 and 0.693/0.849
        with the gate off).
        Applied only with a known scale (a map or
        ``--gsd``), as ``split_accel_mps2``: with a scale estimated from box sizes it cut
        truck4's tiny truck into pieces (best single ID 0.658 -> 0.437). ``gap_accel_mps2`` 0
        (the default) disables; 6 with ``gap_lateral_mps2`` 3 is the measured setting. Off
        because the two benchmarks disagree: the 18 held-out generated scenes gained (MCMC
        seeds 0-2, HOTA/IDF1 0.693/0.849 -> 0.698/0.857), the identity benchmark lost (IDF1
        0.866 -> 0.848, occlusions re-acquired 23 -> 20-22 of 31): a vehicle coming out from
        under a tree is first seen as growing partial boxes whose centres run ahead of it, and
        the test cut those first frames off its track; Santiago with ``--gsd 0.125`` (seed 0)
        also lost, HOTA/IDF1 0.662/0.889 -> 0.656/0.881 (docs/DESIGN.md, "Physically possible
        gaps").
    miss_cost : float
        Log-penalty per missed frame inside a link; raising it prefers ending a track to bridging.
    birth_cost : float
        Log-penalty per track born in the window (prior on the number of tracks): with the link
        reward it sets how many consistent links a track needs to beat leaving its observations as
        false alarms. Raising it rejects more false positives but also short true tracks. It is
        also the price of cutting a track in two: too low, and the sampler splits a long track
        where its constant-velocity fit has drifted (a vehicle braking or turning), since a
        restarted filter fits the rest better. 16 rather than 8 removed those splits on Santiago
        (IDF1 0.70 -> 0.75, ID switches 5 -> 0), raised local-alone IDF1 on generated scenes
        (benchmarks/identity.py, 0.60 -> 0.63 with ground-truth detections, 0.47 -> 0.49 with the
        detector) and left UAVDT unchanged (IDF1 0.810 mean over seeds 0-2 either way).
    app_weight : float
        Weight of the appearance likelihood (eq. 9, symmetric KL of colour histograms); 0 disables.
    overlap_lambda : float
        MRF interaction lambda (eq. 10): penalty per unit IoU of two same-frame observations that
        both belong to tracks. Suppresses tracks made of split blobs.
    partial_score : float
        Log-likelihood ratio of a *partial* link (``posterior.link_step``): a detection that fails
        the whole-box gate of a track but is clearly smaller than its predicted box and lies
        inside it is taken as a part of the target (a blob detector's fragment). It says the
        target is there (the track lives on without the missed-detection cost) but updates
        nothing, and the track's row there is bridged between its whole observations. A
        detection inside two boxes of the previous frame is never a part. 0 disables. Raising it
        absorbs fragments that would otherwise form a second tracklet interleaved with the
        vehicle's, but lets a track take a small neighbour lying inside its predicted box in a
        frame where its own detection is missing. 4 against 0 depends on the detector (mean of
        seeds 0-2, HOTA / IDF1, ``benchmarks/association.py --seeds-ablation``): with the
        detector of commit 7b6f1ea Santiago 0.632 / 0.825 vs 0.618 / 0.802 and generated
        default:0 0.576 / 0.778 vs 0.554 / 0.759; with the reworked one (persistence) Santiago
        0.629 / 0.830 vs 0.636 / 0.838, default:0 0.567 / 0.767 vs 0.575 / 0.799, convoy:2
        0.578 / 0.689 vs 0.558 / 0.639, convoy:1 0.478 / 0.704 vs 0.476 / 0.686; UAVDT (seed
        0) 0.754 / 0.813 vs 0.751 / 0.810. A part taken instead of a whole detection that
        narrowly fails the gate leaves the size stale, the track splits, and pieces shorter than
        ``linking.min_track_s`` are dropped. Off.
    partial_min_inside : float
        Share of a detection's area that must lie inside the predicted box for a partial link.
    partial_max_area : float
        Largest ratio of a partial detection's area to the predicted box's: a part is clearly
        smaller than the whole (box jitter is not a part).
    partial_max_run_s : float
        Longest time from a track's last whole observation to a partial one. A detector returns a
        part for a few frames; a long run of "parts" is a target of its own, which a track that
        started on a merged blob of two vehicles would otherwise keep following (Santiago's
        fragment runs last up to 0.37 s; such merged-blob runs on generated scenes 1 s).
    iters_per_ambiguity : float
        MCMC samples per frame, per ambiguous new detection (in the gate of several tracks, or
        unmatched), plus ``min_iters``. More samples explore more but cost time linearly.
    min_iters : int
        MCMC samples per frame regardless of the number of detections.
    extend_gamma : float
        Probability that an extension move appends one more observation (the paper's gamma).
    min_length_s : float
        Tracklets shorter than this (first to last observation, seconds) are rejected as false
        positives when they end.
    stitch_gap_s, stitch_dist_m, stitch_max_turn_deg, stitch_min_speed_mps : float
        ... unless a live track begins at most ``stitch_gap_s`` after such a piece ends, its
        first observation within ``stitch_dist_m`` of the piece's last and its heading within
        ``stitch_max_turn_deg`` of the piece's (least squares over 8 observations each; either
        slower than ``stitch_min_speed_mps`` has no heading): the piece then starts that track
        (``LocalAssociator._lead_into``). The sampler cuts a vehicle whose box changes faster
        than the size model follows (a sharp turn rotates it) into pieces that were each
        dropped: a vehicle turning as it came out from under an occluder lost its first second.
        0 metres disables. Measured against off (``benchmarks/identity.py``, own detector, MCMC
        seeds 0-2): IDF1 0.836/0.846/0.829 -> 0.843/0.849/0.843, HOTA 0.638/0.639/0.629 ->
        0.640/0.642/0.639, occlusions <= 4 s re-acquired 19/20/20 -> 22/23/22 of 31, exits
        <= 10 s 4/4/4 -> 6/5/4 of 7; six other scenes (seed 0) IDF1 0.784 -> 0.783, occlusions
        28 -> 29 of 51, exits 9 -> 10 of 15; ground-truth detections, UAVDT and truck4 unchanged,
        the demo's MOTA 0.814 -> 0.813; Santiago (seeds 0-2) HOTA 0.654 both, IDF1 0.876 -> 0.875. Without the
        heading check the demo lost 0.03 IDF1 (a piece of a vehicle's merged blob with an
        oncoming one put before the oncoming one's track, which linking then joined to the
        first). ``stitch_gap_s`` 0.2: the five scenes the same, the six others 0.783 -> 0.777.
        Keeping every short piece for linking instead (``min_length_s`` 0.2) cost IDF1
        0.836 -> 0.828 and 0.784 -> 0.725.
    follow_on_gap_s : float
        A piece too short to be a tracklet is kept when it begins at most this long after a
        tracklet's last observation, within ``stitch_dist_m`` of where that tracklet's velocity
        puts it, heading the same way (``LocalAssociator._follows_ended``): the end of a vehicle
        that the sampler cut off (a bus leaving the view shrank faster than the size model
        follows), for global linking to join. 0 (the default) disables. Measured at 0.2 s
        (2026-12-02): Santiago HOTA 0.669 -> 0.670 (the bus's last six detections), but the 18
        held-out generated scenes 0.718/0.865 -> 0.713/0.859 HOTA/IDF1, ID switches 44 -> 49
        (occlusion:21 -0.060 HOTA: pieces of other vehicles emerging near a track's end were
        kept and linked to it; dense:12 -0.023). Off.
    split_appearance : float
        A finished tracklet is cut where it bridges a run of missed frames across which its
        mean colour histogram changes by more than this Bhattacharyya distance
        (:func:`aerotrack.association.local.split_appearance_jumps`: one vehicle went under an
        occluder, another came out). 0 disables. Measured (``benchmarks/identity.py``, 5
        generated scenes, own detector, MCMC seeds 0-2): IDF1 0.818 -> 0.824, HOTA 0.620 ->
        0.625, ID switches 18 -> 14.7 per run (0.3: the same on seed 0, 0.25 less); Santiago's
        tracks identical (seeds 0-2; 0.3 cost seed 0 0.007 HOTA); UAVDT has no frames, hence no
        histograms, and is unaffected.
    split_min_gap_s, split_side_obs : float, int
        Shortest bridged run checked, seconds (0: every pair of consecutive observations, so a
        hand-over without missed frames is cut too; on the identity scenes and Santiago that
        found nothing more: identity identical, Santiago HOTA -0.002); observations averaged on
        each side.
    split_max_size_ratio : float
        The colour check skips a run across which the median box area changes by more than this
        factor (0: never skips): a box that changes size holds other pixels (a trail of road
        behind a slow vehicle, a vehicle half behind a tree), so its colour changes although the
        vehicle does not. Measured 0 -> 1.5: truck4 with persistence, best ID over MCMC seeds
        0-2 0.461/0.755/0.458 -> 0.767/0.755/0.753 (1.3 the same, 2.0 left seed 2 cut); identity
        benchmark seeds 0-2 IDF1 0.826/0.832/0.814 -> 0.826/0.832/0.813, ID switches 17/13/14
        unchanged (no hand-over there changes box size that much); Santiago identical.
    split_accel_mps2, split_speed_slack_mps, split_motion_side_s : float
        A finished tracklet is also cut where its velocity changes faster than a vehicle can:
        least-squares velocities over ``split_motion_side_s`` of observations before and after a
        point differing by more than ``split_accel_mps2`` x the time between the two fits plus
        ``split_speed_slack_mps`` (:func:`aerotrack.association.local.split_motion_jumps`: two
        vehicles passing each other left one merged blob, and the tracklet came out of it on
        the other one). Applied only with a known scale (a map or ``--gsd``): in pixels the
        scale is estimated from box sizes, and without frames (``--detections`` alone) the
        camera's own motion is in the velocities (UAVDT: IDF1 0.812 -> 0.803, 4 -> 9 switches
        when applied there). 0 disables. Measured 0 -> 6 m/s^2 (with ``turn_a_max_mps2`` 10):
        identity benchmark (own detector, seed 0) IDF1 0.833 -> 0.870, HOTA 0.692 -> 0.715,
        occlusions re-acquired 20 -> 22 of 31, exits 5 -> 6 of 7; 18 held-out generated scenes
        HOTA/IDF1 0.687/0.842 -> 0.692/0.848 (one scene changed, dense:12 IDF1 0.709 -> 0.827);
        Santiago (seeds 0-2) HOTA 0.665 -> 0.664, IDF1 0.885 -> 0.884; demo identical.
    split_merged : bool
        A detection in which two or more confirmed tracks expect their vehicles (predicted
        centre inside, most of the predicted box inside, the detection well larger than each) is
        replaced by one box per track before association (:mod:`aerotrack.association.merged`):
        vehicles that touch leave one blob. Off by default. On the generated identity scenes a
        third of the detector's misses are such blobs (1196 of 3151 missed boxes lie in a
        detection holding another vehicle too); splitting them by the ground truth would raise
        IDF1 0.826 -> 0.855. This rule, MCMC seeds 0-2: IDF1 0.824 -> 0.827, HOTA 0.625 ->
        0.630, occlusions 18.3 -> 19/31, exits 4 -> 4.7/7; but Santiago HOTA 0.650 -> 0.640,
        IDF1 0.871 -> 0.853, 0 -> 1-2 ID switches (about ten splits there, plausible ones; the
        switches appear away from them, in the same windows).
    split_merged_area_ratio : float
        The detection's area must be at least this times the largest predicted box's.
    split_merged_min_obs_s, split_merged_max_age_s : float
        A track counts when observed for at least this long (in frames at the video's rate),
        the last time at most this long ago.
    follow_stopped : bool
        Follow vehicles that slow down and stop where the detector loses them, by
        normalised cross-correlation with their last detected appearance
        (:mod:`aerotrack.association.follow`); needs the frames (not with ``track --from``),
        and a resumed run starts it afresh (its templates are not in the saved state). Off by
        default: measured neutral (docs/DESIGN.md, "Following stopped vehicles").
    follow_start_s : float
        A track is followed when it was last detected at most this long ago.
    follow_max_s : float
        A follow lasts at most this long after the vehicle's last real detection.
    follow_max_speed_mps : float
        Only tracks no faster than this at their last observation are followed; it also bounds
        how far the vehicle is looked for from one frame to the next.
    follow_min_travel_m : float
        Only tracks whose points spread over at least this many metres (seen driving).
    follow_min_obs_s : float
        Only tracks observed for at least this long (in frames at the video's rate).
    follow_min_ncc : float
        The least normalised cross-correlation of a match.
    follow_min_contrast : float
        A template whose grey levels' standard deviation is under this is not followed.
    follow_margin_px : int
        Pixels kept around each detection's box in the remembered patches.
    follow_max_creep_m : float
        A followed vehicle is at most this far (metres) from its last real detection.
    follow_past_s : float
        A track is followed only when its place, as it looked this long before the track came
        within a metre of it, does not match the template (the vehicle arrived there: a fixed
        pattern detected by mistake matches itself).
    follow_min_width_m, follow_min_area_m2 : float
        A template box narrower or smaller than this (a fragment) is not followed.
    """

    window_s: float = 1.5
    max_speed_mps: float = 40.0
    max_gap_s: float = 1.2
    target_size_m: float = 2.8
    accel_std_mps2: float = 10.0
    size_std_m: float = 0.3
    pos_std_m: float = 0.2
    pos_frac: float = 0.06
    size_frac: float = 0.06
    gate_chi2: float = 16.0
    gap_accel_mps2: float = 0.0
    gap_lateral_mps2: float = 3.0
    gap_min_s: float = 0.25
    gap_size_change: float = 0.3
    miss_cost: float = 0.3
    birth_cost: float = 16.0
    app_weight: float = 1.0
    overlap_lambda: float = 4.0
    partial_score: float = 0.0
    partial_min_inside: float = 0.8
    partial_max_area: float = 0.75
    partial_max_run_s: float = 0.5
    iters_per_ambiguity: float = 2.0
    min_iters: int = 20
    extend_gamma: float = 0.5
    min_length_s: float = 0.4
    stitch_gap_s: float = 0.1
    stitch_dist_m: float = 3.0
    stitch_max_turn_deg: float = 60.0
    stitch_min_speed_mps: float = 1.0
    follow_on_gap_s: float = 0.0
    split_appearance: float = 0.4
    split_min_gap_s: float = 0.1
    split_side_obs: int = 6
    split_max_size_ratio: float = 1.5
    split_accel_mps2: float = 6.0
    split_speed_slack_mps: float = 2.0
    split_motion_side_s: float = 0.5
    split_merged: bool = False
    split_merged_area_ratio: float = 1.4
    split_merged_min_obs_s: float = 0.5
    split_merged_max_age_s: float = 0.2
    follow_stopped: bool = False
    follow_start_s: float = 0.3
    follow_max_s: float = 60.0
    follow_max_speed_mps: float = 4.0
    follow_min_travel_m: float = 4.0
    follow_min_obs_s: float = 0.5
    follow_min_ncc: float = 0.8
    follow_min_contrast: float = 6.0
    follow_margin_px: int = 2
    follow_max_creep_m: float = 3.0
    follow_past_s: float = 2.0
    follow_min_width_m: float = 1.2
    follow_min_area_m2: float = 3.0


@dataclass(frozen=True)
class LinkingConfig:
    """Global tracklet association (Yu & Medioni section 5) and re-acquisition.

    Attributes
    ----------
    max_gap_s : float
        Longest gap between two tracklets that may still be linked, seconds: an occlusion, or
        an exit and re-entry (a gap's seconds in view cost ``gap_cost_per_s`` each; a wait is a
        stop link, ``stop_max_gap_s``). 12 -> 60 (2026-12-03, after a probe found 40 of 44 lost
        re-entries were over 12 s, the camera panning away and back): its seven exit scenes
        (1800-2100 frames) HOTA/IDF1 0.650/0.740 -> 0.666/0.780, ID switches 66 -> 49, same
        ID after 10-20 s 3/20 -> 9/21 and after 20-60 s 0/26 -> 10/27 (of the re-acquisitions
        it claims over 12 s, 19 right and 15 wrong: ``links.csv`` gives each one's cost); the
        18 held-out scenes 0.723/0.871/0.825 -> 0.730/0.884/0.825, ID switches 40 -> 31 (five
        scenes changed, all up: static:11 0.585/0.790 -> 0.617/0.837, static:21 0.706/0.820 ->
        0.738/0.910); 30 s scored the same on those 30 s scenes, 0.659/0.763 on the exit scenes.
        The identity benchmark, Santiago (seeds 0-2), truck4 and UAVDT identical. Linking took
        2-2.6x as long on the exit scenes (9 s for 2100 frames).
    v_max_mps : float
        Spatial gate (Yu & Medioni 5.1): the start of a later tracklet must lie within
        ``v_max_mps x gap`` (plus ``gate_slack_m``) of the end of the earlier one.
    a_max_mps2 : float
        Velocity gate: ``|V_end - V_start| <= a_max_mps2 x gap + speed_slack_mps``.
    gate_slack_m : float
        Added to the distance gate (detection jitter, box centre vs ground point).
    speed_slack_mps : float
        Added to the velocity gate (velocity estimated from noisy short tracklets).
    motion_sigma_m : float
        Standard deviation of the motion-context prediction error at gap 0, metres.
    motion_sigma_growth_mps : float
        How fast that deviation grows with the gap, metres per second. Raising both tolerates
        worse predictions but lets look-alikes swap identities.
    velocity_sigma_mps, velocity_sigma_growth_mps2 : float
        Expected change of velocity between the end of one tracklet and the start of its
        continuation: at gap 0 (m/s) and its growth per second of gap (m/s^2).
    weight_motion, weight_appearance, weight_descriptor : float
        Weights of the three cues in the link cost (docs/DESIGN.md, "Persistent identity"); 0 switches a cue off.
    max_cost : float
        A pair whose fused cost exceeds this is never linked (the cost of "a new target").
    min_tracklet_s : float
        Tracks (chains of linked tracklets, first to last observation) shorter than this get no
        prediction after their end: most are false alarms or split blobs.
    predict_gaps : bool
        Add ``predicted`` points in the frames between linked tracklets and after a track's end.
    lag_sigma_growth_mps : float
        How far a target may fall behind its predicted position per second of gap (slowing down,
        waiting at a light behind an occluder), metres per second. Larger links stop-and-go
        targets after long gaps but lets a later look-alike on the same path take the identity.
    turn_max_gap_s : float
        Gaps up to this long may hide a turn or U-turn: a link may then change heading freely if
        its speed and reach are consistent (the tracklet often breaks exactly there; a vehicle
        that left the view may come back the other way). On generated scenes (benchmarks/
        identity.py) 3, 6 and 12 s scored alike with ground-truth detections; 12 s re-acquired
        more exits with the detector's.
    turn_a_max_mps2 : float
        Over such gaps the velocity gate still applies to the whole change of velocity (not
        only of speed) with this acceleration and the time of the two velocity fits
        (``history_s`` each side) added to the gap: a vehicle turns round only so fast (10 m/s^2,
        about what tyres give). 0: only the speed is gated. Two vehicles passing each other in
        opposite lanes leave one merged blob; the tracklet of one may end in it and one of the
        other start a few frames later beside it, "turned round" at full speed. Measured 0 -> 10
        (the first on this machine's run of the old rule): demo IDF1 0.831 -> 0.853, HOTA 0.678
        -> 0.697 (one such link gone); identity benchmark (own detector, seed 0) IDF1 0.829 ->
        0.833; 18 held-out generated scenes, Santiago (seeds 0-2), UAVDT and truck4 identical.
        6 m/s^2 (``a_max_mps2``) refused generated vehicles' 90-degree turns at 11 m/s hidden at
        the image edge (identity IDF1 0.823); 8 and 12 as 10 on the demo and default:2. Two
        vehicles passing each other in opposite lanes leave a merged blob, after which a
        tracklet of one may end and one of the other start a few frames later close by.
    turn_max_gap_image_s : float
        ``turn_max_gap_s`` when tracking in image coordinates with no known scale (``--detections``
        without frames, so nothing is registered, and no ``--gsd``): there the camera's own motion
        looks like manoeuvres and the reach is only estimated, and long-gap manoeuvre links were
        wrong more often than right (UAVDT). Registered frames are the ground even without a
        scale, and ``turn_max_gap_s`` applies: on the 18 held-out generated scenes tracked
        without their map (MCMC seeds 0-2) this limit had cost HOTA/IDF1 0.017/0.038.
    turn_cost : float
        Extra cost of that manoeuvre hypothesis over a straight continuation, on top of
        ``log(1 + reach / sigma)`` for the spread of where a target with a free heading may
        re-appear (:func:`aerotrack.context.reacquire.motion_cost`). Measured with that term on
        generated scenes (gt-dets and detector, benchmarks/identity.py), UAVDT and Santiago: 0.5
        beat 1.0 and 2.0.
    min_track_s : float
        Final tracks (after linking) spanning less than this, first to last in-view point, are
        dropped as false alarms; 0 keeps every tracklet local association kept. Makes tracking
        blind to targets seen for less than this in the whole video.
    min_edge_track_s : float
        A track shorter than ``min_track_s`` is kept when it spans at least this long and the view
        cut it short: its first observed box lies within its own length of the frame's border or
        in the video's first frame, or its last one within its length of the border or in the
        video's last frame (``linking._cut_by_view``). A vehicle crossing a corner of the view, or
        entering as a moving camera pans, is seen for less than a second; a false alarm is as
        likely anywhere. Santiago (real, 1920x1080) cropped to 1600x900 and moved (pan, 4 degrees
        of rotation, 12% zoom) HOTA/IDF1/MOTA 0.593/0.775/0.598 -> 0.607/0.800/0.643 (four
        vehicles that cross the view's edge were dropped); the static crop 0.634/0.840/0.669 ->
        0.639/0.850/0.687; the full clip (seeds 0-2) -0.002 HOTA, a vehicle leaving the view in
        frames 1-18 that its ground truth omits. 0 (or >= ``min_track_s``) turns it off.
    in_view_horizon_s : float
        A track's final prediction stops once its predicted position has been inside the frame
        this long (it should have been detected again: a lost or spurious track); outside the
        frame it runs to ``context.prediction_horizon_s``. Needs registrations (frames).
    partial_size_ratio : float
        A tracklet's end (start) points whose box's longer side is below this fraction of the
        tracklet's typical size were partly hidden (an occluder, the image edge): their centre and
        velocity are biased, so the end state is estimated without them. 0 keeps every point.
    partial_trim_s : float
        At most this much of each end is left out that way.
    partial_model : str
        ``"trim"``: partial boxes at a tracklet's ends are left out of its end state (above).
        ``"edge"``: with registrations, they are kept and moved to the whole target's centre, half
        its full extent from the box edge away from the occluder
        (``linking.partial_edge_positions``); without registrations, or standing still, trimmed.
        Measured with aerotrack's detector (tracklets of e5cc4a3, benchmarks/identity.py) against
        ``trim``: IDF1/HOTA 0.781/0.558 -> 0.793/0.565 on the 5 default generated scenes
        (re-acquisition unchanged), 0.716/0.551 -> 0.751/0.571 on 3 others (occlusion:2, exits:3,
        default:1; occlusions <= 4 s 6/19 -> 9/19); ground-truth detections, UAVDT (no
        registrations) unchanged, Santiago 0.6466/0.8465 -> 0.6469/0.8470. On the previous
        tracklets (before 7f6d6bc) it was neutral (+2/36, -1/19 occlusions). The moved points
        themselves are no closer to the truth (this detector shrinks a box about its centre as
        often as from the occluder's side); what helps is that the end is kept where the target
        was last seen, with the trailing edge's velocity. Only linking uses them: the output
        track keeps the observed positions. Box extents are compared in world units (each
        through its frame's registration): in frame pixels, a camera that descends or zooms made
        the early, smaller whole boxes of a long tracklet look partial (UAV123 truck4: a start
        moved 20 px back, and the truck's link across a 0.6 s gap refused; best-ID coverage
        0.553 -> 0.594 on MCMC seed 0, seeds 1-2 0.594 before and after).
    partial_raw_gap_s : float
        Links over a gap up to this long whose end boxes differ in size (one under
        ``partial_size_ratio`` of the other along the motion) are also scored on the ends as
        detected (not trimmed or moved as partial) and the cheaper cost is kept: nothing can have
        hidden the target in a gap of a frame or two, and a box that changes size across it (a
        detector that saw part of a vehicle, then all of it) is not a vehicle half behind an
        occluder. UAV123 truck4 with persistence: the truck's tracklet
        ended in 13 x 7.5 px boxes and the next began one frame later in 21 x 11 px ones; the
        partial-box model moved the first forward and the second back, 10.6 world units apart
        for a truck moving 1 a frame (motion cost 13.4, no link). 0 disables.
    partial_min_speed_mps : float
        The edge model needs the direction of motion: ends slower than this are trimmed instead.
    end_noise_scale : float
        The motion sigmas are widened by each tracklet's own end-state uncertainty: the scatter of
        its positions about a straight line over ``history_s`` (metres) and the resulting velocity
        uncertainty, times this factor. Detector boxes jitter far more than ground truth, and a
        prediction from a short, jittery tracklet should not veto a link. 0 turns it off.
    duplicate_overlap : float
        Two tracklets that coexist in time on the same object (a split blob: a partial fragment
        beside the whole vehicle, a second tracklet through a turn) overlap by at least this mean
        fraction of the smaller box (intersection over the smaller area, frame pixels) in their
        common frames. A tracklet lying within another's time span that way is merged into it; one
        that starts during it and outlives it may continue it (a hand-over link). Lower merges
        vehicles driving side by side; 1 turns both off.
    handover_max_s : float
        Longest time overlap of a hand-over link, seconds.
    handover_cost : float
        Link cost of a hand-over at the ``duplicate_overlap`` threshold, falling linearly to 0
        for boxes that overlap entirely.
    handover_max_area_ratio : float
        A hand-over needs the later tracklet's boxes, while both are seen, to be at most this many
        times the earlier one's (median): a box that holds the earlier vehicle's whole box and
        two more of its size is a blob of it merged with a neighbour, which the later tracklet
        may go on following (found on the identity scenes: a vehicle's identity went to the
        vehicle beside it, area ratio 3.75). 0: no limit. Measured (3 against no limit):
        identity benchmark, MCMC seeds 0-2, IDF1 0.826/0.832/0.813 -> 0.821/0.839/0.820, HOTA
        0.628/0.629/0.617 -> 0.631/0.636/0.623, ID switches 44 -> 42; Santiago, UAVDT, truck4 and
        the demo unchanged. 2 scored the same there but cut truck4's truck at a hand-over of
        ratio between 2 and 3 (best ID 0.59 -> 0.31).
    descriptor_max : float
        The tracklet-descriptor cost (KL distances, Yu & Medioni eqs. 13-14) is truncated here
        (:func:`aerotrack.context.reacquire.descriptor_cost`): partial and merged blobs make it
        unbounded for a vehicle's own tracklets. Lower lets the descriptor decide less (0: off);
        a large value (1e9) is the paper's untruncated distance.
    fill_sigma : float
        A tracklet unlinked on both sides that lies inside the gap of a link, its points within
        this many motion sigmas of the gap's path (median), is inserted into the chain
        (``GlobalLinker.fill_gaps``): the short pieces of partial boxes where a vehicle goes
        under an occluder or comes out. Higher inserts more, and a crossing vehicle's piece
        sooner; 0 turns it off. Measured against 0 (benchmarks/identity.py tracklets of
        a1835b6, 8 generated scenes): with aerotrack's detector occlusions <= 4 s re-acquired
        25/55 -> 26/55, IDF1 0.768 unchanged; ground-truth detections, Santiago (seeds 0-2)
        and UAVDT unchanged (few pieces survive local association's ``min_length_s``).
    rounds : int
        Linking rounds. After the first, every chain of linked tracklets is linked again as one
        tracklet (``GlobalLinker.relink``): a chain often ends in a short piece (partial boxes at
        an occluder, a hand-over) whose own motion and colours cannot reach the re-acquisition,
        while the whole chain's can. Only pairs where at least one side is a chain of several
        tracklets are new; rounds stop when nothing changes. 1 (or 0) is the single joint assignment.
        Measured 1 -> 2 (``benchmarks/identity.py``, own detector, MCMC seeds 0-2): IDF1
        0.821/0.839/0.820 -> 0.836/0.846/0.829, ID switches 17/12/13 -> 13/10/12, occlusions
        re-acquired 16/19/19 -> 19/20/20 of 31; six other scenes (default:1, default:3,
        occlusion:0, occlusion:2, exits:0, exits:4, seed 0) IDF1 0.734 -> 0.779, switches
        29 -> 20, occlusions 23 -> 27 of 51, exits 8 -> 9 of 15; ground-truth detections,
        Santiago (seeds 0-2), UAVDT and truck4 unchanged; 3 rounds = 2. One scene lost: the Dask
        benchmark's (480x270 at 15 fps, no map; seeds 0-4) HOTA/IDF1 0.508/0.622 -> 0.504/0.611,
        where the first round had already chained different vehicles and the second joins such
        chains further. Allowing only joins at a piece shorter than 1 s: that scene 0.505/0.617,
        the six other scenes 0.784 -> 0.772; not kept.
    split_gap_s : float
        Gaps up to this long are taken for splits of one track by local association (a vehicle
        pulling away from a stop or braking, which the constant-velocity filter cannot follow):
        the velocity gate of such a link spans both ends' velocity windows (2 ``history_s``)
        instead of one, when b starts within ``split_dist_m`` of where a's last point would be
        after the gap at a's speed and the appearance agrees (``split_max_appearance``).
        0 disables. Measured (0 -> 0.2 s): Santiago HOTA/IDF1/MOTA (seeds 0-2) 0.634/0.851/0.700
        -> 0.642/0.862/0.712 (a car pulling away from the light, split after 18 frames and its
        first piece lost, is kept whole); generated identity scenes (detector) IDF1 0.784 both,
        HOTA 0.599 -> 0.597, ID switches 18 -> 20; ground-truth detections, UAVDT and the demo
        scene identical. Without the appearance condition generated IDF1 fell to 0.772 (a
        false-alarm fragment right after a vehicle's tracklet taken for its continuation);
        0.5 s: 0.754.
    split_dist_m : float
        See ``split_gap_s``: less than a vehicle length, so that a neighbour in a queue starting
        right behind does not count as a split.
    stop_max_gap_s : float
        Longest wait a *stop link* may bridge, seconds: a vehicle that the detector loses as it
        brakes to a standstill (a motion detector's background absorbs it) and finds again as
        it pulls away, a red light or a queue later (``GlobalLinker._stop_cost`` in
        ``association/linking.py``). Both ends must be slow (``stop_max_speed_mps``), the second start ahead of
        the first end along the heading by about the distance covered braking and pulling away
        (``stop_decel_mps2``; ``stop_sigma_m``), in the same lane and heading (within
        ``stop_max_turn_deg``). Such a link is priced by that stop model alone: the gap's time
        in view is not charged (``gap_cost_per_s``: a standing vehicle is not expected to be
        detected) and ``max_gap_s`` does not apply; under ``max_gap_s`` the cheaper of the stop
        model and the ordinary cost counts. Only on registered frames (the ground; with
        ``--detections`` alone a standing vehicle and the camera's motion cannot be told
        apart). 0 disables.
    stop_max_speed_mps : float
        Both ends of a stop link are at most this fast (the first tracklet's end velocity and
        the second's start velocity, each fitted over the 0.4 s next to the gap).
    stop_decel_mps2 : float
        Braking and pulling-away acceleration of the stop model: with end speeds ``v_a`` and
        ``v_b`` the second tracklet is expected to start ``(v_a^2 + v_b^2) / (2 a)`` ahead.
    stop_sigma_m : float
        Spread of where the second tracklet starts, across the heading and along it (along it
        also half the expected distance).
    stop_max_turn_deg : float
        Largest change of heading across a stop link (a vehicle waiting to turn pulls away at an
        angle).
    split_max_appearance : float
        ... and a split's motion cost is only relaxed when the appearance context agrees (its
        cost at most this; unknown appearance counts as agreeing). A hand-over needs the same
        agreement: on 11 generated scenes (own detector) the 20 true hand-overs scored 0-0.09,
        a vehicle whose box covered another's while passing it 461 (the identity benchmark's
        five scenes unchanged; six others IDF1 0.779 -> 0.784, one switch less).
    gap_cost_per_s : float
        Cost added per second of a link's gap during which the first tracklet's predicted
        position lies inside the frame (nothing without registrations and frame size, e.g.
        ``--detections`` alone, where in view and out of it cannot be told apart): a target in
        view should be detected again, so the longer it would have stayed unseen there, the less
        likely the link; time outside the view (an exit) costs nothing. Without it the manoeuvre
        hypothesis prices any tracklet within reach of a long gap at about ``turn_cost + log(1 +
        reach / sigma)`` ~ 3, and a look-alike seen 10 s earlier beat a 1 s link whose ends
        disagreed by a few metres. Measured (benchmarks/identity.py, 5 generated scenes, tracklets
        of the built-in detector; 0 -> 0.3 / 0.6 / 1.0): IDF1 0.778 -> 0.783 / 0.784 / 0.766, ID
        switches 30 -> 22 / 18 / 20, occlusions <= 4 s re-acquired 15 -> 16 / 17 / 16 of 31,
        exits 4/7 throughout; with ground-truth detections unchanged up to 0.6 (IDF1 0.964,
        30/31), 1.0 lost occlusions (28/31). The demo scene at 0.6: IDF1 0.803 -> 0.826, HOTA
        0.624 -> 0.633, 3 -> 1 ID switches; Santiago identical (seeds 0-2); UAVDT (no
        registrations) identical. Charging every second of the gap instead (exits too) lost a
        returning vehicle's identity to a look-alike that had just left (tests/test_linking.py).
    gap_cost_entry : bool
        Charge ``gap_cost_per_s`` also for the time the second tracklet would have spent in view
        on its way in (its start run back at its start velocity to the frame's edge, when that
        is within the gap), the larger of the two counting: a target that left the view and
        came back had to drive in unseen. Measured (2026-12-03, relinking the cached stages):
        18 held-out generated scenes HOTA/IDF1 0.721/0.868 -> 0.722/0.871, ID switches 43 ->
        40 (static:11 0.562/0.728 -> 0.585/0.790, convoy:11 0.645/0.795 -> 0.656/0.843;
        default:21 0.624/0.788 -> 0.610/0.738: two more true links there left a look-alike's
        wrong one to decide the majority ID); identity benchmark (both detector modes),
        Santiago (seeds 0-2) and the demo identical.
        0 disables.
    appearance_max : float
        The appearance-context cost (intra-class distance and failed verification, Ali et al. 4.3)
        is truncated here (:func:`aerotrack.context.reacquire.appearance_cost`): a vehicle's own
        tracklets score up to ~1000 when one is a mixed or partial-box tracklet, which vetoes the
        link whatever motion says. Below ``max_cost`` minus the other cues' caps the cue ranks
        candidates but cannot veto alone; lower lets appearance decide less (0: off), 1e9 is the
        untruncated cost. Generated scenes with aerotrack's detector (5 default): IDF1/HOTA
        0.778/0.586 -> 0.792/0.599 at 3 (2 to 4 alike); other datasets unchanged.
    """

    max_gap_s: float = 60.0
    v_max_mps: float = 40.0
    a_max_mps2: float = 6.0
    gate_slack_m: float = 3.0
    speed_slack_mps: float = 3.0
    motion_sigma_m: float = 0.7
    motion_sigma_growth_mps: float = 0.7
    velocity_sigma_mps: float = 1.0
    velocity_sigma_growth_mps2: float = 0.5
    weight_motion: float = 1.0
    weight_appearance: float = 1.0
    weight_descriptor: float = 0.5
    max_cost: float = 6.0
    min_tracklet_s: float = 1.0
    predict_gaps: bool = True
    lag_sigma_growth_mps: float = 6.0
    turn_max_gap_s: float = 12.0
    turn_max_gap_image_s: float = 1.5
    turn_a_max_mps2: float = 10.0
    turn_cost: float = 0.5
    in_view_horizon_s: float = 4.0
    min_track_s: float = 1.0
    min_edge_track_s: float = 0.4
    end_noise_scale: float = 1.0
    partial_size_ratio: float = 0.8
    partial_trim_s: float = 1.0
    partial_model: str = "edge"
    partial_min_speed_mps: float = 1.0
    partial_raw_gap_s: float = 0.2
    duplicate_overlap: float = 0.5
    handover_max_s: float = 2.0
    handover_cost: float = 1.0
    handover_max_area_ratio: float = 3.0
    descriptor_max: float = 3.0
    fill_sigma: float = 3.0
    rounds: int = 2
    appearance_max: float = 3.0
    gap_cost_per_s: float = 0.6
    gap_cost_entry: bool = True
    split_gap_s: float = 0.2
    split_dist_m: float = 1.5
    split_max_appearance: float = 1.0
    stop_max_gap_s: float = 300.0
    stop_max_speed_mps: float = 6.0
    stop_decel_mps2: float = 2.0
    stop_sigma_m: float = 1.0
    stop_max_turn_deg: float = 60.0


@dataclass(frozen=True)
class ContextConfig:
    """Motion and appearance contexts (Ali, Reilly & Shah section 4).

    Attributes
    ----------
    history_s : float
        Seconds of a target's last observations matched against other tracks (the paper's F).
    prediction_horizon_s : float
        How long an unobserved target's position is predicted into ``predicted.csv``.
    method : str
        Motion predictor: ``context`` (aerotrack's path following, default), ``paper`` (Ali et al.
        as written), ``kalman`` or ``constant-velocity``.
    lce_alpha : float
        ``paper``: LCE threshold (eq. 1) below which a track section becomes a predictor. Raising it
        admits more (and less similar) predictors.
    min_predictors : int
        ``paper``: the regression needs at least this many predictors (3 unknown pairs).
    regression_cond : float
        ``paper``: the regression is refused (Kalman fallback) when the smaller eigenvalue of S(0)
        is below this fraction of the larger: predictors nearly on a line leave the affine map
        undetermined across it and amplify their noise.
    path_radius_m : float
        ``context``: other tracks' rows within this distance of the predicted position form the
        local flow. Larger finds more support but mixes neighbouring lanes.
    path_heading_deg : float
        ``context``: rows whose heading differs from the target's by more than this are ignored
        (opposite lane, crossing traffic). Too small and the target cannot follow a curve.
    path_match_m : float
        ``context``: a predictor's path must pass the target's last F positions at a mean distance
        of about this (weight ``exp(-d^2 / 2 path_match_m^2)``, cut at twice it). Smaller picks
        only predictors on the very same line; larger averages over neighbouring lanes and exits.
    path_noise_m : float
        ``context``: error of a path-following prediction from one perfectly matched predictor,
        metres; it is fused with the Kalman prediction by inverse variance (with the predictors'
        spread and match distance added). Raising it trusts other objects' paths less.
    path_chord_s : float
        ``context``: predictors' paths are walked as chords between rows this many seconds apart
        (arc length over every jittery row is longer than the distance actually covered).
    path_speed_ratio : float
        ``context``: predictors must move at between 1/ratio and ratio times the target's speed
        where they pass it (objects that move alike, the paper's criterion). Larger admits walkers
        beside cars; smaller finds fewer predictors.
    group_radius_m : float
        ``context``: tracks seen at ``last_seen`` within this distance may be co-movers (a queue,
        a convoy), whose displacement while the target is hidden is observed.
    group_match_m : float
        ``context``: co-movers' last F frames, start-normalised, differ from the target's by at
        most this RMS distance. Larger admits more co-movers that move less alike.
    group_noise_m : float
        ``context``: error of one co-mover's displacement as a prediction, metres (fused by
        inverse variance with the Kalman and path estimates).
    flow_radius_m : float
        ``context``: the learned road (the local flow of earlier objects). Their rows within this
        distance of the target (heading within ``flow_heading_deg``) give a target with a short
        history its likely velocity, and with ``flow_follow`` they steer the prediction. 0
        disables both. Larger finds more support but mixes neighbouring lanes.
    flow_heading_deg : float
        ``context``: flow rows whose heading differs from the predicted heading by more than this
        are ignored (opposite lane, crossing traffic, the other branch of a fork).
    flow_follow : bool
        ``context``: turn the prediction as the local flow turns
        (:func:`~aerotrack.context.paths.follow_flow`). Off by default: measured on SDD and on
        generated scenes it gained nothing over path following (SDD straight windows lost 1-4%).
    flow_prior_weight : float
        ``context``, ``flow_follow``: support (sum of row weights) at which the flow's turn is half
        believed. Raising it follows the road only where many earlier objects passed.
    flow_step_s : float
        ``context``, ``flow_follow``: seconds between heading updates along the learned road.
    flow_velocity_std_mps : float
        ``context``: least uncertainty of the flow's velocity used as a prior for the target's own
        (fused by their covariances: only a target with a short history takes the flow's speed).
        Raising it trusts the target's short history more.
    min_speed_mps : float
        ``context``: slower rows (standing objects) carry no heading and are no path predictors; a
        slower target gets no path estimate (co-movers still apply).
    path_sample_s : float
        ``context``: other tracks' rows are sampled every this many seconds (speed vs density).
    velocity_lag_s : float
        ``context``: a row's velocity is its backward difference over this many seconds.
    kalman_accel_mps2 : float
        Process noise of the constant-velocity Kalman filter (white acceleration), m/s^2.
    kalman_meas_std_m : float
        Measurement noise of the Kalman filter, metres.
    kalman_vel_std_mps : float
        Prior spread of a target's velocity when the filter starts, m/s (zero mean). It decides
        what a target seen for a frame or two is taken to do: smaller shrinks its speed towards
        standing still. 5 m/s put 95% of the prior under 10 m/s, which halved the speed of
        vehicles glimpsed at the start of a video; 15 m/s spans road traffic. Measured (5 -> 15):
        generated scenes, MPE at 2 s into every gap, Kalman 2.19 -> 2.08 m, context with roads
        1.37 -> 1.27 m (0.63x -> 0.61x the Kalman filter); SDD, ETH/UCY, the identity benchmark
        (seeds 0-2), Santiago and UAVDT unchanged (to 0.001).
    image_object_size_m : float
        With no map and no ``--gsd`` (``aerotrack track`` and ``aerotrack predict`` on image
        coordinates): the median box's longer side is taken to be this many metres (a car), which
        sets the scale of linking's and finishing's metre-based settings (a too-small value
        makes every vehicle "too small" for ``finish.min_size_estimated_m``: no track).
    roads_snap_m : float
        ``context`` with a road network (``--roads``): centre-line ends and crossings closer than
        this become one junction (:class:`~aerotrack.context.roads.RoadNetwork`). Larger joins
        roads digitised with gaps but may fuse close parallel carriageways.
    road_snap_m : float
        ``context`` with roads: a target further than this from every centre-line is off-road (the
        prediction is then what it is without roads). Raise it for wide multi-lane roads.
    road_heading_deg : float
        ``context`` with roads: the target's heading must agree with the centre-line's (either
        direction) within this angle to snap to it.
    road_lane_m : float
        ``context`` with roads: the target's lateral offset from the centre-line up to this is its
        lane and is kept along the road (turns and U-turns included); any excess decays.
    road_offset_tau_s : float
        ``context`` with roads: time constant of the decay of the lateral offset beyond
        ``road_lane_m`` (a target drifting back into its lane).
    road_uturn_s : float
        ``context`` with roads: time a U-turn at a dead end costs (slowing down, turning).
    road_vote_radius_m : float
        ``context`` with roads: at a junction, earlier objects that passed within this distance of
        the target's approach (same heading) vote for the branch they took (the learned road);
        without votes the straightest branch is taken. Larger finds more voters but mixes lanes.
    road_turn_speed_mps, road_turn_decel_mps2, road_turn_accel_mps2 : float
        ``context`` with roads: a target predicted to turn at a junction by more than 45 degrees
        brakes at ``road_turn_decel_mps2`` to ``road_turn_speed_mps`` at the junction and speeds
        up again at ``road_turn_accel_mps2`` after it. ``road_turn_speed_mps`` or ``road_turn_decel_mps2``
        0 keeps the speed.
        5 m/s is an urban right-angle turn (not the generator's 3 m/s): on the generated scenes
        (``benchmarks/prediction.py --synth``) the 2 s error of ``context`` with roads relative
        to the Kalman filter went 0.71x -> 0.68x (scenes with exits 0.68x -> 0.62x), the 1 s
        error unchanged; 3 m/s gave 0.67x at 2 s but worse at 1 s on exits (0.85x). Identity
        benchmark unchanged (IDF1 0.784).
    road_hedge : str
        ``context`` with roads: how one prediction is made of the routes through the junctions
        within reach, each weighted by its probability (:func:`~aerotrack.context.roads.hedge`):
        ``median`` (default) the weighted geometric median per frame, the point of least expected
        distance; ``mean`` the weighted mean (least expected squared distance); ``none`` the most
        likely route (winner takes all). The median leaves the likeliest branch only when no
        branch has about half the weight (of two branches it is the heavier one; at a tie the
        midpoint is taken). Generated scenes (``benchmarks/prediction.py --synth``, 22 scenes, a
        choice the papers do not make), MPE ratio to the Kalman filter at 1 / 2 / 4 s over all
        gaps: ``none`` 0.607 / 0.677 / 0.973, ``median`` 0.632 / 0.627 / 0.834, ``mean``
        0.634 / 0.626 / 0.834 (with ``--fragment``: ``none`` 0.60 / 0.76 / 0.97, ``median``
        0.65 / 0.68 / 0.83). The gain comes from about a dozen of the 117 gaps at 2 s (two
        branches, no earlier vehicle from that approach, so a tie); hedging costs a little at 1 s,
        where a vehicle right at a junction is put between its branches. The median is the
        default although the mean scores alike: with a majority branch its prediction stays on
        that road (what ``predicted.csv`` and the map pictures show), the mean's never does.
    road_vote_prior : float
        ``context`` with roads: at a junction the probability of each way on is
        ``(votes + a * prior) / (sum(votes) + a)`` with ``a`` this (the prior's worth in earlier
        vehicles' votes, :func:`~aerotrack.context.roads.branch_probabilities`). Larger trusts a
        few voters less. 0.5, 1, 2 and 4 gave the same 2 s error on the generated scenes (few
        gaps have voters at a junction).
    road_straight_kappa : float
        ``context`` with roads: the prior over the ways on at a junction is proportional to
        ``exp(kappa cos(turn angle))``: 0 (default) uniform, larger favours straight on. On the
        generated scenes, of the 10 gaps at 2 s before a two-way junction with no voter, 5 were
        nearer straight on and 5 nearer the turn, so the data do not support favouring straight
        on (the generator's own rate is not assumed): with any ``kappa`` > 0 straight on has
        most of the weight and the median is the straight route (2 s: 0.677 as with ``none``;
        ``mean``: 0.626 / 0.626 / 0.628 for ``kappa`` 0 / 0.25 / 0.5).
    road_glimpse_frames, road_traffic_side, road_lane_min_m, road_glimpse_speed_mps
        ``context`` with roads: a target seen in fewer than ``road_glimpse_frames`` frames of its
        last ``history_s`` has no velocity to speak of (a glimpse: the first frames of a video, a
        vehicle seen between two occluders). Vehicles keep to one side of the road
        (``road_traffic_side``: ``right``, ``left``, or ``auto``, the side most of the other
        objects moving in the last second keep to, right until three of them are on a road): one
        at least ``road_lane_min_m`` off the nearest centre-line (within ``road_snap_m``) drives
        along it in the direction that puts it on that side, at the median speed of those
        objects, or ``road_glimpse_speed_mps`` before any. ``road_glimpse_frames`` 0 disables.
    """

    history_s: float = 1.0
    prediction_horizon_s: float = 10.0
    method: str = "context"
    lce_alpha: float = 0.05
    min_predictors: int = 3
    regression_cond: float = 1e-2
    path_radius_m: float = 2.0
    path_heading_deg: float = 45.0
    path_match_m: float = 1.0
    path_noise_m: float = 3.0
    path_chord_s: float = 0.5
    path_speed_ratio: float = 1.5
    group_radius_m: float = 20.0
    group_match_m: float = 0.3
    group_noise_m: float = 4.0
    flow_radius_m: float = 3.0
    flow_heading_deg: float = 45.0
    flow_follow: bool = False
    flow_prior_weight: float = 5.0
    flow_step_s: float = 0.2
    flow_velocity_std_mps: float = 2.0
    min_speed_mps: float = 0.3
    path_sample_s: float = 0.3
    velocity_lag_s: float = 0.5
    kalman_accel_mps2: float = 3.0
    kalman_meas_std_m: float = 0.1
    kalman_vel_std_mps: float = 15.0
    image_object_size_m: float = 4.5
    roads_snap_m: float = 5.0
    road_snap_m: float = 6.0
    road_heading_deg: float = 40.0
    road_lane_m: float = 4.0
    road_offset_tau_s: float = 1.0
    road_uturn_s: float = 1.0
    road_vote_radius_m: float = 4.0
    road_turn_speed_mps: float = 5.0
    road_turn_decel_mps2: float = 3.0
    road_turn_accel_mps2: float = 2.5
    road_hedge: str = "median"
    road_vote_prior: float = 1.0
    road_straight_kappa: float = 0.0
    road_glimpse_frames: int = 3
    road_traffic_side: str = "auto"
    road_lane_min_m: float = 0.5
    road_glimpse_speed_mps: float = 8.0


@dataclass(frozen=True)
class FinishConfig:
    """What ``tracks.csv`` reports for each final track (:mod:`aerotrack.association.finish`).

    Applied after global linking: each track's in-view positions are smoothed offline, its box
    is rebuilt from one robust vehicle size, and tracks that never move are dropped.

    Attributes
    ----------
    enabled : bool
        False reports the tracks exactly as linking made them (detection boxes).
    smooth : bool
        Replace each in-view point's ground point by the Rauch-Tung-Striebel smoothed state of the
        constant-velocity Kalman filter (:mod:`aerotrack.kalman`), world coordinates.
    accel_std_mps2 : float
        Smoother's white-noise acceleration. Lower smooths jitter harder but cuts corners on turns
        and lags on braking.
    pos_std_m, pos_frac : float
        Smoother's observation noise: metres, plus a fraction of the box size.
    outlier_chi2 : float
        Observations whose squared Mahalanobis residual (2 dof) against the smoothed path exceeds
        this are down-weighted (their noise scaled by residual / threshold) and the track
        smoothed again: partial, merged and shifted blobs pull the path less. Lower rejects more.
    robust_iters : int
        Re-weighting passes.
    size_outlier_ratio : float
        An observed box whose area is over this factor above or below the vehicle's size at that
        time (the ``size_mode`` size) is a merged blob or a fragment, and its centre is off the
        vehicle's by up to half the difference: the track is smoothed once more with such
        centres' noise variance raised 25-fold (they still count where nothing else is seen).
        0 disables. Found on generated scenes where a car's detection switched frame by frame
        between its own box and one merged with the car beside it: the smoothed centre sat 2 px
        towards the neighbour even in the frames whose box was exact. Measured 0 -> 1.2 with
        the same detections and links (so no MCMC noise): 18 held-out generated scenes
        HOTA/IDF1 0.6998/0.8576 -> 0.7079/0.8611 (DetA 0.683 -> 0.691, LocA 0.852 -> 0.857;
        every scene gained, +0.003 to +0.015), Santiago (MCMC seeds 0-2) 0.6662/0.8866 ->
        0.6671/0.8897, UAVDT through the CLI (no registrations, size jitter only)
        0.7547/0.8132 -> 0.7539/0.8128, truck4 unchanged. 1.1 / 1.3 / 1.5 / 2 gave 0.7078 /
        0.7069 / 0.7054 / 0.7025 on the generated scenes; smoothing every centre harder instead
        (``pos_std_m`` 0.6) lost (0.6965). Taking a merged box's centre from its edge on the
        smoothed path's side instead of down-weighting it scored the same.
    size_mode : str
        ``oriented``: one vehicle length and width per track (a quantile of per-observation
        estimates), drawn as the box of the footprint at the smoothed heading through each
        frame's homography (turns and camera rotation change the box, the vehicle does not);
        ``window``: per axis, a quantile of the frame boxes (normalised by the local image scale)
        within ``size_window_s``; ``detection``: each point keeps its own box size;
        ``auto``: ``oriented`` when frames are registered (headings mean something on the
        ground), else ``window``. Measured (benchmarks/finish.py): ``window`` helped on all four
        sources; ``oriented`` scored higher on Santiago and generated scenes with the detector
        (+0.006 HOTA) but lower with noisy ground-truth detections (-0.022) and on small, bloated
        blobs, and is useless in image coordinates of a moving camera (UAVDT -0.23).
    size_quantile : float
        Quantile of the per-observation sizes. Above 0.5 leans towards full views of the vehicle
        (partial blobs are smaller); too high takes merged blobs.
    size_window_s : float
        ``window`` mode: width of the time window on registered frames (sizes normalised by each
        frame's scale, so zoom and range do not change them). 1 -> 2 s, with ``size_turn_deg``
        20 and the same detections and links: 18 held-out generated scenes HOTA/IDF1
        0.7079/0.8611 -> 0.7166/0.8673 (LocA 0.857 -> 0.859, DetA 0.691 -> 0.699), Santiago
        (seed 0) 0.6659/0.8878 -> 0.6694/0.8911; 2 s without the turn test 0.7134 / 0.6674;
        1.5 / 2.5 / 3 / 5 s with it 0.7134 / 0.7169 / 0.7173 / 0.7156 on the generated scenes
        but 0.6686 / 0.6672 / 0.6603 / 0.6622 on Santiago (queued cars half absorbed).
    size_window_image_s : float
        The same without registrations (``--detections`` alone: image coordinates of a moving
        camera, where a vehicle's size changes with range): 2 s cost UAVDT 0.007 HOTA (0.7539 ->
        0.7466), so 1 s.
    size_turn_deg : float
        ``window`` mode on registered frames: a point's size pools only the observations whose
        smoothed heading is within this angle of its own (modulo 180 degrees; all of them when
        none is): across a turn a vehicle's box changes its aspect, and a window spanning the
        turn boxed it as a square. 0 disables. 0 -> 20 with a 1 s window: generated scenes
        0.7079 -> 0.7088, Santiago 0.6659 -> 0.6673; 10 / 30 degrees 0.7081 / 0.7083. Where the
        smoothed speed is under ``min_heading_speed_mps`` a point has no heading and pools with
        every other (carrying the nearest heading instead: 0.7166 / 0.6694 against 0.7167 /
        0.6695). Classes of the boxes' own aspect (wider or taller by 1.3 or 1.6) instead of
        headings: 0.7154 / 0.6664 and 0.7143 / 0.6676.
    min_heading_speed_mps : float
        Headings are taken from the smoothed velocity where the speed exceeds this, else carried
        from the nearest such point.
    default_aspect : float
        Width / length of a vehicle when a track never shows it (always diagonal to the axes).
    edge_margin_px : float
        An observed box within this many pixels of the frame border is partly outside the frame:
        it gives no size, and its centre is rebuilt from its inner edges and the track's size.
    clip_to_frame : bool
        Clip reported boxes to the frame. Off: ground truths (generated scenes, Santiago) draw the
        whole vehicle past the border, and clipping cost 0.014 HOTA on generated scenes.
    centre_out_of_view : bool
        A point whose whole-vehicle box has its centre outside the frame (more than half the
        vehicle past the border) is out of view: it goes to ``predicted.csv``, not ``tracks.csv``
        (the contract: a target's ground point is its box's centre, and tracks.csv holds the
        frames it is believed in view). Ground truths do not score such a vehicle as one whole
        box: generated scenes call it outside, and truth that clips boxes to the image (UAVDT,
        VisDrone, Santiago's exits) keeps a sliver no whole box matches at IoU 0.5. On the 18
        held-out generated scenes it removed 189 of 4527 false positives for 19 more misses
        (HOTA +0.002, MOTA +0.003); Santiago unchanged. Off: such rows stay in tracks.csv.
    static_extent_m : float
        Tracks whose smoothed ground points all lie within a box of this diagonal (metres) never
        moved: a parked vehicle, a road marking, a registration artefact, not a target. 0 keeps
        them. A vehicle that waits and then drives has a long extent and is kept. Applied only on
        registered frames (in the image of a moving camera a vehicle driving with it stands
        still). Raising it drops slow crawlers seen only briefly; 4 m (about a car length)
        and 6 m dropped the same tracks on Santiago, 2.5 m fewer.
    static_speed_mps : float
        A track counts as standing still only if its extent is also under this speed times the
        time it was seen: one seen for a moment (a short clip) has not had the time to cover
        ``static_extent_m``. 0 leaves the extent alone. 3 m/s (11 km/h): on a 20-frame
        generated clip (0.67 s, cars at 3.4-10 m/s) 13 -> 35 of 80 boxes matched; Santiago's
        tracks unchanged (2 m/s kept a creeping car the ground truth leaves out: HOTA -0.003).
    wander_extent_m, wander_path_ratio, wander_step_s : float
        A track whose smoothed ground points stay within a box of ``wander_extent_m`` diagonal
        while the path through them, sampled every ``wander_step_s``, is more than
        ``wander_path_ratio`` x that diagonal went back and forth over a few metres: not a
        vehicle but the parallax of something tall (a tree's or a wall's edge sweeping over the
        ground as the camera moves), and it is dropped. 0 (either) keeps them. Vehicles drive
        on: of the tracks with an extent under 10 m, the 4 others on the 18 held-out generated
        scenes (3 of them on vehicles) and the one on Santiago have a ratio of 1.00 (path along
        the reported positions, unsampled), while the three tracks convoy:21 made on a wall
        beside a tree (moving camera) have 2.6-3.3 at 5.7-6.8 m, and a vehicle's U-turn goes
        back only once (2). Sampling at 0.5 s keeps a waiting vehicle's residual jitter out of
        the path. Registered frames only.
        Measured (held-out scenes, ``benchmarks/scenarios.py``): HOTA/IDF1/MOTA
        0.692/0.848/0.781 -> 0.697/0.856/0.800 (convoy:21 alone changed, 0.657/0.786/0.500 ->
        0.748/0.918/0.837); Santiago (seeds 0-2), the identity scenes, the demo and truck4
        unchanged.
    min_size_m : float
        Tracks whose typical footprint (median over fully visible observations of the square
        root of width x height, metres) is smaller than this are not vehicles (pedestrians, a
        fragment of a parked car) and are dropped; 0 keeps them. Applied only on registered
        frames, like ``static_extent_m`` (in the image of an oblique moving camera the size
        changes with the range). 1.5 m is about the detector's own gate (``detection
        .min_area_m2`` 2 m^2): a track whose typical box is that small is made of blobs at the
        limit of detection. Measured (mean of seeds 0-2, HOTA / IDF1): Santiago with the
        detections of commit 7b6f1ea 0.632 / 0.825 -> 0.648 / 0.850 (a walking pedestrian and a
        fragment of a car dropped; 1.5 to 2.3 m drop the same tracks), with the reworked
        detector unchanged (no track that small); generated scenes default:0, convoy:1,
        convoy:2 and UAVDT (no registered frames) unchanged.
    min_size_estimated_m : float
        ``min_size_m`` for a scale estimated from the objects themselves (no map, no ``--gsd``:
        the median object's longer side is ``context.image_object_size_m``, 4.5 m), where a
        size in metres is really a fraction of the typical object. Measured (2026-11-27):
        Santiago kept a small mover on the median (a pedestrian or cyclist) for 85 frames with
        MCMC seed 0 (1.8-2.0 m at that scale; seeds 1 and 2 never made it a track): at 2.0
        HOTA / IDF1 / MOTA 0.656 / 0.872 / 0.727 -> 0.665 / 0.885 / 0.760, seeds 1-2 and truck4
        unchanged; ``benchmarks/moved_santiago.py`` (seeds 0-2) better in all four variants, e.g.
        the moving 1600x900 crop 0.608 / 0.806 / 0.657 -> 0.612 / 0.813 / 0.675. Santiago's
        vehicles start to be dropped between 2.6 and 3.0 (3.0: 0.622 / 0.811 / 0.632). With a
        known scale ``min_size_m`` stays 1.5: a small car (2.7 x 1.7 m) is 2.1 m, and a tight
        box makes it less.
    regain_gap_s : float
        Inside a linked track's gaps up to this long, a detection lying on the track's path
        (interpolated between the sightings either side) that no other track holds becomes an
        observation of it (:mod:`aerotrack.association.regain`): local association had left it
        out (a run too short for a tracklet). 0 turns it off, as does ``enabled`` false.
        Raising it claims detections across longer gaps, where a straight path between two
        sightings is a worse guess. ``links.csv`` keeps the linked gap as linking made it.
    regain_end_s : float
        Past a track's last in-view frame (and before its first) when that frame is observed,
        for up to this long, the track is carried on at the velocity fitted to its last (first)
        observations (up to five, without a gap), frame by frame over the frames the run
        processed, each claim the new start, claiming free detections on that path until a frame
        has none. 0 turns it off, as does ``enabled`` false. A detection is free when no other
        track's in-view box of that frame is on it (IoU > 0.3).
    regain_iou : float
        IoU a detection needs with the interpolated box to be claimed (0-1). Lower claims more,
        and risks taking a neighbour's detection.
    fill_gaps_s : float
        Gaps between linked tracklets up to this long are reported in ``tracks.csv`` as
        ``bridged`` (smoothed through) instead of ``predicted``, as local association reports the
        misses it bridges inside a tracklet. 0 keeps them in ``predicted.csv``. Measured: 0.5 s
        and 1.2 s alike, +0.002-0.004 IDF1 on generated scenes and UAVDT, Santiago unchanged.
    stop_hold_s : float
        A vehicle whose track ends standing still (it stopped and the detector's background
        absorbed it) is reported ``stationary`` at its stop for up to this long, until another
        track is seen there (:func:`aerotrack.association.finish.hold_stops`; registered frames
        only). Longer keeps vehicles through long red lights, but a vehicle that drives off
        unseen, or a false alarm that moved and stopped, is reported for that long. 0 disables.
        Measured (mean of seeds 0-2 on Santiago, seed 0 on generated scenes default:0, dense:1,
        convoy:2 and two scenes with a stop at most junctions): no track of them ends standing
        (the detector's ``hold_stopped`` keeps standing vehicles; it loses them earlier, while
        they still creep at 2-4 m/s), so 30 s and 0 scored the same. Off by default since
        2026-11-26: the holds that did happen were false, a track whose last second sat still
        for another reason held for the full 30 s (a vehicle driving under a tree canopy left
        its track on the canopy's edge: 475 false rows on a generated 1800-frame scene, MOTA
        0.683 -> 0.569 from a one-feature change of the registration; convoy:12 HOTA/MOTA
        0.711/0.788 at 30 s, 0.760/0.896 at 0). Measured 30 -> 0 s: eighteen held-out scenes
        (yielding traffic) HOTA/IDF1/MOTA 0.681/0.835/0.765 -> 0.684/0.838/0.771; identity
        scenes (detector and ground-truth detections), Santiago seeds 0-2 and UAVDT unchanged.
        Standing vehicles are kept by the detector (``detection.hold_stopped``); this is for
        footage where it loses them standing (30 s is a red light's order of magnitude).
    stop_hold_back_s : float
        The same backwards from a track's start: a vehicle that stood from before its first
        detection and then drove off. 0 disables. Measured: on Santiago it held only the
        start of a vehicle the ground truth does not annotate (-0.001 HOTA, -0.0014 IDF1), no
        effect on the generated scenes: off by default.
    stop_speed_mps : float
        A track stands still at its end (start) when the least-squares speed of its observations
        in the last (first) ``stop_window_s`` is below this. Higher also holds vehicles lost
        while creeping, and whatever ends slowly: measured 3 m/s -> convoy:2 HOTA/MOTA
        0.561/0.518 -> 0.489/0.216, Santiago 0.636 -> 0.635, the two stop scenes -0.01 to -0.04
        HOTA (held in the wrong place or held false tracks); 5 m/s worse on every source.
    stop_decel_mps2 : float
        A held vehicle brakes from its end speed at this deceleration to its stop (only matters
        with a larger ``stop_speed_mps``).
    stop_radius_m : float
        A gap between two observations of a track closer than this (ground, metres), entered or
        left standing, is a stop and is reported ``stationary``; another track seen this close to
        a held stop ends the hold, and skips a stop-and-go point (``stop_gap_speed_mps``; with
        0 none is skipped). 0 with both holds and ``stop_gap_speed_mps`` 0 disables all of it.
    stop_window_s : float
        Observations at a track's end (start) that give its speed and its stop's position and
        box (``size_quantile`` of their sizes). Longer is steadier, shorter reacts to a stop
        that was short before the detector lost it.
    stop_gap_speed_mps : float
        A gap of at least one second between two observations of a track (a linked gap, or
        one inside a tracklet) over which the vehicle moved on average no faster than this is
        a stop: the detector lost the vehicle while it braked and found it again while it
        pulled away, so neither end need stand still nor lie within ``stop_radius_m`` of the
        other. The gap is reported ``stationary`` along a stop-and-go path between the two
        observations (braking, standing, pulling away), but not in frames where another track
        is seen at that point or the point is out of the frame. Both ends must be inside the
        frame and the track seen driving on both sides (the 3 s of observations before and after
        spread over half ``static_extent_m``, one side over all of it). The filled boxes take
        the ends' sizes: a vehicle that turned while it stood has them turned. 0 disables (then
        only the ``stop_radius_m`` rule fills gaps).
    stop_run_gap_s : float
        A track's end (start) is held only when the run of observations leading into its stop
        (away from it), consecutive ones at most this far apart, spread over at least
        ``static_extent_m``: the vehicle was seen driving into the stop. The whole track's spread
        is not enough: linking may join two pieces of a never-moving false alarm (the parallax of
        a tree canopy's edge, which creeps as the camera moves) into a track that "moved" and
        then "stopped", and such a track was held for ``stop_hold_s`` (generated convoy:5: 417
        false rows against 464 true ones). 1.2 s is local association's ``max_gap_s``; 0
        measures the whole track.
    max_overlap : float
        Two tracks' in-view boxes in one frame that overlap by more than this fraction of the
        smaller box are one object seen twice (seen from above, vehicles do not overlap): the
        weaker point (bridged or held before observed, then the track with fewer observations)
        is removed (:func:`aerotrack.association.finish.suppress_overlaps`). It catches a
        fragment's tracklet kept alive by bridging beside the whole vehicle's (a long truck
        the detector splits now and then). Registered frames only (in an oblique camera's image
        vehicles do overlap). 1 disables. Measured against 1: identity benchmark (5 generated
        scenes) IDF1 0.784 -> 0.800, HOTA 0.597 -> 0.609, ID switches 20 -> 20 (local
        association alone 0.569 -> 0.598); Santiago seeds 0-2 HOTA 0.642 -> 0.643, IDF1
        0.862 -> 0.863, MOTA 0.712 -> 0.723.
    absorbed_ratio, absorbed_speed : float
        A vehicle that creeps or waits is half absorbed by the background window and detected as
        a fragment (issue 4.3): on registered frames, where a track moves slower than
        ``absorbed_speed`` of its own sizes per second (the square root of its median box area
        while faster: no metre scale needed) and its window size's area falls under
        ``absorbed_ratio`` of that moving area, it keeps the size of its other observations
        (``TrackFinisher._unabsorbed``). 0 disables. Measured (2026-11-26) 0 -> 0.6 / 1.5: Santiago
        seeds 0-2 HOTA 0.647/0.650/0.654 -> 0.650/0.654/0.658, IDF1 0.871 -> 0.876, MOTA 0.728 ->
        0.739 (the queued GT 24 at IoU 0.22 -> 0.47-0.61 while it creeps; the same for ratios
        0.5-0.7 and speeds 1-2 sizes/s); identity benchmark, truck4 unchanged. Not applied
        without registrations (``--detections`` without frames: speeds in a moving camera's
        image say nothing of the ground; on UAVDT it cost 0.05 HOTA).
    """

    enabled: bool = True
    smooth: bool = True
    accel_std_mps2: float = 2.0
    pos_std_m: float = 0.3
    pos_frac: float = 0.05
    outlier_chi2: float = 9.0
    robust_iters: int = 2
    size_outlier_ratio: float = 1.2
    size_mode: str = "window"
    size_quantile: float = 0.5
    size_window_s: float = 2.0
    size_window_image_s: float = 1.0
    size_turn_deg: float = 20.0
    min_heading_speed_mps: float = 1.0
    default_aspect: float = 0.45
    edge_margin_px: float = 1.0
    clip_to_frame: bool = False
    centre_out_of_view: bool = True
    static_extent_m: float = 4.0
    static_speed_mps: float = 3.0
    wander_extent_m: float = 10.0
    wander_path_ratio: float = 2.0
    wander_step_s: float = 0.5
    min_size_m: float = 1.5
    min_size_estimated_m: float = 2.0
    regain_gap_s: float = 8.0
    regain_end_s: float = 1.0
    regain_iou: float = 0.5
    fill_gaps_s: float = 0.5
    stop_hold_s: float = 0.0
    stop_hold_back_s: float = 0.0
    stop_speed_mps: float = 1.0
    stop_decel_mps2: float = 2.0
    stop_radius_m: float = 2.0
    stop_window_s: float = 1.0
    stop_run_gap_s: float = 1.2
    stop_gap_speed_mps: float = 1.0
    max_overlap: float = 0.6
    absorbed_ratio: float = 0.6
    absorbed_speed: float = 1.5


@dataclass(frozen=True)
class Config:
    """The whole pipeline's configuration, one section per stage."""

    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    linking: LinkingConfig = field(default_factory=LinkingConfig)
    context: ContextConfig = field(default_factory=ContextConfig)
    finish: FinishConfig = field(default_factory=FinishConfig)


def _section_types() -> dict[str, type]:
    hints = typing.get_type_hints(Config)
    return {f.name: hints[f.name] for f in fields(Config)}


def _coerce(section: str, key: str, value: Any, typ: Any) -> Any:
    where = f"{section}.{key}"
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "1", "0", "yes", "no"):
            return value.lower() in ("true", "1", "yes")
        raise ConfigError(f"config {where}: expected true or false, got {value!r}")
    if typ is int:
        if isinstance(value, bool):
            raise ConfigError(f"config {where}: expected an integer, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"config {where}: expected an integer, got {value!r}") from None
        if not f.is_integer():
            raise ConfigError(f"config {where}: expected an integer, got {value!r}")
        if f < 0:  # every count, time, distance, ratio and weight here is >= 0 (0 disables)
            raise ConfigError(f"config {where}: must be >= 0, got {value!r}")
        return int(f)
    if typ is float:
        if isinstance(value, bool):
            raise ConfigError(f"config {where}: expected a number, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"config {where}: expected a number, got {value!r}") from None
        if not math.isfinite(f):
            raise ConfigError(f"config {where}: expected a finite number, got {value!r}")
        if f < 0:  # every time, distance, ratio and weight here is >= 0 (0 disables)
            raise ConfigError(f"config {where}: must be >= 0, got {value!r}")
        return f
    if typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"config {where}: expected a string, got {value!r}")
        return value
    origin = typing.get_origin(typ)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config {where}: expected a list, got {value!r}")
        (inner, *_) = typing.get_args(typ) or (float,)
        return tuple(_coerce(section, key, v, inner) for v in value)
    return value


def check_range(where: str, value: float, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, hi_open: bool = False, hi_name: str | None = None) -> None:
    """Raise :class:`ConfigError` ``config WHERE: must be ... , got VALUE`` unless ``value`` lies
    between ``lo`` and ``hi`` (excluded when ``*_open``; None: no bound). ``hi_name``: the setting
    ``hi`` comes from, named in the message."""
    ok = ((lo is None or (value > lo if lo_open else value >= lo))
          and (hi is None or (value < hi if hi_open else value <= hi)))
    if ok:
        return
    if hi_name is not None:
        want = (f"{'>' if lo_open else '>='} {lo:g} and " if lo is not None else "") + \
            f"{'below' if hi_open else 'at most'} {hi_name} ({hi:g})"
    elif hi is None:
        want = f"{'>' if lo_open else '>='} {lo:g}"
    elif lo is None:
        want = f"{'<' if hi_open else '<='} {hi:g}"
    else:
        want = f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    raise ConfigError(f"config {where}: must be {want}, got {value!r}")


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build a :class:`Config` from nested tables, rejecting unknown sections and keys."""
    sections = _section_types()
    kwargs = {}
    import difflib

    for name, table in data.items():
        if name not in sections:
            if not isinstance(table, dict):  # `key = value` above every [section]
                owners = [s for s, c in sections.items() if name in {f.name for f in fields(c)}]
                where = f"; it belongs under [{owners[0]}]" if owners else ""
                raise ConfigError(f"config: {name} = {table!r} is outside any [section]{where}")
            close = difflib.get_close_matches(name, sections, n=1)
            raise ConfigError(
                f"config: unknown section [{name}]"
                + (f"; did you mean [{close[0]}]?" if close else "")
                + f" (valid: {', '.join(sorted(sections))})")
        if not isinstance(table, dict):
            raise ConfigError(f"config: [{name}] must be a table")
        cls = sections[name]
        hints = typing.get_type_hints(cls)
        valid = {f.name for f in fields(cls)}
        values = {}
        for key, value in table.items():
            if key not in valid:
                close = difflib.get_close_matches(key, valid, n=3)
                raise ConfigError(
                    f"config: unknown parameter {name}.{key}"
                    + (f"; did you mean {' or '.join(f'{name}.{c}' for c in close)}?" if close
                       else f" (valid: {', '.join(sorted(valid))})"))
            values[key] = _coerce(name, key, value, hints[key])
        kwargs[name] = cls(**values)
    return Config(**kwargs)


def as_config(config: Config | dict | None) -> Config:
    """``config`` checked for the library's entry points: ``None`` gives the defaults, a dict of
    sections is read as a config file is (:func:`config_from_dict`), and a :class:`Config` built in
    Python (``dataclasses.replace``) must hold values of its fields' types, as a file's are made
    to: ``persist="false"`` had turned persistence on (a non-empty string is true) and
    ``window_s="3"`` failed deep inside a stage.

    Raises
    ------
    ConfigError
        Naming the first setting of the wrong type (or a config that is neither).
    """
    import numpy as np

    if config is None:
        return Config()
    if isinstance(config, dict):
        return config_from_dict(config)
    if not isinstance(config, Config):
        raise ConfigError(f"config: expected an aerotrack Config or a dict of sections, got "
                          f"{type(config).__name__}")
    sections = _section_types()
    for name, cls in sections.items():
        section = getattr(config, name)
        if not isinstance(section, cls):
            raise ConfigError(f"config.{name}: expected a {cls.__name__}, got "
                              f"{type(section).__name__}")
        hints = typing.get_type_hints(cls)
        for f in fields(cls):
            value, typ = getattr(section, f.name), hints[f.name]
            if typ is bool:
                ok = isinstance(value, (bool, np.bool_))
            elif typ is int:
                ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
            elif typ is float:
                ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
                    value, bool)
            elif typ is str:
                ok = isinstance(value, str)
            else:
                continue
            if not ok:
                raise ConfigError(f"config {name}.{f.name}: expected {typ.__name__}, got "
                                  f"{value!r} ({type(value).__name__})")
    return config


def config_to_dict(config: Config) -> dict[str, dict[str, Any]]:
    return {f.name: dataclasses.asdict(getattr(config, f.name)) for f in fields(config)}


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Load a TOML config (or the defaults) and apply ``section.key=value`` overrides.

    Raises
    ------
    ConfigError
        The file is unreadable, not TOML, or names an unknown or mistyped parameter.
    """
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8-sig"))
        except FileNotFoundError:
            raise ConfigError(f"{p}: config file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{p}: cannot read config ({exc})") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    for item in overrides:
        key, sep, raw = item.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not dot or not name:
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        data.setdefault(section, {})[name] = value
    return config_from_dict(data)


def given_settings(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()
                   ) -> set[str]:
    """The ``section.key`` names ``--set`` overrides give, and those a config file sets to other
    than the default (a run's own config.toml lists every setting), for :func:`unused_settings`.
    Call after :func:`load_config` of the same arguments has accepted them."""
    out = set()
    if path is not None:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8-sig"))
        defaults = config_to_dict(Config())
        for section, table in data.items():
            if isinstance(table, dict):
                out |= {f"{section}.{k}" for k, v in table.items()
                        if defaults.get(section, {}).get(k) != (
                            tuple(v) if isinstance(v, list) else v)}
    for item in overrides:
        out.add(item.partition("=")[0].strip())
    return out


#: detection settings used only without a metric scale (a map or --gsd), and only with one
PIXEL_ONLY = {"min_area_px": "min_area_m2", "max_length_px": "max_length_m",
              "min_width_px": "min_width_m", "persist_max_speed_px_s": "persist_max_speed_mps",
              "persist_max_length_px": "persist_max_length_m"}
METRIC_ONLY = {**{m: p for p, m in PIXEL_ONLY.items()}, "close_m": "close_px",
               "join_gap_m": "join_gap_px", "model_pixel_max_m": "model_scale"}


def unused_settings(given: set[str], config: Config, *, metric_scale: bool,
                    detector: bool = True) -> list[str]:
    """Why settings the user gave (``given``, :func:`given_settings`) change nothing in this run:
    a pixel gate with a map or ``--gsd`` (the metre one applies) and the reverse, detection
    settings with external detections, ``association.max_gap_s`` beyond the window it is capped
    by. A probe set ``detection.min_area_px=100000`` with a map and got the same detections,
    without a word."""
    out = []
    scale = "with a map or --gsd" if metric_scale else "without a map or --gsd"
    for name in sorted(given):
        section, _, key = name.partition(".")
        if section != "detection":
            continue
        if not detector and key not in ("min_conf",):
            out.append(f"{name}: not used with --detections (only detection.min_conf applies to "
                       "external detections)")
        elif detector and metric_scale and key in PIXEL_ONLY:
            out.append(f"{name}: not used {scale}: detection.{PIXEL_ONLY[key]} applies")
        elif detector and not metric_scale and key in METRIC_ONLY:
            out.append(f"{name}: not used {scale}: detection.{METRIC_ONLY[key]} applies")
    a = config.association
    if a.max_gap_s >= a.window_s and ("association.max_gap_s" in given
                                      or "association.window_s" in given):
        out.append(f"association.max_gap_s {a.max_gap_s:g}: capped at association.window_s "
                   f"({a.window_s:g} s) less a frame; longer gaps are linking's "
                   "(linking.max_gap_s)")
    return out


def describe_settings() -> dict[str, str]:
    """``section.key`` -> the setting's description from its section's docstring (the
    ``Attributes`` entries; an entry may name several settings, ``a, b : float``), for
    ``aerotrack config``."""
    import inspect

    out = {}
    for section, cls in _section_types().items():
        doc = inspect.cleandoc(cls.__doc__ or "")
        names = {f.name for f in fields(cls)}
        entries: list[tuple[list[str], list[str]]] = []  # (settings, description lines)
        inside = False
        for line in doc.splitlines():
            heads = [h.strip() for h in line.split(" : ", 1)[0].split(",")]
            if not line.startswith(" ") and heads and all(h in names for h in heads):
                entries.append((heads, []))
                inside = True
            elif inside and (line.startswith(" ") or not line.strip()):
                entries[-1][1].append(line)
            else:  # the next docstring section
                inside = False
        for keys, lines in entries:
            text = " ".join(x.strip() for x in lines).strip()
            out.update({f"{section}.{k}": text for k in keys})
    return out


def first_sentence(text: str, limit: int = 110) -> str:
    """The first sentence of ``text``, cut at ``limit`` characters."""
    import re

    m = re.search(r"(?<!\.)(?<!e\.g)(?<!i\.e)(?<!eq)(?<!eqs)\.(\s|$)", text)
    s = text[:m.start() + 1] if m else text
    return s if len(s) <= limit else s[:limit - 3].rstrip() + "..."


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_config(config: Config) -> str:
    """The configuration as TOML text (``load_config`` of it gives back an equal Config)."""
    lines = ["# aerotrack resolved configuration"]
    for section, table in config_to_dict(config).items():
        lines.append(f"\n[{section}]")
        for key, value in table.items():
            lines.append(f"{key} = {toml_value(value)}")
    return "\n".join(lines) + "\n"

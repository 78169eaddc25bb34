"""Wires the stages: frames -> registration -> detection -> local association -> global linking.

Two APIs over one implementation:

* push: ``Pipeline(...).step(frame)`` for each frame, then ``.finish()``;
* pull: ``run(source, ...)`` iterates a frame source (or runs association alone on a detections file);
  ``detect(source, ...)`` runs registration and detection alone.

Both return a :class:`Result` holding the tracks (in world coordinates, with each point's box in its
frame's pixels), the registrations and the detections; :func:`aerotrack.outputs.write_outputs` writes
them as the CLI contract's files.
"""

from __future__ import annotations

import logging
import math
import time
import weakref
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import Config, as_config
from .errors import InputError
from .geo import GeoMap
from .io.frames import read_ahead
from .types import Detections, Frame, Registration, Track, apply_homography, local_scales

#: ``registration.csv``'s status of a frame placed by the map's placement of frame 1 when there
#: are no frames to register (``--detections`` and ``--map``/``--map-init`` without INPUT).
STILL = "still"
STILL_REASON = "no frames (--detections alone): a still camera, placed by --map-init"

log = logging.getLogger(__name__)


@dataclass
class Result:
    """What a run produced.

    Attributes
    ----------
    tracks : list of Track
        Final tracks after global linking; points of kind observed, bridged, stationary, predicted.
    registrations : dict of int -> Registration
        Frame index -> registration used (frame pixels -> world).
    detections : list of Detections
        Every frame's detections, in frame order.
    fps : float
    frame_size : (int, int) or None
        (width, height) of the frames, None for association alone.
    metres_per_unit : float or None
        Metres per world unit (map pixel), when known.
    timings : dict
        Seconds spent in each stage (wall clock).
    cpu_timings : dict
        CPU seconds of this process (all its threads) in each stage: the stage's cost when other
        work shares the machine, where wall seconds say more about the load than the stage.
    frames : int
        Number of frames processed.
    frames_timed : int or None
        Frames processed in this process, which ``timings`` cover (a resumed run's frames
        before the interruption are in ``frames``, not in ``timings``); None: ``frames``.
    overlay_mask : ndarray (H, W) bool or None
        On-screen overlay pixels found (``detection.overlay_mask``), left out of detection.
    overlay_held : list of (x, y, w, h)
        Overlay-like marks in the middle of the frame, left in (a crosshair, or a vehicle the
        camera keeps centred; ``detection.overlay_mask = "edges"``).
    repeated_frames : list of int
        Frames whose pixels repeat the frame before exactly (a recorder that dropped frames and
        re-emitted the last one): the tracker sees a stop, then a jump.
    thresholds : dict
        Frame -> the built-in detector's residual threshold there (grey levels): above
        ``detection.min_threshold`` where the frame's noise set it (the noise hint).
    resumed : dict or None
        A resumed run: ``from_frame`` (the first frame read after the restart) and ``exact``
        (the stages' working state was restored: the results equal an uninterrupted run's;
        False: from the last checkpoint, a few frames' decisions may differ). None otherwise.
    followed : int or None
        Detections the stop follower added (``association.follow_stopped``; None when it is
        off; a segment-parallel run counts each segment's own frames): associated like the
        others, not in ``detections``.
    mcmc : dict or None
        Local association's MCMC moves (:meth:`LocalAssociator.mcmc_counts`): ``proposed`` and
        ``accepted`` per move, summed over the segments with ``--workers`` (whose overlaps are
        sampled twice); None without association.
    still_H : ndarray (3, 3) or None
        Detections alone (no frames) on a map: the placement every frame was given (a still
        camera, ``Pipeline.still_registration``); None otherwise.
    """

    tracks: list[Track]
    registrations: dict[int, Registration]
    detections: list[Detections]
    fps: float
    frame_size: tuple[int, int] | None
    metres_per_unit: float | None
    timings: dict[str, float] = field(default_factory=dict)
    cpu_timings: dict[str, float] = field(default_factory=dict)
    frames: int = 0
    first_frame: int = 1
    last_frame: int = 0
    followed: int | None = None
    frames_timed: int | None = None
    repeated_frames: list[int] = field(default_factory=list)
    thresholds: dict[int, float] = field(default_factory=dict)
    overlay_mask: np.ndarray | None = None
    overlay_held: list[tuple[int, int, int, int]] = field(default_factory=list)
    resumed: dict | None = None
    mcmc: dict | None = None
    still_H: np.ndarray | None = None

    def __repr__(self) -> str:  # the generated one printed every array: 15 MB for a 100-frame run
        n_dets = sum(len(d) for d in self.detections)
        return (f"Result({len(self.tracks)} tracks, frames {self.first_frame}-{self.last_frame} "
                f"({self.frames} processed), {n_dets} detections, fps={self.fps:g})")


class Pipeline:
    """The whole tracker, fed one frame at a time.

    Parameters
    ----------
    config : Config
    fps : float
    geomap : GeoMap, optional
        The map; world coordinates are then its pixels.
    H_init : ndarray (3, 3), optional
        Frame 1 pixels -> map pixels (required with a map).
    seed : int
        Seed of every random choice (MCMC).
    detections : dict of int -> ndarray (N, 10), optional
        External detections (MOT rows) per frame; they replace the built-in detector.
    metres_per_unit : float, optional
        Scale of world units without a map (``--gsd``).
    spill : bool
        Keep finished tracklets on disk until global linking (``checkpoint_dir/tracklets`` with a
        checkpoint folder, else a temporary folder): memory then does not grow with the number of
        tracklets. The tracks are the same either way.
    associate : bool
        False runs registration and detection only (``aerotrack detect``): detections are kept
        (regions applied) and boxes kept out of registration as in a full run, so the detections
        equal those of ``aerotrack track`` with the same inputs, but no tracklet is made.
    debug : bool
        The detector keeps ``debug_frames`` (``aerotrack detect --debug-video``).
    stabilised : bool
        The frames are already registered to each other (``aerotrack track --stabilised``):
        identity homographies instead of the registrar (not with a map).
    opencv_threads : int or None
        OpenCV worker threads while the pipeline works on a frame (set for each step and restored
        after it); None leaves OpenCV's own setting. One by default: the stages call OpenCV on
        many small images, where its thread pool costs more than it brings. Measured on the
        2-core machine with other work running (load 4-5): full pipeline 1.4-1.6x faster in wall
        time at 640x480, 0.9-1.35x at 1280x720, within 7 % at 1920x1080 and 4000x3000, and
        5-15 % less CPU.
    """

    def __init__(self, config: Config, fps: float, *, geomap: GeoMap | None = None,
                 H_init: np.ndarray | None = None, seed: int = 0,
                 detections: dict[int, np.ndarray] | None = None,
                 metres_per_unit: float | None = None,
                 checkpoint_dir: Path | None = None, checkpoint_every: int = 300,
                 undistort: Callable[[Frame], Frame] | None = None,
                 regions: list | None = None, min_speed_mps: float | None = None,
                 spill: bool = True, roads=None, opencv_threads: int | None = 1,
                 associate: bool = True, debug: bool = False, stabilised: bool = False) -> None:
        from .association import LocalAssociator
        from .io.checkpoint import TrackletSpill
        from .io.state import as_built

        config = as_config(config)
        self.config = config
        self.fps = float(fps)
        self.geomap = geomap
        self.roads = roads  # RoadNetwork in world units (map pixels), for the motion context
        self.metres_per_unit = geomap.metres_per_pixel if geomap is not None else metres_per_unit
        self.external = detections
        self.registrar = None
        self.detector = None
        self._H_init = H_init
        self.debug = debug
        if stabilised and geomap is not None:
            raise InputError("stabilised frames (identity homographies) cannot be placed on a map")
        self.stabilised = stabilised
        self.associator = LocalAssociator(config.association, self.fps,
                                          metres_per_unit=self.metres_per_unit, seed=seed)
        self._built_assoc = as_built(self.associator)
        if not associate:
            self.associator = None
        # stopped-vehicle following: it holds frames from their step until their detections
        # are associated (the detector holds them as long, so this costs no memory)
        self.follower = None
        if self.associator is not None and config.association.follow_stopped:
            from .association.follow import StopFollower

            self.follower = StopFollower(config.association, self.fps, geomap=geomap)
            self._built_follower = as_built(self.follower)
        # the last stages' configuration errors surface now, not after the whole video
        from .association.finish import TrackFinisher
        from .association.linking import GlobalLinker
        GlobalLinker(config.linking, config.context, self.fps, metres_per_unit=self.metres_per_unit)
        TrackFinisher(config.finish, self.fps, metres_per_unit=self.metres_per_unit)
        self.registrations: dict[int, Registration] = {}
        self.detections: list[Detections] = []
        # finished tracklets (on disk with ``spill``; a list again after finish_local)
        self.tracklets: list[Track] | TrackletSpill = (
            TrackletSpill(None if checkpoint_dir is None else Path(checkpoint_dir) / "tracklets")
            if spill else [])
        #: Local association's MCMC counts (``Result.mcmc``), set when association ends.
        self.mcmc: dict | None = None
        self.timings = {"registration": 0.0, "detection": 0.0, "association": 0.0, "linking": 0.0}
        self.cpu_timings = dict(self.timings)
        self.frame_size: tuple[int, int] | None = None
        self.n_frames = 0
        self.n_timed = 0  # frames stepped in this process (a resumed run's: after the restart)
        self.first_frame: int | None = None
        self.last_frame = 0
        self._last_step: int | None = None  # the frame last given to step (its order is checked)
        self._size: tuple[int, int] | None = None  # (H, W) of the first frame given to step
        self.overlay = None  # detection.overlay.OverlayFinder (on-screen text, crosshairs)
        self._given_overlay: np.ndarray | None = None  # a mask found by an earlier run (--from)
        self._region_mask: np.ndarray | None = None  # the detector's mask from the regions
        self._prev_sample: np.ndarray | None = None  # every 4th pixel of the last frame
        self.repeated_frames: list[int] = []
        self.thresholds: dict[int, float] = {}  # frame -> detector threshold (Result)
        self._pending_thr: dict[int, float] = {}  # ... since the last checkpoint
        self._last_boxes_world: np.ndarray | None = None  # (N, 4) world centre + size, for masking
        # checkpoints (DIR/.partial) for --resume
        self.checkpoint_dir = checkpoint_dir
        self.checkpoint_every = max(1, int(checkpoint_every))
        self._pending_regs: list[Registration] = []
        self._pending_dets: list[Detections] = []
        self._chunk_no = 0
        self._since_checkpoint = 0
        self._skip_until = 0  # detections of frames <= this were restored from checkpoints
        self.exact_resume = False  # restore() put the stages' working state back
        # scope: lens undistortion, regions of interest / ignore regions, parked-vehicle filter
        self.undistort = undistort
        self.regions = list(regions or [])
        self.min_speed_mps = min_speed_mps
        self.opencv_threads = opencv_threads
        self._outer_threads: int | None = None  # see _wide_threads
        # frame index -> the image the stages were given, while some stage still holds it: on
        # interruption the state then refers to these frames instead of holding their pixels
        self._images: weakref.WeakValueDictionary[int, np.ndarray] = weakref.WeakValueDictionary()

    @contextmanager
    def _timed(self, stage: str) -> Iterator[None]:
        """Add the block's wall and CPU seconds to ``stage``'s timings."""
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.timings[stage] += time.perf_counter() - t0
            self.cpu_timings[stage] += time.process_time() - c0

    # -- stages -----------------------------------------------------------------------------------
    def _ensure_stages(self, frame: Frame) -> None:
        if self.registrar is not None:
            return
        self._make_stages((frame.image.shape[1], frame.image.shape[0]))

    def _make_stages(self, frame_size: tuple[int, int]) -> None:
        from .io.state import as_built
        from .registration import FrameRegistrar

        self.frame_size = frame_size
        self.registrar = _Stabilised() if self.stabilised else FrameRegistrar(
            self.config.registration, self.fps, geomap=self.geomap, H_init=self._H_init)
        if self.external is None:
            from .detection import MovingObjectDetector

            self.detector = MovingObjectDetector(self.config.detection, self.fps, geomap=self.geomap,
                                                 metres_per_unit=self.metres_per_unit)
            self.detector.keep_debug = self.debug
            from .geo.roi import frame_mask

            self.detector.frame_mask = frame_mask(self.regions, frame_size)
            self._region_mask = self.detector.frame_mask
            mode = self.config.detection.overlay_mask
            if mode != "off" and not self.stabilised:
                from .detection.overlay import OverlayFinder

                self.overlay = OverlayFinder(self.fps, self.config.detection.overlay_min_s,
                                             self.config.detection.overlay_share, mode)
        # what the constructors made: save_state leaves it out (the resumed run makes it again)
        self._built = {"registrar": as_built(self.registrar)}
        if self.detector is not None:
            self._built["detector"] = as_built(self.detector)

    def _exclude_boxes(self) -> np.ndarray | None:
        """Boxes of the latest final detections, in the previous frame's pixels (moving vehicles must
        not pull the frame-to-frame estimate)."""
        prev = self.registrations.get(self.last_frame)
        if not self.config.registration.mask_detections:
            return None
        if prev is None or self._last_boxes_world is None or not len(self._last_boxes_world):
            return None
        c = self._last_boxes_world
        inv = np.linalg.inv(prev.H)
        centre = apply_homography(inv, c[:, :2])
        half = np.abs(apply_homography(inv, c[:, :2] + c[:, 2:] / 2) - centre)
        half = np.maximum(half, 4.0) * 1.5
        return np.hstack([centre - half, 2 * half])

    def step(self, frame: Frame) -> None:
        """Process one frame (frames must come in increasing order, all of one size).

        ``frame.image`` is BGR ``(H, W, 3)`` uint8 as OpenCV decodes it; grey ``(H, W)`` or
        ``(H, W, 1)`` and BGRA ``(H, W, 4)`` frames are converted. Anything else (16-bit or float
        pixels, channels first) raises :class:`~aerotrack.errors.InputError` naming the frame,
        as do frame numbers below 1 or not increasing and a frame size that changes.
        """
        from .detection.detector import cv_threads

        frame = self._checked(frame)
        self._wide_threads()
        with cv_threads(self.opencv_threads):
            self._step(frame)

    def _checked(self, frame: Frame) -> Frame:
        """``frame`` with a BGR uint8 image, or an InputError naming what is wrong with it (a grey
        frame failed deep in OpenCV a window later; a frame size change was accepted)."""
        import dataclasses

        index = frame.index
        if int(index) != index or index < 1:
            raise InputError(f"frame {index!r}: frame numbers are integers from 1")
        if self._last_step is not None and index <= self._last_step:
            raise InputError(f"frame {index}: frames must come in increasing order (the previous "
                             f"one was {self._last_step})")
        self._last_step = index
        img = frame.image
        if img is None:
            return frame
        if not isinstance(img, np.ndarray):
            raise InputError(f"frame {index}: image is a {type(img).__name__}, expected a numpy "
                             "array")
        if img.dtype != np.uint8:
            raise InputError(f"frame {index}: pixels are {img.dtype}, expected uint8 (scale 16-bit "
                             "or float frames to 0-255 first)")
        channels = 1 if img.ndim == 2 else (img.shape[2] if img.ndim == 3 else 0)
        if channels not in (1, 3, 4) or min(img.shape[:2]) < 2:
            raise InputError(f"frame {index}: image shape {img.shape}, expected (H, W, 3) BGR, "
                             "(H, W) grey or (H, W, 4) BGRA, channels last")
        if channels != 3:
            import cv2

            code = cv2.COLOR_GRAY2BGR if channels == 1 else cv2.COLOR_BGRA2BGR
            img = cv2.cvtColor(np.ascontiguousarray(img.reshape(img.shape[:2]) if channels == 1
                                                    else img), code)
        if self._size is None:
            self._size = img.shape[:2]
        elif img.shape[:2] != self._size:
            raise InputError(f"frame {index}: size {img.shape[1]}x{img.shape[0]} differs from the "
                             f"first frame's {self._size[1]}x{self._size[0]}")
        sample = img[::4, ::4]
        if self._prev_sample is not None and np.array_equal(sample, self._prev_sample):
            self.repeated_frames.append(int(index))
        self._prev_sample = sample.copy()
        return frame if img is frame.image else dataclasses.replace(frame, image=img)

    def _wide_threads(self) -> None:
        """The OpenCV threads the process has outside the stages, for the detector's whole-frame
        work (``MovingObjectDetector.wide_threads``)."""
        if self.opencv_threads is not None:
            import cv2

            self._outer_threads = cv2.getNumThreads()
        if self.detector is not None:
            self.detector.wide_threads = self._outer_threads

    def _step(self, frame: Frame) -> None:
        if self.undistort is not None:
            frame = self.undistort(frame)
        self._ensure_stages(frame)
        if self.detector is not None:
            self.detector.wide_threads = self._outer_threads
        if frame.image is not None:
            self._images[frame.index] = frame.image
            if self.follower is not None:  # the detector holds it until its detections are final
                self.follower.hold(frame.index, frame.image)
        if self.first_frame is None:
            self.first_frame = frame.index
        with self._timed("registration"):
            reg = self.registrar.step(frame, exclude_boxes=self._exclude_boxes())
        if reg is not None and frame.index not in self.registrations:
            self.registrations[frame.index] = reg
            if self.checkpoint_dir is not None:  # else nothing ever empties it (a leak per frame)
                self._pending_regs.append(reg)
        with self._timed("detection"):
            if self.overlay is not None and frame.image is not None:
                self._mask_overlay(frame, reg)
            if self.external is not None:
                final = [self._external_detections(frame, reg)]
            elif reg is None:
                final = []
            else:
                final = self.detector.step(frame, reg)
                self._take_thresholds()
        if frame.index > self.last_frame:
            self.n_frames += 1
            self.n_timed += 1
            self.last_frame = frame.index
        self._associate(final)
        self._since_checkpoint += 1
        if self.checkpoint_dir is not None and self._since_checkpoint >= self.checkpoint_every:
            self.checkpoint()

    def _take_thresholds(self) -> None:
        if self.detector is not None and self.detector.thresholds:
            self.thresholds.update(self.detector.thresholds)
            if self.checkpoint_dir is not None:
                self._pending_thr.update(self.detector.thresholds)
            self.detector.thresholds.clear()

    def _external_detections(self, frame: Frame | None, reg: Registration | None) -> Detections:
        idx = frame.index
        rows = self.external.get(idx)
        if rows is not None and len(rows):
            # the given confidences count: boxes below detection.min_conf are dropped, as the
            # built-in detector's are (they were all tracked, a detector's low-confidence false
            # alarms included)
            rows = rows[np.clip(rows[:, 6], 0.0, 1.0) >= self.config.detection.min_conf]
        if rows is None or not len(rows):
            return Detections.empty(idx)
        boxes = rows[:, 2:6].copy()
        conf = np.clip(rows[:, 6], 0.0, 1.0)
        centres = boxes[:, :2] + boxes[:, 2:] / 2
        if reg is None:
            world = centres
            size_world = boxes[:, 2:].copy()
        else:
            world = reg.to_world(centres)
            # as the built-in detector's: the box's sides times the frame's local scale (the
            # corner's offset through a rotating homography is no size: at 45 degrees one side
            # of it vanishes, and the finish stage dropped such vehicles as too small)
            size_world = boxes[:, 2:] * local_scales(reg.H, centres)[:, None]
        hist = desc = None
        extra = {}
        if frame is not None and frame.image is not None:
            from .detection import describe

            hist, desc = describe(frame.image, boxes)
            extra["desc"] = desc
        mapxy = lonlat = None
        if self.geomap is not None and reg is not None:
            mapxy = self.geomap.pixel_to_crs(world)
            lonlat = self.geomap.crs_to_lonlat(mapxy)
        return Detections(frame=idx, boxes=boxes, conf=conf, world=world, mapxy=mapxy,
                          lonlat=lonlat, hist=hist, size_world=size_world, extra=extra)

    def _associate(self, final: Iterable[Detections]) -> None:
        with self._timed("association"):
            for dets in final:
                if dets.frame <= self._skip_until:
                    continue  # already restored from a checkpoint
                for region in self.regions:
                    if len(dets):
                        dets = dets.subset(region.keep_detections(dets.centers, dets.world))
                mask = self.overlay_mask
                if mask is not None and len(dets):
                    dets = dets.subset(_outside(mask, dets.centers))
                self.detections.append(_light(dets))
                if self.checkpoint_dir is not None:  # full detections, appearance included: only
                    self._pending_dets.append(dets)  # kept until the next checkpoint empties them
                self._remember_boxes(dets)
                if self.associator is None:  # detection only
                    continue
                if self.config.association.split_merged and len(dets):
                    dets = self._split_merged(dets)
                if self.follower is not None:
                    dets = self.follower.step(dets, self.registrations.get(dets.frame),
                                              self.associator)
                self.tracklets.extend(_thin_appearance(t) for t in self.associator.step(dets))

    def _split_merged(self, dets: Detections) -> Detections:
        """``dets`` with detections holding several tracked vehicles split (merged.py)."""
        from .association.merged import split_merged

        c = self.config.association
        reg = self.registrations.get(dets.frame)
        H = np.eye(3) if reg is None else np.asarray(reg.H, dtype=np.float64)
        centres, sizes, hists = self.associator.predictions(
            dets.frame, c.split_merged_max_age_s, max(2, round(c.split_merged_min_obs_s * self.fps)))
        out, _ = split_merged(dets, centres, sizes, H, hists=hists, geomap=self.geomap,
                              area_ratio=c.split_merged_area_ratio)
        return out

    def _remember_boxes(self, dets: Detections | None) -> None:
        """Keep the latest final detections' world boxes (kept out of registration)."""
        if dets is not None and len(dets):
            size = dets.size_world if dets.size_world is not None else dets.boxes[:, 2:]
            self._last_boxes_world = np.hstack([dets.world, size])
        else:
            self._last_boxes_world = None

    def _replay(self, dets: list[Detections]) -> None:
        """Association over checkpointed detections (resume without association's state)."""
        self._associate(dets)
        self._pending_dets = []  # already in the checkpoints
        self._skip_until = max((d.frame for d in dets), default=0)

    def _mask_overlay(self, frame: Frame, reg) -> None:
        """Feed the overlay finder; when its mask changes, the detector works around it (with
        the regions' own mask), and detections whose centre falls in it are dropped."""
        self.overlay.step(frame.image, None if reg is None else reg.H)
        if not self.overlay.changed:
            return
        mask = self.overlay.mask
        work = None if mask is None else np.where(mask, 0, 255).astype(np.uint8)
        if work is not None and self._region_mask is not None:
            work = np.minimum(work, self._region_mask)
        self.detector.frame_mask = work if work is not None else self._region_mask
        self.detector._mask_small = None  # made again at the model's resolution

    def step_detections_only(self, index: int) -> None:
        """Association alone: feed frame ``index`` of the external detections (no image). With a
        map and its placement (``--map-init``) the camera is taken to be still there: every
        frame's boxes go to the map through that placement (they were taken as map pixels)."""
        if self.first_frame is None:
            self.first_frame = index
        self.n_frames += 1
        self.n_timed += 1
        self.last_frame = index
        still = self.still_registration(index)
        self._associate([self._external_detections(Frame(index, None, (index - 1) / self.fps),
                                                   still)])
        self._since_checkpoint += 1
        if self.checkpoint_dir is not None and self._since_checkpoint >= self.checkpoint_every:
            self.checkpoint()

    def still_registration(self, index: int) -> Registration | None:
        """Frame ``index``'s placement on the map when there are no frames to register: the
        map's placement of frame 1 (``H_init``) for every frame, or None without a map."""
        if self.geomap is None or self._H_init is None:
            return None
        return Registration(index, np.asarray(self._H_init, dtype=np.float64), STILL, 0,
                            float("nan"), float("nan"), STILL_REASON)

    # -- checkpoints ------------------------------------------------------------------------------
    def checkpoint(self) -> None:
        """Save registrations and final detections produced since the last checkpoint."""
        if self.checkpoint_dir is None or not (self._pending_regs or self._pending_dets):
            return
        from .io.checkpoint import save_chunk
        from .io.state import drop_state

        save_chunk(self.checkpoint_dir, self._chunk_no, self._pending_regs, self._pending_dets,
                   self._pending_thr)
        self._pending_thr = {}
        drop_state(self.checkpoint_dir)  # an earlier interruption's stage state is stale now
        self._chunk_no += 1
        self._pending_regs, self._pending_dets = [], []
        self._since_checkpoint = 0

    def save_state(self) -> bool:
        """Save the registrar's, detector's and local association's (with the stop follower's)
        working state after the last frame (on Ctrl-C, between two frames, after
        :meth:`checkpoint`), so :meth:`restore` continues exactly; the finished tracklets
        spilled so far are linked beside it (``state-tracklets/``), so that association is not
        replayed over the whole video.
        Returns False (and saves nothing) when the registrar or detector holds a value the state
        codec cannot write (:mod:`aerotrack.io.state`); resume then restarts from the checkpoints
        alone. When only association's state cannot be written, resume replays association (and
        following starts again: the checkpoints hold no followed detections)."""
        from .io.checkpoint import TrackletSpill
        from .io.state import (
            STATE_TRACKLETS,
            Rereadable,
            StateNotSaved,
            drop_state,
            save_state,
        )

        if self.checkpoint_dir is None or self.registrar is None \
                or isinstance(self.registrar, _Ended):
            return False
        stages = {"registrar": (self.registrar, self._built["registrar"])}
        if self.detector is not None:
            stages["detector"] = (self.detector, self._built["detector"])
        frames = Rereadable(dict(self._images), self._derive(),
                            {} if self.follower is None else self.follower.kept())
        extra = {"frame_size": list(self.frame_size)}
        drop_state(self.checkpoint_dir)
        if isinstance(self.tracklets, TrackletSpill) and self.associator is not None:
            # association's window and the tracklets it finished: resume need not replay it;
            # the follower goes with it (it follows association's tracks)
            local = {"associator": (self.associator, self._built_assoc)}
            if self.follower is not None:
                local["follower"] = (self.follower, self._built_follower)
            try:
                save_state(self.checkpoint_dir, self.last_frame, {**stages, **local},
                           extra={**extra, "tracklets": self.tracklets.link_into(
                               Path(self.checkpoint_dir) / STATE_TRACKLETS)},
                           shared=(self.geomap,), frames=frames)
                return True
            except StateNotSaved as exc:
                drop_state(self.checkpoint_dir)
                log.info("association state not saved (%s): --resume replays association", exc)
        try:
            save_state(self.checkpoint_dir, self.last_frame, stages, extra=extra,
                       shared=(self.geomap,), frames=frames)
        except StateNotSaved as exc:
            drop_state(self.checkpoint_dir)
            log.warning("stage state not saved (%s): --resume restarts registration and "
                        "detection shortly before frame %d", exc, self.last_frame)
            return False
        return True

    def _derive(self) -> dict:
        """What the stages make from a frame and keep beside it (the detector's model-resolution
        copy, the follower's grey frame): state.npz refers to it instead of holding it
        (:mod:`aerotrack.io.state`)."""
        out = {} if self.detector is None else {"model": self.detector.model_image}
        if self.follower is not None:
            out["grey"] = self.follower.grey
        return out

    def _reread(self, source, indices: list[int]) -> dict[int, np.ndarray]:
        """Frames ``indices`` of ``source`` as the stages were given them (undistorted)."""
        if source is None or not indices:
            return {}
        want = set(indices)
        lo, hi = min(want), max(want)
        step = math.gcd(*[b - a for a, b in zip(sorted(want), sorted(want)[1:])]) or 1
        out = {}
        for frame in source.frames(start=lo, stop=hi, stride=step):
            if frame.index in want:
                out[frame.index] = (self.undistort(frame) if self.undistort else frame).image
                self._images[frame.index] = out[frame.index]  # the stages get this very array
        return out

    def restore(self, source=None) -> int:
        """Load checkpoints from ``checkpoint_dir``, and association's state with them or else
        replay association on them.

        Returns the frame from which frames must be fed again. With the stages' working state
        saved on interruption (:meth:`save_state`) that is the frame after the last one taken,
        and the run continues exactly as if never stopped (``self.exact_resume``); the frames
        the stages still held are read again from ``source`` (the run's frame source), which
        must give the same pixels (checked; see :mod:`aerotrack.io.state`). Without that state
        (a killed process: periodic checkpoints only), or when ``source`` is missing or gives
        other pixels, registration and detection restart a background half-window before the
        first frame whose detections were not final, from that frame's registration: the frames
        after the restart can then be registered and detected slightly differently (another
        keyframe chain, a background window without the frames before the restart).
        """
        from .io.checkpoint import TrackletSpill, load_chunks, load_thresholds
        from .io.state import (
            STATE_TRACKLETS,
            FramesChanged,
            apply_state,
            load_state,
            saved_frame,
        )

        regs, dets, n = load_chunks(self.checkpoint_dir)
        self._chunk_no = n
        self.thresholds.update(load_thresholds(self.checkpoint_dir))  # the noise hint's
        if not regs and not dets:
            return 1
        self.registrations.update(regs)
        last_det = max((d.frame for d in dets), default=0)
        self.last_frame = max(regs) if regs else last_det
        self.first_frame = min(regs) if regs else 1
        self.n_frames = len({*regs, *(d.frame for d in dets)})
        if self.external is not None and not regs:
            self._replay(dets)
            return last_det + 1
        head = saved_frame(self.checkpoint_dir)
        if head is not None and regs and head[0] == max(regs):  # not stale: exact
            self._make_stages(tuple(head[1]["frame_size"]))
            try:
                frame, stages, extra = load_state(self.checkpoint_dir,
                                                  lambda idx: self._reread(source, idx),
                                                  self._derive())
            except FramesChanged as exc:
                log.warning("--resume: stage state not used (%s); registration and detection "
                            "restart shortly before frame %d", exc, head[0])
                self.registrar = self.detector = None  # made again at the restart
            else:
                assoc = stages.pop("associator", None)
                follow = stages.pop("follower", None)
                for name, (_, attrs) in stages.items():
                    apply_state(getattr(self, name), attrs)
                if assoc is not None and isinstance(self.tracklets, TrackletSpill) \
                        and self.tracklets.adopt(Path(self.checkpoint_dir) / STATE_TRACKLETS,
                                                 extra.get("tracklets")):
                    apply_state(self.associator, assoc[1])  # no replay: as it stood
                    if follow is not None and self.follower is not None:
                        apply_state(self.follower, follow[1])
                    self.detections = [_light(d) for d in dets]
                    self._remember_boxes(dets[-1] if dets else None)
                    self._skip_until = last_det
                else:
                    self._replay(dets)
                self.exact_resume = True
                self._restart = frame + 1
                return frame + 1
        self._replay(dets)
        half = int(np.ceil(self.config.detection.window_s * self.fps / 2)) + 1
        restart = max(self.first_frame, last_det + 1 - half)
        while restart > self.first_frame and restart not in regs:
            restart -= 1
        if restart in regs:
            self._H_init = regs[restart].H
        self._restart = restart
        if head is None or not regs or head[0] != max(regs):
            log.warning("--resume: no working state was saved at frame %d (a second Ctrl-C, a "
                        "kill or a crash): registration and detection restart from frame %d, so "
                        "a few frames may be decided differently than in an uninterrupted run",
                        self.last_frame, restart)
        return restart

    def finish_local(self) -> list[Track]:
        """Flush registration, detection and local association; return every tracklet (world
        coordinates) before global linking. ``self.registrations`` and ``self.detections`` are then
        complete. Used by segment-parallel processing (:mod:`aerotrack.parallel`), which links the
        tracklets of all segments at once.

        This ends the stream: the stages' working state (the detector's window of frames, the
        registrar's keyframe, the association window) is released before spilled tracklets are
        read back, so that the end of a long run does not hold both.
        """
        from .io.checkpoint import TrackletSpill

        if self.detector is not None:
            from .detection.detector import cv_threads

            self._wide_threads()
            with self._timed("detection"), cv_threads(self.opencv_threads):
                rest = self.detector.flush()
            self._take_thresholds()
            self._associate(rest)
        if self.associator is not None:
            with self._timed("association"):
                self.tracklets.extend(_thin_appearance(t) for t in self.associator.flush())
            self.mcmc = self.associator.mcmc_counts()
        self.detector = self.associator = None
        self.registrar = _Ended()
        if isinstance(self.tracklets, TrackletSpill):
            spill, self.tracklets = self.tracklets, self.tracklets.load()
            spill.close()
        return self.tracklets

    def finish(self) -> Result:
        """Flush every stage and link tracklets into final tracks."""
        self.finish_local()
        self.checkpoint()  # the last chunk: checkpoints then hold every stage result
        if self.checkpoint_dir is not None:  # a resumed run's state is spent (not kept in stages/)
            from .io.state import drop_state

            drop_state(self.checkpoint_dir)
        tracklets = self.tracklets
        mask = self.overlay_mask
        if mask is not None:
            tracklets = self._drop_overlay(mask)
        with self._timed("linking"):
            tracks = self._link(tracklets)
            if self.min_speed_mps:
                from .geo.roi import filter_min_speed

                mpu = self.metres_per_unit
                if not mpu and tracks:  # no map or --gsd: the scale linking estimated, not pixels/s
                    from .association.linking import estimate_scale

                    mpu = estimate_scale(tracks, self.config.context.image_object_size_m)
                tracks = _renumber(filter_min_speed(tracks, self.min_speed_mps, self.fps, mpu))
        return Result(tracks=tracks, registrations=self.registrations, detections=self.detections,
                      fps=self.fps, frame_size=self.frame_size,
                      metres_per_unit=self.metres_per_unit, timings=dict(self.timings),
                      cpu_timings=dict(self.cpu_timings),
                      frames=self.n_frames, first_frame=self.first_frame or 1,
                      last_frame=self.last_frame,
                      followed=None if self.follower is None else self.follower.n_followed,
                      frames_timed=self.n_timed, repeated_frames=list(self.repeated_frames),
                      thresholds=dict(self.thresholds),
                      overlay_mask=mask,
                      overlay_held=[] if self.overlay is None else list(self.overlay.held),
                      mcmc=self.mcmc, still_H=self.still_H)

    @property
    def overlay_mask(self) -> np.ndarray | None:
        """On-screen overlay pixels (H, W) bool found in this run, or given (``track --from``
        takes the first run's from ``stages/``), or None."""
        if self.overlay is not None:
            return self.overlay.mask
        return self._given_overlay

    def _drop_overlay(self, mask: np.ndarray) -> list[Track]:
        """The tracklets and detections not on the overlay (:func:`drop_on_overlay`); the mask is
        saved beside the checkpoints for ``track --from``."""
        from .detection.overlay import OVERLAY_FILE, write_mask

        kept, self.detections = drop_on_overlay(self.tracklets, self.detections, mask)
        if self.checkpoint_dir is not None:
            write_mask(Path(self.checkpoint_dir) / OVERLAY_FILE, mask)
        return kept

    def _link(self, tracklets: list[Track]) -> list[Track]:
        return link(tracklets, self.config, self.fps, metres_per_unit=self.metres_per_unit,
                    frame_size=self.frame_size, registrations=self.registrations, roads=self.roads,
                    still_H=self.still_H, detections=self.detections)

    @property
    def still_H(self) -> np.ndarray | None:
        """Detections alone (no frames) on a map: the placement every frame was given
        (:meth:`still_registration`); None otherwise."""
        if self.registrations or self.frame_size is not None:
            return None
        reg = self.still_registration(1)
        return None if reg is None else reg.H


class _Stabilised:
    """Registrar of frames already registered to each other: identity homographies."""

    def step(self, frame: Frame, exclude_boxes=None) -> Registration:
        return Registration(frame.index, np.eye(3))


class _Ended:
    """Stands for the registrar after :meth:`Pipeline.finish_local`: the stream has ended."""

    def step(self, *args, **kwargs):
        from .errors import StageError

        raise StageError("Pipeline.step after finish_local/finish: the stream has ended")


def check_config(config: Config, fps: float | None = None) -> None:
    """Raise :class:`~aerotrack.errors.ConfigError` naming the first out-of-range setting of any
    stage. The command line calls it before it touches an output folder: the registrar and the
    detector are otherwise built at the first frame, and ``--overwrite`` had by then emptied the
    folder of the results it was asked to replace."""
    from .detection.detector import check_config as check_detection
    from .registration.registrar import check_config as check_registration

    check_registration(config.registration)
    # external detections (``detector`` False) use detection.min_conf alone, but a config.toml
    # written with out-of-range detection settings failed only when given to a video run
    check_detection(config.detection)
    Pipeline(config, fps or 30.0, spill=False)  # association, following, linking, finishing


def link(tracklets: list[Track], config: Config, fps: float, *, metres_per_unit: float | None = None,
         frame_size: tuple[int, int] | None = None,
         registrations: dict[int, Registration] | None = None, roads=None,
         still_H: np.ndarray | None = None,
         detections: Iterable[Detections] | None = None) -> list[Track]:
    """Global linking of tracklets (world coordinates) into tracks numbered 1..N.

    The step after local association, shared by :class:`Pipeline` and segment-parallel runs
    (:mod:`aerotrack.parallel`); without the linking stage the tracklets are the tracks.
    ``roads``: a :class:`~aerotrack.context.roads.RoadNetwork` in world units for the motion
    context. The linked tracks are then finished (:mod:`aerotrack.association.finish`, config
    section ``finish``): smoothed ground points, robust box sizes, static tracks dropped.
    ``still_H``: detections alone on a map, the placement their boxes went through (boxes are
    rebuilt in frame pixels through it). ``detections``: the run's, for the detections regained
    inside the linked tracks' gaps (:mod:`aerotrack.association.regain`; none without them).
    """
    try:
        from .association.linking import GlobalLinker
    except ImportError:  # linking not available: tracklets are the tracks
        log.warning("global linking unavailable; tracklets are reported as tracks")
        return _renumber(tracklets)
    if len(tracklets) >= 500:  # minutes of work after the progress bar reached its end
        log.info("global linking of %d tracklets", len(tracklets))
    linker = GlobalLinker(config.linking, config.context, fps, metres_per_unit=metres_per_unit)
    if roads is not None:
        linker.predictor.roads = roads
    tracks = linker.link(tracklets, frame_size=frame_size, registrations=registrations or None)
    if detections is not None and config.finish.enabled:
        from .association.finish import TrackFinisher
        from .association.regain import regain_gap_detections

        TrackFinisher(config.finish, fps)  # its settings checked before they are used
        regain_gap_detections(tracks, detections, fps=fps, max_gap_s=config.finish.regain_gap_s,
                              min_iou=config.finish.regain_iou,
                              end_s=config.finish.regain_end_s,
                              registrations=registrations or None,
                              still_H=None if registrations else still_H)
    from .association.finish import finish_tracks  # smoothed boxes, static tracks out

    tracks = finish_tracks(tracks, config.finish, fps, metres_per_unit=metres_per_unit or linker.mpu,
                           registrations=registrations or None, frame_size=frame_size,
                           scale_estimated=not metres_per_unit,
                           still_H=None if registrations else still_H)
    return _renumber(tracks)


#: Observed points per tracklet that keep their appearance data (first, last and evenly spread).
APPEARANCE_KEEP = 16


def drop_on_overlay(tracklets: Iterable[Track], detections: list[Detections], mask: np.ndarray
                    ) -> tuple[list[Track], list[Detections]]:
    """The tracklets and detections not on an on-screen overlay (``mask``, frame pixels): its
    pixels were left out of detection from the moment it was found; what came before (the first
    second or two of the camera's motion) goes now. A tracklet goes when most of its observed
    boxes centre on it."""
    kept = []
    dropped = 0
    for t in tracklets:
        obs = np.array([[p.box[0] + p.box[2] / 2, p.box[1] + p.box[3] / 2] for p in t.points
                        if p.kind == "observed" and p.box is not None]).reshape(-1, 2)
        if len(obs) and (~_outside(mask, obs)).mean() > 0.5:
            dropped += 1
        else:
            kept.append(t)
    before = sum(len(d) for d in detections)
    detections = [d.subset(_outside(mask, d.centers)) if len(d) else d for d in detections]
    n = before - sum(len(d) for d in detections)
    if dropped or n:
        log.info("on-screen overlay: %d tracklets and %d detections on it, from before it was "
                 "found, dropped", dropped, n)
    return kept, detections


def _outside(mask: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Which frame-pixel ``centers`` fall outside ``mask`` (True pixels; outside the frame:
    outside)."""
    h, w = mask.shape
    x = np.clip(np.floor(centers[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.floor(centers[:, 1]).astype(int), 0, h - 1)
    return ~mask[y, x]


def _light(dets: Detections) -> Detections:
    """The detections without appearance arrays: what outputs need, so a long run's memory is not
    held by per-blob histograms and descriptors (the checkpoints keep the full data)."""
    if dets.hist is None and not dets.extra:
        return dets
    return Detections(frame=dets.frame, boxes=dets.boxes, conf=dets.conf, world=dets.world,
                      mapxy=dets.mapxy, lonlat=dets.lonlat, size_world=dets.size_world)


def _thin_appearance(tracklet: Track, keep: int = APPEARANCE_KEEP) -> Track:
    """Keep appearance (``hist``, ``desc``, as float32) on at most ~``3 * keep`` observed points of
    a finished tracklet: its first and last ``keep`` and ``keep`` evenly spread between.

    Global linking compares a tracklet's ends and its accumulated descriptor; a descriptor summed
    over a few dozen blobs is as good as over thousands, and this bounds memory per tracklet
    instead of growing with its length.
    """
    obs = [i for i, p in enumerate(tracklet.points) if p.hist is not None or p.desc is not None]
    for i in obs:  # float32 halves what long runs hold; the linker sums in float64
        p = tracklet.points[i]
        if p.hist is not None:
            p.hist = np.asarray(p.hist, dtype=np.float32)
        if p.desc is not None:
            p.desc = np.asarray(p.desc, dtype=np.float32)
    if len(obs) <= 3 * keep:
        return tracklet
    spread = np.linspace(keep, len(obs) - keep - 1, keep).round().astype(int)
    kept = {*obs[:keep], *obs[-keep:], *(obs[i] for i in spread)}
    for i in obs:
        if i not in kept:
            p = tracklet.points[i]
            p.hist = None
            p.desc = None
    return tracklet


def _renumber(tracks: list[Track]) -> list[Track]:
    """Ids 1..N in order of first appearance (stable output for the same input)."""
    tracks = [t for t in tracks if t.points]
    tracks.sort(key=lambda t: (t.first, t.points[0].world[0], t.points[0].world[1]))
    for i, t in enumerate(tracks, start=1):
        t.id = i
    return tracks


def run(source=None, *, config: Config | None = None, fps: float | None = None,
        geomap: GeoMap | None = None, H_init: np.ndarray | None = None, seed: int = 0,
        detections: np.ndarray | str | Path | None = None, metres_per_unit: float | None = None,
        progress: Callable[[int], None] | None = None, start: int = 1, stop: int | None = None,
        stride: int = 1, checkpoint_dir: Path | None = None, resume: bool = False,
        checkpoint_every: int = 300, undistort: Callable[[Frame], Frame] | None = None,
        regions: list | None = None, min_speed_mps: float | None = None, roads=None,
        stabilised: bool = False, H_init_frame: int = 1) -> Result:
    """Track a whole video (pull API).

    Parameters
    ----------
    source : FrameSource or path, optional
        Frames (a path is opened with :func:`aerotrack.io.open_source`); may be None when
        ``detections`` is given (association alone, image coordinates). Frames already in memory:
        feed :class:`Pipeline` one :class:`~aerotrack.types.Frame` at a time (``step``, then
        ``finish``), or wrap them in a :class:`~aerotrack.io.frames.FrameSource`.
    config : Config or dict, optional
        Settings (:func:`aerotrack.config.load_config` reads a file and ``section.key=value``
        overrides, as ``--config`` and ``--set`` do; a dict of sections is read as a file is);
        default :class:`~aerotrack.config.Config`.
    fps : float, optional
        Frame rate; default the source's.
    geomap : GeoMap, optional
        The map (:class:`aerotrack.geo.GeoMap`): world coordinates are then its pixels, and
        tracks get map and lon/lat positions.
    seed : int
        Seed of every random choice: the same input, config and seed give the same tracks.
    start, stop, stride : int
        1-based first and last frame (inclusive; ``stop`` None: the last) and the step between
        frames processed, as ``--frames A:B`` and ``--stride``.
    detections : ndarray (N, 6..10) or path, optional
        External MOT detection rows (1-based frames), or a MOTChallenge file of them; they
        replace the built-in detector.
    H_init : ndarray (3, 3), optional
        Frame ``H_init_frame`` (1: the video's first, whatever ``start`` is) -> ``geomap`` pixels;
        needed with a map. When ``start`` is later, the frames between are registered first to
        carry the placement to frame ``start`` (it was taken as frame ``start``'s: 155 map pixels
        off at frame 300 of a generated scene).
    H_init_frame : int
        The frame ``H_init`` places (the command line passes ``start``: it has carried it).
    progress : callable, optional
        Called with the number of frames done after each frame. A ``KeyboardInterrupt`` (Ctrl-C,
        a notebook's interrupt, or raised by ``progress`` to stop early) carries the
        :class:`Pipeline` as ``exc.pipeline``: ``exc.pipeline.finish()`` gives the tracks of the
        frames done (linking them takes a moment), as ``checkpoint_dir`` and ``resume`` keep them
        across processes.
    checkpoint_dir : path, optional
        Folder for checkpoints (``DIR/.partial``): finished work is saved every
        ``checkpoint_every`` frames and on Ctrl-C.
    resume : bool
        Continue from the checkpoints in ``checkpoint_dir``.
    undistort : callable, optional
        Applied to every frame first (``geo.lens.Undistorter``).
    regions : list of geo.roi.Region, optional
        Detections outside an include region or inside an ignore region are dropped.
    min_speed_mps : float, optional
        Tracks that never move faster than this are dropped (parked vehicles).
    roads : aerotrack.context.roads.RoadNetwork, optional
        Road centre-lines in map pixels (``read_roads(path, geomap=geomap)``): the motion
        context predicts unobserved vehicles along them.
    stabilised : bool
        The frames are already registered to each other (a stabilised video, a fixed camera):
        identity homographies instead of the registrar; not with a map.

    Returns
    -------
    Result
        ``tracks`` (linked and finished, world coordinates), ``registrations``, ``detections``
        and timings; :func:`aerotrack.outputs.track_rows` gives the rows of ``tracks.csv``.

    Raises
    ------
    InputError, ConfigError
        Bad input or settings (both are ``ValueError``), named in one line.

    Examples
    --------
    >>> from aerotrack import io, pipeline
    >>> src = io.open_source("flight.mp4")                      # doctest: +SKIP
    >>> result = pipeline.run(src)                               # doctest: +SKIP
    >>> for track in result.tracks: print(track.id, track.world()[:3])  # doctest: +SKIP
    """
    config = as_config(config)
    if source is None and detections is None:
        raise InputError("give an INPUT video/folder or --detections")
    source, detections, H_init = _api_inputs(source, detections, H_init, geomap, fps,
                                             config.detection.min_conf)
    _check_range(source, start, stop, stride)
    if fps is None:
        fps = source.fps if source is not None else 30.0
    per_frame = _group_rows(detections) if detections is not None else None
    pipe = Pipeline(config, fps, geomap=geomap, H_init=H_init, seed=seed, detections=per_frame,
                    metres_per_unit=metres_per_unit, checkpoint_dir=checkpoint_dir,
                    checkpoint_every=checkpoint_every, undistort=undistort, regions=regions,
                    min_speed_mps=min_speed_mps, roads=roads, stabilised=stabilised)
    if stride > 1 and pipe.associator is not None:
        pipe.associator.set_frame_step(stride)
    resumed = None
    if resume and checkpoint_dir is not None:
        restart = pipe.restore(source)
        if restart > start:
            # keep the stride grid of the original run (exact: the next grid frame not taken)
            steps = restart - start
            steps = -(-steps // stride) if pipe.exact_resume else steps // stride
            start = start + steps * stride
            log.info("resuming from frame %d", start)
            resumed = {"from_frame": int(start), "exact": bool(pipe.exact_resume)}
    if not pipe.registrations:  # nothing restored: H_init places the first frame read
        pipe._H_init = carried_placement(source, H_init, H_init_frame, start, geomap, fps,
                                         config, undistort)
    done = 0
    stepping = False  # inside Pipeline.step: its stages' state is not between two frames
    try:
        if source is None:
            last = int(detections[:, 0].max()) if len(detections) else 0
            stop = last if stop is None else min(stop, last)
            for index in range(start, stop + 1, stride):
                if index > pipe.last_frame:
                    pipe.step_detections_only(index)
                done += 1
                if progress:
                    progress(done)
        else:
            for frame in read_ahead(source.frames(start=start, stop=stop, stride=stride)):
                stepping = True
                pipe.step(frame)
                stepping = False
                done += 1
                if progress:
                    progress(done)
    except KeyboardInterrupt as exc:
        exc.pipeline = pipe  # the work so far: ``exc.pipeline.finish()`` links and finishes it
        exc.between_frames = not stepping  # (only then is finishing it exact)
        pipe.checkpoint()
        exact = not stepping and pipe.save_state()
        if not exact and isinstance(getattr(exc, "note", None), str) and exc.note:
            # a second Ctrl-C inside a frame: only the checkpoints are kept
            exc.note += ("; the working state was not saved (stopped inside a frame), so --resume "
                         "restarts a little earlier and may decide a few frames differently")
        raise
    result = pipe.finish()
    result.resumed = resumed
    return result


def carried_placement(source, H_init, H_init_frame: int, start: int, geomap, fps: float,
                      config: Config, undistort=None):
    """``H_init`` (frame ``H_init_frame`` -> map pixels) carried to frame ``start`` when that is
    later and there are a map and frames (:func:`~aerotrack.registration.registrar.carry_placement`);
    else ``H_init`` as it is."""
    if geomap is None or H_init is None or source is None or start <= H_init_frame:
        return H_init
    from .registration.registrar import carry_placement

    log.info("registering frames %d-%d to carry the map placement of frame %d to frame %d",
             H_init_frame, start - 1, H_init_frame, start)
    return carry_placement(source, H_init, start, geomap, fps, config.registration, undistort,
                           first=H_init_frame)


def detect(source, *, config: Config | None = None, geomap: GeoMap | None = None,
           H_init: np.ndarray | None = None, metres_per_unit: float | None = None,
           start: int = 1, stop: int | None = None, stride: int = 1,
           undistort: Callable[[Frame], Frame] | None = None, regions: list | None = None,
           stabilised: bool = False, progress: Callable[[int], None] | None = None,
           debug: Callable[[tuple], None] | None = None, H_init_frame: int = 1) -> Result:
    """Registration and detection alone (``aerotrack detect``): the stages of :func:`run`, with the
    same options, so the detections equal those of a full run; no tracklet is made.

    Parameters
    ----------
    source : FrameSource
    H_init, H_init_frame : as in :func:`run` (frame ``H_init_frame``'s placement on the map,
        carried to ``start``).
    stabilised : bool
        The frames are registered to each other already: identity homographies (no map).
    progress : callable, optional
        Called with the number of frames done after each frame. An exception it raises (an
        interruption) stops the run: the result then holds the frames the detector had finished
        (all but the last half background window) and is attached to the exception as
        ``partial_result``.
    debug : callable, optional
        Called with ``(index, image, residual, boxes, stationary)`` of every finished frame
        (``MovingObjectDetector.debug_frames``).

    Returns
    -------
    Result
        ``tracks`` empty; ``registrations`` and ``detections`` (frame pixels, world coordinates)
        of every frame.

    Examples
    --------
    >>> from aerotrack import io, pipeline
    >>> result = pipeline.detect(io.open_source("flight.mp4"))       # doctest: +SKIP
    >>> sum(len(d) for d in result.detections)                      # doctest: +SKIP
    """
    config = as_config(config)
    if source is None:
        raise InputError("detect needs a source (a video, an image folder, or a FrameSource)")
    source, _, H_init = _api_inputs(source, None, H_init, geomap, None)
    _check_range(source, start, stop, stride)
    H_init = carried_placement(source, H_init, H_init_frame, start, geomap, source.fps, config,
                               undistort)
    pipe = Pipeline(config, source.fps, geomap=geomap, H_init=H_init,
                    metres_per_unit=metres_per_unit, undistort=undistort, regions=regions,
                    spill=False, associate=False, debug=debug is not None, stabilised=stabilised)
    detector = None

    def drain() -> None:
        if detector is not None and debug is not None:
            for item in detector.debug_frames:
                debug(item)
            detector.debug_frames.clear()

    def result() -> Result:
        dets = pipe.detections
        mask = pipe.overlay_mask
        if mask is not None:  # as track drops them: what came before the overlay was found
            _, dets = drop_on_overlay([], dets, mask)
        return Result(tracks=[], registrations=pipe.registrations, detections=dets,
                      fps=pipe.fps, frame_size=pipe.frame_size,
                      metres_per_unit=pipe.metres_per_unit, timings=dict(pipe.timings),
                      cpu_timings=dict(pipe.cpu_timings), frames=pipe.n_frames,
                      first_frame=pipe.first_frame or 1, last_frame=pipe.last_frame,
                      repeated_frames=list(pipe.repeated_frames),
                      thresholds=dict(pipe.thresholds), overlay_mask=mask)

    done = 0
    try:
        for frame in read_ahead(source.frames(start=start, stop=stop, stride=stride)):
            pipe.step(frame)
            detector = pipe.detector
            drain()
            done += 1
            if progress:
                progress(done)
        pipe.finish_local()  # flushes the detector's window (a second Ctrl-C may land here)
        drain()
    except BaseException as exc:
        exc.partial_result = result()
        raise
    return result()


def run_cached(stages: Path, *, config: Config | None = None, fps: float,
               geomap: GeoMap | None = None, seed: int = 0, metres_per_unit: float | None = None,
               frame_size: tuple[int, int] | None = None, regions: list | None = None,
               min_speed_mps: float | None = None, roads=None,
               still_H: np.ndarray | None = None) -> Result:
    """Association and linking alone, on the registrations and detections cached by an earlier
    run (its ``stages/`` folder): changing association parameters does not redo registration and
    detection. ``still_H``: that run's placement of detections without frames on its map
    (``summary.json``'s ``still_placement``), for the outputs."""
    from .io.checkpoint import load_chunks, load_thresholds

    config = as_config(config)
    what = "--from: cached stage"
    regs, dets, _ = load_chunks(stages, what)
    # a higher detection.min_conf (--min-conf) applies to the cached boxes too (it was ignored,
    # while config.toml said it was used); the earlier run already dropped those below its own
    floor = config.detection.min_conf
    dets = [d.subset(np.asarray(d.conf, float) >= floor) if len(d) and floor > 0 else d
            for d in dets]
    no_frames = not regs  # --detections without INPUT: no registrations, no frames
    if any(len(d) and d.hist is None for d in dets) and not no_frames:  # (without frames, the
        # first run compared motion only too: nothing to say)
        log.warning("%s: the cached detections carry no colour histograms (a --workers run keeps "
                    "them light): association compares motion only", stages)
    pipe = Pipeline(config, fps, geomap=geomap, seed=seed, detections={},
                    metres_per_unit=metres_per_unit, regions=regions, min_speed_mps=min_speed_mps,
                    roads=roads, H_init=still_H if no_frames else None)
    pipe.registrations.update(regs)
    pipe.thresholds.update(load_thresholds(stages, what))  # the noise hint's (clip_hints)
    pipe.frame_size = frame_size
    from .detection.overlay import OVERLAY_FILE, read_mask

    # the first run's on-screen overlay, applied to every frame here (that run found it a second
    # or two in and dropped what it had made of the frames before)
    pipe._given_overlay = read_mask(Path(stages) / OVERLAY_FILE)
    frames = sorted({*regs, *(d.frame for d in dets)})
    if frames:
        pipe.first_frame, pipe.last_frame, pipe.n_frames = frames[0], frames[-1], len(frames)
    # a --stride run cached every stride-th frame: association runs on that grid again (it ran
    # as if at every frame with the skipped ones missed, and --stride 15 gave no track at all)
    stride = int(np.gcd.reduce(np.diff(frames))) if len(frames) > 1 else 1
    if stride > 1 and pipe.associator is not None:
        pipe.associator.set_frame_step(stride)
    pipe._associate(sorted(dets, key=lambda d: d.frame))
    return pipe.finish()


def _check_range(source, start: int, stop: int | None, stride: int) -> None:
    """The frame range of the Python API checked as ``--frames`` is: an empty range, or one
    starting after the input's last frame, ran silently to an empty result."""
    if not (isinstance(start, (int, np.integer)) and start >= 1):
        raise InputError(f"start {start}: frames are numbered from 1")
    if stop is not None and stop < start:
        raise InputError(f"start {start}, stop {stop}: need start <= stop")
    if not (isinstance(stride, (int, np.integer)) and stride >= 1):
        raise InputError(f"stride {stride}: must be a positive integer")
    count = getattr(source, "count", None) if source is not None else None
    if count and start > count:
        raise InputError(f"start {start}: after the input's last frame ({count})")


def _api_inputs(source, detections, H_init, geomap, fps, min_conf: float = 0.0):
    """The Python API's inputs checked as the command line checks them: paths opened or read,
    arrays of the right shape (one-line :class:`InputError` instead of an error frames deep)."""
    from .io import open_source
    from .io.mot import check_detections, read_mot

    if isinstance(source, (str, Path)):
        source = open_source(source, fps)
    elif source is not None and not (hasattr(source, "frames") and hasattr(source, "fps")):
        raise InputError(f"source: expected a path or a FrameSource (aerotrack.io.open_source), "
                         f"got {type(source).__name__}")
    if isinstance(detections, (str, Path)):
        detections = read_mot(detections, option="detections", strict=True)
    elif detections is not None:
        try:
            d = np.asarray(detections, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("detections: expected an (N, 6..10) array of MOT rows") from None
        if d.size == 0 and not (d.ndim == 2 and d.shape[1] == 10):  # (a file's empty rows stay)
            d = np.zeros((0, 10))
        if d.ndim != 2 or not 6 <= d.shape[1] <= 10:
            raise InputError(f"detections: expected an (N, 6..10) array of MOT rows (frame, id, "
                             f"x, y, w, h, conf, ...), got shape {d.shape}")
        if not np.isfinite(d[:, :6]).all() or np.any(d[:, 0] < 1) \
                or np.any(d[:, 0] != np.round(d[:, 0])) or np.any(d[:, 4:6] <= 0):
            raise InputError("detections: frames must be 1-based integers and boxes finite with "
                             "sizes > 0 (as in a --detections file)")
        if d.shape[1] >= 7 and not np.isfinite(d[:, 6]).all():
            raise InputError(f"detections: row {int(np.argmax(~np.isfinite(d[:, 6])))} has a "
                             "non-finite confidence (as in a --detections file)")
        if d.shape[1] < 10:  # conf 1, x, y, z -1, as the file reader fills them
            d = np.hstack([d, np.array([1.0, -1.0, -1.0, -1.0])[d.shape[1] - 6:]
                           * np.ones((len(d), 1))])
        detections = d
    if detections is not None:  # the command line's checks and warnings (a file's or an array's)
        check_detections(detections, "detections", source, min_conf=min_conf)
    if H_init is not None:
        try:
            H = np.asarray(H_init, dtype=np.float64)
        except (TypeError, ValueError):
            H = np.zeros(0)
        if H.shape != (3, 3) or not np.isfinite(H).all() or abs(np.linalg.det(H)) < 1e-12:
            what = (f"shape {H.shape}" if H.shape != (3, 3) else
                    "non-finite values" if not np.isfinite(H).all() else "a singular matrix")
            raise InputError(f"H_init: expected an invertible 3x3 homography (frame 1 -> map "
                             f"pixels), got {what}")
        H_init = H
    if geomap is not None and H_init is None:
        raise InputError("geomap needs H_init (frame 1 -> map pixels; geo.read_map_init reads "
                         "a --map-init file)")
    return source, detections, H_init


def _group_rows(rows: np.ndarray) -> dict[int, np.ndarray]:
    """Given detection rows by frame, each frame's rows in a canonical order (by box, then
    confidence): the sampler's moves follow the detections' order, so the same boxes listed in
    another order gave other tracks (UAVDT M0101, rows shuffled within frames: HOTA 0.925 ->
    0.919)."""
    out: dict[int, np.ndarray] = {}
    if not len(rows):
        return out
    frames = rows[:, 0].astype(np.int64)
    order = np.lexsort((rows[:, 6], rows[:, 5], rows[:, 4], rows[:, 3], rows[:, 2], frames))
    rows, frames = rows[order], frames[order]
    cuts = np.flatnonzero(np.diff(frames)) + 1
    for chunk in np.split(rows, cuts):
        out[int(chunk[0, 0])] = chunk
    return out

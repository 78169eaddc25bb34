"""Segment-parallel processing: a long video split into overlapping segments, run on Dask workers.

Registration, detection and local association only look a bounded time around each frame (the
background window ``detection.window_s``, the association window ``association.window_s``), so a
long video can be cut into segments processed independently, provided neighbouring segments overlap
by at least those windows. Global linking, which looks across occlusions of many seconds, then runs
once over the tracklets of every segment, and links across segment joins as it links across
occlusions.

The steps, each a plain function usable without Dask:

1. :func:`plan_segments`: cut the frame range into ``K`` segments; segment ``k`` *owns* the frames
   between two cuts and *reads* a lead before (its warm-up) and a tail after them (what the
   windows need for its last owned frames to be decided as in one run; see
   :class:`ParallelConfig`), with cuts placed so that every segment reads about as many frames;
2. :func:`run_segment` (on a worker): :class:`~aerotrack.pipeline.Pipeline` over the frames the
   segment reads, up to :meth:`~aerotrack.pipeline.Pipeline.finish_local`. Without a map a segment's
   world is its own first frame's pixels;
3. :func:`join_segments`: express every segment's world in segment 0's world, keep each frame's
   registration and detections from the one segment that owns it, and stitch tracklets that cross
   a cut;
4. :func:`aerotrack.pipeline.link` over all tracklets.

:func:`run_parallel` does all of it on a ``distributed.Client``; :func:`dask_client` starts a local
cluster (processes on loopback, one thread each) or connects to an existing scheduler.

Where the wall time goes (:attr:`JoinReport.timeline`; ``benchmarks/parallel.py`` prints it). With
``K`` segments on ``K`` cores the floor is the largest segment's frames (owned plus overlap; 960 of
1800 for 2 segments at the default windows, 0.533 of the single process) plus what runs serially
after the last segment. What was cut, each measured: a segment of a video seeks to its first frame
(:meth:`~aerotrack.io.frames.VideoSource.frames`) instead of decoding every frame before it;
workers load the stages' code (imports, numba) while the cluster starts (:func:`warm_up_worker`: a warm worker's first segment
costs what its second does), and the client loads global linking's (:func:`warm_up_linking`: the
first link after the segments took 0.8-1.9 s cold, 0.13-0.2 s warm); the cluster's own
housekeeping is slowed down (:data:`WORKER_CONFIG`). What remains: the overlap (each of 2 segments
reads 6.7% more than half), a fixed start of about 0.2-0.3 CPU s per segment (the detector's first
window), segments that cost differently per frame (more vehicles, more association), and two
processes sharing the machine's caches; the join, linking and results' transfer took 0.2-0.3 s
together on the benchmark's 1800-frame video.

Chaining the worlds (no map): for a frame ``f`` read by segments ``k-1`` and ``k``, with ``H_j(f)``
its frame -> world_j homography, ``H_{0<-k} = H_{0<-k-1} @ H_{k-1}(f) @ inv(H_k(f))``. The estimate
of one frame carries that frame's registration noise, so ``H_{0<-k}`` is the least-squares
homography over a grid of points of every overlap frame registered by both segments.

With a map (``geomap`` and ``H_init``), every segment runs against the map as the single process
does (:attr:`ParallelConfig.map_every_segment`): a later segment first carries frame 1's placement
to its own first frame, registering every ``keyframe_s / 2`` of the frames before it and refining
against the map as a run does (:func:`~aerotrack.registration.registrar.carry_placement`), then
registers its frames on the map, refined every ``refine_every_s``. The join then keeps its map
pixels (``world_rms`` is the two segments' disagreement in the overlap as they are). Before, later
segments ran in their own first frame's pixels and were chained into map pixels, never refined: on
generated 1500- and 2400-frame scenes the second segment's corner error against the generator's
truth was median/max 0.27/0.91, 0.16/0.33 and 0.59/3.05 map pixels, and is 0.08/0.30,
0.06/0.18 and 0.07/0.45 now (the single process: 0.08/0.22, 0.06/0.24, 0.07/0.27), for a carry of
4-11 s of the segment's time. ``map_every_segment=False`` keeps the chained segments.

Differences from the single process (generated 900-frame videos at 15 frames/s, 2 segments, the
same code in every run; ``benchmarks/parallel.py`` measures them per join). Frames before the first
cut are identical. After it, a segment differs from the single process only where some stage's
state at the segment's first frame matters:

* periodic choices counted from a stage's first frame: the detector's background samples and
  background rebuilds (every 0.2 s), the registrar's keyframes (every 0.5 s; the frames it
  polishes). Segments therefore start on their common phase grid (:func:`phase_period`): off the
  detector's, 66 of the 450 frames after the cut had other detections, on it 8-10; on a 1800-frame
  480x270 video, aligning the keyframes too took the 2-segment run from HOTA -0.010 / IDF1 -0.031
  to +0.001 / -0.003. Local association cuts its window and seeds its MCMC at absolute frame numbers, so it
  needs no alignment (before it did, the random stream restarting at each segment's start moved
  HOTA/IDF1 by as much as another seed does: up to 0.02 IDF1);
* the detector's held stopped vehicles (``detection.hold_stopped``): a segment does not know
  about a vehicle that stopped before its first frame, and, worse, holding from its very first
  frame freezes what a one-sided background window detects then (a vehicle still in the median)
  for up to ``detection.max_hold_s``. Segments hold only after half their warm-up
  (:attr:`ParallelConfig.hold_after_s`): on the tests' 200-frame scene a segment start 5 frames
  earlier otherwise changed the detections of all 100 frames it owned (HOTA -0.055);
* segment k's world is its own first frame, chained to world 0 (0.03-0.05 px RMS), and the
  keyframes the registrar takes early (features lost) are not on the grid, so the background is
  resampled with another sub-pixel phase and borderline blobs change (the remaining 10 of 450,
  62 of 900 frames, spread over the segment, not gathered after the cut).

Joins themselves (tracklets crossing a cut are stitched when they coincide in the overlap) split
or merged at most one track per join on the benchmark videos; see
``benchmarks/results/parallel*.json`` (``joins``).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import pickle
import shutil
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .config import Config
from .errors import ConfigError, InputError, OutputError, install_extra
from .geo.init import placement_fingerprint
from .pipeline import Pipeline, Result, _group_rows, link
from .registration.chain import normalize
from .types import Detections, Registration, Track, TrackPoint, apply_homography, local_scales

log = logging.getLogger(__name__)

#: Environment of worker processes: one OpenMP/BLAS/numba thread each (the parallelism is the
#: processes; nested thread pools on a 2-core machine only add contention).
THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}

#: Dask settings of a local cluster (scheduler, nannies, workers). Its processes' housekeeping
#: runs beside the tasks on the same cores (and, in a worker, takes the GIL from its task thread):
#: no statistical profiler (it samples the task thread's stack every 10 ms and only feeds the
#: dashboard, which local clusters do not start); the event-loop health check every 1 s instead
#: of 20 ms, the memory monitor every 1 s instead of 0.1 s, system statistics every 2 s instead of
#: 0.5 s; no work stealing (each segment is one long task, placed once). Measured: an idle
#: 2-worker cluster used 6.4-8.1% of a core with Dask's defaults, 1.2-1.5% with these.
#: glibc's allocator as in a single process: Dask starts its workers with
#: ``MALLOC_TRIM_THRESHOLD_=65536``, and setting any malloc threshold turns off glibc's sliding
#: mmap threshold, so every array over 128 kB (each frame and its every temporary) was mapped and
#: unmapped again, its pages zeroed by the kernel each time: a generated 1080p scene (300 frames,
#: 2 workers) made 9.2 M page faults, 21 s of system time and ran 100 s; with the thresholds a
#: single process reaches by itself (trim 128 MB, mmap 32 MB, glibc's largest) 0.27 M, 2.2 s and
#: 44 s, tracks identical (a 4K survey probe: 62 M faults, 2.2x the single process's wall time).
WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": str(2**27),
                 "distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": str(2**25),
                 "distributed.worker.profile.enabled": False,
                 "distributed.admin.tick.interval": "1s",
                 "distributed.worker.memory.monitor-interval": "1s",
                 "distributed.admin.system-monitor.interval": "2s",
                 "distributed.scheduler.work-stealing": False}

GOOD_STATUS = ("ok", "refined")



def sum_mcmc(counts: list[dict | None]) -> dict | None:
    """The segments' MCMC counts added up per move (None when no segment associated)."""
    given = [c for c in counts if c]
    if not given:
        return None
    out: dict = {"proposed": {}, "accepted": {}}
    for c in given:
        for kind, total in out.items():
            for move, n in c[kind].items():
                total[move] = total.get(move, 0) + int(n)
    return out

@dataclass(frozen=True)
class ParallelConfig:
    """How a video is cut into segments.

    Attributes
    ----------
    segment_s : float
        Target length of the part of the video each segment owns, in seconds. Shorter segments
        spread better over many workers but repeat the overlap more often (each segment reads
        ``overlap_s`` more than it owns).
    overlap_s : float or None
        Frames read by both neighbours, in seconds: the *lead* (frames before the cut, read by
        the later segment to warm up) plus the *tail* (frames after the cut, read by the earlier
        segment so that the frames it owns are final). None: lead
        ``detection.window_s + association.window_s`` plus the tail below. The lead is the
        warm-up: the detector settles more slowly after its first frame than its centred window
        alone suggests (held vehicles, background holes; measured on a generated 15 frames/s
        video: detections still differ from the single process's 4-6 s after a segment's start,
        and a 2.25 s lead cost 0.014 HOTA / 0.022 IDF1 where 4.5 s cost +0.004 / -0.000). Less
        than ``detection.window_s`` is refused.
    tail_s : float or None
        Frames read past the cut by the earlier segment, seconds (part of ``overlap_s``). None:
        what the windows need for the owned frames to be decided as in one run,
        ``detection.window_s / 2`` (the centred background window of the last owned frame) plus
        ``4/3 * association.window_s`` (an observation becomes final once the association window,
        which slides in batches of a third of itself, has passed it). Frames read beyond that
        only serve the stitching, which needs ``min_common`` frames. A longer tail costs time
        and changes nothing the segment owns; a shorter one leaves the last owned frames'
        association undecided when the segment ends (decided on a partial window).
    min_segments : int
        At least this many segments when the video is long enough (use the number of workers).
    match_px : float
        Stitching: two tracklets of neighbouring segments are the same target in an overlap frame
        when their box centres are within this many frame pixels (or 30% of the box's smaller
        side, if larger). Detections in the middle of the overlap are the same in both segments,
        so this only absorbs small differences.
    min_common : int
        Stitching: frames of the overlap in which two tracklets must coincide to be joined.
    hold_after_s : float or None
        Seconds after a segment's first frame (not the first segment's) before the detector starts
        keeping stopped vehicles in view (``detection.hold_stopped``); None: half the frames the
        segment reads before its first own frame. Holding from the very first frame freezes
        whatever a one-sided background window detects in the first frames (moving vehicles still
        in the median) for up to ``detection.max_hold_s``: measured on the tests' 200-frame scene,
        a segment starting 5 frames earlier had other detections in all 100 of its own frames
        (HOTA -0.055, IDF1 -0.085 against the single process), and -0.001 / -0.002 with
        this warm-up. 0 holds from the first frame.
    map_every_segment : bool
        With a map, every segment is registered against it, as the single process is: a later
        segment first carries the first frame's placement to its own first frame (frames
        registered every ``registration.keyframe_s / 2``, refined against the map; see
        :func:`~aerotrack.registration.registrar.carry_placement`), then runs on the map.
        False: only segment 0 runs on the map and later ones are chained into it over the
        overlap, never refined (their drift stays; cheaper by the carry).
    """

    segment_s: float = 60.0
    overlap_s: float | None = None
    tail_s: float | None = None
    min_segments: int = 1
    match_px: float = 3.0
    min_common: int = 2
    hold_after_s: float | None = None
    map_every_segment: bool = True

    def tail(self, config: Config) -> float:
        """The tail in seconds, resolved against the stage windows of ``config``."""
        if self.tail_s is not None:
            if self.tail_s < 0:
                raise ConfigError(f"tail_s {self.tail_s}: must not be negative")
            return float(self.tail_s)
        return config.detection.window_s / 2.0 + 4.0 / 3.0 * config.association.window_s

    def overlap(self, config: Config) -> float:
        """The overlap (lead + tail) in seconds, resolved against the stage windows of
        ``config``."""
        need = config.detection.window_s
        if self.overlap_s is None:
            return config.detection.window_s + config.association.window_s + self.tail(config)
        if self.overlap_s < need:
            raise ConfigError(f"overlap_s {self.overlap_s}: must be at least detection.window_s "
                              f"({need} s)")
        if self.tail_s is not None and self.tail_s > self.overlap_s:
            raise ConfigError(f"tail_s {self.tail_s}: must not exceed overlap_s "
                              f"({self.overlap_s} s)")
        return float(self.overlap_s)

    def plan(self, first: int, last: int, config: Config, fps: float, stride: int = 1
             ) -> list[Segment]:
        """:func:`plan_segments` with these settings and the phase grid of ``config``."""
        overlap = self.overlap(config)
        return plan_segments(first, last, fps=fps, stride=stride, segment_s=self.segment_s,
                             overlap_s=overlap, tail_s=min(self.tail(config), overlap),
                             min_segments=self.min_segments,
                             align=phase_period(config, fps, stride))


@dataclass(frozen=True)
class Segment:
    """One segment of a video (1-based frame numbers, inclusive ranges on the stride grid).

    Attributes
    ----------
    index : int
        0-based position in the plan.
    start, stop : int
        First and last frame the segment reads.
    own_start, own_stop : int
        First and last frame whose results come from this segment (between two cuts).
    """

    index: int
    start: int
    stop: int
    own_start: int
    own_stop: int

    def owns(self, frame: int) -> bool:
        return self.own_start <= frame <= self.own_stop


def plan_segments(first: int, last: int, *, fps: float, stride: int = 1, segment_s: float = 60.0,
                  overlap_s: float = 4.5, min_segments: int = 1, align: int = 1,
                  tail_s: float | None = None) -> list[Segment]:
    """Cut frames ``first, first+stride, ..., <= last`` into overlapping segments.

    Segment ``k`` owns the frames between its two cuts, reads ``tail_s`` more after its last
    cut (default: half the overlap) and ``overlap_s - tail_s`` more before its first, so
    neighbours share at least ``overlap_s``. A segment owns more than one overlap, so every frame
    is read by at most two segments; a video too short for two such segments is one segment.

    ``align`` (grid frames, see :func:`phase_period`): each segment starts reading a multiple of
    ``align`` grid frames after ``first``, so that the stages' periodic choices fall on the same
    frames as in one run.

    Cuts balance the frames each segment *reads* (owned frames plus its lead and tail, which the
    first and last segments lack), so that workers finish together: each cut is the one on the
    phase grid (``lead`` frames after a multiple of ``align``) nearest to the balanced position,
    so segments differ by less than ``align`` frames read and none reads more than its lead.

    Returns
    -------
    list of Segment
        Ordered; the owned ranges partition the grid frames.
    """
    if stride < 1:
        raise InputError(f"stride {stride}: must be at least 1")
    if segment_s <= 0:
        raise ConfigError(f"segment_s {segment_s}: must be positive")
    n = (last - first) // stride + 1 if last >= first else 0
    if n <= 0:
        return []
    grid = fps / stride
    tail_s = overlap_s / 2 if tail_s is None else min(max(0.0, tail_s), overlap_s)
    tail = max(1, math.ceil(tail_s * grid - 1e-9))
    lead = max(1, math.ceil(overlap_s * grid - 1e-9) - tail)
    align = max(1, int(align))
    per = max(1, round(segment_s * grid))
    k_max = max(1, n // (lead + tail + 1))
    k = min(max(min_segments, math.ceil(n / per)), k_max)
    # frames each segment reads outside its owned range; every cut but the first is placed so
    # that the segment after it starts on the phase grid with exactly ``lead`` frames before it
    extra = [(tail if j < k - 1 else 0) + (lead if j else 0) for j in range(k)]
    reads = (n + sum(extra)) / k
    cuts = [0]
    for j in range(1, k):
        target = j * reads - sum(extra[:j])
        snapped = lead + round((target - lead) / align) * align
        cuts.append(min(n - 1, max(cuts[-1] + 1, snapped)))
    cuts.append(n)
    out = []
    for j in range(k):
        own0, own1 = cuts[j], cuts[j + 1] - 1
        r0 = max(0, own0 - lead) if j else 0
        r1 = min(n - 1, own1 + tail)
        r0 -= r0 % align
        out.append(Segment(j, first + r0 * stride, first + r1 * stride,
                           first + own0 * stride, first + own1 * stride))
    return out


def phase_period(config: Config, fps: float, stride: int = 1) -> int:
    """Grid frames after which the stages' periodic choices repeat, counted from their first frame.

    The detector keeps a background sample every ``detection.sample_every_s`` and rebuilds the
    background every ``detection.update_every_s``, both counted from the first frame it sees. A
    segment that starts reading a multiple of this period after the video's first frame makes the
    same choices on the same frames as one process does (measured on a generated 900-frame video
    at 15 frames/s: a start off this grid changed the detections of 66 of the 450 frames after the
    cut, far from it as well; on it, 8). The rules are ``detection.MovingObjectDetector``'s (frames
    there, grid frames here). Local association needs nothing: it cuts its window and seeds its
    sampler at absolute frame numbers.
    """
    s = max(1, int(stride))
    det = config.detection
    from .detection.detector import frames_for

    every = frames_for(det.sample_every_s, fps)  # as the detector converts them
    update = frames_for(det.update_every_s, fps)
    # the registrar takes a keyframe every ``registration.keyframe_s`` (also earlier when too few
    # features are left, which this cannot foresee); its frames are the ones polished
    key = max(1, math.ceil(config.registration.keyframe_s * fps - 1e-6))
    period = 1
    for frames in (every, -(-update // s) * s, -(-key // s) * s):
        grid = frames // math.gcd(frames, s)  # grid frames in which `frames` frames recur
        period = period * grid // math.gcd(period, grid)
    return period


# -- the worker -----------------------------------------------------------------------------------
@dataclass
class SegmentTask:
    """Everything a worker needs to run one segment (picklable; the source is reopened there).

    ``input_path`` None means association alone on ``detections``. ``map_path``/``H_init`` only for
    a segment that starts at the video's first frame (see the module notes on maps).
    """

    segment: Segment
    input_path: str | None
    fps: float
    config: Config
    stride: int = 1
    seed: int = 0
    metres_per_unit: float | None = None
    map_path: str | None = None
    H_init: np.ndarray | None = None
    detections: np.ndarray | None = None  # (N, 10) MOT rows of the frames the segment reads
    hold_from: int | None = None  # first frame fed with detection.hold_stopped (None: all)
    undistort: Callable | None = None
    regions: list | None = None
    stabilised: bool = False  # frames already registered to each other: identity homographies
    #: With a map, for a segment after the first: the frame whose placement ``H_init`` is; the
    #: segment carries it to its own first frame and runs on the map (``map_every_segment``).
    carry_from: int | None = None
    #: ``H_init`` places frames on a ground plane in metres (``track --ground``, no map): every
    #: segment carries it and runs in that plane, as on a map.
    ground: bool = False


@dataclass
class SegmentResult:
    """What :func:`run_segment` returns, in the segment's own world coordinates."""

    segment: Segment
    registrations: dict[int, Registration]
    detections: list[Detections]
    tracklets: list[Track]
    frame_size: tuple[int, int] | None
    timings: dict[str, float] = field(default_factory=dict)
    pid: int = 0
    wall_s: float = 0.0  # the whole task on the worker: opening the input, reading, every stage
    cpu_s: float = 0.0  # CPU seconds of the worker process meanwhile (all its threads)
    #: Detections the stop follower added in the frames the segment owns (None: it is off).
    followed: int | None = None
    #: Local association's MCMC proposals and acceptances (``Result.mcmc``), or None.
    mcmc: dict | None = None
    started: float = 0.0  # time.time() on the worker when the task started and ended (the
    ended: float = 0.0  # timeline of a run: dispatch, imbalance, return of results)
    #: The segment's world is the map's pixels (registered against it), not its first frame's.
    on_map: bool = False
    #: On-screen overlay pixels the segment found (frame pixels), or None.
    overlay_mask: np.ndarray | None = None
    #: Frames of the segment repeating the one before exactly (Pipeline.repeated_frames).
    repeated_frames: list[int] = field(default_factory=list)
    #: Frame -> the detector's residual threshold, the segment's own frames (Pipeline.thresholds).
    thresholds: dict = field(default_factory=dict)


def limit_threads() -> None:
    """One OpenCV thread in this process (the environment variables cover OpenMP/BLAS when set
    before the libraries load; OpenCV's pool can still be changed now)."""
    import cv2

    cv2.setNumThreads(1)


def warm_up_worker(n: int = 24, size: tuple[int, int] = (160, 120)) -> float:
    """Import the stages and run them on ``n`` frames of noise, so that a worker's first segment
    does not pay for imports and compiled-code loading (done once per worker when the cluster
    starts; a failure here only leaves the worker cold). Returns the seconds it took."""
    import time

    t0 = time.perf_counter()
    try:
        import cv2

        from .types import Frame

        limit_threads()
        rng = np.random.default_rng(0)  # smooth texture drifting 1 px/frame, one moving box
        noise = rng.integers(0, 255, (size[1] + 16, size[0] + 16, 3), dtype=np.uint8)
        base = cv2.GaussianBlur(noise, (0, 0), 2)
        pipe = Pipeline(Config(), 10.0, metres_per_unit=0.3, spill=False)
        for k in range(n):
            img = base[k % 8:k % 8 + size[1], :size[0]].copy()
            cv2.rectangle(img, (20 + 3 * k, 50), (34 + 3 * k, 58), (255, 255, 255), -1)
            pipe.step(Frame(k + 1, img, k / 10.0))
        pipe.finish_local()
    except Exception as exc:  # noqa: BLE001 - a cold worker still works
        log.debug("worker warm-up failed: %s", exc)
    return time.perf_counter() - t0


def run_segment(task: SegmentTask) -> SegmentResult:
    """Registration, detection and local association over one segment (runs on a worker).

    Without a map the segment's world is the pixels of its first frame (``task.segment.start``).
    """
    import time

    started = time.time()
    t0, c0 = time.perf_counter(), time.process_time()
    limit_threads()
    seg = task.segment
    geomap = None
    if task.map_path is not None:
        from .geo import GeoMap

        geomap = GeoMap(task.map_path)
    per_frame = _group_rows(task.detections) if task.detections is not None else None
    hold_from = task.hold_from if task.config.detection.hold_stopped else None
    config = task.config
    if hold_from is not None and hold_from > seg.start:
        config = replace(config, detection=replace(config.detection, hold_stopped=False))
    H_init = task.H_init if geomap is not None or task.ground else None
    carry_s = 0.0
    if H_init is not None and task.carry_from is not None and task.input_path is not None \
            and seg.start > task.carry_from:
        from .io import open_source
        from .registration.registrar import carry_placement

        c0 = time.perf_counter()
        step = max(1, int(config.registration.keyframe_s * task.fps / 2))
        H_init = carry_placement(open_source(task.input_path, task.fps), H_init, seg.start, geomap,
                                 task.fps, config.registration, task.undistort,
                                 first=task.carry_from, stride=step)
        carry_s = time.perf_counter() - c0
    pipe = Pipeline(config, task.fps, geomap=geomap, H_init=H_init, seed=task.seed,
                    detections=per_frame,
                    metres_per_unit=None if geomap is not None else task.metres_per_unit,
                    undistort=task.undistort, regions=task.regions, stabilised=task.stabilised)
    if task.stride > 1 and pipe.associator is not None:
        pipe.associator.set_frame_step(task.stride)
    if pipe.follower is not None:
        pipe.follower.count_frames = (seg.own_start, seg.own_stop)
    if task.input_path is None:
        for index in range(seg.start, seg.stop + 1, task.stride):
            pipe.step_detections_only(index)
    else:
        from .io import open_source

        source = open_source(task.input_path, task.fps)
        for frame in source.frames(start=seg.start, stop=seg.stop, stride=task.stride):
            if config is not task.config and frame.index >= hold_from and pipe.detector is not None:
                pipe.detector.config = task.config.detection  # warm-up over: hold from now on
                config = task.config
            pipe.step(frame)
    tracklets = pipe.finish_local()
    timings = dict(pipe.timings)
    if carry_s:
        timings["carry"] = carry_s
    return SegmentResult(segment=seg, registrations=dict(pipe.registrations),
                         detections=list(pipe.detections), tracklets=list(tracklets),
                         frame_size=pipe.frame_size, timings=timings, pid=os.getpid(),
                         on_map=geomap is not None or task.ground,
                         overlay_mask=pipe.overlay_mask,
                         repeated_frames=[f for f in pipe.repeated_frames
                                          if seg.own_start <= f <= seg.own_stop],
                         thresholds={f: v for f, v in pipe.thresholds.items()
                                     if seg.own_start <= f <= seg.own_stop},
                         followed=None if pipe.follower is None else pipe.follower.n_followed,
                         mcmc=getattr(pipe, "mcmc", None),
                         wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
                         started=started, ended=time.time())


# -- the join -------------------------------------------------------------------------------------
@dataclass
class JoinReport:
    """How well the segments fitted together (for the summary and the tests).

    Attributes
    ----------
    world_rms : list of float
        Per join, RMS distance (world units) between where the two segments put the overlap
        frames' grid points after chaining (or as they are, when both segments were registered
        against the map): the registration disagreement at the join.
    stitched, cut : list of int
        Per join, tracklets stitched across the cut, and tracklets that crossed it unmatched (cut
        in two, left to global linking).
    segments : list of Segment
        The segments joined, in order (their ``own_stop`` are the cuts).
    segment_wall_s, segment_cpu_s : list of float
        Per segment, its task's wall time and CPU seconds on the worker
        (:attr:`SegmentResult.wall_s`, :attr:`SegmentResult.cpu_s`).
    timeline : dict
        Where the wall time of :func:`run_parallel` went, in seconds after the tasks were
        submitted (set by :func:`run_parallel` on a cluster): per segment ``started`` and
        ``ended`` (the task on its worker; clocks of remote workers may be offset) and
        ``received`` (its result in the client), then ``joined`` and ``linked`` (the client's
        join and global linking, which wait for the last segment), and ``client_cpu_s``, the
        client's CPU seconds meanwhile (join, linking, receiving results).
    """

    world_rms: list[float] = field(default_factory=list)
    stitched: list[int] = field(default_factory=list)
    cut: list[int] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    segment_wall_s: list[float] = field(default_factory=list)
    segment_cpu_s: list[float] = field(default_factory=list)
    timeline: dict = field(default_factory=dict)


def _grid(frame_size: tuple[int, int] | None, n: int = 4) -> np.ndarray:
    w, h = frame_size or (2.0, 2.0)
    xs, ys = np.meshgrid(np.linspace(0, w, n), np.linspace(0, h, n))
    return np.column_stack([xs.ravel(), ys.ravel()])


def chain_worlds(prev: dict[int, Registration], cur: dict[int, Registration], frames: Sequence[int],
                 frame_size: tuple[int, int] | None) -> tuple[np.ndarray, float]:
    """Homography world_cur -> world_prev from frames registered in both segments.

    Parameters
    ----------
    prev : dict of frame -> Registration
        The earlier segment's registrations, already in the target world (world 0).
    cur : dict of frame -> Registration
        The later segment's registrations, in its own world.
    frames : sequence of int
        Overlap frames.

    Returns
    -------
    H : ndarray (3, 3)
        Least-squares fit of ``H_prev(f) @ inv(H_cur(f))`` over a grid of frame points of every
        frame ``f`` registered well (``ok``/``refined``) by both; the identity when none is.
    rms : float
        RMS residual of the fit in target world units (NaN without frames).
    """
    import cv2

    grid = _grid(frame_size)
    src, dst = [], []
    for f in frames:
        a, b = prev.get(f), cur.get(f)
        if a is None or b is None or a.status not in GOOD_STATUS or b.status not in GOOD_STATUS:
            continue
        src.append(apply_homography(b.H, grid))
        dst.append(apply_homography(a.H, grid))
    if not src:
        return np.eye(3), float("nan")
    src_a, dst_a = np.vstack(src), np.vstack(dst)
    H, _ = cv2.findHomography(src_a, dst_a, 0)
    if H is None:
        return np.eye(3), float("nan")
    H = H / H[2, 2]
    rms = float(np.sqrt(np.mean(np.sum((apply_homography(H, src_a) - dst_a) ** 2, axis=1))))
    return H, rms


def world_disagreement(prev: dict[int, Registration], cur: dict[int, Registration],
                       frames: Sequence[int], frame_size: tuple[int, int] | None) -> float:
    """RMS distance (world units) between where two segments put a grid of frame points in the
    frames both registered, as they are (segments registered against the same map); NaN without
    such frames."""
    grid = _grid(frame_size)
    d = [apply_homography(a.H, grid) - apply_homography(b.H, grid)
         for f in frames if (a := prev.get(f)) is not None and (b := cur.get(f)) is not None
         and a.status in GOOD_STATUS and b.status in GOOD_STATUS]
    if not d:
        return float("nan")
    return float(np.sqrt(np.mean(np.sum(np.vstack(d) ** 2, axis=1))))


def _size_to(A: np.ndarray, world: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(N, 2) world sizes at (N, 2) world points, carried through homography ``A``: times its
    local scale there (sizes are box sides times a scale, not a direction that ``A`` rotates)."""
    return size * local_scales(A, world)[:, None]


def _move_detections(d: Detections, A: np.ndarray, geomap) -> Detections:
    if not len(d) or np.allclose(A, np.eye(3)):
        return d
    world = np.asarray(d.world, dtype=np.float64)
    size = None if d.size_world is None else _size_to(A, world, np.asarray(d.size_world, float))
    new_world = apply_homography(A, world)
    mapxy = lonlat = None
    if geomap is not None:
        mapxy = geomap.pixel_to_crs(new_world)
        lonlat = geomap.crs_to_lonlat(mapxy)
    return replace(d, world=new_world, size_world=size, mapxy=mapxy, lonlat=lonlat)


def _move_track(t: Track, A: np.ndarray) -> Track:
    """A copy of ``t`` with every point's world position and size carried through ``A``."""
    if not t.points:
        return Track(t.id, [])
    world = np.array([p.world for p in t.points], dtype=np.float64).reshape(-1, 2)
    new = apply_homography(A, world)
    has = [i for i, p in enumerate(t.points) if p.size_world is not None]
    sizes: dict[int, np.ndarray] = {}
    if has:
        sz = _size_to(A, world[has], np.array([t.points[i].size_world for i in has], float))
        sizes = dict(zip(has, sz))
    return Track(t.id, [replace(p, world=new[i], size_world=sizes.get(i))
                        for i, p in enumerate(t.points)])


def _centres(t: Track, lo: int, hi: int) -> dict[int, np.ndarray]:
    """Frame -> (x, y, min side) of the track's boxes in frames [lo, hi] (frame pixels)."""
    out = {}
    for p in t.points:
        if lo <= p.frame <= hi and p.box is not None:
            b = np.asarray(p.box, dtype=np.float64)
            if np.all(np.isfinite(b)):
                out[p.frame] = np.array([b[0] + b[2] / 2, b[1] + b[3] / 2, min(b[2], b[3])])
    return out


def stitch_pairs(left: Sequence[Track], right: Sequence[Track], lo: int, hi: int, *,
                 match_px: float = 3.0, min_common: int = 2) -> list[tuple[int, int]]:
    """Pairs (i, j) of ``left[i]`` and ``right[j]`` that are one target in the overlap [lo, hi].

    Two tracklets coincide in a frame when their boxes' centres (frame pixels, so independent of
    either segment's world) are within ``max(match_px, 0.3 * smaller box side)``; the score of a
    pair is the number of such frames, and pairs are chosen by maximum total score (Hungarian)
    among those with at least ``min_common`` frames.
    """
    from scipy.optimize import linear_sum_assignment

    lc = [_centres(t, lo, hi) for t in left]
    rc = [_centres(t, lo, hi) for t in right]
    li = [i for i, c in enumerate(lc) if c]
    ri = [j for j, c in enumerate(rc) if c]
    if not li or not ri:
        return []
    score = np.zeros((len(li), len(ri)))
    lspan = {i: (min(lc[i]), max(lc[i])) for i in li}
    rspan = {j: (min(rc[j]), max(rc[j])) for j in ri}
    for a, i in enumerate(li):
        for b, j in enumerate(ri):
            if lspan[i][1] < rspan[j][0] or rspan[j][1] < lspan[i][0]:
                continue
            common = lc[i].keys() & rc[j].keys()
            n = 0
            for f in common:
                p, q = lc[i][f], rc[j][f]
                if np.hypot(*(p[:2] - q[:2])) <= max(match_px, 0.3 * min(p[2], q[2])):
                    n += 1
            score[a, b] = n
    rows, cols = linear_sum_assignment(-score)
    return [(li[r], ri[c]) for r, c in zip(rows, cols) if score[r, c] >= min_common]


def join_segments(results: Sequence[SegmentResult], *, geomap=None,
                  match_px: float = 3.0, min_common: int = 2
                  ) -> tuple[dict[int, Registration], list[Detections], list[Track], JoinReport]:
    """Join segment results into one world (segment 0's) without duplicates.

    Returns
    -------
    registrations : dict of frame -> Registration
        Frame pixels -> world 0, each frame from the segment that owns it.
    detections : list of Detections
        In frame order, world coordinates in world 0 (and map CRS / lon-lat with a map).
    tracklets : list of Track
        Points of the owned frames only; tracklets crossing a cut are stitched into one when their
        points coincide in the overlap (:func:`stitch_pairs`), otherwise cut there.
    report : JoinReport
    """
    results = sorted(results, key=lambda r: r.segment.index)
    report = JoinReport(segments=[r.segment for r in results],
                        segment_wall_s=[r.wall_s for r in results],
                        segment_cpu_s=[r.cpu_s for r in results])
    frame_size = next((r.frame_size for r in results if r.frame_size), None)
    # 1. every segment's world in world 0
    moved_regs: list[dict[int, Registration]] = []
    moved_tracks: list[list[Track]] = []
    worlds: list[np.ndarray] = []  # world_k -> world 0
    for k, r in enumerate(results):
        if k == 0:
            A = np.eye(3)
        else:
            prev = results[k - 1].segment
            overlap = sorted(f for f in r.registrations if prev.start <= f <= prev.stop)
            if getattr(r, "on_map", False) and getattr(results[k - 1], "on_map", False):
                # both registered against the map already (a checkpoint from before: no field)
                A, rms = np.eye(3), world_disagreement(moved_regs[k - 1], r.registrations,
                                                       overlap, frame_size)
            else:
                A, rms = chain_worlds(moved_regs[k - 1], r.registrations, overlap, frame_size)
            report.world_rms.append(rms)
        regs = {f: (reg if k == 0 else replace(reg, H=normalize(A @ reg.H)))
                for f, reg in r.registrations.items()}
        moved_regs.append(regs)
        moved_tracks.append(
            r.tracklets if k == 0 else
            [_move_track(t, A) for t in r.tracklets])
        worlds.append(A)
    registrations: dict[int, Registration] = {}
    detections: list[Detections] = []
    for k, r in enumerate(results):
        seg = r.segment
        registrations.update({f: reg for f, reg in moved_regs[k].items() if seg.owns(f)})
        detections.extend(_move_detections(d, worlds[k], geomap if k else None)
                          for d in r.detections if seg.owns(d.frame))
    detections.sort(key=lambda d: d.frame)
    # 2. stitch across each cut
    succ: dict[tuple[int, int], tuple[int, int]] = {}
    for k in range(len(results) - 1):
        lo, hi = results[k + 1].segment.start, results[k].segment.stop
        pairs = stitch_pairs(moved_tracks[k], moved_tracks[k + 1], lo, hi,
                             match_px=match_px, min_common=min_common)
        for i, j in pairs:
            succ[(k, i)] = (k + 1, j)
        cut = results[k].segment.own_stop
        crossing = sum(1 for t in moved_tracks[k] if t.points and t.first <= cut < t.last)
        report.stitched.append(len(pairs))
        report.cut.append(max(0, crossing - len(pairs)))
    has_pred = set(succ.values())
    tracklets: list[Track] = []
    for k, tracks in enumerate(moved_tracks):
        for i in range(len(tracks)):
            if (k, i) in has_pred:
                continue
            points: list[TrackPoint] = []
            node: tuple[int, int] | None = (k, i)
            while node is not None:
                kk, ii = node
                seg = results[kk].segment
                points.extend(p for p in moved_tracks[kk][ii].points if seg.owns(p.frame))
                node = succ.get(node)
            if points:
                tracklets.append(Track(len(tracklets) + 1, points))
    return registrations, detections, tracklets, report


# -- the engine -----------------------------------------------------------------------------------
def _distributed():
    try:
        import distributed
    except ImportError:
        raise InputError(f"--workers/--scheduler need Dask: {install_extra('dask')}") from None
    return distributed


def check_scheduler(address: str, timeout: float = 5.0) -> None:
    """Refuse, within seconds, a ``--scheduler`` address that is not a running Dask scheduler.

    ``distributed.Client`` takes a malformed address with a traceback, retries a refused
    connection or a failed name lookup for its whole timeout, reads a non-Dask server's reply as
    a message length (an attempt to allocate exabytes: "out of memory"), and waits for ever on a
    server that waits for a request (an HTTP port, such as the dashboard's). Here the address is
    parsed, a plain TCP connection is tried, then Dask's own handshake and an ``identity``
    request are given ``timeout`` seconds each.

    Raises
    ------
    InputError
        One line naming ``--scheduler`` and what is wrong.
    """
    import asyncio
    import socket

    distributed = _distributed()
    from distributed.comm.addressing import parse_address, parse_host_port

    label = f"--scheduler {address}"
    try:
        scheme, loc = parse_address(address)
        host, port = parse_host_port(loc) if scheme in ("tcp", "tls") else (None, None)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{label}: not a scheduler address like tcp://host:8786 ({exc})") from None
    if scheme not in ("tcp", "tls", "ucx"):
        raise InputError(f"{label}: a Dask scheduler is reached by tcp://host:port (or tls://, "
                         f"ucx://), not {scheme}://")
    if port is not None and not 0 < int(port) < 65536:
        raise InputError(f"{label}: port {port} is not a TCP port (1-65535)")
    if host is not None:
        try:
            socket.create_connection((host, port), timeout=timeout).close()
        except OSError as exc:
            why = exc.strerror or type(exc).__name__
            raise InputError(f"{label}: cannot connect ({why})") from None

    async def identity():
        comm = await asyncio.wait_for(distributed.comm.connect(address, timeout=timeout), timeout)
        try:
            await asyncio.wait_for(comm.write({"op": "identity", "reply": True}), timeout)
            return await asyncio.wait_for(comm.read(), timeout)
        finally:
            comm.abort()

    try:
        reply = asyncio.run(identity())
    except TimeoutError:
        raise InputError(f"{label}: no Dask scheduler answered within {timeout:g} s (a "
                         "scheduler listens on tcp://host:8786 by default; 8787 is its "
                         "dashboard)") from None
    except Exception as exc:  # noqa: BLE001 - whatever a foreign server's bytes raise
        # (MemoryError: a foreign reply read as a frame length)
        raise InputError(f"{label}: not a Dask scheduler (reading its reply: "
                         f"{type(exc).__name__})") from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        raise InputError(f"{label}: not a Dask scheduler (it answered {str(reply)[:60]!r})")


@contextlib.contextmanager
def _children_ignore_sigint() -> Iterator[None]:
    """Start processes that ignore SIGINT (an ignored signal stays ignored in a child, and Python
    then installs no KeyboardInterrupt handler). Ctrl-C in a terminal goes to the whole process
    group: the local cluster's workers died of it mid-task while the main process, which stops
    gracefully after its current work, waited for their results forever. Now only the main
    process hears Ctrl-C; it cancels or collects the segments and closes the cluster."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator:
    """A ``distributed.Client``: on an existing scheduler, or on a new local cluster.

    Parameters
    ----------
    workers : int, optional
        Start a ``LocalCluster`` of this many worker processes on loopback, one thread each, with
        OpenMP/BLAS/numba limited to one thread (:data:`THREAD_ENV`); OpenCV is limited to one
        thread by each task.
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``); its workers must see the input files
        under the same paths.
    """
    distributed = _distributed()
    if scheduler is not None and workers is not None:
        raise InputError("--workers and --scheduler cannot be used together")
    if scheduler is not None:
        check_scheduler(scheduler)
        try:
            client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    if workers is None or workers < 1:
        raise InputError(f"--workers {workers}: must be at least 1")
    import dask

    # read by the scheduler, each worker's nanny and the client when they are created
    # Dask's own errors are shown with -vv only: a task's failure reaches the client as its
    # exception anyway, and on Ctrl-C the workers logged heartbeat tracebacks (CommClosedError)
    debug = logging.getLogger("aerotrack").getEffectiveLevel() <= logging.DEBUG
    with dask.config.set(WORKER_CONFIG), _children_ignore_sigint():
        cluster = distributed.LocalCluster(
            n_workers=int(workers), threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address=None, env=dict(THREAD_ENV),
            silence_logs=logging.ERROR if debug else logging.CRITICAL,
            # no dashboard; the scheduler's HTTP endpoints on a free loopback port, not 8787
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    try:
        with dask.config.set(WORKER_CONFIG):
            client = distributed.Client(cluster)
        try:
            # the client warms up global linking while the workers warm up: done during the
            # segments it would take CPU from them (2 workers on 2 cores)
            importer = threading.Thread(target=warm_up_linking, name="aerotrack-warm-up",
                                        daemon=True)
            importer.start()
            client.wait_for_workers(int(workers), timeout=120)
            client.run(warm_up_worker)
            importer.join()
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def n_workers(client) -> int:
    """Number of workers the client's scheduler has now (at least 1)."""
    return max(1, len(client.scheduler_info().get("workers", {})))


def make_tasks(input_path, *, config: Config, fps: float, segments: Sequence[Segment],
               stride: int = 1, seed: int = 0, metres_per_unit: float | None = None,
               map_path=None, H_init: np.ndarray | None = None,
               detections: np.ndarray | None = None, undistort: Callable | None = None,
               regions: Sequence | None = None,
               hold_after_s: float | None = None,
               frame_size: tuple[int, int] | None = None,
               stabilised: bool = False, map_every_segment: bool = True,
               ground: bool = False) -> list[SegmentTask]:
    """One :class:`SegmentTask` per segment (external detections cut to each segment's frames).

    With a map, later segments get frame 1's metres per pixel at its centre (``frame_size``, as
    the single process's detector takes it for its gates and model scale), else at its origin.

    ``hold_after_s``: see :attr:`ParallelConfig.hold_after_s` (segments after the first only).
    ``map_every_segment``: see :attr:`ParallelConfig.map_every_segment`.

    Regions in frame pixels go to every segment; regions in world coordinates only to segment 0
    (the others' worlds are not world 0 yet: :func:`assemble` applies them after the join).
    """
    regions = list(regions or [])
    mpu = metres_per_unit
    if map_path is not None:
        from .geo import GeoMap

        # later segments run in their first frame's pixels: scale of frame 1 on the map
        lin = np.asarray(H_init, dtype=np.float64)
        if frame_size:
            from .types import local_scale

            at = np.array([frame_size[0] / 2, frame_size[1] / 2])
            mpu = GeoMap(map_path).metres_per_pixel * local_scale(lin, at)
        else:
            mpu = GeoMap(map_path).metres_per_pixel * math.sqrt(abs(np.linalg.det(
                lin[:2, :2] / lin[2, 2])))
    tasks = []
    for seg in segments:
        rows = None
        if detections is not None:
            f = detections[:, 0]
            rows = detections[(f >= seg.start) & (f <= seg.stop)]
        # detections alone on a map: every segment's boxes go through the one still placement
        # (a later one ran in its own pixels and was chained by the tracklets it shares)
        with_map = map_path is not None and (seg.index == 0 or (
            map_every_segment and input_path is not None) or (
            input_path is None and H_init is not None))
        placed = with_map or (ground and (seg.index == 0 or input_path is not None))
        hold_from = None
        if seg.start > segments[0].start:
            lead = (seg.own_start - seg.start) / 2 if hold_after_s is None else hold_after_s * fps
            hold_from = seg.start + int(round(lead))
        tasks.append(SegmentTask(
            segment=seg, input_path=None if input_path is None else str(input_path), fps=fps,
            config=config, stride=stride, seed=seed, metres_per_unit=mpu,
            map_path=str(map_path) if with_map else None, H_init=H_init if placed else None,
            detections=rows, undistort=undistort, hold_from=hold_from,
            regions=[g for g in regions if seg.index == 0 or g.space == "frame"],
            stabilised=stabilised,
            carry_from=segments[0].start if placed and seg.index > 0 else None,
            ground=ground))
    return tasks


def submit_tasks(client, tasks: Sequence[SegmentTask], *, retries: int = 2, name: str = "segment"):
    """Submit segment tasks; a task whose worker died is re-run on another worker (the scheduler
    re-runs tasks of lost workers up to ``distributed.scheduler.allowed-failures`` times) and one
    that raised is retried ``retries`` times."""
    import uuid

    tag = uuid.uuid4().hex[:8]
    return [client.submit(run_segment, t, retries=retries, pure=False,
                          key=f"aerotrack-{name}-{t.segment.index}-{tag}") for t in tasks]


def _segment_file(folder: Path, task: SegmentTask) -> Path:
    """Checkpoint of one segment, named by its frames and a digest of everything else it depends
    on (so a resumed run with other settings does not pick up stale segments)."""
    import hashlib

    from .config import dumps_config

    h = hashlib.sha1()
    for part in (dumps_config(task.config), task.input_path, task.fps, task.stride, task.seed,
                 task.metres_per_unit, task.map_path, task.hold_from):
        h.update(repr(part).encode())
    if task.carry_from is not None:
        h.update(f"carry{task.carry_from}".encode())
    if task.ground:  # only then: digests of earlier runs stay valid
        h.update(b"ground" + np.asarray(task.H_init, np.float64).tobytes())
    if task.stabilised:  # only then: digests of earlier runs stay valid
        h.update(b"stabilised")
    for arr in (task.H_init, task.detections):
        h.update(b"-" if arr is None else np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    seg = task.segment
    return folder / (f"segment-{seg.start}-{seg.stop}-{seg.own_start}-{seg.own_stop}-"
                     f"{h.hexdigest()[:12]}.pkl")


#: Set once this process has run :func:`warm_up_linking` (imports and compiled code are loaded
#: once per process, so once is enough).
_LINKING_WARM = threading.Event()


def warm_up_linking() -> float:
    """Run global linking and the finish stage once on two small tracklets in this process (the
    client), so that the join does not pay for their cold start after the last segment: the
    imports (scipy.spatial, the contexts) and loading the numba-compiled Kalman and smoother
    functions from numba's cache took 0.8 s of the first :func:`aerotrack.pipeline.link` on a
    600-frame run and 0.2 s of the second (measured; the single process has loaded most of them
    by the time it links). Done while the cluster's workers warm up (:func:`dask_client`), else
    while the segments run. A failure only leaves the client cold. Returns the seconds it took.
    """
    import time

    t0 = time.perf_counter()
    if _LINKING_WARM.is_set():
        return 0.0
    try:
        from .pipeline import link

        def points(frames, y):  # a car driving 2 px/frame along x, 12x8 px boxes
            return [TrackPoint(f, np.array([10 + 2.0 * f, y, 12, 8]),
                               np.array([16 + 2.0 * f, y + 8.0]), 0.9,
                               size_world=np.array([12.0, 8.0])) for f in frames]

        # one target seen, lost for 5 frames, seen again (a link), and another one beside it
        tracklets = [Track(1, points(range(1, 21), 50.0)), Track(2, points(range(26, 46), 50.0)),
                     Track(3, points(range(5, 40), 120.0))]
        link(tracklets, Config(), 10.0, metres_per_unit=0.3, frame_size=(320, 240))
        _LINKING_WARM.set()
    except Exception as exc:  # noqa: BLE001 - a cold client still works
        log.debug("linking warm-up failed: %s", exc)
    return time.perf_counter() - t0


def gather_segments(client, tasks: Sequence[SegmentTask], *, retries: int = 2,
                    checkpoint_dir: Path | None = None, resume: bool = False,
                    progress: Callable[[int], None] | None = None,
                    while_waiting: Callable[[], None] | None = None,
                    received: dict[int, float] | None = None) -> list[SegmentResult]:
    """Run tasks on the cluster (``client``; None runs them here, in turn) and collect their
    results in segment order.

    With ``checkpoint_dir`` each finished segment is saved there (atomically) as it arrives, and
    with ``resume`` segments already saved are not run again. ``while_waiting`` is called once
    after the tasks are submitted to the cluster (client-side work that can overlap them).
    ``received``, when given, gets segment index -> ``time.time()`` when its result arrived.
    """
    import time

    from .io.output import atomic_write_bytes

    done: dict[int, SegmentResult] = {}
    folder = Path(checkpoint_dir) / "segments" if checkpoint_dir is not None else None
    todo = []
    for t in tasks:
        path = _segment_file(folder, t) if folder is not None else None
        if resume and path is not None and path.exists():
            with open(path, "rb") as fh:
                done[t.segment.index] = pickle.load(fh)
        else:
            todo.append(t)
    owned = {t.segment.index: (t.segment.own_stop - t.segment.own_start) // t.stride + 1
             for t in tasks}
    by_index = {t.segment.index: t for t in tasks}
    count = sum(owned[k] for k in done)
    if progress and count:
        progress(count)
    stopped: KeyboardInterrupt | None = None
    if todo:
        futures = []
        if client is None:  # in this process, one after the other
            finished = map(run_segment, todo)
        else:
            distributed = _distributed()
            futures = submit_tasks(client, todo, retries=retries)
            if while_waiting is not None:
                while_waiting()
            finished = (fut.result() for fut in distributed.as_completed(futures)
                        if fut.status != "cancelled")
        for res in finished:
            done[res.segment.index] = res
            if received is not None:
                received[res.segment.index] = time.time()
            if folder is not None:
                folder.mkdir(parents=True, exist_ok=True)
                atomic_write_bytes(_segment_file(folder, by_index[res.segment.index]),
                                   pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
            count += owned[res.segment.index]
            if progress and stopped is None:
                try:
                    progress(count)
                except KeyboardInterrupt as exc:  # a first Ctrl-C (a second one stops at once)
                    stopped = exc
                    if client is None:
                        break
                    # the segments running on the cluster are finished and kept, as the message
                    # promises; those still queued are not started (they dropped the running
                    # ones' work: the loop stopped at the first result)
                    running = {k for keys in client.processing().values() for k in keys}
                    queued = [f for f in futures if not f.done() and f.key not in running]
                    if queued:
                        client.cancel(queued)
    if stopped is not None:
        raise stopped
    return [done[t.segment.index] for t in tasks]


def assemble(results: Sequence[SegmentResult], *, config: Config, fps: float, geomap=None,
             metres_per_unit: float | None = None, stride: int = 1,
             parallel: ParallelConfig | None = None, regions: Sequence | None = None,
             min_speed_mps: float | None = None, roads=None,
             still_H: np.ndarray | None = None) -> tuple[Result, JoinReport]:
    """Join segment results and link all tracklets once: the :class:`~aerotrack.pipeline.Result`
    a single process would return (``timings`` sum the segments' stage times, plus ``join``), and
    the join's :class:`JoinReport`. ``roads``: a road network for the motion context, as in
    :func:`aerotrack.pipeline.link` (linking runs here, in the client, so it is never shipped to
    the workers). ``still_H``: detections alone on a map, the placement every segment gave
    their boxes (:meth:`aerotrack.pipeline.Pipeline.still_registration`)."""
    import time

    parallel = parallel or ParallelConfig()
    t0 = time.perf_counter()
    regs, dets, tracklets, report = join_segments(results, geomap=geomap,
                                                  match_px=parallel.match_px,
                                                  min_common=parallel.min_common)
    world_regions = [g for g in regions or [] if g.space != "frame"]
    if world_regions and len(results) > 1:
        dets, tracklets = _apply_world_regions(dets, tracklets, world_regions,
                                               results[0].segment.own_stop)
    # an overlay found in any segment: the whole run's (each segment left it out once found)
    masks = [m for m in (getattr(r, "overlay_mask", None) for r in results) if m is not None]
    overlay = np.logical_or.reduce(masks) if masks else None
    if overlay is not None:
        from .pipeline import drop_on_overlay

        tracklets, dets = drop_on_overlay(tracklets, dets, overlay)
    t1 = time.perf_counter()
    frame_size = next((r.frame_size for r in results if r.frame_size), None)
    mpu = geomap.metres_per_pixel if geomap is not None else metres_per_unit
    still_H = still_H if geomap is not None and not regs and frame_size is None else None
    tracks = link(tracklets, config, fps, metres_per_unit=mpu, frame_size=frame_size,
                  registrations=regs, roads=roads, still_H=still_H, detections=dets)
    if min_speed_mps:
        from .geo.roi import filter_min_speed
        from .pipeline import _renumber

        scale = mpu
        if not scale and tracks:  # as Pipeline.finish: the estimated ground scale, not pixels/s
            from .association.linking import estimate_scale

            scale = estimate_scale(tracks, config.context.image_object_size_m)
        tracks = _renumber(filter_min_speed(tracks, min_speed_mps, fps, scale))
    t2 = time.perf_counter()
    timings: dict[str, float] = {}
    for r in results:
        for k, v in r.timings.items():
            if k != "linking":
                timings[k] = timings.get(k, 0.0) + v
    timings["join"] = t1 - t0
    timings["linking"] = t2 - t1
    segs = [r.segment for r in results]
    frames = sum((s.own_stop - s.own_start) // stride + 1 for s in segs)
    # the frames decoded, not planned: a video whose end is corrupt stops before the count its
    # header gives (a 150-frame video with 49 decodable frames reported 150 frames here, 49 run
    # in one process)
    done = sorted(f for f in regs if any(s.own_start <= f <= s.own_stop for s in segs))
    if done:
        frames = min(frames, len(done))
    log.debug("joined %d segments: world rms %s, stitched %s, cut %s", len(segs),
             [round(x, 3) for x in report.world_rms], report.stitched, report.cut)
    result = Result(tracks=tracks, registrations=regs, detections=dets, fps=fps,
                    frame_size=frame_size, metres_per_unit=mpu, timings=timings, frames=frames,
                    first_frame=segs[0].own_start if segs else 1,
                    last_frame=(min(segs[-1].own_stop, done[-1]) if done else
                                segs[-1].own_stop if segs else 0),
                    followed=(None if all(getattr(r, "followed", None) is None for r in results)
                              else sum(getattr(r, "followed", None) or 0 for r in results)),
                    overlay_mask=overlay, mcmc=sum_mcmc([getattr(r, "mcmc", None) for r in results]),
                    repeated_frames=sorted(f for r in results
                                           for f in getattr(r, "repeated_frames", [])),
                    thresholds={f: v for r in results
                                for f, v in (getattr(r, "thresholds", None) or {}).items()},
                    still_H=still_H)
    return result, report


def _apply_world_regions(dets: list[Detections], tracklets: list[Track], regions: Sequence,
                         after: int) -> tuple[list[Detections], list[Track]]:
    """World-coordinate regions on the frames after ``after`` (segments > 0), once in world 0.

    Unlike the single process, which drops the detections before local association, this drops
    them and the observed tracklet points at them afterwards; a tracklet is otherwise unchanged.
    """
    out = []
    for d in dets:
        if d.frame > after and len(d):
            keep = np.ones(len(d), bool)
            for g in regions:
                keep &= g.keep_detections(d.centers, np.asarray(d.world, float))
            d = d.subset(keep)
        out.append(d)
    kept = []
    for t in tracklets:
        pts = [p for p in t.points
               if p.frame <= after or p.kind != "observed"
               or all(g.keep_detections(np.zeros((1, 2)), np.asarray(p.world, float)[None])[0]
                      for g in regions)]
        if pts:
            kept.append(Track(t.id, pts))
    return out, kept


def frame_range(source, detections: np.ndarray | None, start: int, stop: int | None,
                stride: int) -> tuple[int, int]:
    """First and last frame of a run (the last frame on the stride grid)."""
    if source is not None:
        count = source.count
        if count is None:
            raise InputError(f"{source.path}: frame count unknown; segments need it "
                             "(run without --workers)")
        last = count if stop is None else min(stop, count)
    else:
        last = int(detections[:, 0].max()) if detections is not None and len(detections) else 0
        last = last if stop is None else min(stop, last)
    if last < start:
        return start, start - 1
    return start, start + ((last - start) // stride) * stride


def run_parallel(source=None, *, client, config: Config | None = None, fps: float | None = None,
                 geomap=None, H_init: np.ndarray | None = None, seed: int = 0,
                 detections: np.ndarray | None = None, metres_per_unit: float | None = None,
                 progress: Callable[[int], None] | None = None, start: int = 1,
                 stop: int | None = None, stride: int = 1, checkpoint_dir: Path | None = None,
                 resume: bool = False, parallel: ParallelConfig | None = None,
                 retries: int = 2, with_report: bool = False,
                 undistort: Callable | None = None, regions: list | None = None,
                 min_speed_mps: float | None = None, checkpoint_every: int | None = None,
                 roads=None, stabilised: bool = False, H_init_frame: int = 1):
    """:func:`aerotrack.pipeline.run` with segments on a Dask cluster.

    Same parameters and result as :func:`~aerotrack.pipeline.run`, plus ``client`` (a
    ``distributed.Client``) and ``parallel``. The input is reopened by path on the workers, so
    they must see it under the same path. ``parallel.min_segments`` defaults to the number of
    workers. With ``with_report`` returns ``(Result, JoinReport)``. Checkpoints are whole
    segments (``checkpoint_every`` is accepted for the same signature and ignored).
    """
    config = config or Config()
    if source is None and detections is None:
        raise InputError("give an INPUT video/folder or --detections")
    if fps is None:
        fps = source.fps if source is not None else 30.0
    parallel = parallel or ParallelConfig(min_segments=n_workers(client))
    import time

    first, last = frame_range(source, detections, start, stop, stride)
    from .pipeline import carried_placement

    H_init = carried_placement(source, H_init, H_init_frame, first, geomap, fps, config, undistort)
    segments = parallel.plan(first, last, config, fps, stride)
    if not segments:
        raise InputError(f"no frames between {start} and {stop}")
    log.info("%d segment%s of about %d frames on %d workers", len(segments),
             "s" * (len(segments) != 1),
             (segments[0].own_stop - segments[0].own_start) // stride + 1, n_workers(client))
    tasks = make_tasks(source.path if source is not None else None, config=config, fps=fps,
                       segments=segments, stride=stride, seed=seed,
                       metres_per_unit=metres_per_unit,
                       map_path=geomap.path if geomap is not None else None, H_init=H_init,
                       detections=detections, undistort=undistort, regions=regions,
                       hold_after_s=parallel.hold_after_s,
                       map_every_segment=parallel.map_every_segment,
                       frame_size=getattr(source, "size", None), stabilised=stabilised,
                       # without a map, a placement is a ground plane's (track --ground)
                       ground=geomap is None and H_init is not None)
    submitted, cpu0, received = time.time(), time.process_time(), {}
    results = gather_segments(client, tasks, retries=retries, checkpoint_dir=checkpoint_dir,
                              resume=resume, progress=progress, while_waiting=warm_up_linking,
                              received=received)
    result, report = assemble(results, config=config, fps=fps, geomap=geomap,
                              metres_per_unit=metres_per_unit, stride=stride, parallel=parallel,
                              regions=regions, min_speed_mps=min_speed_mps, roads=roads,
                              still_H=H_init if source is None else None)
    linked = time.time() - submitted
    ran = [r for r in results if r.ended]  # run now, not loaded from a checkpoint
    report.timeline = {
        "started": [round(r.started - submitted, 3) for r in ran],
        "ended": [round(r.ended - submitted, 3) for r in ran],
        "received": [round(received[r.segment.index] - submitted, 3) for r in ran
                     if r.segment.index in received],
        "joined": round(linked - result.timings["linking"], 3), "linked": round(linked, 3),
        "client_cpu_s": round(time.process_time() - cpu0, 3)}
    return (result, report) if with_report else result


def run_on_dask(source=None, *, workers: int | None = None, scheduler: str | None = None,
                **kwargs) -> Result:
    """:func:`run_parallel` on a local cluster of ``workers`` processes or on ``scheduler``."""
    with dask_client(workers=workers, scheduler=scheduler) as client:
        return run_parallel(source, client=client, **kwargs)


# -- many videos ----------------------------------------------------------------------------------
VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".wmv", ".webm", ".ts",
                  ".mts", ".m2ts", ".flv", ".3gp", ".ogv", ".h264", ".264", ".h265", ".265",
                  ".hevc", ".mjpeg", ".mjpg"}


@dataclass(frozen=True)
class BatchItem:
    """One input of a batch: a video file or a folder of images, and its output folder.

    ``done`` when the output folder already holds a ``summary.json`` (written last by a run).
    """

    name: str
    input: Path
    out: Path
    done: bool


def plan_batch(input_dir, out_dir) -> list[BatchItem]:
    """Every video file and every image-folder sub-folder of ``input_dir``, sorted by name.

    Output folders are ``out_dir/<stem>``; when two inputs share a stem (``a.mp4``, ``a/``) both use
    their full name instead.
    """
    from .io.frames import IMAGE_SUFFIXES, SEQINFO

    input_dir, out_dir = Path(input_dir), Path(out_dir)
    if not input_dir.is_dir():
        raise InputError(f"{input_dir}: not a folder")
    found = []
    for p in sorted(input_dir.iterdir(), key=lambda p: p.name):
        if p.name.startswith("."):
            continue
        video = p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES and p.stat().st_size > 0
        # an image folder, or a MOTChallenge sequence (SEQ/seqinfo.ini, SEQ/img1/)
        if video or (p.is_dir() and ((p / SEQINFO).is_file() or any(
                q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES for q in p.iterdir()))):
            found.append(p)
    stems = [p.stem if p.is_file() else p.name for p in found]
    # stems alike but for case keep their suffixes too: Clip.AVI's Clip/ and clip.mkv's clip/
    # are one folder on macOS, Windows and exFAT
    folded = [s.casefold() for s in stems]
    # an earlier batch's folder by the stem alone is kept (its results are not redone), by its
    # exact name and for one input of a group alike but for case (on a case-insensitive disk
    # every one of them "exists")
    existing = set(os.listdir(out_dir)) if out_dir.is_dir() else set()
    kept: set[str] = set()
    items = []
    for p, stem in zip(found, stems):
        keep = (folded.count(stem.casefold()) > 1 and stem in existing
                and stem.casefold() not in kept)
        if keep:
            kept.add(stem.casefold())
        name = p.name if stems.count(stem) > 1 or (
            folded.count(stem.casefold()) > 1 and not keep) else stem
        out = out_dir / name
        src, dst = p.resolve(), out.resolve()
        if dst == src or src in dst.parents or dst in src.parents:
            # its results would replace the images (``--out`` = INPUT_DIR deleted every image
            # folder's frames and reported the batch a success)
            raise InputError(f"--out {out_dir}: the results of {p.name} would go to {out}, "
                             f"{'its own folder' if dst == src else 'inside or around it'}; give "
                             "an output folder apart from the inputs")
        items.append(BatchItem(name, p, out, (out / "summary.json").is_file()))
    return items


@contextlib.contextmanager
def _messages_named(name: str) -> Iterator[None]:
    """Messages logged meanwhile (any stage's) start with ``name``: a batch's lines say which
    input they are about."""
    class Prefix(logging.Filter):
        def filter(self, record: logging.LogRecord) -> bool:
            record.msg = f"{name}: {record.msg}"
            return True

    handlers = logging.getLogger("aerotrack").handlers
    f = Prefix()
    for h in handlers:
        h.addFilter(f)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(f)


def batch_changes(item: BatchItem, *, config: Config, fps: float | None, seed: int,
                  metres_per_unit: float | None, stride: int,
                  stabilised: bool = False, geomap=None,
                  run_info: dict | None = None, detections: str | None = None) -> list[str]:
    """What differs between the settings of this batch and those a finished item was tracked
    with (its ``summary.json`` and ``config.toml``): names of options, empty when alike or
    unknown (a folder from before these were recorded compares by its config alone)."""
    import json

    from .config import dumps_config

    try:
        summary = json.loads((item.out / "summary.json").read_text(encoding="utf-8"))
        stored = (item.out / "config.toml").read_text(encoding="utf-8")
    except (OSError, ValueError):
        return []
    changed = []
    before = summary.get("input")
    if isinstance(before, str) and before and Path(before) != Path(item.input).resolve():
        changed.append(f"input ({before})")  # another file of the same name, or a moved one
    # the first line naming the run's options (outputs.write_outputs) is not configuration
    stored = "".join(ln for ln in stored.splitlines(keepends=True)
                     if not ln.startswith("# run with:"))
    if stored != dumps_config(config):
        changed.append("--config/--set")
    if summary.get("seed", seed) != seed:
        changed.append("--seed")
    if summary.get("stride", stride) != stride:
        changed.append("--stride")
    if "gsd" in summary and summary["gsd"] != metres_per_unit:
        changed.append("--gsd")
    # (compared as it applies to this input: a video or sequence that names its rate keeps it)
    if "fps_given" in summary and summary["fps_given"] not in (fps, item_fps(item.input, fps)):
        changed.append("--fps")
    if bool(summary.get("stabilised", False)) != stabilised:
        changed.append("--stabilised")
    before_map = summary.get("map")
    now_map = str(Path(geomap.path).resolve()) if geomap is not None else None
    if (before_map or None) != now_map:
        changed.append("--map")
    elif now_map is not None and summary.get("placement") != placement_fingerprint(item.input):
        changed.append(f"placement on the map (its {summary.get('placement', '?').split()[0]} "
                       "is changed or replaced)")
    try:
        own = str(item_detections_path(item.input, detections).resolve()) if detections else None
    except InputError:
        own = None
    if summary.get("detections") != own:
        changed.append("--detections")
    elif own is not None and "detections_file" in summary \
            and summary["detections_file"] != file_fingerprint(Path(own)):
        changed.append(f"detections ({Path(own).name} changed since)")
    for key in BATCH_MAP_OPTIONS:  # --roads, --min-speed, --out-crs: absent when not given
        if summary.get(key) != (run_info or {}).get(key):
            changed.append("--" + key.replace("_", "-"))
    return changed


#: ``summary.json`` keys of the batch options that change a finished item's results.
BATCH_MAP_OPTIONS = ("roads", "min_speed", "out_crs")


#: In an interrupted batch item's ``.partial/``: the settings it was tracked with (JSON text).
BATCH_SETTINGS = "batch.json"


def _batch_settings(item: BatchItem, config: Config, fps, seed, metres_per_unit, stride,
                    stabilised, geomap=None, placement: dict | None = None,
                    detections: Path | None = None) -> str:
    import json

    from .config import dumps_config

    on_map = {"map": str(Path(geomap.path).resolve()), **(placement or {}),
              "placement": placement_fingerprint(item.input)} \
        if geomap is not None else {}  # (absent without a map: earlier batches' files match)
    own = {"detections": str(Path(detections).resolve()),
           "detections_file": file_fingerprint(detections)} if detections is not None else {}
    return json.dumps({"input": str(Path(item.input).resolve()), "fps": fps, "seed": seed,
                       "gsd": metres_per_unit, "stride": stride, "stabilised": stabilised,
                       **on_map, **own, "config": dumps_config(config)}, indent=1) + "\n"


def _interrupted_with(item: BatchItem, settings: str, resume: bool = True) -> bool:
    """True when ``item``'s output folder holds the checkpoints of a run interrupted with these
    settings and ``resume`` allows it (resume it); False for none, or other settings, or
    ``resume`` False (tracked again: then a warning says the interrupted run's frames are
    dropped, which the user might not expect)."""
    from .io.output import PARTIAL

    partial = Path(item.out) / PARTIAL
    if not any(partial.glob("chunk_*.npz")):
        return False
    try:
        same = (partial / BATCH_SETTINGS).read_text(encoding="utf-8") == settings
    except (OSError, ValueError):
        same = False
    if same and resume:
        return True
    why = ("--overwrite" if not resume else
           "its settings differ from this batch's (config, --fps, --seed, --gsd, --stride, "
           "--stabilised, --map or the file placing it there, --detections)")
    # (the batch's messages already start with the input's name)
    log.warning("an interrupted run in %s is not continued (%s): tracking it again from the "
                "first frame", item.out, why)
    return False


def _check_item_folder(item: BatchItem) -> None:
    """Refuse (as ``track --overwrite`` does) an item's output folder that holds files aerotrack
    did not write: the batch replaced its whole content, a user's notes included."""
    from .io.output import is_aerotrack_output

    if not item.out.is_dir():
        return
    foreign = sorted(e.name for e in item.out.iterdir() if not is_aerotrack_output(e.name))
    if foreign:
        raise OutputError(f"{item.out}: holds files aerotrack did not write (e.g. "
                          f"{foreign[0]!r}); move them, or give another --out")


def file_fingerprint(path) -> str | None:
    """A file's ``size mtime_ns`` (None when it is gone): a batch names an input whose
    detections file was regenerated in place since it was tracked."""
    try:
        st = Path(path).stat()
    except OSError:
        return None
    return f"{st.st_size} {st.st_mtime_ns}"


def item_detections_path(input_path, pattern: str) -> Path:
    """Where ``batch --detections PATTERN`` looks for an input's detections
    (:func:`item_detections`)."""
    p = Path(input_path)
    if "{name}" in pattern:
        return Path(pattern.replace("{name}", p.name if p.is_dir() else p.stem))
    if p.is_dir():
        return p / pattern
    raise InputError(f"--detections {pattern}: {p.name} is a video, not a folder; name each "
                     "video's file with {name} (dets/{name}.txt)")


def item_detections(input_path, pattern: str, source=None, *, zero_based: bool = False,
                    min_conf: float | None = None) -> tuple[np.ndarray, Path]:
    """A batch input's own detections (``batch --detections PATTERN``): ``(MOT rows, file)``.

    ``PATTERN`` with ``{name}`` names a file for each input by its name (a video's without its
    suffix): ``dets/{name}.txt``. Without it, it is a path inside each input folder:
    ``det/det.txt`` for MOTChallenge sequences (public detections). The rows are read and
    checked as ``track --detections`` reads them; a missing file is an :class:`InputError` for
    that input alone."""
    from .io.mot import check_detections, read_mot

    p = Path(input_path)
    path = item_detections_path(p, pattern)
    if not path.is_file():
        raise InputError(f"--detections {pattern}: no {path} for {p.name}")
    label = f"--detections {path}"
    rows, lines = read_mot(path, option="--detections", strict=True, zero_based=zero_based,
                           detections=True, lines=True)
    check_detections(rows, label, source, lines=lines, min_conf=min_conf)
    return rows, path


def item_fps(input_path, fps: float | None) -> float | None:
    """The ``--fps`` a batch gives one input: an image folder's rate, and a video's only when the
    video names none. A video's own rate is kept (a folder of 30 frames/s videos beside 10
    frames/s image sequences was all tracked at the rate given for the images)."""
    if fps is None:
        return fps
    if Path(input_path).is_dir():
        from .io.frames import mot_sequence

        try:
            seq = mot_sequence(input_path)
        except InputError:
            return fps  # (open_source reports it, for this input alone)
        if seq is None or seq[1] is None:
            return fps
        if abs(seq[1] - fps) > 1e-3 * fps:  # a sequence names its rate, as a video does
            log.info("%s: tracked at its own %g frames/s (seqinfo.ini; --fps %g is for image "
                     "folders and videos that name no rate)", input_path, seq[1], fps)
        return None
    from .io.frames import RAW_STREAM_SUFFIXES, cv_path

    if Path(input_path).suffix.lower() in RAW_STREAM_SUFFIXES:
        return fps  # FFmpeg's guess (25), not a rate the stream names
    import cv2

    cap = cv2.VideoCapture(cv_path(input_path))
    try:
        native = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else 0.0
    finally:
        cap.release()
    if native and math.isfinite(native) and native > 0:
        if abs(native - fps) > 1e-3 * fps:
            log.info("%s: tracked at its own %g frames/s (--fps %g is for image folders and "
                     "videos that name no rate)", input_path, native, fps)
        return None
    return fps


def run_batch(items: Sequence[BatchItem], *, config: Config | None = None, fps: float | None = None,
              seed: int = 0, metres_per_unit: float | None = None, stride: int = 1, client=None,
              parallel: ParallelConfig | None = None, stabilised: bool = False,
              progress: Callable[[int], None] | None = None, resume: bool = True,
              on_done: Callable[[BatchItem, dict | None, BaseException | None], None] | None = None,
              geomap=None, roads=None, min_speed_mps: float | None = None,
              out_crs: str | None = None, telemetry_defaults: Sequence[str] = (),
              run_info: dict | None = None, detections: str | None = None,
              detections_zero_based: bool = False,
              hints: Callable[..., list[str]] | None = None) -> dict[str, dict | BaseException]:
    """Track every unfinished item into its output folder.

    With ``geomap`` every item is tracked on that map, its frame 1 placed by the file beside it
    (:func:`aerotrack.geo.init.sidecar_placement`: ``NAME.map-init.txt`` or its flight log
    ``NAME.srt``; ``telemetry_defaults`` as ``--telemetry-default``); an item without one fails
    alone. ``roads``, ``min_speed_mps`` and ``out_crs`` are ``track``'s ``--roads``,
    ``--min-speed`` and ``--out-crs``; ``run_info`` goes into every ``summary.json`` (the
    command's options). ``detections``: each item's own detections replace the built-in
    detector (:func:`item_detections`). ``hints(result, config, detections_given=,
    input_path=, fps=, geomap=, metres_per_unit=, gsd=)`` gives each run's warnings (logged under
    its name and written to its ``summary.json``, as ``track`` does:
    :func:`aerotrack.cli.hints.run_hints`).

    Without ``client`` the videos run one after the other in this process. With a
    ``distributed.Client`` the segments of every video are submitted at once (so workers stay busy
    across videos) and each video is joined, linked and written here as its segments arrive.

    Returns
    -------
    dict
        Name -> the run's summary (as written to ``summary.json``), or the exception that stopped
        that item; finished items are not run. ``on_done(item, summary, error)`` is called after
        each item.

    In this process, ``progress`` is called after each frame of the item being tracked (and
    with 0 before each item, so that an interruption during the previous one's finish stops the
    batch there); an
    interruption it raises (``KeyboardInterrupt``) stops the batch with that item's checkpoints
    kept, and the next batch over the same inputs and settings resumes the item from them
    (``.partial/batch.json`` records the settings; it was tracked again from frame 1); ``resume``
    False tracks it again (``batch --overwrite``). With a client, ``progress(0)`` is called after
    each input is written (or has failed): an interruption it raises stops the batch between two
    inputs, and the segments of the inputs not yet joined are dropped with the client.
    """
    import time

    from .io import open_source
    from .io.output import OutputDir
    from .outputs import write_outputs
    from .pipeline import run

    config = config or Config()
    todo = [it for it in items if not it.done]
    sources: dict[str, object] = {}
    futures: dict[str, list] = {}
    out: dict[str, dict | BaseException] = {}

    def fail(it: BatchItem, exc: BaseException) -> None:
        log.warning("%s: %s", it.input, exc, exc_info=not isinstance(exc, (InputError, OutputError)))
        out[it.name] = exc
        if on_done:
            on_done(it, None, exc)

    given = {it.name: item_fps(it.input, fps) for it in todo}
    placed: dict[str, tuple[np.ndarray, dict, dict]] = {}  # name -> (H_init, notes, options)
    dets: dict[str, tuple[np.ndarray, Path]] = {}  # name -> (MOT rows, file)
    for it in todo:
        try:
            _check_item_folder(it)
            src = open_source(it.input, given[it.name])
            if detections is not None:
                dets[it.name] = item_detections(it.input, detections, src,
                                                zero_based=detections_zero_based,
                                                min_conf=config.detection.min_conf)
            if geomap is not None:
                from .geo.init import sidecar_placement

                placed[it.name] = sidecar_placement(it.input, src, geomap,
                                                    telemetry_defaults=telemetry_defaults)
            sources[it.name] = src
        except Exception as exc:  # noqa: BLE001  one bad input must not stop the batch
            fail(it, exc)
    if client is not None:
        per = parallel or ParallelConfig(min_segments=1)
        for it in todo:
            src = sources.get(it.name)
            if src is None:
                continue
            try:
                first, last = frame_range(src, None, 1, None, stride)
                segs = per.plan(first, last, config, src.fps, stride)
                tasks = make_tasks(src.path, config=config, fps=src.fps, segments=segs,
                                   stride=stride, seed=seed, metres_per_unit=metres_per_unit,
                                   hold_after_s=per.hold_after_s, stabilised=stabilised,
                                   map_path=geomap.path if geomap is not None else None,
                                   H_init=placed[it.name][0] if geomap is not None else None,
                                   map_every_segment=per.map_every_segment,
                                   frame_size=getattr(src, "size", None),
                                   detections=dets[it.name][0] if it.name in dets else None)
                futures[it.name] = (segs, submit_tasks(client, tasks, name=it.name))
            except Exception as exc:  # noqa: BLE001  as above: logged and returned per input
                fail(it, exc)
    for it in todo:
        src = sources.get(it.name)
        if src is None or it.name in out:
            continue
        if client is None and progress is not None:
            # an interruption that came while the previous input was being finished (linked,
            # written) stops the batch here, not after the next input's first frame
            progress(0)
        summary = error = folder = None
        again = False  # continuing an interrupted run (its checkpoints are kept whatever happens)
        with _messages_named(Path(it.input).name):  # whose run a message is about
            t0 = time.perf_counter()
            try:
                H_init, notes, where = placed.get(it.name, (None, {}, {}))
                if client is None:
                    settings = _batch_settings(it, config, fps, seed, metres_per_unit, stride,
                                               stabilised, geomap=geomap, placement=where,
                                               detections=dets.get(it.name, (None, None))[1])
                    again = _interrupted_with(it, settings, resume)
                    folder = OutputDir(it.out, resume=True, stage=True) if again else \
                        OutputDir(it.out, overwrite=True, stage=True)
                    from .io.output import atomic_write_text

                    atomic_write_text(folder.partial / BATCH_SETTINGS, settings)
                    if again:
                        log.info("%s: continuing the interrupted run in %s", it.input, it.out)
                    n_src = getattr(src, "count", None)
                    log.info("tracking (input %d of %d%s) -> %s", todo.index(it) + 1, len(todo),
                             f", {n_src} frames" if n_src else "", it.out)
                    result = run(src, config=config, fps=src.fps, seed=seed,
                                 metres_per_unit=metres_per_unit, stride=stride,
                                 checkpoint_dir=folder.partial, stabilised=stabilised,
                                 resume=again, progress=progress, geomap=geomap, H_init=H_init,
                                 roads=roads, min_speed_mps=min_speed_mps,
                                 detections=dets[it.name][0] if it.name in dets else None)
                else:
                    folder = OutputDir(it.out, overwrite=True, stage=True)
                    results = client.gather(futures[it.name][1])
                    result, _ = assemble(results, config=config, fps=src.fps, geomap=geomap,
                                         metres_per_unit=metres_per_unit, stride=stride,
                                         parallel=parallel, roads=roads,
                                         min_speed_mps=min_speed_mps)
                info = {"input": str(Path(it.input).resolve()), "seed": seed, "stride": stride,
                        "gsd": metres_per_unit, "fps_given": given[it.name],
                        **({"stabilised": True} if stabilised else {}),
                        **({"map": str(Path(geomap.path).resolve()),
                            "placement": placement_fingerprint(it.input),
                            "options": where} if geomap is not None else {}),
                        **({"detections": str(dets[it.name][1].resolve()),
                            "detections_file": file_fingerprint(dets[it.name][1])}
                           if it.name in dets else {}),
                        **(run_info or {}),
                        "wall_time_s": round(time.perf_counter() - t0, 3), **notes}
                said = hints(result, config, detections_given=it.name in dets,
                             input_path=it.input, fps=given[it.name], geomap=geomap,
                             metres_per_unit=metres_per_unit,
                             gsd=metres_per_unit) if hints is not None else []
                for hint in said:
                    log.warning(hint)
                if said:
                    info["hints"] = said
                summary = write_outputs(result, folder, config=config, geomap=geomap,
                                        run_info=info, out_crs=out_crs)
                if client is not None:  # the joined stages, as `aerotrack track --workers` keeps them
                    from .io.checkpoint import save_chunk

                    save_chunk(folder.partial, 0, [result.registrations[k]
                                                   for k in sorted(result.registrations)],
                               list(result.detections), result.thresholds)
                folder.finish(keep_as="stages")  # like `aerotrack track`: `track --from` reuses them
            except Exception as exc:  # noqa: BLE001  as above: logged and returned per input
                error = exc
                if isinstance(exc, InputError) and folder is not None and not again:
                    # a bad input (an unreadable frame): nothing to resume, so nothing kept, as
                    # `track` keeps nothing (its .partial/ was left, or a folder of only that)
                    shutil.rmtree(folder.partial, ignore_errors=True)
                    if folder.path.is_dir() and not any(folder.path.iterdir()):
                        folder.path.rmdir()
        if error is not None:
            fail(it, error)
        else:
            out[it.name] = summary
            if on_done:
                on_done(it, summary, None)
        if client is not None and progress is not None:
            progress(0)  # between two inputs: where a --workers batch stops on Ctrl-C
    return out

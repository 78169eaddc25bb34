"""Local data association: detections -> tracklets by data-driven MCMC (Yu & Medioni section 4).

:class:`LocalAssociator` consumes one frame of :class:`~aerotrack.types.Detections` at a time. Each
frame it

1. adds the frame's detections to the window's observation graph (:mod:`.graph`, eq. 3);
2. finalises observations that left the window (the paper: 45 frames = 1.5 s at 30 fps);
3. initialises the new frame's part of the partition from the previous one: a Hungarian
   assignment of the new detections to the live tracks' Kalman predictions (the link
   log-likelihood ratios of :mod:`.posterior`), then greedy births from chains of unassigned
   detections;
4. runs data-driven MCMC (:mod:`.moves`) over the whole window and keeps the best partition;
5. returns the tracklets that ended (no observation can extend them any more), dropping the short
   ones as false positives, with ``bridged`` points filling their short runs of missed detections.

:func:`associate` is the same as a pure function over a list of frames.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..config import AssociationConfig
from ..errors import ConfigError, InputError
from ..kalman import ConstantVelocityKF
from ..types import Detections, Track, Tracklet, TrackPoint
from .graph import HIST_EPS
from .moves import Prior, SamplerParams, WindowSampler, WTrack
from .posterior import iou_pairs, link_step, partial_candidates, score_matrix

#: Below this frame rate the link gate ``association.gate_chi2`` grows as ``LOW_RATE_FPS / fps``.
#: A link's score is ``0.5 (gate - d^2 - log det S/R)``, and between frames a second or half a
#: second apart the prediction's spread S (constant velocity with ``accel_std_mps2``) is so
#: wide that even an exact detection scores near 0 while a track must still earn
#: ``birth_cost`` within ``window_s`` (3 frames at 2 frames/s): at wide-area rates (1-3
#: frames/s) no track was ever born and a run wrote 0 tracks from good detections. Measured
#: on a generated 1080p scene kept at every 10th / 15th / 30th frame (a probe, 2026-12-03),
#: HOTA/IDF1 at the default gate 0/0 at 3, 2 and 1 frames/s; with this rule 0.797/0.940,
#: 0.772/0.930 and 0.512/0.654 (30 frames/s: 0.824/0.948); a fixed 50 gave 2 and 3 frames/s
#: as much but 1 frame/s nothing. Six held-out generated scenes (one per scenario) kept at 3 and
#: 2 frames/s: HOTA/IDF1 0/0 -> 0.652/0.812 and 0.570/0.696 (a fixed 50: 0.636/0.777 and
#: 0.580/0.738). At 10 frames/s and more nothing changes.
LOW_RATE_FPS = 10.0


class LocalAssociator:
    """Online MCMC association over a sliding window.

    Parameters
    ----------
    config : AssociationConfig
        Seconds and metres.
    fps : float
        Frame rate, turns seconds into frames.
    metres_per_unit : float, optional
        Metres per world unit. When None, estimated from the first detections' median size and
        ``config.target_size_m`` (or world units are taken as metres if that is 0).
    seed : int or numpy.random.Generator
        The same seed gives the same tracklets. The MCMC of each frame ``t`` draws from its own
        stream, ``numpy.random.default_rng([seed, t])`` (a Generator is turned into an integer
        seed once): the samples of a frame do not depend on how many frames came before, so a run
        started later in the video (a segment of :mod:`aerotrack.parallel`) draws the same numbers
        and, once its window has filled, reproduces the single process.

    Notes
    -----
    Tracklet ids are positive and unique per instance, given in the order the tracklets are
    emitted. A tracklet is emitted once, when it has ended (no observation can extend it any
    more: its last one is older than ``max_gap_s`` and final) or at :meth:`flush`, which ends the
    stream. Points are the detections' rows (``observed``, fields copied from the Detections)
    plus ``bridged`` points over the missed frames inside the tracklet. Tracklets shorter than
    ``min_length_s`` or with fewer than two observations are dropped as false positives.

    Image coordinates (no map, e.g. ``--detections`` alone) work the same way: world units are
    then frame pixels and the scale comes from ``target_size_m``; the gate must then also absorb
    the camera's motion (``accel_std_mps2``).
    """

    def __init__(self, config: AssociationConfig | None = None, fps: float = 30.0,
                 metres_per_unit: float | None = None, seed: int | np.random.Generator = 0):
        self.config = config = config or AssociationConfig()
        if not fps or fps <= 0 or not math.isfinite(fps):
            raise ConfigError(f"association: fps must be positive, got {fps}")
        for name in ("window_s", "max_speed_mps", "max_gap_s", "gate_chi2"):
            if getattr(config, name) <= 0:
                raise ConfigError(f"config association.{name}: must be positive")
        if (config.partial_score < 0 or not 0 < config.partial_min_inside <= 1
                or not 0 < config.partial_max_area <= 1 or config.partial_max_run_s < 0):
            raise ConfigError("config association.partial_score and partial_max_run_s must be "
                              ">= 0, partial_min_inside and partial_max_area in (0, 1]")
        for name in ("gap_accel_mps2", "gap_min_s", "gap_lateral_mps2", "gap_size_change"):
            if getattr(config, name) < 0:
                raise ConfigError(f"config association.{name}: must be >= 0")
        if not 0 < config.extend_gamma < 1:
            raise ConfigError("config association.extend_gamma: must be in (0, 1)")
        # the sampler's cost grows linearly with these: 10^6 ran for days
        for name, hi in (("iters_per_ambiguity", 1000), ("min_iters", 100_000)):
            if not 0 <= getattr(config, name) <= hi:
                raise ConfigError(f"config association.{name}: must be in [0, {hi}], got "
                                  f"{getattr(config, name)!r}")
        if config.split_appearance < 0 or config.split_min_gap_s < 0 or config.split_side_obs < 1:
            raise ConfigError("config association.split_appearance and split_min_gap_s must be "
                              ">= 0, split_side_obs >= 1")
        if (config.split_accel_mps2 < 0 or config.split_speed_slack_mps < 0
                or config.split_motion_side_s <= 0):
            raise ConfigError("config association.split_accel_mps2 and split_speed_slack_mps must "
                              "be >= 0, split_motion_side_s > 0")
        if config.split_max_size_ratio != 0 and not config.split_max_size_ratio >= 1:
            raise ConfigError("config association.split_max_size_ratio: must be 0 (off) or >= 1")
        if (config.split_merged_area_ratio < 1 or config.split_merged_min_obs_s < 0
                or config.split_merged_max_age_s <= 0):
            raise ConfigError("config association.split_merged_area_ratio must be >= 1, "
                              "split_merged_min_obs_s >= 0 and split_merged_max_age_s > 0")
        self.fps = float(fps)
        self.mpu = metres_per_unit
        # motion is judged in m/s^2 only with a known scale (a map or --gsd), not one estimated
        # from box sizes on pixels that may also carry the camera's motion (--detections alone)
        self.scale_known = metres_per_unit is not None
        if isinstance(seed, np.random.Generator):
            seed = int(seed.integers(2**63 - 1))
        if int(seed) < 0:
            raise ConfigError(f"association: seed must be >= 0, got {seed}")
        self.seed = int(seed)
        self.rng = np.random.default_rng([self.seed, 0])
        #: the link gate at this frame rate (:data:`LOW_RATE_FPS`)
        self.gate2 = config.gate_chi2 * max(1.0, LOW_RATE_FPS / self.fps)
        self.window = max(2, int(round(config.window_s * fps)))
        self.slide_batch = max(1, self.window // 3)
        self.max_gap = max(1, min(int(round(config.max_gap_s * fps)), self.window - 1))
        self.kf = ConstantVelocityKF(
            accel_std=config.accel_std_mps2, size_std=config.size_std_m, pos_std=config.pos_std_m,
            pos_frac=config.pos_frac, size_std_obs=config.pos_std_m, size_frac=config.size_frac,
            vel_std=0.5 * config.max_speed_mps)
        self.sampler: WindowSampler | None = None
        self.last_frame: int | None = None
        self.points: dict[int, list[TrackPoint]] = {}  # final points of each internal track
        self.lead_in: dict[int, list[TrackPoint]] = {}  # short pieces to put before a live track
        #: (last frame, world, velocity) of recently finished tracklets (``_follows_ended``)
        self.recent_ends: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.next_id = 1
        self.stats = {"frames": 0, "mcmc_iters": 0}

    def mcmc_counts(self) -> dict | None:
        """The sampler's proposals and acceptances so far, per move (``{"proposed": {move: n},
        "accepted": {move: n}}``), or None before it started."""
        if self.sampler is None:
            return None
        return {"proposed": dict(self.sampler.proposed), "accepted": dict(self.sampler.accepted)}

    def set_frame_step(self, step: int) -> None:
        """Frames come every ``step``-th (``--stride``): the link gate follows the rate actually
        processed, ``fps / step`` (:data:`LOW_RATE_FPS`; at ``--stride 15`` on a 30 frames/s
        video no track was born). Call before the first detections.

        The skipped frames stay empty frames of the window (a track's ``step - 1`` misses
        between two grid frames, bridged in its points). Numbering the grid frames 1, 2, 3, ...
        inside instead, at ``fps / step`` (skipped frames no misses, association 2-3x faster),
        was measured worse (2026-12-03, a generated 1080p scene, HOTA/IDF1 on every frame's
        ground truth): ``--stride 5`` 0.732/0.872 -> 0.695/0.840 and ``--stride 15``
        0.691/0.843 -> 0.643/0.804, from more false tracks (the misses charged for the skipped
        frames keep short false ones from paying their birth cost)."""
        if self.sampler is not None:
            raise RuntimeError("set_frame_step: association has already started")
        self.gate2 = self.config.gate_chi2 * max(1.0, LOW_RATE_FPS * max(1, int(step)) / self.fps)

    # ------------------------------------------------------------------ setup
    def _start(self, det: Detections) -> None:
        if not len(det):
            # wait for a frame with detections: the scale, and whether they carry histograms
            # (external detections on a video whose first frames have none came with none)
            return
        if self.mpu is None:
            if self.config.target_size_m > 0 and len(det):
                size = self._sizes(det)
                med = float(np.median(np.sqrt(np.abs(size[:, 0] * size[:, 1]))))
                self.mpu = self.config.target_size_m / med if med > 0 else 1.0
            elif self.config.target_size_m <= 0:
                self.mpu = 1.0
            else:
                return  # wait for a frame with detections to estimate the scale
        c = self.config
        # the compiled link kernels take the partial-link terms and the gate after the filter's
        # own parameters (posterior.link_step)
        kf = np.concatenate([self.kf.as_array(),
                             [c.partial_score, c.partial_min_inside, self.gate2,
                              c.partial_max_area, round(c.partial_max_run_s * self.fps),
                              c.gap_accel_mps2 if self.scale_known else 0.0, c.gap_min_s,
                              c.gap_lateral_mps2, c.gap_size_change]])
        params = SamplerParams(
            fps=self.fps, kf=kf, kf_back=np.where(np.arange(len(kf)) == 7, 0.0, kf),
            reach_mps=c.max_speed_mps, max_gap=self.max_gap,
            gate2=self.gate2, miss_cost=c.miss_cost, birth_cost=c.birth_cost,
            app_weight=c.app_weight, overlap_lambda=c.overlap_lambda, gamma=c.extend_gamma)
        bins = None if det.hist is None else int(np.shape(det.hist)[1])
        self.sampler = WindowSampler(params, self.rng, bins)

    @staticmethod
    def _sizes(det: Detections) -> np.ndarray:
        if det.size_world is not None:
            return np.abs(np.asarray(det.size_world, float).reshape(-1, 2))
        return np.abs(np.asarray(det.boxes, float).reshape(-1, 4)[:, 2:])

    # ------------------------------------------------------------------ main verb
    def step(self, detections: Detections) -> list[Tracklet]:
        """Add one frame's detections; returns the tracklets whose decisions became final.

        Raises
        ------
        InputError
            Frames out of order, or histograms appearing/disappearing mid-stream.
        """
        det = detections
        if self.last_frame is not None and det.frame <= self.last_frame:
            raise InputError(f"association: frame {det.frame} after frame {self.last_frame}; "
                             "frames must increase")
        if self.sampler is None:
            self._start(det)
            if self.sampler is None:
                self.last_frame = det.frame
                return []
        S = self.sampler
        if (S.store.hist is None) != (det.hist is None) and len(det):
            raise InputError(f"association: frame {det.frame}: colour histograms present in some "
                             "frames and missing in others")
        # frames skipped by the caller (--stride, a frame without detections) are empty frames;
        # tracks can end in them, and their tracklets are final like any other
        out = []
        if self.last_frame is not None:
            for f in range(self.last_frame + 1, det.frame):
                out.extend(self._add(Detections.empty(f)))
        out.extend(self._add(det))
        self.last_frame = det.frame
        self.stats["frames"] += 1
        return out

    def flush(self) -> list[Tracklet]:
        """Finalise everything: returns the remaining tracklets."""
        S = self.sampler
        if S is None:
            return []
        out = []
        for t in list(S.tracks.values()):
            self._freeze_track(t, len(t))
        for tid in list(S.tracks):
            out.extend(self._finish(tid))
        S.store.drop_before(S.now + 1)
        return out

    def predictions(self, frame: int, max_age_s: float, min_obs: int
                    ) -> tuple[np.ndarray, np.ndarray, list]:
        """Where the live tracks expect their targets in ``frame``: constant-velocity
        predictions of tracks observed at least ``min_obs`` times, the last time within
        ``max_age_s`` seconds. Returns world centres (K, 2) and sizes (K, 2), world units, and
        each track's latest colour histogram (None without histograms)."""
        S = self.sampler
        if S is None or not self.mpu:
            return np.zeros((0, 2)), np.zeros((0, 2)), []
        centres, sizes, hists = [], [], []
        for tid, tr in S.tracks.items():
            if len(tr):
                x, f = tr.xs[-1], int(S.frame_of(int(tr.nodes[-1])))
                h = S.hist_of(int(tr.nodes[-1]))
            elif tr.prior is not None:
                x, f, h = tr.prior.x, int(tr.prior.frame), tr.prior.hist
            else:
                continue
            dt = (frame - f) / self.fps
            if dt <= 0 or dt > max_age_s:
                continue
            n_obs = len(tr) + sum(p.kind == "observed" for p in self.points.get(tid, ()))
            if n_obs < min_obs:
                continue
            centres.append((x[0] + x[4] * dt, x[1] + x[5] * dt))
            sizes.append((x[2], x[3]))
            hists.append(h)
        if not centres:
            return np.zeros((0, 2)), np.zeros((0, 2)), []
        return np.asarray(centres) / self.mpu, np.abs(np.asarray(sizes)) / self.mpu, hists

    def track_ends(self) -> list[dict]:
        """Each track's last observation in the window: ``tid``, its ``frame``, ``index`` (its
        Detections row), ``followed`` and ``world`` (ground point, world units)."""
        S = self.sampler
        if S is None or not self.mpu:
            return []
        s = S.store
        out = []
        for tid in sorted(S.tracks):
            tr = S.tracks[tid]
            if not len(tr):
                continue
            g = int(tr.nodes[-1])
            det, i = s.payload[g - s.base]
            out.append({"tid": tid, "frame": int(s.frame[g - s.base]), "index": int(i),
                        "followed": _is_followed((det, i)),
                        "box": np.asarray(det.boxes[i], float),
                        "world": s.z[g - s.base, :2] / self.mpu})
        return out

    def lost_tracks(self, frame: int, start_s: float, max_s: float, max_speed_mps: float,
                    min_travel_m: float, min_obs: int) -> list[dict]:
        """The :meth:`track_ends` of tracks that may have stopped where the detector lost them,
        for :class:`~aerotrack.association.follow.StopFollower`: last observed before ``frame``,
        at most ``start_s`` seconds ago (a real detection) or in the frame before (a followed
        one, for at most ``max_s`` since the last real one), at no more than ``max_speed_mps``,
        observed at least ``min_obs`` times and spread over at least ``min_travel_m`` metres."""
        S = self.sampler
        out = []
        for e in self.track_ends():
            tid, f = e["tid"], e["frame"]
            if f >= frame:
                continue
            tr = S.tracks[tid]
            s = S.store
            if e["followed"]:
                if f != frame - 1:
                    continue
                real = [int(n) for n in tr.nodes
                        if not _is_followed(s.payload[int(n) - s.base])]
                f_real = int(s.frame[real[-1] - s.base]) if real else \
                    max((p.frame for p in self.points.get(tid, ()) if p.kind == "observed"),
                        default=f)
                if (frame - f_real) / self.fps > max_s:
                    continue
            elif (frame - f) / self.fps > start_s:
                continue
            x = tr.xs[-1]
            if float(np.hypot(x[4], x[5])) > max_speed_mps:
                continue
            n_obs = len(tr) + sum(p.kind == "observed" for p in self.points.get(tid, ()))
            if n_obs < min_obs:
                continue
            pos = s.z[tr.nodes - s.base, :2]
            frozen = [p.world for p in self.points.get(tid, ())]
            if frozen:
                pos = np.vstack([pos, np.asarray(frozen, float) * self.mpu])
            if float(np.hypot(*np.ptp(pos, axis=0))) < min_travel_m:
                continue
            out.append(e)
        return out

    # ------------------------------------------------------------------ per frame
    def _add(self, det: Detections) -> list[Tracklet]:
        S = self.sampler
        t = det.frame
        n = len(det)
        world = np.asarray(det.world, float).reshape(-1, 2)
        z = np.zeros((n, 4))
        z[:, :2] = world * self.mpu
        z[:, 2:] = self._sizes(det) * self.mpu
        ious = iou_pairs(z)
        payload = [(det, i) for i in range(n)]
        pok = None
        if self.config.partial_score > 0 and n:
            lo, hi = S.store.range(t - 1, t - 1)
            pok = partial_candidates(z, S.store.z[lo - S.store.base:hi - S.store.base],
                                     self.config.partial_min_inside, self.config.partial_max_area)
        S.now = t
        S.rng = self.rng = np.random.default_rng([self.seed, max(t, 0)])
        gids = S.store.add_frame(t, z, None if det.hist is None else np.asarray(det.hist, float),
                                 payload, ious, pok)
        finished = self._slide(t - self.window + 1)
        n_amb = self._initialise(gids)
        n_iter = int(self.config.min_iters + math.ceil(self.config.iters_per_ambiguity * n_amb))
        if len(S.tids) or S.n_free():
            S.run(n_iter)
            S.greedy_merges()
            self.stats["mcmc_iters"] += n_iter
        # tracks that can no longer be extended
        for tid in sorted(S.tracks):
            tr = S.tracks[tid]
            if not len(tr) and tr.prior.frame < t - self.max_gap:
                finished.extend(self._finish(tid))
        return finished

    def _slide(self, w0: int) -> list[Tracklet]:
        """Finalise observations of frames before ``w0``."""
        S = self.sampler
        # frames are finalised in batches of a third of the window (the window holds between
        # ``window`` and 4/3 ``window`` frames): one freeze per track per batch instead of per
        # frame. The cuts fall on multiples of the batch in absolute frame numbers, so that a run
        # started at another frame (a segment) freezes the same observations at the same frames.
        w0 -= w0 % self.slide_batch
        if not S.store.fstart or S.store.first_frame >= w0:
            return []
        for tr in list(S.tracks.values()):
            if not len(tr):
                continue
            fr = S.store.frame[tr.nodes - S.store.base]
            k = int(np.searchsorted(fr, w0))
            if k:
                self._freeze_track(tr, k)
        S.store.drop_before(w0)
        return []

    def _freeze_track(self, tr: WTrack, k: int) -> None:
        """Make the first ``k`` window observations of ``tr`` final (points + new prior)."""
        S = self.sampler
        if k == 0:
            return
        pts = self.points.setdefault(tr.tid, [])
        s = S.store
        for g, d2 in zip(tr.nodes[:k].tolist(), tr.d2[:k].tolist()):
            if d2 < 0:
                # a partial observation (posterior.link_step): its box is a part of the target's;
                # the target's box is bridged there from the whole observations around it
                continue
            det, i = s.payload[g - s.base]
            pt = _point(det, i)
            if pts and pt.frame - pts[-1].frame > 1:
                pts.extend(_bridge(pts[-1], pt))
            pts.append(pt)
        g = int(tr.nodes[k - 1])
        prior = Prior(tr.xs[k - 1], tr.Ps[k - 1], S.frame_of(g), S.hist_of(g))
        new = WTrack(tr.tid, tr.nodes[k:], tr.xs[k:], tr.Ps[k:], tr.d2[k:], tr.gaps[k:],
                     tr.links[k:], prior, float(tr.links[k:].sum()), tr.f_end, tr.app[k:])
        # the frozen nodes leave with the window; the rest only shift position
        li = tr.nodes - s.base
        s.label[li[:k]] = -1
        s.prev[li[:k]] = -1
        if len(li) > k:
            s.idx[li[k:]] -= k
            s.prev[li[k]] = -1
        S.tracks[tr.tid] = new

    def _finish(self, tid: int) -> list[Tracklet]:
        """Remove an ended track from the sampler; return it if long enough."""
        S = self.sampler
        tr = S.tracks[tid]
        S.swap([tr], [])
        pts = self.points.pop(tid, [])
        lead = self.lead_in.pop(tid, None)
        if lead and pts and lead[-1].frame < pts[0].frame:
            pts = [*lead, *_bridge(lead[-1], pts[0]), *pts]
        c = self.config
        pieces = [pts]
        if c.split_appearance > 0 and pts:
            pieces = split_appearance_jumps(pts, min_gap=(max(2, round(c.split_min_gap_s * self.fps))
                                                         if c.split_min_gap_s > 0 else 1),
                                            side=c.split_side_obs, threshold=c.split_appearance,
                                            max_size_ratio=c.split_max_size_ratio)
        if c.split_accel_mps2 > 0 and self.scale_known:
            side = max(3, int(round(c.split_motion_side_s * self.fps)))
            pieces = [q for piece in pieces for q in split_motion_jumps(
                piece, fps=self.fps, metres_per_unit=self.mpu, side=side,
                accel_mps2=c.split_accel_mps2, slack_mps=c.split_speed_slack_mps)]
        out = []
        for k, piece in enumerate(pieces):
            n_obs = sum(p.kind == "observed" for p in piece)
            if n_obs < 2 or (piece[-1].frame - piece[0].frame) / self.fps < c.min_length_s:
                if k == len(pieces) - 1 and piece and self._lead_into(piece):
                    continue
                if not (k == 0 and piece and self._follows_ended(piece)):
                    continue
            out.append(Track(id=self.next_id, points=piece))
            self.next_id += 1
        if out:
            self._remember_end(out[-1].points)
        return out

    def _remember_end(self, pts: list[TrackPoint]) -> None:
        """Keep where and how a finished tracklet ended, for :meth:`_follows_ended`."""
        if self.config.follow_on_gap_s <= 0:
            return
        obs = [(p.frame, p.world) for p in pts if p.kind == "observed"][-STITCH_OBS:]
        if len(obs) < 2:
            return
        # a piece starting within the gap after this end is finished at most a window, a batch
        # and the largest gap after its own last frame (or at the flush): keep ends that long
        keep = 2 * self.window + self.max_gap + max(1, int(round(self.config.follow_on_gap_s
                                                                 * self.fps)))
        now = self.sampler.now if self.sampler is not None else obs[-1][0]
        ends = [e for e in getattr(self, "recent_ends", []) if e[0] >= now - keep]
        ends.append((int(obs[-1][0]), np.asarray(obs[-1][1], float).reshape(2), _velocity(obs)))
        self.recent_ends = ends

    def _follows_ended(self, piece: list[TrackPoint]) -> bool:
        """Whether a piece too short to be a tracklet goes on from one that ended just before it:
        it begins at most ``follow_on_gap_s`` after that one's last observation, within
        ``stitch_dist_m`` of where its velocity puts it then, heading the same way. Kept, the
        piece lets global linking join the end of a vehicle the sampler cut off (Santiago's bus
        leaving the view at the left edge shrank faster than the size model follows; its last six
        detections were dropped). aerotrack's own step, the mirror of :meth:`_lead_into`."""
        c = self.config
        obs = [p for p in piece if p.kind == "observed"]
        if c.follow_on_gap_s <= 0 or c.stitch_dist_m <= 0 or len(obs) < 2:
            return False
        start = obs[0]
        v_piece = _velocity([(p.frame, p.world) for p in obs[:STITCH_OBS]])
        gap_max = max(1, int(round(c.follow_on_gap_s * self.fps)))
        reach = c.stitch_dist_m / self.mpu
        for f_end, w_end, v_end in getattr(self, "recent_ends", []):
            gap = start.frame - f_end
            if not 0 < gap <= gap_max:
                continue
            d = float(np.hypot(*(np.asarray(start.world, float).reshape(2) - (w_end + v_end * gap))))
            if d <= reach and _same_heading(v_piece, v_end, c.stitch_max_turn_deg,
                                            c.stitch_min_speed_mps / self.mpu / self.fps):
                return True
        return False

    def _lead_into(self, piece: list[TrackPoint]) -> bool:
        """Keep a piece too short to be a tracklet as the start of a live track that begins
        right after it, close to where it ended (``stitch_gap_s``, ``stitch_dist_m``) and heading
        the same way (within ``stitch_max_turn_deg``).

        The sampler cuts a vehicle where its box changes faster than the size model follows (a
        sharp turn rotates it) into pieces; each alone is under ``min_length_s`` and would be
        dropped as a false positive. Put before the track that goes on from it, the piece makes
        that track start where the vehicle re-appeared. The heading check keeps a piece of one
        vehicle off another that starts where it ended (two vehicles passing each other leave a
        merged blob between them). aerotrack's own step."""
        c = self.config
        obs = [p for p in piece if p.kind == "observed"]
        if c.stitch_dist_m <= 0 or len(obs) < 2 or self.sampler is None:
            return False
        end = obs[-1]
        v_piece = _velocity([(p.frame, p.world) for p in obs[-STITCH_OBS:]])
        gap = max(1, int(round(c.stitch_gap_s * self.fps)))
        S = self.sampler
        best, best_d = None, c.stitch_dist_m / self.mpu
        for tid, tr in S.tracks.items():
            if tid in self.lead_in:
                continue
            head = [(p.frame, p.world) for p in self.points.get(tid, ())
                    if p.kind == "observed"][:STITCH_OBS]
            for g in tr.nodes[:max(0, STITCH_OBS - len(head))].tolist():
                det, i = S.store.payload[g - S.store.base]
                head.append((det.frame, det.world[i]))
            if not head or not 0 < head[0][0] - end.frame <= gap:
                continue
            d = float(np.hypot(*(np.asarray(head[0][1], float) - np.asarray(end.world, float))))
            if d > best_d or not _same_heading(v_piece, _velocity(head), c.stitch_max_turn_deg,
                                               c.stitch_min_speed_mps / self.mpu
                                               / self.fps):
                continue
            best, best_d = tid, d
        if best is not None:
            self.lead_in[best] = [p for p in piece if p.frame <= end.frame]
        return best is not None

    # ------------------------------------------------------------------ initialisation
    def _initialise(self, gids: np.ndarray) -> int:
        """Extend live tracks with the new frame by a Hungarian assignment, then greedy births.

        Returns the number of ambiguous new detections (inside the gate of several live tracks,
        matched to a track that gates several of them, or left unmatched): the data-driven share
        of the frame's MCMC samples goes to frames where the assignment is in doubt.
        """
        S = self.sampler
        s = S.store
        t = S.now
        c = self.config
        live = [S.tracks[k] for k in sorted(S.tracks)
                if t - self.max_gap <= S.end_frame(S.tracks[k]) < t]
        n = len(gids)
        ambiguous = np.ones(n, dtype=bool)
        if live and n:
            B = 0 if s.hist is None else s.hist.shape[1]
            X = np.empty((len(live), 6))
            P = np.empty((len(live), 6, 6))
            FE = np.empty(len(live), np.int64)
            FW = np.array([S.whole_frame(tr) for tr in live], np.int64)
            HE = np.zeros((len(live), B))
            for r, tr in enumerate(live):
                X[r], P[r], FE[r], h = S.end_state(tr)
                if h is not None:
                    HE[r] = h
            a, b = gids[0] - s.base, gids[-1] + 1 - s.base
            if B:
                H, LH, LHE = s.hist[a:b], s.loghist[a:b], np.log(HE + HIST_EPS)
            else:
                H = LH = np.zeros((n, 0))
                LHE = HE
            score = score_matrix(X, P, FE, HE, LHE, s.z[a:b], s.frame[a:b], H, LH, self.fps,
                                 S.p.kf, c.max_speed_mps, self.gate2, S.p.miss_cost,
                                 S.p.app_weight if B else 0.0, FW, s.pok[a:b])
            fin = np.isfinite(score)
            per_det = fin.sum(axis=0)
            per_track = fin.sum(axis=1)
            ok_rows = np.flatnonzero(per_track > 0)
            if len(ok_rows):
                sub = score[ok_rows]
                cost = np.where(np.isfinite(sub), -sub, 1e9)
                ri, ci = _assignment(cost, np.isfinite(sub))
                for r, j in zip(ri.tolist(), ci.tolist()):
                    if cost[r, j] >= 1e9:
                        continue
                    tr = live[ok_rows[r]]
                    new = S.build(tr.tid, np.append(tr.nodes, gids[j]), tr.prior, tr, len(tr))
                    if math.isfinite(new.score):
                        S.replace_extended(tr, new)
                        ambiguous[j] = per_det[j] > 1 or per_track[ok_rows[r]] > 1
        # greedy births: chains of free observations ending at the new ones
        for g in gids.tolist():
            if s.label[g - s.base] >= 0:
                continue
            chain = self._greedy_back_chain(g)
            if len(chain) < 2:
                continue
            new = S.build(S.next_tid, np.array(chain), None)
            if new.score > 0:
                S.next_tid += 1
                S.swap([], [new])
        return int(ambiguous.sum())

    def _greedy_back_chain(self, g: int) -> list[int]:
        S = self.sampler
        single = S.build(0, np.array([g]), None)
        x, P = single.xs[0], single.Ps[0]
        f, h = S.frame_of(g), S.hist_of(g)
        chain = [g]
        while True:
            lo, hi = max(f - self.max_gap, S.store.first_frame), f - 1
            cands, w = S._children(x, P, f, h, lo, hi, forward=False)
            if cands is None:
                break
            j = int(np.argmax(w))
            gg = int(cands[j])
            fg = S.frame_of(gg)
            x, P, _, _ = link_step(x, P, (f - fg) / self.fps, S.store.z[gg - S.store.base],
                                   S.p.kf_back)
            f, h = fg, S.hist_of(gg)
            chain.append(gg)
        return chain[::-1]


#: Above this many cells the assignment is solved per connected group of gated pairs.
SPARSE_ASSIGNMENT_CELLS = 250_000


def _assignment(cost: np.ndarray, gated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``linear_sum_assignment(cost)``, rows ascending, for a cost whose ungated cells hold 1e9.

    Large problems (3000 tracks by 3000 detections: a dense solve of about 0.1 s a frame) are
    split into the connected groups of gated (track, detection) pairs, each solved alone: groups
    share no gated pair, so the optimum of each is the whole problem's there, and ungated pairs
    are dropped by the caller anyway. Small problems are solved whole, as they always were."""
    R, C = cost.shape
    if R * C <= SPARSE_ASSIGNMENT_CELLS:
        return linear_sum_assignment(cost)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    r, c = np.nonzero(gated)
    graph = coo_matrix((np.ones(len(r)), (r, R + c)), shape=(R + C, R + C))
    _, lab = connected_components(graph, directed=False)
    rl, cl = lab[:R], lab[R:]
    ro = np.argsort(rl, kind="stable")
    co = np.argsort(cl, kind="stable")
    groups = np.unique(rl)
    r_cut = np.searchsorted(rl[ro], groups)
    r_end = np.searchsorted(rl[ro], groups, side="right")
    c_cut = np.searchsorted(cl[co], groups)
    c_end = np.searchsorted(cl[co], groups, side="right")
    out_r, out_c = [], []
    for a, b, p, q in zip(r_cut.tolist(), r_end.tolist(), c_cut.tolist(), c_end.tolist()):
        if q <= p:
            continue  # a row with no gated detection (callers pass rows with one)
        rows, cols = ro[a:b], co[p:q]
        i, j = linear_sum_assignment(cost[np.ix_(rows, cols)])
        out_r.append(rows[i])
        out_c.append(cols[j])
    if not out_r:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ri, ci = np.concatenate(out_r), np.concatenate(out_c)
    o = np.argsort(ri, kind="stable")
    return ri[o], ci[o]


def _is_followed(payload) -> bool:
    det, i = payload
    fol = det.extra.get("followed")
    return fol is not None and bool(fol[i])


def _point(det: Detections, i: int) -> TrackPoint:
    """The observed TrackPoint of row ``i`` of ``det`` (its fields copied)."""
    desc = det.extra.get("desc")
    weak = det.extra.get("persistent")
    return TrackPoint(
        frame=det.frame,
        box=np.asarray(det.boxes[i], dtype=np.float64).copy(),
        world=np.asarray(det.world[i], dtype=np.float64).copy(),
        conf=float(det.conf[i]),
        kind="observed",
        det_index=i,
        size_world=None if det.size_world is None else np.asarray(det.size_world[i], float).copy(),
        hist=None if det.hist is None else np.asarray(det.hist[i], float).copy(),
        desc=None if desc is None else np.asarray(desc[i]).copy(),
        weak=False if weak is None else bool(weak[i]),
    )


def bhattacharyya(a: np.ndarray, b: np.ndarray) -> float:
    """Bhattacharyya distance ``-ln sum sqrt(a b)`` of two histograms (normalised here)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    bc = float(np.sum(np.sqrt(a / max(a.sum(), 1e-12) * b / max(b.sum(), 1e-12))))
    return -math.log(max(bc, 1e-12))


def split_appearance_jumps(points: list[TrackPoint], *, min_gap: int, side: int,
                           threshold: float, max_size_ratio: float = 0.0
                           ) -> list[list[TrackPoint]]:
    """A tracklet cut where it bridges a gap across which its colour changes: two vehicles.

    The sampler scores each link by the colour of the two blobs it joins (eq. 9), one noisy
    histogram against another, and over a long run of missed frames (a vehicle under a tree or
    a bridge) the motion reward and the price of a new track can outweigh it: a tracklet then
    hands over from the vehicle that went under the occluder to another that comes out of it.
    Here, for every bridged run of at least ``min_gap`` frames, the mean colour histograms of up
    to ``side`` observations before and after it are compared (Bhattacharyya distance, means
    of several blobs being far steadier than one); above ``threshold`` the tracklet is cut
    there and its bridged points dropped; of cuts closer than ``side`` observations only the
    strongest is made. Global linking then decides, with its whole-tracklet appearance, whether
    the pieces are one vehicle. Our addition, not the paper's.

    Measured on the generated identity scenes' tracklets (own detector, 432 bridged runs of
    >= 3 frames): same vehicle on both sides p50 / p99 = 0.04 / 0.21; 8 of the 11 hand-overs
    above 0.25.

    Parameters
    ----------
    points : list of TrackPoint
        A tracklet's points, sorted by frame.
    min_gap : int
        Shortest bridged run (frames) that is checked.
    side : int
        Observations (with a histogram) averaged on each side.
    threshold : float
        Bhattacharyya distance above which the tracklet is cut.
    max_size_ratio : float
        A run is checked only when the median box areas of the two sides differ by at most this
        factor (0: always): where the box changes size its blob holds other pixels (a trail of
        road, a vehicle half behind a tree), so its colour changes with no other vehicle.

    Returns
    -------
    list of list of TrackPoint
        The pieces in time order (``[points]`` when nothing is cut).
    """
    obs = [i for i, p in enumerate(points) if p.kind == "observed"]
    found = []  # (distance, k): observation k starts a new piece
    for k in range(1, len(obs)):
        i, j = obs[k - 1], obs[k]
        if points[j].frame - points[i].frame < min_gap:
            continue
        before = [points[m].hist for m in obs[max(0, k - side):k] if points[m].hist is not None]
        after = [points[m].hist for m in obs[k:k + side] if points[m].hist is not None]
        if not before or not after:
            continue
        if max_size_ratio > 0:
            a = np.median([points[m].box[2] * points[m].box[3] for m in obs[max(0, k - side):k]])
            b = np.median([points[m].box[2] * points[m].box[3] for m in obs[k:k + side]])
            if max(a, b) > max_size_ratio * max(min(a, b), 1e-9):
                continue
        d = bhattacharyya(np.mean(before, axis=0), np.mean(after, axis=0))
        if d > threshold:
            found.append((d, k))
    # the strongest change first; none within ``side`` observations of a kept one
    kept: list[int] = []
    for _, k in sorted(found, reverse=True):
        if all(abs(k - q) >= side for q in kept):
            kept.append(k)
    cuts = [(obs[k - 1], obs[k]) for k in sorted(kept)]
    if not cuts:
        return [points]
    pieces, start = [], 0
    for i, j in cuts:
        pieces.append(points[start:i + 1])
        start = j
    pieces.append(points[start:])
    return pieces


def split_motion_jumps(points: list[TrackPoint], *, fps: float, metres_per_unit: float,
                       side: int, accel_mps2: float, slack_mps: float
                       ) -> list[list[TrackPoint]]:
    """A tracklet cut where its velocity changes faster than a vehicle can: two vehicles.

    Two vehicles passing each other in adjacent lanes leave one merged blob for a few frames;
    when one of them has just come out from under an occluder (not yet a track that
    :mod:`~aerotrack.association.merged` could split for), the sampler follows the merged blob
    and can leave it on the other vehicle. The tracklet then turns round within a fraction of a
    second, a change of velocity no vehicle makes. At every observation the velocities fitted
    (least squares) to the ``side`` observations before and the ``side`` from it on are
    compared; where they differ by more than ``accel_mps2`` x the time between the two fits'
    centres plus ``slack_mps`` (box jitter), the tracklet is cut between the two observations
    with the largest excess (of cuts closer than ``side`` observations only the strongest is
    made) and its bridged points there dropped. Global linking then decides, with the whole
    pieces' motion and appearance, whether they are one vehicle. Our addition, not the paper's
    (its sampler scores each link with a Kalman filter whose process noise must be loose enough
    for real manoeuvres and camera shake, so a gradual hand-over through a merged blob passes).

    Parameters
    ----------
    points : list of TrackPoint
        A tracklet's points, sorted by frame.
    fps : float
        Frames per second.
    metres_per_unit : float
        Metres per world unit (the velocities are compared in m/s).
    side : int
        Observations in each velocity fit (at least 3).
    accel_mps2, slack_mps : float
        The largest plausible change of velocity is ``accel_mps2 * dt + slack_mps``.

    Returns
    -------
    list of list of TrackPoint
        The pieces in time order (``[points]`` when nothing is cut).
    """
    from ..context.motion import fit_constant_velocity

    obs = [i for i, p in enumerate(points) if p.kind == "observed"]
    if len(obs) < 2 * side:
        return [points]
    frames = np.array([points[i].frame for i in obs], dtype=np.float64)
    xy = np.array([np.asarray(points[i].world, float).reshape(-1)[:2] for i in obs])
    scale = metres_per_unit * fps  # world units per frame -> m/s
    found = []  # (excess, k): observation k starts a new piece
    for k in range(side, len(obs) - side + 1):
        fb, fa = frames[k - side:k], frames[k:k + side]
        vb = fit_constant_velocity(fb, xy[k - side:k])[1]
        va = fit_constant_velocity(fa, xy[k:k + side])[1]
        dt = (fa.mean() - fb.mean()) / fps
        excess = float(np.hypot(*(va - vb))) * scale - (accel_mps2 * dt + slack_mps)
        if excess > 0:
            found.append((excess, k))
    kept: list[int] = []
    for _, k in sorted(found, reverse=True):
        if all(abs(k - q) >= side for q in kept):
            kept.append(k)
    if not kept:
        return [points]
    pieces, start = [], 0
    for k in sorted(kept):
        pieces.append(points[start:obs[k - 1] + 1])
        start = obs[k]
    pieces.append(points[start:])
    return pieces


#: Observations at the end of a piece and the start of a track whose velocities
#: :meth:`LocalAssociator._lead_into` compares.
STITCH_OBS = 8


def _velocity(pts: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """Least-squares velocity (world units per frame) of (frame, world xy) pairs; zero for one."""
    from ..context.motion import fit_constant_velocity

    return fit_constant_velocity(np.array([p[0] for p in pts]),
                                 np.array([np.asarray(p[1], float).reshape(2) for p in pts]))[1]


def _same_heading(u: np.ndarray, v: np.ndarray, max_turn_deg: float, min_speed: float) -> bool:
    """Whether velocities ``u`` and ``v`` point within ``max_turn_deg`` of each other; true when
    either is slower than ``min_speed`` (a standing vehicle has no heading)."""
    nu, nv = float(np.hypot(*u)), float(np.hypot(*v))
    if nu < min_speed or nv < min_speed:
        return True
    return float(np.dot(u, v)) / (nu * nv) >= np.cos(np.radians(max_turn_deg))


def _bridge(a: TrackPoint, b: TrackPoint) -> list[TrackPoint]:
    """``bridged`` points for the frames strictly between ``a`` and ``b`` (linear interpolation
    of world position, box and world size: over the short gaps allowed, constant velocity)."""
    out = []
    n = b.frame - a.frame
    for f in range(a.frame + 1, b.frame):
        u = (f - a.frame) / n
        sw = None
        if a.size_world is not None and b.size_world is not None:
            sw = (1 - u) * a.size_world + u * b.size_world
        out.append(TrackPoint(frame=f, box=(1 - u) * a.box + u * b.box,
                              world=(1 - u) * a.world + u * b.world,
                              conf=min(a.conf, b.conf), kind="bridged", size_world=sw))
    return out


def associate(frames: Iterable[Detections], config: AssociationConfig | None = None,
              fps: float = 30.0, metres_per_unit: float | None = None, seed: int = 0
              ) -> list[Tracklet]:
    """Tracklets of a whole sequence of per-frame detections (frames in increasing order)."""
    la = LocalAssociator(config, fps, metres_per_unit, seed)
    out: list[Tracklet] = []
    for det in frames:
        out.extend(la.step(det))
    out.extend(la.flush())
    return out


__all__ = ["LocalAssociator", "associate"]

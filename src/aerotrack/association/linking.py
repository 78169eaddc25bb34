"""Global tracklet association and re-acquisition (Yu & Medioni 5; Ali, Reilly & Shah 4-5).

:class:`GlobalLinker` joins the tracklets of local association into tracks that keep one identity
across occlusions and exits from the view:

1. **Spatio-temporal consistency** (Yu & Medioni 5.1), on the world plane: a later tracklet b may
   continue an earlier one a when it starts after a ends, within ``max_gap_s``, no farther than
   ``v_max x gap`` from a's end and with a velocity change of at most ``a_max x gap`` (each with a
   small slack for the noise of short tracklets).
2. **Cues** for every consistent pair (:mod:`aerotrack.context.reacquire`): how far b starts from
   the path the motion context predicted for a (:mod:`aerotrack.context.motion`, which follows the
   paths of the other tracklets) and how far behind it (a stop behind an occluder), or, competing
   at a fixed extra cost, a manoeuvre (turn, U-turn, a vehicle coming back into the view the
   other way) that keeps only speed and reach (:meth:`GlobalLinker._motion`); the appearance context of a against b's observations with the
   inter-class verification against the other candidates (Ali et al. 4.3), and the Yu & Medioni
   tracklet descriptor (eqs. 12-14); plus ``gap_cost_per_s`` for each second a's prediction
   spends inside the frame unseen (:meth:`GlobalLinker._in_view`; exits are free).
3. **Joint assignment**: every tracklet may have at most one successor and one predecessor; the
   links minimise the total cost over all consistent pairs at once (a minimum-cost assignment on
   the sparse matrix of those pairs, augmented with "no link" at ``max_cost / 2`` per side,
   :func:`_assign`), not greedily one pair at a time.
   Then the chains are linked again, each as one tracklet (``rounds``, :meth:`GlobalLinker.relink`):
   a chain that ends in a short partial piece gets its whole history's motion and colours.
4. **Output**: one track per chain with the observed, bridged and stationary points of its
   tracklets, and ``predicted`` points for every unobserved frame: across each linked gap (the
   forward prediction, corrected linearly to land on the re-acquired position) and after the
   track's last observation up to ``prediction_horizon_s`` or the end of the video, but for no
   more than ``in_view_horizon_s`` inside the frame (a target there should be seen again), and
   not at all for tracks shorter than ``min_tracklet_s``; final tracks shorter than
   ``min_track_s`` are dropped.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import min_weight_full_bipartite_matching

from ..config import ContextConfig, LinkingConfig, check_range
from ..context.appearance import (
    AppearanceContext,
    TrackletDescriptor,
    kl_color,
    kl_edge,
    track_histograms,
)
from ..context.motion import TrackTable, get_predictor, kalman_start
from ..context.reacquire import (
    Cues,
    appearance_cost,
    descriptor_cost,
    link_cost,
    motion_cost,
    motion_costs,
)
from ..errors import ConfigError
from ..types import Track, TrackPoint, homography_jacobian

__all__ = ["GlobalLinker", "link_tracklets", "estimate_scale"]

log = logging.getLogger(__name__)

_IN_VIEW = ("observed", "bridged", "stationary")
#: An end of a stop link slower than this (m/s) gives no heading (:meth:`GlobalLinker._stop_cost`).
STOP_HEADING_MPS = 0.5
#: A stop link's end speeds are fitted over this many seconds at each end: a vehicle braking or
#: pulling away changes speed by metres per second within the ``context.history_s`` of the end
#: states, whose constant-velocity fit reports its mean (a vehicle found at 3.5 m/s pulling away
#: started at 6 m/s by the end state, at 4 by this).
STOP_FIT_S = 0.4
#: Each side of a stop link travels at least this far (metres) within this many seconds of the
#: stop, and its box there keeps this many pixels from the frame's border
#: (:meth:`GlobalLinker._stop_end_ok`).
STOP_TRAVEL_M = 2.0
STOP_TRAVEL_S = 3.0
STOP_EDGE_PX = 2.0
#: Treatments of a tracklet's partly visible ends (``LinkingConfig.partial_model``).
PARTIAL_MODELS = ("trim", "edge")


def _positions(t: Track) -> tuple[np.ndarray, np.ndarray]:
    """(frames (n,), world xy (n, 2)) of a tracklet's in-view points with a finite position, one
    per frame (the first), sorted by frame."""
    pts = sorted((p for p in t.points if p.kind in _IN_VIEW), key=lambda p: p.frame)
    if not pts:
        return np.zeros(0, np.int64), np.zeros((0, 2))
    fr = np.fromiter((p.frame for p in pts), np.int64, len(pts))
    xy = np.array([p.world for p in pts], dtype=np.float64).reshape(-1, 2)
    ok = np.isfinite(xy).all(axis=1)
    fr, xy = fr[ok], xy[ok]
    first = np.r_[True, fr[1:] != fr[:-1]] if len(fr) else np.zeros(0, bool)
    return fr[first], xy[first]


@dataclasses.dataclass
class _Ends:
    """Per-call data of :meth:`GlobalLinker.solve`, one entry per tracklet. Positions are world
    coordinates; ``raw`` as detected, ``pos`` with the partly visible ends trimmed."""

    tracklets: list[Track]
    raw: list[tuple[np.ndarray, np.ndarray]]  # (frames (n,), xy (n, 2))
    pos: list[tuple[np.ndarray, np.ndarray]]
    ends: list  # Kalman (position, velocity) of the end, from pos
    starts: list  # ... of the start, filtered backwards
    F: int  # frames of history behind an end state
    first: np.ndarray  # first and last frame of pos
    last: np.ndarray
    raw_first: np.ndarray  # ... of raw
    raw_last: np.ndarray
    epoch_first: np.ndarray  # registration epoch (resets before) of raw_first / raw_last
    epoch_last: np.ndarray
    # speeds (m/s) and positions of the end and start states, for stop links (filled on demand)
    end_speed: np.ndarray | None = None
    start_speed: np.ndarray | None = None
    end_xy: np.ndarray | None = None
    start_xy: np.ndarray | None = None
    end_v: np.ndarray | None = None  # (n, 2) world units per frame, over STOP_FIT_S
    start_v: np.ndarray | None = None
    end_ok: np.ndarray | None = None  # (n,) bool, GlobalLinker._stop_end_ok
    start_ok: np.ndarray | None = None
    # ``ends`` / ``starts`` / the trimmed end points / ``GlobalLinker._noise`` as (n, 2) arrays,
    # for the gates and bounds of many pairs at once (:meth:`GlobalLinker._successors`)
    ends_xy: np.ndarray | None = None
    ends_v: np.ndarray | None = None
    starts_xy: np.ndarray | None = None
    starts_v: np.ndarray | None = None
    last_xy: np.ndarray | None = None
    first_xy: np.ndarray | None = None
    noise_end: np.ndarray | None = None  # (position m, velocity m/s) of each end
    noise_start: np.ndarray | None = None


class GlobalLinker:
    """Links tracklets into persistent tracks.

    Parameters
    ----------
    config : LinkingConfig
    ctx : ContextConfig
        Motion-context settings (method, history window, prediction horizon).
    fps : float
    metres_per_unit : float, optional
        World units -> metres. None (no map, no ground sampling distance): estimated from the
        objects' sizes at :meth:`link` (:func:`estimate_scale`).
    """

    def __init__(self, config: LinkingConfig | None = None, ctx: ContextConfig | None = None,
                 fps: float = 30.0, metres_per_unit: float | None = None) -> None:
        self.config = config or LinkingConfig()
        self.ctx = ctx or ContextConfig()
        if not fps or fps <= 0:
            raise ConfigError(f"fps must be positive, got {fps}")
        if self.config.partial_model not in PARTIAL_MODELS:
            raise ConfigError(f"config linking.partial_model: unknown "
                              f"{self.config.partial_model!r}; one of {', '.join(PARTIAL_MODELS)}")
        check_range("linking.duplicate_overlap", self.config.duplicate_overlap, 0, 1)
        check_range("linking.rounds", self.config.rounds, 1)
        check_range("linking.stop_max_gap_s", self.config.stop_max_gap_s, 0)
        for name in ("stop_max_speed_mps", "stop_decel_mps2", "stop_sigma_m"):
            check_range(f"linking.{name}", getattr(self.config, name), 0, lo_open=True)
        check_range("linking.stop_max_turn_deg", self.config.stop_max_turn_deg, 0, 180)
        self.fps = float(fps)
        self.metres_per_unit = metres_per_unit
        self.mpu = float(metres_per_unit) if metres_per_unit else 1.0
        self.turn_max_gap_s = self._turn_max_gap(registered=False)
        self.predictor = get_predictor(self.ctx.method, self.ctx, self.fps, self.mpu)
        self.last_costs: dict[tuple[int, int], tuple[float, Cues]] = {}
        self._pred: dict[int, np.ndarray] = {}
        self._table: TrackTable | None = None
        self._table_key: list[Track] | None = None
        self._trimmed: list[tuple[np.ndarray, np.ndarray]] | None = None
        self._regs: dict | None = None  # frame -> Registration, for the partial-box model
        self._frame_size: tuple[int, int] | None = None
        self._in_view_cache: dict[tuple[int, int], np.ndarray] = {}

    # -- public -----------------------------------------------------------------------------------

    def link(self, tracklets: list[Track], frame_size: tuple[int, int] | None = None,
             registrations=None) -> list[Track]:
        """Join tracklets of one target; returns new :class:`Track` objects (ids 1..N).

        Parameters
        ----------
        tracklets : list of Track
            Local association's tracklets; points in world coordinates (``TrackPoint.world``),
            observed points may carry ``hist`` and ``desc``.
        frame_size : (W, H), optional
            With ``registrations``: a track's final prediction stops once it has lain inside the
            frame for ``in_view_horizon_s`` (:meth:`_tail_length`).
        registrations : dict frame -> Registration, optional
            Frame pixels -> world of every frame.

        Returns
        -------
        list of Track
            Sorted by first frame; points sorted by frame, kinds observed / bridged / stationary /
            predicted.
        """
        tl = [t for t in tracklets if len(_positions(t)[0])]
        if not tl:
            return []
        tl = merge_duplicates(tl, self.config.duplicate_overlap)
        if not self.metres_per_unit:
            self.mpu = estimate_scale(tl, self.ctx.image_object_size_m)
            self.predictor = get_predictor(self.ctx.method, self.ctx, self.fps, self.mpu)
            log.info("linking: no scale known; taking the median object (%.1f world units) as %.1f m",
                     self.ctx.image_object_size_m / self.mpu, self.ctx.image_object_size_m)
        self._regs = registrations or None
        self._frame_size = frame_size
        # registered frames are the ground, free of the camera's motion, so a manoeuvre over a
        # long gap is as plausible there as with a known scale; turn_max_gap_image_s is for
        # image coordinates
        self.turn_max_gap_s = self._turn_max_gap(bool(self._regs))
        links, _ = self.solve(tl)
        self._inserted: dict[tuple[int, int], tuple[int, int]] = {}  # piece hop -> its link
        links = self.fill_gaps(tl, links)
        for _ in range(max(0, self.config.rounds - 1)):
            more = self.relink(tl, links)
            if more == links:
                break
            links = self.fill_gaps(tl, more)
        return self.build_tracks(tl, links, registrations, frame_size)

    def _turn_max_gap(self, registered: bool) -> float:
        c = self.config
        known = self.metres_per_unit or registered
        return c.turn_max_gap_s if known else min(c.turn_max_gap_s, c.turn_max_gap_image_s)

    def relink(self, tl: list[Track], links: dict[int, int]) -> dict[int, int]:
        """``links`` with the chains they make linked again, as tracklets of their own.

        A chain's end is often a short piece (partial boxes where the vehicle went under an
        occluder, a hand-over, a split) whose own end state is poor, so its onward link costs too
        much though its predecessor's motion and appearance would have made it. Here each chain
        becomes one tracklet (its points in frame order), :meth:`solve` links the chains, and a
        chain link a -> b becomes a link from a's last tracklet to b's first. The predictions
        :meth:`solve` made for ``tl`` are kept (:meth:`build_tracks` uses them)."""
        chains = _chains(len(tl), links)
        if len(chains) == len(tl) or len(chains) < 2:
            return links
        merged = [tl[ch[0]] if len(ch) == 1 else
                  Track(id=0, points=_one_per_frame(sorted(
                      (p for i in ch for p in tl[i].points if p.kind != "predicted"),
                      key=lambda p: p.frame)))
                  for ch in chains]
        # solve's per-call state (indexed by tracklet) is the first round's again afterwards
        names = ("_pred", "_trimmed", "_table", "_table_key", "last_costs", "_noise",
                 "_in_view_cache", "_plain", "_horizon", "_hopeless", "_stop_costs", "_stop_won")
        saved = {k: getattr(self, k, None) for k in names}
        try:
            chain_links, _ = self.solve(merged)
            judged = {(a, b): (self.last_costs.get((a, b)), (a, b) in self._stop_won)
                      for a, b in chain_links.items()}
        finally:
            for k, v in saved.items():
                setattr(self, k, v)
        out = dict(links)
        for a, b in chain_links.items():
            if len(chains[a]) > 1 or len(chains[b]) > 1:  # two single tracklets were judged
                u, v = chains[a][-1], chains[b][0]
                out[u] = v
                cost, stop = judged[(a, b)]
                if cost is not None:  # (links.csv: the chains' costs decided it)
                    self.last_costs[(u, v)] = cost
                    (self._stop_won.add if stop else self._stop_won.discard)((u, v))
        return out

    def solve(self, tl: list[Track]) -> tuple[dict[int, int], dict[tuple[int, int], float]]:
        """Links as {index of a: index of b} and the cost of every allowed pair {(a, b): cost}
        (pairs missing are inconsistent or cost more than ``max_cost``).

        Steps 1-3 of the module docstring: the consistent pairs (:meth:`_successors`), hand-overs
        between overlapping tracklets at a cost of their own (:meth:`_handover_costs`), the cues
        of every consistent pair (:meth:`_pair_cost`), one joint assignment."""
        c = self.config
        n = len(tl)
        self._pred = {}
        self._in_view_cache = {}
        self._entry_cache: dict[int, int | None] = {}
        self._table = None  # built again for these tracklets by _forward when needed
        self._trimmed = None
        e = self._tracklet_ends(tl)
        self._plain: set[tuple[int, int]] = set()  # pairs through _successors' ordinary gates
        self._horizon: dict[int, int] = {}  # a's longest gap to a pair through them
        self._hopeless = 0  # such pairs whose motion alone costs more than max_cost
        self._stop_costs: dict[tuple[int, int], float] = {}  # stop links' motion costs
        self._stop_won: set[tuple[int, int]] = set()  # pairs priced as stops
        cand = {a: bs for a in range(n) if (bs := self._successors(e, a))}
        log.debug("linking %d tracklets: %d consistent pairs, %d of them left out on motion alone",
                  n, sum(map(len, cand.values())), self._hopeless)
        C: dict[tuple[int, int], float] = {}
        self.last_costs = {}
        handovers = handover_pairs(tl, c.duplicate_overlap, int(round(c.handover_max_s * self.fps)),
                                   c.handover_max_area_ratio)
        app = None
        if handovers or cand:
            hists_end = {i: track_histograms(t) for i, t in enumerate(tl)}
            app = AppearanceContext({i: h for i, h in hists_end.items() if h.size})
        self._handover_costs(tl, handovers, app, C)
        if not cand:
            return _assign(n, C, c.max_cost), C
        table = _table_of(e.pos)
        self._table, self._table_key = table, tl
        preds = {}
        if c.weight_motion > 0 or c.predict_gaps:
            for a in cand:
                if a in self._horizon:
                    preds[a] = self.predictor.predict(table, a, int(e.last[a]), self._horizon[a])
        desc = [TrackletDescriptor.from_track(t) for t in tl] if c.weight_descriptor > 0 else [None] * n
        preds_of: dict[int, list[int]] = {}
        for a, bs in cand.items():
            for b in bs:
                preds_of.setdefault(b, []).append(a)
        first = np.array([int(t.first) for t in tl])
        last = np.array([int(t.last) for t in tl])
        # b's possible predecessors with an appearance model, in order, and b's first
        # histograms: built once per b (per pair, 16.7M checks for 161k pairs on a 500 s video
        # at max_gap_s 60)
        others = {b: np.array([o for o in os_ if o in app.X], dtype=np.int64)
                  for b, os_ in preds_of.items()} if app is not None else {}
        hists_b: dict[int, np.ndarray] = {}

        def distinct(b: int, a: int) -> list[int]:
            # other targets for certain: seen at the same time as a, and not a split of it
            o = others[b]
            o = o[(o != a) & (first[o] <= last[a]) & (first[a] <= last[o])]
            return [int(k) for k in o if (k, a) not in handovers and (a, k) not in handovers]
        for a, bs in cand.items():
            bs = [b for b in bs if (a, b) in self._plain or (a, b) in self._stop_costs]
            # (the others' motion alone costs more than max_cost, _successors)
            aps, des = [], []
            for b in bs:
                ap = float("nan")
                if c.weight_appearance > 0 and a in app.intra:
                    if b not in hists_b:
                        hists_b[b] = track_histograms(tl[b], max_obs=5)
                    s = hists_b[b]
                    if s.size and s.shape[1] == app.X[a].shape[1]:
                        z2 = app.intra_distance(s, a)
                        ok = app.verify(s, a, distinct(b, a))
                        ap = appearance_cost(z2, ok, c.appearance_max)
                de = float("nan")
                if desc[a] is not None and desc[b] is not None:
                    de = descriptor_cost(kl_color(desc[a], desc[b]), kl_edge(desc[a], desc[b]),
                                         c.descriptor_max)
                aps.append(ap)
                des.append(de)
            plain = [k for k, b in enumerate(bs) if (a, b) in self._plain]
            motions = {}
            if plain and a in preds:
                # a split needs the appearance's agreement too (a false fragment right after
                # a vehicle's tracklet also starts where it ended)
                allow = ~(np.array([aps[k] for k in plain]) > c.split_max_appearance)
                m = self._motions(e, a, np.array([bs[k] for k in plain]), preds[a], allow)
                motions = {bs[k]: (float(v), bool(ok)) for k, v, ok in zip(plain, m, allow)}
            for b, ap, de in zip(bs, aps, des):
                cost, cues = np.inf, Cues(float("nan"), ap, de)
                if (a, b) in self._plain:
                    m, allow = motions.get(b, (None, True))
                    m = self._motion_cue(e, a, b, preds.get(a), allow_split=allow, m=m)
                    cues = Cues(m, ap, de)
                    cost = link_cost(cues, c)
                    gap = int(e.first[b] - e.last[a])
                    if c.gap_cost_per_s > 0 and a in preds and gap > 0:
                        unseen = int(self._in_view(a, preds[a], e.last[a])[
                            min(gap, len(preds[a])) - 1])
                        if c.gap_cost_entry:
                            unseen = max(unseen, self._entry_frames(e, b, gap))
                        cost += c.gap_cost_per_s * unseen / self.fps
                if (a, b) in self._stop_costs:
                    # a vehicle standing unseen: its time in view is not charged
                    stop = Cues(self._stop_costs[(a, b)], ap, de)
                    if link_cost(stop, c) < cost:
                        cost, cues = link_cost(stop, c), stop
                        self._stop_won.add((a, b))
                self.last_costs[(a, b)] = (cost, cues)
                log.debug("linking: %d (ends %d) -> %d (starts %d): cost %.2f, motion %.2f, "
                          "appearance %.2f, descriptor %.2f", a, e.last[a], b, e.first[b], cost,
                          cues.motion, ap, de)
                if cost <= c.max_cost:
                    C[(a, b)] = cost
        self._pred = preds
        return _assign(n, C, c.max_cost), C

    def _tracklet_ends(self, tl: list[Track]) -> _Ends:
        """Each tracklet's points as detected and with its partly visible ends trimmed, the
        Kalman states of its end and start, and their noise (kept for :meth:`relink`)."""
        F = max(2, int(round(self.ctx.history_s * self.fps)))
        raw = [_positions(t) for t in tl]
        # end states from the fully visible part: a box shrinking into an occluder or the image
        # edge (growing out of it) has a displaced centre and a wrong velocity
        pos = [self._trim_partial(t, fr, xy) for t, (fr, xy) in zip(tl, raw)]
        self._trimmed = pos
        ends, starts, self._noise = [], [], []
        for fr, xy in pos:
            h = (fr >= fr[-1] - F)
            s = (fr <= fr[0] + F)
            ends.append(self._end_state(fr, xy, F, True))
            starts.append(self._end_state(fr, xy, F, False))
            self._noise.append((end_noise(fr[h], xy[h], self.mpu, self.fps),
                                end_noise(fr[s], xy[s], self.mpu, self.fps)))
        # a ``reset`` registration (a scene change, or a loss too long to bridge without a map)
        # starts an unrelated world: nothing is linked across it
        resets = np.array(sorted(f for f, r in (self._regs or {}).items() if r.status == "reset"),
                          dtype=np.int64)
        raw_first = np.array([fr[0] for fr, _ in raw])
        raw_last = np.array([fr[-1] for fr, _ in raw])

        def xy2(vs) -> np.ndarray:
            return np.array([np.asarray(v, dtype=np.float64).reshape(2) for v in vs]).reshape(-1, 2)
        return _Ends(tracklets=tl, raw=raw, pos=pos, ends=ends, starts=starts, F=F,
                     first=np.array([fr[0] for fr, _ in pos]),
                     last=np.array([fr[-1] for fr, _ in pos]),
                     raw_first=raw_first, raw_last=raw_last,
                     epoch_first=np.searchsorted(resets, raw_first, side="right"),
                     epoch_last=np.searchsorted(resets, raw_last, side="right"),
                     ends_xy=xy2(s[0] for s in ends), ends_v=xy2(s[1] for s in ends),
                     starts_xy=xy2(s[0] for s in starts), starts_v=xy2(s[1] for s in starts),
                     last_xy=xy2(xy[-1] for _, xy in pos), first_xy=xy2(xy[0] for _, xy in pos),
                     noise_end=xy2(n[0] for n in self._noise),
                     noise_start=xy2(n[1] for n in self._noise))

    def _successors(self, e: _Ends, a: int) -> list[int]:
        """The tracklets that may continue tracklet a (spatio-temporal consistency, Yu & Medioni
        5.1): starting after a ends, within ``max_gap_s`` and the same registration epoch, within
        ``v_max x gap`` of a's end and with a velocity change within ``a_max x gap``. Over a gap of
        at most ``turn_max_gap_s`` a turn may hide in the gap and in the velocity windows, so only
        the change of speed counts there (and the whole velocity's against
        ``turn_a_max_mps2``)."""
        c = self.config
        max_gap = int(round(c.max_gap_s * self.fps))
        ends, starts, pos = e.ends, e.starts, e.pos
        gaps = e.first - e.last[a]
        order = e.raw_first - e.raw_last[a]
        same = e.epoch_first == e.epoch_last[a]
        out = self._stop_successors(e, a, (order > 0) & same)
        idx = np.flatnonzero((order > 0) & (gaps <= max_gap) & same)
        short = gaps[idx] / self.fps <= self.turn_max_gap_s
        plain = []
        for b in idx[short]:
            gap_s = gaps[b] / self.fps
            d = float(np.hypot(*(starts[b][0] - ends[a][0]))) * self.mpu
            dv_turn = float(np.hypot(*(starts[b][1] - ends[a][1]))) * self.mpu * self.fps
            dv = abs(_speed(starts[b][1]) - _speed(ends[a][1])) * self.mpu * self.fps
            # a split of one track (a vehicle pulling away, braking): both ends'
            # velocities are fitted over history_s while it accelerates
            split = self._is_split(pos[a][1][-1], pos[b][1][0], ends[a][1], int(gaps[b]))
            gap_s += self.ctx.history_s * (2.0 if split else 1.0)
            if c.turn_a_max_mps2 > 0 and \
                    dv_turn > c.turn_a_max_mps2 * gap_s + c.speed_slack_mps:
                log.debug("linking: %d -> %d refused, velocity change %.1f m/s in %.2f s",
                          a, b, dv_turn, gap_s)
                continue
            if d <= c.v_max_mps * gap_s + c.gate_slack_m and \
                    dv <= c.a_max_mps2 * gap_s + c.speed_slack_mps:
                plain.append(int(b))
        # past turn_max_gap_s (most pairs of a long video at max_gap_s 60) all at once
        far = idx[~short]
        gap_s = gaps[far] / self.fps
        d = np.hypot(*(e.starts_xy[far] - e.ends_xy[a]).T) * self.mpu
        dv = np.hypot(*(e.starts_v[far] - e.ends_v[a]).T) * self.mpu * self.fps
        ok = (d <= c.v_max_mps * gap_s + c.gate_slack_m) & \
            (dv <= c.a_max_mps2 * gap_s + c.speed_slack_mps)
        plain = np.array(plain + far[ok].tolist(), dtype=np.int64)
        if len(plain):
            self._horizon[a] = int(gaps[plain].max())
            # a pair whose motion cost is sure to exceed max_cost is never linked: its cues
            # are not worked out (on a busy video most of the pairs within max_gap_s 60)
            hopeless = self._hopeless_pairs(e, a, plain)
            self._hopeless += int(hopeless.sum())
            self._plain.update((a, int(b)) for b in plain[~hopeless])
            out = sorted(set(out) | set(plain.tolist()))
        return sorted(out)

    def _hopeless_pairs(self, e: _Ends, a: int, bs: np.ndarray) -> np.ndarray:
        """Which of the pairs a -> b (``bs``) cost more than ``max_cost`` on motion alone.

        A lower bound of :meth:`_motion`'s cost, for all b at once: the distance from a's end to
        b's backward path and its lag are half of what :meth:`_motion` averages (the forward
        halves need a's prediction), and the manoeuvre's terms are taken at their smallest (the
        longer velocity window of a split). The other cues and the gap's cost only add, so such
        a pair cannot be linked and leaving it out changes no link. Gaps within
        ``partial_raw_gap_s`` (where the ends as detected also compete) and a motion weight of 0
        are never judged here."""
        c, mpu, fps = self.config, self.mpu, self.fps
        out = np.zeros(len(bs), dtype=bool)
        if c.weight_motion <= 0 or not len(bs):
            return out
        judged = (e.first[bs] - e.last[a]) > int(round(c.partial_raw_gap_s * fps))
        bs = bs[judged]
        if not len(bs):
            return out
        gap = (e.first[bs] - e.last[a]).astype(np.float64)
        g = gap / fps
        a_end, va = e.last_xy[a], e.ends_v[a]
        p0, vb = e.starts_xy[bs], e.starts_v[bs]
        vv = np.einsum("ij,ij->i", vb, vb)
        t = np.where(vv > 0, np.clip(((p0 - a_end) * vb).sum(1) / np.where(vv > 0, vv, 1.0), 0.0,
                                     gap), 0.0)
        d_b = np.hypot(*(p0 - vb * t[:, None] - a_end).T) * mpu
        lag_b = (gap - t) * np.sqrt(vv) * mpu
        dv = np.hypot(*(vb - va).T) * mpu * fps
        na, nb = e.noise_end[a], e.noise_start[bs]
        k = c.end_noise_scale
        noise_m = k * np.sqrt(na[0] ** 2 + nb[:, 0] ** 2 + (0.5 * (na[1] + nb[:, 1]) * g) ** 2)
        noise_mps = k * np.hypot(na[1], nb[:, 1])
        sp = np.hypot(c.motion_sigma_m + c.motion_sigma_growth_mps * g, noise_m)
        sv = np.hypot(c.velocity_sigma_mps + c.velocity_sigma_growth_mps2 * g, noise_mps)
        sl = np.hypot(c.motion_sigma_m + c.lag_sigma_growth_mps * g, noise_m)
        bound = 0.5 * (0.5 * d_b / sp) ** 2 + 0.5 * (dv / sv) ** 2 + 0.5 * (0.5 * lag_b / sl) ** 2
        turn = g <= self.turn_max_gap_s
        if turn.any():
            sa, sb = np.hypot(*va) * mpu * fps, np.hypot(*vb.T) * mpu * fps
            reach = np.maximum(sa, sb) * g
            excess = np.maximum(0.0, np.hypot(*(e.first_xy[bs] - a_end).T) * mpu - reach)
            window = g + 2.0 * self.ctx.history_s
            st = sv + 0.5 * c.a_max_mps2 * window
            too_fast = np.maximum(0.0, dv - c.a_max_mps2 * window)
            manoeuvre = c.turn_cost + np.log1p(reach / sp) + 0.5 * (excess / sp) ** 2 \
                + 0.5 * ((sb - sa) / st) ** 2 + 0.5 * (too_fast / st) ** 2
            bound = np.where(turn, np.minimum(bound, manoeuvre), bound)
        # a margin for rounding: the bound is not computed in the order _motion computes
        out[np.flatnonzero(judged)] = c.weight_motion * bound > c.max_cost * (1 + 1e-6) + 1e-6
        return out

    def _stop_successors(self, e: _Ends, a: int, allowed: np.ndarray) -> list[int]:
        """The tracklets b (among ``allowed``) that may continue a as a stop, their motion costs
        entered in ``_stop_costs`` (:meth:`_stop_cost`)."""
        c = self.config
        if c.stop_max_gap_s <= 0 or not self._regs:
            return []
        if e.end_speed is None:
            n = round(STOP_FIT_S * self.fps)
            e.end_v = np.array([_local_velocity(fr[-n - 1:], xy[-n - 1:]) for fr, xy in e.pos])
            e.start_v = np.array([_local_velocity(fr[:n + 1], xy[:n + 1]) for fr, xy in e.pos])
            e.end_speed = np.hypot(*e.end_v.T) * self.mpu * self.fps
            e.start_speed = np.hypot(*e.start_v.T) * self.mpu * self.fps
            e.end_xy = np.array([p for p, _ in e.ends], float).reshape(-1, 2)
            e.start_xy = np.array([p for p, _ in e.starts], float).reshape(-1, 2)
            k = round(STOP_TRAVEL_S * self.fps)
            e.end_ok = np.array([self._stop_end_ok(t, fr, xy, k, True)
                                 for t, (fr, xy) in zip(e.tracklets, e.raw)])
            e.start_ok = np.array([self._stop_end_ok(t, fr, xy, k, False)
                                   for t, (fr, xy) in zip(e.tracklets, e.raw)])
        vmax = c.stop_max_speed_mps
        if e.end_speed[a] > vmax or not e.end_ok[a]:
            return []
        reach = vmax * vmax / c.stop_decel_mps2 * 1.5 + 4.0 * c.stop_sigma_m  # metres
        d = np.hypot(*(e.start_xy - e.end_xy[a]).T) * self.mpu
        gaps = e.first - e.last[a]
        out = []
        for b in np.flatnonzero(allowed & (gaps <= round(c.stop_max_gap_s * self.fps))
                                & (e.start_speed <= vmax) & e.start_ok & (d <= reach)):
            m = self._stop_cost(e, a, int(b))
            if m is not None:
                self._stop_costs[(a, int(b))] = m
                out.append(int(b))
        return out

    def _stop_end_ok(self, t: Track, fr: np.ndarray, xy: np.ndarray, k: int, end: bool) -> bool:
        """Whether a tracklet's end (``end``) or start may be a stop link's: its box there wholly
        inside the frame (a box cut by the border moves slowly as the vehicle comes in; the
        vehicle may have left the view) and its points over the ``k`` frames next to it spread
        over at least ``STOP_TRAVEL_M`` (it was seen driving: two vehicles crossing in one
        blob look slow and stand nowhere)."""
        if not len(fr):
            return False
        sel = fr >= fr[-1] - k if end else fr <= fr[0] + k
        if float(np.hypot(*np.ptp(xy[sel], axis=0))) * self.mpu < STOP_TRAVEL_M:
            return False
        if self._frame_size is None:
            return True
        obs = [p for p in t.points if p.kind == "observed" and p.box is not None]
        if not obs:
            return False
        x, y, w, h = (float(v) for v in (obs[-1] if end else obs[0]).box)
        W, H = self._frame_size
        return x > STOP_EDGE_PX and y > STOP_EDGE_PX and x + w < W - STOP_EDGE_PX \
            and y + h < H - STOP_EDGE_PX

    def _stop_cost(self, e: _Ends, a: int, b: int) -> float | None:
        """Motion cost of a -> b as a stop (``LinkingConfig.stop_max_gap_s``), or None when the
        pair cannot be one.

        A vehicle lost while braking at ``v_a`` and found pulling away at ``v_b`` needed at least
        ``(v_a + v_b) / a`` seconds (``stop_decel_mps2``) and covered about ``s = (v_a^2 +
        v_b^2) / (2 a)`` metres in them, along its heading (the mean of the two ends' headings;
        neither end slower than 0.5 m/s has one). The cost is ``0.5 (along - s)^2 / (sigma +
        s / 2)^2 + 0.5 lateral^2 / sigma^2`` (``stop_sigma_m``); starting behind the end (a
        vehicle does not back up in a queue) or off the lane by over ``3 sigma``, turned by over
        ``stop_max_turn_deg``, or costing over ``max_cost`` is no stop. aerotrack's own rule:
        neither paper has one, and with a background model that absorbs a waiting vehicle (Yu &
        Medioni's) a red light longer than ``max_gap_s`` split every vehicle that waited at it."""
        c = self.config
        va, vb = float(e.end_speed[a]), float(e.start_speed[b])
        gap_s = (e.first[b] - e.last[a]) / self.fps
        if gap_s < (va + vb) / c.stop_decel_mps2:
            return None
        heads = [v / np.hypot(*v) for sp, v in ((va, e.end_v[a]), (vb, e.start_v[b]))
                 if sp >= STOP_HEADING_MPS]
        D = (e.start_xy[b] - e.end_xy[a]) * self.mpu
        sigma = c.stop_sigma_m
        expect = (va * va + vb * vb) / (2.0 * c.stop_decel_mps2)
        if not heads:
            return 0.5 * (float(np.hypot(*D)) / (sigma + 0.5 * expect)) ** 2 \
                if np.hypot(*D) <= 3.0 * (sigma + 0.5 * expect) else None
        if len(heads) == 2 and float(heads[0] @ heads[1]) < np.cos(np.radians(c.stop_max_turn_deg)):
            return None
        u = heads[0] + heads[-1]
        u = u / np.hypot(*u)
        along = float(D @ u)
        lateral = abs(float(D[0] * u[1] - D[1] * u[0]))
        if along < -sigma or lateral > 3.0 * sigma:
            return None
        cost = 0.5 * ((along - expect) / (sigma + 0.5 * expect)) ** 2 + 0.5 * (lateral / sigma) ** 2
        return cost if cost <= c.max_cost else None

    def _handover_costs(self, tl: list[Track], handovers: dict[tuple[int, int], float],
                        app: AppearanceContext | None, C: dict[tuple[int, int], float]) -> None:
        """Enter into ``C`` (and ``last_costs``) the cost of each hand-over a -> b (b's box takes
        over a's while they overlap, :func:`handover_pairs`), dropping from ``handovers`` those
        whose appearance disagrees."""
        c = self.config
        for (a, b), ov in list(handovers.items()):
            if c.weight_appearance > 0 and a in app.intra:
                # like a split, a hand-over needs the appearance's agreement: two vehicles whose
                # boxes overlap while one passes the other are not one handed over
                s = track_histograms(tl[b], max_obs=5)
                if s.size and s.shape[1] == app.X[a].shape[1] and \
                        appearance_cost(app.intra_distance(s, a), True) > c.split_max_appearance:
                    del handovers[(a, b)]
                    continue
            cost = c.handover_cost * (1.0 - ov) / max(1e-9, 1.0 - c.duplicate_overlap)
            self.last_costs[(a, b)] = (cost, Cues())
            C[(a, b)] = cost

    def _motion_cue(self, e: _Ends, a: int, b: int, pred: np.ndarray | None,
                    allow_split: bool, m: float | None = None) -> float:
        """Motion cost of a -> b (:meth:`_motion`, or ``m`` when :meth:`_motions` worked it out)
        on the trimmed ends; NaN without a prediction.

        Within ``partial_raw_gap_s``, when one end's box is under ``partial_size_ratio`` of the
        other's along the motion and trimming changed an end, the ends as detected compete: the
        lower cost counts."""
        if pred is None:
            return float("nan")
        c = self.config
        raw, pos, F = e.raw, e.pos, e.F
        gap = int(e.first[b] - e.last[a])
        if m is None:
            m = self._motion(pred[:gap], pos[a][1][-1], pos[b][1][0], e.ends[a], e.starts[b], gap,
                             self._noise[a][0], self._noise[b][1], allow_split=allow_split)
        if gap <= int(round(c.partial_raw_gap_s * self.fps)) and \
                self._resized(e.tracklets[a], e.tracklets[b], e.ends[a][1]) and (
                len(pos[a][0]) < len(raw[a][0]) or len(pos[b][0]) < len(raw[b][0])
                or not np.array_equal(pos[a][1][-1], raw[a][1][-1])
                or not np.array_equal(pos[b][1][0], raw[b][1][0])):
            ea = self._end_state(*raw[a], F, True)
            sb = self._end_state(*raw[b], F, False)
            shift = ea[0] - e.ends[a][0]
            m = min(m, self._motion(pred[:gap] + shift, raw[a][1][-1], raw[b][1][0], ea, sb, gap,
                                    self._noise[a][0], self._noise[b][1], allow_split=allow_split))
        return m

    def _resized(self, ta: Track, tb: Track, velocity: np.ndarray) -> bool:
        """One end's box under ``partial_size_ratio`` of the other's along the motion."""
        la, lb = _end_extent(ta, velocity, True), _end_extent(tb, velocity, False)
        return la > 0 and lb > 0 and min(la, lb) < self.config.partial_size_ratio * max(la, lb)

    def _end_state(self, fr: np.ndarray, xy: np.ndarray, F: int, end: bool):
        """Kalman (position, velocity) of a tracklet's end (``end``) or start from its points
        within ``F`` frames of it (a start is filtered backwards in time)."""
        if end:
            h = fr >= fr[-1] - F
            return kalman_start(fr[h], xy[h], self.fps, self.mpu, self.ctx)
        s = fr <= fr[0] + F
        p, v = kalman_start(-fr[s][::-1], xy[s][::-1], self.fps, self.mpu, self.ctx)
        return p, -v

    def _is_split(self, a_last: np.ndarray, b_first: np.ndarray, a_velocity: np.ndarray,
                  gap: int) -> bool:
        """Whether b continues a as a split of one track: a gap of at most ``split_gap_s`` frames'
        time and b's first point (world) where a's last one would be after the gap at a's speed
        (world units per frame), within ``split_dist_m`` (a neighbour in a queue starts a
        vehicle length away)."""
        c = self.config
        if c.split_gap_s <= 0 or gap / self.fps > c.split_gap_s:
            return False
        step = _speed(a_velocity) * gap
        d = float(np.hypot(*(np.asarray(b_first, float) - np.asarray(a_last, float))))
        return d <= step + c.split_dist_m / self.mpu

    def _in_view(self, a: int, pred: np.ndarray, last: int) -> np.ndarray:
        """Cumulative count of the frames last+1.. in which tracklet a's prediction ``pred``
        (h, 2) world lies inside the frame (none without registrations or frame size: in view
        and out of it cannot be told apart), cached per tracklet."""
        cache = self._in_view_cache
        if (a, len(pred)) in cache:
            return cache[(a, len(pred))]
        regs, size = self._regs, self._frame_size
        if not regs or size is None:
            out = np.zeros(len(pred), int)
        else:
            W, H = size
            inside = np.zeros(len(pred), bool)
            ks = [k for k in range(len(pred)) if last + k + 1 in regs]
            if ks:
                Hs = np.array([regs[last + k + 1].H for k in ks], dtype=np.float64)
                w = np.column_stack([pred[ks], np.ones(len(ks))])[:, :, None]
                q = np.linalg.solve(Hs, w)[:, :, 0]  # world -> frame pixels, all frames at once
                with np.errstate(divide="ignore", invalid="ignore"):
                    x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
                inside[ks] = (q[:, 2] != 0) & (x >= 0) & (x < W) & (y >= 0) & (y < H)
            out = np.cumsum(inside)
        cache[(a, len(pred))] = out
        return out

    def _entry_frames(self, e: _Ends, b: int, gap: int) -> int:
        """Frames tracklet b would have been in view, unseen, on its way in: its start run back
        at its start velocity until it leaves the frame. 0 when that takes longer than ``gap``
        (b was in view all along, or its start velocity says little: a vehicle pulling away) or
        without registrations and frame size.

        A link whose first tracklet left the view and whose second starts inside it claims the
        target came back in unseen: a candidate that ended at the other edge of the view 4 s
        earlier beat the tracklet that went under a tree 1 s before b came out of it (generated
        static:11, a U-turn outside the view against a straight drive under the tree)."""
        regs, size = self._regs, self._frame_size
        if not regs or size is None or gap <= 0:
            return 0
        cache = self._entry_cache
        if b not in cache:  # frames back to the first one outside the view, over the longest gap
            first = int(e.first[b])
            p0, vb = np.asarray(e.pos[b][1][0], float), np.asarray(e.starts[b][1], float)
            span = int(round(self.config.max_gap_s * self.fps))
            ks = [k for k in range(1, span + 1) if first - k in regs]
            exit_k = None
            if ks:
                Hs = np.array([regs[first - k].H for k in ks], dtype=np.float64)
                w = np.column_stack([p0 - np.outer(ks, vb), np.ones(len(ks))])[:, :, None]
                q = np.linalg.solve(Hs, w)[:, :, 0]  # world -> frame pixels
                W, H = size
                with np.errstate(divide="ignore", invalid="ignore"):
                    x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
                inside = (q[:, 2] != 0) & (x >= 0) & (x < W) & (y >= 0) & (y < H)
                out = np.flatnonzero(~inside)
                exit_k = int(ks[out[0]]) if out.size else None
            cache[b] = exit_k
        exit_k = cache[b]
        return exit_k - 1 if exit_k is not None and exit_k <= gap else 0

    def fill_gaps(self, tl: list[Track], links: dict[int, int]) -> dict[int, int]:
        """Links with unlinked tracklets inserted into the gaps of the links they lie on.

        A vehicle going under an occluder or out of the view is often seen last as a short
        tracklet of partial boxes, split from its long one (the box shrinks and shifts, and local
        association starts a new track), and the same on the way out. Its link costs are poor (a
        displaced centre, a velocity from a few jittery boxes, a descriptor of partial blobs), so
        the joint assignment prefers the direct link over the gap (rightly, by its costs) and the
        short piece, left alone, is dropped under ``min_track_s``: the track then misses the
        target's last (first) seconds before (after) the gap. Here every tracklet unlinked on
        both sides that lies wholly inside the gap of an accepted link a -> b, all its points
        near the gap's path (the motion context's prediction from a corrected linearly to land
        on b's start, as :meth:`build_tracks` reports it), is inserted into the chain. Near means
        a median of ``d / sigma <= fill_sigma`` with ``d`` the distance (metres) of each point
        from the path at its frame, less half a's typical length (a partial box's centre is up
        to that far off the vehicle's; a neighbour in a queue is a whole length and more away),
        and ``sigma = motion_sigma_m + motion_sigma_growth_mps x t``,
        ``t`` the time to the nearer end of the gap (the path is pinned at both ends). Tracklets
        in one gap that overlap in time are taken best first. aerotrack's own step; neither
        paper has it (Yu & Medioni link pairs only).

        Parameters
        ----------
        tl : list of Track
            The tracklets :meth:`solve` linked (world coordinates).
        links : dict
            {index of a: index of b} from :meth:`solve`.

        Returns
        -------
        dict
            The links with the inserted tracklets chained in (a -> s1 -> ... -> b).
        """
        c = self.config
        if c.fill_sigma <= 0 or not links:
            return links
        linked = set(links) | set(links.values())
        free = [i for i in range(len(tl)) if i not in linked]
        if not free:
            return links
        pos = {i: _positions(tl[i]) for i in free}
        span = {i: (int(pos[i][0][0]), int(pos[i][0][-1])) for i in free if len(pos[i][0])}
        out = dict(links)
        for a, b in links.items():
            pa = [p for p in tl[a].points if p.kind != "predicted"]
            pb = [p for p in tl[b].points if p.kind != "predicted"]
            f0, f1 = pa[-1].frame, pb[0].frame
            inside = [i for i, (s0, s1) in span.items() if f0 < s0 and s1 < f1]
            if f1 - f0 < 3 or not inside:
                continue
            gap = f1 - f0
            pr = self._forward(tl, a, gap, f0)
            miss = np.asarray(pb[0].world, float) - pr[gap - 1]
            path = pr + (np.arange(1, gap + 1) / gap)[:, None] * miss  # frames f0+1 .. f1
            # a partial box's centre lies up to half the vehicle's length off its true centre
            half = 0.5 * _typical_length(tl[a]) * self.mpu
            scored = []
            for i in inside:
                fr, xy = pos[i]
                d = np.maximum(np.hypot(*(xy - path[fr - f0 - 1]).T) * self.mpu - half, 0.0)
                t = np.minimum(fr - f0, f1 - fr) / self.fps
                z = float(np.median(d / (c.motion_sigma_m + c.motion_sigma_growth_mps * t)))
                if z <= c.fill_sigma:
                    scored.append((z, i))
            taken: list[int] = []
            for _, i in sorted(scored):
                if all(span[i][1] < span[j][0] or span[j][1] < span[i][0] for j in taken):
                    taken.append(i)
            if not taken:
                continue
            chain = [a, *sorted(taken, key=lambda i: span[i][0]), b]
            for u, v in itertools.pairwise(chain):
                out[u] = v
                if hasattr(self, "_inserted"):
                    self._inserted[(u, v)] = self._inserted.get((a, b), (a, b))
            for i in taken:
                del span[i]
        n_in = len(out) - len(links)
        if n_in:
            log.debug("linking: %d unlinked tracklets inserted into linked gaps", n_in)
        return out

    def _motion(self, pred: np.ndarray, a_end: np.ndarray, b_start: np.ndarray, end_state,
                start_state, gap: int, noise_a=(0.0, 0.0), noise_b=(0.0, 0.0),
                allow_split: bool = True) -> float:
        """Motion cost of linking a (ending at ``a_end``, predicted ``pred`` (gap, 2) world) to b
        (starting at ``b_start`` ``gap`` frames later), :func:`~aerotrack.context.reacquire.motion_cost`.

        The distance is from b's start to the *path* a was predicted to follow (its last position
        included), and from a's end to b's constant-velocity backward path, averaged; how far along
        each path the closest point falls short of the full gap is the lag (the target slowed
        down or stopped while unseen)."""
        c, mpu, fps = self.config, self.mpu, self.fps
        path = np.vstack([a_end[None], pred])
        dist = np.hypot(*(path - b_start).T)
        k = int(np.argmin(dist))
        d_f, lag_f = float(dist[k]) * mpu, float(np.hypot(*(path[-1] - path[k]))) * mpu
        p0, vb = np.asarray(start_state[0], float), np.asarray(start_state[1], float)
        vv = float(vb @ vb)
        t = float(np.clip((p0 - a_end) @ vb / vv, 0.0, gap)) if vv > 0 else 0.0
        d_b = float(np.hypot(*(p0 - vb * t - a_end))) * mpu
        lag_b = (gap - t) * np.sqrt(vv) * mpu
        va = np.asarray(end_state[1], float)
        dv = float(np.hypot(*(vb - va))) * mpu * fps
        gap_s = gap / fps
        turn = None
        if gap_s <= self.turn_max_gap_s:
            sa, sb = _speed(va) * mpu * fps, _speed(vb) * mpu * fps
            reach = max(sa, sb) * gap_s
            chord = float(np.hypot(*(b_start - a_end))) * mpu
            turn = (max(0.0, chord - reach), abs(sb - sa), reach, dv)
        log.debug("motion: d %.2f/%.2f m lag %.1f/%.1f m dv %.2f m/s turn %s", d_f, d_b, lag_f,
                  lag_b, dv, turn)
        k = c.end_noise_scale
        noise_m = k * float(np.sqrt(noise_a[0] ** 2 + noise_b[0] ** 2
                                    + (0.5 * (noise_a[1] + noise_b[1]) * gap_s) ** 2))
        noise_mps = k * float(np.hypot(noise_a[1], noise_b[1]))
        split = allow_split and self._is_split(a_end, b_start, end_state[1], gap)
        return motion_cost(0.5 * (d_f + d_b), gap_s, c, dv, 0.5 * (lag_f + lag_b), turn,
                           noise_m, noise_mps,
                           windows_s=self.ctx.history_s * (2.0 if split else 1.0))

    def _motions(self, e: _Ends, a: int, bs: np.ndarray, pred: np.ndarray,
                 allow_split: np.ndarray) -> np.ndarray:
        """:meth:`_motion` of a -> b on the trimmed ends for every b in ``bs`` at once (the cost
        of a long video's linking was that of its pairs, one Python call each: 6000 tracklets
        over 10 minutes, 740 000 pairs, 64 of 117 s)."""
        c, mpu, fps = self.config, self.mpu, self.fps
        bs = np.asarray(bs, dtype=np.int64)
        gap = (e.first[bs] - e.last[a]).astype(np.int64)
        a_end, va = e.last_xy[a], e.ends_v[a]
        b_start = e.first_xy[bs]
        path = np.vstack([a_end[None], pred])
        out = np.empty(len(bs))
        # distance of each b's start to a's path up to its own gap: by increasing gap, in
        # chunks of bounded size, each over the path as far as its longest gap
        ends = np.minimum(gap, len(pred))
        d_f, lag_f = np.empty(len(bs)), np.empty(len(bs))
        by_gap = np.argsort(ends, kind="stable")
        s = 0
        while s < len(by_gap):
            m = 16  # rows, doubled while rows x columns stays within 2 million distances
            while s + m < len(by_gap) and \
                    2 * m * (int(ends[by_gap[min(len(by_gap), s + 2 * m) - 1]]) + 1) <= 2_000_000:
                m *= 2
            rows = by_gap[s:s + m]
            cols = int(ends[rows[-1]]) + 1
            end = ends[rows]
            dist = np.hypot(path[None, :cols, 0] - b_start[rows, None, 0],
                            path[None, :cols, 1] - b_start[rows, None, 1])
            dist[np.arange(cols)[None, :] > end[:, None]] = np.inf
            k = np.argmin(dist, axis=1)
            d_f[rows] = dist[np.arange(len(k)), k] * mpu
            lag_f[rows] = np.hypot(*(path[end] - path[k]).T) * mpu
            s += len(rows)
        p0, vb = e.starts_xy[bs], e.starts_v[bs]
        vv = vb[:, 0] * vb[:, 0] + vb[:, 1] * vb[:, 1]
        t = np.where(vv > 0, np.clip(((p0 - a_end) * vb).sum(1) / np.where(vv > 0, vv, 1.0), 0.0,
                                     gap), 0.0)
        d_b = np.hypot(*(p0 - vb * t[:, None] - a_end).T) * mpu
        lag_b = (gap - t) * np.sqrt(vv) * mpu
        dv = np.hypot(*(vb - va).T) * mpu * fps
        gap_s = gap / fps
        turn = None
        short = gap_s <= self.turn_max_gap_s
        if short.any():
            sa, sb = float(np.hypot(*va)) * mpu * fps, np.hypot(*vb.T) * mpu * fps
            reach = np.maximum(sa, sb) * gap_s
            chord = np.hypot(*(b_start - a_end).T) * mpu
            turn = np.column_stack([np.maximum(0.0, chord - reach), np.abs(sb - sa), reach, dv])
            turn[~short] = np.nan
        k = c.end_noise_scale
        na, nb = e.noise_end[a], e.noise_start[bs]
        noise_m = k * np.sqrt(na[0] ** 2 + nb[:, 0] ** 2 + (0.5 * (na[1] + nb[:, 1]) * gap_s) ** 2)
        noise_mps = k * np.hypot(na[1], nb[:, 1])
        split = np.zeros(len(bs), dtype=bool)
        if c.split_gap_s > 0:
            near = np.hypot(*(b_start - a_end).T) <= float(np.hypot(*va)) * gap + c.split_dist_m / mpu
            split = allow_split & (gap_s <= c.split_gap_s) & near
        windows = self.ctx.history_s * np.where(split, 2.0, 1.0)
        out[:] = motion_costs(0.5 * (d_f + d_b), gap_s, c, dv, 0.5 * (lag_f + lag_b), turn,
                              noise_m, noise_mps, windows)
        return out

    # -- output -----------------------------------------------------------------------------------

    def build_tracks(self, tl: list[Track], links: dict[int, int], registrations=None,
                     frame_size: tuple[int, int] | None = None) -> list[Track]:
        """One track per chain of links, with predicted points in gaps and after the end (cut
        short by :meth:`_tail_length` when ``registrations`` and ``frame_size`` are given)."""
        video_end = max(t.last for t in tl)
        video_start = min(t.first for t in tl)
        horizon = int(round(self.ctx.prediction_horizon_s * self.fps))
        min_len = self.config.min_tracklet_s * self.fps
        out = []
        for chain in _chains(len(tl), links):
            points: list[TrackPoint] = []
            records = [self._link_record(tl, i, j) for i, j in itertools.pairwise(chain)]
            for k, i in enumerate(chain):
                pts = [p for p in tl[i].points if p.kind != "predicted"]
                points.extend(pts)
                if not self.config.predict_gaps:
                    continue
                last_obs = pts[-1]
                if k + 1 < len(chain):
                    nxt = next(p for p in tl[chain[k + 1]].points if p.kind != "predicted")
                    gap = nxt.frame - last_obs.frame
                    if gap > 1:
                        pr = self._forward(tl, i, gap, last_obs.frame)
                        # land on the re-acquired position: spread the final miss linearly
                        miss = np.asarray(nxt.world, float) - pr[gap - 1]
                        ramp = (np.arange(1, gap) / gap)[:, None]
                        points.extend(_predicted(last_obs, pr[:gap - 1] + ramp * miss))
                else:
                    h = min(horizon, video_end - last_obs.frame)
                    if h > 0 and (tl[i].last - tl[chain[0]].first) >= min_len:
                        pr = self._forward(tl, i, h, last_obs.frame)
                        pr = pr[:self._tail_length(last_obs.frame, pr, registrations, frame_size)]
                        points.extend(_predicted(last_obs, pr))
            points = _one_per_frame(points)
            span = tl[chain[-1]].last - tl[chain[0]].first
            if span < self.config.min_track_s * self.fps and not (
                    span >= self.config.min_edge_track_s * self.fps
                    and _cut_by_view(points, frame_size, video_start, video_end)):
                continue  # a short unlinked blip: a false alarm or a split blob
            out.append(Track(id=0, points=points, links=records))
        out.sort(key=lambda t: (t.first, t.points[0].world[0], t.points[0].world[1]))
        for k, t in enumerate(out, start=1):
            t.id = k
        return out

    def _link_record(self, tl: list[Track], i: int, j: int) -> dict:
        """What ``links.csv`` says of the link i -> j: the last frame i was seen, the first j
        was, how it was made (``linked``: the joint assignment on motion, appearance and the
        descriptor; ``stop``: priced as a wait, ``_stop_cost``; ``inserted``: a short piece put
        in a linked gap, :meth:`fill_gaps`; ``handover``: j's box took over i's while both were
        seen) and its cost and cues (an inserted piece's: those of the link it was put in)."""
        lost = max(p.frame for p in tl[i].points if p.kind != "predicted")
        found = min(p.frame for p in tl[j].points if p.kind != "predicted")
        inserted = getattr(self, "_inserted", {})
        # an inserted piece's hops carry the cost of the link whose gap it lies in, which
        # decided the identity across it
        judged = self.last_costs.get(inserted.get((i, j), (i, j)))
        kind = "inserted" if (i, j) in inserted or judged is None \
            else "stop" if (i, j) in getattr(self, "_stop_won", ()) \
            else "handover" if found <= lost else "linked"
        rec = {"lost": int(lost), "found": int(found), "kind": kind}
        if judged is not None:
            cost, cues = judged
            rec.update(cost=float(cost), motion=float(cues.motion),
                       appearance=float(cues.appearance), descriptor=float(cues.descriptor))
        return rec

    def _tail_length(self, last: int, pr: np.ndarray, registrations, frame_size) -> int:
        """How many of a track's final predictions (``pr`` (h, 2) world, frames last+1..) to keep.

        A target whose predicted position stays inside the frame should be detected again: once
        it has been predicted in view for ``in_view_horizon_s`` (an occlusion longer than that, or
        a lost or spurious track) the prediction stops. Outside the frame (an exit) it runs on to
        ``prediction_horizon_s``. Without registrations or frame size every prediction is kept."""
        if not registrations or frame_size is None:
            return len(pr)
        W, H = frame_size
        limit = int(round(self.config.in_view_horizon_s * self.fps))
        inside = 0
        for k, w in enumerate(pr):
            reg = registrations.get(last + k + 1)
            if reg is None:
                continue
            q = np.linalg.inv(reg.H) @ np.array([w[0], w[1], 1.0])
            if q[2] != 0 and 0 <= q[0] / q[2] < W and 0 <= q[1] / q[2] < H:
                inside += 1
                if inside > limit:
                    return k
        return len(pr)

    def _forward(self, tl: list[Track], i: int, h: int, after: int) -> np.ndarray:
        """Motion-context prediction of tracklet i for the h frames after frame ``after`` (its last
        in-view point), made from the end of its fully visible part (:meth:`_trim_partial`)."""
        if self._trimmed is None or self._table_key is not tl:
            self._trimmed = [self._trim_partial(t, *_positions(t)) for t in tl]
            self._table = None
        fr, _ = self._trimmed[i]
        off = int(after - fr[-1])
        pr = self._pred.get(i)
        if pr is None or len(pr) < h + off:
            if self._table is None or self._table_key is not tl:
                self._table = _table_of(self._trimmed)
                self._table_key = tl
            pr = self.predictor.predict(self._table, i, int(fr[-1]), h + off)
        return pr[off:off + h]

    def _trim_partial(self, t: Track, fr: np.ndarray, xy: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """A tracklet's (frames, xy) with its partly visible ends corrected or left out.

        With registrations and ``partial_model = "edge"`` the partial boxes are corrected
        (:func:`partial_edge_positions`); where that is not possible (no registrations, a target
        standing still) they are left out as below.
        """
        c = self.config
        if c.partial_model == "edge" and self._regs and c.partial_size_ratio > 0:
            out = partial_edge_positions(t, fr, xy, self._regs, self.mpu, self.fps, c.partial_size_ratio,
                                         c.partial_trim_s, c.partial_min_speed_mps,
                                         max(2, int(round(self.ctx.history_s * self.fps))),
                                         self._frame_size)
            if out is not None:
                return out
        return self._trim_ends(t, fr, xy)

    def _trim_ends(self, t: Track, fr: np.ndarray, xy: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """A tracklet's (frames, xy) without the ends where it was only partly visible.

        A target sliding under an occluder or out of the image is detected as a shrinking box
        whose centre lags behind the target's and whose velocity is too low (and the reverse as it
        comes out); estimating the end state there sends the prediction astray. Points at either
        end whose box's longer side (``size_world``) is under ``partial_size_ratio`` of the
        tracklet's typical (90th percentile) size are left out of the end-state estimates and the
        motion context, for at most ``partial_trim_s`` and keeping at least half the points. They
        stay in the output track."""
        c = self.config
        n = len(fr)
        if c.partial_size_ratio <= 0 or n < 4:
            return fr, xy
        obs = [p for p in t.points if p.kind == "observed" and p.size_world is not None]
        S = np.array([p.size_world for p in obs], dtype=np.float64).reshape(len(obs), -1) \
            if obs else np.zeros((0, 2))
        ok = np.isfinite(S).all(axis=1) if S.size else np.zeros(len(obs), bool)
        size = dict(zip([p.frame for p, good in zip(obs, ok) if good],
                        S[ok].max(axis=1).tolist() if ok.any() else []))  # the last per frame
        sz = np.array([size.get(int(f), np.nan) for f in fr.tolist()])
        if np.isfinite(sz).sum() < 4:
            return fr, xy
        small = sz < c.partial_size_ratio * np.nanpercentile(sz, 90)  # NaN: not small
        keep = max(2, (n + 1) // 2)
        span = c.partial_trim_s * self.fps
        lo, hi = 0, n
        while hi - lo > keep and small[hi - 1] and fr[-1] - fr[hi - 1] < span:
            hi -= 1
        while hi - lo > keep and small[lo] and fr[lo] - fr[0] < span:
            lo += 1
        return fr[lo:hi], xy[lo:hi]


def _end_extent(t: Track, velocity: np.ndarray, end: bool, n: int = 3) -> float:
    """Median extent (world units) along ``velocity`` of the boxes of a tracklet's last (first,
    ``end`` False) ``n`` observed points; 0 when unknown."""
    pts = [p for p in t.points if p.kind == "observed" and p.size_world is not None
           and np.all(np.isfinite(p.size_world))]
    pts = pts[-n:] if end else pts[:n]
    sp = float(np.hypot(*velocity))
    if not pts or not (sp > 0):
        return 0.0
    u = np.abs(np.asarray(velocity, float)) / sp
    return float(np.median([u @ np.abs(np.asarray(p.size_world, float)) for p in pts]))


def _cut_by_view(points: list[TrackPoint], frame_size, first_frame: int, last_frame: int,
                 margin_px: float = 2.0) -> bool:
    """Whether a track was seen only briefly because the view cut it: its first observed box
    lies within its own length of the frame's border or in the video's first frame, or its last
    observed box within its length of the border or in the video's last frame."""
    obs = [p for p in points if p.kind == "observed" and p.box is not None]
    if not obs:
        return False
    if obs[0].frame <= first_frame or obs[-1].frame >= last_frame:
        return True
    if frame_size is None:
        return False
    W, H = frame_size

    def at_border(b) -> bool:
        x, y, w, h = (float(v) for v in b)
        m = margin_px + max(w, h)
        return x <= m or y <= m or x + w >= W - m or y + h >= H - m
    return at_border(obs[0].box) or at_border(obs[-1].box)


def _chains(n: int, links: dict[int, int]) -> list[list[int]]:
    """The chains of ``links`` ({a: b}) over tracklets 0..n-1, each in order, by its head."""
    has_pred = set(links.values())
    out = []
    for head in range(n):
        if head in has_pred:
            continue
        chain = [head]
        while chain[-1] in links:
            chain.append(links[chain[-1]])
        out.append(chain)
    return out


def _box_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over the smaller area of boxes ``a`` (n, 4) and ``b`` (n, 4) row by row,
    ``x, y, w, h`` frame pixels; 0 where either box is degenerate or NaN."""
    iw = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2]) - np.maximum(a[:, 0], b[:, 0])
    ih = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3]) - np.maximum(a[:, 1], b[:, 1])
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    small = np.minimum(a[:, 2] * a[:, 3], b[:, 2] * b[:, 3])
    with np.errstate(invalid="ignore", divide="ignore"):
        r = inter / small
    return np.where(np.isfinite(r) & (small > 0), r, 0.0)


def _boxes(t: Track) -> dict[int, np.ndarray]:
    """{frame: box (4,)} of a tracklet's in-view points with a finite box (the first per frame)."""
    pts = [p for p in t.points if p.kind in _IN_VIEW and p.box is not None]
    if not pts:
        return {}
    B = np.array([p.box for p in pts], dtype=np.float64).reshape(-1, 4)
    ok = np.isfinite(B).all(axis=1)
    out: dict[int, np.ndarray] = {}
    for p, b, good in zip(pts, B, ok.tolist()):
        if good and p.frame not in out:
            out[p.frame] = b
    return out


def same_frame_overlaps(frames: np.ndarray, boxes: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair of rows of one frame whose boxes touch: (row i, row j, overlap of the smaller
    box, :func:`_box_overlap`), rows indexing ``frames`` (n,) and ``boxes`` (n, 4) as given;
    candidates from :func:`~aerotrack.association.posterior.left_edge_pairs`."""
    from .posterior import left_edge_pairs

    B = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    finite = np.isfinite(B[:, 2])
    wmax = float(B[finite, 2].max()) if finite.any() else 0.0
    i, j = left_edge_pairs(B[:, 0], wmax, np.asarray(frames))
    if not len(i):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    ov = _box_overlap(B[i], B[j])
    touch = ov > 0
    return i[touch], j[touch], ov[touch]


def coexisting_overlaps(tracklets: list[Track]) -> dict[tuple[int, int], tuple[float, int]]:
    """For every pair of tracklets whose in-view boxes touch in some frame, (i < j): (mean overlap
    of the smaller box over their common frames, frames where they touch counting their overlap
    and the others 0; number of common frames); see :func:`_box_overlap`."""
    idx, fr, boxes, frames = [], [], [], []
    for i, t in enumerate(tracklets):
        bx = _boxes(t)
        frames.append(set(bx))
        idx.extend([i] * len(bx))
        fr.extend(bx)
        boxes.extend(bx.values())
    if not idx:
        return {}
    idx = np.asarray(idx)
    acc: dict[tuple[int, int], float] = {}
    r1, r2, ov = same_frame_overlaps(np.asarray(fr), np.asarray(boxes, dtype=np.float64))
    a, b = idx[r1], idx[r2]
    for lo, hi, o in zip(np.minimum(a, b).tolist(), np.maximum(a, b).tolist(), ov.tolist()):
        acc[(lo, hi)] = acc.get((lo, hi), 0.0) + o
    out = {}
    for (a, b), total in acc.items():
        n = len(frames[a] & frames[b])
        out[(a, b)] = (total / n, n)
    return out


def merge_duplicates(tracklets: list[Track], min_overlap: float) -> list[Track]:
    """Merge tracklets that are a second view of another, longer tracklet's object.

    Local association sometimes keeps two tracklets on one vehicle for a while: a partial blob
    beside the whole one, or a second tracklet through a turn while the first is bridged across
    it. Neither can be *linked* (they coexist), and the shorter one becomes a spurious identity
    that also competes for the object's later tracklets. A tracklet whose box overlaps a longer
    one's by at least ``min_overlap`` of the smaller box on average over all its in-view frames
    (a frame where they do not touch, or where the longer one is not seen, counts 0) is merged
    into it: in each frame the better point is kept (:func:`_one_per_frame`); the merged points
    carry no appearance (``hist``, ``desc``), so the host's appearance models stay its own.
    The shorter one need not lie within the longer one's span: a fragment's tracklet (a long
    vehicle's cab, bridged between the frames where the detector splits it off) often starts a
    little before the whole vehicle's. Dropping that requirement (the frames outside still count
    0) raised the identity benchmark's IDF1 0.800 -> 0.811 (ID switches 20 -> 15) and left
    Santiago and UAVDT unchanged.

    Parameters
    ----------
    tracklets : list of Track
        Frame-pixel boxes on the in-view points.
    min_overlap : float
        Mean intersection over the smaller area; >= 1 disables merging.

    Returns
    -------
    list of Track
        The tracklets left, in input order, merged ones with new point lists (inputs untouched).
    """
    if min_overlap >= 1.0 or len(tracklets) < 2:
        return tracklets
    ov = coexisting_overlaps(tracklets)
    if not ov:
        return tracklets
    frames = [set(_boxes(t)) for t in tracklets]
    host: dict[int, tuple[float, int]] = {}
    for (i, j), (m, n) in ov.items():
        for small, big in ((i, j), (j, i)):
            ts, tb = tracklets[small], tracklets[big]
            nf = len(frames[small])
            if not nf or (tb.last - tb.first, big) <= (ts.last - ts.first, small):
                continue
            score = m * n / nf  # frames of the small one without the big one count 0
            if score >= min_overlap and score > host.get(small, (-1.0, -1))[0] \
                    and not _opposite_motion(ts, tb):
                host[small] = (score, big)
    if not host:
        return tracklets

    def root(i: int) -> int:
        while i in host:
            i = host[i][1]
        return i

    extra: dict[int, list[TrackPoint]] = {}
    for i in sorted(host):
        # a second view of the object is mostly a partial one: its position and box may fill the
        # host's frames, its appearance would blur the host's appearance models
        extra.setdefault(root(i), []).extend(
            dataclasses.replace(p, hist=None, desc=None) for p in tracklets[i].points)
    out = []
    for i, t in enumerate(tracklets):
        if i in host:
            continue
        if i in extra:
            t = Track(id=t.id, points=_one_per_frame(list(t.points) + extra[i]))
        out.append(t)
    log.debug("linking: %d duplicate tracklets merged into the tracklets they lie on", len(host))
    return out


#: :func:`_opposite_motion`: each tracklet moves at least this fraction of its own typical length
#: over the frames both are seen.
OPPOSITE_MIN_TRAVEL = 0.25


def _opposite_motion(a: Track, b: Track) -> bool:
    """Whether tracklets ``a`` and ``b`` move in opposite directions over the frames both are seen
    (their displacements, from a straight-line fit, at over 90 degrees, and each at least
    ``OPPOSITE_MIN_TRAVEL`` of its typical length): one object does not, so neither is a second
    view of the other's (two vehicles passing in one blob, one leaving the view at its edge as
    another comes in)."""
    (fa, xa), (fb, xb) = _positions(a), _positions(b)
    common = np.intersect1d(fa, fb)
    if len(common) < 3:
        return False
    d = []
    for fr, xy, t in ((fa, xa, a), (fb, xb, b)):
        k = np.isin(fr, common)
        slope = np.polyfit(fr[k].astype(np.float64), xy[k], 1)[0]  # (2,) world units per frame
        step = slope * float(common[-1] - common[0])
        if float(np.hypot(*step)) < OPPOSITE_MIN_TRAVEL * _typical_length(t):
            return False
        d.append(step)
    return float(d[0] @ d[1]) < 0.0


def handover_pairs(tracklets: list[Track], min_overlap: float, max_overlap_frames: int,
                   max_area_ratio: float = 0.0) -> dict[tuple[int, int], float]:
    """Pairs (a, b) where b takes over a's object while both are seen: b starts during a, after
    a's first frame, and ends after a's last; they coexist for at most ``max_overlap_frames``
    and their boxes overlap by at least ``min_overlap`` of the smaller on average over a's frames
    from b's start (:func:`merge_duplicates`). With ``max_area_ratio`` > 0, b's boxes in the
    frames both are seen must not be larger than that many times a's (median of the frame
    ratios): a box that holds a's whole box and much more is a blob of a's vehicle merged with
    another one, which b may go on following. Returns {(a, b): mean overlap}."""
    out: dict[tuple[int, int], float] = {}
    if min_overlap >= 1.0:
        return out
    for (i, j), (m, n) in coexisting_overlaps(tracklets).items():
        for a, b in ((i, j), (j, i)):
            ta, tb = tracklets[a], tracklets[b]
            if not (ta.first < tb.first <= ta.last < tb.last):
                continue
            boxes_a = _boxes(ta)
            span = [f for f in boxes_a if f >= tb.first]
            if not span or ta.last - tb.first + 1 > max_overlap_frames:
                continue
            score = m * n / len(span)
            if score < min_overlap:
                continue
            if max_area_ratio > 0:
                boxes_b = _boxes(tb)
                ratios = [boxes_b[f][2] * boxes_b[f][3] / (boxes_a[f][2] * boxes_a[f][3])
                          for f in span if f in boxes_b and boxes_a[f][2] * boxes_a[f][3] > 0]
                if ratios and float(np.median(ratios)) > max_area_ratio:
                    continue
            out[(a, b)] = score
    return out


_KIND_RANK = {"observed": 3, "bridged": 2, "stationary": 2, "predicted": 0}


def _one_per_frame(points: list[TrackPoint]) -> list[TrackPoint]:
    """Points sorted by frame, one per frame: an observation before an interpolated point before
    a prediction, and of two observations the larger box (a partial blob is smaller than the
    whole vehicle)."""
    best: dict[int, TrackPoint] = {}
    for p in points:
        q = best.get(p.frame)
        if q is None or _point_rank(p) > _point_rank(q):
            best[p.frame] = p
    return [best[f] for f in sorted(best)]


def _point_rank(p: TrackPoint) -> tuple[int, float]:
    area = 0.0
    if p.box is not None:
        b = np.asarray(p.box, dtype=np.float64).reshape(4)
        if np.all(np.isfinite(b)):
            area = float(b[2] * b[3])
    return _KIND_RANK.get(p.kind, 1), area


def end_noise(fr: np.ndarray, xy: np.ndarray, mpu: float, fps: float) -> tuple[float, float]:
    """Uncertainty of a tracklet end's state from its own scatter.

    Parameters
    ----------
    fr : ndarray, shape (n,)
        Frames of the end window.
    xy : ndarray, shape (n, 2)
        Positions, world units.

    Returns
    -------
    sigma_m, sigma_mps : float
        Standard deviation of the positions about their least-squares straight line (metres, per
        axis, with n - 2 degrees of freedom) and the resulting standard error of the fitted
        velocity (m/s). With fewer than 3 points the scatter is unknown: (0, 0), the configured
        sigmas alone.
    """
    n = len(fr)
    if n < 3:
        return 0.0, 0.0
    t = (fr - fr.mean()).astype(float)
    stt = float(t @ t)
    if stt <= 0:
        return 0.0, 0.0
    x = xy - xy.mean(axis=0)
    slope = (t @ x) / stt
    r = x - np.outer(t, slope)
    sigma = float(np.sqrt((r ** 2).sum() / (2 * (n - 2)))) * mpu
    return sigma, sigma / np.sqrt(stt) * fps


def estimate_scale(tracklets: list[Track], object_size_m: float) -> float:
    """Metres per world unit when none is known (``--detections`` without a map or ``--gsd``): the
    median observed object's longer side (``size_world``, else the frame-pixel box) is taken to be
    ``object_size_m`` metres. Crude, but it keeps speeds and gates in proportion to the objects."""
    sides = []
    for t in tracklets:
        for p in t.points:
            if p.kind != "observed":
                continue
            size = p.size_world if p.size_world is not None else (None if p.box is None else p.box[2:4])
            if size is not None and np.all(np.isfinite(size)) and max(size) > 0:
                sides.append(float(max(size)))
    return object_size_m / float(np.median(sides)) if sides else 1.0


def partial_edge_positions(t: Track, fr: np.ndarray, xy: np.ndarray, registrations: dict,
                           mpu: float, fps: float, ratio: float, window_s: float,
                           min_speed_mps: float, history: int,
                           frame_size: tuple[int, int] | None = None
                           ) -> tuple[np.ndarray, np.ndarray] | None:
    """World positions of a tracklet with the partial boxes at its ends moved to where the whole
    target's centre is (the partial-box model of a target sliding under an occluder or out of the
    image, and the reverse).

    A target going into an occluder (or over the image edge) at the end of a tracklet keeps its
    *trailing* edge visible until it is gone; one coming out at the start shows its *leading*
    edge first. The edge away from the occluder is therefore on the target, and the centre lies
    half the target's full extent from it. With ``u`` the direction of motion in frame pixels
    (from the world velocity over the ``history`` frames at that end, mapped through the end
    frame's registration; the shrinking happens along the motion, so the direction is not
    biased) and the extent of a box along it ``e = |w u_x| + |h u_y|``, an end (start) point whose
    box has ``e < ratio L`` (``L`` the 90th percentile of e over the tracklet's observed boxes;
    both in world units, through each box's registration, as a box's size in frame pixels changes
    with the camera's zoom and height) is moved forward (backward) along ``u`` by ``(L - e) / 2``,
    for at most ``window_s`` from the end (start), and back to world through its frame's
    registration. (Taking ``L`` near each end instead, within ``window_s`` plus ``history``, lost
    0.006/0.010 HOTA/IDF1 on the held-out generated scenes: a short window holds the partial boxes
    themselves.)
    The image edge is an occluder whose side is known: a box touching it on its leading side
    keeps its trailing edge (moved forward), on its trailing side its leading edge (moved
    backward), whichever end it is at; a box cut on both sides (an occluder at one end, the image
    edge at the other) has no reliable edge and is left out.

    Unlike leaving the partial points out (:meth:`GlobalLinker._trim_ends`), this keeps the
    tracklet's end where it was last seen, so the gap to the next tracklet is the true one and the
    end velocity is that of the trailing edge, the target's own. ``L`` is underestimated for a
    tracklet that never showed the whole target (the correction is then too small, never wrong
    in direction). The papers have no such model; it is aerotrack's. It holds for boxes cut by an
    occluder's outline (ground-truth-like boxes); aerotrack's own detector shrinks a vehicle's
    box about its centre about as often, so the moved points are no closer to the truth on
    average, yet linking gains (``LinkingConfig.partial_model`` has the measurements).

    Parameters
    ----------
    t : Track
        The tracklet (frame-pixel boxes on its points).
    fr : ndarray, shape (n,)
    xy : ndarray, shape (n, 2)
        Frames and world positions of its in-view points (:func:`_positions`).
    registrations : dict frame -> Registration
        Frame pixels -> world.
    mpu, fps : float
        Metres per world unit, frames per second.
    ratio, window_s, min_speed_mps : float
        ``partial_size_ratio``, ``partial_trim_s`` and ``partial_min_speed_mps`` of
        :class:`~aerotrack.config.LinkingConfig`: an end slower than ``min_speed_mps`` has no
        direction and is not corrected.
    history : int
        Frames of the velocity windows.
    frame_size : (W, H), optional
        Image size, for boxes touching the image edge (within 2 pixels).

    Returns
    -------
    (frames (m,), xy (m, 2)) or None
        The points kept (m <= n) with corrected world positions; None when neither end could be
        treated (too few boxes, no registration at the ends, standing still), for the caller to
        fall back on trimming.
    """
    n = len(fr)
    boxes = _boxes(t)
    if n < 4 or len(boxes) < 4:
        return None
    B = np.array([boxes.get(int(f), np.full(4, np.nan)) for f in fr])
    observed = np.array([p.frame for p in t.points if p.kind == "observed"])
    obs = np.isin(fr, observed) & np.isfinite(B).all(axis=1)
    if obs.sum() < 4:
        return None
    out = xy.copy()
    drop = np.zeros(n, dtype=bool)
    span = window_s * fps
    done = False
    for end in (True, False):
        sel = (fr >= fr[-1] - history) if end else (fr <= fr[0] + history)
        f, w = fr[sel].astype(float), xy[sel]
        if len(f) < 3 or np.ptp(f) <= 0:
            continue
        v = np.polyfit(f - f.mean(), w, 1)[0]  # world units per frame, (2,)
        if np.hypot(*v) * mpu * fps < min_speed_mps:
            continue
        k = n - 1 if end else 0
        reg = registrations.get(int(fr[k]))
        if reg is None:
            continue
        a, b = reg.to_frame(np.vstack([xy[k], xy[k] + v * fps]))
        u = b - a
        if not np.all(np.isfinite(u)) or np.hypot(*u) <= 0:
            continue
        u = u / np.hypot(*u)
        e = np.abs(B[:, 2] * u[0]) + np.abs(B[:, 3] * u[1])
        near = (fr >= fr[-1] - span) if end else (fr <= fr[0] + span)
        # the whole target's extent in world units: a box's size in frame pixels changes along
        # a tracklet with the camera's zoom and height (UAV123 truck4: 17 px -> 82 px), and a
        # percentile of frame pixels called every small early box partial
        scale = np.full(n, np.nan)  # world units per frame pixel along u at the box
        idx = [i for i in np.flatnonzero((obs | near) & np.isfinite(e))
               if int(fr[i]) in registrations]
        if idx:
            idx = np.array(idx)
            scale[idx] = _scale_along(np.stack([registrations[int(fr[i])].H for i in idx]),
                                      B[idx, :2] + B[idx, 2:] / 2, u)
        ew = e * scale
        if not np.isfinite(ew[obs]).any():
            continue
        L = float(np.nanpercentile(ew[obs], 90))
        fix = np.flatnonzero(near & np.isfinite(ew) & (ew < ratio * L))
        for i in fix:
            r = registrations[int(fr[i])]
            sign = 1.0 if end else -1.0  # the occluder ahead at an end, behind at a start
            if frame_size is not None:
                lead, trail = _edge_cut(B[i], u, frame_size)
                if lead and trail or (trail and end) or (lead and not end):
                    drop[i] = True  # the image edge cuts the side the occluder rule keeps
                    continue
                if lead or trail:
                    sign = 1.0 if lead else -1.0
            c = B[i, :2] + B[i, 2:] / 2
            out[i] = xy[i] + (r.to_world(c[None] + sign * 0.5 * (L / scale[i] - e[i]) * u[None])[0]
                              - r.to_world(c[None])[0])
        done = True
    if not done or (~drop).sum() < 2:
        return None
    return fr[~drop], out[~drop]


def _scale_along(H: np.ndarray, points: np.ndarray, u: np.ndarray) -> np.ndarray:
    """World units per frame pixel along the unit direction ``u`` at each of ``points`` (k, 2),
    through the homographies ``H`` (k, 3, 3), frame -> world."""
    return np.hypot(*np.einsum("kij,j->ki", homography_jacobian(H, points), u).T)


def _edge_cut(box: np.ndarray, u: np.ndarray, frame_size: tuple[int, int],
              margin: float = 2.0) -> tuple[bool, bool]:
    """Whether a frame-pixel box ``x, y, w, h`` touches the image edge on its leading side
    (the side ``u`` points to) and on its trailing side."""
    W, H = frame_size
    x, y, w, h = box
    at = {"left": x <= margin, "right": x + w >= W - margin, "top": y <= margin,
          "bottom": y + h >= H - margin}
    lead = (u[0] > 0.3 and at["right"]) or (u[0] < -0.3 and at["left"]) or \
        (u[1] > 0.3 and at["bottom"]) or (u[1] < -0.3 and at["top"])
    trail = (u[0] > 0.3 and at["left"]) or (u[0] < -0.3 and at["right"]) or \
        (u[1] > 0.3 and at["top"]) or (u[1] < -0.3 and at["bottom"])
    return bool(lead), bool(trail)


def _typical_length(t: Track) -> float:
    """90th percentile of the longer side (``size_world``, world units) of a tracklet's observed
    boxes, 0 without sizes: its whole length (partial boxes are shorter)."""
    sides = [max(p.size_world) for p in t.points if p.kind == "observed"
             and p.size_world is not None and np.all(np.isfinite(p.size_world))]
    return float(np.percentile(np.abs(sides), 90)) if sides else 0.0


def _local_velocity(fr: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Least-squares velocity (world units per frame) of points ``xy`` at frames ``fr``; zero
    from fewer than two frames."""
    if len(fr) < 2 or fr[-1] == fr[0]:
        return np.zeros(2)
    t = np.asarray(fr, float) - float(np.mean(fr))
    return (t @ (np.asarray(xy, float) - np.mean(xy, axis=0))) / float(t @ t)


def _speed(v) -> float:
    return float(np.hypot(*np.asarray(v, dtype=np.float64).reshape(2)))


def _table_of(pos: list[tuple[np.ndarray, np.ndarray]]) -> TrackTable:
    """A TrackTable of tracklets' (frames, world xy), the tracklet's index as its id."""
    return TrackTable.from_arrays(np.concatenate([np.full(len(fr), j) for j, (fr, _) in enumerate(pos)]),
                                  np.concatenate([fr for fr, _ in pos]),
                                  np.concatenate([xy for _, xy in pos]))


def _predicted(last: TrackPoint, xy: np.ndarray) -> list[TrackPoint]:
    """Predicted points after ``last`` at world positions ``xy`` (k, 2); the box is left for the
    output writer to project (NaN), the size carried from the last observation."""
    return [TrackPoint(frame=last.frame + k + 1, box=np.full(4, np.nan), world=np.asarray(p, float),
                       conf=0.0, kind="predicted", size_world=last.size_world)
            for k, p in enumerate(xy)]


def _assign(n: int, costs: dict[tuple[int, int], float], max_cost: float) -> dict[int, int]:
    """Minimum-cost links among n tracklets from the allowed pairs' costs {(a, b): cost}, each
    tracklet at most once as a and once as b, leaving a tracklet unlinked at ``max_cost / 2``
    per side.

    The Hungarian problem on the (2n, 2n) matrix [[C, no-link diagonal], [no-link diagonal,
    C^T's pattern at 0]], kept sparse: a dense one held 4n^2 numbers and took O(n^3) time (4000
    tracklets, a busy quarter of an hour: 0.5 GB and 20 s per round; 20 000, a few hours: 13 GB),
    sparse 0.1 s and 1.8 s. The lower right block needs only C^T's pattern: with k links taken,
    the k dummies of the linked b's match the k dummies of the linked a's through the taken
    links' transposes, so every set of links is reachable and the optimum is the dense one's
    (checked equal on random problems and every benchmark). All weights are shifted to be
    positive (a perfect matching has 2n edges, so the shift changes no choice): the solver
    reads a stored zero as no edge."""
    if n == 0 or not costs:
        return {}
    ab = np.array(list(costs), dtype=np.int64)
    c = np.array(list(costs.values()), dtype=np.float64)
    off = 1.0 - min(0.0, float(c.min()))
    half = max_cost / 2 + off
    i = np.arange(n)
    rows = np.concatenate([ab[:, 0], i, n + i, n + ab[:, 1]])
    cols = np.concatenate([ab[:, 1], n + i, i, n + ab[:, 0]])
    w = np.concatenate([c + off, np.full(n, half), np.full(n, half), np.full(len(c), off)])
    rows_of, cols_of = min_weight_full_bipartite_matching(
        csr_matrix((w, (rows, cols)), shape=(2 * n, 2 * n)))
    return {int(r): int(k) for r, k in zip(rows_of, cols_of) if r < n and k < n}


def link_tracklets(tracklets: list[Track], fps: float, metres_per_unit: float | None = None,
                   config: LinkingConfig | None = None, ctx: ContextConfig | None = None) -> list[Track]:
    """Pure-function form of :meth:`GlobalLinker.link`."""
    return GlobalLinker(config, ctx, fps, metres_per_unit).link(tracklets)

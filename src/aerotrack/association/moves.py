"""Data-driven MCMC over partitions of the window's observation graph (Yu & Medioni 4.3).

:class:`WindowSampler` holds the current partition of the window (tracks and false alarms) and
runs Metropolis-Hastings with the paper's moves:

==================  ==========================================================================
forward extension   pick a track u.a.r.; append children of its last node, each drawn with
                    probability proportional to its link likelihood (motion x appearance), and
                    continue with probability ``gamma``
forward reduction   pick a track u.a.r. and a cut u.a.r.; drop the observations after it
backward ext./red.  the same at the start of tracks born in the window, with reverse dynamics
birth / death       a false alarm u.a.r. starts a track, extended forward or backward u.a.r. /
                    a track born in the window u.a.r. is dissolved into false alarms
split / merge       cut a track at a link drawn with probability ``1 - p(link)`` (the least
                    likely links first) / join a pair of ``C_merge``: a track u.a.r., then a
                    partner u.a.r. among the tracks born at its last node's children
switch              exchange the tails of two tracks (eq. 11): a track u.a.r., a switch point
                    drawn by link unlikelihood, a partner u.a.r. among its candidates
==================  ==========================================================================

Every move is paired with its reverse and the acceptance ratio uses the exact proposal
probabilities of both directions (including the extension chain's probability of drawing the
same observations in the same order). Observations that left the window are final: a track that
continues across the window start keeps a *prior* (the Kalman state of its last final observation)
and can be extended, reduced down to its prior, split, merged at its end and switched, but not
dissolved or extended backwards.

Tracks are immutable values; a move builds new ones, swaps them in, and swaps them back if
rejected. Per-track Kalman states are cached per observation, so extending or cutting a track
costs one Kalman step, and re-filtering (split tails, merges, switches) runs in compiled code.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from .graph import NodeStore
from .posterior import (
    append_link,
    children_scores,
    link_step,
    partial_allowed,
    run_track,
    switch_candidates,
)

MOVES = ("ext_f", "red_f", "ext_b", "red_b", "birth", "death", "split", "merge", "switch")
#: Proposal probability of each move. Reverse pairs share a weight so that the ratios in the
#: acceptance test stay moderate; switch and extension do most of the useful work once the
#: greedy initialisation has placed the tracks.
MOVE_PROBS = np.array([0.14, 0.14, 0.07, 0.07, 0.1, 0.1, 0.1, 0.1, 0.18])
MOVE_PROBS = MOVE_PROBS / MOVE_PROBS.sum()
REVERSE = {"ext_f": "red_f", "red_f": "ext_f", "ext_b": "red_b", "red_b": "ext_b",
           "birth": "death", "death": "birth", "split": "merge", "merge": "split",
           "switch": "switch"}
_P = dict(zip(MOVES, MOVE_PROBS))


@dataclass(frozen=True)
class Prior:
    """Kalman state (metres) after a track's last final observation, at ``frame``."""

    x: np.ndarray
    P: np.ndarray
    frame: int
    hist: np.ndarray | None


class WTrack:
    """A track's part inside the window (treated as immutable: moves build new ones).

    nodes (n,) gids in frame order; xs (n, 6), Ps (n, 6, 6) filtered states (metres); d2 (n,) and
    gaps (n,) of each incoming link; links (n,) their log-likelihood ratios (motion + appearance
    + missed detections), app (n,) their appearance part; prior the state before the window (None
    for a track born in it); score the track's term of the log posterior (links minus the birth
    cost when born in the window); f_end the frame of its last observation (or of the prior).
    A plain slotted class: tracks are created at every move, a dataclass costs too much.
    """

    __slots__ = ("tid", "nodes", "xs", "Ps", "d2", "gaps", "links", "prior", "score", "f_end",
                 "app")

    def __init__(self, tid, nodes, xs, Ps, d2, gaps, links, prior, score, f_end, app):
        self.tid = tid
        self.nodes = nodes
        self.xs = xs
        self.Ps = Ps
        self.d2 = d2
        self.gaps = gaps
        self.links = links
        self.prior = prior
        self.score = score
        self.f_end = f_end
        self.app = app

    def __len__(self) -> int:
        return len(self.nodes)


@dataclass(frozen=True)
class SamplerParams:
    """Numbers the sampler needs, already converted to metres and frames."""

    fps: float
    kf: np.ndarray  # ConstantVelocityKF.as_array() in metres, then posterior.link_step partial terms
    kf_back: np.ndarray  # the same without partial links, for reverse-time filtering
    reach_mps: float
    max_gap: int  # frames
    gate2: float
    miss_cost: float
    birth_cost: float
    app_weight: float
    overlap_lambda: float
    gamma: float


def _unlikeliness(d2: np.ndarray) -> np.ndarray:
    """``1 - p(link)`` of links with squared Mahalanobis distances ``d2``: ``1 - exp(-d2 / 2)``,
    and 1 for partial links (``d2 < 0``, :data:`.posterior.PARTIAL_D2`), the least certain."""
    return np.where(d2 < 0, 1.0, 1.0 - np.exp(-0.5 * np.abs(d2)))


_ZX = np.zeros(6)
_ZP = np.zeros((6, 6))
_EMPTY1 = np.zeros(0)
_EMPTY2 = np.zeros((0, 0))


class IndexedSet:
    """A set of ints kept sorted, with uniform sampling.

    Sorted rather than in insertion order so that a draw depends only on the members (track ids
    are handed out in the order tracks are created), not on the history of additions and
    removals: a run started later in the video then draws the same tracks from the same random
    numbers. Sets hold at most a few hundred tracks, where ``bisect`` and list inserts are cheap.
    """

    def __init__(self):
        self.items: list[int] = []

    def __len__(self) -> int:
        return len(self.items)

    def __contains__(self, v: int) -> bool:
        i = bisect.bisect_left(self.items, v)
        return i < len(self.items) and self.items[i] == v

    def add(self, v: int) -> None:
        i = bisect.bisect_left(self.items, v)
        if i == len(self.items) or self.items[i] != v:
            self.items.insert(i, v)

    def discard(self, v: int) -> None:
        i = bisect.bisect_left(self.items, v)
        if i < len(self.items) and self.items[i] == v:
            del self.items[i]

    def choice(self, rng: np.random.Generator) -> int:
        return self.items[int(rng.integers(len(self.items)))]


class WindowSampler:
    """The partition of the window and its Metropolis-Hastings sampler.

    Parameters
    ----------
    params : SamplerParams
    rng : numpy.random.Generator
        Owned by the caller's instance; every random choice is drawn from it.
    hist_bins : int or None
        Length of the colour histograms, None when detections carry none (appearance term off).
    """

    def __init__(self, params: SamplerParams, rng: np.random.Generator, hist_bins: int | None):
        self.p = params
        self.rng = rng
        self.store = NodeStore(hist_bins)
        self.tracks: dict[int, WTrack] = {}
        self.tids = IndexedSet()
        self.now = 0
        self.next_tid = 1
        self._trim_checked: dict[tuple[int, int], int] = {}
        self.accepted = dict.fromkeys(MOVES, 0)
        self.proposed = dict.fromkeys(MOVES, 0)

    # ------------------------------------------------------------------ node access
    def _i(self, g):
        return np.asarray(g) - self.store.base

    def frame_of(self, g: int) -> int:
        return int(self.store.frame[g - self.store.base])

    def hist_of(self, g: int) -> np.ndarray | None:
        h = self.store.hist
        return None if h is None else h[g - self.store.base]

    # ------------------------------------------------------------------ track building
    def _app(self, li_prev: np.ndarray, li: np.ndarray) -> np.ndarray:
        """Eq. 9 log appearance likelihood between nodes (store indices) ``li_prev`` and ``li``."""
        s = self.store
        if s.hist is None or self.p.app_weight == 0:
            return np.zeros(len(li))
        kl = np.sum((s.hist[li_prev] - s.hist[li]) * (s.loghist[li_prev] - s.loghist[li]), axis=-1)
        return -0.5 * self.p.app_weight * kl

    def _app_prior(self, h: np.ndarray, li: int) -> float:
        s = self.store
        if s.hist is None or h is None or self.p.app_weight == 0:
            return 0.0
        from .graph import HIST_EPS
        kl = np.sum((h - s.hist[li]) * (np.log(h + HIST_EPS) - s.loghist[li]))
        return float(-0.5 * self.p.app_weight * kl)

    def n_free(self) -> int:
        s = self.store
        return int(np.count_nonzero(s.label[: len(s)] < 0))

    def choice_free(self) -> int:
        s = self.store
        free = np.flatnonzero(s.label[: len(s)] < 0)
        return int(free[int(self.rng.integers(len(free)))]) + s.base

    def build(self, tid: int, nodes: np.ndarray, prior: Prior | None, base: WTrack | None = None,
              keep: int = 0) -> WTrack:
        """A track over ``nodes`` (gids in frame order) after ``prior``.

        The first ``keep`` nodes must be ``base``'s first ``keep`` nodes with the same prior: their
        cached states and link terms are reused and only the rest is filtered. A link outside the
        gate makes the score -inf (no such edge in the graph).
        """
        nodes = np.asarray(nodes, dtype=np.int64)
        s = self.store
        li = nodes - s.base
        n = len(nodes)
        born = prior is None
        if keep == n and keep > 0:
            links = base.links[:keep]
            score = float(links.sum()) - (self.p.birth_cost if born else 0.0)
            return WTrack(tid, nodes, base.xs[:keep], base.Ps[:keep], base.d2[:keep],
                          base.gaps[:keep], links, prior, score, int(s.frame[li[-1]]),
                          base.app[:keep])
        if keep > 0 and keep == n - 1:
            return self._append(tid, nodes, prior, base, keep)
        if keep > 0:
            x0, P0, f0 = base.xs[keep - 1], base.Ps[keep - 1], int(s.frame[li[keep - 1]])
            has, fw = True, self.whole_frame(base, keep)
        elif not born:
            x0, P0, f0, has, fw = prior.x, prior.P, prior.frame, True, prior.frame
        else:
            x0, P0, f0, has, fw = _ZX, _ZP, 0, False, -1
        rest = li[keep:]
        xs, Ps, d2, rel, gaps = run_track(x0, P0, f0, has, s.z[rest], s.frame[rest], self.p.fps,
                                          self.p.kf, fw, s.pok[rest])
        links = 0.5 * self.p.gate2 + rel - self.p.miss_cost * np.maximum(gaps - 1, 0)
        start = 1 if (born and keep == 0) else 0  # index in `rest` of the first incoming link
        if start and len(links):
            links[0] = 0.0
        valid = not np.any(d2[start:] > self.p.gate2)
        app = np.zeros(len(rest))
        if s.hist is not None and self.p.app_weight and len(rest):
            if len(rest) > 1:
                app[1:] = self._app(rest[:-1], rest[1:])
            if keep > 0:
                app[0] = self._app(li[keep - 1:keep], rest[:1])[0]
            elif not born and prior.hist is not None:
                app[0] = self._app_prior(prior.hist, int(rest[0]))
            links = links + app
        if keep > 0:
            xs = np.concatenate([base.xs[:keep], xs])
            Ps = np.concatenate([base.Ps[:keep], Ps])
            d2 = np.concatenate([base.d2[:keep], d2])
            gaps = np.concatenate([base.gaps[:keep], gaps])
            links = np.concatenate([base.links[:keep], links])
            app = np.concatenate([base.app[:keep], app])
        score = float(links.sum()) - (self.p.birth_cost if born else 0.0)
        if not valid:
            score = -math.inf
        f_end = int(s.frame[li[-1]]) if n else prior.frame
        return WTrack(tid, nodes, xs, Ps, d2, gaps, links, prior, score, f_end, app)

    def _append(self, tid, nodes, prior, base, keep) -> WTrack:
        """:meth:`build` for one observation appended to ``base``'s first ``keep`` (compiled)."""
        s = self.store
        lp, lg = int(nodes[keep - 1]) - s.base, int(nodes[keep]) - s.base
        if s.hist is not None:
            hp, lhp, h, lh = s.hist[lp], s.loghist[lp], s.hist[lg], s.loghist[lg]
        else:
            hp = lhp = h = lh = _EMPTY1
        xs, Ps, d2s, gaps, links, apps, d2, _link = append_link(
            base.xs[:keep], base.Ps[:keep], base.d2[:keep], base.gaps[:keep], base.links[:keep],
            base.app[:keep], int(s.frame[lp]), s.z[lg], int(s.frame[lg]), hp, lhp, h, lh,
            self.p.fps, self.p.kf, self.p.gate2, self.p.miss_cost, self.p.app_weight,
            self.whole_frame(base, keep), bool(s.pok[lg]))
        score = float(links.sum()) - (self.p.birth_cost if prior is None else 0.0)
        if d2 > self.p.gate2:
            score = -math.inf
        return WTrack(tid, nodes, xs, Ps, d2s, gaps, links, prior, score, int(s.frame[lg]), apps)

    def end_state(self, t: WTrack):
        """(x, P, frame, hist) at the track's last observation (or its prior)."""
        if len(t):
            g = int(t.nodes[-1])
            return t.xs[-1], t.Ps[-1], self.frame_of(g), self.hist_of(g)
        return t.prior.x, t.prior.P, t.prior.frame, t.prior.hist

    def whole_frame(self, t: WTrack, k: int | None = None) -> int:
        """Frame of the last whole (not partial) observation among ``t``'s first ``k`` (all by
        default), or of its prior."""
        d2 = t.d2
        n = len(d2) if k is None else k
        # almost always the last one is whole: scan from the end (called for every live track
        # every frame; a numpy search per call cost 5 % of the CPU time at 150 objects/frame)
        for i in range(n - 1, -1, -1):
            if d2[i] >= 0:
                return int(self.store.frame[t.nodes[i] - self.store.base])
        return t.prior.frame if t.prior is not None else t.f_end

    @staticmethod
    def end_frame(t: WTrack) -> int:
        return t.f_end

    def start_reverse_state(self, nodes: np.ndarray):
        """Reverse-time Kalman state at the first of ``nodes`` (filtering them backwards)."""
        li = np.asarray(nodes[::-1], dtype=np.int64) - self.store.base
        xs, Ps, _, _, _ = run_track(np.zeros(6), np.zeros((6, 6)), 0, False, self.store.z[li],
                                    self.store.frame[li], self.p.fps, self.p.kf_back, -1,
                                    self.store.pok[li])
        return xs[-1], Ps[-1]

    # ------------------------------------------------------------------ partition edits
    def _set(self, t: WTrack) -> None:
        s = self.store
        li = t.nodes - s.base
        s.label[li] = t.tid
        s.idx[li] = np.arange(len(li))
        if len(li):
            s.prev[li[0]] = -1
            s.prev[li[1:]] = t.nodes[:-1]
        self.tracks[t.tid] = t
        self.tids.add(t.tid)

    def _unset(self, t: WTrack) -> None:
        s = self.store
        li = t.nodes - s.base
        s.label[li] = -1
        s.prev[li] = -1
        del self.tracks[t.tid]
        self.tids.discard(t.tid)

    def replace_extended(self, old: WTrack, new: WTrack) -> None:
        """Swap in ``new``, which is ``old`` with observations appended (only those get labels)."""
        s = self.store
        k = len(old)
        li = new.nodes[k:] - s.base
        s.label[li] = new.tid
        s.idx[li] = np.arange(k, len(new))
        s.prev[li] = new.nodes[k - 1:-1] if k else np.concatenate([[-1], new.nodes[:-1]])
        self.tracks[new.tid] = new

    def swap(self, out: list[WTrack], new: list[WTrack]) -> None:
        for t in out:
            self._unset(t)
        for t in new:
            self._set(t)

    def overlap_gain(self, g: int) -> float:
        """Rise of the eq. 10 term when assigned node ``g`` becomes a false alarm."""
        ov = self.store.overlaps.get(g)
        if ov is None:
            return 0.0
        s = self.store
        return self.p.overlap_lambda * float(sum(
            iou for h, iou in zip(ov[0].tolist(), ov[1].tolist()) if s.label[h - s.base] >= 0))

    def overlap_delta(self, out: list[WTrack], new: list[WTrack]) -> float:
        """Change of the eq. 10 interaction term when ``out`` is replaced by ``new`` (applied)."""
        if not self.store.overlaps:
            return 0.0
        before = set()
        for t in out:
            before.update(t.nodes.tolist())
        after = set()
        for t in new:
            after.update(t.nodes.tolist())
        changed = before ^ after
        if not changed:
            return 0.0
        s = self.store
        delta = 0.0
        for g in changed:
            ov = s.overlaps.get(g)
            if ov is None:
                continue
            for h, iou in zip(ov[0].tolist(), ov[1].tolist()):
                if h in changed and h < g:
                    continue
                a_after = bool(s.label[h - s.base] >= 0)
                a_before = (h in before) if h in changed else a_after
                g_after = g in after
                delta += iou * (float(g_after and a_after) - float((not g_after) and a_before))
        return -self.p.overlap_lambda * delta

    # ------------------------------------------------------------------ proposals
    def _children(self, x, P, f_end, h_end, lo_frame, hi_frame, forward=True, f_whole=None):
        """Free nodes of frames lo..hi linked to a track end (x, P at ``f_end``, histogram
        ``h_end``) by an edge of the graph inside the gate; returns gids and link log-ratios.

        Backwards (``forward`` False, a reverse-time state) there are no partial links: a part
        is smaller than the whole that comes *before* it in the track, and a track is always
        scored forwards (:meth:`build`)."""
        s = self.store
        lo, hi = s.range(lo_frame, hi_frame)
        if hi <= lo:
            return None, None
        a, b = lo - s.base, hi - s.base
        if s.hist is not None and h_end is not None:
            H, LH = s.hist[a:b], s.loghist[a:b]
            from .graph import HIST_EPS
            he, lhe = h_end, np.log(h_end + HIST_EPS)
        else:
            H = LH = _EMPTY2
            he = lhe = _EMPTY1
        idx, w = children_scores(x, P, f_end, he, lhe, s.z[a:b], s.frame[a:b], s.label[a:b], H, LH,
                                 self.p.fps, self.p.kf if forward else self.p.kf_back,
                                 self.p.reach_mps, self.p.gate2,
                                 self.p.miss_cost, self.p.app_weight,
                                 f_end if f_whole is None else f_whole, s.pok[a:b])
        if not len(idx):
            return None, None
        return idx + lo, w

    @staticmethod
    def _softmax_logp(w: np.ndarray) -> np.ndarray:
        m = w.max()
        e = w - m
        return e - math.log(np.exp(e).sum())

    def chain(self, x, P, f_end, h_end, forward: bool, given=None, allow_empty=False,
              f_whole=None):
        """Sample (``given`` None) or evaluate (``given`` a gid list) an extension chain.

        Starting from a track end with state (x, P) at ``f_end``, each draw picks a free child
        (forward) or parent (backward, reverse-time state) with probability proportional to its
        link likelihood; after the first draw, the chain continues with probability ``gamma``
        while candidates exist. The first draw is forced when there are candidates; when there
        are none the chain is empty, which only births allow (``allow_empty``).
        ``f_whole``: frame of the track's last whole observation (default ``f_end``).
        Returns (gids in the order drawn, log probability of drawing exactly them).
        """
        rng = self.rng
        s = self.store
        out: list[int] = []
        logq = 0.0
        k = 0
        G = self.p.max_gap
        while True:
            if forward:
                lo, hi = f_end + 1, min(f_end + G, self.now)
            else:
                lo, hi = max(f_end - G, s.first_frame), f_end - 1
            cands, w = self._children(x, P, f_end, h_end, lo, hi, forward, f_whole)
            if cands is None:
                if given is not None and k < len(given):
                    return out, -math.inf
                if k == 0 and not allow_empty:
                    return out, -math.inf
                return out, logq
            if k > 0:
                stop = (rng.random() >= self.p.gamma) if given is None else k == len(given)
                if stop:
                    return out, logq + math.log(1 - self.p.gamma)
                logq += math.log(self.p.gamma)
            elif given is not None and not len(given):
                return out, -math.inf
            lp = self._softmax_logp(w)
            if given is None:
                j = int(rng.choice(len(cands), p=np.exp(lp)))
            else:
                hit = np.flatnonzero(cands == given[k])
                if not len(hit):
                    return out, -math.inf
                j = int(hit[0])
            g = int(cands[j])
            logq += float(lp[j])
            out.append(g)
            k += 1
            fg = int(s.frame[g - s.base])
            fw = f_end if f_whole is None else f_whole
            x, P, d2, _ = link_step(x, P, abs(fg - f_end) / self.p.fps, s.z[g - s.base],
                                    self.p.kf if forward else self.p.kf_back,
                                    bool(s.pok[g - s.base])
                                    and partial_allowed(fg, fw, self.p.kf))
            if d2 >= 0:
                f_whole = fg
            f_end = fg
            h_end = None if s.hist is None else s.hist[g - s.base]

    # ------------------------------------------------------------------ moves
    def _pick_track(self) -> WTrack | None:
        if not len(self.tids):
            return None
        return self.tracks[self.tids.choice(self.rng)]

    def _cut_choices(self, t: WTrack, forward: bool) -> int:
        n = len(t)
        if forward:
            return n - (0 if t.prior is not None else 1)
        return n - 1 if t.prior is None else 0

    def _chain_eval(self, t_kept: WTrack, seq: list[int], forward: bool) -> float:
        if forward:
            x, P, f, h = self.end_state(t_kept)
            fw = self.whole_frame(t_kept)
        else:
            fw = None
            x, P = self.start_reverse_state(t_kept.nodes)
            g0 = int(t_kept.nodes[0])
            f, h = self.frame_of(g0), self.hist_of(g0)
        _, lq = self.chain(x, P, f, h, forward, given=seq, f_whole=fw)
        return lq

    def move_ext(self, forward: bool):
        t = self._pick_track()
        if t is None or (not forward and (t.prior is not None or not len(t))):
            return None
        if forward:
            x, P, f, h = self.end_state(t)
            if f >= self.now:
                return None
            fw = self.whole_frame(t)
        else:
            fw = None
            x, P = self.start_reverse_state(t.nodes)
            g0 = int(t.nodes[0])
            f, h = self.frame_of(g0), self.hist_of(g0)
        seq, lq = self.chain(x, P, f, h, forward, f_whole=fw)
        if not seq:
            return None
        if forward:
            new = self.build(t.tid, np.concatenate([t.nodes, seq]), t.prior, t, len(t))
        else:
            new = self.build(t.tid, np.concatenate([seq[::-1], t.nodes]), None)
        K = len(self.tids)
        log_fwd = math.log(_P["ext_f" if forward else "ext_b"] / K) + lq

        def log_rev():
            return math.log(_P["red_f" if forward else "red_b"] / K
                            / self._cut_choices(new, forward))
        return [t], [new], log_fwd, log_rev

    def move_red(self, forward: bool):
        t = self._pick_track()
        if t is None:
            return None
        c = self._cut_choices(t, forward)
        if c < 1:
            return None
        r = int(self.rng.integers(c))
        n = len(t)
        if forward:
            keep = r + (0 if t.prior is not None else 1)
            seq = t.nodes[keep:].tolist()
            new = self.build(t.tid, t.nodes[:keep], t.prior, t, keep)
        else:
            keep = r + 1  # suffix length kept
            seq = t.nodes[: n - keep][::-1].tolist()
            new = self.build(t.tid, t.nodes[n - keep:], None)
        K = len(self.tids)
        log_fwd = math.log(_P["red_f" if forward else "red_b"] / K / c)

        def log_rev():
            return math.log(_P["ext_f" if forward else "ext_b"] / K) + self._chain_eval(
                new, seq, forward)
        return [t], [new], log_fwd, log_rev

    def _birth_logq(self, t: WTrack, n_free: int) -> float:
        """log q of a birth producing track ``t``, seeded at its first node and extended forward
        or at its last node and extended backward (both routes counted); ``t``'s nodes free."""
        nodes = t.nodes.tolist()
        terms = []
        for forward in (True, False):
            seed = nodes[0] if forward else nodes[-1]
            single = self.build(0, np.array([seed]), None)
            seq = nodes[1:] if forward else nodes[:-1][::-1]
            _, lq = self.chain(single.xs[0], single.Ps[0], self.frame_of(seed), self.hist_of(seed),
                               forward, given=seq, allow_empty=True)
            terms.append(math.log(0.5) + lq)
        m = max(terms)
        if m == -math.inf:
            return -math.inf
        return math.log(_P["birth"] / n_free) + m + math.log(sum(math.exp(v - m) for v in terms))

    def move_birth(self):
        n_free = self.n_free()
        if not n_free:
            return None
        seed = self.choice_free()
        forward = bool(self.rng.random() < 0.5)
        single = self.build(self.next_tid, np.array([seed]), None)
        x, P = single.xs[0], single.Ps[0]
        seq, _ = self.chain(x, P, self.frame_of(seed), self.hist_of(seed), forward,
                            allow_empty=True)
        nodes = [seed] + seq if forward else seq[::-1] + [seed]
        new = self.build(self.next_tid, np.array(nodes), None)
        log_fwd = self._birth_logq(new, n_free)
        K = len(self.tids)

        def log_rev():
            return math.log(_P["death"] / (K + 1))
        return [], [new], log_fwd, log_rev

    def move_death(self):
        t = self._pick_track()
        if t is None or t.prior is not None:
            return None
        K = len(self.tids)
        log_fwd = math.log(_P["death"] / K)

        def log_rev():
            return self._birth_logq(t, self.n_free())
        return [t], [], log_fwd, log_rev

    def _split_weights(self, t: WTrack) -> tuple[np.ndarray, int]:
        """Weights ``1 - p(link)`` of the links that may be cut, and the index of the first."""
        first = 0 if t.prior is not None else 1
        w = _unlikeliness(t.d2[first:]) + 1e-3
        return w, first

    def move_split(self):
        t = self._pick_track()
        if t is None:
            return None
        w, first = self._split_weights(t)
        if not len(w):
            return None
        j = int(self.rng.choice(len(w), p=w / w.sum()))
        i = first + j  # the link into node i is cut
        head = self.build(t.tid, t.nodes[:i], t.prior, t, i)
        tail = self.build(self.next_tid, t.nodes[i:], None)
        K = len(self.tids)
        log_fwd = math.log(_P["split"] / K * w[j] / w.sum())

        def log_rev():
            n = len(self.merge_cands(head))
            return math.log(_P["merge"] / (K + 1) / n) if n else -math.inf
        return [t], [head, tail], log_fwd, log_rev

    def merge_cands(self, t: WTrack) -> list[int]:
        """Tracks born in the window whose first observation is a child of ``t``'s last (the
        part of C_merge whose first member is ``t``)."""
        s = self.store
        if len(t):
            e = t.nodes[-1] - s.base
            ep, esz = s.z[e, :2], 0.25 * (s.z[e, 2] + s.z[e, 3])
        else:
            ep, esz = t.prior.x[:2], 0.25 * (t.prior.x[2] + t.prior.x[3])
        lo, hi = s.range(t.f_end + 1, min(t.f_end + self.p.max_gap, self.now))
        if hi <= lo:
            return []
        li = np.arange(lo - s.base, hi - s.base)
        li = li[(s.label[li] >= 0) & (s.prev[li] < 0) & (s.label[li] != t.tid)]
        if not len(li):
            return []
        dt = (s.frame[li] - t.f_end) / self.p.fps
        r = self.p.reach_mps * dt + esz
        ok = np.sum((s.z[li, :2] - ep) ** 2, axis=1) <= r * r
        out = []
        for lab in s.label[li[ok]].tolist():
            if self.tracks[lab].prior is None:
                out.append(lab)
        return out

    def move_merge(self):
        """Merge: a track u.a.r., then a partner u.a.r. among its candidates in C_merge."""
        t1 = self._pick_track()
        if t1 is None:
            return None
        cands = self.merge_cands(t1)
        if not cands:
            return None
        t2 = self.tracks[cands[int(self.rng.integers(len(cands)))]]
        new = self.build(t1.tid, np.concatenate([t1.nodes, t2.nodes]), t1.prior, t1, len(t1))
        K = len(self.tids)
        log_fwd = math.log(_P["merge"] / K / len(cands))

        def log_rev():
            w, first = self._split_weights(new)
            jj = len(t1) - first
            return math.log(_P["split"] / (K - 1) * w[jj] / w.sum())
        return [t1, t2], [new], log_fwd, log_rev

    def _switch_cands(self, t: WTrack, p: int) -> np.ndarray:
        """Nodes y = k2(q+1) such that exchanging the tails after t(p) and k2(q) is allowed.

        Eq. 11's pairs, plus (as a natural extension, q = -1) the first node of a track born in
        the window: then t keeps its head and takes all of k2, and t's old tail becomes a track of
        its own. This repairs a track that took a wrong observation where the right one started a
        new track, which neither a merge (the tracks overlap in time) nor eq. 11 can do.
        """
        s = self.store
        gp, gn = int(t.nodes[p]), int(t.nodes[p + 1])
        fp, fn = self.frame_of(gp), self.frame_of(gn)
        lo, hi = s.range(fp + 1, min(fp + self.p.max_gap, self.now))
        if hi <= lo:
            return np.zeros(0, np.int64)
        reg, heads = switch_candidates(s.label, s.prev, s.frame, s.z, s.base, lo - s.base,
                                       hi - s.base, t.tid, fp, fn, s.z[gp - s.base],
                                       s.z[gn - s.base], self.p.fps, self.p.reach_mps,
                                       self.p.max_gap)
        if len(heads):
            heads = heads[[self.tracks[int(v)].prior is None for v in s.label[heads]]]
            reg = np.concatenate([reg, heads])
        return reg + s.base

    @staticmethod
    def _switch_weights(t: WTrack) -> np.ndarray:
        """Data-driven choice of the switch point p (the link p -> p+1): unlikely links first."""
        return _unlikeliness(t.d2[1:]) + 0.05

    def _switch_route(self, t: WTrack, p: int) -> float:
        """Probability of proposing the switch at ``t``'s node p with a given partner."""
        c = len(self._switch_cands(t, p))
        if c == 0:
            return 0.0
        w = self._switch_weights(t)
        return float(w[p] / w.sum()) / c

    def move_switch(self):
        t1 = self._pick_track()
        if t1 is None or len(t1) < 2:
            return None
        w = self._switch_weights(t1)
        p = int(self.rng.choice(len(w), p=w / w.sum()))
        cands = self._switch_cands(t1, p)
        if not len(cands):
            return None
        y = int(cands[int(self.rng.integers(len(cands)))])
        s = self.store
        t2 = self.tracks[int(s.label[y - s.base])]
        q = int(s.idx[y - s.base]) - 1
        # with q = -1 (t2 born at y) only the route from t1 exists, in both directions
        fwd = self._switch_route(t1, p) + (self._switch_route(t2, q) if q >= 0 else 0.0)
        n1 = self.build(t1.tid, np.concatenate([t1.nodes[:p + 1], t2.nodes[q + 1:]]), t1.prior,
                        t1, p + 1)
        n2 = self.build(t2.tid, np.concatenate([t2.nodes[:q + 1], t1.nodes[p + 1:]]), t2.prior,
                        t2, q + 1)
        K = len(self.tids)
        log_fwd = math.log(_P["switch"] / K * fwd)

        def log_rev():
            rev = self._switch_route(n1, p) + (self._switch_route(n2, q) if q >= 0 else 0.0)
            return math.log(_P["switch"] / K * rev) if rev > 0 else -math.inf
        return [t1, t2], [n1, n2], log_fwd, log_rev

    # ------------------------------------------------------------------ MH loop
    def step_mcmc(self) -> float:
        """One Metropolis-Hastings step; returns the change of the log posterior (0 if rejected)."""
        k = int(self.rng.choice(len(MOVES), p=MOVE_PROBS))
        name = MOVES[k]
        self.proposed[name] += 1
        if name == "ext_f":
            prop = self.move_ext(True)
        elif name == "ext_b":
            prop = self.move_ext(False)
        elif name == "red_f":
            prop = self.move_red(True)
        elif name == "red_b":
            prop = self.move_red(False)
        elif name == "birth":
            prop = self.move_birth()
        elif name == "death":
            prop = self.move_death()
        elif name == "split":
            prop = self.move_split()
        elif name == "merge":
            prop = self.move_merge()
        else:
            prop = self.move_switch()
        if prop is None:
            return 0.0
        out, new, log_fwd, log_rev = prop
        d_score = sum(t.score for t in new) - sum(t.score for t in out)
        if not math.isfinite(d_score) or not math.isfinite(log_fwd):
            return 0.0
        self.swap(out, new)
        d_score += self.overlap_delta(out, new)
        # accept iff d + log q_rev - log q_fwd >= log u; as log q_rev <= 0, a proposal with
        # d - log q_fwd < log u is rejected without evaluating the (costly) reverse proposal
        log_u = math.log(max(self.rng.random(), 1e-300))
        accept = d_score - log_fwd >= log_u
        if accept:
            log_a = d_score + log_rev() - log_fwd
            accept = math.isfinite(log_a) and log_a >= log_u
        if accept:
            self.accepted[name] += 1
            if any(t.tid == self.next_tid for t in new):
                self.next_tid += 1
            self._last_swap = (out, new)
            return d_score
        self.swap(new, out)
        return 0.0

    def run(self, n_iter: int) -> None:
        """``n_iter`` MH steps; the best partition met (highest posterior) is kept at the end."""
        total = 0.0
        best = 0.0
        best_state = None
        for _ in range(n_iter):
            d = self.step_mcmc()
            if not d:
                continue
            was_best = best_state is None
            total += d
            if total > best + 1e-9:
                best = total
                best_state = None  # the current partition is the best: no copy needed
            elif was_best and total < best - 1e-9:
                out, new = self._last_swap
                best_state = dict(self.tracks)
                for t in new:
                    del best_state[t.tid]
                for t in out:
                    best_state[t.tid] = t
        if best_state is not None:
            self.restore(best_state)

    def greedy_merges(self) -> int:
        """Deterministic hill climbing after sampling: drop the first observations of tracks born in
        the window while that raises the posterior, and join every track that stopped before the
        current frame to its best merge candidate when that raises the posterior. A chain of
        Metropolis-Hastings samples can leave a fragment behind (a split accepted early, with the
        gains of other moves later); this repairs it. Returns the number of merges."""
        done = 0
        if len(self._trim_checked) > 4 * len(self.tracks) + 256:  # memory bounded by the window
            base = self.store.base
            self._trim_checked = {k: v for k, v in self._trim_checked.items() if k[1] >= base}
        for tid in sorted(self.tracks):
            t1 = self.tracks.get(tid)
            # a birth that starts on a false alarm: drop head nodes while that raises the posterior
            # (checked again each time the track has doubled in length, not every frame)
            while t1 is not None and t1.prior is None and len(t1) >= 3:
                key = (tid, int(t1.nodes[0]))
                if 2 * self._trim_checked.get(key, 1) > len(t1):
                    break
                self._trim_checked[key] = len(t1)
                trimmed = self.build(tid, t1.nodes[1:], None)
                if trimmed.score + self.overlap_gain(int(t1.nodes[0])) <= t1.score:
                    break
                self.swap([t1], [trimmed])
                t1 = trimmed
                done += 1
            if t1 is None or t1.f_end >= self.now:
                continue
            best, best_d = None, 0.0
            for c in self.merge_cands(t1):
                t2 = self.tracks[c]
                new = self.build(t1.tid, np.concatenate([t1.nodes, t2.nodes]), t1.prior, t1,
                                 len(t1))
                d = new.score - t1.score - t2.score
                if d > best_d:
                    best, best_d = (t2, new), d
            if best is not None:
                self.swap([t1, best[0]], [best[1]])
                done += 1
        return done

    def restore(self, tracks: dict[int, WTrack]) -> None:
        for t in list(self.tracks.values()):
            self._unset(t)
        for t in tracks.values():
            self._set(t)

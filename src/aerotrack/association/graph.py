"""The observation graph of the sliding window (Yu & Medioni section 4, eq. 3).

Nodes are the detections of the window, numbered by a global id (``gid``) that increases with the
frame, so the nodes of a run of frames are one contiguous id range. Edges are not stored: eq. 3
(``|y_t1 - y_t2| < v_max * |t2 - t1|``, with ``|t2 - t1|`` at most the bridging gap) is evaluated on
demand over the id range of the neighbouring frames, which keeps memory proportional to the window
and avoids building edges that no move ever looks at. The children ``N^c(y)`` of a node are the
neighbours in later frames, its parents ``N^p(y)`` those in earlier frames.
"""

from __future__ import annotations

import numpy as np

HIST_EPS = 1e-6  # added to histogram bins before logs (eq. 9)


class NodeStore:
    """Per-node arrays of the window, indexed by ``gid - base``.

    Attributes (all indexed by ``gid - base``)
    ------------------------------------------
    frame : (n,) int64
    z : (n, 4) float64
        Observation ``[x, y, w, h]`` in metres (world centre and size times ``metres_per_unit``).
    hist : (n, B) float64 or None
        Colour histogram (appearance, eq. 9).
    label : (n,) int64
        Internal track id the node is assigned to, -1 for a false alarm (tau_0).
    prev : (n,) int64
        The previous node's gid in its track's window part, -1 if first or unassigned.
    idx : (n,) int64
        Position of the node in its track's window part.
    pok : (n,) bool
        Whether the node may be a partial observation of a target
        (:func:`.posterior.partial_candidates`).
    payload : list
        Per node, the source row for output: (Detections, row index).
    """

    def __init__(self, hist_bins: int | None):
        self.base = 0
        self.next = 0
        cap = 256
        self.frame = np.zeros(cap, np.int64)
        self.z = np.zeros((cap, 4))
        self.hist = None if hist_bins is None else np.zeros((cap, hist_bins))
        self.loghist = None if hist_bins is None else np.zeros((cap, hist_bins))
        self.label = np.full(cap, -1, np.int64)
        self.prev = np.full(cap, -1, np.int64)
        self.idx = np.zeros(cap, np.int64)
        self.pok = np.ones(cap, bool)
        self.payload: list = []
        self.fstart: dict[int, int] = {}
        self.fend: dict[int, int] = {}
        self.overlaps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.first_frame = 0
        self.last_frame = -1

    def __len__(self) -> int:
        return self.next - self.base

    def add_frame(self, frame: int, z: np.ndarray, hist: np.ndarray | None, payload: list,
                  ious: tuple[np.ndarray, np.ndarray, np.ndarray],
                  pok: np.ndarray | None = None) -> np.ndarray:
        """Append one frame's nodes; ``ious`` their overlapping pairs ``(i, j, IoU)``, i < j
        (eq. 10; :func:`~aerotrack.association.posterior.iou_pairs`), ``pok`` (n,) which may be
        partial observations (default all).

        Returns their gids."""
        n = len(z)
        self._reserve(n)
        lo = self.next - self.base
        self.frame[lo:lo + n] = frame
        self.z[lo:lo + n] = z
        if self.hist is not None and n:
            self.hist[lo:lo + n] = hist
            self.loghist[lo:lo + n] = np.log(np.asarray(hist) + HIST_EPS)
        self.label[lo:lo + n] = -1
        self.prev[lo:lo + n] = -1
        self.idx[lo:lo + n] = 0
        self.pok[lo:lo + n] = True if pok is None else pok
        self.payload.extend(payload)
        gids = np.arange(self.next, self.next + n, dtype=np.int64)
        if not self.fstart:
            self.first_frame = frame
        self.last_frame = frame
        self.fstart[frame] = self.next
        self.fend[frame] = self.next + n
        self.next += n
        if n > 1:
            ii, jj, vv = ious
            for i, j, v in zip(ii.tolist(), jj.tolist(), vv.tolist()):
                for a, b in ((i, j), (j, i)):
                    g, h = int(gids[a]), int(gids[b])
                    og, ov = self.overlaps.get(g, (np.zeros(0, np.int64), np.zeros(0)))
                    self.overlaps[g] = (np.append(og, h), np.append(ov, v))
        return gids

    def _reserve(self, n: int) -> None:
        used = self.next - self.base
        cap = len(self.frame)
        if used + n <= cap:
            return
        new = max(2 * cap, used + n)
        for name in ("frame", "z", "hist", "loghist", "label", "prev", "idx", "pok"):
            arr = getattr(self, name)
            if arr is None:
                continue
            fill = -1 if name in ("label", "prev") else 0
            out = np.full((new,) + arr.shape[1:], fill, arr.dtype)
            out[:used] = arr[:used]
            setattr(self, name, out)

    def drop_before(self, frame: int) -> None:
        """Forget nodes of frames before ``frame`` (they left the window)."""
        old = [f for f in self.fstart if f < frame]
        if not old:
            return
        new_base = max(self.fend[f] for f in old)
        for f in old:
            del self.fstart[f], self.fend[f]
        self.first_frame = frame
        for g in range(self.base, new_base):
            self.overlaps.pop(g, None)
        shift = new_base - self.base
        used = self.next - self.base
        for name in ("frame", "z", "hist", "loghist", "label", "prev", "idx", "pok"):
            arr = getattr(self, name)
            if arr is None:
                continue
            arr[: used - shift] = arr[shift:used]
        del self.payload[:shift]
        self.base = new_base

    def range(self, f_lo: int, f_hi: int) -> tuple[int, int]:
        """Gid range [lo, hi) of the nodes in frames ``f_lo..f_hi`` (clipped to the window)."""
        if not self.fstart:
            return 0, 0
        f_lo = max(f_lo, self.first_frame)
        f_hi = min(f_hi, self.last_frame)
        if f_lo > f_hi:
            return 0, 0
        return self.fstart[f_lo], self.fend[f_hi]

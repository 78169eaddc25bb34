"""Following vehicles that slow down and stop where the detector loses them (ours, not the papers').

A vehicle that brakes for a light or a queue fades from the sliding-window background's residual
while it still creeps (2-4 m/s) and is gone once it stands: the window's median takes it in.
Without pixels, a track that ends like that cannot be told from one that ended on a false alarm
or went under a tree (``finish.hold_stops`` measured holds of such ends as more often wrong than
right). Here the pixels are still at hand: before each frame's detections go to local
association, every confirmed track that was seen driving (its points spread over
``follow_min_travel_m``), was last seen at most ``follow_start_s`` ago at no more than
``follow_max_speed_mps``, and has no detection at its last place, is looked for in the
frame by normalised cross-correlation with the vehicle's last detected appearance (a grey patch of
its last real detection's box, warped into this frame through both frames' homographies), within
the distance it could have crept since. A match of at least ``follow_min_ncc`` becomes a
detection flagged ``extra["followed"]`` at the match; local association then links it like any
other. The template is never updated from a followed detection, so a follow cannot drift onto
the road: when the vehicle drives off, the road at its place no longer matches and the follow
ends; when it drives off and is detected again, the real detection takes over. A template with
less contrast than ``follow_min_contrast`` grey levels (a dark car on dark asphalt) is not
followed: its correlation with the road is noise. A follow lasts at most ``follow_max_s``.

A false alarm on a fixed pattern (a tree's edge drifting with parallax, a marking) that moved
like a vehicle matches its own place forever. So a track is followed only when its place, as it
looked ``follow_past_s`` before the track came within ``REF_MOVE_M`` of it, does not match the
template: the vehicle arrived there. The follower keeps, per track, a patch of that place from
that earlier frame (taken while the track still moved, kept while it stands, however long), and a
frame every ``PAST_EVERY_S`` for ``follow_past_s`` and a little more.

Frames are needed: with ``track --from`` (cached detections, no frames) nothing is followed.
The follower holds each frame from the pipeline's step until its detections are associated (the
detector holds it as long). Its state (templates, references, the frames it holds and keeps) is
saved when a run is interrupted, beside local association's (:mod:`aerotrack.io.state`), so
``--resume`` goes on following as the uninterrupted run does; the frames are saved as
references to the input and read again.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ConfigError
from ..types import Detections, Registration, apply_homography, local_scales
from .posterior import iou_xywh_centre

__all__ = ["StopFollower"]


@dataclass
class _Template:
    """A grey patch of a frame around a box: a vehicle's appearance at its last real detection,
    or the place a track came to, as it looked before."""

    frame: int
    patch: np.ndarray  # grey uint8, the box plus ``margin`` px on each side (clipped)
    origin: np.ndarray  # (2,) frame pixels of patch[0, 0]
    box: np.ndarray  # (4,) x, y, w, h of the vehicle's box in that frame's pixels
    H: np.ndarray  # that frame's homography (frame pixels -> world)


class StopFollower:
    """Adds ``followed`` detections of lost slow tracks to each frame (see the module doc).

    Parameters
    ----------
    config : AssociationConfig
        The ``follow_*`` settings.
    fps : float
        Frame rate.
    """

    def __init__(self, config, fps: float, geomap=None):
        if not config.follow_min_ncc <= 1.0:
            raise ConfigError("config association.follow_min_ncc: a normalised cross-correlation "
                              f"is at most 1, got {config.follow_min_ncc!r}")
        self.c = config
        self.geomap = geomap
        self.fps = float(fps)
        self._cache: dict[int, dict[int, _Template]] = {}  # frame -> detection index -> template
        self._tmpl: dict[int, _Template] = {}  # track id -> template of its last real detection
        self._past: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # frame -> (grey, H), sampled
        self._moved: dict[tuple, bool] = {}  # (track, template frame, ref frame) -> arrived
        # track id -> (ground point, the place's patch from before the track came there)
        self._ref: dict[int, tuple[np.ndarray, _Template]] = {}
        self._held: dict[int, np.ndarray] = {}  # frame -> image, until its detections come
        self.n_followed = 0  # followed detections added so far (in ``count_frames``)
        #: (first, last) frame whose followed detections ``n_followed`` counts (None: all): a
        #: segment of a parallel run counts only the frames it owns.
        self.count_frames: tuple[int, int] | None = None

    # ------------------------------------------------------------------ per frame
    def hold(self, index: int, image: np.ndarray) -> None:
        """Keep frame ``index``'s image until :meth:`step` gets its detections."""
        self._held[index] = image

    def step(self, dets: Detections, reg: Registration | None, associator) -> Detections:
        """``dets`` with the followed detections of ``dets.frame`` appended, found in the frame
        :meth:`hold` kept for it (none without one); remembers the templates of its real
        detections. Frames held before ``dets.frame`` (they gave no detections) are let go."""
        k = dets.frame
        image = self._held.pop(k, None)
        for f in [f for f in self._held if f < k]:
            del self._held[f]
        if image is None or reg is None or not associator.mpu:
            return dets
        grey = self.grey(image)
        H = np.asarray(reg.H, dtype=np.float64)
        keep = max(1, int(round((self.c.follow_start_s + 0.1) * self.fps)) + 1)
        for f in [f for f in self._cache if f < k - keep]:
            del self._cache[f]
        self._update_refs(k, associator)
        new = self._follow(dets, grey, H, associator)
        out = dets if new is None else _append(dets, new, image, H, self.geomap)
        if self.count_frames is None or self.count_frames[0] <= k <= self.count_frames[1]:
            self.n_followed += len(out) - len(dets)
        self._remember(dets, grey, H)
        every = max(1, int(round(self.fps * PAST_EVERY_S)))
        if k % every == 0:
            self._past[k] = (grey, H)
        horizon = int(round((self.c.follow_past_s + self.c.follow_start_s + 2 * PAST_EVERY_S)
                            * self.fps))
        for f in [f for f in self._past if f < k - horizon]:
            del self._past[f]
        if len(self._moved) > 4096:
            self._moved.clear()
        return out

    @staticmethod
    def grey(image: np.ndarray) -> np.ndarray:
        """The grey frame (uint8, frame pixels) the follower matches in."""
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)

    def kept(self) -> dict[int, dict[str, np.ndarray]]:
        """Frame -> ``{"grey": grey}`` of the frames kept for :meth:`_arrived` (:meth:`grey`
        of frames no stage holds any more): a saved state refers to them instead of holding
        them (:class:`aerotrack.io.state.Rereadable`)."""
        return {f: {"grey": grey} for f, (grey, _) in self._past.items()}

    def _update_refs(self, k: int, associator) -> None:
        """For every track detected in the frame before ``k``: when it is more than
        ``REF_MOVE_M`` from where its reference was taken (or has none), a patch of that place
        from the kept frame at least ``follow_past_s`` older. A vehicle that stands keeps the
        reference of the place as it was before it came there, however long it stands."""
        mpu = associator.mpu
        live = set()
        for e in associator.track_ends():
            live.add(e["tid"])
            if e["followed"] or e["frame"] != k - 1:
                continue
            old = self._ref.get(e["tid"])
            if old is not None and float(np.hypot(*(old[0] - e["world"]))) * mpu <= REF_MOVE_M:
                continue
            want = e["frame"] - self.c.follow_past_s * self.fps
            older = [f for f in self._past if f <= want]
            if not older:
                self._ref.pop(e["tid"], None)
                continue
            f = max(older)
            grey, H = self._past[f]
            c = apply_homography(np.linalg.inv(H), np.asarray(e["world"], float)[None])[0]
            scale = float(local_scales(H, c[None])[0]) * mpu
            if not (np.all(np.isfinite(c)) and scale > 0):
                continue
            w, h = e["box"][2:]
            m = int(np.ceil(PAST_RADIUS_M / scale)) + 4 + int(np.ceil(0.3 * max(w, h)))
            x0, y0 = int(max(0, np.floor(c[0] - w / 2 - m))), int(max(0, np.floor(c[1] - h / 2 - m)))
            x1 = int(min(grey.shape[1], np.ceil(c[0] + w / 2 + m)))
            y1 = int(min(grey.shape[0], np.ceil(c[1] + h / 2 + m)))
            if x1 - x0 < 3 or y1 - y0 < 3:
                continue
            self._ref[e["tid"]] = (np.asarray(e["world"], float).copy(), _Template(
                f, grey[y0:y1, x0:x1].copy(), np.array([x0, y0], float),
                np.array([c[0] - w / 2, c[1] - h / 2, w, h]), H))
        for tid in [t for t in self._ref if t not in live]:
            del self._ref[tid]

    def _arrived(self, tid: int, t: _Template, r_px: int) -> bool:
        """Whether the vehicle of template ``t`` came to where it stands: the place, as it
        looked at least ``follow_past_s`` before the track came within ``REF_MOVE_M`` of it,
        does not match the template within ``r_px`` pixels (a false alarm on a fixed pattern,
        a tree's edge or a marking matches itself there and is never followed)."""
        ref = self._ref.get(tid)
        if ref is None:
            return False  # nothing seen of the place before: cannot tell
        r = ref[1]
        key = (tid, t.frame, r.frame)
        if key not in self._moved:
            # the reference patch as a small frame: its pixels -> world
            Hp = r.H @ np.array([[1, 0, r.origin[0]], [0, 1, r.origin[1]], [0, 0, 1]], float)
            m = _match(t, r.patch, Hp, None, r_px)
            self._moved[key] = m is not None and m[0] < self.c.follow_min_ncc
        return self._moved[key]

    def _remember(self, dets: Detections, grey: np.ndarray, H: np.ndarray) -> None:
        m = self.c.follow_margin_px
        out = {}
        followed = dets.extra.get("followed")
        for i, b in enumerate(np.asarray(dets.boxes, dtype=np.float64)):
            if followed is not None and followed[i]:
                continue
            x0, y0 = int(max(0, np.floor(b[0] - m))), int(max(0, np.floor(b[1] - m)))
            x1 = int(min(grey.shape[1], np.ceil(b[0] + b[2] + m)))
            y1 = int(min(grey.shape[0], np.ceil(b[1] + b[3] + m)))
            if x1 - x0 < 3 or y1 - y0 < 3:
                continue
            out[i] = _Template(dets.frame, grey[y0:y1, x0:x1].copy(), np.array([x0, y0], float),
                               b.copy(), H)
        self._cache[dets.frame] = out

    def _follow(self, dets: Detections, grey: np.ndarray, H: np.ndarray, associator):
        c = self.c
        k = dets.frame
        cands = associator.lost_tracks(k, c.follow_start_s, c.follow_max_s,
                                       c.follow_max_speed_mps, c.follow_min_travel_m,
                                       max(2, round(c.follow_min_obs_s * self.fps)))
        live = {cd["tid"] for cd in cands}
        for tid in [t for t in self._tmpl if t not in live]:
            del self._tmpl[tid]
        if not cands:
            return None
        Hinv = np.linalg.inv(H)
        boxes = np.asarray(dets.boxes, dtype=np.float64).reshape(-1, 4)
        found = []
        mpu = associator.mpu
        for cd in cands:
            tid = cd["tid"]
            if not cd["followed"]:  # its last observation is a real detection: its template
                t = self._cache.get(cd["frame"], {}).get(cd["index"])
                if t is None:
                    continue
                self._tmpl[tid] = t
            t = self._tmpl.get(tid)
            if t is None or float(t.patch.std()) < c.follow_min_contrast:
                continue
            centre = apply_homography(Hinv, np.asarray(cd["world"], float)[None])[0]
            if not np.all(np.isfinite(centre)):
                continue
            scale = float(local_scales(H, centre[None])[0]) * mpu  # metres per frame pixel
            if not scale > 0:
                continue
            # a vehicle, not a fragment: the template's box in metres
            tb = t.box[2:] * float(local_scales(t.H, (t.box[:2] + t.box[2:] / 2)[None])[0]) * mpu
            if min(tb) < c.follow_min_width_m or tb[0] * tb[1] < c.follow_min_area_m2:
                continue
            # how far it may have crept since the track's last observation (a frame, when
            # followed); a stopping vehicle creeps at most ``follow_max_creep_m`` more from its
            # last real detection
            dt = (k - cd["frame"]) / self.fps
            r = int(np.ceil(c.follow_max_speed_mps * dt / scale)) + 1
            m = _match(t, grey, H, centre, r, boxes)
            if m is None or not m[0] >= c.follow_min_ncc or not self._arrived(
                    tid, t, int(np.ceil(PAST_RADIUS_M / scale)) + 1):
                continue
            best, x, y, tw, th = m
            at = np.array([x + tw / 2, y + th / 2])
            if float(np.hypot(*(apply_homography(H, at[None])[0]
                                - apply_homography(t.H, (t.box[:2] + t.box[2:] / 2)[None])[0])
                               )) * mpu > c.follow_max_creep_m:
                continue
            found.append(([x, y, tw, th], float(best)))
        return found or None


#: How often a frame is kept for :meth:`StopFollower._arrived`, seconds, and how far from the
#: template's place (metres) the earlier frame is searched.
PAST_EVERY_S = 0.2
PAST_RADIUS_M = 0.5
#: A track's reference of its place is taken again once it is this far (metres) from where the
#: last one was taken.
REF_MOVE_M = 1.0


def _match(t: _Template, grey: np.ndarray, H: np.ndarray, centre: np.ndarray | None, r: int,
           boxes: np.ndarray | None = None):
    """Template ``t`` warped into the frame (``grey``, homography ``H``) and matched by
    normalised cross-correlation within ``r`` pixels of ``centre`` (frame pixels; None: where
    the template's own box lands). Returns ``(ncc, x, y, w, h)`` of the best match (box in frame
    pixels), or None when the search leaves the frame or ``boxes`` (the frame's detections)
    already hold something there."""
    Hinv = np.linalg.inv(H)
    G = Hinv @ t.H  # template frame pixels -> this frame's pixels
    corners = np.array([[0, 0], [t.box[2], 0], [t.box[2], t.box[3]], [0, t.box[3]]],
                       float) + t.box[:2]
    ck = apply_homography(G, corners)
    w, h = float(np.ptp(ck[:, 0])), float(np.ptp(ck[:, 1]))
    if not (np.isfinite(w) and np.isfinite(h)) or w < 3 or h < 3:
        return None
    bc = apply_homography(G, (t.box[:2] + t.box[2:] / 2)[None])[0]
    if centre is None:
        centre = bc
    if boxes is not None and len(boxes):
        pb = np.array([centre[0] - w / 2, centre[1] - h / 2, w, h])
        if np.any(iou_xywh_centre(_centred(pb), _centred(boxes)) >= 0.2):
            return None  # a detection already there: association takes that one
    tw, th = int(round(w)), int(round(h))
    # the vehicle's box (not the margin) warped to land centred in a tw x th template
    T = np.array([[1, 0, tw / 2 - bc[0]], [0, 1, th / 2 - bc[1]], [0, 0, 1]])
    O = np.array([[1, 0, t.origin[0]], [0, 1, t.origin[1]], [0, 0, 1]])
    tmpl = cv2.warpPerspective(t.patch, T @ G @ O, (tw, th), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)
    x0, y0 = int(round(centre[0] - tw / 2)) - r, int(round(centre[1] - th / 2)) - r
    x1, y1 = x0 + tw + 2 * r, y0 + th + 2 * r
    if x0 < 0 or y0 < 0 or x1 > grey.shape[1] or y1 > grey.shape[0]:
        return None  # at the border: leaving the view, not standing
    res = cv2.matchTemplate(grey[y0:y1, x0:x1], tmpl, cv2.TM_CCOEFF_NORMED)
    _, best, _, loc = cv2.minMaxLoc(res)
    return float(best), x0 + loc[0], y0 + loc[1], tw, th


def _centred(boxes: np.ndarray) -> np.ndarray:
    """(N, 4) ``x, y, w, h`` boxes as ``centre x, centre y, w, h``."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return np.column_stack([b[:, :2] + b[:, 2:] / 2, b[:, 2:]])


def _append(dets: Detections, found, image: np.ndarray, H: np.ndarray, geomap) -> Detections:
    """``dets`` with one row per ``(box, ncc)`` in ``found``, flagged ``extra["followed"]``."""
    from ..detection import describe

    boxes = np.array([b for b, _ in found], dtype=np.float64)
    ncc = np.array([s for _, s in found])
    n, m = len(dets), len(boxes)
    centres = boxes[:, :2] + boxes[:, 2:] / 2
    world = apply_homography(H, centres)
    size_world = boxes[:, 2:] * local_scales(H, centres)[:, None]
    hist, desc = describe(image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR),
                          boxes)
    extra = {}
    for key, v in dets.extra.items():
        v = np.asarray(v)
        if key == "desc" and desc is not None and desc.shape[1:] == v.shape[1:]:
            add = desc.astype(v.dtype)
        else:
            add = np.zeros((m, *v.shape[1:]), dtype=v.dtype)
        extra[key] = np.concatenate([v, add]) if n else add
    extra["followed"] = np.concatenate([np.asarray(dets.extra.get("followed", np.zeros(n, bool)),
                                                   bool), np.ones(m, bool)])

    def cat(a, b):
        return None if a is None else np.concatenate([np.asarray(a).reshape(n, *np.shape(b)[1:]), b])

    hist_all = None
    if dets.hist is not None and hist is not None and hist.shape[1] == np.shape(dets.hist)[1]:
        hist_all = cat(dets.hist, hist)
    elif dets.hist is None and n == 0:
        hist_all = hist
    if dets.hist is not None and hist_all is None:
        return dets  # appearance of another kind: leave the frame as it is
    mapxy = lonlat = None
    if dets.mapxy is not None and geomap is not None:
        xy = geomap.pixel_to_crs(world)
        mapxy = cat(dets.mapxy, xy)
        if dets.lonlat is not None:
            lonlat = cat(dets.lonlat, geomap.crs_to_lonlat(xy))
    return Detections(frame=dets.frame,
                      boxes=np.concatenate([np.asarray(dets.boxes, float).reshape(n, 4), boxes]),
                      conf=np.concatenate([np.asarray(dets.conf, float), ncc * 0.5]),
                      world=np.concatenate([np.asarray(dets.world, float).reshape(n, 2), world]),
                      mapxy=mapxy, lonlat=lonlat, hist=hist_all,
                      size_world=cat(dets.size_world, size_world),
                      extra=extra)

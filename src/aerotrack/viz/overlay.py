"""Overlay video: the input frames with each track's box, ID label, short trail, and the predicted
position of targets that are out of view.

Drawing rules
-------------
* colour: a pure function of the ID (:mod:`aerotrack.viz.colours`), the same in every picture;
* in view (``tracks.csv``): solid box and a filled label with the ID;
* out of view (``predicted.csv``): dashed box, label ``ID +t s`` (seconds since last seen) and a
  dashed circle of the position uncertainty; when the predicted position lies outside the image, an
  arrow on the image border points to it;
* trail: the last ``trail_s`` seconds of the target's ground points, carried into the current frame
  through the homographies of ``registration.csv`` (so trails stay on the ground while the camera
  moves); predicted parts of the trail are dotted.

Text height is a fraction of the frame height (at least 1.5 %), so labels read the same on 4K and on
640x480 video.

The uncertainty circle: ``predicted.csv`` carries no covariance, so the radius is modelled as the
box's half-diagonal plus ``speed_uncertainty`` times the target's last observed speed times the time
since it was last seen (a constant relative speed error integrated over the gap). A circle wider
than ``MAX_CIRCLE`` of the frame's shorter side is not drawn: it would cross the whole picture as a
stray arc and say nothing (the label's ``+t s`` tells how old the prediction is).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..types import apply_homography
from .colours import id_bgr, text_colour_on
from .results import RunResults, TrackView
from .video import VideoEncoder

FONT = cv2.FONT_HERSHEY_SIMPLEX

#: Largest uncertainty circle drawn, as a share of the frame's shorter side (radius).
MAX_CIRCLE = 0.35


@dataclass(frozen=True)
class OverlayStyle:
    """How the overlay is drawn.

    Attributes
    ----------
    trail_s : float
        Seconds of trail behind each target. Longer shows more history but clutters dense scenes.
    text_height : float
        Label text height as a fraction of the frame height (the default 0.017 reads at 640x480
        and 4K alike; down to 0.008 for dense traffic, where a label is larger than a car).
    line_width : float
        Box line width as a fraction of the frame height (at least 1 pixel).
    speed_uncertainty : float
        Relative speed error used to grow the uncertainty circle of predicted positions.
    max_width : int or None
        Output frames wider than this are downscaled (keeps report videos small).
    hud : bool
        Draw the frame number, time and counts in the top-left corner.
    labels : bool
        Draw the ID labels (off: boxes, trails and predictions only).
    """

    trail_s: float = 2.0
    text_height: float = 0.017
    line_width: float = 0.0022
    speed_uncertainty: float = 0.3
    max_width: int | None = None
    hud: bool = True
    labels: bool = True

    def __post_init__(self) -> None:
        if not 0.008 <= self.text_height <= 0.1:
            raise InputError(f"--text-height {self.text_height}: must be between 0.008 and 0.1 "
                             "(a fraction of the frame height)")
        if self.trail_s < 0:
            raise InputError(f"--trail-s {self.trail_s}: must be >= 0")


@dataclass
class _Row:
    id: int
    box: np.ndarray
    observed: bool
    since_s: float  # seconds since last in view (0 when observed)
    radius_world: float  # uncertainty radius growth in world units (without the box half-diagonal)


class OverlayPainter:
    """Draws one run's tracks on its frames (the pure per-frame drawing is :meth:`draw`).

    Parameters
    ----------
    results : RunResults
    style : OverlayStyle
    """

    def __init__(self, results: RunResults, style: OverlayStyle = OverlayStyle()) -> None:
        self.results = results
        self.style = style
        self.fps = results.fps
        self.reg = results.registration
        self.tracks: dict[int, TrackView] = {tv.id: tv for tv in results.track_views(None)}
        self.by_frame: dict[int, list[_Row]] = defaultdict(list)
        for tv in self.tracks.values():
            self._index(tv)

    def _index(self, tv: TrackView) -> None:
        last_seen = None
        speed = 0.0  # world units per second, over the last observed half-second
        k = max(2, int(round(0.5 * self.fps)))
        for i, f in enumerate(tv.frames):
            if tv.observed[i]:
                last_seen = i
                j = max(0, i - k)
                seg = tv.world[j:i + 1][tv.observed[j:i + 1]]
                fr = tv.frames[j:i + 1][tv.observed[j:i + 1]]
                if len(seg) >= 2 and np.all(np.isfinite(seg[[0, -1]])) and fr[-1] > fr[0]:
                    speed = float(np.hypot(*(seg[-1] - seg[0]))) / ((fr[-1] - fr[0]) / self.fps)
                self.by_frame[int(f)].append(_Row(tv.id, tv.boxes[i], True, 0.0, 0.0))
            else:
                since = (f - tv.frames[last_seen]) / self.fps if last_seen is not None else 0.0
                self.by_frame[int(f)].append(
                    _Row(tv.id, tv.boxes[i], False, since, self.style.speed_uncertainty * speed * since))

    # -- geometry helpers ---------------------------------------------------------------------------
    def _world_to_frame(self, frame: int, pts: np.ndarray) -> np.ndarray | None:
        if self.reg is None or not len(self.reg):
            return pts
        H = self.reg.get(frame)
        if H is None:
            return None
        return apply_homography(np.linalg.inv(H), pts)

    def _world_scale(self, frame: int, at: np.ndarray) -> float:
        """Frame pixels per world unit near ``at`` (frame pixels)."""
        if self.reg is None or not len(self.reg):
            return 1.0
        H = self.reg.get(frame)
        if H is None:
            return 1.0
        p = np.array([at, at + [1.0, 0.0], at + [0.0, 1.0]])
        w = apply_homography(H, p)
        u, v = w[1] - w[0], w[2] - w[0]
        a = abs(u[0] * v[1] - u[1] * v[0])
        return 1.0 / math.sqrt(a) if a > 0 and math.isfinite(a) else 1.0

    # -- drawing ------------------------------------------------------------------------------------
    def draw(self, image: np.ndarray, frame: int, *, copy: bool = True) -> np.ndarray:
        """Return ``image`` (frame ``frame``'s BGR pixels) with the overlay drawn: on a copy, or on
        ``image`` itself with ``copy=False``."""
        img = image.copy() if copy else image
        h, w = img.shape[:2]
        lw = max(1, int(round(self.style.line_width * h)))
        text_px = max(8.0, self.style.text_height * h)
        scale = text_px / cv2.getTextSize("0", FONT, 1.0, 1)[0][1]
        thick = max(1, int(round(scale * 1.6)))
        rows = self.by_frame.get(frame, [])
        trail_n = int(round(self.style.trail_s * self.fps))
        if trail_n > 0:
            for r in rows:
                self._draw_trail(img, frame, r.id, trail_n, lw)
        # predicted shapes first, observed boxes on top; labels of observed targets always, those
        # of predicted ones only where they do not hide another label (most recently seen first)
        pending = []
        hud = self._hud_box(frame, rows, scale, thick) if self.style.hud else None
        pscale = scale * max(0.008, 0.85 * self.style.text_height) / self.style.text_height
        for r in sorted((r for r in rows if not r.observed), key=lambda r: r.since_s):
            colour = id_bgr(r.id)
            x, y, bw, bh = (float(v) for v in r.box)
            cx, cy = x + bw / 2, y + bh / 2
            radius = 0.5 * math.hypot(bw, bh) + r.radius_world * self._world_scale(frame, np.array([cx, cy]))
            text = f"{r.id} +{r.since_s:.1f}s"
            if 0 <= cx < w and 0 <= cy < h:
                _dashed_rect(img, x, y, bw, bh, colour, lw)
                if radius <= MAX_CIRCLE * min(h, w):
                    _dashed_circle(img, cx, cy, radius, colour, max(1, lw // 2 + 1))
                pending.append((text, x, y, y + bh, colour))
            else:
                pending.append((text, *self._draw_offscreen(img, cx, cy, colour, lw, keep_out=hud), colour))
        placed = _Rects()
        if hud is not None:
            placed.append((0, 0, hud[0], hud[1]))
        observed = [r for r in rows if r.observed]
        boxes = np.array([(r.box[0], r.box[1], r.box[0] + r.box[2], r.box[1] + r.box[3])
                          for r in observed], np.float64).reshape(-1, 4).astype(np.int64)
        chosen = []
        for i, r in enumerate(observed):
            colour = id_bgr(r.id)
            x, y, bw, bh = (float(v) for v in r.box)
            cv2.rectangle(img, _pt(x, y), _pt(x + bw, y + bh), colour, lw, cv2.LINE_AA)
            if self.style.labels:
                chosen.append(_label(img, str(r.id), x, y, y + bh, colour, scale, thick,
                                     placed=placed, right=x + bw,
                                     avoid=np.delete(boxes, i, axis=0)))
        if self.style.labels:
            for text, x, top, bottom, colour in pending:
                _label(img, text, x, top, bottom, colour, pscale, thick, hollow=True,
                       placed=placed, optional=True, avoid=boxes)
            for r, rect in zip(observed, chosen):  # again, on top of any predicted label edge
                x, y, bw, bh = (float(v) for v in r.box)
                _label(img, str(r.id), x, y, y + bh, id_bgr(r.id), scale, thick, rect=rect)
        if self.style.hud:
            self._draw_hud(img, frame, rows, scale, thick)
        return img

    def _draw_trail(self, img, frame, tid, n, lw) -> None:
        tv = self.tracks[tid]
        sel = (tv.frames > frame - n) & (tv.frames <= frame)
        if sel.sum() < 2:
            return
        world = tv.world[sel]
        ok = np.all(np.isfinite(world), axis=1)
        pts = self._world_to_frame(frame, np.where(ok[:, None], world, 0.0))
        if pts is None:
            return
        colour = id_bgr(tid)
        obs = tv.observed[sel]
        good = ok & np.all(np.isfinite(pts), axis=1) & (np.abs(pts).max(axis=1, initial=0) < 1e5)
        solid = good[1:] & good[:-1] & obs[1:] & obs[:-1]  # segment i-1 -> i drawn solid
        # runs of consecutive solid segments become one polyline each
        edges = np.flatnonzero(np.diff(np.r_[0, solid.astype(np.int8), 0]))
        ipts = np.round(np.nan_to_num(pts)).astype(np.int32)
        lines = [ipts[a:b + 1] for a, b in zip(edges[::2], edges[1::2])]
        if lines:
            cv2.polylines(img, lines, False, colour, lw, cv2.LINE_AA)
        for i in np.flatnonzero(good & ~obs)[::2]:  # predicted part: dotted
            cv2.circle(img, (int(ipts[i, 0]), int(ipts[i, 1])), lw, colour, -1, cv2.LINE_AA)

    def _draw_offscreen(self, img, cx, cy, colour, lw, keep_out=None) -> tuple[float, float, float]:
        """Arrow on the image border towards a predicted position outside the image; returns the
        label anchor (x, top, bottom)."""
        h, w = img.shape[:2]
        m = int(0.04 * h)
        ex, ey = min(max(cx, m), w - 1 - m), min(max(cy, m), h - 1 - m)
        if keep_out is not None and ex < keep_out[0] + m and ey < keep_out[1] + m:
            # below or beside the HUD, on the same border
            if cy < 0:
                ex = keep_out[0] + m
            else:
                ey = keep_out[1] + m
        d = np.array([cx - ex, cy - ey])
        n = np.hypot(*d)
        d = d / n if n > 1e-6 and np.isfinite(n) else np.array([0.0, -1.0])
        tip = np.array([ex, ey]) + d * m * 0.9
        tail = np.array([ex, ey]) - d * m * 0.6
        cv2.arrowedLine(img, _pt(*tail), _pt(*tip), colour, max(2, lw), cv2.LINE_AA, tipLength=0.45)
        return tail[0] - m * 0.5, tail[1] - m * 0.3, tail[1] + m * 0.3

    def _hud_text(self, frame, rows) -> str:
        n_obs = sum(r.observed for r in rows)
        return f"frame {frame}  t={(frame - 1) / self.fps:.2f}s  in view {n_obs}  predicted {len(rows) - n_obs}"

    def _hud_box(self, frame, rows, scale, thick) -> tuple[int, int]:
        """(right, bottom) pixel of the HUD panel."""
        (tw, th), base = cv2.getTextSize(self._hud_text(frame, rows), FONT, scale * 0.9, thick)
        pad = int(th * 0.4)
        return pad + tw + 2 * pad, pad + th + base + 2 * pad

    def _draw_hud(self, img, frame, rows, scale, thick) -> None:
        text = self._hud_text(frame, rows)
        s = scale * 0.9
        (tw, th), base = cv2.getTextSize(text, FONT, s, thick)
        pad = int(th * 0.4)
        x0, y0 = pad, pad
        roi = img[y0:y0 + th + base + 2 * pad, x0:x0 + tw + 2 * pad]
        roi[:] = (roi * 0.35).astype(np.uint8)
        cv2.putText(img, text, (x0 + pad, y0 + pad + th), FONT, s, (255, 255, 255), thick, cv2.LINE_AA)


def _pt(x: float, y: float) -> tuple[int, int]:
    return (int(round(x)), int(round(y)))


class _Rects(list):
    """A list of rectangles (x0, y0, x1, y1) that also keeps them as an array, for
    :func:`_label`'s overlap test without converting the list on every call."""

    def __init__(self, rects=()) -> None:
        super().__init__()
        self.arr = np.zeros((0, 4), np.int64)
        self._n = 0
        for r in rects:
            self.append(r)

    def append(self, r) -> None:
        super().append(r)
        if self._n == len(self.arr):
            self.arr = np.vstack([self.arr, np.zeros((max(8, self._n), 4), np.int64)])
        self.arr[self._n] = r
        self._n += 1

    def view(self) -> np.ndarray:
        return self.arr[:self._n]


def _overlap(rect, q) -> int:
    ix = min(rect[2], q[2]) - max(rect[0], q[0])
    iy = min(rect[3], q[3]) - max(rect[1], q[1])
    return ix * iy if ix > 0 and iy > 0 else 0


def _label(img, text, x, top, bottom, colour, scale, thick, hollow=False, placed=None,
           optional=False, right=None, avoid=(), rect=None):
    """A filled (or outlined, for predicted targets) label at a corner of the box: above it at its
    left edge, else below it, else at its right edge (``right``, the box's right x) above or
    below, whichever first covers at most a quarter of its area with a label drawn so far
    (``placed``) or a box in ``avoid``; the first of them when none does. At the top edge of the
    frame "above" is below. Dense traffic put every label above-left and they hid each other and
    the vehicles next to them (a probe, Santiago at 1080p).

    An ``optional`` label (a predicted target's) with no free place is skipped. ``rect`` draws at
    a place chosen before. Returns the rectangle drawn, or None.
    """
    h, w = img.shape[:2]
    (tw, th), base = cv2.getTextSize(text, FONT, scale, thick)
    pad = max(1, int(th * 0.25))
    bh, bw = th + base + 2 * pad, tw + 2 * pad
    if rect is None:
        cands = []
        for left in ([x] if right is None else [x, right - bw]):
            for y0 in (top - bh if top - bh >= 0 else bottom, bottom if top - bh >= 0 else top - bh):
                y0 = int(min(max(y0, 0), h - bh))
                x0 = int(min(max(left, 0), max(0, w - bw)))
                cands.append((x0, y0, x0 + bw, y0 + bh))
        rect = None
        as_arr = [r.view() if isinstance(r, _Rects) else np.asarray(r, np.int64).reshape(-1, 4)
                  for r in (placed if placed is not None else [], avoid)]
        others = np.vstack(as_arr)
        for c in cands:  # (vectorised: one pair at a time cost 57 ms a frame with 200 targets)
            ix = np.minimum(c[2], others[:, 2]) - np.maximum(c[0], others[:, 0])
            iy = np.minimum(c[3], others[:, 3]) - np.maximum(c[1], others[:, 1])
            if not np.any((ix > 0) & (iy > 0) & (ix * iy > 0.25 * bw * bh)):
                rect = c
                break
        if rect is None:
            if optional and placed is not None:
                return None
            rect = cands[0]
        if placed is not None:
            placed.append(rect)
    x0, y0 = rect[0], rect[1]
    if hollow:
        roi = img[y0:y0 + bh, x0:x0 + bw]
        roi[:] = (roi * 0.3).astype(np.uint8)
        cv2.rectangle(img, (x0, y0), (x0 + bw, y0 + bh), colour, max(1, thick // 2))
        fg = _lifted(colour)
    else:
        cv2.rectangle(img, (x0, y0), (x0 + bw, y0 + bh), colour, -1)
        fg = text_colour_on(colour)
    cv2.putText(img, text, (x0 + pad, y0 + pad + th), FONT, scale, fg, thick, cv2.LINE_AA)
    return rect


def _lifted(bgr, luma_min: float = 150.0) -> tuple[int, int, int]:
    """``bgr`` mixed with white until its luma is at least ``luma_min``: the text of a predicted
    target's label, drawn in its colour on a darkened patch (navy and blue IDs vanished there)."""
    b, g, r = (float(c) for c in bgr)
    luma = 0.299 * r + 0.587 * g + 0.114 * b
    if luma >= luma_min:
        return int(b), int(g), int(r)
    t = (luma_min - luma) / (255.0 - luma)
    return tuple(int(round(c + t * (255.0 - c))) for c in (b, g, r))


def _dashed_line(img, p, q, colour, lw, dash) -> None:
    p, q = np.asarray(p, float), np.asarray(q, float)
    n = np.hypot(*(q - p))
    if n < 1:
        return
    steps = max(1, int(n // dash))
    for k in range(0, steps, 2):
        a = p + (q - p) * (k / steps)
        b = p + (q - p) * (min(k + 1, steps) / steps)
        cv2.line(img, _pt(*a), _pt(*b), colour, lw, cv2.LINE_AA)


def _dashed_rect(img, x, y, bw, bh, colour, lw) -> None:
    dash = max(3.0, 3.0 * lw)
    c = [(x, y), (x + bw, y), (x + bw, y + bh), (x, y + bh)]
    for i in range(4):
        _dashed_line(img, c[i], c[(i + 1) % 4], colour, lw, dash)


def _dashed_circle(img, cx, cy, r, colour, lw) -> None:
    n = int(min(72, max(12, 2 * math.pi * r / 8)))
    n -= n % 2
    step = 360.0 / n
    for k in range(0, n, 2):
        cv2.ellipse(img, _pt(cx, cy), (int(round(r)), int(round(r))), 0, k * step, (k + 1) * step,
                    colour, lw, cv2.LINE_AA)


def render_overlay(input_path: str | Path, results: RunResults | str | Path, out_path: str | Path, *,
                   style: OverlayStyle = OverlayStyle(), fps: float | None = None,
                   start: int = 1, stop: int | None = None, progress=None) -> Path:
    """Write the overlay video of a run.

    Parameters
    ----------
    input_path : path
        The run's input (video file or image folder; frame n = n-th frame).
    results : RunResults or path
        The run (an output folder).
    out_path : path
        ``.webm`` (VP9) or ``.mp4`` (H.264).
    style : OverlayStyle
    fps : float, optional
        Frame rate of the written video (default: the run's).
    start, stop : int
        1-based frame range, inclusive.
    progress : callable, optional
        Called with the number of frames written so far.

    Returns
    -------
    Path of the written video.
    """
    from ..io.frames import open_source

    if not isinstance(results, RunResults):
        results = RunResults.load(results)
    source = open_source(input_path, results.fps)
    painter = OverlayPainter(results, style)
    w, h = source.size
    if style.max_width and w > style.max_width:
        out_size = (int(style.max_width), int(round(h * style.max_width / w)))
    else:
        out_size = (w, h)
    with VideoEncoder(out_path, out_size, fps or results.fps) as enc:
        for frame in source.frames(start=start, stop=stop):
            enc.write(painter.draw(frame.image, frame.index, copy=False))
            if progress is not None:
                progress(enc.frames_written)
    return Path(out_path)

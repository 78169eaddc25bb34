"""Screen-line counts and turning movements from finished tracks.

What a traffic study wants from a tracker: how many vehicles crossed a line (a stop line, a cross-
section of a road, an approach of a junction), in which direction and when; and at a junction,
which approach each vehicle came in by and which it left by (turning movements, the origin-
destination matrix of the junction).

Coordinates
-----------
Everything here works in a run's *world* frame (:meth:`aerotrack.viz.results.RunResults.track_views`):
map pixels with a map, the run's first frame's pixels without. Both have y down, so the sides of a
line are as seen on the screen: walking along a line from its first point to its second, ``+`` is a
crossing from the left side to the right, ``-`` from right to left.

Crossing rule
-------------
A box centre jitters by a pixel or two from frame to frame, and a vehicle waiting on a stop line
would otherwise cross it back and forth. A track's side of a line therefore changes only when the
track is at least ``band`` (world units) beyond it: a crossing is counted when a track that was
definitely on one side is next definitely on the other, at the point where its path crosses the
line, and only when that point lies on the line's segment (within ``band`` of its ends). The
path runs through the track's in-view rows and through its predicted rows *between* two in-view
rows (a vehicle that crossed under a bridge or a tree is counted, marked ``observed = False``);
predictions after a track's last in-view row are guesses and never count.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

__all__ = ["CountLine", "Crossing", "Movement", "CountComparison", "parse_line", "read_count_lines",
           "track_crossings", "count_crossings", "movements", "tally", "movement_matrix",
           "compare_counts", "line_in_view", "in_view_per_bin", "speed_window_frames",
           "SPEED_WINDOW_S"]


@dataclass(frozen=True)
class CountLine:
    """A straight count line (screen-line) from ``a`` to ``b``, world coordinates.

    Attributes
    ----------
    name : str
    a, b : ndarray, shape (2,)
        End points, world (map pixels with a map, the first frame's pixels without).
    """

    name: str
    a: np.ndarray
    b: np.ndarray

    def __post_init__(self):
        a = np.asarray(self.a, dtype=np.float64).reshape(2)
        b = np.asarray(self.b, dtype=np.float64).reshape(2)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise InputError(f"count line {self.name!r}: end points must be finite numbers")
        if float(np.hypot(*(b - a))) == 0.0:
            raise InputError(f"count line {self.name!r}: its two end points are the same point")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.b - self.a)))

    def side(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (world units; > 0 right of a -> b as seen on the screen, y down) and
        position along the segment (0 at ``a``, 1 at ``b``) of points (N, 2)."""
        d = self.b - self.a
        q = np.asarray(pts, dtype=np.float64).reshape(-1, 2) - self.a
        n = self.length
        return (d[0] * q[:, 1] - d[1] * q[:, 0]) / n, (q @ d) / (n * n)


@dataclass(frozen=True)
class Crossing:
    """One track crossing one line.

    Attributes
    ----------
    line : str
    direction : str
        ``+`` (left to right of the line as drawn, seen on the screen) or ``-``.
    id : int
        Track ID.
    frame : float
        When the path met the line, interpolated between the two rows around it (1-based frames).
    world : ndarray, shape (2,)
        Where, world coordinates.
    observed : bool
        Both rows around the crossing were in view (False: it happened in a predicted stretch
        between two sightings, e.g. under a bridge).
    velocity : ndarray, shape (2,)
        World units per frame at the crossing: the straight line from the track's position
        ``SPEED_WINDOW_S`` seconds before it to the one as long after (the nearest rows inside
        the track), which averages out box jitter (NaN when the track has no row on one side).
    """

    line: str
    direction: str
    id: int
    frame: float
    world: np.ndarray = field(repr=False)
    observed: bool = True
    velocity: np.ndarray = field(default_factory=lambda: np.full(2, np.nan), repr=False)


#: Half-width, seconds, of the window a crossing's velocity is measured over.
SPEED_WINDOW_S = 0.25


def speed_window_frames(fps: float | None) -> int:
    """``SPEED_WINDOW_S`` in frames at ``fps`` (at least 1; 8 when the rate is unknown)."""
    if not fps or not math.isfinite(fps) or fps <= 0:
        return 8
    return max(1, int(round(SPEED_WINDOW_S * fps)))


@dataclass(frozen=True)
class Movement:
    """A track's way through the lines: the first line it crossed and the last.

    ``to_line`` is empty for a track that crossed lines only once (it entered, or left, the counted
    area inside the view; or a line was missing)."""

    id: int
    from_line: str
    from_direction: str
    from_frame: float
    to_line: str
    to_direction: str
    to_frame: float


def parse_line(text: str, option: str = "--line") -> tuple[str, np.ndarray]:
    """``NAME:x1,y1,x2,y2`` -> (name, (2, 2) points). Raises :class:`InputError` naming the
    option."""
    name, sep, rest = str(text).rpartition(":")
    if not sep or not name.strip():
        raise InputError(f"{option} {text!r}: expected NAME:x1,y1,x2,y2 (a name, a colon, then "
                         "the two end points)")
    try:
        vals = [float(v) for v in rest.split(",")]
    except ValueError:
        raise InputError(f"{option} {text!r}: the end points must be four numbers "
                         "x1,y1,x2,y2") from None
    if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"{option} {text!r}: the end points must be four finite numbers "
                         f"x1,y1,x2,y2 (got {len(vals)})")
    pts = np.array(vals, dtype=np.float64).reshape(2, 2)
    if float(np.hypot(*(pts[1] - pts[0]))) == 0.0:
        raise InputError(f"{option} {text!r}: its two end points are the same point")
    return name.strip(), pts


def read_count_lines(path, geomap, option: str = "--lines") -> list[tuple[str, np.ndarray]]:
    """Count lines from a GeoJSON file: ``(name, (2, 2) map pixels)`` per LineString.

    Coordinates are lon/lat (RFC 7946) or in the CRS of the file's legacy ``crs`` member; each
    line needs exactly two vertices (a straight screen-line; a MultiLineString of one part is
    taken as its part) and is named by its feature's ``name`` property (else ``id``, else
    ``line<k>``). Other geometries (points, polygons) are ignored with a warning. Needs the run's
    map (``geomap``).
    """
    import json
    from pathlib import Path

    from pyproj import CRS, Transformer

    from ..io.geojson import document_crs

    p = Path(path)
    label = f"{option} {p}"
    if not p.is_file():
        raise InputError(f"{label}: file not found")
    try:
        doc = json.loads(p.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{label}: cannot read as GeoJSON ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{label}: not a GeoJSON object")
    feats = (doc.get("features") or [] if doc.get("type") == "FeatureCollection"
             else [doc] if doc.get("type") == "Feature" else [{"geometry": doc}])
    src = document_crs(doc, label)
    dst = CRS.from_user_input(geomap.crs.to_wkt())
    move = Transformer.from_crs(src, dst, always_xy=True) if src != dst else None
    out = []
    skipped: dict[str, int] = {}
    for k, f in enumerate(feats, start=1):
        g = f.get("geometry") if isinstance(f, dict) else None
        kind = g.get("type") if isinstance(g, dict) else None
        props = f.get("properties") if isinstance(f, dict) and \
            isinstance(f.get("properties"), dict) else {}
        name = _feature_name(f if isinstance(f, dict) else {}, props, k)
        coords = g.get("coordinates") if isinstance(g, dict) else None
        if kind == "MultiLineString":
            parts = coords if isinstance(coords, list) else []
            if len(parts) != 1:
                raise InputError(f"{label}: line {name!r} is a MultiLineString of {len(parts)} "
                                 "parts; give each count line its own LineString feature")
            coords, kind = parts[0], "LineString"
        if kind != "LineString":
            skipped[str(kind)] = skipped.get(str(kind), 0) + 1
            continue
        try:
            a = np.asarray([c[:2] for c in coords or []], dtype=np.float64)
        except (TypeError, ValueError, IndexError):
            raise InputError(f"{label}: line {name!r} has malformed coordinates") from None
        if a.shape != (2, 2) or not np.all(np.isfinite(a)):
            raise InputError(f"{label}: line {name!r} has {len(a)} vertices; a count line is a "
                             "straight segment of exactly 2")
        if move is not None:
            a = np.column_stack(move.transform(a[:, 0], a[:, 1]))
        if not np.all(np.isfinite(a)):
            raise InputError(f"{label}: line {name!r} falls outside the map's CRS")
        out.append((name, geomap.crs_to_pixel(a)))
    if skipped and out:
        log.warning(
            "%s: %s not count lines, ignored", label,
            ", ".join(f"{n} {t} feature{'s' if n > 1 else ''}" for t, n in sorted(skipped.items())))
    if not out:
        raise InputError(f"{label}: no LineString count lines")
    return out


def _feature_name(feature: dict, props: dict, k: int) -> str:
    """A feature's ``name`` property, else its ``id`` (member or property), else ``line<k>``;
    empty and null values are skipped."""
    for v in (props.get("name"), feature.get("id"), props.get("id")):
        if v is not None and str(v).strip():
            return str(v).strip()
    return f"line{k}"


def track_crossings(frames: np.ndarray, world: np.ndarray, observed: np.ndarray,
                    line: CountLine, band: float, track_id: int = 0,
                    speed_window: int = 8) -> list[Crossing]:
    """Every crossing of ``line`` by one track (see the module docstring for the rule).

    Parameters
    ----------
    frames : ndarray, shape (N,)
        Increasing frame numbers.
    world : ndarray, shape (N, 2)
        World positions (NaN rows are skipped).
    observed : ndarray, shape (N,), bool
        In view (``tracks.csv``) or predicted.
    band : float
        World units a track must be beyond the line to be on one side of it. Raising it ignores
        more jitter about the line but misses vehicles that cross its very end.
    speed_window : int
        Half-width, frames, of the velocity window (:func:`speed_window_frames`).
    """
    frames = np.asarray(frames, dtype=np.float64)
    world = np.asarray(world, dtype=np.float64).reshape(-1, 2)
    observed = np.asarray(observed, dtype=bool)
    seen = np.flatnonzero(observed)
    if len(seen) < 2:
        return []
    keep = np.zeros(len(frames), bool)
    keep[seen[0]:seen[-1] + 1] = True  # predictions before the first and after the last sighting
    keep &= np.all(np.isfinite(world), axis=1)  # are guesses
    idx = np.flatnonzero(keep)
    if len(idx) < 2:
        return []
    f, p, ob = frames[idx], world[idx], observed[idx]
    s, t = line.side(p)
    band = max(float(band), 0.0)
    definite = np.where(s >= band, 1, np.where(s <= -band, -1, 0))
    if band == 0.0:
        definite = np.where(s > 0, 1, np.where(s < 0, -1, 0))
    slack = band / line.length
    out: list[Crossing] = []
    nz = np.flatnonzero(definite)
    flips = np.flatnonzero(definite[nz][1:] != definite[nz][:-1])
    for last, k in zip(nz[flips].tolist(), nz[flips + 1].tolist()):
        side = int(definite[k])
        # the sign change between the last definite point and this one closest to this one
        m = np.arange(last, k)
        change = m[(s[m] * s[m + 1] <= 0) & (s[m] != s[m + 1])]
        j = int(change[-1]) if len(change) else last
        u = s[j] / (s[j] - s[j + 1]) if s[j] != s[j + 1] else 0.0
        tt = t[j] + u * (t[j + 1] - t[j])
        if -slack <= tt <= 1.0 + slack:
            at = float(f[j] + u * (f[j + 1] - f[j]))
            lo = int(np.searchsorted(f, at - speed_window, side="left"))
            hi = int(np.searchsorted(f, at + speed_window, side="right")) - 1
            lo, hi = min(lo, j), max(hi, j + 1)
            vel = (p[hi] - p[lo]) / (f[hi] - f[lo]) if f[hi] > f[lo] else np.full(2, np.nan)
            out.append(Crossing(line.name, "+" if side > 0 else "-", int(track_id), at,
                                p[j] + u * (p[j + 1] - p[j]), bool(ob[j] and ob[j + 1]),
                                vel))
    return out


def count_crossings(tracks: Iterable, lines: Sequence[CountLine], band: float,
                    fps: float | None = None) -> list[Crossing]:
    """Crossings of every line by every track, sorted by frame, then line and ID.

    ``tracks`` yields objects with ``id``, ``frames``, ``world`` and ``observed`` (as
    :class:`aerotrack.viz.results.TrackView`); ``fps`` sets the speed window
    (:data:`SPEED_WINDOW_S`)."""
    out = []
    window = speed_window_frames(fps)
    for tr in tracks:
        for line in lines:
            out.extend(track_crossings(tr.frames, tr.world, tr.observed, line, band, tr.id,
                                       window))
    out.sort(key=lambda c: (c.frame, c.line, c.id))
    return out


def movements(crossings: Iterable[Crossing]) -> list[Movement]:
    """Each track's first and last crossing, sorted by ID (a track that crossed once gets an
    empty ``to_line``)."""
    by_id: dict[int, list[Crossing]] = {}
    for c in crossings:
        by_id.setdefault(c.id, []).append(c)
    out = []
    for tid in sorted(by_id):
        cs = sorted(by_id[tid], key=lambda c: c.frame)
        first, lastc = cs[0], cs[-1]
        if len(cs) == 1:
            out.append(Movement(tid, first.line, first.direction, first.frame, "", "", math.nan))
        else:
            out.append(Movement(tid, first.line, first.direction, first.frame, lastc.line,
                                lastc.direction, lastc.frame))
    return out


def movement_matrix(moves: Iterable[Movement]) -> dict[tuple[str, str], int]:
    """Origin-destination counts {(from line, to line): tracks} over tracks that crossed two or
    more times."""
    out: dict[tuple[str, str], int] = {}
    for m in moves:
        if m.to_line:
            out[(m.from_line, m.to_line)] = out.get((m.from_line, m.to_line), 0) + 1
    return out


def _bins(fps: float, first_frame: int, last_frame: int, bin_s: float | None
          ) -> tuple[float, float, float, int]:
    """(start s, run length s, bin width s, number of bins) of :func:`tally`'s bins."""
    t0 = (first_frame - 1) / fps
    span = (last_frame - first_frame + 1) / fps
    width = span if not bin_s or bin_s <= 0 else float(bin_s)
    return t0, span, width, max(1, int(math.ceil(span / width - 1e-9)))


def tally(crossings: Iterable[Crossing], lines: Sequence[CountLine], fps: float,
          first_frame: int, last_frame: int, bin_s: float | None = None
          ) -> list[tuple[str, str, float, float, int]]:
    """Counts per line, direction and time bin: rows ``(line, direction, start_s, end_s, count)``
    with times in seconds since frame 1 (bins start at ``first_frame``), every (line, direction,
    bin) present, zeros too. ``bin_s`` None or 0: one bin over the whole run."""
    t0, span, width, nbins = _bins(fps, first_frame, last_frame, bin_s)
    counts: dict[tuple[str, str, int], int] = {}
    for c in crossings:
        b = min(nbins - 1, max(0, int(((c.frame - first_frame) / fps) // width)))
        counts[(c.line, c.direction, b)] = counts.get((c.line, c.direction, b), 0) + 1
    rows = []
    for line in lines:
        for d in ("+", "-"):
            for b in range(nbins):
                rows.append((line.name, d, t0 + b * width, t0 + min(span, (b + 1) * width),
                             counts.get((line.name, d, b), 0)))
    return rows


def line_in_view(line: CountLine, frame_to_world: np.ndarray, frame_size: tuple[int, int],
                 samples: int = 33) -> np.ndarray:
    """Share of ``line``'s length inside each frame: (N,) in [0, 1].

    A zero count means something only while the camera saw the line: a moving camera that looked
    away from it, or left it at the edge of the view, counted nothing there whatever drove by.

    Parameters
    ----------
    frame_to_world : ndarray, shape (N, 3, 3)
        Each frame's pixels -> world (``registration.csv``).
    frame_size : (int, int)
        Width and height of the frames, pixels.
    samples : int
        Points along the line tested (the share is the fraction inside).
    """
    hs = np.asarray(frame_to_world, dtype=np.float64).reshape(-1, 3, 3)
    if not len(hs):
        return np.zeros(0)
    u = np.linspace(0.0, 1.0, samples)
    pts = line.a[None, :] + u[:, None] * (line.b - line.a)[None, :]
    ph = np.column_stack([pts, np.ones(samples)])
    out = np.zeros(len(hs))
    w, h = float(frame_size[0]), float(frame_size[1])
    for i, H in enumerate(hs):
        try:
            q = ph @ np.linalg.inv(H).T
        except np.linalg.LinAlgError:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
        ok = (q[:, 2] > 0) & (x >= 0) & (x <= w) & (y >= 0) & (y <= h)
        out[i] = float(np.mean(ok))
    return out


def in_view_per_bin(frames: np.ndarray, share: np.ndarray, fps: float, first_frame: int,
                    last_frame: int, bin_s: float | None = None) -> list[float]:
    """Mean of :func:`line_in_view` over each of :func:`tally`'s bins (frames without a row,
    e.g. not registered, count as not seen; frames between rows of a ``--stride`` run take the
    row before)."""
    _, _, width, nbins = _bins(fps, first_frame, last_frame, bin_s)
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    share = np.asarray(share, dtype=np.float64).reshape(-1)
    order = np.argsort(frames, kind="stable")
    frames, share = frames[order], share[order]
    allf = np.arange(first_frame, last_frame + 1, dtype=np.float64)
    pos = np.searchsorted(frames, allf, side="right") - 1
    vals = np.where(pos >= 0, share[np.maximum(pos, 0)], 0.0)
    if len(frames):
        step = np.median(np.diff(frames)) if len(frames) > 1 else 1.0
        vals[allf > frames[-1] + step - 1] = 0.0  # after the last registered frame
        gaps = allf - frames[np.maximum(pos, 0)] >= max(step, 1.0)
        vals[gaps] = 0.0  # a frame the registration skipped (failed)
    else:
        vals[:] = 0.0
    b = np.minimum(nbins - 1, ((allf - first_frame) / fps // width).astype(int))
    out = []
    for k in range(nbins):
        sel = b == k
        out.append(float(vals[sel].mean()) if sel.any() else math.nan)
    return out


@dataclass(frozen=True)
class CountComparison:
    """Counts against a ground truth counted the same way.

    Attributes
    ----------
    per_line : list of (line, direction, true, measured, matched)
        ``matched``: crossings paired one to one with a true crossing of the same line and
        direction within the tolerance.
    count_error : float
        ``sum |measured - true| / sum true`` over lines and directions (NaN without true
        crossings): the error of the totals a study would report.
    precision, recall : float
        Of crossing events (matched / measured, matched / true).
    movement_error : float
        ``sum |OD measured - OD true| / sum OD true`` over the cells of the origin-destination
        matrix (NaN when no true vehicle crossed two lines).
    movements_true, movements_measured : int
        Vehicles (tracks) with a movement (two or more crossings).
    """

    per_line: list[tuple[str, str, int, int, int]]
    count_error: float
    precision: float
    recall: float
    movement_error: float
    movements_true: int
    movements_measured: int


def compare_counts(measured: Sequence[Crossing], truth: Sequence[Crossing],
                   lines: Sequence[CountLine], tolerance_frames: float) -> CountComparison:
    """Score measured crossings against true ones (both from :func:`count_crossings`): per line
    and direction, crossings are paired one to one (Hungarian algorithm on the time difference)
    when within ``tolerance_frames`` of each other."""
    from scipy.optimize import linear_sum_assignment

    per_line = []
    tot_t = tot_m = tot_match = 0
    abs_err = 0
    for line in lines:
        for d in ("+", "-"):
            tm = np.array([c.frame for c in measured if c.line == line.name and c.direction == d])
            tt = np.array([c.frame for c in truth if c.line == line.name and c.direction == d])
            matched = 0
            if len(tm) and len(tt):
                cost = np.abs(tm[:, None] - tt[None, :])
                big = tolerance_frames + 1.0
                r, c = linear_sum_assignment(np.where(cost <= tolerance_frames, cost, big * 10))
                matched = int(np.sum(cost[r, c] <= tolerance_frames))
            per_line.append((line.name, d, len(tt), len(tm), matched))
            tot_t += len(tt)
            tot_m += len(tm)
            tot_match += matched
            abs_err += abs(len(tm) - len(tt))
    od_t = movement_matrix(movements(truth))
    od_m = movement_matrix(movements(measured))
    n_t, n_m = sum(od_t.values()), sum(od_m.values())
    od_err = sum(abs(od_m.get(k, 0) - od_t.get(k, 0)) for k in set(od_t) | set(od_m))
    nan = float("nan")
    return CountComparison(per_line, abs_err / tot_t if tot_t else nan,
                           tot_match / tot_m if tot_m else nan,
                           tot_match / tot_t if tot_t else nan,
                           od_err / n_t if n_t else nan, n_t, n_m)

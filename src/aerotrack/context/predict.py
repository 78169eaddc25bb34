"""``aerotrack predict``: motion-context prediction for queries on any tracks file.

``Q.csv`` has a header ``id,last_seen,horizon``; the answer has a header ``query,id,frame,x,y``
with exactly ``horizon`` rows per query (frames ``last_seen+1 .. last_seen+horizon``), x, y the
predicted box centre in the coordinates of the tracks' box columns (``space="image"``) or of their
x, y map columns (``space="map"``). The prediction at frame f uses only the target's rows up to
``last_seen`` and the other tracks' rows up to f (see :mod:`aerotrack.context.motion`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import ContextConfig
from ..errors import FormatError, InputError
from ..io.mot import read_mot
from ..io.output import atomic_write_text
from .motion import TrackTable, get_predictor

log = logging.getLogger(__name__)

__all__ = ["Query", "read_queries", "tracks_table", "scale_of", "predict_queries", "format_predictions",
           "run_predict", "score_predictions"]

QUERY_HEADER = ("id", "last_seen", "horizon")
OUTPUT_HEADER = "query,id,frame,x,y"


@dataclass(frozen=True)
class Query:
    id: int
    last_seen: int
    horizon: int
    line: int = field(default=0, compare=False)  # line of the queries file (1-based), for messages


#: Longest prediction horizon in frames (over 9 hours at 30 frames/s).
MAX_HORIZON = 1_000_000


def read_queries(path: str | Path) -> list[Query]:
    """Read ``Q.csv`` (header ``id,last_seen,horizon``, one query per row).

    Raises
    ------
    InputError, FormatError
        Missing file, bad header, a non-integer value or a horizon <= 0 (the message names the line).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"--queries {p}: file not found")
    try:
        lines = p.read_text(encoding="utf-8-sig").splitlines()  # a BOM, as Excel writes
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"--queries {p}: cannot read ({exc})") from None
    rows = [(n, ln) for n, ln in enumerate(lines, start=1)
            if ln.strip() and not ln.lstrip().startswith("#")]  # comments, as in MOT files
    if not rows:
        raise FormatError(f"--queries {p}: empty, expected a header id,last_seen,horizon")
    header = tuple(c.strip().lower() for c in rows[0][1].split(","))
    if header != QUERY_HEADER:
        raise FormatError(f"--queries {p} line {rows[0][0]}: expected the header id,last_seen,horizon, "
                          f"found {rows[0][1].strip()!r}")
    out = []
    for n, ln in rows[1:]:
        parts = [c.strip() for c in ln.split(",")]
        if len(parts) != 3:
            raise FormatError(f"--queries {p} line {n}: expected 3 values, found {len(parts)}")
        try:
            vals = [float(v) for v in parts]
        except ValueError:
            raise FormatError(f"--queries {p} line {n}: non-numeric value in {ln.strip()!r}") from None
        if not all(math.isfinite(v) and v.is_integer() for v in vals):
            raise FormatError(f"--queries {p} line {n}: id, last_seen and horizon must be integers")
        q = Query(*(int(v) for v in vals), line=n)
        if q.horizon <= 0:
            raise FormatError(f"--queries {p} line {n}: horizon must be positive, got {q.horizon}")
        if q.horizon > MAX_HORIZON:  # one output row per frame: this would exhaust memory
            raise FormatError(f"--queries {p} line {n}: horizon {q.horizon} is more than "
                              f"{MAX_HORIZON} frames (hours of video)")
        out.append(q)
    return out


def tracks_table(rows: np.ndarray, space: str = "image", name: str = "TRACKS") -> TrackTable:
    """A :class:`TrackTable` from (N, 10) MOT rows: box centres (``image``) or x, y (``map``)."""
    if space not in ("image", "map"):
        raise InputError(f"--space: expected image or map, got {space!r}")
    if space == "image":
        xy = rows[:, 2:4] + rows[:, 4:6] / 2.0
    else:
        xy = rows[:, 7:9]
        if len(rows) and np.all(xy == -1):
            raise InputError(f"{name}: --space map needs the x,y map columns, but they are all -1")
        placed = ~np.all(xy == -1, axis=1)  # -1, -1: no map position in this row (MOT's blank)
        if not placed.all():
            log.info("%s: %d rows without a map position (x, y = -1) left out", name,
                     int((~placed).sum()))
            rows, xy = rows[placed], xy[placed]
        distinct = len(np.unique(xy, axis=0))
        if distinct <= 10 and len(np.unique(rows[:, 1])) > distinct:
            log.warning("%s: the x,y map columns hold %d distinct values over %d tracks: are they "
                        "positions? (UAVDT's *_gt_whole.txt keeps occlusion and category there; "
                        "--space image predicts the boxes)", name, distinct,
                        len(np.unique(rows[:, 1])))
    return TrackTable.from_arrays(rows[:, 1], rows[:, 0], xy)


#: Metres in a degree of latitude (and of longitude at the equator).
METRES_PER_DEGREE = 111_320.0


def _looks_geographic(rows: np.ndarray) -> bool:
    """x, y map columns within +-180 / +-90 spanning under a degree: lon/lat (see
    :func:`scale_of`)."""
    xy = rows[:, 7:9]
    xy = xy[~np.all(xy == -1, axis=1)]
    return bool(len(xy) and np.all(np.abs(xy[:, 0]) <= 180) and np.all(np.abs(xy[:, 1]) <= 90)
                and np.ptp(xy, axis=0).max() < 1.0)


def scale_of(rows: np.ndarray, space: str, config: ContextConfig) -> float:
    """Metres per coordinate unit when none is given.

    ``map``: coordinates within +-180 / +-90 spanning under a degree are taken as lon/lat degrees
    (metres from the local radius of the Earth), anything else as metres (projected CRS).
    ``image``: the median box's longer side is taken to be ``config.image_object_size_m`` metres,
    a guess that keeps the metre-based settings in proportion to the objects.
    """
    if space == "map":
        if _looks_geographic(rows):
            xy = rows[:, 7:9]
            lat = float(np.median(xy[~np.all(xy == -1, axis=1), 1]))
            return METRES_PER_DEGREE * math.cos(math.radians(lat))
        return 1.0
    side = np.maximum(rows[:, 4], rows[:, 5])
    side = side[side > 0]
    if len(side) == 0:
        return 1.0
    return config.image_object_size_m / float(np.median(side))


def predict_queries(table: TrackTable, queries: list[Query], method: str, config: ContextConfig,
                    fps: float, metres_per_unit: float | None, roads=None,
                    label: str = "--queries", unplaced: np.ndarray | None = None
                    ) -> list[np.ndarray]:
    """One (horizon, 2) array of predicted positions per query, in the table's units (``roads``:
    a :class:`~aerotrack.context.roads.RoadNetwork` in the same units, used by ``context``).
    ``label`` starts error messages (``--queries FILE``).

    Raises
    ------
    InputError
        A query names an unknown id, or a ``last_seen`` that is not one of the track's frames.
    """
    pred = get_predictor(method, config, fps, metres_per_unit, roads=roads)
    known = set(table.track_ids().tolist())
    # (id, frame) of rows left out for having no map position (x, y = -1; --space map)
    blank = set() if unplaced is None else {(int(i), int(f)) for f, i in unplaced[:, :2]}
    out = []
    for n, q in enumerate(queries):
        where = f"{label} line {q.line or n + 2} (query {n})"
        if (q.id, q.last_seen) in blank:
            fr = table.track(q.id)[0] if q.id in known else np.zeros(0)
            before = fr[fr < q.last_seen]
            last = f" (its last one before is at frame {int(before.max())})" if len(before) else ""
            raise InputError(f"{where}: track {q.id} has no map position (x, y = -1) at "
                             f"last_seen {q.last_seen}{last}")
        if q.id not in known:
            raise InputError(f"{where}: unknown id {q.id}")
        fr, _ = table.track(q.id)
        if not np.any(fr == q.last_seen):
            raise InputError(f"{where}: track {q.id} has no row at last_seen {q.last_seen}")
        out.append(pred.predict(table, q.id, q.last_seen, q.horizon))
    if getattr(pred, "fallbacks", 0):
        log.warning("--method %s: %d of %d queries had fewer than %d predictors with a Lyapunov "
                    "exponent under lce_alpha (%g) and were predicted by the Kalman filter", method,
                    pred.fallbacks, len(queries), config.min_predictors, config.lce_alpha)
    return out


def format_predictions(queries: list[Query], preds: list[np.ndarray], decimals: int = 6) -> str:
    """The output CSV; ``decimals`` 7 for map coordinates (lon/lat to about 1 cm, as tracks.csv)."""
    lines = [OUTPUT_HEADER]
    d = int(decimals)
    for n, (q, p) in enumerate(zip(queries, preds)):
        for k in range(q.horizon):
            lines.append(f"{n},{q.id},{q.last_seen + k + 1},{p[k, 0]:.{d}f},{p[k, 1]:.{d}f}")
    return "\n".join(lines) + "\n"


def frame_step(rows: np.ndarray) -> int:
    """The step of tracks whose rows come every ``step`` > 1 frames (ETH/UCY annotate every 6th
    or 10th frame), else 1: the greatest common divisor of the tracks' frame differences, when
    it is also their most common difference, at least half of them, and tracks have three rows
    or more (a median): two sightings 199 frames apart are a gap, not a rate. The tracks need
    not share one grid (ETH's shift between recordings)."""
    if len(rows) < 2:
        return 1
    order = np.lexsort((rows[:, 0], rows[:, 1]))
    f, i = rows[order, 0].astype(np.int64), rows[order, 1]
    d = np.diff(f)[np.diff(i) == 0]
    d = d[d > 0]
    if not len(d) or np.median(np.unique(i, return_counts=True)[1]) < 3:
        return 1
    step = int(np.gcd.reduce(d))
    values, counts = np.unique(d, return_counts=True)
    if step <= 1 or values[np.argmax(counts)] != step or counts.max() < 0.5 * len(d):
        return 1
    return step


def _on_grid(rows: np.ndarray, queries: list[Query], step: int, offset: int
             ) -> tuple[np.ndarray, list[Query]]:
    """Rows and queries on the grid of frames ``offset + k * step`` (numbered ``k + 1``): a row
    between two grid frames goes to the later one, so that the prediction at a grid frame still
    uses no row after it (tracks on another grid keep their causality); a query's horizon is
    rounded up to whole steps."""
    g = rows.copy()
    g[:, 0] = -((offset - rows[:, 0]) // step) + 1  # ceil((f - offset) / step) + 1
    qs = [Query(q.id, (q.last_seen - offset) // step + 1, -(-q.horizon // step), q.line)
          for q in queries]
    return g, qs


def _between_steps(grid_pred: np.ndarray, last: np.ndarray, before: np.ndarray, step: int,
                   horizon: int) -> np.ndarray:
    """(horizon, 2) positions at every frame from the positions at the grid's frames: a frame
    between two grid frames goes on from the grid frame before it at the velocity of the step
    that ended there (the one before the first predicted grid frame is the target's own last
    step, ``before`` -> ``last``), so that the position at frame f still uses nothing after f."""
    anchors = np.vstack([before[None], last[None], grid_pred])  # grid frames -1, 0, 1, ...
    j = np.arange(1, horizon + 1)
    k, r = j // step, j % step  # grid frames passed, frames since the last one
    base = anchors[k + 1]
    vel = (anchors[k + 1] - anchors[k]) / step
    return base + r[:, None] * vel


def _first_row_fields(path: str | Path) -> int:
    """Number of fields of the first data row of a text file (0 when unreadable or empty)."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                t = line.strip()
                if not t or t.startswith("#"):
                    continue
                fields = [f for f in t.replace(",", " ").replace("\t", " ").split(" ") if f]
                try:
                    [float(f) for f in fields]
                except ValueError:
                    continue  # a header
                return len(fields)
    except OSError:
        return 0
    return 0


def read_positions(path: str | Path, zero_based: bool = False) -> np.ndarray:
    """A trajectories file of rows ``frame,id,x,y`` (positions, no boxes: ETH/UCY, SDD
    centres, a GIS export) as (N, 10) MOT rows whose box is 1 unit wide about ``x, y`` and
    whose map columns are ``x, y``: both ``--space`` values then predict the positions.

    Raises
    ------
    FormatError
        A row with another number of fields, a repeated (frame, id), a negative id.
    """
    from ..io.mot import _decode, parse_mot_text

    label = f"TRACKS {path}"
    try:
        data = parse_mot_text(_decode(Path(path).read_bytes(), label), label, min_columns=4,
                              zero_based=zero_based)
    except ValueError as exc:  # rows of different lengths
        if isinstance(exc, FormatError):
            raise
        data = np.zeros((0, 0))
    if data.ndim != 2 or data.shape[1] != 6 or len(data) == 0 or not np.all(data[:, 4:6] == -1):
        raise FormatError(f"{label}: every row must be frame,id,x,y (a positions file: its first "
                          "row has 4 fields), or every row a MOT row of 6 to 10")
    if np.any(data[:, 1] < 0) or not np.all(data[:, 1] == np.round(data[:, 1])):
        raise FormatError(f"{label}: ids must be non-negative integers")
    key = data[:, 0] * (data[:, 1].max() + 1) + data[:, 1]
    if len(np.unique(key)) != len(key):
        raise FormatError(f"{label}: a (frame, id) pair appears twice")
    x, y = data[:, 2], data[:, 3]
    rows = np.column_stack([data[:, 0], data[:, 1], x - 0.5, y - 0.5, np.ones(len(data)),
                            np.ones(len(data)), np.ones(len(data)), x, y, -np.ones(len(data))])
    return rows[np.lexsort((rows[:, 1], rows[:, 0]))]


def run_predict(tracks: str | Path, queries: str | Path, out: str | Path, *, method: str = "context",
                fps: float = 30.0, space: str = "image", config: ContextConfig | None = None,
                metres_per_unit: float | None = None, roads: str | Path | None = None,
                crs: str | None = None, zero_based: bool = False) -> int:
    """Read the inputs, predict every query, write ``out`` atomically; returns the row count.

    ``roads``: a GeoJSON of road centre-lines (``--space map`` only), reprojected to ``crs``, the
    CRS of the tracks' x, y columns (default: lon/lat when they look like degrees).
    ``zero_based``: the tracks, the queries and the answer number frames from 0.
    """
    config = config or ContextConfig()
    get_predictor(method, config, fps)  # fail on a bad method before reading anything
    if roads is not None and space != "map":
        raise InputError(f"--roads {roads}: needs --space map (the roads are in map coordinates)")
    positions = Path(tracks).is_file() and _first_row_fields(tracks) == 4
    if positions:  # frame,id,x,y: the same positions whichever space; their scale is a map's
        rows = read_positions(tracks, zero_based)
        log.info("%s: rows of frame,id,x,y (positions without boxes)", tracks)
        space = "map"
    else:
        rows = read_mot(tracks, option="TRACKS", strict=True, allow_empty=False, tracks=True,
                        zero_based=zero_based)
    # lon/lat degrees are not square (a degree of longitude is cos(latitude) of one of latitude):
    # longitudes are scaled to the latitude's length for the prediction and back afterwards, so
    # that distances, radii and gates mean the same in every direction (and in any unit)
    squash = 1.0
    if space == "map" and metres_per_unit is None and _looks_geographic(rows):
        squash = scale_of(rows, "map", config) / METRES_PER_DEGREE
        placed = ~np.all(rows[:, 7:9] == -1, axis=1)
        rows = rows.copy()
        rows[placed, 7] *= squash
        log.info("%s: x, y taken as lon/lat degrees (longitudes scaled by cos(latitude) = %.4f "
                 "for the prediction); give --gsd if they are not", tracks, squash)
    qs = read_queries(queries)
    if zero_based:
        qs = [Query(q.id, q.last_seen + 1, q.horizon, q.line) for q in qs]
    step = frame_step(rows)
    if step > 1:
        have = {(int(i), int(f)) for f, i in rows[:, :2]}
        for n, q in enumerate(qs):  # named in the file's own frame numbers
            if (q.id, q.last_seen) not in have:
                known = any(i == q.id for i, _ in have)
                raise InputError(f"--queries {queries} line {q.line or n + 2} (query {n}): "
                                 + (f"track {q.id} has no row at last_seen {q.last_seen}" if known
                                    else f"unknown id {q.id}"))
        if space == "map":
            blank = {(int(i), int(f)) for f, i in rows[np.all(rows[:, 7:9] == -1, axis=1), :2]}
            for n, q in enumerate(qs):
                if (q.id, q.last_seen) in blank:
                    raise InputError(f"--queries {queries} line {q.line or n + 2} (query {n}): "
                                     f"track {q.id} has no map position (x, y = -1) at "
                                     f"last_seen {q.last_seen}")
        log.info("%s: rows every %d frames: predicted on those frames (%g frames/s) and carried "
                 "on between them", tracks, step, fps / step)
    table = tracks_table(rows, space, name=str(tracks))
    mpu = metres_per_unit or (METRES_PER_DEGREE if squash != 1.0 else
                              scale_of(rows, space, config))
    network = None
    if roads is not None:
        from .roads import RoadNetwork, read_roads

        if crs is None:
            if scale_of(rows, "map", config) == 1.0:
                raise InputError(f"--roads {roads}: give --crs, the CRS of the tracks' x,y columns")
            crs = "EPSG:4326"
        else:
            from pyproj import CRS
            from pyproj.exceptions import CRSError

            try:
                CRS.from_user_input(crs)
            except CRSError:
                raise InputError(f"--crs {crs}: not a CRS pyproj knows (e.g. EPSG:32611)") from None
        network = read_roads(roads, crs=crs, snap_m=config.roads_snap_m)
        if squash != 1.0 or not math.isclose(network.mpu, mpu, rel_tol=1e-9):  # the tracks'
            lines = [np.column_stack([ln[:, 0] * squash, ln[:, 1:]]) for ln in network.lines]
            try:  # scale rules, and their longitudes are scaled as theirs
                network = RoadNetwork(lines, mpu, config.roads_snap_m, y_down=network.y_down)
            except InputError as exc:
                raise InputError(f"--roads {roads}: {exc} (--crs {crs} is taken as the tracks' "
                                 "CRS)") from None
        _check_roads_near(network, table, roads, crs, mpu)
    unplaced = rows[np.all(rows[:, 7:9] == -1, axis=1)] if space == "map" else None
    label = f"--queries {queries}"
    if step == 1:
        preds = predict_queries(table, qs, method, config, fps, mpu, roads=network, label=label,
                                unplaced=unplaced)
    else:  # on each query's grid (tracks may lie on several), then every frame between
        preds = [None] * len(qs)
        for offset in sorted({q.last_seen % step for q in qs}):
            pick = [n for n, q in enumerate(qs) if q.last_seen % step == offset]
            grows, gqs = _on_grid(rows, [qs[n] for n in pick], step, offset)
            gtable = tracks_table(grows, space, name=str(tracks))
            gp = predict_queries(gtable, gqs, method, config, fps / step, mpu, roads=network,
                                 label=label, unplaced=unplaced if unplaced is None else
                                 grows[np.all(grows[:, 7:9] == -1, axis=1)])
            for n, g, p in zip(pick, gqs, gp):
                fr, xy = gtable.track(g.id)
                k = int(np.searchsorted(fr, g.last_seen))
                before = xy[k - 1] if k > 0 and fr[k - 1] == g.last_seen - 1 else xy[k]
                preds[n] = _between_steps(p, xy[k], before, step, qs[n].horizon)
    if squash != 1.0:
        preds = [np.column_stack([p[:, 0] / squash, p[:, 1]]) for p in preds]
    if zero_based:
        qs = [Query(q.id, q.last_seen - 1, q.horizon, q.line) for q in qs]
    atomic_write_text(out, format_predictions(qs, preds, 7 if space == "map" else 6))
    return sum(q.horizon for q in qs)


def _check_roads_near(network, table: TrackTable, roads, crs, mpu: float,
                      within_m: float = 1000.0) -> None:
    """Warn when no road passes within ``within_m`` of the tracks: the roads then change no
    prediction, which is what a wrong ``--crs`` does silently (lon/lat tracks read as UTM)."""
    pts = [table.track(i)[1] for i in table.track_ids()]
    if not pts or not getattr(network, "lines", None):
        return
    xy = np.vstack(pts)
    lo, hi = xy.min(axis=0) - within_m / mpu, xy.max(axis=0) + within_m / mpu
    boxes = np.array([np.r_[np.min(ln, axis=0)[:2], np.max(ln, axis=0)[:2]]
                      for ln in network.lines])  # each line's bounding box
    if not np.any(np.all(boxes[:, :2] <= hi, axis=1) & np.all(boxes[:, 2:] >= lo, axis=1)):
        log.warning("--roads %s: no road within %.0f m of the tracks in %s; the roads change no "
                    "prediction (is --crs the CRS of the tracks' x,y columns?)", roads, within_m, crs)



def score_predictions(tracks: str | Path, predictions: str | Path, *, space: str = "image",
                      fps: float = 30.0, metres_per_unit: float | None = None,
                      zero_based: bool = False) -> tuple[list[dict], str]:
    """MPE_n and Variance_n (Ali et al. section 5) of a predictions file against the tracks'
    own rows of each target after its ``last_seen``: ``aerotrack predict --score``.

    A query counts at ``n`` when its horizon reaches ``n``; its errors are those of the frames
    among its first ``n`` where the target has a row (all of them for tracks with a row every
    frame; the annotated ones for ETH/UCY). Distances are in metres when the scale is known
    (``--space map`` in metres or lon/lat, or ``metres_per_unit``), else in the tracks' units.

    Returns
    -------
    (rows, unit)
        One dict per n (``n``, ``seconds``, ``queries``, ``MPE``, ``Variance``) and the unit.
    """
    from ..evaluation.prediction import prediction_errors

    if Path(tracks).is_file() and _first_row_fields(tracks) == 4:
        rows, space = read_positions(tracks, zero_based), "map"
    else:
        rows = read_mot(tracks, option="TRACKS", strict=True, allow_empty=False, tracks=True,
                        zero_based=zero_based)
    xy = rows[:, 2:4] + rows[:, 4:6] / 2.0 if space == "image" else rows[:, 7:9].copy()
    unit = "px" if space == "image" else "units"
    kx = ky = 1.0
    if metres_per_unit:
        kx = ky = float(metres_per_unit)
        unit = "m"
    elif space == "map":
        if _looks_geographic(rows):
            ky = METRES_PER_DEGREE
            kx = scale_of(rows, "map", ContextConfig())
        unit = "m"
    truth = {(int(i), int(f)): p for f, i, p in zip(rows[:, 0], rows[:, 1], xy)}
    try:
        P = np.loadtxt(predictions, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{predictions}: cannot read the predictions ({exc})") from None
    if zero_based:
        P[:, 2] += 1
    errors = []
    for q in np.unique(P[:, 0]).astype(int):
        r = P[P[:, 0] == q]
        t = np.array([truth.get((int(i), int(f)), (np.nan, np.nan)) for _, i, f, _, _ in r])
        d = np.column_stack([(r[:, 3] - t[:, 0]) * kx, (r[:, 4] - t[:, 1]) * ky])
        errors.append(prediction_errors(d, np.zeros_like(d)))
    h = max((len(e) for e in errors), default=0)
    out = []
    for n in sorted({1, 10, 30, 60, h} & set(range(1, h + 1))):
        mpe, var = [], []
        for e in errors:
            if len(e) < n or not np.isfinite(e[:n]).any():
                continue
            first = e[:n][np.isfinite(e[:n])]
            mpe.append(first.mean())
            var.append(((first - first.mean()) ** 2).mean())
        out.append({"n": n, "seconds": n / fps, "queries": len(mpe),
                    "MPE": float(np.mean(mpe)) if mpe else math.nan,
                    "Variance": float(np.mean(var)) if var else math.nan})
    return out, unit

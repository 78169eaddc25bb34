"""Road-network motion context: an unobserved vehicle keeps driving along the road it was on.

The learned road (:mod:`aerotrack.context.motion`: where earlier objects went) has no support
where nobody was seen: behind an occluder or outside the view every other vehicle is hidden too,
and most of the error of a prediction is made at the turns, U-turns and junctions there. With road
centre-lines (a GeoJSON file, ``--roads``) the road geometry itself says where a vehicle can go.

* :class:`RoadNetwork` holds the centre-lines as a graph: polylines cut at their junctions (ends
  and crossings closer than ``roads_snap_m`` merge into one node).
* :func:`road_prediction` snaps a target's last state (position, heading, speed) to the best edge
  (distance and heading agreement, either direction of travel), then drives along the centre-line
  at the target's speed, keeping its lateral offset (its lane; any excess decays). At a junction
  each way on has a probability from the votes of earlier vehicles from the same approach (the
  learned road, a :class:`~aerotrack.context.paths.PathIndex`) smoothed by a prior
  (:func:`branch_probabilities`); a route's probability is the product of its junction choices'.
  At a dead end inside the map it U-turns; at an end on the map's edge (the road goes on beyond)
  it goes straight on. The prediction is the routes' weighted centre (``road_hedge``,
  :func:`hedge`: where the branch is uncertain, the point of least expected error lies between
  the branches, not on the likeliest). Every route is returned too
  (:attr:`RoadPrediction.hypotheses`, most likely first), so a linker can gate a re-appearing
  object on the nearest one.

Coordinates: one planar "world" frame (map pixels in the pipeline, the tracks' map CRS in
``aerotrack predict``, metres in the benchmark); ``metres_per_unit`` converts the configuration's
metres to it. Frames are video frames; speeds are world units per frame.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..config import ContextConfig
from ..errors import ConfigError, InputError, install_extra
from ..io.geojson import document_crs

log = logging.getLogger(__name__)

__all__ = ["HEDGES", "RoadNetwork", "RoadPrediction", "branch_probabilities", "hedge", "read_roads",
           "road_prediction"]


# --------------------------------------------------------------------------------------------------
# reading


def _ogr_document(path: Path, label: str) -> dict:
    """A file GDAL reads (GeoPackage, Shapefile, FlatGeobuf, ...; its first layer) as the GeoJSON
    document :func:`read_roads` reads: line geometries and the layer's CRS as a ``crs`` member."""
    try:
        from pyogrio.errors import DataSourceError
        from pyogrio.raw import read
    except ImportError:
        raise InputError(f"{label}: not GeoJSON; reading other formats (GeoPackage, Shapefile) "
                         f"needs pyogrio: {install_extra('gis')}") from None
    try:
        meta, _, wkbs, _ = read(str(path), read_geometry=True, columns=[])
    except (DataSourceError, OSError, RuntimeError, ValueError) as exc:
        raise InputError(f"{label}: cannot read as GeoJSON or as a GDAL vector file "
                         f"({str(exc).splitlines()[0]})") from None
    geoms = []
    for b in wkbs if wkbs is not None else []:
        if b is None:
            continue
        try:
            parts = _wkb_lines(memoryview(bytes(b)), 0)[0]
        except (struct.error, IndexError, ValueError):
            raise InputError(f"{label}: a geometry GDAL returned cannot be decoded") from None
        if parts:
            geoms.append({"type": "MultiLineString", "coordinates": parts})
    doc: dict = {"type": "FeatureCollection", "read_by_gdal": True,
                 "features": [{"type": "Feature", "geometry": g} for g in geoms]}
    if meta.get("crs"):
        doc["crs"] = {"type": "name", "properties": {"name": meta["crs"]}}
    return doc


def _wkb_lines(b: memoryview, at: int) -> tuple[list, int]:
    """The line parts ((n, 2) coordinate lists) of the WKB geometry at offset ``at``, and the offset
    after it. LineStrings and MultiLineStrings (ISO or EWKB Z/M flavours, collections of them);
    other geometry types give no parts."""
    order = "<" if b[at] == 1 else ">"
    (code,) = struct.unpack_from(order + "I", b, at + 1)
    at += 5
    if code & 0x20000000:  # EWKB SRID
        at += 4
    dims = 2 + bool(code & 0x80000000) + bool(code & 0x40000000)
    code &= 0x0FFFFFFF
    base, flavour = code % 1000, code // 1000
    dims += {1: 1, 2: 1, 3: 2}.get(flavour, 0)
    if base == 1:
        return [], at + 8 * dims
    if base == 2:
        (n,) = struct.unpack_from(order + "I", b, at)
        vals = struct.unpack_from(order + f"{n * dims}d", b, at + 4)
        pts = [list(vals[i * dims:i * dims + 2]) for i in range(n)]
        return [pts], at + 4 + 8 * n * dims
    if base == 3:  # polygon: skip its rings
        (rings,) = struct.unpack_from(order + "I", b, at)
        at += 4
        for _ in range(rings):
            (n,) = struct.unpack_from(order + "I", b, at)
            at += 4 + 8 * n * dims
        return [], at
    if base in (4, 5, 6, 7):  # multi-geometries and collections: their members in turn
        (n,) = struct.unpack_from(order + "I", b, at)
        at += 4
        out = []
        for _ in range(n):
            parts, at = _wkb_lines(b, at)
            out += parts
        return out, at
    raise ValueError(f"WKB geometry type {code}")


def _lines_of(doc: dict, label: str) -> list[np.ndarray]:
    """Every LineString / MultiLineString of a FeatureCollection, Feature or bare geometry."""
    if doc.get("type") == "FeatureCollection":
        geoms = [f.get("geometry") for f in doc.get("features") or [] if isinstance(f, dict)]
    elif doc.get("type") == "Feature":
        geoms = [doc.get("geometry")]
    else:
        geoms = [doc]
    out = []
    skipped = 0
    for g in geoms:
        if not isinstance(g, dict):
            continue
        kind, coords = g.get("type"), g.get("coordinates")
        parts = [coords] if kind == "LineString" else coords if kind == "MultiLineString" else []
        for part in parts or []:
            try:
                a = np.asarray([c[:2] for c in part], dtype=np.float64).reshape(-1, 2)
            except (TypeError, ValueError, IndexError):
                raise InputError(f"{label}: a {kind} has malformed coordinates") from None
            if len(a) >= 2 and np.all(np.isfinite(a)):
                out.append(a)
            else:
                skipped += 1
    if not out:
        raise InputError(f"{label}: no LineString or MultiLineString road centre-lines"
                         + (f" ({skipped} with fewer than 2 vertices or a NaN one)"
                            if skipped else ""))
    if skipped:
        log.warning("%s: %d line%s left out (fewer than 2 vertices, or a NaN or infinite "
                    "vertex)", label, skipped, "s" * (skipped != 1))
    return out


def read_roads(path: str | Path, *, geomap=None, crs=None, snap_m: float = 5.0,
               option: str = "--roads") -> RoadNetwork:
    """Road centre-lines from a GeoJSON file, in the world frame of a map or a CRS.

    Parameters
    ----------
    path : path
        GeoJSON with LineString / MultiLineString geometries (FeatureCollection, Feature or a bare
        geometry). Coordinates are in its legacy ``crs`` member's CRS, else WGS 84 lon/lat.
    geomap : GeoMap, optional
        The map: coordinates are reprojected to its CRS, then to its pixels (the pipeline's world
        frame); metres per unit is the map's, and the map's extent tells dead ends (inside) from
        roads leaving the map (an end on its edge).
    crs : str or pyproj.CRS, optional
        Without a map: reproject to this CRS instead (e.g. the CRS of a tracks file's x, y
        columns). Metres per unit: 1 for a projected CRS in metres, the local length of a degree
        of longitude for a geographic one (so lon/lat distances are only approximate).
    snap_m : float
        Junction snapping distance (``ContextConfig.roads_snap_m``).

    Raises
    ------
    InputError
        Missing file, not JSON, no line geometry, an unknown CRS (one line naming the file).
    """
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    p = Path(path)
    label = f"{option} {p}"
    if p.is_dir():
        raise InputError(f"{label}: is a folder, expected a GeoJSON file")
    if not p.is_file():
        raise InputError(f"{label}: file not found")
    try:
        head = p.read_bytes()[:64].lstrip(b"\xef\xbb\xbf \t\r\n")
    except OSError as exc:
        raise InputError(f"{label}: cannot read ({exc.strerror})") from None
    if head[:1] in (b"{", b"[") or p.suffix.lower() in (".geojson", ".json"):
        try:
            doc = json.loads(p.read_text(encoding="utf-8-sig"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{label}: cannot read as GeoJSON "
                             f"({str(exc).splitlines()[0]})") from None
    else:  # a GeoPackage, Shapefile, ... through GDAL
        doc = _ogr_document(p, label)
    if not isinstance(doc, dict):
        raise InputError(f"{label}: not a GeoJSON object")
    src = document_crs(doc, label)
    lines = _lines_of(doc, label)
    if src.is_geographic:
        allpts = np.vstack(lines)
        if np.any(np.abs(allpts[:, 0]) > 180) or np.any(np.abs(allpts[:, 1]) > 90):
            fix = ("the file names no CRS: a Shapefile needs its .prj beside it"
                   if doc.get("read_by_gdal") else
                   "GeoJSON is lon, lat: swapped? or give the file's CRS in its 'crs' member")
            raise InputError(f"{label}: coordinates are not lon/lat (a latitude beyond 90 or a "
                             f"longitude beyond 180; {fix})")
    if geomap is not None:
        dst = CRS.from_user_input(geomap.crs.to_wkt())
    elif crs is not None:
        try:
            dst = CRS.from_user_input(crs)
        except CRSError:
            raise InputError(f"{label}: unknown target CRS {crs!r}") from None
    else:
        dst = src
    if dst != src:
        t = Transformer.from_crs(src, dst, always_xy=True)
        lines = [np.column_stack(t.transform(a[:, 0], a[:, 1])) for a in lines]
    if not all(np.all(np.isfinite(a)) for a in lines):
        raise InputError(f"{label}: coordinates fall outside the target CRS")
    if geomap is not None:
        lines = [geomap.crs_to_pixel(a) for a in lines]
        allpx = np.vstack(lines)
        lo, hi = allpx.min(axis=0), allpx.max(axis=0)
        if not (hi[0] >= 0 and hi[1] >= 0 and lo[0] <= geomap.width and lo[1] <= geomap.height):
            log.warning("%s: no road crosses the map (the roads span map pixels %.0f..%.0f x "
                        "%.0f..%.0f, the map is %dx%d): they change no prediction", label, lo[0],
                        hi[0], lo[1], hi[1], geomap.width, geomap.height)
        return RoadNetwork(lines, metres_per_unit=geomap.metres_per_pixel, snap_m=snap_m,
                           bounds=(0.0, 0.0, float(geomap.width), float(geomap.height)))
    if dst.is_geographic:
        lat = float(np.median(np.concatenate([a[:, 1] for a in lines])))
        mpu = 111_320.0 * math.cos(math.radians(lat))
    else:
        mpu = float(dst.axis_info[0].unit_conversion_factor) if dst.axis_info else 1.0
    return RoadNetwork(lines, metres_per_unit=mpu, snap_m=snap_m, y_down=False)


# --------------------------------------------------------------------------------------------------
# the graph


@dataclass
class _Edge:
    u: int  # node at the start of pts
    v: int  # node at the end
    pts: np.ndarray  # (n, 2) world units
    cum: np.ndarray  # (n,) arc length at each point

    @property
    def length(self) -> float:
        return float(self.cum[-1])


def _cumlen(pts: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])


def _at(pts: np.ndarray, cum: np.ndarray, s) -> np.ndarray:
    """Points at arc lengths ``s`` (clamped) of a polyline -> (len(s), 2)."""
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, cum[-1])
    return np.column_stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])])


def _project(q: np.ndarray, pts: np.ndarray, cum: np.ndarray) -> tuple[float, float]:
    """(distance, arc length) of the point of a polyline nearest ``q``."""
    a, b = pts[:-1], pts[1:]
    ab = b - a
    L2 = (ab * ab).sum(-1)
    u = np.clip(((q - a) * ab).sum(-1) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    d = np.hypot(*(a + u[:, None] * ab - q).T)
    k = int(np.argmin(d))
    return float(d[k]), float(cum[k] + u[k] * math.sqrt(L2[k]))


def _crossings(p: np.ndarray, q: np.ndarray) -> list[tuple[float, float]]:
    """Arc lengths (on p, on q) where two polylines properly cross."""
    cp, cq = _cumlen(p), _cumlen(q)
    a, r = p[:-1, None], (p[1:] - p[:-1])[:, None]  # (m, 1, 2)
    b, s = q[None, :-1], (q[1:] - q[:-1])[None]  # (1, k, 2)
    den = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    ab = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ab[..., 0] * s[..., 1] - ab[..., 1] * s[..., 0]) / den
        u = (ab[..., 0] * r[..., 1] - ab[..., 1] * r[..., 0]) / den
    hit = (np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    out = []
    for i, j in zip(*np.nonzero(hit)):
        out.append((cp[i] + t[i, j] * (cp[i + 1] - cp[i]), cq[j] + u[i, j] * (cq[j + 1] - cq[j])))
    return out


class RoadNetwork:
    """Road centre-lines as a graph of polylines joined at junctions.

    Parameters
    ----------
    lines : list of ndarray, each (n_i, 2)
        Centre-lines in world units (n_i >= 2).
    metres_per_unit : float
        World units -> metres.
    snap_m : float
        Ends and crossings closer than this (metres) become one node: a road ending within it of
        another road joins it there (a T junction), two ends within it join each other, and two
        lines crossing are cut at the crossing. The node sits on the through road (ends move onto
        it by at most ``snap_m``).
    bounds : (xmin, ymin, xmax, ymax), optional
        Extent of the map, world units. A road end within ``snap_m`` of its edge is *open* (the
        road goes on beyond the map: a vehicle drives straight on); any other end is a dead end
        (a U-turn). Default: the lines' own bounding box.
    y_down : bool
        World y grows downwards (image and map pixels, the pipeline's world frame: the default);
        False for a CRS's north-up coordinates (``read_roads(crs=...)``). Only which side of a
        road is the right-hand side depends on it (:meth:`lane_heading`).

    Attributes
    ----------
    lines : list of ndarray
        The input centre-lines.
    edges : list
        Polylines between nodes (``u``, ``v`` node ids, ``pts`` (n, 2), ``cum`` arc lengths).
    nodes : ndarray, shape (N, 2)
    adjacency : list of list of (edge, direction)
        For each node, the ways out of it: ``(e, +1)`` along edge e from its start, ``(e, -1)``
        backwards from its end.
    open_ends : set of int
        Nodes where a road leaves the map.
    """

    def __init__(self, lines: list[np.ndarray], metres_per_unit: float = 1.0, snap_m: float = 5.0,
                 bounds: tuple[float, float, float, float] | None = None,
                 y_down: bool = True) -> None:
        self.mpu = float(metres_per_unit)
        #: +1 when the normal (-t_y, t_x) of a heading t points to the right of travel (world y
        #: down), -1 when it points to the left (y up)
        self.y_down = bool(y_down)
        self.right_sign = 1.0 if y_down else -1.0
        clean = []
        for a in lines:
            a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
            keep = np.concatenate([[True], np.hypot(*np.diff(a, axis=0).T) > 1e-9])
            a = a[keep]
            if len(a) >= 2:
                clean.append(a)
        if not clean:
            raise InputError("road network: no centre-line with two distinct points")
        self.lines = clean
        self.snap = snap_m / self.mpu
        allp = np.vstack(clean)
        self.bounds = tuple(float(v) for v in (bounds if bounds is not None else
                                               (*allp.min(axis=0), *allp.max(axis=0))))
        self._build()

    # -- construction -----------------------------------------------------------------------------
    def _build(self) -> None:
        lines, snap = self.lines, self.snap
        cums = [_cumlen(a) for a in lines]
        # cut positions per line: (arc length, interior?) ; ends always
        cuts: list[list[tuple[float, bool]]] = [[(0.0, False), (c[-1], False)] for c in cums]
        boxes = [(a.min(axis=0) - snap, a.max(axis=0) + snap) for a in lines]
        for i in range(len(lines)):
            for j in range(len(lines)):
                if i == j or np.any(boxes[i][1] < boxes[j][0]) or np.any(boxes[j][1] < boxes[i][0]):
                    continue
                if i < j:
                    for si, sj in _crossings(lines[i], lines[j]):
                        cuts[i].append((si, True))
                        cuts[j].append((sj, True))
                for end in (lines[i][0], lines[i][-1]):  # an end of i near line j: a T junction
                    d, sj = _project(end, lines[j], cums[j])
                    if d <= snap:
                        cuts[j].append((sj, 0 < sj < cums[j][-1]))
        # candidate node points, clustered within snap
        pts, owner = [], []
        for i, cs in enumerate(cuts):
            for s, interior in cs:
                pts.append(_at(lines[i], cums[i], [s])[0])
                owner.append((i, s, interior))
        P = np.array(pts)
        parent = list(range(len(P)))

        def find(a):
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        for a, b in sorted(cKDTree(P).query_pairs(snap)):
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
        roots = sorted({find(a) for a in range(len(P))})
        node_of_root = {r: n for n, r in enumerate(roots)}
        members: dict[int, list[int]] = {}
        for a in range(len(P)):
            members.setdefault(node_of_root[find(a)], []).append(a)
        nodes = np.zeros((len(roots), 2))
        for n, idx in members.items():
            inner = [a for a in idx if owner[a][2]]
            nodes[n] = P[inner or idx].mean(axis=0)
        cut_node = {a: node_of_root[find(a)] for a in range(len(P))}
        # edges: each line cut at its (merged) cut positions
        edges: list[_Edge] = []
        k = 0
        for i, cs in enumerate(cuts):
            here = sorted((owner[k + n][1], cut_node[k + n]) for n in range(len(cs)))
            k += len(cs)
            seq: list[tuple[float, int]] = []
            for s, n in here:  # one position per node along the line (the first)
                if seq and seq[-1][1] == n:
                    continue
                seq.append((s, n))
            for (s0, n0), (s1, n1) in itertools.pairwise(seq):
                if s1 - s0 <= 1e-9:
                    continue
                inside = (cums[i] > s0) & (cums[i] < s1)
                mid = lines[i][inside]
                e_pts = np.vstack([nodes[n0], mid, nodes[n1]])
                keep = np.concatenate([[True], np.hypot(*np.diff(e_pts, axis=0).T) > 1e-9])
                e_pts = e_pts[keep]
                if len(e_pts) < 2 or (n0 == n1 and _cumlen(e_pts)[-1] < 2 * snap):
                    continue
                edges.append(_Edge(n0, n1, e_pts, _cumlen(e_pts)))
        self.nodes = nodes
        self.edges = edges
        self.adjacency: list[list[tuple[int, int]]] = [[] for _ in range(len(nodes))]
        for e, ed in enumerate(edges):
            self.adjacency[ed.u].append((e, 1))
            self.adjacency[ed.v].append((e, -1))
        x0, y0, x1, y1 = self.bounds
        self.open_ends = {n for n in range(len(nodes)) if len(self.adjacency[n]) == 1 and min(
            nodes[n, 0] - x0, x1 - nodes[n, 0], nodes[n, 1] - y0, y1 - nodes[n, 1]) <= snap}
        if not edges:  # every line shorter than the snap distance: units not the network's
            raise InputError(f"road network: every centre-line is shorter than the snap distance "
                             f"({self.snap:.3g} units at {self.mpu:.3g} m a unit): are the roads "
                             "and the tracks in the same CRS?")
        # every segment, for snapping
        seg_a, seg_b, seg_e, seg_s = [], [], [], []
        for e, ed in enumerate(edges):
            seg_a.append(ed.pts[:-1])
            seg_b.append(ed.pts[1:])
            seg_e.append(np.full(len(ed.pts) - 1, e))
            seg_s.append(ed.cum[:-1])
        self._sa, self._sb = np.vstack(seg_a), np.vstack(seg_b)
        self._se, self._ss = np.concatenate(seg_e), np.concatenate(seg_s)

    # -- queries ------------------------------------------------------------------------------------
    def snap_state(self, p: np.ndarray, v: np.ndarray, max_dist: float, max_angle_deg: float
                   ) -> tuple[int, float, int, float] | None:
        """The edge a target at ``p`` moving along ``v`` is driving on.

        Cost ``(d / max_dist)^2 + (angle / max_angle)^2`` over every segment within ``max_dist``
        (world units) whose direction agrees with ``v`` within ``max_angle_deg``, either way.

        Returns
        -------
        (edge, arc length of the projection, direction +1/-1 along the edge, signed lateral offset
        (positive to the right-hand normal ``(-t_y, t_x)`` of the direction of travel)), or None
        (off-road, or ``v`` is zero).
        """
        sp = math.hypot(v[0], v[1])
        if sp <= 0:
            return None
        u = np.asarray(v, float) / sp
        ab = self._sb - self._sa
        L = np.hypot(ab[:, 0], ab[:, 1])
        t = ab / L[:, None]
        w = np.clip(((p - self._sa) * t).sum(-1), 0.0, L)
        q = self._sa + w[:, None] * t
        d = np.hypot(*(p - q).T)
        cos = t @ u
        ang = np.degrees(np.arccos(np.clip(np.abs(cos), 0.0, 1.0)))
        cost = (d / max_dist) ** 2 + (ang / max(max_angle_deg, 1e-9)) ** 2
        ok = (d <= max_dist) & (ang <= max_angle_deg)
        if not ok.any():
            return None
        k = int(np.argmin(np.where(ok, cost, np.inf)))
        direction = 1 if cos[k] >= 0 else -1
        td = t[k] * direction
        n = np.array([-td[1], td[0]])
        return int(self._se[k]), float(self._ss[k] + w[k]), direction, float((p - q[k]) @ n)

    def lane_heading(self, p: np.ndarray, max_dist: float, min_offset: float,
                     side: str = "right") -> np.ndarray | None:
        """Unit heading of a vehicle at ``p`` whose velocity is unknown, from its lane: along the
        nearest centre-line segment (within ``max_dist``), in the direction that puts ``p`` on the
        ``side`` (``right`` or ``left``) of its travel. None when off-road or within
        ``min_offset`` of the centre-line (either way is as likely)."""
        ab = self._sb - self._sa
        L = np.hypot(ab[:, 0], ab[:, 1])
        t = ab / np.maximum(L, 1e-12)[:, None]
        w = np.clip(((p - self._sa) * t).sum(-1), 0.0, L)
        q = self._sa + w[:, None] * t
        d = np.hypot(*(p - q).T)
        k = int(np.argmin(d))
        if d[k] > max_dist:
            return None
        n = np.array([-t[k][1], t[k][0]]) * self.right_sign  # right of travel along +t
        off = float((p - q[k]) @ n)
        if abs(off) < min_offset:
            return None
        along = 1.0 if (off > 0) == (side == "right") else -1.0
        return t[k] * along

    def tangent_out(self, e: int, direction: int, reach: float) -> np.ndarray:
        """Unit heading leaving along edge e in ``direction``, over its first ``reach`` units."""
        ed = self.edges[e]
        s0, s1 = (0.0, min(reach, ed.length)) if direction > 0 else (ed.length, max(0.0, ed.length - reach))
        a, b = _at(ed.pts, ed.cum, [s0, s1])
        d = b - a
        n = math.hypot(d[0], d[1])
        return d / n if n > 0 else np.array([1.0, 0.0])

    def exits(self, node: int, e_in: int, dir_in: int) -> list[tuple[int, int]]:
        """Ways on from ``node`` after arriving along (e_in, dir_in), not back the same edge."""
        return [(e, d) for e, d in self.adjacency[node] if not (e == e_in and d == -dir_in)]


# --------------------------------------------------------------------------------------------------
# prediction


@dataclass
class _Route:
    centre: list[np.ndarray] = field(default_factory=list)  # pieces of centre-line, world units
    uturns: list[float] = field(default_factory=list)  # arc lengths where it turns back
    choices: list[tuple[int, int]] = field(default_factory=list)
    turns: list[tuple[float, float]] = field(default_factory=list)  # (arc length, degrees) at junctions
    length: float = 0.0
    prob: float = 1.0  # product of its junction choices' probabilities

    def add(self, pts: np.ndarray) -> None:
        if self.centre and len(pts) and np.allclose(self.centre[-1][-1], pts[0]):
            pts = pts[1:]
        if len(pts):
            prev = self.centre[-1][-1] if self.centre else pts[0]
            self.length += float(np.hypot(*np.diff(np.vstack([prev, pts]), axis=0).T).sum())
            self.centre.append(pts)

    def copy(self) -> _Route:
        return _Route(list(self.centre), list(self.uturns), list(self.choices), list(self.turns),
                      self.length, self.prob)


@dataclass(frozen=True)
class RoadPrediction:
    """A target's predicted drive along the road network.

    Attributes
    ----------
    positions : ndarray, shape (h, 2)
        World units, frames ``T+1 .. T+h``: the routes' centre under their ``weights``
        (``road_hedge``, :func:`hedge`; ``none``: the most likely route, ``hypotheses[0]``).
    hypotheses : list of ndarray, each (h, 2)
        Every route through the junctions within reach (the most likely one first: at each
        junction the branch most earlier objects took, else the straightest), for gating a
        re-appearing object on the nearest (:meth:`nearest`).
    weights : ndarray, shape (len(hypotheses),)
        Each route's probability: the product of its junction choices'
        (:func:`branch_probabilities`); they sum to 1.
    edge, direction : int
        The edge the target snapped to and its direction of travel along it.
    offset : float
        Lateral offset from the centre-line at the start, world units (right of travel positive).
    voted : bool
        Whether a junction choice came from earlier objects (the learned road).
    """

    positions: np.ndarray
    hypotheses: list[np.ndarray]
    weights: np.ndarray
    edge: int
    direction: int
    offset: float
    voted: bool

    def nearest(self, xy: np.ndarray, k: int) -> tuple[np.ndarray, float]:
        """The hypothesis closest to ``xy`` (2,) at step ``k`` (0-based) -> (its (h, 2) positions,
        the distance at step k). For a linker: gate and score a candidate on the branch it is on."""
        d = [float(np.hypot(*(hyp[k] - xy))) for hyp in self.hypotheses]
        i = int(np.argmin(d))
        return self.hypotheses[i], d[i]


def branch_probabilities(votes: np.ndarray, cos: np.ndarray, prior_weight: float,
                         kappa: float) -> np.ndarray:
    """Probability of each way on at a junction from earlier objects' votes and a turn prior.

    ``p_b = (votes_b + a * prior_b) / (sum(votes) + a)`` (the posterior mean of a Dirichlet with
    concentration ``a * prior``), with ``prior_b`` proportional to ``exp(kappa * cos_b)``: von
    Mises in the turn angle, uniform for ``kappa`` 0, more on straight on the larger it is.

    Parameters
    ----------
    votes : ndarray, shape (n,)
        Earlier objects that left by each branch (:func:`_branch_votes`).
    cos : ndarray, shape (n,)
        Cosine of each branch's turn angle (1 straight on, 0 a right angle, -1 back).
    prior_weight : float
        ``a``, the prior's worth in votes (``road_vote_prior``); 0 with votes is their frequency.
    kappa : float
        ``road_straight_kappa``.

    Returns
    -------
    ndarray, shape (n,), summing to 1.
    """
    votes = np.asarray(votes, dtype=np.float64)
    z = kappa * np.asarray(cos, dtype=np.float64)
    prior = np.exp(z - z.max())
    prior /= prior.sum()
    n = votes.sum()
    if n <= 0:
        return prior
    return (votes + prior_weight * prior) / (n + prior_weight)


def _geometric_median(points: np.ndarray, w: np.ndarray, iters: int = 30) -> np.ndarray:
    """Weighted geometric median per step: (R, h, 2) points, (R,) weights -> (h, 2).

    Weiszfeld's iteration from the weighted mean, then damped Newton steps (a step is kept only
    where it lowers the objective ``sum_r w_r |x_r - y|``): Weiszfeld alone creeps towards a
    median near a point. Where a point itself is the median (a branch with enough of the weight)
    a step ends there if that is strictly cheaper (at a tie between two branches the iterate,
    their midpoint, stays)."""
    steps = np.arange(points.shape[1])

    def cost(y):
        return np.einsum("r,rh->h", w, np.hypot(*(points - y[None]).transpose(2, 0, 1)))

    y = np.einsum("r,rhk->hk", w, points)
    for _ in range(iters):
        q = w[:, None] / np.maximum(np.hypot(*(points - y[None]).transpose(2, 0, 1)), 1e-12)
        y = np.einsum("rh,rhk->hk", q, points) / q.sum(axis=0)[:, None]
    f = cost(y)
    for _ in range(iters):
        D = points - y[None]  # (R, h, 2)
        d = np.maximum(np.hypot(D[..., 0], D[..., 1]), 1e-12)
        g = -np.einsum("r,rhk->hk", w, D / d[..., None])
        c3 = w[:, None] / d ** 3
        hxx = (c3 * D[..., 1] ** 2).sum(0)
        hyy = (c3 * D[..., 0] ** 2).sum(0)
        hxy = -(c3 * D[..., 0] * D[..., 1]).sum(0)
        det = hxx * hyy - hxy ** 2
        ok = det > 1e-12 * np.maximum(hxx * hyy, 1e-300)  # singular: points on a line
        det = np.where(ok, det, 1.0)
        step = -np.column_stack([hyy * g[:, 0] - hxy * g[:, 1], hxx * g[:, 1] - hxy * g[:, 0]]) / det[:, None]
        step[~ok] = 0.0
        moved = False
        for t in (1.0, 0.5, 0.25, 0.125):
            y_t = y + t * step
            f_t = cost(y_t)
            better = f_t < f
            y[better], f[better] = y_t[better], f_t[better]
            step[better] = 0.0
            moved |= bool(better.any())
        if not moved:
            break
    cand = np.concatenate([y[None], points])  # (R + 1, h, 2)
    c = np.stack([f, *(cost(p) for p in points)])
    best = 1 + np.argmin(c[1:], axis=0)
    better = c[best, steps] < c[0] - 1e-9 * (1.0 + c[0])
    return np.where(better[:, None], cand[best, steps], y)


#: ``road_hedge`` values: how one point prediction is made of the weighted routes.
HEDGES = ("none", "mean", "median")


def check_traffic_side(side: str) -> None:
    """Raise ConfigError for a ``road_traffic_side`` other than ``auto``, ``right`` or ``left``."""
    if side not in ("auto", "right", "left"):
        raise ConfigError(f"config context.road_traffic_side: unknown {side!r} "
                          "(valid: auto, right, left)")


def check_hedge(kind: str) -> None:
    """Raise ConfigError for an unknown ``road_hedge``, listing the valid ones."""
    if kind not in HEDGES:
        raise ConfigError(f"config context.road_hedge: unknown {kind!r} (valid: {', '.join(HEDGES)})")


def hedge(points: np.ndarray, weights: np.ndarray, kind: str) -> np.ndarray:
    """One point prediction per step from weighted route hypotheses.

    Parameters
    ----------
    points : ndarray, shape (R, h, 2)
        Routes' positions (world units), the most likely first.
    weights : ndarray, shape (R,)
        Their probabilities (sum 1).
    kind : str
        ``none``: the first route (winner takes all); ``mean``: the weighted mean (least expected
        squared error); ``median``: the weighted geometric median (least expected distance, the
        benchmark's error; of two branches it is the heavier one, and at a tie, where every point
        between them is as good, the midpoint). Routes that share the road up to a junction
        coincide there, so the choice only matters after it, and routes that part beyond the
        horizon (or differ only in braking for a later turn) are weighted by their common
        junction choices, not counted twice.

    Raises
    ------
    ConfigError
        An unknown ``kind`` (listing the valid ones).
    """
    check_hedge(kind)
    if kind == "none" or len(points) == 1:
        return points[0]
    w = np.asarray(weights, dtype=np.float64)
    if kind == "mean":
        return np.einsum("r,rhk->hk", w, points)
    out = points[0].copy()
    split = np.flatnonzero(np.abs(points - points[:1]).max(axis=(0, 2)) > 0)  # steps past a junction
    if len(split):
        out[split] = _geometric_median(points[:, split], w)
    return out


def _branch_votes(net: RoadNetwork, index, node: int, u_in: np.ndarray, cands, frame: int,
                  exclude_id: int, radius: float, look: float) -> np.ndarray:
    """How many earlier objects that approached ``node`` like the target (heading ``u_in``, within
    ``radius`` of the approach point ``look`` before the node) left by each candidate branch.

    Each voter's first row, seen no later than ``frame``, more than ``look`` beyond the node is
    assigned to the nearest candidate branch (within ``2 radius`` of its first ``4 look``), so a
    voter hidden at the junction (an occluder) still votes with where it re-appeared.
    """
    votes = np.zeros(len(cands))
    if index is None or index.tree is None:
        return votes
    c = net.nodes[node]
    approach = c - look * u_in
    rows = index.near(approach, radius, frame, exclude_id)
    if len(rows) == 0:
        return votes
    vel = index.vel[rows]
    sp = np.hypot(vel[:, 0], vel[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.isfinite(sp) & (sp > 0) & ((vel @ u_in) >= math.cos(math.radians(45)) * sp)
    rows = rows[ok]
    seen: set[int] = set()
    branch_pts = []
    for e, d in cands:
        ed = net.edges[e]
        s = np.linspace(0, min(ed.length, 4 * look), 24)
        branch_pts.append(_at(ed.pts, ed.cum, s if d > 0 else ed.length - s))
    for r in rows:  # canonical (id, frame) order: the first approach row of each voter
        t = int(index.ids[r])
        if t in seen:
            continue
        seen.add(t)
        _, hi = index.rows_of(t)
        after = np.arange(r + 1, hi)
        after = after[index.frames[after] <= frame]
        if len(after) == 0:
            continue
        xy = index.xy[after]
        beyond = (np.hypot(*(xy - c).T) > look) & (np.hypot(*(xy - approach).T) > 1.5 * look)
        if not beyond.any():
            continue
        q = xy[int(np.argmax(beyond))]
        dist = [float(np.hypot(*(bp - q).T).min()) for bp in branch_pts]
        b = int(np.argmin(dist))
        if dist[b] <= 2 * radius:
            votes[b] += 1
    return votes


def _routes(net: RoadNetwork, e: int, s: float, direction: int, need: float, order_exits,
            max_routes: int) -> list[_Route]:
    """Routes of at least ``need`` units from (edge, arc length, direction), the preferred first.

    ``order_exits(node, e_in, dir_in, u_in, exits) -> (exits, probabilities)`` ranks the ways on at
    a junction and says how likely each is. A route's ``prob`` is the product of its choices'; when
    ``max_routes`` cuts the less likely ways of a junction, the kept ones share its probability
    (renormalised), so the routes' probabilities always sum to 1."""
    start = _Route()
    todo = [(start, e, s, direction)]
    done: list[_Route] = []
    while todo:
        route, e, s, d = todo.pop(0)
        ed = net.edges[e]
        end_s = ed.length if d > 0 else 0.0
        inner = (ed.cum > s) & (ed.cum < ed.length) if d > 0 else (ed.cum < s) & (ed.cum > 0)
        piece = np.vstack([_at(ed.pts, ed.cum, [s]), ed.pts[inner][:: d], _at(ed.pts, ed.cum, [end_s])])
        route.add(piece)
        if route.length >= need:
            done.append(route)
            continue
        node = ed.v if d > 0 else ed.u
        u_in = -net.tangent_out(e, -d, 2 * net.snap)
        exits = net.exits(node, e, d)
        if not exits:
            if node in net.open_ends or len(net.adjacency[node]) != 1:
                route.add(net.nodes[node] + u_in * (need - route.length + 1.0))  # leaves the map
                done.append(route)
                continue
            route.uturns.append(route.length)  # dead end: back the way it came
            exits, probs = [(e, -d)], [1.0]
        else:
            exits, probs = order_exits(node, e, d, u_in, exits)
        n = len(exits)
        for k in range(1, len(exits)):
            if len(done) + len(todo) + k >= max_routes:
                n = k
                break
        exits, probs = exits[:n], np.asarray(probs[:n], dtype=np.float64)
        probs = probs / probs.sum() if probs.sum() > 0 else np.full(n, 1.0 / n)
        for k, (e2, d2) in enumerate(exits):
            r2 = route.copy() if k < len(exits) - 1 else route
            r2.prob = route.prob * float(probs[k])
            r2.choices.append((e2, d2))
            if e2 != e:  # (a dead end's U-turn costs road_uturn_s instead)
                u2 = net.tangent_out(e2, d2, 2 * net.snap)
                angle = math.degrees(math.acos(float(np.clip(u_in @ u2, -1, 1))))
                r2.turns.append((route.length, angle))
            todo.insert(k, (r2, e2, 0.0 if d2 > 0 else net.edges[e2].length, d2))
    return done


def _travel(speed: float, turns: list[tuple[float, float]], h: int, turn_speed: float,
            decel: float, accel: float, min_angle: float = 45.0) -> np.ndarray:
    """Arc length driven after each of ``h`` frames at ``speed`` (units per frame), slowing down
    at ``decel`` (units per frame^2) to ``turn_speed`` for each junction turn sharper than
    ``min_angle`` degrees and speeding up again at ``accel`` after it.

    A vehicle brakes for a turn it is about to take; constant speed through a right-angle turn
    overshoots it by the braking distance. Straight on (or a slight bend) keeps the speed.
    """
    sharp = sorted(a for a, angle in turns if angle > min_angle)
    if not sharp or turn_speed <= 0 or decel <= 0 or speed <= turn_speed:
        return speed * np.arange(1, h + 1, dtype=np.float64)
    out = np.empty(h)
    s, v = 0.0, speed
    for i in range(h):
        ahead = [a - s for a in sharp if a > s]
        cap = math.sqrt(turn_speed ** 2 + 2.0 * decel * ahead[0]) if ahead else speed
        v = min(v + accel, speed, cap)
        s += v
        out[i] = s
    return out


def _drive(route: _Route, lengths: np.ndarray, offset: np.ndarray, width: float) -> np.ndarray:
    """Positions at arc ``lengths`` along a route, ``offset`` to the right of travel."""
    pts = np.vstack(route.centre)
    cum = _cumlen(pts)
    c = _at(pts, cum, lengths)
    # heading from a chord around each point: corners are rounded over ``width`` instead of
    # jumping the lateral offset from one side of a corner to the other
    d = _at(pts, cum, lengths + width) - _at(pts, cum, lengths - width)
    n = np.hypot(d[:, 0], d[:, 1])
    d = d / np.where(n > 0, n, 1.0)[:, None]
    return c + offset[:, None] * np.column_stack([-d[:, 1], d[:, 0]])


def road_prediction(net: RoadNetwork, p0: np.ndarray, v0: np.ndarray, h: int, fps: float,
                    config: ContextConfig | None = None, *, index=None, frame: int | None = None,
                    exclude_id: int = -1, max_routes: int = 8) -> RoadPrediction | None:
    """Drive a target along the road network for ``h`` frames.

    Parameters
    ----------
    net : RoadNetwork
    p0 : ndarray, shape (2,)
        Position at the last observed frame ``frame`` (world units).
    v0 : ndarray, shape (2,)
        Velocity, world units per frame (its direction is the heading, its norm the speed, kept).
    h : int
        Frames to predict.
    fps : float
    config : ContextConfig
        ``road_snap_m``, ``road_heading_deg``, ``road_lane_m``, ``road_offset_tau_s``,
        ``road_uturn_s``, ``road_vote_radius_m``, ``road_turn_*``, ``road_hedge``,
        ``road_vote_prior``, ``road_straight_kappa``, ``min_speed_mps``.
    index : PathIndex, optional
        Other objects' rows (:class:`aerotrack.context.paths.PathIndex`): at each junction the
        ways on earlier objects from the same approach took (rows seen no later than ``frame``,
        not ``exclude_id``'s) are voted for (:func:`_branch_votes`, :func:`branch_probabilities`);
        the most likely route goes by the most votes, then the straightest.
    max_routes : int
        Most branch hypotheses enumerated; the less likely ways of a junction beyond it are
        dropped and the kept ones share its probability.

    Returns
    -------
    RoadPrediction, or None when the target is off-road (no centre-line within ``road_snap_m``
    with a heading within ``road_heading_deg``) or slower than ``min_speed_mps``.

    Notes
    -----
    Speed is kept constant except for ``road_uturn_s`` lost at each dead-end U-turn and braking
    to ``road_turn_speed_mps`` for a junction turn sharper than 45 degrees (:func:`_travel`). The lateral
    offset is kept up to ``road_lane_m`` (the lane; right of travel stays right through turns and
    U-turns, as in right- or left-hand traffic alike) and the excess decays with
    ``road_offset_tau_s``.
    """
    c = config or ContextConfig()
    p0 = np.asarray(p0, dtype=np.float64)
    v0 = np.asarray(v0, dtype=np.float64)
    speed = math.hypot(v0[0], v0[1])
    if h <= 0 or speed * fps * net.mpu < c.min_speed_mps:
        return None
    snap = net.snap_state(p0, v0, c.road_snap_m / net.mpu, c.road_heading_deg)
    if snap is None:
        return None
    e, s, direction, off = snap
    T = -1 if frame is None else int(frame)
    look = max(2 * net.snap, 8.0 / net.mpu)
    radius = c.road_vote_radius_m / net.mpu
    voted = [False]

    def order_exits(node, e_in, d_in, u_in, exits):
        cos = np.array([float(u_in @ net.tangent_out(e2, d2, look)) for e2, d2 in exits])
        order = np.argsort(-cos, kind="stable")  # straightest first
        votes = np.zeros(len(exits))
        if index is not None and frame is not None:
            votes = _branch_votes(net, index, node, u_in, exits, T, exclude_id, radius, look)
            if votes.sum() > 0:
                voted[0] = True
                order = np.lexsort((-cos, -votes))
        p = branch_probabilities(votes, cos, c.road_vote_prior, c.road_straight_kappa)
        return [exits[i] for i in order], p[order]

    k = np.arange(1, h + 1, dtype=np.float64)
    need = speed * h + look
    routes = _routes(net, e, s, direction, need, order_exits, max_routes)
    t = k / fps
    lane = c.road_lane_m / net.mpu
    kept = float(np.clip(off, -lane, lane))
    offset = kept + (off - kept) * np.exp(-t / max(c.road_offset_tau_s, 1e-9))
    width = max(abs(off), 2.0 / net.mpu)
    out = []
    mps = fps * net.mpu  # world units per frame -> m/s
    for r in routes:
        lengths = _travel(speed, r.turns, h, c.road_turn_speed_mps / mps,
                          c.road_turn_decel_mps2 / (mps * fps), c.road_turn_accel_mps2 / (mps * fps))
        for a in r.uturns:
            lengths = np.where(lengths > a, np.maximum(a, lengths - speed * c.road_uturn_s * fps),
                               lengths)
        out.append(_drive(r, lengths, offset, width))
    weights = np.array([r.prob for r in routes])
    weights = weights / weights.sum()
    positions = hedge(np.stack(out), weights, c.road_hedge)
    return RoadPrediction(positions, out, weights, e, direction, off, voted[0])

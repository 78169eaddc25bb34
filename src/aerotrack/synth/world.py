"""The static world of a generated scene: the colourised satellite tile, its road graph and occluders.

Geometry is kept in a local metric plane: ``m = (east, south)`` metres from the map's top-left
corner, so that ``map_px = m / (mx, my)`` where ``mx, my`` are the metres per map pixel along the
columns and rows (they differ on a lon/lat raster: about 0.24 and 0.30 m on the bundled tile).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import cv2
import numpy as np

from ..geo import GeoMap

DATA = Path(str(resources.files("aerotrack.synth") / "data"))
TILE = DATA / "vegas_tile.tif"
ROADS = DATA / "vegas_roads.geojson"


def colourise(gray: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """A plausible colour image (BGR uint8) from a panchromatic band (H, W) uint8.

    Dark textured areas (trees, lawns) get green, bright smooth areas (roofs, concrete) a warm
    tint, mid greys (asphalt, desert soil) a slightly blue-grey or sandy hue. A heuristic, not a
    spectral model: it only has to look like a colour aerial photo to a detector and a person.
    """
    g = gray.astype(np.float32) / 255.0
    mean = cv2.blur(g, (15, 15))
    sq = cv2.blur(g * g, (15, 15))
    texture = np.sqrt(np.maximum(sq - mean * mean, 0))
    veg = np.clip((0.40 - mean) * 5.0, 0, 1) * np.clip((texture - 0.05) * 10.0, 0, 1)
    veg = cv2.GaussianBlur(veg, (0, 0), 3.0) * np.clip((0.5 - g) * 4.0, 0, 1)
    bright = np.clip((mean - 0.55) * 3.0, 0, 1)
    sandy = np.clip(1.0 - np.abs(mean - 0.5) * 4.0, 0, 1) * np.clip(1.0 - texture * 12, 0, 1)
    # Las Vegas ground (desert lots, gravel yards) is tan whatever its texture: a mild warm tint on
    # everything that is neither vegetation nor dark (asphalt, shadow).
    soil = np.clip((mean - 0.22) * 4.0, 0, 1) * (1.0 - veg)
    b = g * (1.0 - 0.45 * veg - 0.10 * bright - 0.12 * sandy - 0.12 * soil)
    gr = g * (1.0 + 0.22 * veg - 0.02 * bright - 0.02 * sandy - 0.02 * soil)
    r = g * (1.0 - 0.22 * veg + 0.08 * bright + 0.08 * sandy + 0.07 * soil)
    img = np.stack([b, gr, r], axis=-1)
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


@dataclass
class Road:
    """A road centre-line resampled every ``step`` metres (points in the metric plane)."""

    points: np.ndarray  # (N, 2) metres
    lanes: int
    step: float

    @property
    def length(self) -> float:
        return (len(self.points) - 1) * self.step

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position (2,) and unit tangent (2,) at arc length s (clamped)."""
        s = min(max(s, 0.0), self.length)
        f = s / self.step
        i = min(int(f), len(self.points) - 2)
        t = f - i
        p = self.points[i] * (1 - t) + self.points[i + 1] * t
        d = self.points[i + 1] - self.points[i]
        return p, d / (np.linalg.norm(d) + 1e-12)


@dataclass
class Junction:
    """Road ``a`` at arc length ``sa`` meets road ``b`` at arc length ``sb``."""

    a: int
    sa: float
    b: int
    sb: float


class World:
    """The map, its metric frame, roads, junctions and occluders of a scene."""

    def __init__(self, rng: np.random.Generator, *, n_trees: int = 10, overpass: bool = True) -> None:
        self.geomap = GeoMap(TILE, option="bundled tile")
        gray = self.geomap.read_image()[..., 0]
        self.image = colourise(gray)
        self.height, self.width = gray.shape
        self.mx, self.my = self._axis_scales()
        self.roads = self._load_roads()
        self.junctions = self._find_junctions()
        self.occ_mask = np.zeros((self.height, self.width), np.uint8)  # 255 = occluded (map px)
        self.occ_layer = np.zeros_like(self.image)
        self.occluders: list[dict] = []
        self._place_trees(rng, n_trees)
        if overpass:
            self._place_overpass(rng)

    # -- geometry -------------------------------------------------------------------------------
    def _axis_scales(self) -> tuple[float, float]:
        from pyproj import Geod

        geod = Geod(ellps="WGS84")
        c = np.array([[self.width / 2, self.height / 2]])
        ll = self.geomap.pixel_to_lonlat(np.vstack([c, c + [1, 0], c + [0, 1]]))
        _, _, dx = geod.inv(ll[0, 0], ll[0, 1], ll[1, 0], ll[1, 1])
        _, _, dy = geod.inv(ll[0, 0], ll[0, 1], ll[2, 0], ll[2, 1])
        return float(dx), float(dy)

    def to_map(self, m: np.ndarray) -> np.ndarray:
        """Metric plane (N, 2) -> map pixels (N, 2)."""
        return np.asarray(m, dtype=np.float64) / np.array([self.mx, self.my])

    def to_metric(self, px: np.ndarray) -> np.ndarray:
        return np.asarray(px, dtype=np.float64) * np.array([self.mx, self.my])

    @property
    def A(self) -> np.ndarray:
        """3x3 metric plane -> map pixels."""
        return np.diag([1 / self.mx, 1 / self.my, 1.0])

    def _load_roads(self, step: float = 0.5) -> list[Road]:
        data = json.loads(ROADS.read_text())
        roads = []
        for f in data["features"]:
            ll = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)[:, :2]
            m = self.to_metric(self.geomap.lonlat_to_pixel(ll))
            seg = np.linalg.norm(np.diff(m, axis=0), axis=1)
            s = np.concatenate([[0], np.cumsum(seg)])
            if s[-1] < 10:
                continue
            q = np.arange(0, s[-1], step)
            pts = np.column_stack([np.interp(q, s, m[:, 0]), np.interp(q, s, m[:, 1])])
            lanes = int(f["properties"].get("lane_number") or 1)
            roads.append(Road(pts, lanes, step))
        return roads

    def _find_junctions(self, reach: float = 9.0) -> list[Junction]:
        """Places where two roads come within ``reach`` metres (ends and crossings)."""
        out = []
        for a, ra in enumerate(self.roads):
            for b, rb in enumerate(self.roads):
                if a == b:
                    continue
                d = np.linalg.norm(ra.points[:, None, :] - rb.points[None, :, :], axis=2)
                close = d < reach
                if not close.any():
                    continue
                # one junction per connected run of close points: take the closest pair
                ia, ib = np.unravel_index(np.argmin(np.where(close, d, np.inf)), d.shape)
                out.append(Junction(a, ia * ra.step, b, ib * rb.step))
        return out

    # -- occluders ------------------------------------------------------------------------------
    def _road_point(self, rng: np.random.Generator, margin: float = 25.0) -> np.ndarray:
        for _ in range(100):
            r = self.roads[rng.integers(len(self.roads))]
            if r.length < 2 * margin:
                continue
            p, _ = r.at(rng.uniform(margin, r.length - margin))
            px = self.to_map(p[None])[0]
            if 40 < px[0] < self.width - 40 and 40 < px[1] < self.height - 40:
                return p
        return self.roads[0].at(self.roads[0].length / 2)[0]

    def _place_trees(self, rng: np.random.Generator, n: int) -> None:
        """Tree canopies over roads: clusters of textured green discs (radius 3-6 m)."""
        for _ in range(n):
            centre = self._road_point(rng) + rng.normal(0, 1.5, 2)
            poly_mask = np.zeros_like(self.occ_mask)
            for _ in range(rng.integers(2, 5)):
                c = centre + rng.normal(0, 2.5, 2)
                rad = rng.uniform(3.0, 6.0)
                ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
                wob = rad * (1 + 0.12 * rng.standard_normal(24))
                pts = c + np.column_stack([np.cos(ang) * wob, np.sin(ang) * wob])
                cv2.fillPoly(poly_mask, [np.round((self.to_map(pts) - 0.5) * 8).astype(np.int32)], 255,
                             lineType=cv2.LINE_AA, shift=3)
            texture = rng.normal(0, 1, (self.height, self.width)).astype(np.float32)
            texture = cv2.GaussianBlur(texture, (0, 0), 1.6)
            shade = np.clip(0.75 + 0.5 * texture, 0.3, 1.3)
            colour = np.array([38, 78, 52], np.float32) * rng.uniform(0.8, 1.2)
            layer = np.clip(colour[None, None, :] * shade[..., None], 0, 255).astype(np.uint8)
            sel = poly_mask > 127
            self.occ_layer[sel] = layer[sel]
            self.occ_mask = np.maximum(self.occ_mask, poly_mask)
            ys, xs = np.nonzero(sel)
            if len(xs):
                self.occluders.append({"kind": "tree", "x0": float(xs.min()), "y0": float(ys.min()),
                                       "x1": float(xs.max() + 1), "y1": float(ys.max() + 1),
                                       "polygons": _outline(sel)})

    def _place_overpass(self, rng: np.random.Generator, width_m: float = 22.0) -> None:
        """A concrete deck 22 m wide crossing the longest road (counting only its length at least
        50 m inside the tile) at right angles."""
        W, H = self.width * self.mx, self.height * self.my

        def inner_length(r: Road) -> float:
            # roads hugging the tile's edge make a deck the camera can hardly see: count only the
            # length at least 50 m inside the tile
            pts = np.array([r.at(s)[0] for s in np.linspace(0, r.length, 41)])
            inside = (np.minimum(pts, [W, H] - pts).min(axis=1) > 50.0).mean()
            return r.length * inside

        self.overpass_road = max(range(len(self.roads)), key=lambda i: inner_length(self.roads[i]))
        road = self.roads[self.overpass_road]
        p, t = road.at(road.length * rng.uniform(0.35, 0.65))
        n = np.array([-t[1], t[0]])
        half_len = 60.0
        corners = np.array([p - n * half_len - t * width_m / 2, p + n * half_len - t * width_m / 2,
                            p + n * half_len + t * width_m / 2, p - n * half_len + t * width_m / 2])
        mask = np.zeros_like(self.occ_mask)
        cv2.fillPoly(mask, [np.round((self.to_map(corners) - 0.5) * 8).astype(np.int32)], 255,
                     lineType=cv2.LINE_AA, shift=3)
        noise = cv2.GaussianBlur(rng.normal(0, 1, mask.shape).astype(np.float32), (0, 0), 1.0)
        deck = np.clip(150 + 10 * noise, 0, 255)
        layer = np.stack([deck * 0.98, deck, deck * 1.02], axis=-1).astype(np.uint8)
        # parapets: darker edges along the deck's long sides
        for s in (-1, 1):
            a = p + s * t * (width_m / 2 - 0.6)
            line = np.array([a - n * half_len, a + n * half_len])
            cv2.line(layer, *[tuple(int(v) for v in q) for q in np.round(self.to_map(line) - 0.5)],
                     (90, 92, 95), 2)
        sel = mask > 127
        self.occ_layer[sel] = layer[sel]
        self.occ_mask = np.maximum(self.occ_mask, mask)
        ys, xs = np.nonzero(sel)
        self.occluders.append({"kind": "overpass", "x0": float(xs.min()), "y0": float(ys.min()),
                               "x1": float(xs.max() + 1), "y1": float(ys.max() + 1),
                               "polygons": _outline(sel)})

    def occluded(self, map_px: np.ndarray) -> np.ndarray:
        """Boolean (N,): is the map point under an occluder."""
        p = np.floor(np.asarray(map_px, dtype=np.float64)).astype(np.int64).reshape(-1, 2)
        ok = (p[:, 0] >= 0) & (p[:, 0] < self.width) & (p[:, 1] >= 0) & (p[:, 1] < self.height)
        out = np.zeros(len(p), bool)
        out[ok] = self.occ_mask[p[ok, 1], p[ok, 0]] > 127
        return out

    def distance_to_occluder_m(self, map_px: np.ndarray) -> np.ndarray:
        """Metres from each map point to the nearest occluder pixel (0 under one)."""
        if not hasattr(self, "_occ_dist"):
            free = (self.occ_mask <= 127).astype(np.uint8)
            self._occ_dist = cv2.distanceTransform(free, cv2.DIST_L2, 5) * math.sqrt(self.mx * self.my)
        p = np.clip(np.floor(np.asarray(map_px)).astype(np.int64).reshape(-1, 2),
                    0, [self.width - 1, self.height - 1])
        return self._occ_dist[p[:, 1], p[:, 0]]


def _outline(sel: np.ndarray) -> list[np.ndarray]:
    """Outer outlines of a boolean (H, W) map-pixel mask, as (K, 2) float64 polygons in continuous
    map pixels (col, row).

    Each outline joins the centres of the mask's boundary pixels (pixel [r, c] covers
    [c, c+1) x [r, r+1), centre (c + 0.5, r + 0.5)), so point-in-polygon on it agrees with the mask
    (which decides the ``occluded`` state) except within half a pixel of the edge.
    """
    contours, _ = cv2.findContours(sel.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return [c.reshape(-1, 2).astype(np.float64) + 0.5 for c in contours if len(c) >= 3]

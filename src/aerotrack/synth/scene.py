"""Vehicles, the UAV camera and the renderer of a generated scene, with exact ground truth.

Definitions shared with every checker (the CLI contract): a target is **visible** when its box centre
is in the frame, at least half its box is inside the frame, and it is not under an occluder; its box
is the axis-aligned bounds of its projected footprint (without shadow).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputError
from ..types import Frame
from .world import World

#: Scenario name -> settings. Each changes what the scene stresses; all share the same world.
SCENARIOS: dict[str, dict] = {
    "default": {"n_vehicles": 22, "convoys": 3, "n_trees": 10, "camera": "survey", "stop_prob": 0.25},
    "static": {"n_vehicles": 20, "convoys": 2, "n_trees": 8, "camera": "static", "stop_prob": 0.25},
    "occlusion": {"n_vehicles": 14, "convoys": 2, "n_trees": 18, "camera": "hover", "stop_prob": 0.2,
                      "speed": (5.0, 9.0)},
    "exits": {"n_vehicles": 14, "convoys": 1, "n_trees": 6, "camera": "pan", "stop_prob": 0.15},
    "convoy": {"n_vehicles": 18, "convoys": 5, "n_trees": 8, "camera": "survey", "stop_prob": 0.2},
    "dense": {"n_vehicles": 40, "convoys": 4, "n_trees": 10, "camera": "survey", "stop_prob": 0.3},
}

VEHICLE_TYPES = [  # kind, length range m, width range m, probability
    ("car", (4.2, 4.9), (1.7, 1.9), 0.70),
    ("suv", (4.8, 5.3), (1.9, 2.0), 0.17),
    ("van", (5.3, 6.0), (2.0, 2.1), 0.09),
    ("truck", (7.0, 9.0), (2.3, 2.5), 0.04),
]
COLOURS = np.array([  # BGR body colours, weighted towards the common white/grey/black
    [235, 235, 238], [225, 228, 230], [180, 182, 185], [150, 150, 152], [40, 40, 42],
    [25, 25, 28], [40, 40, 170], [150, 80, 30], [60, 90, 40], [90, 140, 200], [30, 150, 210],
], dtype=np.float64)
COLOUR_P = np.array([0.2, 0.12, 0.14, 0.1, 0.12, 0.08, 0.07, 0.07, 0.03, 0.04, 0.03])
SUPERSAMPLE = 8  # vehicles are drawn at this many times the resolution (Scenario._draw_vehicle)
SUN = np.array([0.9, 0.7])  # shadow offset on the ground, metres (sun in the north-west)
MAX_SWITCH_OFFSET_M = 5.0  # a junction switch further than this from the new lane is not taken
YIELD_MARGIN_M = 0.4  # lateral clearance a vehicle keeps from one ahead in its path (yield rule)
YIELD_LOOKAHEAD_S = (0.0, 0.5, 1.0, 1.5)  # where other vehicles will be, for the yield rule
YIELD_GIVE_UP_S = 4.0  # held up this long by cross traffic, a vehicle goes on (no gridlock)


@dataclass
class Vehicle:
    id: int
    kind: str
    length: float
    width: float
    colour: np.ndarray
    road: int
    s: float
    direction: int
    cruise: float
    route: np.random.Generator
    speed: float = 0.0
    stop_until: float = -1.0
    offset: np.ndarray = field(default_factory=lambda: np.zeros(2))
    heading: float | None = None
    pos: np.ndarray = field(default_factory=lambda: np.zeros(2))
    last_junction: tuple = ()
    held_s: float = 0.0  # how long it has been held up by cross traffic (Scenario._yield_limits)


def _padded(img: np.ndarray, y0: int, y1: int, x0: int, x1: int, pad: tuple) -> np.ndarray:
    """``img[y0:y1, x0:x1]`` extended by ``pad`` = (top, bottom, left, right) pixels of mirror
    image about the image's own edges."""
    crop = img[y0:y1, x0:x1]
    if not any(pad):
        return crop.copy()
    return cv2.copyMakeBorder(crop, *[max(0, int(p)) for p in pad], cv2.BORDER_REFLECT)


class Camera:
    """A UAV camera over the metric plane: centre (m), yaw (rad), ground sample distance (m/px).

    ``H_map(t)`` maps frame pixels to map pixels: map <- metric (axis scales) <- similarity
    (centre, yaw, gsd) <- a slight fixed tilt (a true homography, not an affine map).
    """

    def __init__(self, world: World, size: tuple[int, int], mode: str, rng: np.random.Generator,
                 gsd_scale: float = 1.0):
        self.world, self.size, self.mode = world, size, mode
        w, h = size
        W = world.width * world.mx
        Hm = world.height * world.my
        self.gsd0 = {"static": 0.30, "hover": 0.28, "pan": 0.26, "survey": 0.28}[mode]
        self.zoom_amp = 0.0 if mode == "static" else 0.08
        # The camera centre keeps at least 45 % of the half-diagonal from the tile's edge: the view
        # may reach past the tile, where the ground is the tile mirrored about its edge (static
        # texture, so registration still sees one plane) and vehicles never go.
        radius = 0.45 * 0.5 * math.hypot(w, h) * self.gsd0 * (1 + self.zoom_amp)
        if mode == "static":
            radius = 0.5 * math.hypot(w, h) * self.gsd0 * 1.02
        self.lo = np.array([radius, radius])
        self.hi = np.array([W - radius, Hm - radius])
        if np.any(self.hi <= self.lo):  # frame larger than the tile: stay centred
            self.lo = self.hi = np.array([W / 2, Hm / 2])
        self.phase = rng.uniform(0, 2 * np.pi, 6)
        self.tilt = rng.uniform(-1.0, 1.0, 2) * np.array([1.2e-5, 1.6e-5])
        self.yaw0 = rng.uniform(-0.3, 0.3)
        self.speed = {"hover": 2.0, "survey": 4.0, "pan": 7.0}.get(mode, 4.0)
        self.dwell = {"hover": 10.0, "survey": 4.0, "pan": 1.0}.get(mode, 4.0)
        self.route = self._waypoints(rng)
        if mode == "hover":
            # hover over the overpass, where most road occlusions happen (no extra rng draws, so
            # the other modes' scenes are unchanged)
            deck = [o for o in world.occluders if o["kind"] == "overpass"]
            if deck:
                o = deck[0]
                c = world.to_metric(np.array([[(o["x0"] + o["x1"]) / 2, (o["y0"] + o["y1"]) / 2]]))
                self.route[0] = np.clip(c[0], self.lo, self.hi)
        # flown higher or lower along the same path (``Scenario.gsd_scale``)
        self.gsd0 *= gsd_scale

    def _waypoints(self, rng: np.random.Generator) -> np.ndarray:
        """Camera centre waypoints (metric): road junctions clipped into the allowed box, so the
        camera looks at roads and sweeps across them (vehicles leave and re-enter the view)."""
        pts = []
        for j in self.world.junctions:
            p, _ = self.world.roads[j.a].at(j.sa)
            pts.append(np.clip(p, self.lo, self.hi))
        for r in self.world.roads:
            pts.append(np.clip(r.at(r.length / 2)[0], self.lo, self.hi))
        pts = np.unique(np.round(np.array(pts), 1), axis=0) if pts else np.array([(self.lo + self.hi) / 2])
        order = rng.permutation(len(pts))
        route = [pts[i] for i in order] + [np.clip(pts[order[0]] + rng.normal(0, 30, 2), self.lo, self.hi)]
        return np.array(route)

    def params(self, t: float) -> tuple[np.ndarray, float, float]:
        """Camera centre (metric), yaw (rad) and ground sample distance (m/px) at time t."""
        p = self.phase
        mid = (self.lo + self.hi) / 2
        if self.mode == "static":
            return mid, 0.0, self.gsd0
        if self.mode == "hover":
            amp = (self.hi - self.lo) / 2 * 0.2
            c = np.clip(self.route[0], self.lo + amp, self.hi - amp) + amp * np.array(
                [math.sin(2 * math.pi * t / 60.0 + p[0]), math.sin(2 * math.pi * t / 47.0 + p[1])])
        else:
            c = self._along_route(t)
        yaw = self.yaw0 + 0.35 * math.sin(2 * math.pi * t / 45.0 + p[2])
        gsd = self.gsd0 * (1 + self.zoom_amp * math.sin(2 * math.pi * t / 31.0 + p[3]))
        return c, yaw, gsd

    def _along_route(self, t: float) -> np.ndarray:
        """Smooth (cosine-eased) flight from waypoint to waypoint at ``self.speed`` m/s, pausing
        ``self.dwell`` s over each."""
        route = self.route
        legs = np.linalg.norm(np.diff(np.vstack([route, route[:1]]), axis=0), axis=1)
        durs = legs / self.speed + self.dwell
        total = durs.sum()
        tt = t % total
        i = int(np.searchsorted(np.cumsum(durs), tt, side="right"))
        i = min(i, len(route) - 1)
        t0 = tt - (np.cumsum(durs)[i - 1] if i else 0.0)
        a, b = route[i], route[(i + 1) % len(route)]
        move = max(durs[i] - self.dwell, 1e-6)
        u = float(np.clip((t0 - self.dwell) / move, 0, 1))
        u = 0.5 - 0.5 * math.cos(math.pi * u)
        return a + (b - a) * u

    def H_map(self, t: float) -> np.ndarray:
        """3x3: frame pixels -> map pixels at time t."""
        c, yaw, gsd = self.params(t)
        w, h = self.size
        ca, sa = math.cos(yaw), math.sin(yaw)
        S = np.array([[gsd * ca, -gsd * sa, 0], [gsd * sa, gsd * ca, 0], [0, 0, 1.0]])
        T = np.array([[1, 0, c[0]], [0, 1, c[1]], [0, 0, 1.0]])
        C = np.array([[1, 0, -w / 2], [0, 1, -h / 2], [0, 0, 1.0]])
        P = np.array([[1, 0, 0], [0, 1, 0], [self.tilt[0], self.tilt[1], 1.0]])
        # tilt about the image centre so the centre keeps its place
        Pc = np.linalg.inv(C) @ P @ C
        Pc /= Pc[2, 2]
        H = self.world.A @ T @ S @ C @ Pc
        return H / H[2, 2]


class Scenario:
    """A generated scene: iterate ``frames()`` for (Frame, Truth) pairs, streamed.

    Parameters
    ----------
    seed : int
    frames : int
        Number of frames.
    size : (int, int)
        Frame (width, height) in pixels.
    fps : float
    name : str
        One of :data:`SCENARIOS`.
    gsd_scale : float
        The camera's ground sample distance times this: 2 flies the same path twice as high
        (vehicles half as long in pixels, four times the ground in view), 0.5 half as high. The
        scene (vehicles, routes, camera path) is the same at every value.
    """

    def __init__(self, seed: int = 0, frames: int = 900, size: tuple[int, int] = (640, 480),
                 fps: float = 30.0, name: str = "default", gsd_scale: float = 1.0) -> None:
        self.validate(frames=frames, size=size, fps=fps, name=name, gsd_scale=gsd_scale)
        self.seed, self.n_frames, self.size, self.fps, self.name = seed, frames, size, fps, name
        self.gsd_scale = float(gsd_scale)
        self.settings = dict(SCENARIOS[name])
        rng = np.random.default_rng(seed)
        self.world = World(rng, n_trees=self.settings["n_trees"])
        self.camera = Camera(self.world, size, self.settings["camera"], rng, gsd_scale)
        self.vehicles = self._spawn(rng)
        self._rng = rng
        h, w = size[1], size[0]
        noise = np.round(rng.normal(0, 2.5, (h + 64, w + 64, 3)))
        # sensor noise as its positive and negative parts, added/subtracted with saturation
        self._noise_pos = np.clip(noise, 0, 255).astype(np.uint8)
        self._noise_neg = np.clip(-noise, 0, 255).astype(np.uint8)
        self._occ_over: np.ndarray | None = None
        self._occ_keep: np.ndarray | None = None
        self._gain_phase = rng.uniform(0, 2 * np.pi)

    @staticmethod
    def validate(*, frames: int, size: tuple[int, int], fps: float, name: str,
                 gsd_scale: float = 1.0) -> None:
        """Raise InputError for settings no scene can have."""
        if not (math.isfinite(gsd_scale) and 0.125 <= gsd_scale <= 8.0):
            raise InputError(f"--gsd-scale {gsd_scale}: must be between 0.125 and 8")
        if name not in SCENARIOS:
            raise InputError(f"--scenario {name!r}: unknown (valid: {', '.join(SCENARIOS)})")
        if frames < 1:
            raise InputError(f"--frames {frames}: must be at least 1")
        if size[0] < 64 or size[1] < 48 or size[0] > 8192 or size[1] > 8192:
            raise InputError(f"--size {size[0]}x{size[1]}: must be between 64x48 and 8192x8192")
        if not (0.5 <= fps <= 1000 and math.isfinite(fps)):
            raise InputError(f"--fps {fps}: must be between 0.5 and 1000 frames/s")

    # -- vehicles ---------------------------------------------------------------------------------
    def _spawn(self, rng: np.random.Generator) -> list[Vehicle]:
        n = self.settings["n_vehicles"]
        speed = self.settings.get("speed", (6.0, 12.0))
        roads = self.world.roads
        weights = np.array([r.length for r in roads])
        if self.settings["camera"] == "hover":
            # the hovering camera watches the overpass: put traffic on its road
            weights[getattr(self.world, "overpass_road", int(np.argmax(weights)))] *= 6.0
        out: list[Vehicle] = []
        vid = 1
        convoys = self.settings["convoys"]
        while len(out) < n:
            size = min(3, n - len(out)) if convoys > 0 else 1
            convoys -= 1 if size > 1 else 0
            road = int(rng.choice(len(roads), p=weights / weights.sum()))
            r = roads[road]
            direction = int(rng.choice([-1, 1]))
            s0 = rng.uniform(0.15, 0.85) * r.length
            route_seed = int(rng.integers(2**31))
            cruise = rng.uniform(*speed)
            for k in range(size):
                kinds = [v[0] for v in VEHICLE_TYPES]
                ki = int(rng.choice(len(kinds), p=[v[3] for v in VEHICLE_TYPES]))
                _, lr, wr, _ = VEHICLE_TYPES[ki]
                colour = COLOURS[rng.choice(len(COLOURS), p=COLOUR_P / COLOUR_P.sum())]
                colour = np.clip(colour * rng.uniform(0.9, 1.08), 0, 255)
                s = s0 - direction * k * rng.uniform(10.0, 14.0)
                if not (2.0 < s < r.length - 2.0):
                    continue
                if any(v.road == road and abs(v.s - s) < 9 for v in out):
                    continue
                out.append(Vehicle(
                    id=vid, kind=kinds[ki], length=rng.uniform(*lr), width=rng.uniform(*wr),
                    colour=colour, road=road, s=s, direction=direction,
                    cruise=cruise if size > 1 else rng.uniform(*speed),
                    route=np.random.default_rng(route_seed), speed=cruise * 0.8))
                vid += 1
        for v in out:
            self._place(v, 0.0, init=True)
        return out

    def _place(self, v: Vehicle, dt: float, init: bool = False) -> None:
        r = self.world.roads[v.road]
        p, tan = r.at(v.s)
        d = tan * v.direction
        target = math.atan2(d[1], d[0])
        if init or v.heading is None:
            v.heading = target
        else:
            diff = (target - v.heading + math.pi) % (2 * math.pi) - math.pi
            step = math.radians(150) * dt
            v.heading += float(np.clip(diff, -step, step))
            # the offset from the lane (after a junction or a U-turn) fades in about 0.6 s, at
            # a lateral speed of at most half the vehicle's speed + 0.5 m/s
            shrink = float(np.hypot(*v.offset)) * (1.0 - math.exp(-dt / 0.6))
            cap = (0.5 * v.speed + 0.5) * dt
            if shrink > 0:
                v.offset = v.offset * (1.0 - min(shrink, cap) / float(np.hypot(*v.offset)))
        # the lane is to the right of where the vehicle heads (not of the centre-line's tangent),
        # so a sharp bend of the centre-line or a U-turn swings the vehicle round instead of
        # moving it across the road in one frame
        right = np.array([-math.sin(v.heading), math.cos(v.heading)])
        v.pos = p + right * (1.8 if r.lanes > 1 else 1.4) + v.offset

    def _yield_limits(self) -> np.ndarray:
        """Speed limit of every vehicle from the vehicles in its path, on any road (m/s).

        Car following (below) only sees the vehicle ahead in the same lane of the same road, so
        vehicles turning at a junction, merging onto a road or crossing it drove through each
        other: on default:1, 6.2% of visible vehicle-frames had footprints overlapping another's
        (half the detector's "merged with a neighbour" misses were such pairs, which no camera
        can see apart). Here a vehicle slows for any vehicle whose footprint lies ahead of it in
        its corridor (its width plus ``YIELD_MARGIN_M`` each side, along its heading), with the
        car-following law on the gap between them. When two vehicles are in each other's
        corridors (crossing paths) the lower id goes first; a vehicle held by cross traffic for
        ``YIELD_GIVE_UP_S`` goes on (at its own lane's car-following limit, ignoring cross traffic
        until its path is clear), so that a cycle of waits cannot stop the scene.
        """
        vs = self.vehicles
        n = len(vs)
        limit = np.full(n, np.inf)
        if n < 2:
            return limit
        P = np.array([v.pos for v in vs], float)
        th = np.array([v.heading if v.heading is not None else 0.0 for v in vs], float)
        L = np.array([v.length for v in vs], float)
        Wd = np.array([v.width for v in vs], float)
        ids = np.array([v.id for v in vs])
        h = np.column_stack([np.cos(th), np.sin(th)])
        nrm = np.column_stack([-np.sin(th), np.cos(th)])
        vel = h * np.array([v.speed for v in vs], float)[:, None]
        rel = th[None, :] - th[:, None]
        c, s_ = np.abs(np.cos(rel)), np.abs(np.sin(rel))
        ext_long = 0.5 * (L[None, :] * c + Wd[None, :] * s_)  # j's half extent along i's heading
        ext_lat = 0.5 * (L[None, :] * s_ + Wd[None, :] * c)
        ahead = np.zeros((n, n), bool)
        gap = np.full((n, n), np.inf)
        # where each other vehicle is now and will be shortly: crossing traffic is seen before it
        # is in front (braking at 4 m/s^2 needs the warning)
        for tau in YIELD_LOOKAHEAD_S:
            D = (P + vel * tau)[None, :, :] - P[:, None, :]  # D[i, j] = pos_j(t + tau) - pos_i
            fwd = np.einsum("ijk,ik->ij", D, h)
            lat = np.einsum("ijk,ik->ij", D, nrm)
            g = fwd - L[:, None] / 2 - ext_long
            a = (fwd > 0) & (np.abs(lat) < Wd[:, None] / 2 + ext_lat + YIELD_MARGIN_M) & (g < 30.0)
            ahead |= a
            gap = np.where(a, np.minimum(gap, g), gap)
        np.fill_diagonal(ahead, False)
        mutual = ahead & ahead.T
        ahead &= ~(mutual & (ids[:, None] < ids[None, :]))  # crossing: the lower id goes first
        for i in np.flatnonzero(ahead.any(axis=1)):
            g = float(gap[i, ahead[i]].min())
            limit[i] = max(0.0, (g - 3.0) / 1.1)
        return limit

    def _advance(self, t: float, dt: float) -> None:
        world, roads = self.world, self.world.roads
        cross = self._yield_limits()
        for i, v in enumerate(self.vehicles):
            # car following: slow down behind the nearest vehicle ahead in the same lane
            limit = v.cruise
            for u in self.vehicles:
                if u is v or u.road != v.road or u.direction != v.direction:
                    continue
                gap = (u.s - v.s) * v.direction - (u.length + v.length) / 2
                if 0 <= gap < 30:
                    limit = min(limit, max(0.0, (gap - 3.0) / 1.1))
            # and for anything else in its path (junctions, merges, crossing traffic)
            if cross[i] < limit and v.held_s < YIELD_GIVE_UP_S:
                limit = float(cross[i])
                v.held_s = v.held_s + dt if limit < 0.5 else 0.0
            elif cross[i] >= 0.5:
                v.held_s = 0.0
            if t < v.stop_until:
                limit = 0.0
            # brake for the end of the road (a junction or a dead end: U-turn) so speed stays
            # continuous: at most 3 m/s^2 down to a walking-pace turn
            r = roads[v.road]
            to_end = r.length - v.s if v.direction > 0 else v.s
            limit = min(limit, 3.0 + math.sqrt(2.0 * 3.0 * max(to_end, 0.0)))
            acc = 2.5 if limit > v.speed else -4.0
            v.speed = float(np.clip(v.speed + acc * dt, min(limit, v.speed), max(limit, v.speed)))
            s_prev = v.s
            v.s += v.direction * v.speed * dt
            r = roads[v.road]
            switched = False
            if v.last_junction and abs(v.s - v.last_junction[2]) > 15:
                v.last_junction = ()
            for j in world.junctions:
                if j.a != v.road or (j.b, round(j.sb)) == v.last_junction[:2]:
                    continue
                crossed = (s_prev - j.sa) * (v.s - j.sa) <= 0 and s_prev != v.s
                at_end = v.s <= 0 or v.s >= r.length
                near_end = abs(j.sa - (0 if v.direction < 0 else r.length)) < 10
                if not (crossed or (at_end and near_end)):
                    continue
                if v.route.random() < (0.4 if not near_end else 0.9):
                    rb = roads[j.b]
                    room = {1: rb.length - j.sb, -1: j.sb}
                    dirs = [d for d in (1, -1) if room[d] > 15]
                    if dirs:
                        old = v.pos.copy()
                        keep = (v.road, v.s, v.direction, v.last_junction, v.offset.copy())
                        v.road, v.s = j.b, j.sb
                        v.direction = int(v.route.choice(dirs))
                        v.last_junction = (j.a, round(j.sa), j.sb)
                        self._place(v, 0.0, init=False)
                        v.offset = old - (v.pos - v.offset)
                        switched = True
                        if np.hypot(*v.offset) > MAX_SWITCH_OFFSET_M:
                            # the new road's lane is too far from where the vehicle is (a
                            # junction matched near a road's end): stay on this road
                            v.road, v.s, v.direction, v.last_junction, v.offset = keep
                            v.pos = old
                            switched = False
                if v.route.random() < self.settings["stop_prob"] * 0.3:
                    v.stop_until = t + v.route.uniform(2.0, 6.0)
                break
            r = roads[v.road]
            if not switched and (v.s <= 0 or v.s >= r.length):  # dead end: U-turn
                v.s = float(np.clip(v.s, 0.0, r.length))
                v.direction *= -1
                v.speed = min(v.speed, 3.0)
                v.last_junction = ()
            self._place(v, dt)

    def footprint(self, v: Vehicle) -> np.ndarray:
        """(4, 2) corners of the vehicle in the metric plane."""
        c, s = math.cos(v.heading), math.sin(v.heading)
        f, r = np.array([c, s]), np.array([-s, c])
        hl, hw = v.length / 2, v.width / 2
        return np.array([v.pos + f * hl + r * hw, v.pos + f * hl - r * hw,
                         v.pos - f * hl - r * hw, v.pos - f * hl + r * hw])

    # -- truth ------------------------------------------------------------------------------------
    def truth(self, index: int, H: np.ndarray) -> list[dict]:
        """Per-vehicle ground truth of one frame (every vehicle, visible or not)."""
        w, h = self.size
        Hinv = np.linalg.inv(H)
        out = []
        for v in self.vehicles:
            corners_map = self.world.to_map(self.footprint(v))
            centre_map = self.world.to_map(v.pos[None])[0]
            pts = np.hstack([corners_map, np.ones((4, 1))]) @ Hinv.T
            fr = pts[:, :2] / pts[:, 2:]
            x0, y0 = fr.min(axis=0)
            x1, y1 = fr.max(axis=0)
            box = np.array([x0, y0, x1 - x0, y1 - y0])
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            ix = max(0.0, min(x1, w) - max(x0, 0.0)) * max(0.0, min(y1, h) - max(y0, 0.0))
            inside = 0 <= cx < w and 0 <= cy < h and ix >= 0.5 * box[2] * box[3]
            occluded = bool(self.world.occluded(centre_map[None])[0])
            state = "outside" if not inside else ("occluded" if occluded else "visible")
            out.append({"frame": index, "id": v.id, "state": state, "map": centre_map,
                        "box": box, "heading": math.degrees(v.heading) % 360.0,
                        "speed": v.speed, "occ_dist_m":
                        float(self.world.distance_to_occluder_m(centre_map[None])[0])})
        return out

    # -- rendering --------------------------------------------------------------------------------
    def render(self, t: float, H: np.ndarray) -> np.ndarray:
        """The BGR uint8 frame seen through homography H (frame -> map pixels) at time t."""
        w, h = self.size
        world = self.world
        corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
        hc = np.hstack([corners, np.ones((4, 1))]) @ H.T
        mc = hc[:, :2] / hc[:, 2:]
        # The crop of the map under the frame; where the view reaches past the tile, the ground is
        # the tile mirrored about its edge (static texture). Vehicles are drawn after padding so
        # they are never mirrored.
        x0 = int(np.floor(mc[:, 0].min()) - 4)
        y0 = int(np.floor(mc[:, 1].min()) - 4)
        x1 = int(np.ceil(mc[:, 0].max()) + 4)
        y1 = int(np.ceil(mc[:, 1].max()) + 4)
        cx0, cy0 = min(max(x0, 0), world.width - 1), min(max(y0, 0), world.height - 1)
        cx1, cy1 = max(min(x1, world.width), cx0 + 1), max(min(y1, world.height), cy0 + 1)
        pad = (cy0 - y0, y1 - cy1, cx0 - x0, x1 - cx1)
        canvas = _padded(world.image, cy0, cy1, cx0, cx1, pad)
        origin = np.array([x0, y0], float)
        shadow = np.zeros(canvas.shape[:2], np.uint8)
        bodies = []
        for v in self.vehicles:
            fp = world.to_map(self.footprint(v)) - origin - 0.5  # OpenCV pixel centres
            if fp[:, 0].max() < -5 or fp[:, 1].max() < -5 or fp[:, 0].min() > x1 - x0 + 5 \
                    or fp[:, 1].min() > y1 - y0 + 5:
                continue
            sh = world.to_map(self.footprint(v) + SUN) - origin - 0.5
            cv2.fillConvexPoly(shadow, np.round(sh * 8).astype(np.int32), 255, cv2.LINE_AA, 3)
            bodies.append((v, fp))
        # Integer OpenCV arithmetic on the crop (float numpy here cost most of the render time).
        if bodies:
            soft = cv2.GaussianBlur(shadow, (0, 0), 1.2)
            keep = cv2.cvtColor(255 - (soft >> 1), cv2.COLOR_GRAY2BGR)  # 1 - 0.5 * shadow
            canvas = cv2.multiply(canvas, keep, scale=1.0 / 255.0)
        for v, fp in bodies:
            self._draw_vehicle(canvas, v, fp)
        if world.occ_mask[cy0:cy1, cx0:cx1].any() or any(pad):
            if self._occ_over is None:
                a = world.occ_mask.astype(np.float32)[..., None] / 255.0
                self._occ_over = np.round(world.occ_layer * a).astype(np.uint8)  # premultiplied
                self._occ_keep = cv2.cvtColor(255 - world.occ_mask, cv2.COLOR_GRAY2BGR)
            keep = _padded(self._occ_keep, cy0, cy1, cx0, cx1, pad)
            over = _padded(self._occ_over, cy0, cy1, cx0, cx1, pad)
            canvas = cv2.add(cv2.multiply(canvas, keep, scale=1.0 / 255.0), over)
        # H maps continuous frame pixels to map pixels in the rasters' convention (pixel [r, c]
        # covers [c, c+1) x [r, r+1), as detector boxes and GeoTIFF transforms count them);
        # OpenCV puts pixel centres at integers: frame index i is the point i + 0.5, and map point
        # m is canvas index m - 0.5 - origin.
        shift = np.array([[1, 0, -x0 - 0.5], [0, 1, -y0 - 0.5], [0, 0, 1.0]])
        half = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
        M = np.linalg.inv(shift @ H @ half)
        frame = cv2.warpPerspective(canvas, M, (w, h), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REPLICATE)
        gain = 1.0 + 0.06 * math.sin(2 * math.pi * t / 17.0 + self._gain_phase)
        ox, oy = self._rng.integers(0, 64, 2)
        frame = cv2.multiply(frame, (gain, gain, gain, 0.0))
        frame = cv2.add(frame, self._noise_pos[oy:oy + h, ox:ox + w])
        return cv2.subtract(frame, self._noise_neg[oy:oy + h, ox:ox + w])

    def _draw_vehicle(self, canvas: np.ndarray, v: Vehicle, fp: np.ndarray) -> None:
        """Draw vehicle ``v`` with footprint ``fp`` (canvas coordinates, OpenCV pixel centres) so
        that each canvas pixel gets the vehicle in the share of its area the footprint covers.

        OpenCV's polygon fill is not area-exact: it includes the outline's pixels on every side,
        and ``LINE_AA`` widens that by about half a pixel more (a 10 x 6 px rectangle drew 77 px
        without anti-aliasing, 87 px with it), so vehicles came out one to two pixels longer and
        wider than their ground-truth boxes; at 15-20 px vehicles that alone cost generated scenes
        about 0.08 HOTA (a 6 px wide vehicle matched its own box at IoU 0.6). The vehicle is
        therefore drawn without anti-aliasing at ``SUPERSAMPLE`` times the resolution in a patch
        around it, where the outline's extra pixel is 1/``SUPERSAMPLE`` px, and the patch is
        area-averaged down and blended by its coverage.
        """
        S = SUPERSAMPLE
        h, w = canvas.shape[:2]
        x0 = max(0, int(np.floor(fp[:, 0].min())) - 1)
        y0 = max(0, int(np.floor(fp[:, 1].min())) - 1)
        x1 = min(w, int(np.ceil(fp[:, 0].max())) + 2)
        y1 = min(h, int(np.ceil(fp[:, 1].max())) + 2)
        if x1 <= x0 or y1 <= y0:
            return
        # canvas pixel (r, c) covers [c - 0.5, c + 0.5) x [r - 0.5, r + 0.5) in fp's coordinates;
        # patch pixel (R, C) covers [C, C + 1) / S from the patch corner (x0 - 0.5, y0 - 0.5)
        origin = np.array([x0 - 0.5, y0 - 0.5])

        def hi(q: np.ndarray) -> np.ndarray:
            return np.round(((q - origin) * S - 0.5) * 8).astype(np.int32)

        paint = np.zeros(((y1 - y0) * S, (x1 - x0) * S, 3), np.uint8)
        cover = np.zeros(paint.shape[:2], np.uint8)
        col = tuple(float(c) for c in v.colour)
        cv2.fillConvexPoly(paint, hi(fp), col, cv2.LINE_8, 3)
        cv2.fillConvexPoly(cover, hi(fp), 255, cv2.LINE_8, 3)
        # windscreen (dark band behind the bonnet) and roof highlight, in footprint coordinates
        f0, f1, b1, b0 = fp  # front-right, front-left, back-left, back-right

        def lerp(a, b, u):
            return a + (b - a) * u

        def quad(u0, u1, inset):
            fr = lerp(f0, b0, u0)
            fl = lerp(f1, b1, u0)
            br = lerp(f0, b0, u1)
            bl = lerp(f1, b1, u1)
            return hi(np.array([lerp(fr, fl, inset), lerp(fl, fr, inset), lerp(bl, br, inset),
                                lerp(br, bl, inset)]))

        dark = tuple(float(c) * 0.25 + 10 for c in v.colour)
        cv2.fillConvexPoly(paint, quad(0.22, 0.38, 0.1), dark, cv2.LINE_8, 3)
        light = tuple(min(255.0, float(c) * 1.08 + 8) for c in v.colour)
        cv2.fillConvexPoly(paint, quad(0.42, 0.75, 0.15), light, cv2.LINE_8, 3)
        if v.kind in ("truck", "van"):
            cv2.fillConvexPoly(paint, quad(0.45, 0.98, 0.05), tuple(c * 0.92 for c in light),
                               cv2.LINE_8, 3)
        size = (x1 - x0, y1 - y0)
        # paint is 0 outside the footprint: its area mean is already premultiplied by coverage
        over = cv2.resize(paint, size, interpolation=cv2.INTER_AREA)
        a = cv2.resize(cover, size, interpolation=cv2.INTER_AREA)
        keep = cv2.cvtColor(255 - a, cv2.COLOR_GRAY2BGR)
        roi = canvas[y0:y1, x0:x1]
        roi[:] = cv2.add(cv2.multiply(roi, keep, scale=1.0 / 255.0), over)

    # -- streaming ----------------------------------------------------------------------------------
    def frames(self) -> Iterator[tuple[Frame, np.ndarray, list[dict]]]:
        """Yield (Frame, H frame->map pixels, per-vehicle truth) for every frame, streamed."""
        dt = 1.0 / self.fps
        for index in range(1, self.n_frames + 1):
            t = (index - 1) * dt
            if index > 1:
                self._advance(t, dt)
            H = self.camera.H_map(t)
            truth = self.truth(index, H)
            yield Frame(index=index, image=self.render(t, H), time=t), H, truth

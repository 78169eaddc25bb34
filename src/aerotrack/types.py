"""Data types that flow between the stages.

Coordinate frames named throughout:

* **frame pixels**: pixels of the frame the object was seen in; continuous, origin at the top-left
  corner of the top-left pixel (pixel [r, c] covers [c, c+1) x [r, r+1)).
* **reference pixels**: pixels of frame 1, used when no map is given.
* **map pixels**: (col, row) of the map raster, same convention as its affine transform.
* **map CRS**: the raster's coordinate reference system (east/north or lon/lat order).
* **lon/lat**: WGS 84 degrees, x = longitude, y = latitude.

"World" coordinates in this package mean map pixels when a map is given and reference pixels
otherwise; ``metres_per_unit`` converts them to metres where known.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One decoded video frame.

    Attributes
    ----------
    index : int
        1-based frame number (the n-th decoded frame / n-th image file).
    image : ndarray, shape (H, W, 3), uint8
        BGR pixels (OpenCV order).
    time : float
        Seconds since frame 1, ``(index - 1) / fps``.
    """

    index: int
    image: np.ndarray
    time: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape[:2]


@dataclass(frozen=True)
class Failure:
    """A failed estimate: falsy, carries the reason (scikit-image's ``from_estimate`` idiom)."""

    reason: str

    def __bool__(self) -> bool:
        return False


@dataclass(frozen=True)
class Registration:
    """How one frame maps to world coordinates.

    Attributes
    ----------
    index : int
        1-based frame number.
    H : ndarray, shape (3, 3), float64
        Frame pixels -> world (map pixels with a map, reference pixels without), normalised H[2,2] = 1.
    status : str
        ``ok``, ``refined`` (corrected against the map), ``carried`` (last motion carried forward after
        a failure), ``reset`` or ``reanchored``.
    inliers : int
        Inlier count of the robust estimate that produced it (0 when carried).
    inlier_ratio : float
        Inliers / tentative correspondences.
    error : float
        Median reprojection error of the inliers, in frame pixels (NaN when unknown).
    reason : str
        Why the status is not ``ok`` (empty otherwise).
    """

    index: int
    H: np.ndarray
    status: str = "ok"
    inliers: int = 0
    inlier_ratio: float = float("nan")
    error: float = float("nan")
    reason: str = ""

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Map (N, 2) frame pixels to (N, 2) world coordinates."""
        return apply_homography(self.H, points)

    def to_frame(self, points: np.ndarray) -> np.ndarray:
        """Map (N, 2) world coordinates to (N, 2) frame pixels."""
        return apply_homography(np.linalg.inv(self.H), points)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU (N, M) of (N, 4) and (M, 4) boxes ``x, y, w, h`` (any one pixel frame); 0
    where both are empty."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 0] + a[:, None, 2], b[None, :, 0] + b[None, :, 2])
    y1 = np.minimum(a[:, None, 1] + a[:, None, 3], b[None, :, 1] + b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    union = a[:, None, 2] * a[:, None, 3] + b[None, :, 2] * b[None, :, 3] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def apply_homography(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 3x3 homography to (N, 2) points; returns (N, 2) float64."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    h = np.hstack([pts, np.ones((len(pts), 1))]) @ np.asarray(H, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[:, :2] / h[:, 2:3]


def homography_jacobian(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Jacobians (N, 2, 2) of the homographies ``H`` (N, 3, 3) at ``points`` (N, 2): how a small
    step at each point maps through its homography; a single (3, 3) and (2,) give one (2, 2)."""
    if H.ndim == 2:
        return homography_jacobian(H[None], np.asarray(points)[None])[0]
    h = np.einsum("nij,nj->ni", H, np.column_stack([points, np.ones(len(points))]))
    w = h[:, 2][:, None, None]
    return (H[:, :2, :2] * w - h[:, :2, None] * H[:, 2, None, :2]) / (w * w)


def local_scale(H: np.ndarray, point: np.ndarray) -> float:
    """World units per frame pixel of ``H`` at ``point`` (square root of the Jacobian's |det|)."""
    x, y = float(point[0]), float(point[1])
    p = np.array([[x, y], [x + 1.0, y], [x, y + 1.0]])
    q = apply_homography(H, p)
    J = np.stack([q[1] - q[0], q[2] - q[0]], axis=1)
    return math.sqrt(abs(float(np.linalg.det(J))))


def local_scales(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """:func:`local_scale` at each of the (N, 2) ``points`` (frame pixels); (N,) float64, the same
    bits as one call per point (the Jacobians of all points from one homography product)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p = np.stack([pts, pts + (1.0, 0.0), pts + (0.0, 1.0)], axis=1).reshape(-1, 2)
    q = apply_homography(H, p).reshape(-1, 3, 2)
    J = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], axis=2)
    return np.sqrt(np.abs(np.linalg.det(J)))


def _check_len(name: str, arr: np.ndarray | None, n: int) -> None:
    if arr is not None and len(arr) != n:
        raise ValueError(f"Detections.{name} has {len(arr)} rows, expected {n}")


@dataclass(frozen=True)
class Detections:
    """The detections of one frame, one array per field (N rows each).

    Attributes
    ----------
    frame : int
        1-based frame number.
    boxes : ndarray, shape (N, 4), float64
        ``bb_left, bb_top, bb_width, bb_height`` in frame pixels.
    conf : ndarray, shape (N,), float64
        Confidence in [0, 1].
    world : ndarray, shape (N, 2), float64
        Ground point (box centre) in world coordinates (map pixels or reference pixels).
    mapxy : ndarray, shape (N, 2) or None
        Ground point in the map CRS (None without a map).
    lonlat : ndarray, shape (N, 2) or None
        Ground point in lon/lat degrees (None without a map).
    hist : ndarray, shape (N, B) or None
        Normalised colour histogram of each blob (appearance), rows sum to 1.
    size_world : ndarray, shape (N, 2) or None
        Box width and height in world units.
    extra : dict
        Stage-specific per-detection arrays (e.g. descriptors, patches), each with N rows.
    """

    frame: int
    boxes: np.ndarray
    conf: np.ndarray
    world: np.ndarray
    mapxy: np.ndarray | None = None
    lonlat: np.ndarray | None = None
    hist: np.ndarray | None = None
    size_world: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.boxes)
        if np.asarray(self.boxes).shape not in ((n, 4),) and n:
            raise ValueError("Detections.boxes must have shape (N, 4)")
        for name in ("conf", "world", "mapxy", "lonlat", "hist", "size_world"):
            _check_len(name, getattr(self, name), n)
        for name, arr in self.extra.items():
            _check_len(f"extra[{name!r}]", arr, n)

    def __repr__(self) -> str:
        return f"Detections(frame={self.frame}, {len(self.boxes)} boxes)"

    def __len__(self) -> int:
        return len(self.boxes)

    @property
    def centers(self) -> np.ndarray:
        """(N, 2) box centres in frame pixels (the ground point)."""
        b = np.asarray(self.boxes, dtype=np.float64).reshape(-1, 4)
        return b[:, :2] + b[:, 2:] / 2.0

    @classmethod
    def empty(cls, frame: int) -> Detections:
        return cls(frame=frame, boxes=np.zeros((0, 4)), conf=np.zeros(0), world=np.zeros((0, 2)))

    def subset(self, keep: np.ndarray) -> Detections:
        """Rows selected by a boolean mask or index array."""

        def sel(a):
            return None if a is None else np.asarray(a)[keep]

        return Detections(
            frame=self.frame,
            boxes=np.asarray(self.boxes)[keep],
            conf=np.asarray(self.conf)[keep],
            world=np.asarray(self.world)[keep],
            mapxy=sel(self.mapxy),
            lonlat=sel(self.lonlat),
            hist=sel(self.hist),
            size_world=sel(self.size_world),
            extra={k: np.asarray(v)[keep] for k, v in self.extra.items()},
        )


@dataclass
class TrackPoint:
    """One row of a track: where a target was (or is believed to be) in one frame.

    ``kind`` is ``observed`` (a detection), ``bridged`` (interpolated across a short run of missed
    detections), ``stationary`` (standing still, absorbed by the background) or ``predicted``
    (believed out of view: occluded or outside the frame).
    """

    frame: int
    box: np.ndarray  # (4,) frame pixels, bb_left, bb_top, w, h
    world: np.ndarray  # (2,) world coordinates
    conf: float
    kind: str = "observed"
    det_index: int = -1  # row in that frame's Detections, -1 if not observed
    size_world: np.ndarray | None = None  # (2,) box width, height in world units
    # appearance, left out of the repr (a track's repr was 0.5 MB, a run's 15 MB: a notebook froze)
    hist: np.ndarray | None = field(default=None, repr=False)  # (B,) colour histogram (Detections.hist row)
    desc: np.ndarray | None = field(default=None, repr=False)  # ring descriptor (Detections.extra["desc"])
    weak: bool = False  # found by multi-frame persistence: a faint box, its place but not its size


@dataclass
class Track:
    """A target's whole history under one identity.

    Attributes
    ----------
    id : int
        Identity written to ``tracks.csv`` (positive).
    points : list of TrackPoint
        Sorted by frame, at most one per frame.
    links : list of dict
        The global links that joined its tracklets across gaps (``GlobalLinker.build_tracks``),
        each ``{"lost": frame, "found": frame, "kind": ..., "cost": ..., "motion": ...,
        "appearance": ..., "descriptor": ...}``; written to ``links.csv``.
    """

    id: int
    points: list[TrackPoint] = field(default_factory=list)
    links: list[dict] = field(default_factory=list)

    def __repr__(self) -> str:
        if not self.points:
            return f"Track(id={self.id}, no points)"
        kinds: dict[str, int] = {}
        for p in self.points:
            kinds[p.kind] = kinds.get(p.kind, 0) + 1
        parts = ", ".join(f"{n} {k}" for k, n in kinds.items())
        return f"Track(id={self.id}, frames {self.first}-{self.last}, {len(self.points)} points: {parts})"

    @property
    def frames(self) -> np.ndarray:
        return np.array([p.frame for p in self.points], dtype=np.int64)

    @property
    def first(self) -> int:
        return self.points[0].frame

    @property
    def last(self) -> int:
        return self.points[-1].frame

    def world(self) -> np.ndarray:
        """(N, 2) world positions of every point."""
        return np.array([p.world for p in self.points], dtype=np.float64).reshape(-1, 2)


# A tracklet is a short track produced by local association; same structure.
Tracklet = Track

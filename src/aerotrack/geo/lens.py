"""Lens distortion: camera intrinsics and the OpenCV distortion model, applied before registration.

A wide-angle drone lens bends straight roads; a homography cannot model that, so frame-to-frame
and frame-to-map registration degrade towards the corners. Undistorting every frame first (and
every point that is given in the original frame's pixels) makes the flat-ground homography model
hold again.

Intrinsics file (``--intrinsics``), TOML or JSON with the same keys::

    # camera.toml: OpenCV pinhole model + distortion, from cv2.calibrateCamera or a vendor sheet
    width = 3840          # frame size the intrinsics were measured for, pixels
    height = 2160
    fx = 2650.0           # focal lengths, pixels
    fy = 2650.0
    cx = 1919.5           # principal point, OpenCV convention (pixel centres at integers)
    cy = 1079.5
    dist = [-0.12, 0.08, 0.0005, -0.0003, -0.02]   # k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]

``camera_matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` may replace ``fx, fy, cx, cy``, and
``dist_coeffs`` / ``distortion_coefficients`` may replace ``dist`` (the names OpenCV's calibration
samples write). The distortion vector has 4, 5, 8, 12 or 14 entries, in OpenCV's order.

Pixel conventions: OpenCV puts pixel centres at integer coordinates, aerotrack at ``+0.5``
(origin at the top-left *corner*); :class:`Undistorter` converts, so its point methods take and
return aerotrack frame pixels.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import FormatError, InputError
from ..io.textfile import read_text
from ..types import Frame

_DIST_LENGTHS = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class CameraIntrinsics:
    """A calibrated camera.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
        Camera matrix (OpenCV convention: pixel centres at integers).
    dist : ndarray, shape (D,)
        OpenCV distortion coefficients, D in (4, 5, 8, 12, 14).
    size : (int, int)
        (width, height) of the frames the calibration applies to.
    source : str
        File it came from (for messages).
    """

    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]
    source: str = "<intrinsics>"

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view of the undistorted pinhole, degrees."""
        return math.degrees(2.0 * math.atan(self.size[0] / (2.0 * float(self.K[0, 0]))))


#: Keys an intrinsics file may hold.
_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "camera_matrix", "dist", "dist_coeffs",
         "distortion_coefficients"}


def read_intrinsics(path: str | Path, *, option: str = "--intrinsics") -> CameraIntrinsics:
    """Read a TOML or JSON intrinsics file (see the module docstring).

    Raises
    ------
    InputError, FormatError
        Missing or unparsable file, a missing key, a non-numeric or non-positive value, or a
        distortion vector of the wrong length; the message names the file and the key (and the
        line for a TOML/JSON syntax error).
    """
    p = Path(path)
    label = f"{option} {p}"
    text = read_text(p, label)
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FormatError(f"{label} line {exc.lineno}: not valid JSON ({exc.msg})") from None
    else:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise FormatError(f"{label}: not valid TOML ({exc})") from None
    if not isinstance(data, dict):
        raise FormatError(f"{label}: expected a table of keys (width, height, fx, fy, cx, cy, dist)")
    return intrinsics_from_dict(data, label)


def _number(data: dict, key: str, label: str) -> float:
    if key not in data:
        raise FormatError(f"{label}: missing key {key!r}")
    v = data[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise FormatError(f"{label}: {key} must be a finite number, got {v!r}")
    return float(v)


def intrinsics_from_dict(data: dict[str, Any], label: str = "intrinsics") -> CameraIntrinsics:
    """Build :class:`CameraIntrinsics` from the keys of an intrinsics file.

    Unknown keys are refused (a misspelt ``focal`` would otherwise be ignored, as a misspelt
    ``--config`` key is not), and a principal point outside the frame or focal lengths below
    a tenth of its width (normalised intrinsics, fx = 0.78, where pixels are expected) too.
    """
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise FormatError(f"{label}: unknown key {unknown[0]!r} (valid: "
                          f"{', '.join(sorted(_KEYS))})")
    w, h = _number(data, "width", label), _number(data, "height", label)
    if not (w >= 1 and h >= 1 and w.is_integer() and h.is_integer()):
        raise FormatError(f"{label}: width and height must be positive integers")
    if "camera_matrix" in data:
        try:
            K = np.asarray(data["camera_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise FormatError(f"{label}: camera_matrix must be 3x3 numbers") from None
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise FormatError(f"{label}: camera_matrix must be 3x3 finite numbers")
    else:
        fx, fy = _number(data, "fx", label), _number(data, "fy", label)
        cx, cy = _number(data, "cx", label), _number(data, "cy", label)
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise FormatError(f"{label}: focal lengths fx, fy must be positive")
    if min(K[0, 0], K[1, 1]) < 0.1 * w or not (0 <= K[0, 2] <= w and 0 <= K[1, 2] <= h):
        raise FormatError(f"{label}: fx, fy {K[0, 0]:g}, {K[1, 1]:g} and cx, cy {K[0, 2]:g}, "
                          f"{K[1, 2]:g} are not in pixels of a {int(w)}x{int(h)} frame "
                          "(normalised intrinsics? multiply fx, cx by the width and fy, cy by "
                          "the height)")
    key = next((k for k in ("dist", "dist_coeffs", "distortion_coefficients") if k in data), None)
    if key is None:
        raise FormatError(f"{label}: missing key 'dist' (k1, k2, p1, p2[, k3 ...])")
    try:
        dist = np.asarray(data[key], dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise FormatError(f"{label}: {key} must be a list of numbers") from None
    if len(dist) not in _DIST_LENGTHS or not np.all(np.isfinite(dist)):
        raise FormatError(f"{label}: {key} must have 4, 5, 8, 12 or 14 finite numbers, "
                          f"found {len(dist)}")
    return CameraIntrinsics(K=K, dist=dist, size=(int(w), int(h)), source=label)


class Undistorter:
    """Removes lens distortion from frames and points.

    The remap tables are built once (``cv2.initUndistortRectifyMap``); each frame then costs one
    ``cv2.remap``. The output frame has the same size; its camera matrix ``K_new`` comes from
    ``cv2.getOptimalNewCameraMatrix`` with ``alpha``.

    Parameters
    ----------
    intrinsics : CameraIntrinsics
    alpha : float
        0 keeps only valid pixels (the view is cropped and slightly zoomed, no black borders, which
        registration and the background model would otherwise see as texture); 1 keeps every
        source pixel (black corners). Values between trade one for the other.
    interpolation : int
        OpenCV interpolation flag for ``remap``.
    """

    def __init__(self, intrinsics: CameraIntrinsics, *, alpha: float = 0.0,
                 interpolation: int = cv2.INTER_LINEAR) -> None:
        if not 0.0 <= alpha <= 1.0:
            raise InputError(f"undistort alpha {alpha}: must be in [0, 1]")
        self.intrinsics = intrinsics
        self.size = intrinsics.size
        self.K_new, _ = cv2.getOptimalNewCameraMatrix(intrinsics.K, intrinsics.dist, self.size,
                                                      alpha, self.size)
        self._map1, self._map2 = cv2.initUndistortRectifyMap(
            intrinsics.K, intrinsics.dist, None, self.K_new, self.size, cv2.CV_16SC2)
        self.interpolation = interpolation

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view of the undistorted frames, degrees (for telemetry)."""
        return math.degrees(2.0 * math.atan(self.size[0] / (2.0 * float(self.K_new[0, 0]))))

    def undistort_image(self, image: np.ndarray) -> np.ndarray:
        """(H, W[, C]) image in the original camera -> same-sized undistorted image."""
        h, w = image.shape[:2]
        if (w, h) != self.size:
            raise InputError(f"{self.intrinsics.source}: intrinsics are for {self.size[0]}x"
                             f"{self.size[1]} frames, got a {w}x{h} frame")
        return cv2.remap(image, self._map1, self._map2, self.interpolation,
                         borderMode=cv2.BORDER_CONSTANT)

    def __call__(self, frame: Frame) -> Frame:
        """The undistorted :class:`~aerotrack.types.Frame` (same index and time)."""
        return Frame(index=frame.index, image=self.undistort_image(frame.image), time=frame.time)

    def undistort_points(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) original frame pixels -> (N, 2) undistorted frame pixels (aerotrack convention)."""
        pts = np.asarray(points, np.float64).reshape(-1, 1, 2) - 0.5
        if len(pts) == 0:
            return np.zeros((0, 2))
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
        out = cv2.undistortPointsIter(pts, self.intrinsics.K, self.intrinsics.dist, None,
                                      self.K_new, crit)
        return out.reshape(-1, 2) + 0.5

    def distort_points(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) undistorted frame pixels -> (N, 2) original frame pixels (aerotrack convention)."""
        p = np.asarray(points, np.float64).reshape(-1, 2) - 0.5
        if len(p) == 0:
            return np.zeros((0, 2))
        Kn = self.K_new
        x = (p[:, 0] - Kn[0, 2]) / Kn[0, 0]
        y = (p[:, 1] - Kn[1, 2]) / Kn[1, 1]
        obj = np.column_stack([x, y, np.ones_like(x)]).reshape(-1, 1, 3)
        img, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.intrinsics.K,
                                   self.intrinsics.dist)
        return img.reshape(-1, 2) + 0.5

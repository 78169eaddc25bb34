"""Multi-frame persistence for small, faint movers (detection/persistence.py)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from test_detection_background import iou  # the tests folder is on sys.path

from aerotrack.config import DetectionConfig
from aerotrack.detection import MovingObjectDetector
from aerotrack.detection.persistence import (
    PersistenceTracker,
    accumulate,
    clutter_gain,
    persistent_peaks,
)
from aerotrack.errors import ConfigError
from aerotrack.types import Frame, Registration

FPS = 10.0
TARGET = (10, 8)  # w, h in frame pixels


def _scene(n: int, contrast: float, *, flicker: bool = False, seed: int = 0,
           size: tuple[int, int] = (240, 320), noise: float = 3.0):
    """Frames of a static, mildly textured ground with sensor noise and either one small target
    ``contrast`` grey levels brighter moving at 15 px/s, or (``flicker``) three such patches per
    frame at new random places. Returns (frames, true boxes or None per frame)."""
    rng = np.random.default_rng(seed)
    h, w = size
    tex = cv2.GaussianBlur(rng.normal(0.0, 1.0, (h, w)).astype(np.float32), (0, 0), 3)
    ground = 120.0 + 8.0 * tex / tex.std()
    frames, truth = [], []
    tw, th = TARGET
    for i in range(n):
        img = ground + rng.normal(0.0, noise, (h, w))
        if flicker:
            for _ in range(3):
                x, y = int(rng.integers(20, w - 30)), int(rng.integers(20, h - 30))
                img[y:y + th, x:x + tw] += contrast
            truth.append(None)
        else:
            x, y = int(round(40 + 1.5 * i)), int(round(100 + 0.5 * i))
            img[y:y + th, x:x + tw] += contrast
            truth.append((x, y, tw, th))
        g = np.clip(img, 0, 255).astype(np.uint8)
        frames.append(Frame(i + 1, cv2.merge([g, g, g]), i / FPS))
    return frames, truth


def _detect(frames, persist: bool):
    # 320x240 frames with targets of 1080p size: the 1080p model scale and gates (no frame-size rule)
    det = MovingObjectDetector(DetectionConfig(persist=persist, pixel_gates_reference_px=0.0), FPS)
    out = []
    for f in frames:
        out += det.step(f, Registration(f.index, np.eye(3)))
    return out + det.flush()


def _hits(out, truth) -> np.ndarray:
    return np.array([any(iou(b, truth[d.frame - 1]) >= 0.3 for b in d.boxes) for d in out])


def test_accumulate_reaches_steady_state_along_the_motion():
    """A blob of evidence e moving 1 px per frame sums to e / (1 - lambda) at its current place
    when the sum may move 1 px per frame, and stays near e when it may not."""
    lam, e0 = 0.8, 1.0
    acc_moving = acc_still = None
    shift = np.array([[1.0, 0, 1.0], [0, 1.0, 0], [0, 0, 1.0]])  # previous -> current pixels
    for t in range(40):
        ev = np.zeros((20, 80), np.float32)
        ev[9:11, 10 + t:12 + t] = e0
        acc_moving = accumulate(acc_moving, np.eye(3), ev, lam, 1)
        acc_still = accumulate(acc_still, np.eye(3), ev, lam, 0)
    assert acc_moving[10, 50] == pytest.approx(e0 / (1 - lam), rel=0.01)
    assert acc_still.max() < 2.0 * e0
    # a registration shift carries the sum with the ground: a static point that moves 1 px in
    # the image each frame is a standing target, summed without dilation
    acc = None
    for t in range(40):
        ev = np.zeros((20, 80), np.float32)
        ev[10, 10 + t] = e0
        acc = accumulate(acc, shift, ev, lam, 0)
    assert acc[10, 49] == pytest.approx(e0 / (1 - lam), rel=0.01)


def test_clutter_gain_keeps_a_lone_target_and_damps_one_in_clutter():
    rng = np.random.default_rng(1)
    e = np.zeros((120, 160), np.float32)
    e[58:62, 38:42] = 1.0  # lone target
    e[:, 90:] = rng.uniform(0.0, 1.0, (120, 70)).astype(np.float32) ** 4  # clutter field
    e[58:62, 118:122] = 1.0  # same target inside the clutter
    gain = clutter_gain(e, 31, 9)
    assert gain[60, 40] == pytest.approx(1.0)
    assert gain[60, 120] < 0.8


def test_persistent_peaks_need_current_evidence_and_respect_exclusion():
    score = np.zeros((30, 30), np.float32)
    ev = np.zeros_like(score)
    score[10, 10] = score[20, 20] = 1.0
    ev[10, 10] = 1.0  # the peak at (20, 20) is only a trail: no evidence in this frame
    assert [(x, y) for x, y, _ in persistent_peaks(score, ev, 0.5, 0.5)] == [(10, 10)]
    excl = np.zeros(score.shape, bool)
    excl[8:13, 8:13] = True
    assert persistent_peaks(score, ev, 0.5, 0.5, excl) == []


def test_faint_small_mover_is_detected_with_persistence_and_not_without():
    frames, truth = _scene(60, 12.0)
    without = _hits(_detect(frames, False), truth)
    with_p = _hits(_detect(frames, True), truth)
    assert without.mean() == 0.0
    # causal over finalised frames: about tau_s + window_s to build up
    assert with_p[20:].mean() >= 0.8
    # and the same target at higher contrast is found without persistence (the scene is fair)
    frames, truth = _scene(60, 30.0)
    assert _hits(_detect(frames, False), truth)[20:].mean() >= 0.9


def test_persistent_detections_are_not_kept_out_of_the_background():
    """A target faint enough to need persistence changes few pixels above the single-frame
    threshold, so the stationary test would call it stopped and hold its box out of the
    background samples; its detections must leave the samples whole."""
    frames, truth = _scene(60, 12.0)
    det = MovingObjectDetector(dataclasses.replace(DetectionConfig(), persist=True), FPS)
    out, held = [], 0
    for f in frames:
        out += det.step(f, Registration(f.index, np.eye(3)))
        held += sum(s.holes is not None and len(s.holes) > 0 for s in det._samples.values())
    out += det.flush()
    assert _hits(out, truth)[20:].mean() >= 0.8  # found by persistence alone
    assert held == 0


def test_flicker_noise_is_not_detected():
    frames, _ = _scene(60, 12.0, flicker=True)
    out = _detect(frames, True)
    assert sum(len(d.boxes) for d in out) == 0


def test_reset_and_bad_options():
    cfg = dataclasses.replace(DetectionConfig(), persist=True)
    tr = PersistenceTracker(cfg, FPS, 0.5)
    res = np.zeros((60, 80), np.uint8)
    valid = np.full(res.shape, 255, np.uint8)
    # numpy scalars as the detector passes them
    assert tr.step(res, np.float32(10.0), valid, np.eye(3), 0.0, np.zeros((0, 4)), None) == []
    tr.reset()
    assert tr._acc is None
    with pytest.raises(ConfigError, match="persist_tau_s"):
        MovingObjectDetector(dataclasses.replace(cfg, persist_tau_s=0.0), FPS)
    with pytest.raises(ConfigError, match="persist_min_support"):
        MovingObjectDetector(dataclasses.replace(cfg, persist_min_support=1.5), FPS)

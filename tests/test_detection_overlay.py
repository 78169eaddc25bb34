"""On-screen overlays (aerotrack.detection.overlay): found on a moving camera, never on the ground."""

from __future__ import annotations

import cv2
import numpy as np

from aerotrack.detection.overlay import OverlayFinder


def _ground(seed: int = 0, size: int = 900) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.integers(0, 255, (size, size), dtype=np.uint8), (0, 0), 2.0)
    return cv2.cvtColor(cv2.normalize(g, None, 0, 255, cv2.NORM_MINMAX), cv2.COLOR_GRAY2BGR)


def _flight(overlay: bool, frames: int = 75, fps: float = 30.0):
    """A camera gliding 2 px a frame over textured ground, 640x360, with a caption and a
    crosshair drawn on the screen (or not); yields (image, H frame -> ground)."""
    ground = _ground()
    for i in range(frames):
        x0, y0 = 20 + 2 * i, 30 + i
        img = ground[y0:y0 + 360, x0:x0 + 640].copy()
        if overlay:
            cv2.putText(img, f"ALT 141.8m  T {i / fps:06.2f}", (12, 30), cv2.FONT_HERSHEY_SIMPLEX,
                        0.8, (0, 0, 0), 4, cv2.LINE_AA)
            cv2.putText(img, f"ALT 141.8m  T {i / fps:06.2f}", (12, 30), cv2.FONT_HERSHEY_SIMPLEX,
                        0.8, (255, 255, 255), 2, cv2.LINE_AA)
            cv2.circle(img, (320, 180), 20, (255, 255, 255), 2)
            cv2.line(img, (290, 180), (350, 180), (255, 255, 255), 2)
        yield img, np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])


def test_a_caption_and_a_crosshair_on_a_moving_camera_are_found_and_the_ground_is_not():
    finder = OverlayFinder(30.0, mode="all")
    for img, H in _flight(True):
        finder.step(img, H)
    assert finder.mask is not None
    m = finder.mask
    caption, cross = m[5:40, 12:380], m[155:205, 295:345]
    assert caption.mean() > 0.6 and cross.mean() > 0.6, (caption.mean(), cross.mean())
    elsewhere = m.copy()
    elsewhere[:60, :420] = False
    elsewhere[140:220, 270:370] = False
    assert elsewhere.mean() < 0.01, elsewhere.mean()
    # by default a mark in the middle is only reported: it may be a vehicle the camera follows
    edges = OverlayFinder(30.0)
    for img, H in _flight(True):
        edges.step(img, H)
    assert edges.mask[5:40, 12:380].mean() > 0.6 and not edges.mask[155:205, 295:345].any()
    (x, y, w, h), = edges.held
    assert x < 300 and x + w > 340 and y < 180 < y + h

    clean = OverlayFinder(30.0)
    for img, H in _flight(False):
        clean.step(img, H)
    assert clean.mask is None


def test_a_camera_that_does_not_move_gives_no_overlay():
    finder = OverlayFinder(30.0)
    for img, _ in _flight(True):
        finder.step(img, np.eye(3))  # registered as still: the caption's digits change only
    assert finder.mask is None


def test_track_leaves_a_burned_in_caption_out(tmp_path, capsys):
    """A generated flight with a clock drawn on every frame: no detection or track on the
    caption, the mask kept for ``track --from``."""
    from conftest import run_cli

    from aerotrack.io.mot import read_mot
    from aerotrack.synth import render_to

    scene = tmp_path / "scene"
    render_to(scene, seed=3, frames=120, scenario="default")
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, f in enumerate(sorted((scene / "frames").iterdir())):
        img = cv2.imread(str(f))
        for colour, width in (((0, 0, 0), 4), ((255, 255, 255), 2)):
            cv2.putText(img, f"2024-05-01 10:30:{i / 30:06.3f}  ALT 141.8m", (10, 28),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.7, colour, width, cv2.LINE_AA)
        cv2.imwrite(str(frames / f"{f.stem}.png"), img)
    code, _, err = run_cli(capsys, "track", frames, "--out", tmp_path / "run", "--fps", "30")
    assert code == 0, err
    assert (tmp_path / "run" / "stages" / "overlay_mask.png").is_file()
    for name in ("detections.csv", "tracks.csv"):
        rows = read_mot(tmp_path / "run" / name, detections=name == "detections.csv")
        cy = rows[:, 3] + rows[:, 5] / 2
        cx = rows[:, 2] + rows[:, 4] / 2
        assert not np.any((cy < 36) & (cx < 560)), name
    # `detect` writes the detections of a full run: none on the caption either
    code, _, err = run_cli(capsys, "detect", frames, "--out", tmp_path / "det", "--fps", "30")
    assert code == 0, err
    rows = read_mot(tmp_path / "det" / "detections.csv", detections=True)
    assert not np.any((rows[:, 3] + rows[:, 5] / 2 < 36) & (rows[:, 2] + rows[:, 4] / 2 < 560))
    code, _, err = run_cli(capsys, "track", "--from", tmp_path / "run", "--out", tmp_path / "again")
    assert code == 0, err
    rows = read_mot(tmp_path / "again" / "tracks.csv")
    assert not np.any((rows[:, 3] + rows[:, 5] / 2 < 36) & (rows[:, 2] + rows[:, 4] / 2 < 560))
    # segments on Dask: each finds it, the join drops what came before
    code, _, err = run_cli(capsys, "track", frames, "--out", tmp_path / "dask", "--fps", "30",
                           "--workers", "2")
    assert code == 0, err
    assert (tmp_path / "dask" / "stages" / "overlay_mask.png").is_file()
    for name in ("detections.csv", "tracks.csv"):
        rows = read_mot(tmp_path / "dask" / name, detections=name == "detections.csv")
        on = (rows[:, 3] + rows[:, 5] / 2 < 36) & (rows[:, 2] + rows[:, 4] / 2 < 560)
        assert not np.any(on), name


def test_bad_overlay_settings_name_the_setting():
    from aerotrack.config import load_config
    from aerotrack.detection.detector import check_config
    from aerotrack.errors import ConfigError

    for kv, needle in (("overlay_mask=bogus", "expected edges, all or off"),
                       ("overlay_share=2", "detection.overlay_share: must be in (0, 1]"),
                       ("overlay_min_s=0", "detection.overlay_min_s: must be > 0")):
        try:
            check_config(load_config(overrides=[f"detection.{kv}"]).detection)
        except ConfigError as exc:
            assert needle in str(exc), (kv, exc)
        else:
            raise AssertionError(kv)

"""Registration: known-answer tests on views rendered from the bundled map tile with known homographies."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from aerotrack.config import RegistrationConfig
from aerotrack.errors import ConfigError, InputError
from aerotrack.geo import GeoMap
from aerotrack.registration import (
    FrameRegistrar,
    chain,
    check_homography,
    corner_error,
    estimate_homography,
    frame_quality,
    read_registration_csv,
    refine_against_map,
    to_gray,
    write_registration_csv,
)
from aerotrack.types import Failure, Frame

TILE = Path(__file__).resolve().parents[1] / "src/aerotrack/synth/data/vegas_tile.tif"
W, H = 320, 240


@pytest.fixture(scope="module")
def tile() -> GeoMap:
    return GeoMap(TILE)


@pytest.fixture(scope="module")
def map_img(tile) -> np.ndarray:
    return tile.read_image()


def camera(t: float, jump: float = 0.0) -> np.ndarray:
    """Frame pixels -> map pixels of a smoothly moving, rotating, zooming, slightly tilted camera."""
    cx = 650 + 200 * np.sin(t / 6.0)
    cy = 650 + 150 * np.sin(t / 5.0 + 1.0)
    th = 0.3 * np.sin(t / 10.0) + jump
    s = 0.9 * (1 + 0.1 * np.sin(t / 4.0))
    C = np.array([[1, 0, -W / 2], [0, 1, -H / 2], [0, 0, 1.0]])
    P = np.array([[1, 0, 0], [0, 1, 0], [3e-5 * np.sin(t / 3), 3e-5 * np.cos(t / 4), 1.0]])
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    M = np.array([[s, 0, cx], [0, s, cy], [0, 0, 1.0]])
    Hm = M @ R @ P @ C
    return Hm / Hm[2, 2]


def to_index(Hm: np.ndarray) -> np.ndarray:
    """A homography between continuous pixels (origin at the corner) as OpenCV's pixel indices."""
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    return np.linalg.inv(T) @ Hm @ T


def render(map_img: np.ndarray, Hm: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """The view of a camera whose frame -> map homography (continuous pixels) is ``Hm``."""
    f = cv2.warpPerspective(map_img, to_index(Hm), (W, H),
                            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    if rng is not None:
        f = np.clip(f + rng.normal(0, 2.0, f.shape), 0, 255).astype(np.uint8)
    return f


# -- frame to frame -------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["lk", "orb"])
def test_recovers_known_homography(map_img, method):
    H0, H1 = camera(0.0), camera(0.4)
    a, b = to_gray(render(map_img, H0)), to_gray(render(map_img, H1))
    true = np.linalg.inv(H1) @ H0  # frame 0 pixels -> frame 1 pixels
    res = estimate_homography(a, b, method=method)
    assert res, res
    Hest, stats = res
    assert stats.inliers >= 20 and stats.inlier_ratio > 0.5
    assert corner_error(Hest, true, W, H) < 0.3


def test_orb_recovers_a_30_degree_jump(map_img):
    H0 = camera(1.0)
    H1 = camera(1.0, jump=np.radians(30))
    a, b = to_gray(render(map_img, H0)), to_gray(render(map_img, H1))
    assert not estimate_homography(a, b, method="lk") or True  # LK may or may not cope
    Hest, _ = estimate_homography(a, b, method="orb")
    assert corner_error(Hest, np.linalg.inv(H1) @ H0, W, H) < 0.5


def test_mask_keeps_features_off_excluded_boxes(map_img):
    a = to_gray(render(map_img, camera(0.0)))
    b = to_gray(render(map_img, camera(0.2)))
    mask = np.full(a.shape, 255, np.uint8)
    mask[50:150, 100:200] = 0
    _, stats = estimate_homography(a, b, mask)
    Hb = np.linalg.inv(camera(0.2)) @ camera(0.0)
    from aerotrack.types import apply_homography
    src = apply_homography(np.linalg.inv(Hb), stats.points)  # inliers back in frame a
    inside = (src[:, 0] > 101) & (src[:, 0] < 199) & (src[:, 1] > 51) & (src[:, 1] < 149)
    assert not inside.any()


@pytest.mark.parametrize("image,reason", [
    (np.zeros((H, W), np.uint8), "blank"),
    (np.full((H, W), 255, np.uint8), "blank"),
    (np.where(np.arange(W)[None, :] % 7 == 0, 100, 255).astype(np.uint8).repeat(H, 0), "overexposed"),
    (np.random.default_rng(0).integers(0, 256, (H, W)).astype(np.uint8), "noise"),
])
def test_frame_quality_names_the_problem(image, reason):
    bad = frame_quality(image)
    assert isinstance(bad, Failure) and not bad
    assert reason in bad.reason


def test_frame_quality_accepts_imagery(map_img):
    assert frame_quality(to_gray(render(map_img, camera(0.0)))) is None


def test_check_homography_rejects_degenerate():
    assert check_homography(np.eye(3), W, H) is None
    bad = {
        "flip": np.diag([-1.0, 1, 1]),  # mirror
        "area": np.diag([3.0, 3, 1]),  # area ratio 9
        "condition": np.diag([2.5, 0.5, 1]),  # strong anisotropic scale
        "finite": np.full((3, 3), np.nan),
        "horizon": np.array([[1, 0, 0], [0, 1, 0], [-0.01, 0, 1.0]]),
    }
    for word, Hb in bad.items():
        res = check_homography(Hb, W, H)
        assert isinstance(res, Failure), word
        assert word in res.reason, (word, res.reason)


# -- chaining (eq. 1) -----------------------------------------------------------------------------
def _near_identity(draw_vals):
    a, b, c, d, tx, ty, p, q = draw_vals
    return np.array([[1 + a, b, tx], [c, 1 + d, ty], [p, q, 1.0]])


small = st.floats(-0.05, 0.05)
hom = st.tuples(small, small, small, small, st.floats(-20, 20), st.floats(-20, 20),
                st.floats(-1e-4, 1e-4), st.floats(-1e-4, 1e-4)).map(_near_identity)


@settings(max_examples=60, deadline=None)
@given(st.lists(hom, min_size=1, max_size=6), st.data())
def test_chain_properties(Hs, data):
    n = len(Hs)
    i = data.draw(st.integers(0, n))
    j = data.draw(st.integers(0, n))
    k = data.draw(st.integers(0, n))
    assert np.allclose(chain(Hs, i, i), np.eye(3))
    Hij, Hji = chain(Hs, i, j), chain(Hs, j, i)
    prod = Hij @ Hji
    assert np.allclose(prod / prod[2, 2], np.eye(3), atol=1e-9)  # H . H^-1 = I
    Hik = chain(Hs, j, k) @ Hij
    assert np.allclose(Hik / Hik[2, 2], chain(Hs, i, k), atol=1e-8)
    if n >= 1:
        assert np.allclose(chain(Hs, 0, 1), Hs[0] / Hs[0][2, 2])


def test_chain_rejects_out_of_range():
    with pytest.raises(IndexError):
        chain([np.eye(3)], 0, 3)


# -- the stage ------------------------------------------------------------------------------------
def _sequence(map_img, n, fps, rng, events=None):
    events = events or {}
    for k in range(n):
        t = k / fps
        Hm = camera(t, jump=np.radians(30) if k >= events.get("jump_at", 10**9) else 0.0)
        img = render(map_img, Hm, rng)
        kind = events.get(k)
        if kind == "black":
            img = np.zeros_like(img)
        elif kind == "noise":
            img = rng.integers(0, 256, img.shape).astype(np.uint8)
        elif kind == "white":
            img = np.full_like(img, 255)
        yield Frame(k + 1, img, t), Hm


def test_registrar_tracks_a_clean_sequence_without_map(map_img):
    fps = 10.0
    rng = np.random.default_rng(1)
    reg = FrameRegistrar(RegistrationConfig(), fps)
    H1 = None
    for frame, Hm in _sequence(map_img, 40, fps, rng):
        r = reg.step(frame)
        H1 = Hm if H1 is None else H1
        assert r.status == "ok"
        # world = frame 1 pixels: truth is H1^-1 Hm
        assert corner_error(r.H, np.linalg.inv(H1) @ Hm, W, H) < 2.0  # chained: drifts slowly


def test_robustness_sequence(map_img):
    """Black, white, repeated, noise frames and a sudden 30 degree jump: no crash, reasons given,
    good frames afterwards stay in frame 1's coordinates."""
    fps = 10.0
    rng = np.random.default_rng(2)
    events = {5: "black", 6: "black", 12: "noise", 13: "noise", 14: "noise", 20: "white",
              "jump_at": 30}
    reg = FrameRegistrar(RegistrationConfig(), fps)
    out, truth = [], []
    prev = None
    for frame, Hm in _sequence(map_img, 45, fps, rng, events):
        if frame.index == 25 and prev is not None:  # a repeated frame
            frame = Frame(frame.index, prev.image.copy(), frame.time)
            Hm = truth[-1]
        out.append(reg.step(frame))
        truth.append(Hm)
        prev = frame
    status = {r.index: (r.status, r.reason) for r in out}
    assert status[6][0] == "carried" and "blank" in status[6][1]
    assert status[13][0] == "carried" and "noise" in status[13][1]
    assert status[21][0] == "carried" and ("blank" in status[21][1] or "overexposed" in status[21][1])
    assert status[25][0] == "ok"
    assert status[31][0] == "ok"  # the 30 degree jump is registered (ORB fallback)
    H1inv = np.linalg.inv(truth[0])
    for r, Hm in zip(out, truth):
        if r.status == "ok":
            assert corner_error(r.H, H1inv @ Hm, W, H) < 1.5, r
    assert reg.summary()["n_failures"] == 6


def test_registrar_exclude_boxes_accepted(map_img):
    reg = FrameRegistrar(RegistrationConfig(), 10.0)
    rng = np.random.default_rng(3)
    for frame, _ in _sequence(map_img, 3, 10.0, rng):
        r = reg.step(frame, exclude_boxes=np.array([[10, 10, 50, 40], [200, 100, 30, 30]]))
        assert r.status == "ok"


# -- map refinement -------------------------------------------------------------------------------
def test_refinement_removes_injected_drift(map_img):
    rng = np.random.default_rng(4)
    mg = cv2.cvtColor(map_img, cv2.COLOR_BGR2GRAY)
    for t in (0.0, 7.0, 19.0):
        Hm = camera(t)
        f = render(map_img, Hm, rng)
        a = 0.01
        drift = np.array([[np.cos(a), -np.sin(a), 6.0], [np.sin(a), np.cos(a), -4.0], [0, 0, 1]])
        c = np.array([[1, 0, 650], [0, 1, 650], [0, 0, 1.0]])
        rough = c @ drift @ np.linalg.inv(c) @ Hm
        assert corner_error(rough, Hm, W, H) > 5
        res = refine_against_map(f, rough, mg)
        assert res, res
        Href, stats = res
        assert corner_error(Href, Hm, W, H) < 0.5
        assert stats.correction_px > 5


def test_refinement_fails_cleanly_off_map(map_img):
    Hm = camera(0.0)
    off = np.array([[1, 0, 5000], [0, 1, 5000], [0, 0, 1.0]]) @ Hm
    res = refine_against_map(render(map_img, Hm), off, map_img)
    assert isinstance(res, Failure) and "outside the map" in res.reason


def test_registrar_with_map_corrects_a_wrong_init(tile, map_img):
    fps = 10.0
    rng = np.random.default_rng(5)
    H_init = np.array([[1, 0, 5.0], [0, 1, 3.0], [0, 0, 1]]) @ camera(0.0)  # a 6 px clicking error
    reg = FrameRegistrar(RegistrationConfig(refine_every_s=1.0), fps, tile, H_init)
    errs = []
    for frame, Hm in _sequence(map_img, 25, fps, rng):
        r = reg.step(frame)
        errs.append(corner_error(r.H, Hm, W, H))
        if frame.index == 1:
            assert r.status == "refined"
    assert max(errs) < 1.0
    assert reg.counts["refined"] >= 3


def test_registrar_refines_against_a_map_much_finer_than_the_frames(tile, map_img, tmp_path):
    """A drone orthomosaic at 5 cm under a video at 30 cm: the refinement's pixel sizes (12 px
    search, 48 px patches) were map pixels, a fraction of a metre there, and it never corrected
    a placement error (a probe: 2.5 m stayed 2.5 m). The map is now downsampled to about the
    frames' ground resolution for it. Here the map is 4x finer and the placement 6 frame pixels
    (24 map pixels) off."""
    import rasterio
    from affine import Affine

    k = 4
    fine = cv2.resize(map_img, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC)
    path = tmp_path / "fine.tif"
    with rasterio.open(path, "w", driver="GTiff", width=fine.shape[1], height=fine.shape[0],
                       count=3, dtype="uint8", crs=tile.crs,
                       transform=tile.transform * Affine.scale(1 / k)) as ds:
        ds.write(fine[..., ::-1].transpose(2, 0, 1))
    fps, S = 10.0, np.diag([k, k, 1.0])
    H_init = S @ np.array([[1, 0, 5.0], [0, 1, 3.0], [0, 0, 1]]) @ camera(0.0)
    reg = FrameRegistrar(RegistrationConfig(refine_every_s=1.0), fps, GeoMap(path), H_init)
    errs = [corner_error(np.linalg.inv(S) @ reg.step(frame).H, Hm, W, H)
            for frame, Hm in _sequence(map_img, 25, fps, np.random.default_rng(5))]
    assert reg.counts["refined"] >= 3
    assert max(errs[5:]) < 1.0, errs  # frame pixels


def test_registrar_validates_inputs(tile):
    with pytest.raises(ConfigError, match="registration.method"):
        FrameRegistrar(RegistrationConfig(method="sift"), 10.0)
    with pytest.raises(ConfigError, match="registration.estimator"):
        FrameRegistrar(RegistrationConfig(estimator="lmeds"), 10.0)
    with pytest.raises(InputError, match="map-init"):
        FrameRegistrar(RegistrationConfig(), 10.0, tile)
    with pytest.raises(InputError, match="fps"):
        FrameRegistrar(RegistrationConfig(), 0.0)


# -- outputs --------------------------------------------------------------------------------------
def test_registration_csv_round_trip(tmp_path, map_img):
    reg = FrameRegistrar(RegistrationConfig(), 10.0)
    rng = np.random.default_rng(6)
    events = {2: "black"}
    regs = [reg.step(f) for f, _ in _sequence(map_img, 5, 10.0, rng, events)]
    p = tmp_path / "registration.csv"
    write_registration_csv(p, regs)
    lines = p.read_text().splitlines()
    assert lines[0] == ("frame,h00,h01,h02,h10,h11,h12,h20,h21,h22,status,inliers,inlier_ratio,"
                        "error,reason")
    back = read_registration_csv(p)
    assert [r.index for r in back] == [1, 2, 3, 4, 5]
    assert back[2].status == "carried" and "blank" in back[2].reason
    for a, b in zip(regs, back):
        assert np.allclose(a.H, b.H, rtol=1e-9, atol=1e-9)


def _write_scene(folder: Path, map_img, n=12):
    folder.mkdir()
    truth = []
    for k in range(n):
        Hm = camera(k / 10.0)
        cv2.imwrite(str(folder / f"{k + 1:04d}.png"), render(map_img, Hm))
        truth.append(Hm)
    return truth


def test_mosaic_command_without_and_with_map(tmp_path, map_img):
    from aerotrack.cli.main import cli

    frames = tmp_path / "frames"
    truth = _write_scene(frames, map_img)
    runner = CliRunner()
    out = tmp_path / "mosaic.png"
    res = runner.invoke(cli, ["-q", "mosaic", str(frames), "--out", str(out), "--stride", "3",
                              "--registration", str(tmp_path / "reg.csv")])
    assert res.exit_code == 0, res.output
    img = cv2.imread(str(out))
    assert img is not None and img.shape[0] >= H and img.shape[1] >= W
    init = tmp_path / "init.txt"
    init.write_text("\n".join(" ".join(f"{v:.10g}" for v in row) for row in truth[0]) + "\n")
    out2 = tmp_path / "mosaic_map.png"
    res = runner.invoke(cli, ["-q", "mosaic", str(frames), "--out", str(out2), "--map", str(TILE),
                              "--map-init", str(init), "--registration", str(tmp_path / "reg2.csv")])
    assert res.exit_code == 0, res.output
    regs = read_registration_csv(tmp_path / "reg2.csv")
    assert all(corner_error(r.H, Hm, W, H) < 1.0 for r, Hm in zip(regs, truth))
    # georeferenced: a world file and the CRS beside the .png (it had neither: identity in GIS),
    # a GeoTIFF for .tif; both put the map's own pixels where the map does
    import rasterio

    from aerotrack.geo import GeoMap

    geomap = GeoMap(TILE)
    assert out2.with_suffix(".pgw").is_file() and Path(str(out2) + ".aux.xml").is_file()
    out3 = tmp_path / "mosaic_map.tif"
    res = runner.invoke(cli, ["-q", "mosaic", str(frames), "--out", str(out3), "--map", str(TILE),
                              "--map-init", str(init)])
    assert res.exit_code == 0, res.output
    png = cv2.imread(str(out2))
    for path in (out2, out3):
        with rasterio.open(path) as ds:
            assert ds.crs == geomap.crs and not ds.transform.is_identity
            assert ds.read().transpose(1, 2, 0)[:, :, ::-1].shape == png.shape
            # away from the painted frames the picture shows the map where it says it does
            tile = geomap.read_image()
            cr = np.array([(c, r) for r in range(2, 12) for c in range(2, 12)], float)
            xy = np.array([ds.transform * (c + 0.5, r + 0.5) for c, r in cr])  # pixel centres
            m = (geomap.crs_to_pixel(xy) - 0.5).astype(np.float32)  # continuous -> index
            want = cv2.remap(tile, m[:, 0].reshape(10, 10), m[:, 1].reshape(10, 10),
                             cv2.INTER_LINEAR)
            assert np.abs(png[2:12, 2:12].astype(int) - want.astype(int)).max() <= 2
            if path == out3:
                assert np.array_equal(ds.read().transpose(1, 2, 0)[:, :, ::-1], png)
    res = runner.invoke(cli, ["mosaic", str(frames), "--out", str(tmp_path / "m.gif")])
    assert res.exit_code != 0


def test_registrar_resets_after_a_cut_to_another_place(map_img):
    """A cut to unrelated ground cannot be registered: frames are carried, then the stage starts a
    new reference (status reset) and registers the following frames against it."""
    fps = 10.0
    cfg = RegistrationConfig(reset_after_s=0.5)
    reg = FrameRegistrar(cfg, fps)
    rng = np.random.default_rng(7)
    away = np.array([[1, 0, -450.0], [0, 1, 420.0], [0, 0, 1]])
    out = []
    for k in range(20):
        Hm = camera(k / fps)
        if k >= 8:
            Hm = away @ Hm
        out.append(reg.step(Frame(k + 1, render(map_img, Hm, rng), k / fps)))
    statuses = [r.status for r in out]
    assert statuses[:8] == ["ok"] * 8
    assert "carried" in statuses[8:13]
    assert "reset" in statuses
    first_reset = statuses.index("reset")
    assert all(s == "ok" for s in statuses[first_reset + 1:])
    assert all(np.all(np.isfinite(r.H)) for r in out)



def _cut_run(map_img, cfg, places):
    """Statuses of 20 frames at 10 fps: 8 along the camera path, then each frame k at
    ``places(k)`` (a homography applied to the path)."""
    reg = FrameRegistrar(cfg, 10.0)
    rng = np.random.default_rng(7)
    out = []
    for k in range(20):
        Hm = camera(k / 10.0)
        if k >= 8:
            Hm = places(k) @ Hm
        out.append(reg.step(Frame(k + 1, render(map_img, Hm, rng), k / 10.0)))
    return [r.status for r in out], [r.reason for r in out]


def test_scene_change_resets_at_once(map_img):
    """After a cut the new frames register against each other but not the old reference: the
    third such frame (``cut_frames`` 3) is a new reference at once, not after ``reset_after_s``
    (3 s, longer than the clip); with ``cut_frames`` 0 the frames are carried to the end."""
    away = np.array([[1, 0, -450.0], [0, 1, 420.0], [0, 0, 1]])
    statuses, reasons = _cut_run(map_img, RegistrationConfig(), lambda k: away)
    assert statuses[:8] == ["ok"] * 8
    assert statuses[8:10] == ["carried", "carried"]
    assert statuses[10] == "reset" and "scene change" in reasons[10]
    assert statuses[11:] == ["ok"] * 9
    statuses, _ = _cut_run(map_img, RegistrationConfig(cut_frames=0), lambda k: away)
    assert statuses[8:] == ["carried"] * 12


def test_unrelated_failed_frames_are_not_a_scene_change(map_img):
    """Frames that fail against the reference and against each other (every frame somewhere
    else) are carried: no new reference before ``reset_after_s``."""
    statuses, _ = _cut_run(map_img, RegistrationConfig(), lambda k: np.array(
        [[1, 0, -450.0 if k % 2 else 400.0], [0, 1, 420.0 if k % 2 else -380.0], [0, 0, 1]]))
    assert statuses[8:] == ["carried"] * 12


def test_cut_frames_is_checked():
    with pytest.raises(ConfigError, match="cut_frames"):
        FrameRegistrar(RegistrationConfig(cut_frames=1), 10.0)
    with pytest.raises(ConfigError, match="cut_frames"):
        FrameRegistrar(RegistrationConfig(cut_frames=-2), 10.0)

def _continuous(Hi: np.ndarray) -> np.ndarray:
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    return T @ Hi @ np.linalg.inv(T)


@pytest.mark.parametrize("perturbed", [False, True])
def test_registrar_on_generated_scene(perturbed):
    """The scenario generator's scene (vehicles, shadows, trees) against its map, or against the
    map as another date would show it: corner error under a map pixel throughout."""
    from aerotrack.synth import Scenario, perturb_map

    sc = Scenario(seed=3, frames=25, size=(480, 360), fps=10.0)
    geomap = sc.world.geomap
    A = np.eye(3)
    base = sc.world.image
    if perturbed:
        base, A = perturb_map(base, rng=4)
        A = _continuous(A)
    geomap._image = base
    try:
        reg = None
        for frame, H_true, _ in sc.frames():
            truth = A @ H_true  # the generator's homographies are in aerotrack's convention
            if reg is None:
                reg = FrameRegistrar(RegistrationConfig(), sc.fps, geomap, truth)
            r = reg.step(frame)
            assert corner_error(r.H, truth, *sc.size) < 1.0, (frame.index, r)
        assert reg.counts["refined"] >= 3
    finally:
        geomap._image = None


@pytest.mark.parametrize("grid", [True, False])
def test_grid_keyframes_make_registration_independent_of_where_the_run_started(grid):
    """With ``keyframe_grid`` a run started on the grid (a Dask segment, a resumed run) registers
    later frames exactly as a run from the first frame; without it the features carried from
    earlier keyframes make the two differ."""
    import dataclasses

    from aerotrack.synth import Scenario

    sc = Scenario(seed=2, frames=60, size=(320, 240), fps=10.0)
    frames = [f for f, _, _ in sc.frames()]
    cfg = dataclasses.replace(RegistrationConfig(), keyframe_grid=grid)

    def relative(start):
        reg = FrameRegistrar(cfg, 10.0)
        out = {f.index: reg.step(f).H for f in frames[start - 1:]}
        return np.linalg.inv(out[55]) @ out[45]

    a, b = relative(1), relative(21)  # frame 21 starts a 0.5 s grid slot at 10 frames/s
    diff = np.abs(a / a[2, 2] - b / b[2, 2]).max()
    if grid:
        assert diff < 1e-9
    else:
        assert diff > 1e-6


def test_detections_mask_the_registration_features_unless_disabled():
    import dataclasses

    from aerotrack.config import Config
    from aerotrack.pipeline import Pipeline
    from aerotrack.synth import Scenario

    sc = Scenario(seed=2, frames=80, size=(320, 240), fps=10.0)
    frames = [f for f, _, _ in sc.frames()]
    for on in (True, False):
        cfg = dataclasses.replace(Config(), registration=dataclasses.replace(
            Config().registration, mask_detections=on))
        pipe = Pipeline(cfg, 10.0, seed=0)
        for f in frames:
            pipe.step(f)
        boxes = pipe._exclude_boxes()
        assert (boxes is not None and len(boxes) > 0) if on else boxes is None


def test_frames_skipped_by_stride_are_not_failures(caplog):
    """``--stride 2`` gives the registrar every other frame. It used to count the frame numbers
    between two registered frames as failed frames: every frame then forced a map refinement
    and a new keyframe (all 150 of a 300-frame stride run 'refined', 3x slower) and logged
    'registered ... after 1 failed frames'."""
    import logging

    from aerotrack.synth import Scenario

    sc = Scenario(seed=3, frames=40, size=(480, 360), fps=10.0)
    geomap = sc.world.geomap
    geomap._image = sc.world.image
    try:
        reg = None
        with caplog.at_level(logging.INFO, logger="aerotrack.registration"):
            for frame, H_true, _ in sc.frames():
                if frame.index % 2 == 0:
                    continue
                if reg is None:
                    reg = FrameRegistrar(RegistrationConfig(), sc.fps, geomap, H_true)
                r = reg.step(frame)
                assert corner_error(r.H, H_true, *sc.size) < 1.0, (frame.index, r)
        assert reg.counts["ok"] >= 12 and reg.counts["refined"] <= 6, reg.counts
        assert "failed frames" not in caplog.text
    finally:
        geomap._image = None


def test_carry_placement_to_a_later_first_frame():
    """``--frames A:B`` with ``--map-init`` (frame 1's placement): frame A's placement comes from
    registering frames 1..A. Frame 1's placement itself is many map pixels off at frame A."""
    from aerotrack.registration.registrar import carry_placement
    from aerotrack.synth import Scenario

    sc = Scenario(seed=3, frames=40, size=(480, 360), fps=10.0)
    geomap = sc.world.geomap
    geomap._image = sc.world.image
    try:
        truth = {f.index: H for f, H, _ in sc.frames()}
        frames = {f.index: f for f, _, _ in sc.frames()}

        class Source:
            def frames(self, start=1, stop=None, stride=1):
                return (frames[i] for i in range(start, (stop or 40) + 1, stride))

        start = 35
        assert corner_error(truth[1], truth[start], *sc.size) > 5.0
        H = carry_placement(Source(), truth[1], start, geomap, sc.fps, RegistrationConfig())
        assert corner_error(H, truth[start], *sc.size) < 1.0
    finally:
        geomap._image = None


def test_frames_range_with_a_map_starts_where_frame_1_puts_it(tmp_path):
    from aerotrack.cli.main import main
    from aerotrack.io.geotable import read_registration_csv

    scene = tmp_path / "s"
    main(["-q", "synth", "--out", str(scene), "--frames", "110", "--size", "320x240",
          "--seed", "7"])
    truth = np.loadtxt(scene / "homographies.csv", delimiter=",", skiprows=1)
    truth = {int(r[0]): r[1:10].reshape(3, 3) for r in truth}
    assert corner_error(truth[1], truth[100], 320, 240) > 20.0  # beyond map refinement's reach
    main(["-q", "detect", str(scene / "frames"), "--out", str(tmp_path / "d"), "--map",
          str(scene / "map.tif"), "--map-init", str(scene / "map_init.txt"), "--frames", "100:110"])
    regs = read_registration_csv(tmp_path / "d" / "registration.csv")
    assert min(regs) == 100
    assert corner_error(regs[100], truth[100], 320, 240) < 1.0


def test_share_of_the_frames_off_the_map():
    """mosaic --map paints only the map's extent; what lies beyond it is measured for a warning."""
    from aerotrack.registration.mosaic import share_off_map

    shift = np.array([[1, 0, 150], [0, 1, 0], [0, 0, 1]], float)
    assert share_off_map([np.eye(3)], 100, 100, (200, 200)) == pytest.approx(0.0, abs=0.02)
    assert share_off_map([shift], 100, 100, (200, 200)) == pytest.approx(0.5, abs=0.02)
    assert share_off_map([np.eye(3), shift], 100, 100, (200, 200)) == pytest.approx(0.25, abs=0.02)


def _zoom_camera(s: float) -> np.ndarray:
    """Frame -> map pixels of a camera over a fixed point, ``s`` map pixels per frame pixel."""
    C = np.array([[1, 0, -W / 2], [0, 1, -H / 2], [0, 0, 1.0]])
    M = np.array([[s, 0, 700.0], [0, s, 650.0], [0, 0, 1.0]])
    return M @ C


def test_registrar_follows_a_fast_zoom_out(map_img):
    """Zooming out keeps every keyframe feature in view, so only the timer renewed the keyframe and
    within its 0.5 s a fast zoom (1.8x in 1 s) passed ``max_scale_change``: frames failed as
    degenerate, were taken for a scene change and reset (the probe's clip: 11 frames with no
    detections after it, 9.6 px off). A keyframe once half the allowed change is used keeps up."""
    fps, n = 30.0, 36
    rng = np.random.default_rng(3)
    reg = FrameRegistrar(RegistrationConfig(), fps)
    H1 = None
    for k in range(n):
        Hm = _zoom_camera(0.5 * 1.8 ** min(k / fps, 1.0))
        H1 = Hm if H1 is None else H1
        r = reg.step(Frame(k + 1, render(map_img, Hm, rng), k / fps))
        assert r.status == "ok", (k + 1, r.status, r.reason)
        assert corner_error(r.H, np.linalg.inv(H1) @ Hm, W, H) < 2.0


def test_a_blurred_frame_does_not_become_the_keyframe(map_img):
    """Motion blur loses features, which called for a new keyframe: the blurred frame became it and
    passed its registration error on to every later frame of a still camera (Santiago: 0.3 ->
    2.3 px for the rest of the clip). It is registered, but the keyframe waits for a sharp one."""
    fps = 30.0
    rng = np.random.default_rng(4)
    Hm = camera(0.0)
    kernel = np.zeros((1, 25), np.float32)
    kernel[0, :] = 1.0 / 25

    def errors(cfg):
        reg = FrameRegistrar(cfg, fps)
        out = []
        for k in range(30):
            img = render(map_img, Hm, rng)
            if k in (10, 11, 12):
                img = cv2.filter2D(img, -1, kernel)
            out.append(corner_error(reg.step(Frame(k + 1, img, k / fps)).H, np.eye(3), W, H))
        return np.array(out)

    kept = errors(RegistrationConfig())
    assert kept[14:].max() < 0.5, kept.round(2)
    before = errors(RegistrationConfig(keyframe_blur_ratio=0.0))  # the rule off: as it was
    assert before[14:].max() > 2 * kept[14:].max(), (before.round(2), kept.round(2))


def test_a_pan_blurred_throughout_keeps_taking_keyframes(map_img):
    """Blur is judged against the recent frames, and a keyframe is held back only while it still
    shows the view: a fast pan blurred throughout, refused keyframes while its features left the
    view, ended 13.7 px off instead of 3.4 (16 px a frame; 187 px and a reset when judged
    against the keyframe's sharpness; a review)."""
    fps, speed = 30.0, 16
    rng = np.random.default_rng(4)
    kernel = np.full((1, speed + 1), 1.0 / (speed + 1), np.float32)

    def cam(k):
        C = np.array([[1, 0, -W / 2], [0, 1, -H / 2], [0, 0, 1.0]])
        return np.array([[1, 0, 500.0 + speed * k], [0, 1, 600], [0, 0, 1.0]]) @ C

    imgs = [render(map_img, cam(k), rng) for k in range(40)]
    imgs = imgs[:5] + [cv2.filter2D(img, -1, kernel) for img in imgs[5:]]

    def final_error(ratio):
        reg = FrameRegistrar(RegistrationConfig(keyframe_blur_ratio=ratio), fps)
        for k, img in enumerate(imgs):
            r = reg.step(Frame(k + 1, img, k / fps))
            assert r.status == "ok", (k + 1, r.status)
        return corner_error(r.H, np.linalg.inv(cam(0)) @ cam(39), W, H)

    assert final_error(RegistrationConfig().keyframe_blur_ratio) <= final_error(0.0) + 0.5


def test_mosaic_frames_leave_no_dark_seam_at_their_edges():
    """A frame's edge was interpolated with the black outside it, leaving a dark dotted seam
    along every painted frame (a probe); --no-outlines (outline_every 0) draws no outline."""
    from aerotrack.registration.mosaic import paint_mosaic
    from aerotrack.types import Frame

    w, h = 64, 48
    frames = [Frame(index=k, image=np.full((h, w, 3), 200, np.uint8), time=0.0)
              for k in (1, 2)]
    Hs = {1: np.eye(3), 2: np.array([[np.cos(0.3), -np.sin(0.3), 20.3],
                                     [np.sin(0.3), np.cos(0.3), 7.7], [0, 0, 1]])}
    img = paint_mosaic(frames, Hs, (w, h), margin=5, outline_every=0)
    bright = img[..., 1] > 100  # painted (the empty canvas is 40)
    assert bright.sum() > w * h
    inner = cv2.erode(bright.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    edge = bright & ~inner
    assert img[edge][:, 1].min() >= 190, img[edge][:, 1].min()

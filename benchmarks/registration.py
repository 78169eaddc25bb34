"""Registration benchmark (issue 3): accuracy with/without map refinement, real video, speed vs a peer.

Run from the repository root::

    /tmp/venv/bin/python benchmarks/registration.py            # everything (~10 min on 2 busy cores)
    /tmp/venv/bin/python benchmarks/registration.py --frames 300 --skip-real   # quick look

Parts
-----
1. Accuracy on a generated flight over the bundled Las Vegas tile (1300x1300 map px, 0.27 m/px):
   640x480 frames rendered from the map by a known homography per frame (smooth translation,
   rotation, zoom and tilt; sensor noise, a slow gain drift and moving bright "vehicles" that must
   not pull the estimate), 30 frames/s. Mean corner error (map px and metres) against frame number:
   chained only (no refinement), refined every K seconds for several K (with the cost of each), and
   refined against a *perturbed* map (gamma, contrast, blur, seasonal colour shift, resampled by a
   sub-pixel offset and a 0.3 % scale), as a satellite map of another date would be. The same on
   the project's scenario generator (``aerotrack.synth``, 'default' scene, its ``perturb_map``).
2. Real moving camera, UAV123 truck4 (1280x720, 10 frames/s, oblique, parallax; no map): inlier
   ratio, median absolute grey difference after warping consecutive frames and frames 10 apart (by
   chaining), against no compensation and against the peer's affine; a mosaic picture.
3. Speed per frame at 640x480, 1280x720 and 1920x1080 of the frame-to-frame stage and of one map
   refinement, as a ratio to the camera-motion compensation of Roboflow ``trackers`` 2.6.1
   (BoT-SORT's sparse optical flow, its defaults) timed interleaved in the same run, plus the
   frame-to-frame accuracy of both on generated frames with known motion.

Writes benchmarks/results/registration.json and docs/images/mosaic_truck4.png.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from common import REPO, SHARED_DATA, write_results

from aerotrack.config import RegistrationConfig
from aerotrack.geo import GeoMap
from aerotrack.registration import (
    FrameRegistrar,
    corner_error,
    refine_against_map,
)
from aerotrack.registration.mosaic import paint_mosaic
from aerotrack.types import Frame

TILE = REPO / "src/aerotrack/synth/data/vegas_tile.tif"
TRUCK4 = SHARED_DATA / "uav123_10fps_truck4" / "frames"


# -- generated flight -----------------------------------------------------------------------------
def camera(t: float, size: tuple[int, int], gsd: float = 0.6, centre=(650.0, 650.0)) -> np.ndarray:
    """Frame pixels -> map pixels at time ``t`` (s): a smooth loop with rotation, zoom and tilt.

    ``gsd`` is map pixels per frame pixel at the mean zoom.
    """
    W, H = size
    cx = centre[0] + 230 * np.sin(2 * np.pi * t / 40.0)
    cy = centre[1] + 200 * np.sin(2 * np.pi * t / 27.0 + 1.0)
    th = 0.6 * np.sin(2 * np.pi * t / 60.0)
    s = gsd * (1 + 0.15 * np.sin(2 * np.pi * t / 23.0))
    tilt = 1.5e-5 * 640.0 / W
    C = np.array([[1, 0, -W / 2], [0, 1, -H / 2], [0, 0, 1.0]])
    P = np.array([[1, 0, 0], [0, 1, 0],
                  [tilt * np.sin(2 * np.pi * t / 17), tilt * np.cos(2 * np.pi * t / 13), 1.0]])
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    M = np.array([[s, 0, cx], [0, s, cy], [0, 0, 1.0]])
    Hm = M @ R @ P @ C
    return Hm / Hm[2, 2]


class Renderer:
    """Frames seen by the camera: the map warped, plus movers, gain drift and noise."""

    def __init__(self, map_img: np.ndarray, size: tuple[int, int], seed: int = 0, movers: int = 12):
        self.map = map_img
        self.size = size
        self.rng = np.random.default_rng(seed)
        self.movers = [(self.rng.uniform(400, 900, 2), self.rng.uniform(-15, 15, 2),
                        self.rng.uniform(8, 16, 2), int(self.rng.integers(150, 256)))
                       for _ in range(movers)]  # (start map px, velocity map px/s, size, grey)

    def __call__(self, t: float, Hm: np.ndarray, noise: bool = True) -> np.ndarray:
        img = self.map.copy() if self.movers else self.map
        for p0, v, wh, grey in self.movers:
            p = p0 + v * t
            cv2.rectangle(img, (int(p[0]), int(p[1])), (int(p[0] + wh[0]), int(p[1] + wh[1])),
                          (grey, grey, grey), -1)
        # Hm maps continuous pixels (origin at the corner); OpenCV warps pixel indices
        T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
        f = cv2.warpPerspective(img, np.linalg.inv(T) @ Hm @ T, self.size,
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        if noise:
            gain = 1.0 + 0.1 * np.sin(2 * np.pi * t / 30.0)
            f = np.clip(f * gain + self.rng.normal(0, 2.0, f.shape), 0, 255).astype(np.uint8)
        return f


def perturb_map(map_img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A map as another date and sensor would give it, and A: original map px -> perturbed map px."""
    h, w = map_img.shape[:2]
    s, off = 1.003, np.array([0.4, -0.3])
    A = np.array([[s, 0, (1 - s) * w / 2 + off[0]], [0, s, (1 - s) * h / 2 + off[1]], [0, 0, 1.0]])
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    Ai = np.linalg.inv(T) @ A @ T  # A acts on continuous pixels, warpAffine on indices
    img = cv2.warpAffine(map_img, Ai[:2], (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    f = img.astype(np.float32) / 255.0
    f = 0.85 * (f ** 0.8) + 0.05  # contrast and gamma
    f = f * np.array([0.85, 1.0, 1.12], np.float32)  # seasonal colour shift (BGR)
    f = cv2.GaussianBlur(f, (0, 0), 1.0)
    return np.clip(f * 255, 0, 255).astype(np.uint8), A


def run_flight(geomap: GeoMap, map_img: np.ndarray, n: int, refine_every_s: float, *, fps: float = 30.0,
               perturbed: bool = False, seed: int = 0) -> dict:
    size = (640, 480)
    render = Renderer(map_img, size, seed)
    A = np.eye(3)
    if perturbed:
        pmap, A = perturb_map(map_img)
        geomap._image = pmap  # the registrar reads the map through GeoMap.read_image()
    else:
        geomap._image = map_img
    cfg = RegistrationConfig(refine_every_s=refine_every_s)
    reg = FrameRegistrar(cfg, fps, geomap, A @ camera(0.0, size))
    errs, t_reg, statuses = [], 0.0, {}
    for k in range(n):
        t = k / fps
        Hm = camera(t, size)
        frame = Frame(k + 1, render(t, Hm), t)
        t0 = time.perf_counter()
        r = reg.step(frame)
        t_reg += time.perf_counter() - t0
        statuses[r.status] = statuses.get(r.status, 0) + 1
        errs.append(corner_error(r.H, A @ Hm, *size))
    geomap._image = None
    e = np.asarray(errs)
    checked = e[::30]
    return {"refine_every_s": refine_every_s, "perturbed_map": perturbed, "frames": n,
            "mean_err_px": float(e.mean()), "max_err_px": float(e.max()),
            "max_checked_err_px": float(checked.max()), "final_err_px": float(e[-1]),
            "max_err_m": float(e.max() * geomap.metres_per_pixel),
            "ms_per_frame": 1000 * t_reg / n, "statuses": statuses,
            "err_every_30_frames_px": [round(float(x), 3) for x in checked]}


def _to_continuous(H: np.ndarray) -> np.ndarray:
    """A homography between OpenCV pixel indices as one between continuous pixels (corner origin)."""
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    return T @ H @ np.linalg.inv(T)


def run_synth(n: int, refine_every_s: float, *, name: str = "default", perturbed: bool = False,
              seed: int = 0) -> dict:
    """Accuracy on the project's scenario generator (aerotrack.synth): vehicles with shadows, trees,
    an overpass, a surveying camera that moves, yaws and zooms; its map is the colourised tile and
    ``perturb_map`` gives another date's version of it."""
    from aerotrack.synth import Scenario, perturb_map

    sc = Scenario(seed=seed, frames=n, name=name)
    geomap = sc.world.geomap
    base = sc.world.image
    A = np.eye(3)
    if perturbed:
        base, A = perturb_map(base, rng=seed + 1)
        A = _to_continuous(A)
    geomap._image = base
    reg = None
    errs, t_reg, statuses = [], 0.0, {}
    for frame, H_true, _ in sc.frames():
        truth = A @ H_true  # the generator's homographies are in aerotrack's convention
        if reg is None:
            reg = FrameRegistrar(RegistrationConfig(refine_every_s=refine_every_s), sc.fps, geomap, truth)
        t0 = time.perf_counter()
        r = reg.step(frame)
        t_reg += time.perf_counter() - t0
        statuses[r.status] = statuses.get(r.status, 0) + 1
        errs.append(corner_error(r.H, truth, *sc.size))
    geomap._image = None
    e = np.asarray(errs)
    checked = e[::30]
    return {"generator": f"aerotrack.synth {name} seed {seed}", "refine_every_s": refine_every_s,
            "perturbed_map": perturbed, "frames": n, "mean_err_px": float(e.mean()),
            "max_err_px": float(e.max()), "max_checked_err_px": float(checked.max()),
            "final_err_px": float(e[-1]), "max_err_m": float(e.max() * geomap.metres_per_pixel),
            "ms_per_frame": 1000 * t_reg / n, "statuses": statuses,
            "err_every_30_frames_px": [round(float(x), 3) for x in checked]}


def map_mosaic(geomap: GeoMap, map_img: np.ndarray, n: int, out_png: Path, fps: float = 30.0) -> dict:
    """Register a generated flight against the map and paint every 30th frame onto it (fig. 2)."""
    size = (640, 480)
    render = Renderer(map_img, size, seed=3)
    geomap._image = map_img
    reg = FrameRegistrar(RegistrationConfig(), fps, geomap, camera(0.0, size))
    Hs, painted = {}, []
    for k in range(n):
        t = k / fps
        frame = Frame(k + 1, render(t, camera(t, size)), t)
        Hs[frame.index] = reg.step(frame).H
        if k % 30 == 0:
            painted.append(frame)
    geomap._image = None
    img = paint_mosaic(painted, Hs, size, base=map_img, max_side=1300, outline_every=4)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_png), img, [cv2.IMWRITE_JPEG_QUALITY, 88])
    return {"frames": n, "mosaic": str(out_png.relative_to(REPO))}


# -- real video -----------------------------------------------------------------------------------
def peer_cmc():
    from trackers import CMC, CMCConfig

    return CMC(CMCConfig(method="sparseOptFlow"))


def _affine3(A: np.ndarray) -> np.ndarray:
    return np.vstack([np.asarray(A, np.float64), [0, 0, 1]])


def bg_diff(a: np.ndarray, b: np.ndarray, H_ab: np.ndarray) -> float:
    """Median |b - warp(a)| over the pixels of b that a covers (grey levels 0-255)."""
    h, w = b.shape
    wa = cv2.warpPerspective(a.astype(np.float32), H_ab, (w, h), flags=cv2.INTER_LINEAR)
    m = cv2.warpPerspective(np.full(a.shape, 255, np.uint8), H_ab, (w, h), flags=cv2.INTER_NEAREST)
    m = cv2.erode(m, np.ones((5, 5), np.uint8)) > 0
    if m.sum() < 0.1 * m.size:
        return float("nan")
    return float(np.median(np.abs(wa.astype(np.float32) - b.astype(np.float32))[m]))


def run_real(out_png: Path) -> dict:
    from aerotrack.io import open_source

    src = open_source(TRUCK4, fps=10.0)
    reg = FrameRegistrar(RegistrationConfig(), src.fps)
    cmc = peer_cmc()
    regs, grays, peer = [], [], []
    for f in src:
        regs.append(reg.step(f))
        peer.append(_affine3(cmc.estimate(f.image)))
        grays.append(cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY))
    Hs = [r.H for r in regs]
    out = {"frames": len(regs), "statuses": dict(reg.counts),
           "inlier_ratio_median": float(np.nanmedian([r.inlier_ratio for r in regs[1:]])),
           "inliers_median": float(np.median([r.inliers for r in regs[1:]]))}
    for gap in (1, 10):
        ours, ident, theirs = [], [], []
        for k in range(0, len(regs) - gap, 2 if gap == 1 else 5):
            H_ab = np.linalg.inv(Hs[k + gap]) @ Hs[k]  # frame k -> frame k+gap
            ours.append(bg_diff(grays[k], grays[k + gap], H_ab))
            ident.append(bg_diff(grays[k], grays[k + gap], np.eye(3)))
            P = np.eye(3)
            for j in range(k + 1, k + gap + 1):
                P = peer[j] @ P
            theirs.append(bg_diff(grays[k], grays[k + gap], P))
        out[f"gap{gap}"] = {"median_abs_diff_ours": float(np.nanmedian(ours)),
                            "median_abs_diff_trackers_cmc": float(np.nanmedian(theirs)),
                            "median_abs_diff_uncompensated": float(np.nanmedian(ident)),
                            "pairs": len(ours)}
    img = paint_mosaic(src.frames(stride=5), {r.index: r.H for r in regs}, src.size, max_side=1600,
                       outline_every=8)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_png), img)
    out["mosaic"] = str(out_png.relative_to(REPO))
    return out


# -- speed ----------------------------------------------------------------------------------------
def run_speed(map_img: np.ndarray, n: int = 60) -> dict:
    if TRUCK4.exists():
        files = sorted(TRUCK4.glob("*.jpg"))[100:100 + n]
        real = [cv2.imread(str(p)) for p in files]
    else:
        real = None
    out = {}
    mg = cv2.cvtColor(map_img, cv2.COLOR_BGR2GRAY)
    for size in ((640, 480), (1280, 720), (1920, 1080)):
        frames = ([cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in real] if real
                  else None)
        # generated frames with known motion (for accuracy) at this size; ~constant ground footprint
        gsd = 0.6 * 640 / size[0]
        render = Renderer(map_img, size, seed=1, movers=0)
        truth = [camera(k / 30.0, size, gsd) for k in range(n)]
        synth = [render(k / 30.0, truth[k]) for k in range(n)]
        res = {}
        for name, seq in (("real", frames), ("generated", synth)):
            if seq is None:
                continue
            ours = FrameRegistrar(RegistrationConfig(), 30.0)
            peer = peer_cmc()
            t_ours, t_peer, e_ours, e_peer = [], [], [], []
            prevH = np.eye(3)
            for k, img in enumerate(seq):  # interleaved, so both see the same machine load
                fr = Frame(k + 1, img, k / 30.0)
                t0 = time.perf_counter()
                r = ours.step(fr)
                t1 = time.perf_counter()
                A = peer.estimate(img)
                t2 = time.perf_counter()
                if k:
                    t_ours.append(t1 - t0)
                    t_peer.append(t2 - t1)
                if name == "generated" and k:
                    true_step = np.linalg.inv(truth[k]) @ truth[k - 1]
                    e_ours.append(corner_error(np.linalg.inv(r.H) @ prevH, true_step, *size))
                    e_peer.append(corner_error(_affine3(A), true_step, *size))
                prevH = r.H
            d = {"ours_ms": 1000 * float(np.median(t_ours)), "trackers_cmc_ms": 1000 * float(np.median(t_peer)),
                 "speed_ratio": float(np.median(t_peer) / np.median(t_ours))}
            if e_ours:
                d["f2f_corner_err_px_ours"] = float(np.mean(e_ours))
                d["f2f_corner_err_px_trackers_cmc"] = float(np.mean(e_peer))
            res[name] = d
        # one refinement: rough = truth shifted by a few map pixels
        t_ref, e_ref = [], []
        for k in range(0, n, max(1, n // 8)):
            rough = np.array([[1, 0, 4.0], [0, 1, -3.0], [0, 0, 1]]) @ truth[k]
            t0 = time.perf_counter()
            rr = refine_against_map(synth[k], rough, mg)
            t_ref.append(time.perf_counter() - t0)
            if rr:
                e_ref.append(corner_error(rr[0], truth[k], *size))
        peer_ms = res.get("real", res["generated"])["trackers_cmc_ms"]
        res["refine"] = {"ms": 1000 * float(np.median(t_ref)),
                         "ratio_to_trackers_cmc_frame": float(1000 * np.median(t_ref) / peer_ms),
                         "err_after_px": float(np.mean(e_ref)) if e_ref else float("nan"),
                         "ok": len(e_ref), "tried": len(t_ref)}
        out[f"{size[0]}x{size[1]}"] = res
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1800, help="frames of the generated flight")
    ap.add_argument("--k", type=float, nargs="*", default=[0.5, 1.0, 2.0, 5.0],
                    help="refinement periods K (s) to compare")
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-synth", action="store_true", help="skip the aerotrack.synth scenes")
    args = ap.parse_args(argv)
    cv2.setRNGSeed(0)
    geomap = GeoMap(TILE)
    map_img = geomap.read_image().copy()
    import json

    from common import RESULTS

    previous = RESULTS / "registration.json"  # parts skipped this time keep their last results
    results = json.loads(previous.read_text()) if previous.exists() else {}
    results.update({"opencv": cv2.__version__, "metres_per_map_px": geomap.metres_per_pixel})
    if not args.skip_speed:
        results["speed"] = sp = run_speed(map_img)
        print("\nspeed per frame (median ms; ratio = trackers CMC time / ours, >1 means faster)")
        print(f"{'size':>10} {'seq':>10} {'ours':>7} {'trackers':>9} {'ratio':>6} {'err ours':>9} "
              f"{'err trk':>8}")
        for size, r in sp.items():
            for name in ("real", "generated"):
                if name in r:
                    d = r[name]
                    print(f"{size:>10} {name:>10} {d['ours_ms']:7.2f} {d['trackers_cmc_ms']:9.2f} "
                          f"{d['speed_ratio']:6.2f} {d.get('f2f_corner_err_px_ours', float('nan')):9.3f} "
                          f"{d.get('f2f_corner_err_px_trackers_cmc', float('nan')):8.3f}")
            f = r["refine"]
            print(f"{size:>10} {'refine':>10} {f['ms']:7.1f}   = {f['ratio_to_trackers_cmc_frame']:.1f} "
                  f"trackers-CMC frames, error after {f['err_after_px']:.3f} px ({f['ok']}/{f['tried']})")
    if not args.skip_accuracy:
        runs = [run_flight(geomap, map_img, args.frames, 0.0)]
        runs += [run_flight(geomap, map_img, args.frames, k) for k in args.k]
        runs.append(run_flight(geomap, map_img, args.frames, 1.0, perturbed=True))
        results["accuracy"] = runs
        print(f"\naccuracy over {args.frames} generated frames (640x480, 30 fps; map "
              f"{geomap.metres_per_pixel:.2f} m/px); corner error in map px")
        print(f"{'refine K':>9} {'map':>9} {'mean':>6} {'max@30':>7} {'max':>6} {'max m':>6} {'ms/frame':>8}")
        for r in runs:
            k = "none" if r["refine_every_s"] == 0 else f"{r['refine_every_s']:g} s"
            print(f"{k:>9} {'perturbed' if r['perturbed_map'] else 'same':>9} {r['mean_err_px']:6.2f} "
                  f"{r['max_checked_err_px']:7.2f} {r['max_err_px']:6.2f} {r['max_err_m']:6.2f} "
                  f"{r['ms_per_frame']:8.2f}")
    if not args.skip_synth:
        runs = [run_synth(args.frames, 0.0), run_synth(args.frames, 1.0),
                run_synth(args.frames, 1.0, perturbed=True)]
        results["accuracy_synth"] = runs
        print(f"\naccuracy on aerotrack.synth 'default' ({args.frames} frames, 640x480, 30 fps, "
              "vehicles, shadows, trees, overpass); corner error in map px")
        print(f"{'refine K':>9} {'map':>9} {'mean':>6} {'max@30':>7} {'max':>6} {'max m':>6} {'ms/frame':>8}")
        for r in runs:
            k = "none" if r["refine_every_s"] == 0 else f"{r['refine_every_s']:g} s"
            print(f"{k:>9} {'perturbed' if r['perturbed_map'] else 'same':>9} {r['mean_err_px']:6.2f} "
                  f"{r['max_checked_err_px']:7.2f} {r['max_err_px']:6.2f} {r['max_err_m']:6.2f} "
                  f"{r['ms_per_frame']:8.2f}")
    if not args.skip_accuracy:
        results["map_mosaic"] = map_mosaic(geomap, map_img, min(args.frames, 900),
                                           REPO / "docs/images/mosaic_vegas_generated.jpg")
    if not args.skip_real and TRUCK4.exists():
        results["truck4"] = tr = run_real(REPO / "docs/images/mosaic_truck4.png")
        print(f"\ntruck4 (no map): {tr['statuses']}, median inlier ratio {tr['inlier_ratio_median']:.3f}")
        for gap in (1, 10):
            g = tr[f"gap{gap}"]
            print(f"  frames {gap} apart: median |diff| ours {g['median_abs_diff_ours']:.2f}, trackers CMC "
                  f"{g['median_abs_diff_trackers_cmc']:.2f}, uncompensated "
                  f"{g['median_abs_diff_uncompensated']:.2f} grey levels")
    path = write_results("registration", results)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    sys.exit(main())

"""How close does a telemetry start land? The Songdo DJI flight log against Geo-trax's homographies.

Data: ../shared/data/songdo_geotrax_sample_tracks/ (see its SOURCE.md): a real DJI flight log
(lat, lon, height above take-off, 35-mm-equivalent focal length; **no heading or gimbal angles**) and
the georeferenced tracks Geo-trax derived for the same 150 frames. There is no orthophoto there, so
the truth is expressed in EPSG:5186 metres: for every frame, a homography frame pixels -> EPSG:5186
is fitted to Geo-trax's (box centre in frame pixels, Local_X/Local_Y) pairs (~130 vehicles/frame,
residual a few mm, i.e. Geo-trax's own frame-to-ortho registration, which is itself a fit to the
orthophoto).

The telemetry start is :func:`aerotrack.geo.telemetry.pose_homography` for the logged pose: a nadir
pinhole (pitch -90) at the logged position and height, field of view from the focal length. The log
has no heading, so three cases are measured:

* ``heading 0 (unknown)``: what a north-up guess gives (the image is really rotated ~52 deg);
* ``heading from truth``: the heading taken from the truth homography (an oracle for the column
  this log lacks; a log with compass/gimbal yaw provides it), isolating the error of the logged
  position, height and field of view;
* ``heading error +/- N deg``: the sensitivity to compass error.

Errors: distance between the four frame corners (and the centre) mapped by the telemetry start and
by the truth, metres on the ground. Also reported: the best pinhole pose fitted to the truth (what
the log got wrong: position offset, effective height, tilt).

Lock-on (before / after refinement): without a Songdo orthophoto, the errors measured above are
replayed on the bundled Las Vegas tile (see :func:`lock_on`): map refinement alone
(``registration.mapref``, 12 map-px search) against ``geo.telemetry.coarse_align`` followed by it.

Run: ``/tmp/venv/bin/python benchmarks/telemetry_init.py`` (about 15 s).
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED_DATA, Timer, require_data, write_results

from aerotrack.geo.telemetry import CameraPose, pose_homography, read_telemetry_csv

DATA = SHARED_DATA / "songdo_geotrax_sample_tracks"
FRAME_SIZE = (3840, 2160)  # 4K UHD; Geo-trax's largest box centre is at x = 3834
CRS = "EPSG:5186"
FPS = 30.0


def truth_homographies(folder: Path) -> tuple[dict[int, np.ndarray], dict[int, float]]:
    """{1-based frame: H frame px -> EPSG:5186} fitted to Geo-trax's observations; and residuals (m)."""
    px = np.loadtxt(folder / "results-full_U_video_cut.txt", delimiter=",")
    geo: dict[tuple[int, int], tuple[float, float]] = {}
    with open(folder / "results-full_U_video_cut.csv", newline="") as fh:
        for r in csv.DictReader(fh):
            geo[(int(r["Frame_Number"]), int(r["Vehicle_ID"]))] = (float(r["Local_X"]),
                                                                    float(r["Local_Y"]))
    Hs, res = {}, {}
    o = np.array([[float(r["Ortho_X"]), float(r["Ortho_Y"])] for r in _csv_rows(folder)])
    m = np.array([[float(r["Local_X"]), float(r["Local_Y"])] for r in _csv_rows(folder)])
    A = np.linalg.lstsq(np.c_[o, np.ones(len(o))], m, rcond=None)[0]
    res["ortho_gsd_m"] = float(np.sqrt(abs(np.linalg.det(A[:2]))))
    for f in np.unique(px[:, 0]).astype(int):
        rows = px[px[:, 0] == f]
        pairs = [(r[2:4], geo[(f, int(r[1]))]) for r in rows if (f, int(r[1])) in geo]
        if len(pairs) < 8:
            continue
        src = np.array([p[0] for p in pairs], np.float64)
        dst = np.array([p[1] for p in pairs], np.float64)
        mu = dst.mean(axis=0)
        H, _ = cv2.findHomography(src, dst - mu, 0)
        H = np.array([[1, 0, mu[0]], [0, 1, mu[1]], [0, 0, 1]]) @ H
        H /= H[2, 2]
        Hs[f + 1] = H
        res[f + 1] = float(np.median(np.linalg.norm(_apply(H, src) - dst, axis=1)))
    return Hs, res


def _csv_rows(folder: Path) -> list[dict]:
    with open(folder / "results-full_U_video_cut.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _apply(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return cv2.perspectiveTransform(np.asarray(pts, np.float64).reshape(1, -1, 2), H)[0]


CORNERS = np.array([[0, 0], [FRAME_SIZE[0], 0], [FRAME_SIZE[0], FRAME_SIZE[1]],
                    [0, FRAME_SIZE[1]]], np.float64)
CENTRE = np.array([[FRAME_SIZE[0] / 2, FRAME_SIZE[1] / 2]])


def errors(H_est: np.ndarray, H_true: np.ndarray) -> dict[str, float]:
    c = np.linalg.norm(_apply(H_est, CORNERS) - _apply(H_true, CORNERS), axis=1)
    m = float(np.linalg.norm(_apply(H_est, CENTRE) - _apply(H_true, CENTRE)))
    return {"corner_mean_m": float(c.mean()), "corner_max_m": float(c.max()), "centre_m": m}


def true_heading(H: np.ndarray) -> float:
    """Azimuth of the image's 'up' direction on the ground, degrees clockwise from true north."""
    from pyproj import Geod, Transformer

    t = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True)
    a, b = _apply(H, CENTRE)[0], _apply(H, CENTRE + [[0, -100]])[0]
    (lon0, lon1), (lat0, lat1) = t.transform([a[0], b[0]], [a[1], b[1]])
    az, _, _ = Geod(ellps="WGS84").inv(lon0, lat0, lon1, lat1)
    return float(az) % 360.0


def fit_pose(H_true: np.ndarray, start: CameraPose) -> tuple[CameraPose, float]:
    """Least-squares pinhole pose whose start reproduces H_true's 5x5 lattice (diagnostic).

    Free: position, height, heading, pitch (roll is fixed at 0: near nadir it is a second
    rotation about the vertical, indistinguishable from heading). The field of view stays at the
    logged one (it trades off exactly against height over flat ground).
    """
    from scipy.optimize import least_squares

    grid = np.stack(np.meshgrid(np.linspace(0, FRAME_SIZE[0], 5),
                                np.linspace(0, FRAME_SIZE[1], 5)), -1).reshape(-1, 2)
    target = _apply(H_true, grid)
    m_per_deg_lat = 111_000.0
    m_per_deg_lon = 111_000.0 * math.cos(math.radians(start.lat))

    def pose(v):
        return CameraPose(lon=start.lon + v[0] / m_per_deg_lon, lat=start.lat + v[1] / m_per_deg_lat,
                          alt_m=start.alt_m * (1 + v[2]), heading_deg=start.heading_deg + v[3],
                          pitch_deg=-90 + v[4], roll_deg=0.0, hfov_deg=start.hfov_deg)

    def resid(v):
        H = pose_homography(pose(v), FRAME_SIZE, CRS, grid=5)
        return (_apply(H, grid) - target).ravel()

    # Small steps in lon/lat would vanish in 5e5 m coordinates: a visible diff_step.
    sol = least_squares(resid, np.zeros(5), diff_step=1e-4, x_scale=[1, 1, 0.01, 1, 1])
    return pose(sol.x), float(np.sqrt(np.mean(sol.fun ** 2)))


# -- lock-on: does map refinement converge from a telemetry-sized error? -----------------------
TILE = Path(__file__).resolve().parents[1] / "src" / "aerotrack" / "synth" / "data" / "vegas_tile.tif"


def lock_on(pos_err_m: float, height_ratio: float, heading_err_deg: float, pitch_err_deg: float,
            *, trials: int = 8, seed: int = 0) -> list[dict]:
    """Map refinement from telemetry-sized errors, without and with the coarse lock-on.

    There is no Songdo orthophoto, so the bundled Las Vegas tile (0.27 m/px) plays the map: a
    960x540 frame is rendered from it through a nadir pinhole at 100 m (the Songdo field of view,
    random heading), with gain, offset and noise, and refinement starts from the pose perturbed by
    the errors measured on the Songdo log (position offset in a random direction, height ratio,
    heading error of random sign, pitch error). The same imagery on both sides makes this an upper
    bound on lock-on; the geometry is what is tested.

    Methods: ``refine`` = ``registration.mapref.refine_against_map`` with the default search
    (12 map px), as the registrar's first anchor does; ``coarse+refine`` =
    :func:`aerotrack.geo.telemetry.coarse_align` (search = 3x the position error, +-6 deg) first.
    """
    from aerotrack.geo import GeoMap
    from aerotrack.geo.telemetry import coarse_align, map_pixel_aspect
    from aerotrack.registration.mapref import refine_against_map
    from aerotrack.types import Failure

    gm = GeoMap(TILE)
    map_img = gm.read_image()
    aspect = map_pixel_aspect(gm)  # the tile is in lon/lat degrees: pixels are not square
    rng = np.random.default_rng(seed)
    size = (960, 540)
    c_ll = gm.pixel_to_lonlat([[gm.width / 2, gm.height / 2]])[0]
    corners = np.array([[0, 0], [size[0], 0], [size[0], size[1]], [0, size[1]]], float)
    out = []
    for k in range(trials):
        true = CameraPose(lon=float(c_ll[0]), lat=float(c_ll[1]), alt_m=100.0,
                          heading_deg=float(rng.uniform(0, 360)), pitch_deg=-90.0,
                          hfov_deg=73.7)
        H_true = pose_homography(true, size, gm)
        frame = cv2.warpPerspective(map_img, _cv_h(np.linalg.inv(H_true)), size,
                                    flags=cv2.INTER_LINEAR)
        frame = np.clip(frame.astype(np.float64) * 0.9 + 12 + rng.normal(0, 3, frame.shape),
                        0, 255).astype(np.uint8)
        az = rng.uniform(0, 2 * math.pi)
        dlat = pos_err_m * math.cos(az) / 111_000.0
        dlon = pos_err_m * math.sin(az) / (111_000.0 * math.cos(math.radians(true.lat)))
        sign = float(rng.choice([-1.0, 1.0]))
        start = CameraPose(lon=true.lon + dlon, lat=true.lat + dlat, alt_m=100.0 * height_ratio,
                           heading_deg=true.heading_deg + sign * heading_err_deg,
                           pitch_deg=-90.0 + pitch_err_deg, hfov_deg=true.hfov_deg)
        H0 = pose_homography(start, size, gm)

        def err_m(H, H_true=H_true):
            return float(np.mean(np.linalg.norm(_apply(H, corners) - _apply(H_true, corners),
                                                axis=1))) * gm.metres_per_pixel

        def refine(H, frame=frame):
            r = refine_against_map(frame, H, map_img)
            return None if isinstance(r, Failure) else r[0]

        row = {"trial": k, "before_m": err_m(H0)}
        H = refine(H0)
        row["refine_m"] = err_m(H) if H is not None else float("nan")
        ca = coarse_align(frame, H0, map_img, search_px=3 * pos_err_m / gm.metres_per_pixel,
                          pixel_aspect=aspect)
        if isinstance(ca, Failure):
            row["coarse_m"] = row["coarse_refine_m"] = float("nan")
        else:
            row["coarse_m"] = err_m(ca[0])
            H = refine(ca[0])
            row["coarse_refine_m"] = err_m(H) if H is not None else float("nan")
        out.append(row)
    return out


def _cv_h(H: np.ndarray) -> np.ndarray:
    """aerotrack pixel convention (centres at +0.5) -> OpenCV's (centres at 0) for warpPerspective."""
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    return np.linalg.inv(T) @ H @ T


def main() -> None:
    require_data(DATA)
    with Timer() as t_truth:
        truth, resid = truth_homographies(DATA)
    ortho_gsd = resid.pop("ortho_gsd_m")
    tel = read_telemetry_csv(DATA / "U_video_cut_flightlog.csv", fps=FPS, frame_base=0,
                             defaults={"heading_deg": 0.0}, option="flight log")
    frames = sorted(truth)
    h_true = {f: true_heading(truth[f]) for f in frames}
    rows = []

    def case(name: str, heading_of) -> dict:
        errs = [errors(pose_homography(_with_heading(tel.pose_at_frame(f, FPS), heading_of(f)),
                                       FRAME_SIZE, CRS), truth[f]) for f in frames]
        r = {"case": name,
             "frame1": errs[0],
             "median_over_frames": {k: float(np.median([e[k] for e in errs])) for k in errs[0]},
             "max_over_frames": {k: float(np.max([e[k] for e in errs])) for k in errs[0]}}
        rows.append(r)
        return r

    with Timer() as t_cases:
        case("heading 0 (unknown, north-up guess)", lambda f: 0.0)
        case("heading from truth (oracle)", lambda f: h_true[f])
        for d in (2.0, 5.0, 10.0):
            case(f"heading error {d:+.0f} deg", lambda f, d=d: h_true[f] + d)
    fitted, rms = fit_pose(truth[1], _with_heading(tel.pose_at_frame(1, FPS), h_true[1]))
    logged = tel.pose_at_frame(1, FPS)
    from pyproj import Transformer

    to5186 = Transformer.from_crs("EPSG:4326", CRS, always_xy=True)
    lx, ly = to5186.transform(logged.lon, logged.lat)
    fx, fy = to5186.transform(fitted.lon, fitted.lat)
    diag = {"logged": {"lon": logged.lon, "lat": logged.lat, "alt_m": logged.alt_m,
                       "hfov_deg": logged.hfov_deg},
            "fitted": {"lon": fitted.lon, "lat": fitted.lat, "alt_m": fitted.alt_m,
                       "heading_deg": fitted.heading_deg, "pitch_deg": fitted.pitch_deg,
                       "roll_deg": fitted.roll_deg, "rms_m": rms},
            "position_offset_m": float(math.hypot(fx - lx, fy - ly)),
            "height_ratio_fitted_over_logged": fitted.alt_m / logged.alt_m,
            "truth_heading_frame1_deg": h_true[1],
            "orthophoto_gsd_m": ortho_gsd,
            "oracle_heading_corner_mean_in_ortho_px": rows[1]["frame1"]["corner_mean_m"] / ortho_gsd,
            "truth_fit_residual_median_m": float(np.median(list(resid.values())))}

    print(f"Songdo DJI log vs Geo-trax homographies: {len(frames)} frames, frame {FRAME_SIZE[0]}x"
          f"{FRAME_SIZE[1]}, truth fit residual median {diag['truth_fit_residual_median_m']*1000:.1f} mm")
    print(f"{'case':40s} {'frame 1 corner mean/max (m)':>28s} {'centre':>7s} "
          f"{'all frames median corner mean':>30s}")
    for r in rows:
        f1, md = r["frame1"], r["median_over_frames"]
        print(f"{r['case']:40s} {f1['corner_mean_m']:13.1f} / {f1['corner_max_m']:6.1f}      "
              f"{f1['centre_m']:7.1f} {md['corner_mean_m']:30.1f}")
    print(f"best-fit pinhole vs log: position off by {diag['position_offset_m']:.1f} m, height x"
          f"{diag['height_ratio_fitted_over_logged']:.3f}, pitch {fitted.pitch_deg:.2f} deg, "
          f"heading {fitted.heading_deg:.1f} deg (rms {rms:.2f} m)")
    print(f"Geo-trax orthophoto: {ortho_gsd:.4f} m/px, so the oracle-heading start is off by "
          f"{diag['oracle_heading_corner_mean_in_ortho_px']:.0f} orthophoto pixels at the corners")
    # Lock-on with the errors measured above, heading error 2 deg (a good compass) and 5 deg.
    lock_summary = []
    with Timer() as t_lock:
        for hd in (2.0, 5.0):
            lk = lock_on(diag["position_offset_m"], diag["height_ratio_fitted_over_logged"], hd,
                         90.0 + fitted.pitch_deg)
            row = {"heading_err_deg": hd, "trials": len(lk), "per_trial": lk}
            for key in ("before_m", "refine_m", "coarse_m", "coarse_refine_m"):
                v = np.array([r[key] for r in lk])
                row[key + "_median"] = float(np.nanmedian(v)) if np.isfinite(v).any() else None
                row[key.replace("_m", "") + "_converged"] = int(np.sum(v < 0.5))
            lock_summary.append(row)
    print(f"\nmap refinement from a telemetry start ({diag['position_offset_m']:.1f} m offset, "
          f"height x{diag['height_ratio_fitted_over_logged']:.3f}, pitch "
          f"{90 + fitted.pitch_deg:.1f} deg), Las Vegas tile as the map (0.27 m/px); corner error "
          f"mean in m, median over trials [converged < 0.5 m]:")
    print(f"{'heading err':>11s} {'start':>8s} {'refine only':>16s} {'coarse_align':>16s} "
          f"{'coarse+refine':>16s}")

    def cell(r, key):
        v = r[key + "_m_median"]
        txt = "fail" if v is None else f"{v:.2f}"
        return f"{txt:>8s} [{r[key + '_converged']}/{r['trials']}]"

    for r in lock_summary:
        print(f"{r['heading_err_deg']:9.0f} d {r['before_m_median']:8.2f} {cell(r, 'refine'):>16s} "
              f"{cell(r, 'coarse'):>16s} {cell(r, 'coarse_refine'):>16s}")
    out = write_results("telemetry_init", {
        "lock_on": {"summary": lock_summary, "seconds": t_lock.seconds,
                    "map": "bundled Las Vegas tile (0.27 m/px); frames rendered from it"},
        "data": str(DATA.name), "frame_size": FRAME_SIZE, "crs": CRS, "frames": len(frames),
        "cases": rows, "diagnosis": diag,
        "seconds": {"truth_fit": t_truth.seconds, "telemetry_starts": t_cases.seconds},
        "note": "errors in metres on the ground (EPSG:5186); the log has no heading column"})
    print(f"wrote {out}")


def _with_heading(p: CameraPose, heading: float) -> CameraPose:
    return CameraPose(lon=p.lon, lat=p.lat, alt_m=p.alt_m, heading_deg=heading % 360.0,
                      pitch_deg=p.pitch_deg, roll_deg=p.roll_deg, hfov_deg=p.hfov_deg)


if __name__ == "__main__":
    main()

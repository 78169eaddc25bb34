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

Run: ``/tmp/venv/bin/python benchmarks/telemetry_init.py`` (a few seconds).
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED_DATA, Timer, require_data, write_results  # noqa: E402

from aerotrack.geo.telemetry import (CameraPose, pose_homography,  # noqa: E402
                                     read_telemetry_csv)

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
          f"{diag['height_ratio_fitted_over_logged']:.3f}, pitch {fitted.pitch_deg:.2f} deg, heading {fitted.heading_deg:.1f} deg (rms {rms:.2f} m)")
    print(f"Geo-trax orthophoto: {ortho_gsd:.4f} m/px, so the oracle-heading start is off by "
          f"{diag['oracle_heading_corner_mean_in_ortho_px']:.0f} orthophoto pixels at the corners")
    out = write_results("telemetry_init", {
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

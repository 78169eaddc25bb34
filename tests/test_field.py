"""Field-ready inputs and outputs: telemetry, control points, lens, scope, per-observation table."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from pyproj import CRS, Geod, Transformer

from aerotrack.errors import FormatError, InputError
from aerotrack.geo import GeoMap, read_map_init
from aerotrack.geo.lens import Undistorter, read_intrinsics
from aerotrack.geo.qgis import read_qgis_points, write_qgis_points
from aerotrack.geo.roi import filter_min_speed, read_region, track_max_speed
from aerotrack.geo.telemetry import (
    CameraPose,
    coarse_align,
    ground_sample_distance,
    hfov_from_focal,
    map_pixel_aspect,
    metres_per_unit,
    pose_homography,
    read_dji_srt,
    read_telemetry,
    read_telemetry_csv,
)
from aerotrack.io.geotable import read_registration_csv, utm_crs_for, write_observation_table
from aerotrack.types import Track, TrackPoint, apply_homography

TILE = Path(__file__).resolve().parents[1] / "src" / "aerotrack" / "synth" / "data" / "vegas_tile.tif"
LON0, LAT0 = -115.2320, 36.1405  # inside the bundled Las Vegas tile
UTM11 = "EPSG:32611"


@pytest.fixture(scope="module")
def geomap() -> GeoMap:
    return GeoMap(TILE)


def _utm(lon, lat):
    t = Transformer.from_crs("EPSG:4326", UTM11, always_xy=True)
    return np.column_stack(t.transform(np.atleast_1d(lon), np.atleast_1d(lat)))


# -- telemetry: the pinhole over flat ground ------------------------------------------------
@pytest.mark.parametrize("heading, corner_azimuth", [(0.0, 315.0), (90.0, 45.0), (200.0, 155.0)])
def test_nadir_camera_footprint(heading, corner_azimuth):
    # hfov 90 deg at 100 m: the square frame covers 200 m x 200 m centred below the camera, so
    # the top-left corner lies 141.4 m away, 45 deg left of the heading (true north based).
    pose = CameraPose(lon=LON0, lat=LAT0, alt_m=100.0, heading_deg=heading, hfov_deg=90.0)
    H = pose_homography(pose, (1000, 1000), "EPSG:4326")
    (clon, clat), (tlon, tlat) = apply_homography(H, [[500, 500], [0, 0]])
    geod = Geod(ellps="WGS84")
    assert geod.inv(LON0, LAT0, clon, clat)[2] < 0.01
    az, _, dist = geod.inv(LON0, LAT0, tlon, tlat)
    assert dist == pytest.approx(100 * math.sqrt(2), abs=0.05)
    assert az % 360 == pytest.approx(corner_azimuth, abs=0.01)


def test_oblique_camera_and_sky():
    # Pitch -45 deg: the principal ray meets the ground alt metres ahead (north).
    pose = CameraPose(lon=LON0, lat=LAT0, alt_m=50.0, heading_deg=0.0, pitch_deg=-45.0,
                      hfov_deg=60.0)
    H = pose_homography(pose, (640, 480), UTM11)
    d = apply_homography(H, [[320, 240]])[0] - _utm(LON0, LAT0)[0]
    assert np.hypot(*d) == pytest.approx(50.0, rel=1e-3)  # UTM scale factor 0.9997
    # ... towards true north, which is 1.04 deg west of grid north here (meridian convergence)
    assert math.degrees(math.atan2(d[0], d[1])) == pytest.approx(-1.04, abs=0.03)
    sky = CameraPose(lon=LON0, lat=LAT0, alt_m=50.0, heading_deg=0.0, pitch_deg=30.0,
                     hfov_deg=40.0)
    res = pose_homography(sky, (640, 480), UTM11)
    assert not res and "ground" in res.reason


def test_pose_to_map_pixels(geomap):
    pose = CameraPose(lon=LON0, lat=LAT0, alt_m=60.0, heading_deg=30.0, hfov_deg=70.0)
    H = pose_homography(pose, (640, 360), geomap)
    centre_ll = geomap.pixel_to_lonlat(apply_homography(H, [[320, 180]]))[0]
    _, _, dist = Geod(ellps="WGS84").inv(LON0, LAT0, *centre_ll)
    assert dist < 0.05
    # metres per frame pixel at the centre equals the nadir GSD
    gsd = ground_sample_distance(60.0, 640, hfov_deg=70.0)
    a, b = geomap.pixel_to_lonlat(apply_homography(H, [[320, 180], [330, 180]]))
    assert Geod(ellps="WGS84").inv(*a, *b)[2] / 10 == pytest.approx(gsd, rel=0.001)


def test_telemetry_csv_interpolation_and_errors(tmp_path):
    p = tmp_path / "log.csv"
    p.write_text("# drone log\nframe,lon,lat,alt_m,heading_deg,hfov_deg\n"
                 f"1,{LON0},{LAT0},100,359,80\n31,{LON0 + 0.001},{LAT0},120,1,80\n")
    tel = read_telemetry_csv(p, fps=30.0)
    pose = tel.pose_at_frame(16, 30.0)
    assert pose.lon == pytest.approx(LON0 + 0.0005)
    assert pose.alt_m == pytest.approx(110.0)
    assert pose.heading_deg % 360 == pytest.approx(0.0, abs=1e-9)  # across north, not via 180
    assert pose.pitch_deg == -90.0 and pose.roll_deg == 0.0
    bad = tmp_path / "bad.csv"
    bad.write_text(f"frame,lon,lat,alt_m,heading_deg,hfov_deg\n1,{LON0},{LAT0},100,0,80\n"
                   f"2,{LON0},north,100,0,80\n")
    with pytest.raises(FormatError, match=r"bad\.csv line 3: lat is not a number"):
        read_telemetry_csv(bad)
    short = tmp_path / "short.csv"
    short.write_text(f"frame,lon,lat,alt_m,heading_deg,hfov_deg\n1,{LON0},{LAT0},100\n")
    with pytest.raises(FormatError, match=r"short\.csv line 2: expected 6 cells"):
        read_telemetry_csv(short)
    nohead = tmp_path / "nohead.csv"
    nohead.write_text(f"frame,lon,lat,alt_m,hfov_deg\n1,{LON0},{LAT0},100,80\n")
    with pytest.raises(FormatError, match="no heading_deg"):
        read_telemetry_csv(nohead)
    assert read_telemetry_csv(nohead, defaults={"heading_deg": 12}).heading_deg[0] == 12
    ground = tmp_path / "ground.csv"
    ground.write_text(f"frame,lon,lat,alt_m,heading_deg,hfov_deg\n1,{LON0},{LAT0},-3,0,80\n")
    with pytest.raises(FormatError, match="line 2: alt_m"):
        read_telemetry_csv(ground)
    with pytest.raises(InputError, match="not found"):
        read_telemetry(tmp_path / "missing.csv")


SONGDO = "songdo_geotrax_sample_tracks"


def _songdo_truth_frame1(folder: Path) -> np.ndarray:
    """Frame 1 pixels -> EPSG:5186 from Geo-trax's own (pixel, Local_X/Y) pairs."""
    px = np.loadtxt(folder / "results-full_U_video_cut.txt", delimiter=",")
    px = px[px[:, 0] == 0]
    with open(folder / "results-full_U_video_cut.csv", newline="") as fh:
        geo = {int(r["Vehicle_ID"]): (float(r["Local_X"]), float(r["Local_Y"]))
               for r in csv.DictReader(fh) if r["Frame_Number"] == "0"}
    src = np.array([r[2:4] for r in px if int(r[1]) in geo])
    dst = np.array([geo[int(r[1])] for r in px if int(r[1]) in geo])
    mu = dst.mean(axis=0)
    H, _ = cv2.findHomography(src, dst - mu, 0)
    return np.array([[1, 0, mu[0]], [0, 1, mu[1]], [0, 0, 1]]) @ H


@pytest.mark.data
def test_songdo_flight_log_lands_near_geotrax(shared_data):
    folder = shared_data / SONGDO
    truth = _songdo_truth_frame1(folder)
    size = (3840, 2160)
    corners = np.array([[0, 0], [size[0], 0], [size[0], size[1]], [0, size[1]]], float)
    # The log has no heading: take the image's true azimuth from the truth (what a log with
    # compass yaw provides); everything else comes from the DJI log as is.
    up = apply_homography(truth, [[1920, 1080], [1920, 980]])
    heading = math.degrees(math.atan2(*(up[1] - up[0]))) % 360  # grid ~ true north here (0.2 deg)
    tel = read_telemetry_csv(folder / "U_video_cut_flightlog.csv", frame_base=0,
                             defaults={"heading_deg": heading})
    assert len(tel) == 151 and tel.hfov_deg[0] == pytest.approx(hfov_from_focal(24.0))
    H = tel.homography(1, 30.0, size, "EPSG:5186")
    err = np.linalg.norm(apply_homography(H, corners) - apply_homography(truth, corners), axis=1)
    assert err.max() < 10.0  # metres, on a 220 m x 125 m footprint (measured: mean 5.8, max 8.1)
    wrong = read_telemetry_csv(folder / "U_video_cut_flightlog.csv", frame_base=0,
                               defaults={"heading_deg": heading + 10})
    err10 = np.linalg.norm(apply_homography(wrong.homography(1, 30.0, size, "EPSG:5186"), corners)
                           - apply_homography(truth, corners), axis=1)
    assert err10.mean() > err.mean() + 10  # the heading matters: 10 deg costs > 10 m


@pytest.mark.data
def test_dji_srt_subtitles(shared_data, tmp_path):
    # DJI Mavic 3-style subtitles rebuilt from the first rows of the real Songdo log.
    with open(shared_data / SONGDO / "U_video_cut_flightlog.csv", newline="") as fh:
        log = list(csv.DictReader(fh))[:5]
    cues = []
    for i, r in enumerate(log):
        t0, t1 = i * 33, (i + 1) * 33
        cues.append(
            f"{i + 1}\n00:00:00,{t0:03d} --> 00:00:00,{t1:03d}\n"
            f'<font size="28">FrameCnt: {i + 1}, DiffTime: 33ms\n{r["timestamp"]}\n'
            f"[iso: {r['iso']}] [shutter: {r['shutter']}] [fnum: {r['fnum']}] [ev: {r['ev']}] "
            f"[color_md : {r['color_md']}] [focal_len: {r['focal_len']}] "
            f"[latitude: {r['latitude']}] [longitude: {r['longitude']}] "
            f"[rel_alt: {r['rel_alt']} abs_alt: {r['abs_alt']}] [ct: {r['ct']}] </font>\n")
    srt = tmp_path / "DJI_0001.SRT"
    srt.write_text("\n".join(cues))
    tel = read_telemetry(srt, defaults={"heading_deg": 308.0})
    assert len(tel) == 5
    np.testing.assert_allclose(tel.time_s, [0, 0.033, 0.066, 0.099, 0.132])
    assert tel.lat[0] == pytest.approx(float(log[0]["latitude"]))
    assert tel.lon[0] == pytest.approx(float(log[0]["longitude"]))
    assert tel.alt_m[0] == pytest.approx(146.0)  # rel_alt, not abs_alt
    assert tel.hfov_deg[0] == pytest.approx(hfov_from_focal(24.0))
    empty = tmp_path / "empty.srt"
    empty.write_text("1\n00:00:00,000 --> 00:00:00,033\nno telemetry here\n")
    with pytest.raises(FormatError, match="no DJI telemetry"):
        read_dji_srt(empty)


def test_scale_without_a_map(geomap):
    assert ground_sample_distance(100.0, 1000, hfov_deg=90.0) == pytest.approx(0.2)
    # 8.8 mm on a 13.2 mm wide sensor, 4000 px, 100 m: f = 2666.7 px
    assert ground_sample_distance(100.0, 4000, focal_mm=8.8, sensor_width_mm=13.2) == \
        pytest.approx(0.0375)
    assert ground_sample_distance(100.0, 1000, focal_35mm=18.0) == pytest.approx(0.2)
    assert metres_per_unit(gsd=0.05) == 0.05
    assert metres_per_unit(altitude_m=100.0, image_width_px=1000, hfov_deg=90.0) == \
        pytest.approx(0.2)
    assert metres_per_unit(gsd=0.05, geomap=geomap) == geomap.metres_per_pixel
    assert metres_per_unit() is None
    with pytest.raises(InputError, match="--gsd"):
        metres_per_unit(gsd=-1.0)
    with pytest.raises(InputError, match="focal length"):
        ground_sample_distance(100.0, 1000)


# -- control points in a map CRS ------------------------------------------------------------
H_TRUE = np.array([[0.9, 0.25, 300.0], [-0.2, 0.95, 420.0], [1e-5, 2e-5, 1.0]])


def _gcps(geomap):
    frame = np.array([[20, 30], [600, 40], [620, 450], [30, 460], [320, 240], [150, 380]], float)
    mapll = geomap.pixel_to_lonlat(apply_homography(H_TRUE, frame))
    return frame, mapll


def test_qgis_points_in_another_crs(geomap, tmp_path):
    frame, ll = _gcps(geomap)
    utm = _utm(ll[:, 0], ll[:, 1])
    p = tmp_path / "frame1.points"
    write_qgis_points(p, frame, utm, crs=UTM11)
    # An extra, disabled, wildly wrong point (QGIS keeps them with enable = 0).
    with open(p, "a") as fh:
        fh.write("999999,1,5,-5,0,0,0,0\n")
    text = p.read_text().splitlines()
    assert text[0].startswith("#CRS: PROJCRS") and text[1].startswith("mapX,mapY,sourceX")
    assert float(text[2].split(",")[3]) == -30.0  # QGIS stores the negated pixel row
    H = read_map_init(p, geomap)
    corners = np.array([[0, 0], [640, 0], [640, 480], [0, 480]], float)
    np.testing.assert_allclose(apply_homography(H, corners), apply_homography(H_TRUE, corners),
                               atol=0.01)
    assert len(read_qgis_points(p).frame_xy) == 6


def test_qgis_points_old_header_without_crs_and_errors(geomap, tmp_path):
    frame, ll = _gcps(geomap)
    p = tmp_path / "old.points"  # QGIS < 3.26: pixelX/pixelY, no CRS line: the map's CRS
    p.write_text("mapX,mapY,pixelX,pixelY,enable\n" + "".join(
        f"{lo:.10f},{la:.10f},{fx},{-fy},1\n" for (lo, la), (fx, fy) in zip(ll, frame)))
    np.testing.assert_allclose(read_map_init(p, geomap)[:2], (H_TRUE / H_TRUE[2, 2])[:2],
                               rtol=1e-4, atol=1e-4)
    few = tmp_path / "few.points"
    few.write_text("mapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n" + "".join(
        f"{lo},{la},{fx},{-fy},{int(i < 3)},0,0,0\n"
        for i, ((lo, la), (fx, fy)) in enumerate(zip(ll, frame))))
    with pytest.raises(FormatError, match=r"few\.points: needs at least 4 enabled"):
        read_map_init(few, geomap)
    bad = tmp_path / "bad.points"
    bad.write_text("mapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n1,2,3,-4,1,0,0,0\n"
                   "1,2,x,-4,1,0,0,0\n")
    with pytest.raises(FormatError, match=r"bad\.points line 3: sourceX"):
        read_map_init(bad, geomap)
    with pytest.raises(InputError, match="need --map"):
        read_map_init(p)


def test_crs_gcp_csv(geomap, tmp_path):
    frame, ll = _gcps(geomap)
    utm = _utm(ll[:, 0], ll[:, 1])
    p = tmp_path / "gcps.csv"
    p.write_text("# crs: EPSG:32611\nframe_x,frame_y,crs_x,crs_y\n" + "".join(
        f"{fx},{fy},{x:.4f},{y:.4f}\n" for (fx, fy), (x, y) in zip(frame, utm)))
    H = read_map_init(p, geomap)
    np.testing.assert_allclose(apply_homography(H, frame), apply_homography(H_TRUE, frame),
                               atol=0.01)
    bad = tmp_path / "badcrs.csv"
    bad.write_text("# crs: EPSG:999999\nframe_x,frame_y,crs_x,crs_y\n1,2,3,4\n")
    with pytest.raises(FormatError, match=r"badcrs\.csv line 1: CRS"):
        read_map_init(bad, geomap)


# -- lens distortion ------------------------------------------------------------------------
CAMERA_TOML = """# A wide-angle action camera at 960x540 (coefficients of the size a GoPro calibration gives)
width = 960
height = 540
fx = 560.0
fy = 560.0
cx = 479.5
cy = 269.5
dist = [-0.28, 0.09, 0.0004, -0.0003, -0.012]
"""


def test_undistort_points_and_image(tmp_path):
    p = tmp_path / "camera.toml"
    p.write_text(CAMERA_TOML)
    cam = read_intrinsics(p)
    und = Undistorter(cam, alpha=0.0)
    # Ideal (undistorted) points, distorted by OpenCV's own forward model.
    ideal = np.stack(np.meshgrid(np.linspace(80, 880, 9), np.linspace(60, 480, 7)), -1)
    ideal = ideal.reshape(-1, 2)
    Kn = und.K_new
    rays = np.column_stack([(ideal[:, 0] - 0.5 - Kn[0, 2]) / Kn[0, 0],
                            (ideal[:, 1] - 0.5 - Kn[1, 2]) / Kn[1, 1], np.ones(len(ideal))])
    dist_pts = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0]
    dist_pts = dist_pts.reshape(-1, 2) + 0.5
    np.testing.assert_allclose(und.undistort_points(dist_pts), ideal, atol=1e-3)
    np.testing.assert_allclose(und.distort_points(ideal), dist_pts, atol=1e-6)
    assert np.abs(dist_pts - ideal).max() > 10  # the lens really bends
    # Image: bright dots drawn at the distorted positions land on the ideal grid after remap.
    img = np.zeros((540, 960), np.uint8)
    for x, y in dist_pts:
        cv2.circle(img, (int(round(x * 4 - 2)), int(round(y * 4 - 2))), 8, 255, -1,
                   lineType=cv2.LINE_AA, shift=2)
    out = und.undistort_image(img)
    n, _, _, cents = cv2.connectedComponentsWithStats((out > 60).astype(np.uint8))
    cents = cents[1:] + 0.5
    d = np.linalg.norm(cents[:, None] - ideal[None], axis=2).min(axis=0)
    assert n - 1 == len(ideal) and np.median(d) < 0.5 and d.max() < 1.0
    with pytest.raises(InputError, match="intrinsics are for 960x540"):
        und.undistort_image(np.zeros((480, 640, 3), np.uint8))


def test_bad_intrinsics(tmp_path):
    js = tmp_path / "cam.json"
    js.write_text(json.dumps({"width": 960, "height": 540,
                              "camera_matrix": [[560, 0, 480], [0, 560, 270], [0, 0, 1]],
                              "dist_coeffs": [-0.2, 0.05, 0, 0]}))
    assert read_intrinsics(js).dist.shape == (4,)
    short = tmp_path / "short.toml"
    short.write_text(CAMERA_TOML.replace("dist = [-0.28, 0.09, 0.0004, -0.0003, -0.012]",
                                         "dist = [-0.28, 0.09, 0.0004]"))
    with pytest.raises(FormatError, match=r"short\.toml: dist must have 4, 5, 8, 12 or 14"):
        read_intrinsics(short)
    nofx = tmp_path / "nofx.toml"
    nofx.write_text(CAMERA_TOML.replace("fx = 560.0\n", ""))
    with pytest.raises(FormatError, match="missing key 'fx'"):
        read_intrinsics(nofx)
    broken = tmp_path / "broken.json"
    broken.write_text('{"width": 960,\n "height": }')
    with pytest.raises(FormatError, match=r"broken\.json line 2"):
        read_intrinsics(broken)
    # found by a probe: an unknown key was ignored, normalised intrinsics taken as pixels
    typo = tmp_path / "typo.toml"
    typo.write_text(CAMERA_TOML + "focal = 3.0\n")
    with pytest.raises(FormatError, match="unknown key 'focal'"):
        read_intrinsics(typo)
    unit = tmp_path / "unit.json"
    unit.write_text(json.dumps({"width": 640, "height": 480, "fx": 0.78, "fy": 1.04, "cx": 0.5,
                                "cy": 0.5, "dist": [0, 0, 0, 0]}))
    with pytest.raises(FormatError, match="normalised intrinsics"):
        read_intrinsics(unit)


# -- scope: regions and the minimum-speed filter --------------------------------------------
def test_region_geojson_lonlat_and_frame(geomap, tmp_path):
    d = 0.0004
    ring = [[LON0 - d, LAT0 - d], [LON0 + d, LAT0 - d], [LON0 + d, LAT0 + d],
            [LON0 - d, LAT0 + d], [LON0 - d, LAT0 - d]]
    p = tmp_path / "roi.geojson"
    p.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring]}}]}))
    roi = read_region(p, geomap)
    assert roi.space == "world"
    pts = geomap.lonlat_to_pixel([[LON0, LAT0], [LON0 + 2 * d, LAT0], [LON0 + 0.9 * d, LAT0]])
    assert roi.inside(pts).tolist() == [True, False, True]
    ign = read_region(p, geomap, mode="ignore")
    assert ign.keep(pts).tolist() == [False, True, False]
    with pytest.raises(InputError, match="needs --map"):
        read_region(p)
    # Frame-pixel polygon with a hole.
    f = tmp_path / "frame.geojson"
    f.write_text(json.dumps({"type": "Polygon", "aerotrack_space": "frame", "coordinates": [
        [[0, 0], [100, 0], [100, 100], [0, 100]], [[40, 40], [60, 40], [60, 60], [40, 60]]]}))
    reg = read_region(f)
    assert reg.space == "frame"
    assert reg.inside([[10, 10], [50, 50], [150, 50], [100, 50]]).tolist() == [True, False, False, True]
    assert reg.keep_detections(np.array([[10, 10]]), np.array([[5000, 5000]])).tolist() == [True]


def test_region_csv(tmp_path):
    p = tmp_path / "ignore.csv"
    p.write_text("polygon,x,y\n1,0,0\n1,10,0\n1,10,10\n1,0,10\n2,20,20\n2,30,20\n2,25,30\n")
    reg = read_region(p, mode="ignore", option="--ignore")
    assert reg.inside([[5, 5], [25, 22], [15, 15]]).tolist() == [True, True, False]
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n0,0\n10,zero\n")
    with pytest.raises(FormatError, match=r"bad\.csv line 3"):
        read_region(bad)
    tri = tmp_path / "two.csv"
    tri.write_text("x,y\n0,0\n1,1\n")
    with pytest.raises(FormatError, match="needs >= 3"):
        read_region(tri)


@pytest.mark.parametrize("crs", [{"type": "name", "properties": {"name": "EPSG:nope"}},
                                 {"type": "name", "properties": ["EPSG:4326"]},
                                 {"type": "name"}])
def test_region_geojson_bad_crs_member_is_a_format_error(tmp_path, crs):
    """A GeoJSON ``crs`` member that names no CRS (unknown, or ``properties`` not an object) is
    a one-line FormatError naming the file (a list ``properties`` was an AttributeError)."""
    p = tmp_path / "roi.geojson"
    p.write_text(json.dumps({"type": "FeatureCollection", "crs": crs, "features": [
        {"type": "Feature", "properties": {},
         "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 0]]]}}]}))
    with pytest.raises(FormatError, match=r"roi\.geojson: crs .* not understood"):
        read_region(p)


def _track(tid, xy_m, fps, mpu):
    return Track(id=tid, points=[TrackPoint(frame=i + 1, box=np.array([0, 0, 4, 2.0]),
                                            world=np.asarray(p) / mpu, conf=1.0)
                                 for i, p in enumerate(xy_m)])


def test_min_speed_filter():
    fps, mpu = 10.0, 0.25
    rng = np.random.default_rng(0)
    parked = rng.normal(0, 0.3, (200, 2)) + [50, 50]  # 20 s of 0.3 m detection jitter
    wait_then_go = np.vstack([np.zeros((50, 2)) + rng.normal(0, 0.2, (50, 2)),
                              np.column_stack([np.arange(1, 51) * 0.5, np.zeros(50)])])  # 5 m/s
    tracks = [_track(1, parked, fps, mpu), _track(2, wait_then_go, fps, mpu)]
    assert track_max_speed(tracks[0], fps, mpu) < 0.6
    assert track_max_speed(tracks[1], fps, mpu) == pytest.approx(5.0, abs=0.3)
    kept = filter_min_speed(tracks, 1.0, fps, mpu)
    assert [t.id for t in kept] == [2]
    assert len(filter_min_speed(tracks, 0.0, fps, mpu)) == 2


# -- per-observation geo table --------------------------------------------------------------
def test_observation_table_gpkg_and_csv(geomap, tmp_path, monkeypatch):
    pyogrio = pytest.importorskip("pyogrio")
    fps, v = 10.0, 10.0  # a car driving east at 10 m/s
    geod = Geod(ellps="WGS84")
    n = 30
    lon, lat, _ = geod.fwd(np.full(n, LON0), np.full(n, LAT0), np.full(n, 90.0),
                           v * np.arange(n) / fps)
    lonlat = np.column_stack([lon, lat])
    mappx = geomap.lonlat_to_pixel(lonlat)
    # A camera whose frame pixels are 0.5 m on the ground, north up.
    # Map pixels of this EPSG:4326 tile are not square in metres: scale each axis.
    ll = geomap.pixel_to_lonlat(mappx[0] + [[0, 0], [1, 0], [0, 1]])
    mx, my = (geod.inv(*ll[0], *ll[k])[2] for k in (1, 2))
    sx, sy = 0.5 / mx, 0.5 / my
    homs, rows = {}, []
    for i in range(n):
        H = np.array([[sx, 0, mappx[i, 0] - 320 * sx], [0, sy, mappx[i, 1] - 240 * sy], [0, 0, 1]])
        homs[i + 1] = H
        # vehicle 4.6 m x 1.8 m, east-west: box 9.2 x 3.6 frame px centred at (320, 240)
        rows.append([i + 1, 7, 320 - 4.6, 240 - 1.8, 9.2, 3.6, 1, lon[i], lat[i], -1])
    rows = np.array(rows)
    obs, pred = rows[:20], rows[20:]
    out = write_observation_table(tmp_path / "observations.csv", obs, geomap, fps,
                                  predicted=pred, homographies=homs, formats=("csv", "gpkg"))
    with open(out["csv"], newline="") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0]) == ["frame", "time_s", "id", "lon", "lat", "x", "y", "crs", "speed_mps",
                              "heading_deg", "length_m", "width_m", "kind"]
    assert len(table) == n and table[0]["crs"] == UTM11 == utm_crs_for(LON0, LAT0)
    r = table[10]
    assert float(r["speed_mps"]) == pytest.approx(10.0, rel=0.01)
    assert float(r["heading_deg"]) == pytest.approx(90.0, abs=0.5)
    assert float(r["length_m"]) == pytest.approx(4.6, rel=0.02)
    assert float(r["width_m"]) == pytest.approx(1.8, rel=0.02)
    assert float(r["time_s"]) == pytest.approx(1.0)
    assert len(r["lon"].split(".")[1]) >= 7
    assert [t["kind"] for t in table].count("predicted") == 10
    np.testing.assert_allclose([[float(t["x"]), float(t["y"])] for t in table[:3]],
                               _utm(lon[:3], lat[:3]), atol=0.01)
    # The GeoPackage opens in a GIS library with the right CRS and metre units.
    info = pyogrio.read_info(out["gpkg"], layer="observations")
    assert info["features"] == n and info["geometry_type"] == "Point"
    crs = CRS.from_user_input(info["crs"])
    assert crs.to_epsg() == 32611 and crs.axis_info[0].unit_name == "metre"
    meta, _, geom, _ = pyogrio.raw.read(out["gpkg"], layer="observations")
    names = list(meta["fields"])
    assert "speed_mps" in names and "kind" in names
    x0, y0 = np.frombuffer(geom[0][-16:], "<f8")
    assert (x0, y0) == pytest.approx(tuple(_utm(lon[0], lat[0])[0]), abs=0.01)
    # and track_segments.gpkg: in view (frames 1-21, joined to the prediction) and predicted
    assert out["segments_gpkg"].name == "track_segments.gpkg"
    meta, _, geom, fields = pyogrio.raw.read(out["segments_gpkg"])
    seg = dict(zip(meta["fields"], fields))
    assert list(seg["in_view"]) == [1, 0] and list(seg["first_frame"]) == [1, 21]
    assert list(seg["last_frame"]) == [21, 30]
    assert seg["length_m"][0] == pytest.approx(20 * v / fps, rel=0.01)
    assert pyogrio.read_info(out["segments_gpkg"])["geometry_type"] == "LineString"
    # lengths on the ground whatever --out-crs is (California state plane in US feet: 3.28x)
    from aerotrack.io.geotable import observation_table, track_segments

    cols, _ = observation_table(obs, geomap, fps, "EPSG:2229", predicted=pred, homographies=homs)
    assert track_segments(cols)[1]["length_m"][0] == pytest.approx(20 * v / fps, rel=0.01)
    # GDAL stamps gpkg_contents.last_change with the time of writing; SOURCE_DATE_EPOCH pins it,
    # and two writes are then the same file
    import sqlite3

    def written(name):
        out = write_observation_table(tmp_path / name / "observations.csv", obs, geomap, fps,
                                      predicted=pred, homographies=homs, formats=("gpkg",))
        with sqlite3.connect(out["gpkg"]) as db:
            when = db.execute("SELECT last_change FROM gpkg_contents").fetchone()[0]
        return out["gpkg"].read_bytes(), when

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1600000000")
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    first = written("a")
    time.sleep(1.1)
    assert written("b") == first and first[1].startswith("2020-09-13T12:26:40")
    if importlib.util.find_spec("pyarrow") is not None:  # Parquet beside, same columns and CRS
        import pyarrow.parquet as pq

        pout = write_observation_table(tmp_path / "observations.csv", obs, geomap, fps,
                                       predicted=pred, homographies=homs, formats=("parquet",))
        t = pq.read_table(pout["parquet"])
        assert t.schema.metadata[b"crs"] == UTM11.encode()
        # GeoParquet: a WKB point geometry in the output CRS, the CRS as PROJJSON (it was plain
        # Parquet, which geopandas.read_parquet and GDAL refused as a layer)
        geo = json.loads(t.schema.metadata[b"geo"])
        col = geo["columns"][geo["primary_column"]]
        assert col["encoding"] == "WKB" and CRS.from_json_dict(col["crs"]).to_epsg() == 32611
        px, py = np.frombuffer(t.column("geometry")[0].as_py()[-16:], "<f8")
        assert (px, py) == pytest.approx(tuple(_utm(lon[0], lat[0])[0]), abs=0.01)
        if "Parquet" in pyogrio.list_drivers():  # GDAL opens it as a point layer
            info = pyogrio.read_info(pout["parquet"])
            assert info["features"] == n and "32611" in info["crs"]
        assert t.column("speed_mps")[10].as_py() == pytest.approx(float(r["speed_mps"]), abs=1e-3)
        assert t.column("kind").to_pylist().count("predicted") == 10
    # What each tracks.csv row is, when the caller knows (bridged and held rows are not seen)
    kinds = {(i + 1, 7): ("bridged" if 5 <= i < 8 else "stationary" if i >= 15 else "observed")
             for i in range(20)}
    out3 = write_observation_table(tmp_path / "k.csv", obs, geomap, fps, predicted=pred,
                                   homographies=homs, formats=("csv",), kinds=kinds)
    with open(out3["csv"], newline="") as fh:
        got = [t["kind"] for t in csv.DictReader(fh)]
    assert got == ["observed"] * 5 + ["bridged"] * 3 + ["observed"] * 7 + ["stationary"] * 5 \
        + ["predicted"] * 10
    # --out-crs: any projected CRS; geographic is refused.
    out2 = write_observation_table(tmp_path / "o2.csv", obs, geomap, fps, "EPSG:3857",
                                   formats=("csv",))
    with open(out2["csv"], newline="") as fh:
        assert next(csv.DictReader(fh))["crs"] == "EPSG:3857"
    with pytest.raises(InputError, match="--out-crs.*projected"):
        write_observation_table(tmp_path / "o3.csv", obs, geomap, fps, "EPSG:4326")
    for bad in ("EPSG:4978", "EPSG:5773"):  # geocentric, vertical: no map x, y either
        with pytest.raises(InputError, match="--out-crs.*projected"):
            write_observation_table(tmp_path / "o3.csv", obs, geomap, fps, bad)
    # A CRS without a code was written as its WKT, unquoted: 108 fields a row for 13 columns
    local = ("+proj=tmerc +lat_0=36.14 +lon_0=-115.232 +k=1 +x_0=0 +y_0=0 +datum=WGS84 "
             "+units=m")
    for crs, label in ((local, local), ("EPSG:32611+5773", "EPSG:32611+5773")):
        o = write_observation_table(tmp_path / "o4.csv", obs, geomap, fps, crs, formats=("csv",))
        with open(o["csv"], newline="") as fh:
            rows = list(csv.reader(fh))
        assert {len(r) for r in rows} == {len(rows[0])}
        assert rows[1][rows[0].index("crs")].startswith(label), rows[1]


def test_read_registration_csv(tmp_path):
    p = tmp_path / "registration.csv"
    p.write_text("frame,h00,h01,h02,h10,h11,h12,h20,h21,h22,status\n1,1,0,5,0,1,6,0,0,1,ok\n")
    H = read_registration_csv(p)
    np.testing.assert_allclose(H[1], [[1, 0, 5], [0, 1, 6], [0, 0, 1]])
    p.write_text("frame,h00\n1,1\n")
    with pytest.raises(FormatError, match="line 1"):
        read_registration_csv(p)



def test_coarse_align_brings_a_telemetry_start_within_reach(geomap):
    # Render a frame from the map through a known nadir camera, start 6 m and 4 deg off.
    map_img = geomap.read_image()
    c = geomap.pixel_to_lonlat([[650, 650]])[0]
    true = CameraPose(lon=c[0], lat=c[1], alt_m=100.0, heading_deg=30.0, hfov_deg=73.7)
    size = (960, 540)
    H_true = pose_homography(true, size, geomap)
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])  # aerotrack -> OpenCV pixel centres
    frame = cv2.warpPerspective(map_img, np.linalg.inv(T) @ np.linalg.inv(H_true) @ T, size)
    dlat = 6.0 / 111_000.0
    start = CameraPose(lon=c[0], lat=c[1] + dlat, alt_m=100.0, heading_deg=34.0, hfov_deg=73.7)
    H0 = pose_homography(start, size, geomap)
    corners = np.array([[0, 0], [960, 0], [960, 540], [0, 540]], float)

    def err_m(H):
        d = apply_homography(H, corners) - apply_homography(H_true, corners)
        return float(np.linalg.norm(d, axis=1).mean()) * geomap.metres_per_pixel

    assert err_m(H0) > 6.0
    aspect = map_pixel_aspect(geomap)
    assert aspect == pytest.approx(1 / math.cos(math.radians(c[1])), rel=0.01)  # lon/lat tile
    H1, score = coarse_align(frame, H0, map_img, search_px=3 * 6.0 / geomap.metres_per_pixel,
                             pixel_aspect=aspect)
    assert score > 0.8 and err_m(H1) < 0.3  # well within map refinement's 12-pixel (3 m) reach
    # A frame that is not of this place is refused rather than "aligned".
    noise = np.random.default_rng(0).integers(0, 255, frame.shape, dtype=np.uint8)
    assert not coarse_align(noise, H0, map_img, search_px=60, pixel_aspect=aspect)


def test_telemetry_map_init_end_to_end(geomap, tmp_path):
    from aerotrack.geo.telemetry import telemetry_map_init
    from aerotrack.types import Frame

    map_img = geomap.read_image()
    c = geomap.pixel_to_lonlat([[600, 700]])[0]
    true = CameraPose(lon=c[0], lat=c[1], alt_m=90.0, heading_deg=250.0, hfov_deg=70.0)
    size = (800, 450)
    H_true = pose_homography(true, size, geomap)
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    img = cv2.warpPerspective(map_img, np.linalg.inv(T) @ np.linalg.inv(H_true) @ T, size)
    log = tmp_path / "log.csv"  # GPS 7 m east, compass 3 deg off
    log.write_text("frame,lon,lat,alt_m,heading_deg,hfov_deg\n"
                   f"1,{c[0] + 7 / (111_000 * math.cos(math.radians(c[1]))):.8f},{c[1]:.8f},"
                   "90,253,70\n")
    H, note = telemetry_map_init(read_telemetry(log), Frame(1, img, 0.0), geomap, 30.0)
    corners = np.array([[0, 0], [800, 0], [800, 450], [0, 450]], float)
    err = np.linalg.norm(apply_homography(H, corners) - apply_homography(H_true, corners), axis=1)
    assert "coarse-aligned" in note and err.mean() * geomap.metres_per_pixel < 0.5


def test_observation_table_sizes_on_frames_without_a_homography(geomap, tmp_path):
    """With ``--stride 2`` the tracks also give the skipped frames, which have no homography of
    their own: their sizes come from the nearest registered frame (they were left empty). A
    heading that rounds to 360.00 is written 0.00."""
    fps = 10.0
    geod = Geod(ellps="WGS84")
    n = 12
    lon, lat, _ = geod.fwd(np.full(n, LON0), np.full(n, LAT0), np.full(n, 359.999),
                           10.0 * np.arange(n) / fps)
    mappx = geomap.lonlat_to_pixel(np.column_stack([lon, lat]))
    ll = geomap.pixel_to_lonlat(mappx[0] + [[0, 0], [1, 0], [0, 1]])
    mx, my = (geod.inv(*ll[0], *ll[k])[2] for k in (1, 2))
    homs, rows = {}, []
    for i in range(n):
        H = np.array([[0.5 / mx, 0, mappx[i, 0] - 320 * 0.5 / mx],
                      [0, 0.5 / my, mappx[i, 1] - 240 * 0.5 / my], [0, 0, 1]])
        if i % 2 == 0:  # frames 1, 3, 5, ... registered
            homs[i + 1] = H
        rows.append([i + 1, 7, 320 - 1.8, 240 - 4.6, 3.6, 9.2, 1, lon[i], lat[i], -1])
    out = write_observation_table(tmp_path / "o.csv", np.array(rows), geomap, fps,
                                  homographies=homs, formats=("csv",))
    with open(out["csv"], newline="") as fh:
        table = list(csv.DictReader(fh))
    assert all(t["length_m"] != "" for t in table)
    assert [float(t["length_m"]) for t in table] == pytest.approx([4.6] * n, rel=0.02)
    headings = [t["heading_deg"] for t in table if t["heading_deg"]]
    assert headings and "360.00" not in headings and "0.00" in headings


def test_telemetry_defaults_and_a_placement_the_map_never_confirms(geomap, tmp_path, capsys):
    """A DJI .srt without gimbal yaw could not be used (the message named a --heading option
    that does not exist); a heading in radians put every position ~60 m off with every frame
    'ok' and no word. Now --telemetry-default gives a missing column, and a run none of whose
    frames matched the map says so."""
    from conftest import run_cli

    map_img = geomap.read_image()
    c = geomap.pixel_to_lonlat([[600, 700]])[0]
    true = CameraPose(lon=c[0], lat=c[1], alt_m=90.0, heading_deg=250.0, hfov_deg=70.0)
    size = (400, 240)
    H_true = pose_homography(true, size, geomap)
    T = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    frames = tmp_path / "frames"
    frames.mkdir()
    img = cv2.warpPerspective(map_img, np.linalg.inv(T) @ np.linalg.inv(H_true) @ T, size)
    for i in range(6):
        cv2.imwrite(str(frames / f"{i + 1:04d}.png"), img)
    no_heading = tmp_path / "noheading.csv"
    no_heading.write_text(f"frame,lon,lat,alt_m,hfov_deg\n1,{c[0]:.8f},{c[1]:.8f},90,70\n")
    args = ["track", frames, "--map", geomap.path, "--telemetry", no_heading]
    code, _, err = run_cli(capsys, *args, "--out", tmp_path / "a")
    assert code == 2 and "--telemetry-default heading_deg=VALUE" in err, err
    code, _, err = run_cli(capsys, *args, "--telemetry-default", "heading=250", "--out",
                           tmp_path / "b")
    assert code == 0 and "no frame could be matched" not in err, err
    radians = tmp_path / "radians.csv"
    radians.write_text("frame,lon,lat,alt_m,heading_deg,hfov_deg\n"
                       f"1,{c[0]:.8f},{c[1]:.8f},90,{math.radians(250):.4f},70\n")
    code, _, err = run_cli(capsys, "track", frames, "--map", geomap.path, "--telemetry", radians,
                           "--out", tmp_path / "c")
    assert code == 0 and "no frame could be matched" in err and "degrees" in err, err
    code, _, err = run_cli(capsys, *args, "--telemetry-default", "heading=east", "--out",
                           tmp_path / "d")
    assert code == 2 and "not a number" in err, err


def test_telemetry_defaults_fill_empty_cells_and_are_checked(tmp_path):
    from aerotrack.geo.telemetry import parse_telemetry_defaults

    log = tmp_path / "log.csv"
    log.write_text(f"frame,lon,lat,alt_m,heading_deg\n1,{LON0},{LAT0},90,\n2,{LON0},{LAT0},90,12\n")
    tel = read_telemetry(log, defaults=parse_telemetry_defaults(["heading_deg=30", "hfov=70"]))
    assert list(tel.heading_deg) == [30.0, 12.0]
    for bad, needle in ((["alt_m=-5"], "alt_m must be"), (["heading=1", "yaw=2"], "twice")):
        with pytest.raises(InputError, match=needle):
            parse_telemetry_defaults(bad)


def test_a_run_with_a_ground_resolution_but_no_map_gets_metric_observations(tmp_path, capsys):
    """``--gsd`` without a map wrote no speeds anywhere (observations.csv needed a map)."""
    from conftest import run_cli

    from aerotrack.io.geotable import LOCAL_CRS, local_observation_table

    # known answer: 10 px a frame to the right at 30 fps and 0.1 m a pixel is 30 m/s at 90 deg
    rows = np.array([[f, 1, 100 + 10 * f, 50, 40, 20, 1, -1, -1, -1] for f in range(1, 31)], float)
    homs = {f: np.eye(3) for f in range(1, 31)}
    cols, crs = local_observation_table(rows, 30.0, 0.1, homographies=homs)
    assert crs == LOCAL_CRS and np.all(np.isnan(cols["lon"]))
    assert np.allclose(cols["speed_mps"], 30.0) and np.allclose(cols["heading_deg"], 90.0)
    assert np.allclose(cols["length_m"], 4.0) and np.allclose(cols["width_m"], 2.0)
    assert np.allclose(cols["x"], (120 + 10 * np.arange(1, 31)) * 0.1)
    assert np.allclose(cols["y"], -60 * 0.1)  # y up: image rows grow down
    # end to end on given detections (no frames: no registrations, no table) and on frames
    from aerotrack.synth import render_to

    scene = tmp_path / "scene"
    render_to(scene, seed=4, frames=60, scenario="default")
    code, _, err = run_cli(capsys, "track", scene / "frames", "--out", tmp_path / "run",
                           "--gsd", "0.3")
    assert code == 0, err
    with open(tmp_path / "run" / "observations.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert table and {r["crs"] for r in table} == {LOCAL_CRS}
    speeds = [float(r["speed_mps"]) for r in table if r["speed_mps"]]
    assert speeds and 0 < np.median(speeds) < 40

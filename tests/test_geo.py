from pathlib import Path

import numpy as np
import pytest
import rasterio
from hypothesis import given, settings
from hypothesis import strategies as st
from rasterio.transform import from_origin

from aerotrack.errors import FormatError, GeoreferenceError
from aerotrack.geo import GeoMap, read_map_init

TILE = Path(__file__).resolve().parents[1] / "src/aerotrack/synth/data/vegas_tile.tif"


@pytest.fixture(scope="module")
def vegas():
    return GeoMap(TILE)


@pytest.fixture(scope="module")
def utm_map(tmp_path_factory):
    p = tmp_path_factory.mktemp("utm") / "utm.tif"
    with rasterio.open(p, "w", driver="GTiff", width=200, height=100, count=3, dtype="uint8",
                       crs="EPSG:32611", transform=from_origin(660000, 4000000, 0.5, 0.5)) as ds:
        ds.write(np.random.default_rng(0).integers(0, 255, (3, 100, 200), dtype=np.uint8))
    return GeoMap(p)


def test_vegas_scale(vegas):
    # 2.7e-6 degrees at 36.14 N: about 0.30 m N-S and 0.24 m E-W
    assert 0.24 < vegas.metres_per_pixel < 0.31


def test_utm_scale(utm_map):
    assert utm_map.metres_per_pixel == pytest.approx(0.5, rel=2e-3)


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 1300), st.floats(0, 1300))
def test_pixel_lonlat_round_trip_geographic(x, y):
    m = GeoMap(TILE)
    ll = m.pixel_to_lonlat(np.array([[x, y]]))
    assert -115.24 < ll[0, 0] < -115.22 and 36.13 < ll[0, 1] < 36.15
    np.testing.assert_allclose(m.lonlat_to_pixel(ll), [[x, y]], atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.floats(-50, 250), st.floats(-50, 150))
def test_pixel_crs_lonlat_round_trip_projected(utm_map, x, y):
    px = np.array([[x, y]])
    crs = utm_map.pixel_to_crs(px)
    np.testing.assert_allclose(crs, [[660000 + 0.5 * x, 4000000 - 0.5 * y]], atol=1e-6)
    ll = utm_map.crs_to_lonlat(crs)
    np.testing.assert_allclose(utm_map.lonlat_to_pixel(ll), px, atol=1e-5)


def test_pixel_centre_convention(utm_map):
    # pixel [r=0, c=0] covers [0,1)x[0,1): its centre (0.5, 0.5) is 0.25 m from the corner
    np.testing.assert_allclose(utm_map.pixel_to_crs([[0.5, 0.5]]), [[660000.25, 3999999.75]])


def test_no_georeference_is_clear_error(tmp_path):
    p = tmp_path / "plain.tif"
    with (pytest.warns(rasterio.errors.NotGeoreferencedWarning),
          rasterio.open(p, "w", driver="GTiff", width=10, height=10, count=1, dtype="uint8") as ds):
        ds.write(np.zeros((1, 10, 10), np.uint8))
    with pytest.raises(GeoreferenceError, match="no georeference"):
        GeoMap(p)


def test_map_init_matrix_and_gcps(tmp_path, vegas):
    H = np.array([[0.9, 0.1, 100], [-0.1, 0.9, 200], [1e-5, 0, 1]])
    (tmp_path / "h.txt").write_text("\n".join(" ".join(str(v) for v in r) for r in H))
    np.testing.assert_allclose(read_map_init(tmp_path / "h.txt"), H)
    src = np.array([[0, 0], [640, 0], [640, 480], [0, 480], [320, 240]], float)
    h = np.hstack([src, np.ones((5, 1))]) @ H.T
    dst = h[:, :2] / h[:, 2:]
    rows = "\n".join(f"{a},{b},{c},{d}" for (a, b), (c, d) in zip(src, dst))
    (tmp_path / "g.csv").write_text("frame_x,frame_y,map_x,map_y\n" + rows)
    np.testing.assert_allclose(read_map_init(tmp_path / "g.csv"), H, atol=1e-6)
    ll = vegas.pixel_to_lonlat(dst)
    rows = "\n".join(f"{a},{b},{c:.9f},{d:.9f}" for (a, b), (c, d) in zip(src, ll))
    (tmp_path / "l.csv").write_text("frame_x,frame_y,lon,lat\n" + rows)
    np.testing.assert_allclose(read_map_init(tmp_path / "l.csv", vegas), H, atol=1e-3)


@pytest.mark.parametrize("text,msg", [
    ("frame_x,frame_y,map_x,map_y\n0,0,1,1\n1,0,2,1\n0,1,1,2\n", "at least 4"),
    ("frame_x,frame_y,map_x,map_y\n0,0,0,0\n1,1,1,1\n2,2,2,2\n3,3,3,3\n", "collinear"),
    ("1 0 0\n0 1 0\n", "3 lines"),
    ("1 0 0\n0 1 0\n0 0 0\n", "singular"),
])
def test_bad_map_init(tmp_path, text, msg):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(FormatError, match=msg):
        read_map_init(p)


def test_outputs_across_the_antimeridian(tmp_path):
    """A map whose geotransform runs past lon 180: GeoJSON and observations keep lon in
    [-180, 180) (they read 180.00002..180.0014) and a track crossing it is cut there."""
    from aerotrack.io.geojson import tracks_feature_collection
    from aerotrack.io.geotable import observation_table

    p = tmp_path / "antimeridian.tif"
    with rasterio.open(p, "w", driver="GTiff", width=200, height=100, count=3, dtype="uint8",
                       crs="EPSG:4326", transform=from_origin(179.999, -16.0, 1e-5, 1e-5)) as ds:
        ds.write(np.random.default_rng(0).integers(0, 255, (3, 100, 200), dtype=np.uint8))
    m = GeoMap(p)
    lon = 179.9999 + np.arange(20) * 1e-5 + 5e-7  # crosses 180 after the 10th row
    rows = np.array([[f + 1, 7, 10, 10, 8, 4, 1, lon[f], -16.0005, -1] for f in range(20)])
    fc = tracks_feature_collection(rows, None, m, 10.0)
    geom = fc["features"][0]["geometry"]
    assert geom["type"] == "MultiLineString" and [len(g) for g in geom["coordinates"]] == [11, 11]
    # the parts meet on the antimeridian (RFC 7946 3.1.9: 180 then -180, one latitude; they
    # stopped short of it, a gap of about 0.3 m)
    a, b = geom["coordinates"]
    assert a[-1][0] == 180.0 and b[0][0] == -180.0 and a[-1][1] == b[0][1] == -16.0005
    flat = np.array([c for part in geom["coordinates"] for c in part[:-1]][:-1])
    assert np.all((flat[:, 0] >= -180) & (flat[:, 0] < 180))
    pyogrio = pytest.importorskip("pyogrio")
    from aerotrack.io.geojson import write_tracks_gpkg

    gp = write_tracks_gpkg(tmp_path / "t.gpkg", rows, None, m, 10.0)  # a MultiLineString layer
    assert pyogrio.read_info(gp, layer="tracks")["geometry_type"] == "MultiLineString"
    _, _, pts, _ = pyogrio.raw.read(gp, layer="track_points")
    xs = np.array([np.frombuffer(bytes(b)[-16:], "<f8")[0] for b in pts])
    assert len(xs) == 20 and np.allclose(xs[:10], lon[:10], atol=1e-9)  # one point a frame
    cols, crs = observation_table(rows, m, 10.0)
    assert np.all((cols["lon"] >= -180) & (cols["lon"] < 180)) and crs in ("EPSG:32760", "EPSG:32701")
    assert np.all(np.abs(cols["speed_mps"] - 10.7) < 0.2)  # no jump at the antimeridian


def _raster(path, bands, **kw):
    bands = np.atleast_3d(bands).transpose(2, 0, 1) if np.ndim(bands) == 3 else bands[None]
    with rasterio.open(path, "w", driver="GTiff", width=bands.shape[2], height=bands.shape[1],
                       count=bands.shape[0], dtype=bands.dtype, crs="EPSG:32611",
                       transform=from_origin(659000, 4001000, 0.5, 0.5), **kw) as ds:
        ds.write(bands)
    return path


@settings(max_examples=25, deadline=None)
@given(st.sampled_from([np.uint8, np.uint16, np.int16]), st.integers(0, 2**31 - 1))
def test_map_stretch_by_histogram_equals_the_percentile_stretch(dtype, seed):
    """The histogram lookup (memory: a 20000 x 20000 map needed > 23 GB stretched in float64)
    gives exactly what the float64 stretch between np.percentile's 0.5 and 99.5 gave."""
    from aerotrack.geo.maprast import _stretch

    rng = np.random.default_rng(seed)
    info = np.iinfo(dtype)
    band = rng.integers(info.min, info.max, (37, 53), endpoint=True).astype(dtype)
    band[:5] = rng.integers(info.min, info.min + 3)  # ties, as real imagery has
    f = band.astype(np.float64)
    lo, hi = np.percentile(f, [0.5, 99.5])
    hi = hi if hi > lo else lo + 1
    expect = np.nan_to_num(np.clip((f - lo) / (hi - lo) * 255.0, 0, 255)).astype(np.uint8)
    np.testing.assert_array_equal(_stretch(band), expect)


def test_map_nodata_alpha_and_palette_are_drawn(tmp_path):
    """A uint16 map with nodata 65535 was drawn all black (the nodata border set the stretch),
    a float one with nodata -9999 all white, a paletted one as grey noise (a probe)."""
    rng = np.random.default_rng(0)
    ground = rng.integers(200, 1400, (60, 80)).astype(np.uint16)
    border = ground.copy()
    border[:, :20] = 65535
    img = GeoMap(_raster(tmp_path / "u16.tif", border, nodata=65535)).read_image()
    assert (img[:, :20] == 0).all() and img[:, 20:].mean() > 60  # valid pixels span the range
    f = np.where(border == 65535, -9999.0, ground).astype(np.float32)
    img = GeoMap(_raster(tmp_path / "f32.tif", f, nodata=-9999)).read_image()
    assert (img[:, :20] == 0).all() and 60 < img[:, 20:].mean() < 200
    pal = (np.arange(60 * 80).reshape(60, 80) % 3).astype(np.uint8)
    path = _raster(tmp_path / "pal.tif", pal)
    with rasterio.open(path, "r+") as ds:
        ds.write_colormap(1, {0: (255, 0, 0, 255), 1: (0, 255, 0, 255), 2: (0, 0, 255, 255)})
    img = GeoMap(path).read_image()
    assert tuple(img[0, 0]) == (0, 0, 255) and tuple(img[0, 1]) == (0, 255, 0)  # BGR of red, green


def test_map_georeference_errors_say_what_is_missing(tmp_path):
    """Rasters placed by control points only, or with a world file but no CRS, were all told
    "no CRS or geotransform" (a probe)."""
    from rasterio.control import GroundControlPoint

    band = np.zeros((1, 20, 30), np.uint8)
    gcps = [GroundControlPoint(row=r, col=c, x=-115.2 + c * 1e-5, y=36.1 - r * 1e-5)
            for r, c in ((0, 0), (0, 29), (19, 0), (19, 29))]
    with rasterio.open(tmp_path / "gcp.tif", "w", driver="GTiff", width=30, height=20, count=1,
                       dtype="uint8", gcps=gcps, crs="EPSG:4326") as ds:
        ds.write(band)
    with pytest.raises(GeoreferenceError, match="ground control points only.*gdalwarp"):
        GeoMap(tmp_path / "gcp.tif")
    with rasterio.open(tmp_path / "nocrs.tif", "w", driver="GTiff", width=30, height=20, count=1,
                       dtype="uint8", transform=from_origin(659000, 4001000, 0.5, 0.5)) as ds:
        ds.write(band)
    with pytest.raises(GeoreferenceError, match="geotransform .* but no CRS"):
        GeoMap(tmp_path / "nocrs.tif")

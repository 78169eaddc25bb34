"""A georeferenced map raster (orthophoto or satellite GeoTIFF).

Map pixels are (col, row), continuous, in the convention of the raster's affine transform: pixel
[r, c] covers [c, c+1) x [r, r+1), so ``transform * (c + 0.5, r + 0.5)`` is its centre.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..errors import GeoreferenceError, InputError
from ..io.frames import cv_path


class GeoMap:
    """A map raster with its georeference.

    Parameters
    ----------
    path : path
        Any raster GDAL reads, 1 or 3+ bands, any dtype, geographic or projected CRS.

    Attributes
    ----------
    crs : rasterio.crs.CRS
    transform : affine.Affine
        Map pixels -> map CRS.
    width, height : int
    metres_per_pixel : float
        Ground size of one map pixel at the map's centre (geometric mean of the two axes), from a
        local projection when the CRS is geographic.
    """

    def __init__(self, path: str | Path, *, option: str = "--map") -> None:
        import rasterio
        from pyproj import CRS, Transformer

        self.path = Path(path)
        label = f"{option} {self.path}"
        if not self.path.exists():
            raise InputError(f"{label}: file not found")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                # (a name that is not valid UTF-8 stopped rasterio with a traceback; its
                # sidecar files, a world file or .aux.xml, are not found through the link)
                ds = rasterio.open(cv_path(self.path))
            with ds:
                self.crs = ds.crs
                self.transform = ds.transform
                gcps = bool(ds.gcps[0])
                self.width, self.height, self.count = ds.width, ds.height, ds.count
                self._dtypes = ds.dtypes
                # its last pixel, read now: a file cut short (a broken download) fails here,
                # not minutes later in a traceback when the map is first drawn on
                from rasterio.windows import Window

                ds.read(1, window=Window(ds.width - 1, ds.height - 1, 1, 1))
        except rasterio.errors.RasterioIOError as exc:
            detail = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
            if detail.startswith("Read failed"):  # (GDAL's own words say nothing more)
                if self.path.suffix.lower() == ".vrt":  # (it was called damaged)
                    raise InputError(f"{label}: its pixels cannot be read: are the files this "
                                     "VRT names there (moved, or named relative to another "
                                     "folder)?") from None
                raise InputError(f"{label}: its pixels cannot be read: a truncated or damaged "
                                 "file?") from None
            raise InputError(f"{label}: cannot read as a raster ({detail})") from None
        no_transform = self.transform is None or self.transform.is_identity
        if (self.crs is None or no_transform) and cv_path(self.path) != str(self.path):
            raise GeoreferenceError(f"{label}: no georeference found; its name is not valid "
                                    "UTF-8, so it is opened through a link and files beside it "
                                    "(a world file, .prj or .aux.xml) are not found: rename it")
        if self.crs is None or no_transform:
            # (each case was "no CRS or geotransform", also for a raster that has one of them)
            if no_transform and gcps:
                raise GeoreferenceError(f"{label}: georeferenced by ground control points only, "
                                        "which aerotrack does not fit: warp it to a grid first "
                                        f"(gdalwarp {self.path.name} warped.tif)")
            if no_transform and self.crs is None:
                raise GeoreferenceError(f"{label}: raster has no georeference (no CRS or "
                                        "geotransform)")
            if self.crs is None:
                raise GeoreferenceError(f"{label}: has a geotransform (a world file?) but no "
                                        "CRS: name it in a .prj or .aux.xml beside it (e.g. "
                                        f"gdal_edit.py -a_srs EPSG:32611 {self.path.name})")
            raise GeoreferenceError(f"{label}: has a CRS but no geotransform (where its pixels "
                                    "lie): a world file or a georeferenced copy is needed")
        if self.width < 2 or self.height < 2:
            raise InputError(f"{label}: raster is too small ({self.width}x{self.height})")
        self._pcrs = CRS.from_user_input(self.crs.to_wkt())
        self._to_ll = Transformer.from_crs(self._pcrs, CRS.from_epsg(4326), always_xy=True)
        self._from_ll = Transformer.from_crs(CRS.from_epsg(4326), self._pcrs, always_xy=True)
        self.metres_per_pixel = self._measure_gsd()
        self._image: np.ndarray | None = None

    # -- conversions -------------------------------------------------------------------------
    def pixel_to_crs(self, px: np.ndarray) -> np.ndarray:
        """(N, 2) map pixels (col, row) -> (N, 2) map CRS coordinates."""
        p = np.asarray(px, dtype=np.float64).reshape(-1, 2)
        a = self.transform
        x = a.a * p[:, 0] + a.b * p[:, 1] + a.c
        y = a.d * p[:, 0] + a.e * p[:, 1] + a.f
        return np.column_stack([x, y])

    def crs_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) map CRS coordinates -> (N, 2) map pixels (col, row)."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        inv = ~self.transform
        c = inv.a * p[:, 0] + inv.b * p[:, 1] + inv.c
        r = inv.d * p[:, 0] + inv.e * p[:, 1] + inv.f
        return np.column_stack([c, r])

    def crs_to_lonlat(self, xy: np.ndarray) -> np.ndarray:
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if self._pcrs.is_geographic and self._pcrs.to_epsg() == 4326:
            return p.copy()
        lon, lat = self._to_ll.transform(p[:, 0], p[:, 1])
        return np.column_stack([lon, lat])

    def lonlat_to_crs(self, ll: np.ndarray) -> np.ndarray:
        p = np.asarray(ll, dtype=np.float64).reshape(-1, 2)
        if self._pcrs.is_geographic and self._pcrs.to_epsg() == 4326:
            return p.copy()
        x, y = self._from_ll.transform(p[:, 0], p[:, 1])
        return np.column_stack([x, y])

    def pixel_to_lonlat(self, px: np.ndarray) -> np.ndarray:
        """(N, 2) map pixels -> (N, 2) lon/lat degrees."""
        return self.crs_to_lonlat(self.pixel_to_crs(px))

    def lonlat_to_pixel(self, ll: np.ndarray) -> np.ndarray:
        """(N, 2) lon/lat degrees -> (N, 2) map pixels."""
        return self.crs_to_pixel(self.lonlat_to_crs(ll))

    # -- scale ---------------------------------------------------------------------------------
    def _measure_gsd(self) -> float:
        """Metres per map pixel at the raster centre, via a local azimuthal equidistant projection."""
        from pyproj import CRS, Transformer

        c = np.array([[self.width / 2, self.height / 2]])
        pts = np.vstack([c, c + [1, 0], c + [0, 1]])
        ll = self.pixel_to_lonlat(pts)
        local = CRS.from_proj4(
            f"+proj=aeqd +lat_0={ll[0, 1]} +lon_0={ll[0, 0]} +datum=WGS84 +units=m"
        )
        t = Transformer.from_crs(CRS.from_epsg(4326), local, always_xy=True)
        x, y = t.transform(ll[:, 0], ll[:, 1])
        dx = math.hypot(x[1] - x[0], y[1] - y[0])
        dy = math.hypot(x[2] - x[0], y[2] - y[0])
        if not (dx > 0 and dy > 0 and math.isfinite(dx * dy)):
            raise GeoreferenceError(f"{self.path}: cannot measure the pixel size in metres")
        return math.sqrt(dx * dy)

    # -- pixels --------------------------------------------------------------------------------
    def read_image(self) -> np.ndarray:
        """The map as an (H, W, 3) uint8 BGR image (cached).

        Each band is stretched between its 0.5 and 99.5 percentiles (11- or 16-bit imagery
        becomes visible); single-band rasters are replicated to three channels, or coloured by
        their palette; 3+ band rasters use bands 1-3 as RGB. Pixels the raster marks invalid
        (nodata, an alpha band, a mask) are left out of the percentiles and drawn black: a uint16
        map with nodata 65535 was drawn all black, a float one with nodata -9999 all white, a
        paletted one as grey noise (a probe).

        Memory: one band at a time, and integer bands of 8 or 16 bits through a lookup table
        from their histogram (the same percentiles as ``np.percentile``, byte-identical output):
        the whole map was stretched in float64, about 20 bytes per raw byte, and a 20000 x 20000
        orthophoto needed more than the machine's 23 GB.
        """
        if self._image is None:
            import rasterio
            from rasterio.enums import MaskFlags

            try:
                with rasterio.open(cv_path(self.path)) as ds:
                    img = np.empty((ds.height, ds.width, 3), np.uint8)
                    masked = any(MaskFlags.all_valid not in f for f in ds.mask_flag_enums)
                    valid = ds.dataset_mask() > 0 if masked else None
                    if ds.count >= 3:
                        for k in range(3):  # bands 1-3 are R, G, B; the image is BGR
                            img[..., 2 - k] = _stretch(ds.read(k + 1), valid)
                    else:
                        band = ds.read(1)
                        lut = _palette_bgr(ds)
                        if lut is not None:
                            img[:] = lut[band]
                            if valid is not None:
                                img[~valid] = 0
                        else:
                            img[:] = _stretch(band, valid)[..., None]
            except rasterio.errors.RasterioIOError:  # damaged inside (or changed since opened)
                raise InputError(f"--map {self.path}: its pixels cannot be read: a truncated or "
                                 "damaged file?") from None
            self._image = img
        return self._image


def _palette_bgr(ds) -> np.ndarray | None:
    """(N, 3) uint8 BGR lookup of a paletted single-band raster's colour table, or None."""
    from rasterio.enums import ColorInterp

    if ds.colorinterp[0] != ColorInterp.palette or np.dtype(ds.dtypes[0]).itemsize > 2:
        return None
    try:
        cmap = ds.colormap(1)
    except ValueError:  # no table after all
        return None
    n = 256 if np.dtype(ds.dtypes[0]).itemsize == 1 else 65536
    lut = np.zeros((n, 3), np.uint8)
    for i, rgba in cmap.items():
        if 0 <= i < n:
            lut[i] = (rgba[2], rgba[1], rgba[0])
    return lut


def _percentiles(values_sorted_counts, n: int, qs) -> list[float]:
    """``np.percentile(a, qs)`` (linear) of ``n`` values given as (distinct values ascending,
    their counts): the same arithmetic, without sorting the values themselves."""
    vals, counts = values_sorted_counts
    cum = np.cumsum(counts)
    out = []
    for q in qs:
        virtual = np.true_divide(q, 100) * (n - 1)
        i = int(np.floor(virtual))
        gamma = virtual - i
        a = float(vals[np.searchsorted(cum, i, side="right")])
        b = float(vals[np.searchsorted(cum, min(i + 1, n - 1), side="right")])
        diff = b - a
        out.append(b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma)
    return out


#: Rows of a map band histogrammed and looked up at a time (:func:`_stretch`).
STRIP_ROWS = 512


def _stretch(band: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """A band as uint8 between its 0.5 and 99.5 percentiles over ``valid`` (finite) pixels;
    invalid pixels 0."""
    if band.dtype.kind in "ui" and band.dtype.itemsize <= 2:
        lo_v = int(np.iinfo(band.dtype).min)
        # offsets of the lowest level as an unsigned band of the same width (signed: the sign
        # bit flipped), so nothing is widened: np.bincount and fancy indexing cast to 8 bytes a
        # pixel, 0.8 GB more for a 10000 x 10000 band (a reviewer); hence row strips below
        idx = band if not lo_v else (band.view(np.uint8) ^ np.uint8(0x80) if band.itemsize == 1
                                     else band.view(np.uint16) ^ np.uint16(0x8000))
        counts = np.zeros(int(np.iinfo(band.dtype).max) - lo_v + 1, np.int64)
        for r in range(0, idx.shape[0], STRIP_ROWS):
            part = idx[r:r + STRIP_ROWS]
            part = part[valid[r:r + STRIP_ROWS]] if valid is not None else part.ravel()
            counts += np.bincount(part, minlength=len(counts))
        n = int(counts.sum())
        if n == 0:
            return np.zeros(band.shape, np.uint8)
        nz = np.flatnonzero(counts)
        lo, hi = _percentiles((nz + lo_v, counts[nz]), n, [0.5, 99.5])
        if hi <= lo:
            hi = lo + 1
        levels = np.arange(len(counts), dtype=np.float64) + lo_v
        lut = np.nan_to_num(np.clip((levels - lo) / (hi - lo) * 255.0, 0, 255)).astype(np.uint8)
        out = np.empty(band.shape, np.uint8)
        for r in range(0, idx.shape[0], STRIP_ROWS):
            out[r:r + STRIP_ROWS] = lut[idx[r:r + STRIP_ROWS]]
    else:
        band = band.astype(np.float64)
        ok = np.isfinite(band) if valid is None else np.isfinite(band) & valid
        finite = band[ok]
        if finite.size == 0:
            return np.zeros(band.shape, np.uint8)
        lo, hi = np.percentile(finite, [0.5, 99.5])
        if hi <= lo:
            hi = lo + 1
        out = np.nan_to_num(np.clip((band - lo) / (hi - lo) * 255.0, 0, 255)).astype(np.uint8)
    if valid is not None:
        out[~valid] = 0
    return out

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
                self.width, self.height, self.count = ds.width, ds.height, ds.count
                self._dtypes = ds.dtypes
                # its last pixel, read now: a file cut short (a broken download) fails here,
                # not minutes later in a traceback when the map is first drawn on
                from rasterio.windows import Window

                ds.read(1, window=Window(ds.width - 1, ds.height - 1, 1, 1))
        except rasterio.errors.RasterioIOError as exc:
            detail = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
            if detail.startswith("Read failed"):  # (GDAL's own words say nothing more)
                raise InputError(f"{label}: its pixels cannot be read: a truncated or damaged "
                                 "file?") from None
            raise InputError(f"{label}: cannot read as a raster ({detail})") from None
        if self.crs is None or self.transform is None or self.transform.is_identity:
            raise GeoreferenceError(f"{label}: raster has no georeference (no CRS or geotransform)")
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

        Single-band rasters are stretched between their 0.5 and 99.5 percentiles (11- or 16-bit
        imagery becomes visible), then replicated to three channels; 3+ band rasters use bands 1-3
        as RGB.
        """
        if self._image is None:
            import rasterio

            try:
                with rasterio.open(cv_path(self.path)) as ds:
                    if ds.count >= 3:
                        rgb = ds.read([1, 2, 3]).astype(np.float64)
                        img = np.stack([_stretch(b) for b in rgb], axis=-1)[..., ::-1]
                    else:
                        band = _stretch(ds.read(1).astype(np.float64))
                        img = np.repeat(band[..., None], 3, axis=-1)
            except rasterio.errors.RasterioIOError:  # damaged inside (or changed since opened)
                raise InputError(f"--map {self.path}: its pixels cannot be read: a truncated or "
                                 "damaged file?") from None
            self._image = np.ascontiguousarray(img)
        return self._image


def _stretch(band: np.ndarray) -> np.ndarray:
    finite = band[np.isfinite(band)]
    if finite.size == 0:
        return np.zeros(band.shape, np.uint8)
    lo, hi = np.percentile(finite, [0.5, 99.5])
    if hi <= lo:
        hi = lo + 1
    out = np.clip((band - lo) / (hi - lo) * 255.0, 0, 255)
    return np.nan_to_num(out).astype(np.uint8)

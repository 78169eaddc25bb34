"""The map: a georeferenced raster and conversions pixel <-> map CRS <-> lon/lat."""

from .maprast import GeoMap
from .init import read_map_init

__all__ = ["GeoMap", "read_map_init"]

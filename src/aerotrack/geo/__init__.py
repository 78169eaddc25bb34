"""The map: a georeferenced raster and conversions pixel <-> map CRS <-> lon/lat."""

from .init import read_map_init
from .maprast import GeoMap

__all__ = ["GeoMap", "read_map_init"]

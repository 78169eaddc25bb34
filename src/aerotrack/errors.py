"""The error hierarchy.

Every error aerotrack raises on purpose derives from :class:`AerotrackError`, and also from the
builtin exception it means, so callers can catch either. The CLI turns any ``AerotrackError`` into a
one-line message and exit code 2.
"""

from __future__ import annotations


class AerotrackError(Exception):
    """Base class of every error raised deliberately by aerotrack."""


class InputError(AerotrackError, ValueError):
    """An input file, folder or option is missing, unreadable or malformed.

    The message names the file or option and says what is wrong.
    """


class FormatError(InputError):
    """A text file (MOT rows, map-init, config) has a malformed line; the message names the line."""


class GeoreferenceError(InputError):
    """A map raster has no usable georeference, or a geo-initialisation is inconsistent with it."""


class ConfigError(InputError):
    """An unknown, mistyped or out-of-range configuration parameter."""


class OutputError(AerotrackError, OSError):
    """An output folder cannot be written or already holds results."""


class StageError(AerotrackError, RuntimeError):
    """A pipeline stage could not continue (not raised for a single failed estimate: see ``Failure``)."""


def install_extra(extra: str) -> str:
    """How to install one of aerotrack's optional extras (``dask``, ``gis``), for messages."""
    return f"pip install 'aerotrack[{extra}]' (from a checkout: pip install '.[{extra}]')"

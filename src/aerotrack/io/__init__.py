"""Inputs and outputs: frame sources, MOTChallenge files, atomic output folders."""

from .frames import FrameSource, open_source
from .mot import read_mot, write_mot
from .output import OutputDir, atomic_write

__all__ = ["FrameSource", "open_source", "read_mot", "write_mot", "OutputDir", "atomic_write"]

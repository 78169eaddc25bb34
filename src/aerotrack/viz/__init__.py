"""What users see: overlay videos, map and space-time pictures, the offline HTML report.

Everything here works from an output folder's files (the CLI contract), see :mod:`.results`.
"""

from .colours import id_bgr, id_hex, id_rgb
from .overlay import OverlayPainter, OverlayStyle, render_overlay
from .results import RegistrationTable, RunResults, TrackView
from .trackstats import TrackStats, track_stats

__all__ = ["id_bgr", "id_hex", "id_rgb", "OverlayPainter", "OverlayStyle", "render_overlay",
           "RegistrationTable", "RunResults", "TrackView", "TrackStats", "track_stats"]

"""Scenario generator: aerial video over a real georeferenced satellite tile, with ground truth.

``Scenario(...).frames()`` streams (frame, true homography, truth) without touching the disk;
``render_to(out_dir, ...)`` writes the files of ``aerotrack synth``.
"""

from .render import perturb_map, render_to
from .scene import SCENARIOS, Scenario
from .world import World, colourise

__all__ = ["SCENARIOS", "Scenario", "World", "colourise", "perturb_map", "render_to"]

"""Re-acquisition: fusing the motion context, the appearance context and the tracklet descriptor.

Both papers leave the fusion open (Ali et al.: "distance < thresh" on the predicted location, then
appearance; Yu & Medioni: an appearance threshold on spatio-temporally consistent pairs). aerotrack
scores a candidate link "earlier tracklet a ends, later tracklet b starts" by a sum of per-cue costs,
each scaled like a negative log-likelihood ratio (about 0 to 1 for a true link, growing for a wrong
one), and links all pairs jointly by minimum total cost (see
:class:`aerotrack.association.linking.GlobalLinker` and docs/CONTEXT.md):

* motion: ``0.5 (d / sigma_p)^2 + 0.5 (dv / sigma_v)^2`` with d the distance, in metres, between
  where the motion context predicted a to be at b's first frame and where b starts (averaged with
  the same distance for b's backward prediction to a's last frame), dv the change of velocity, and
  sigmas growing linearly with the gap: a prediction is trusted less the longer the target was
  unseen;
* appearance context: ``0.5 max(0, z2 - 1)`` with z2 the mean squared z-score, under a's
  intra-class model, of the best difference between b's observations (5, spread over b) and a's
  (about 1 for the same target), plus 1 when the inter-class verification against the other
  candidates fails;
* descriptor: the KL distances of eqs. 13 + 14 between the two tracklets' descriptors.

A cue that cannot be computed (no histograms, no descriptor statistics) contributes 0: it neither
helps nor hurts. Weights of 0 switch a cue off (the ablation in benchmarks/identity.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..config import LinkingConfig

__all__ = ["Cues", "motion_cost", "appearance_cost", "link_cost"]


@dataclass(frozen=True)
class Cues:
    """The per-cue costs of one candidate link (NaN when a cue is unavailable)."""

    motion: float = float("nan")
    appearance: float = float("nan")
    descriptor: float = float("nan")


def motion_cost(distance_m: float, gap_s: float, config: LinkingConfig,
                speed_change_mps: float = 0.0) -> float:
    """``0.5 (d / sigma_p)^2 + 0.5 (dv / sigma_v)^2``: the predicted-versus-observed distance and
    velocity change in units of their expected errors, which grow with the gap."""
    sp = config.motion_sigma_m + config.motion_sigma_growth_mps * max(gap_s, 0.0)
    sv = config.velocity_sigma_mps + config.velocity_sigma_growth_mps2 * max(gap_s, 0.0)
    return 0.5 * (distance_m / sp) ** 2 + 0.5 * (speed_change_mps / sv) ** 2


def appearance_cost(z2: float, verified: bool) -> float:
    """Cost from the appearance context: excess of the intra-class distance over its typical 1,
    plus 1 when the inter-class verification fails."""
    if not math.isfinite(z2):
        return float("nan")
    return 0.5 * max(0.0, z2 - 1.0) + (0.0 if verified else 1.0)


def link_cost(cues: Cues, config: LinkingConfig) -> float:
    """Weighted sum of the available cues' costs."""
    total = 0.0
    for value, weight in ((cues.motion, config.weight_motion),
                          (cues.appearance, config.weight_appearance),
                          (cues.descriptor, config.weight_descriptor)):
        if weight > 0 and math.isfinite(value):
            total += weight * value
    return total

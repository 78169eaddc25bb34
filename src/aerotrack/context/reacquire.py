"""Re-acquisition: fusing the motion context, the appearance context and the tracklet descriptor.

Both papers leave the fusion open (Ali et al.: "distance < thresh" on the predicted location, then
appearance; Yu & Medioni: an appearance threshold on spatio-temporally consistent pairs). aerotrack
scores a candidate link "earlier tracklet a ends, later tracklet b starts" by a sum of per-cue costs,
each scaled like a negative log-likelihood ratio (about 0 to 1 for a true link, growing for a wrong
one), and links all pairs jointly by minimum total cost (see
:class:`aerotrack.association.linking.GlobalLinker` and docs/DESIGN.md ("Persistent identity")):

* motion: ``0.5 (d / sigma_p)^2 + 0.5 (dv / sigma_v)^2 + 0.5 (lag / sigma_l)^2`` with d the
  distance, in metres, from b's start to the path the motion context predicted for a (averaged with
  the same distance of a's end from b's backward path), lag how far behind its prediction the target
  fell (a stop behind an occluder), dv the change of velocity, and sigmas growing linearly with the
  gap: a prediction is trusted less the longer the target was unseen. For short gaps a manoeuvre
  hypothesis (turn, U-turn: heading free, speed and reach kept) competes at an extra cost
  (:func:`motion_cost`);
* appearance context: ``0.5 max(0, z2 - 1)`` with z2 the mean squared z-score, under a's
  intra-class model, of the best difference between b's observations (5, spread over b) and a's
  (about 1 for the same target), plus 1 when the inter-class verification against the other
  candidates fails, at most ``appearance_max`` (:func:`appearance_cost`);
* descriptor: the KL distances of eqs. 13 + 14 between the two tracklets' descriptors, at most
  ``descriptor_max`` (:func:`descriptor_cost`).

A cue that cannot be computed (no histograms, no descriptor statistics) contributes 0: it neither
helps nor hurts. Weights of 0 switch a cue off (the ablation in benchmarks/identity.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import LinkingConfig

__all__ = ["Cues", "motion_cost", "motion_costs", "appearance_cost", "descriptor_cost", "link_cost"]


@dataclass(frozen=True)
class Cues:
    """The per-cue costs of one candidate link (NaN when a cue is unavailable)."""

    motion: float = float("nan")
    appearance: float = float("nan")
    descriptor: float = float("nan")


def motion_cost(distance_m: float, gap_s: float, config: LinkingConfig,
                speed_change_mps: float = 0.0, lag_m: float = 0.0,
                turn: tuple[float, ...] | None = None, noise_m: float = 0.0,
                noise_mps: float = 0.0, windows_s: float = 1.0) -> float:
    """Motion cost of a candidate link: the cheaper of two hypotheses.

    * **along the prediction**: ``0.5 (d / sigma_p)^2 + 0.5 (dv / sigma_v)^2 + 0.5 (lag / sigma_l)^2``
      with d the distance from the predicted path, dv the change of velocity and ``lag`` how far
      the target fell behind its predicted position (it slowed down or stopped behind an occluder:
      a queue at a light); the sigmas grow linearly with the gap;
    * **manoeuvre** (only when ``turn`` is given, for gaps up to ``turn_max_gap_s``): a turn or
      U-turn during or just before the gap, which the end/start velocities (each averaged over up
      to ``history_s``) cannot follow. ``turn = (excess_m, speed_change_mps, reach_m,
      velocity_change_mps)``: the straight-line distance beyond what the target could cover at its
      speed, the change of speed, the distance it could cover (speed x gap) and the norm of the
      change of velocity. It costs ``turn_cost`` plus ``log(1 + reach / sigma_p)``: with the
      heading free, where the target re-appears is spread along the roads within its reach
      (a one-dimensional set of length ~reach) instead of the prediction's Gaussian, so a turn
      hidden in a gap of a few frames costs little more than ``turn_cost`` and one hidden in
      10 s about 2.5 more (the flat cost used before let any look-alike within reach of a long
      gap take the link). The velocity may change by at most ``a_max_mps2`` x (gap + the 1 s of
      the velocity windows); beyond that the excess costs like the speed change (a vehicle does
      not reverse at the image edge in a quarter of a second).

    Parameters
    ----------
    distance_m : float
        Distance from the predicted path (forward and backward averaged), metres.
    gap_s : float
        Length of the gap, seconds.
    speed_change_mps : float
        Norm of the velocity change between the end of a and the start of b, m/s.
    lag_m : float
        Along-path shortfall, metres.
    turn : tuple of float, optional
        Manoeuvre hypothesis ``(excess_m, speed_change_mps[, reach_m[, velocity_change_mps]])``
        (missing terms count 0).
    noise_m, noise_mps : float
        The two tracklets' own end-state uncertainty (position, metres, including the velocity
        uncertainty carried over the gap; velocity, m/s), added in quadrature to the sigmas.
    windows_s : float
        Seconds of velocity windows around the gap over which the manoeuvre may change the
        velocity (1: half a second each side; a split of one accelerating track: both whole
        windows).
    """
    if turn is not None:
        turn = np.array([(tuple(turn) + (0.0, 0.0))[:4]], dtype=np.float64)
    return float(motion_costs(np.array([distance_m], dtype=np.float64), np.array([gap_s]), config,
                              np.array([speed_change_mps]), np.array([lag_m]), turn,
                              np.array([noise_m]), np.array([noise_mps]),
                              np.array([windows_s]))[0])


def motion_costs(distance_m: np.ndarray, gap_s: np.ndarray, config: LinkingConfig,
                 speed_change_mps: np.ndarray, lag_m: np.ndarray, turn: np.ndarray | None,
                 noise_m: np.ndarray, noise_mps: np.ndarray, windows_s: np.ndarray) -> np.ndarray:
    """:func:`motion_cost` of many candidate links at once (arrays of one length ``k``; the one
    implementation of the formula, :func:`motion_cost` calls it); ``turn`` is (k, 4) with NaN
    rows where the manoeuvre hypothesis does not apply (gaps over ``turn_max_gap_s``), or None
    for none."""
    g = np.maximum(gap_s, 0.0)
    sp = np.hypot(config.motion_sigma_m + config.motion_sigma_growth_mps * g, noise_m)
    sv = np.hypot(config.velocity_sigma_mps + config.velocity_sigma_growth_mps2 * g, noise_mps)
    sl = np.hypot(config.motion_sigma_m + config.lag_sigma_growth_mps * g, noise_m)
    straight = 0.5 * (distance_m / sp) ** 2 + 0.5 * (speed_change_mps / sv) ** 2 \
        + 0.5 * (lag_m / sl) ** 2
    if turn is None:
        return straight
    excess, dspeed, reach, dvel = np.asarray(turn, dtype=np.float64).T
    window = g + windows_s
    st = sv + 0.5 * config.a_max_mps2 * window
    too_fast = np.maximum(0.0, dvel - config.a_max_mps2 * window)
    manoeuvre = config.turn_cost + np.log1p(reach / sp) + 0.5 * (excess / sp) ** 2 \
        + 0.5 * (dspeed / st) ** 2 + 0.5 * (too_fast / st) ** 2
    return np.where(np.isnan(excess), straight, np.minimum(straight, manoeuvre))


def appearance_cost(z2: float, verified: bool, cap: float = math.inf) -> float:
    """Cost from the appearance context: excess of the intra-class distance over its typical 1,
    plus 1 when the inter-class verification fails, at most ``cap``.

    Like the descriptor's (:func:`descriptor_cost`) the distance is unbounded: the intra-class
    model is a per-bin Gaussian of histogram differences whose deviation is floored at 1e-3, so a
    bin empty in all of a's observations scores z^2 ~ 1e4 per unit of mass in b's. With
    aerotrack's detector a vehicle's own tracklets then score tens to ~1000 (z2) when one of them
    is a mixed tracklet (two vehicles, a vehicle and its shadow or the occluder's edge) or mostly
    partial boxes, and the cost alone vetoes the link whatever motion says. Past a few units the
    distance only says "looks different": truncated there, appearance ranks the candidates but no
    longer vetoes alone (with ``descriptor_max`` 3 at weight 0.5 the two cues add at most 4.5,
    below ``max_cost`` 6: the motion cost must also disagree). Measured on the generated scenes
    (benchmarks/identity.py, the tracklets of results/identity.json at 4adef84, aerotrack's
    detector, 5 default scenes): among candidate pairs the motion context finds plausible (motion
    cost < 6) this cue tells true from false links better than motion does (area under the ROC
    curve 0.86 vs 0.62), but 14 of 172 true pairs cost more than 2 (2.2 to 1200), all but one
    involving a tracklet less than 80% one vehicle or a third of partial boxes, against 62% of
    the 449 false pairs. Cap (``linking.appearance_max``) 1e9 / 1.5 / 2 / 2.5
    / 3 / 4 / 6: IDF1/HOTA on the 5 default scenes 0.778/0.586, 0.794/0.595, 0.797/0.598,
    0.800/0.603, 0.792/0.599, 0.794/0.600, 0.778/0.586 (no appearance context: 0.790/0.592); the
    3 other scenes (occlusion:2, exits:3, default:1) 0.746/0.580 at every cap (0.675/0.541
    without the cue); ground-truth detections (8 scenes), Santiago (seeds 0-2) and UAVDT
    unchanged. Leaving partial boxes (< 0.6 or 0.8 of the tracklet's typical length) out of the
    models instead was neutral (0.774-0.777 IDF1): the far-off scores come from mixed tracklets
    more than from partial boxes. Three unseen scenes (occlusion:3, default:3, exits:4): 0.782/
    0.604 capped or not (0.766/0.592 without the cue). The price is in the "no motion" ablation,
    where appearance was the only veto: 0.867 -> 0.788 IDF1 with ground-truth detections.
    """
    if not math.isfinite(z2):
        return float("nan")
    return min(0.5 * max(0.0, z2 - 1.0) + (0.0 if verified else 1.0), cap)


def descriptor_cost(d_color: float, d_edge: float, cap: float = math.inf) -> float:
    """Cost from the tracklet descriptors: ``d_color + d_edge`` (Yu & Medioni eqs. 13-14, the
    negative log of eq. 12 with lambda 1), at most ``cap``.

    The KL divergence of two Gaussian ring models is unbounded: one tracklet of partial or merged
    blobs (an occluder's edge, a shadow, two vehicles in one blob) scores tens or hundreds against
    the rest of its own vehicle, which outweighs every other cue and vetoes the link. Past a few
    units the distance only says "looks different", so it is truncated there: the cue then
    behaves like a likelihood with an outlier floor (a robust mixture). Measured on generated
    scenes with aerotrack's detector (benchmarks/identity.py, three detector versions' tracklets):
    exits re-acquired 3/7 -> 4/7 with each, IDF1 -0.008 to +0.012; unchanged with ground-truth
    detections and UAVDT, Santiago IDF1 -0.002.
    """
    d = d_color + d_edge
    return min(d, cap) if math.isfinite(d) else d


def link_cost(cues: Cues, config: LinkingConfig) -> float:
    """Weighted sum of the available cues' costs."""
    total = 0.0
    for value, weight in ((cues.motion, config.weight_motion),
                          (cues.appearance, config.weight_appearance),
                          (cues.descriptor, config.weight_descriptor)):
        if weight > 0 and math.isfinite(value):
            total += weight * value
    return total

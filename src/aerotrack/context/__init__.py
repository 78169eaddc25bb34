"""Motion and appearance contexts (Ali, Reilly & Shah 2007, section 4) and re-acquisition.

* :mod:`.motion`: predictors of an unobserved target's positions (``context``, ``paper``,
  ``kalman``, ``constant-velocity``), chosen by name from ``PREDICTION_METHODS``; built on
  :mod:`.base` (track table, interface, baselines), :mod:`.paper` (Ali et al. as written) and
  :mod:`.paths` (where earlier objects went).
* :mod:`.appearance`: intra-/inter-class appearance Gaussians and the two-stage match (4.3), and
  the Yu & Medioni 5.2 tracklet descriptor with its KL distances (eqs. 12-14).
* :mod:`.reacquire`: fusion of the cues into one link cost.
* :mod:`.predict`: ``aerotrack predict`` on tracks files.
"""

from .motion import (
    PREDICTION_METHODS,
    MotionPredictor,
    TrackTable,
    affine_regression,
    get_predictor,
    lce,
)

__all__ = ["PREDICTION_METHODS", "MotionPredictor", "TrackTable", "affine_regression",
           "get_predictor", "lce"]

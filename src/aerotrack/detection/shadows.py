"""Moving cast-shadow suppression: the deterministic non-model-based HSV test of Prati et al.
(PAMI 2003, "Detecting moving shadows"), the method Yu & Medioni section 3 names.

A foreground pixel ``p`` is a shadow when the background darkens without changing colour::

    alpha <= V_I(p) / V_B(p) <= beta,   |S_I(p) - S_B(p)| <= tau_S,   D_H(p) <= tau_H

where I is the frame, B the background and ``D_H`` the angular hue difference. Prati et al. use
a signed ``S_I - S_B <= tau_S``; we use the absolute difference, which behaves better on the
compressed, low-saturation colours of aerial video (a vehicle with the road's hue but a different
saturation is then not mistaken for shadow).
"""

from __future__ import annotations

import cv2
import numpy as np


def shadow_mask(image_bgr: np.ndarray, background_bgr: np.ndarray, *, alpha: float = 0.4,
                beta: float = 0.9, tau_s: float = 0.15, tau_h: float = 50.0) -> np.ndarray:
    """Pixels of ``image_bgr`` that look like a cast shadow on ``background_bgr``.

    Parameters
    ----------
    image_bgr, background_bgr : ndarray, shape (h, w, 3) uint8
        Frame and background in the same pixels.
    alpha, beta : float
        Allowed range of the brightness ratio V_I / V_B (alpha: darkest shadow; beta below 1
        so that noise on unchanged background is not called shadow).
    tau_s : float
        Largest saturation difference, on a [0, 1] scale.
    tau_h : float
        Largest hue difference, degrees.

    Returns
    -------
    ndarray, shape (h, w) bool
    """
    hi = cv2.cvtColor(np.ascontiguousarray(image_bgr), cv2.COLOR_BGR2HSV_FULL).astype(np.float32)
    hb = cv2.cvtColor(np.ascontiguousarray(background_bgr), cv2.COLOR_BGR2HSV_FULL).astype(np.float32)
    ratio = (hi[..., 2] + 0.5) / (hb[..., 2] + 0.5)
    ds = np.abs(hi[..., 1] - hb[..., 1]) / 255.0
    dh = np.abs(hi[..., 0] - hb[..., 0]) * (360.0 / 256.0)
    dh = np.minimum(dh, 360.0 - dh)
    # Hue is undefined for grey pixels: do not let it veto a shadow on grey asphalt.
    grey = (hi[..., 1] < 40) & (hb[..., 1] < 40)
    return (ratio >= alpha) & (ratio <= beta) & (ds <= tau_s) & ((dh <= tau_h) | grey)

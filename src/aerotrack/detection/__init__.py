"""Moving-object detection without a trained detector (Yu & Medioni section 3).

``MovingObjectDetector(config, fps, geomap=None, metres_per_unit=None).step(frame, registration)``
returns the detections of the frames that became final; ``describe(image, boxes)`` gives the
appearance data of externally given boxes.
"""

from .appearance import colour_histogram, describe, ring_descriptor
from .background import stack_median, window_background
from .detector import MovingObjectDetector
from .moving import detect_moving
from .shadows import shadow_mask

__all__ = [
    "MovingObjectDetector",
    "colour_histogram",
    "describe",
    "detect_moving",
    "ring_descriptor",
    "shadow_mask",
    "stack_median",
    "window_background",
]

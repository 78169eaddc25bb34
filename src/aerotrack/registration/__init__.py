"""Registration (Yu & Medioni section 2): frame-to-frame homographies, chaining, map refinement.

``FrameRegistrar(config, fps, geomap, H_init).step(frame)`` gives every frame's homography to world
coordinates (map pixels with a map, frame 1's pixels otherwise); the algorithms are pure functions
beside it: :func:`estimate_homography`, :func:`chain` (eq. 1), :func:`refine_against_map`.
"""

from .chain import (
                        chain,
                        check_homography,
                        corner_error,
                        frame_corners,
                        normalize,
                        scale_homography,
)
from .frame2frame import EstimateStats, estimate_homography, frame_quality, to_gray
from .mapref import RefineStats, mutual_information_surface, refine_against_map
from .registrar import (
                        STATUSES,
                        FrameRegistrar,
                        read_registration_csv,
                        register_frames,
                        write_registration_csv,
)

__all__ = [
                        "STATUSES",
                        "EstimateStats",
                        "FrameRegistrar",
                        "RefineStats",
                        "chain",
                        "check_homography",
                        "corner_error",
                        "estimate_homography",
                        "frame_corners",
                        "frame_quality",
                        "mutual_information_surface",
                        "normalize",
                        "read_registration_csv",
                        "refine_against_map",
                        "register_frames",
                        "scale_homography",
                        "to_gray",
                        "write_registration_csv",
]

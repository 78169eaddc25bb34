"""aerotrack: persistent multi-target tracking in aerial video from a moving platform.

The pipeline, one subpackage per stage::

    io/            frames in (video, image folder), MOTChallenge / GeoJSON out
    registration/  frame-to-frame homographies, chaining, refinement against a map
    geo/           map raster: pixel <-> map CRS <-> lon/lat
    detection/     moving objects from a sliding-window background on registered frames
    association/   local (data-driven MCMC) and global (tracklet linking)
    context/       motion context, appearance context, re-acquisition
    pipeline.py    wires the stages
    synth/         scenario generator with ground truth
    evaluation/    TrackEval wrappers, MPE_n
    analysis/      what users make of tracks: screen-line counts, turning movements
    viz/           overlays, map plots, report
    cli/           the command-line layer

Start with :func:`aerotrack.pipeline.run` (a video or image folder in, a
:class:`~aerotrack.pipeline.Result` out), :func:`aerotrack.config.load_config` for settings,
:func:`aerotrack.evaluation.evaluate` for scores and :func:`aerotrack.io.write_mot` for files.
Subpackages are imported on first use (``import aerotrack; aerotrack.pipeline.run(...)``), so
``import aerotrack`` stays fast.
"""

import importlib as _importlib
import os as _os

__version__ = "0.1.0"


def _numba_cache_fallback(package_dir: str, environ=_os.environ) -> None:
    """Give numba a writable cache folder when it would have none.

    The compiled kernels (``@njit(cache=True)``) are cached beside the sources, else in the
    user's cache folder; with neither writable (a read-only install run as ``nobody`` with no
    home: a container) numba raised "cannot cache function" when the detector was imported, and
    ``track`` stopped with a traceback (an ops probe). ``NUMBA_CACHE_DIR`` is then set to a folder
    in the temporary directory; one the user set is kept."""
    import tempfile

    if "NUMBA_CACHE_DIR" in environ or _os.access(package_dir, _os.W_OK):
        return
    base = environ.get("XDG_CACHE_HOME") or _os.path.join(_os.path.expanduser("~"), ".cache")
    try:
        _os.makedirs(_os.path.join(base, "numba"), exist_ok=True)
        if _os.access(_os.path.join(base, "numba"), _os.W_OK):
            return
    except OSError:
        pass
    uid = getattr(_os, "getuid", lambda: "user")()
    environ["NUMBA_CACHE_DIR"] = _os.path.join(tempfile.gettempdir(), f"aerotrack-numba-{uid}")


_numba_cache_fallback(_os.path.dirname(_os.path.abspath(__file__)))

#: The subpackages and modules reachable as attributes of the package.
__all__ = ["analysis", "association", "config", "context", "detection", "errors", "evaluation", "geo", "io",
           "kalman", "outputs", "parallel", "pipeline", "registration", "synth", "types", "viz",
           "__version__"]


def __getattr__(name: str):
    if name in __all__ and name != "__version__":
        return _importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'aerotrack' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})

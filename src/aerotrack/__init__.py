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
    viz/           overlays, map plots, report
    cli/           the command-line layer
"""

__version__ = "0.1.0"

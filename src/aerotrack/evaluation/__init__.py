"""Evaluation: TrackEval's HOTA / CLEAR / Identity on class-agnostic boxes, and published protocols.

``evaluate(gt, pred)`` scores one sequence, ``evaluate_sequences({name: (gt, pred[, ignore])})``
several, combined as TrackEval combines them. See :mod:`aerotrack.evaluation.mot`.
"""

from .mot import (
    EXTRA_KEYS,
    METRIC_KEYS,
    GroundTruthFix,
    drop_exact_duplicates,
    drop_ignored,
    evaluate,
    evaluate_sequences,
    fix_ground_truth,
    sequence_data,
    summarise,
)
from .santiago import SANTIAGO_FRAMES, evaluate_santiago, load_santiago, read_zero_based_mot

__all__ = [
    "EXTRA_KEYS", "METRIC_KEYS", "GroundTruthFix", "SANTIAGO_FRAMES", "drop_exact_duplicates",
    "drop_ignored", "evaluate", "evaluate_santiago", "evaluate_sequences", "fix_ground_truth",
    "load_santiago", "read_zero_based_mot", "sequence_data", "summarise",
]

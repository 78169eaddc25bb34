"""What users make of finished tracks: screen-line counts and turning movements
(:mod:`aerotrack.analysis.counting`)."""

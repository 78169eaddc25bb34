"""Fuzzing of the text parsers and of the association path (issue 9).

Fast profile by default; the long profile runs more examples:
``AEROTRACK_FUZZ_EXAMPLES=2000 python -m pytest tests/test_fuzz.py``.
"""

from __future__ import annotations

import os

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aerotrack.config import load_config
from aerotrack.errors import AerotrackError
from aerotrack.geo import read_map_init
from aerotrack.io.mot import parse_mot_text
from aerotrack.pipeline import run

N = int(os.environ.get("AEROTRACK_FUZZ_EXAMPLES", "60"))
FUZZ = settings(max_examples=N, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

cell = st.one_of(st.integers(-5, 5000).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr),
                 st.text(alphabet="0123456789.,-e naxf\t", max_size=8))
line = st.lists(cell, min_size=0, max_size=12).map(",".join)


@FUZZ
@given(st.lists(line, max_size=20).map("\n".join))
def test_mot_parser_never_crashes(text):
    try:
        arr = parse_mot_text(text, "fuzz.txt")
    except AerotrackError as exc:
        assert "fuzz.txt" in str(exc) and "\n" not in str(exc)
        return
    assert arr.shape[1] == 10
    assert np.all(np.isfinite(arr)) and np.all(arr[:, 0] >= 1)


@FUZZ
@given(st.lists(line, max_size=8).map("\n".join), st.booleans())
def test_map_init_parser_never_crashes(tmp_path_factory, body, gcp):
    p = tmp_path_factory.mktemp("mi") / "init.csv"
    p.write_text(("frame_x,frame_y,map_x,map_y\n" if gcp else "") + body)
    try:
        H = read_map_init(p)
    except AerotrackError as exc:
        assert "\n" not in str(exc)
        return
    assert H.shape == (3, 3) and np.all(np.isfinite(H)) and H[2, 2] == 1


toml_key = st.sampled_from(["window_s", "max_speed_mps", "method", "bogus", "scale", "min_inliers"])
toml_val = st.one_of(st.integers(-10, 10).map(str), st.floats(-1e3, 1e3).map(repr),
                     st.sampled_from(['"lk"', "true", "[1, 2]", '"x"', "nan", "inf", "{}"]))
section = st.sampled_from(["registration", "detection", "association", "linking", "context", "nope"])


@FUZZ
@given(st.lists(st.tuples(section, toml_key, toml_val), max_size=6),
       st.text(alphabet="[]=\"'abc.\n 1", max_size=20))
def test_config_loader_never_crashes(tmp_path_factory, entries, junk):
    text = "".join(f"[{s}]\n{k} = {v}\n" for s, k, v in entries) + (junk if len(entries) % 2 else "")
    p = tmp_path_factory.mktemp("cfg") / "c.toml"
    p.write_text(text)
    try:
        load_config(p)
    except AerotrackError as exc:
        assert "\n" not in str(exc).strip()


@st.composite
def detection_stream(draw):
    n_frames = draw(st.integers(1, 25))
    rows = []
    for f in range(1, n_frames + 1):
        for _ in range(draw(st.integers(0, 6))):
            x = draw(st.floats(-50, 600))
            y = draw(st.floats(-50, 400))
            w = draw(st.floats(1, 80))
            h = draw(st.floats(1, 80))
            c = draw(st.floats(0, 1))
            rows.append([f, -1, x, y, w, h, c, -1, -1, -1])
    return np.array(rows, dtype=float).reshape(-1, 10)


@settings(max_examples=max(10, N // 3), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(detection_stream(), st.integers(0, 3))
def test_association_on_random_streams(dets, seed):
    """No crash; partition invariants: each detection in at most one track, one point per track
    per frame, observed points are real detections."""
    result = run(None, detections=dets, fps=30.0, seed=seed)
    used = set()
    by_frame = {}
    for d in result.detections:
        by_frame[d.frame] = d
    for t in result.tracks:
        frames = [p.frame for p in t.points]
        assert frames == sorted(frames) and len(frames) == len(set(frames))
        for p in t.points:
            if p.kind == "observed":
                key = (p.frame, p.det_index)
                assert key not in used
                used.add(key)
                d = by_frame[p.frame]
                np.testing.assert_allclose(p.box, d.boxes[p.det_index])

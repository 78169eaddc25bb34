"""The HTML report, loaded in real headless Chromium: no console errors, every picture decodes,
the overlay video plays, the tracks are shown, nothing is fetched from the network."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from test_viz import H, W, make_run  # the tests folder is on sys.path

from aerotrack.viz.browser import find_chromium, load_page
from aerotrack.viz.report import build_report

pytestmark = pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed")


@pytest.fixture
def report(tmp_path):
    run = make_run(tmp_path, n_frames=30)
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for f in range(1, 31):
        img = rng.integers(40, 200, (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(frames / f"{f:06d}.jpg"), img)
    # ground truth = the tracks themselves: a known answer (MOTA 1) the report must show
    gt = tmp_path / "gt.txt"
    gt.write_text((run / "tracks.csv").read_text())
    return build_report(run, input_path=frames, gt_path=gt), run


def test_report_is_self_contained(report):
    path, run = report
    text = path.read_text()
    assert not re.search(r'(src|href)\s*=\s*"(https?:)?//', text)
    assert "Content-Security-Policy" in text
    # map, space-time, registration, and the evaluation's errors over time
    assert 'src="data:video/webm;base64,' in text and text.count('src="data:image/png;base64,') == 4
    assert "Frames with the most errors" not in text  # a perfect prediction has none
    assert (run / "overlay.webm").is_file()


def test_report_in_chromium(report):
    path, _ = report
    page = load_page(path)
    assert page.console == []  # no errors, no warnings, no CSP violations
    sc = page.selfcheck
    assert sc is not None, "the page's self-check did not run"
    assert sc["images"] >= 4 and sc["images_ok"] == sc["images"]
    assert sc["video"] == "ok" and sc["video_width"] > 0
    assert sc["track_rows"] == 3
    assert 'id="evaluation"' in page.dom and "MOTA" in page.dom and "1.000" in page.dom
    assert "Tracks on the map" in page.dom


def test_chromium_sees_console_errors(tmp_path):
    """The check above can fail: a page with a script error is reported."""
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('boom'); notDefined();</script></body></html>")
    page = load_page(bad, budget_ms=2000)
    assert any("boom" in m for m in page.console)
    assert any("notDefined" in m for m in page.console)

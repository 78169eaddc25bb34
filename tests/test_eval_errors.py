"""The error analysis: CLEAR's box-by-box matching (its counts are TrackEval's), ``eval --errors``
and the report's error section."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest
from test_eval import _run as _cli  # the tests folder is on sys.path
from test_eval import _two_targets

from aerotrack.cli.main import main
from aerotrack.evaluation import evaluate
from aerotrack.evaluation.errors import (
    FALSE,
    MISS,
    SWITCH,
    clear_matching,
    error_rows_csv,
    false_tracks,
    target_summaries,
)
from aerotrack.io.mot import write_mot


def _random_case(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Crowded targets, predictions that drop, jitter, swap ids, and false boxes; frames with
    only true or only predicted boxes (TrackEval's matching carries over those)."""
    n_t, n_f = int(rng.integers(2, 7)), int(rng.integers(5, 40))
    gt, pred = [], []
    pos = rng.uniform(0, 120, (n_t, 2))
    vel = rng.normal(0, 3, (n_t, 2))
    next_id = 100
    ids = np.arange(n_t) + 50
    for f in range(1, n_f + 1):
        if rng.random() < 0.1:
            continue  # an empty frame
        pos += vel
        for t in range(n_t):
            if rng.random() < 0.85:
                gt.append([f, t + 1, *pos[t], 20, 12])
            if rng.random() < 0.8:
                if rng.random() < 0.05:
                    ids[t], next_id = next_id, next_id + 1  # a new id for the target
                j = rng.normal(0, 4, 2)
                pred.append([f, ids[t], *(pos[t] + j), 20, 12])
        if rng.random() < 0.2 and n_t >= 2:  # two predicted tracks swap targets
            a, b = rng.choice(n_t, 2, replace=False)
            ids[a], ids[b] = ids[b], ids[a]
        for _ in range(int(rng.poisson(0.5))):
            pred.append([f, next_id, *rng.uniform(0, 150, 2), 20, 12])
            next_id += 1
    gt = np.asarray(gt, float).reshape(-1, 6)
    pred = np.asarray(pred, float).reshape(-1, 6)
    return gt, pred


@pytest.mark.parametrize("seed", range(40))
@pytest.mark.parametrize("iou", [0.3, 0.5])
def test_matching_counts_are_trackevals(seed, iou):
    gt, pred = _random_case(np.random.default_rng(seed))
    if not len(gt):
        return
    last = int(max(gt[:, 0].max(), pred[:, 0].max(initial=1)))
    want = evaluate(gt, pred, iou_threshold=iou, frames=(1, last))
    m = clear_matching(gt, pred, iou_threshold=iou)
    assert m.counts() == {k: want[k] for k in ("TP", "FP", "FN", "IDSW")}
    assert len(m) == len(gt) + want["FP"]  # every true box once, every false one once


def test_a_switch_names_the_old_and_new_track_and_the_frame():
    gt = _two_targets(20)
    pred = gt.copy()
    pred[:, 1] += 10
    pred[(pred[:, 1] == 11) & (pred[:, 0] > 10), 1] = 7  # target 1 gets a new id at frame 11
    keep = ~((pred[:, 1] == 12) & np.isin(pred[:, 0], [5, 6, 7]))  # target 2 missed 5-7
    fp = np.array([[3, 9, 300, 300, 20, 10, 1, -1, -1, -1]], float)
    m = clear_matching(gt, np.vstack([pred[keep], fp]))
    sw = np.flatnonzero(m.kind == SWITCH)
    assert len(sw) == 1 and m.frame[sw[0]] == 11 and m.gt_id[sw[0]] == 1
    assert (m.previous_id[sw[0]], m.track_id[sw[0]]) == (11, 7)
    miss = m.kind == MISS
    assert m.frame[miss].tolist() == [5, 6, 7] and set(m.gt_id[miss].tolist()) == {2}
    false = np.flatnonzero(m.kind == FALSE)
    assert len(false) == 1 and m.track_id[false[0]] == 9
    assert m.box[false[0]].tolist() == [300, 300, 20, 10]
    t1, t2 = target_summaries(m)
    assert (t1.gt_id, t1.found, t1.frames, t1.tracks, t1.switches) == (1, 20, 20, ((11, 10), (7, 10)), 1)
    assert (t2.found, t2.longest_miss, t2.tracks) == (17, 3, ((12, 17),))
    assert false_tracks(m) == [(9, 1, 1)]


def test_eval_errors_writes_every_error_once(tmp_path, capsys):
    gt = _two_targets(20)
    pred = gt.copy()
    pred[(pred[:, 1] == 1) & (pred[:, 0] > 10), 1] = 7
    pred = pred[~((pred[:, 1] == 2) & (pred[:, 0] > 15))]
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", pred)
    code, out, err = _cli(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                           "--errors", tmp_path / "errors.csv", "--json"], capsys)
    assert code == 0, err
    res = json.loads(out)
    with open(tmp_path / "errors.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    kinds = [r["kind"] for r in rows]
    assert kinds.count("miss") == res["FN"] == 5 and kinds.count("switch") == res["IDSW"] == 1
    assert kinds.count("false") == res["FP"] == 0
    sw = next(r for r in rows if r["kind"] == "switch")
    assert (sw["frame"], sw["gt_id"], sw["previous_id"], sw["track_id"]) == ("11", "1", "1", "7")
    assert "gt 2 75 %" in err  # the least-found target named


def test_eval_errors_frames_follow_zero_based_files(tmp_path, capsys):
    gt = _two_targets(5)
    gt[:, 0] -= 1  # frames 0..4
    pred = gt[~((gt[:, 1] == 2) & (gt[:, 0] == 0))]
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", pred)
    code, _, err = _cli(["-q", "eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                         "--zero-based", "--errors", tmp_path / "e.csv"], capsys)
    assert code == 0, err
    lines = (tmp_path / "e.csv").read_text().splitlines()
    assert len(lines) == 2 and lines[1].split(",")[1:4] == ["0", "miss", "2"]


@pytest.mark.parametrize("bad", ["folder", "gt"])
def test_eval_errors_refuses_a_bad_file_before_scoring(tmp_path, capsys, bad):
    write_mot(tmp_path / "gt.txt", _two_targets(3))
    write_mot(tmp_path / "pred.txt", _two_targets(3))
    (tmp_path / "folder").mkdir()
    before = (tmp_path / "gt.txt").read_bytes()
    code, out, err = _cli(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                           "--errors", tmp_path / ("folder" if bad == "folder" else "gt.txt")],
                          capsys)
    assert code == 2 and out == "" and err.strip().count("\n") == 0 and "--errors" in err, err
    assert (tmp_path / "gt.txt").read_bytes() == before


def test_report_shows_the_errors(tmp_path, capsys):
    from test_viz import grey_frames, make_run

    run = make_run(tmp_path, with_map=False, n_frames=12)
    rows = np.loadtxt(run / "tracks.csv", delimiter=",")
    gt = rows.copy()
    extra = gt[(gt[:, 0] <= 6) & (gt[:, 1] == gt[0, 1])].copy()  # a target no track found
    extra[:, 1], extra[:, 3] = 999, extra[:, 3] + 60
    write_mot(tmp_path / "gt.txt", np.vstack([gt, extra]))
    frames = grey_frames(tmp_path / "frames")
    main(["-q", "report", str(run), "--input", str(frames), "--gt", str(tmp_path / "gt.txt"),
          "--no-video"])
    text = (run / "report.html").read_text()
    assert "Errors over time" in text and "Frames with the most errors" in text
    targets = re.search(r'<table id="targets">.*?</table>', text, re.DOTALL).group(0)
    assert targets.count("<tr>") == len(np.unique(gt[:, 1])) + 2  # a row each, and the head
    assert re.search(r'<td data-v="999">999</td>.*?<td data-v="0.0">0 %</td>', targets)
    assert 'alt="frame 1"' in text  # the worst frames start with the first of the misses


def test_eval_errors_never_replaces_an_ignore_file_found_by_auto(tmp_path, capsys):
    """`--ignore auto` finds SEQ_gt_ignore.txt beside the ground truth: --errors naming it
    replaced UAVDT's ignore regions with the errors, exit 0 (a probe)."""
    write_mot(tmp_path / "M01_gt.txt", _two_targets(3))
    write_mot(tmp_path / "pred.txt", _two_targets(3))
    ign = tmp_path / "M01_gt_ignore.txt"
    write_mot(ign, np.array([[1, -1, 500, 500, 10, 10, 1, -1, -1, -1]], float))
    before = ign.read_bytes()
    code, _, err = _cli(["eval", "--gt", tmp_path / "M01_gt.txt", "--pred", tmp_path / "pred.txt",
                         "--ignore", "auto", "--errors", ign], capsys)
    assert code == 2 and "--errors" in err and "--ignore" in err, err
    assert ign.read_bytes() == before
    code, _, err = _cli(["eval", "--gt", tmp_path / "M01_gt.txt", "--pred", tmp_path / "pred.txt",
                         "--errors", "-"], capsys)
    assert code == 2 and "file name" in err and not (tmp_path / "-").exists()


def test_a_loose_box_names_its_neighbour_and_percentages_round_down():
    gt = _two_targets(400)
    pred = gt.copy()
    half = (pred[:, 1] == 2) & (pred[:, 0] == 5)
    pred[half, 4] *= 2.5  # target 2's box far too wide in frame 5: IoU 0.4
    m = clear_matching(gt, pred)
    miss, false = np.flatnonzero(m.kind == MISS), np.flatnonzero(m.kind == FALSE)
    assert len(miss) == len(false) == 1
    assert (m.near_id[miss[0]], m.near_id[false[0]]) == (2, 2)
    assert m.near_iou[miss[0]] == pytest.approx(0.4) == m.near_iou[false[0]]
    t2 = target_summaries(m)[1]
    assert (t2.found, t2.frames, t2.found_percent) == (399, 400, "99 %")
    lines = error_rows_csv({"s": m}).splitlines()
    assert lines[0].endswith(",iou,near_id,near_iou") and lines[1].endswith(",2,0.400")


def test_report_scores_the_frames_asked(tmp_path, capsys):
    from test_viz import make_run

    run = make_run(tmp_path, with_map=False, n_frames=12)
    rows = np.loadtxt(run / "tracks.csv", delimiter=",")
    write_mot(tmp_path / "gt.txt", rows[rows[:, 0] != 3])  # frame 3: every track a false box
    main(["-q", "report", str(run), "--gt", str(tmp_path / "gt.txt"), "--no-video",
          "--frames", "4:"])
    text = (run / "report.html").read_text()
    assert "frames 4-12 (as asked)" in text and "Tracks with false positives" not in text
    main(["-q", "report", str(run), "--gt", str(tmp_path / "gt.txt"), "--no-video"])
    assert "Tracks with false positives" in (run / "report.html").read_text()
    code, _, err = _cli(["report", run, "--frames", "2:3"], capsys)
    assert code == 2 and "--frames" in err


def test_eval_errors_is_not_written_when_eval_fails(tmp_path, capsys):
    """--geo-crs refusing metres as degrees failed after the errors file was written."""
    gt = _two_targets(3)
    gt[:, 7:9] = [500000.0, 4000000.0]  # metres, not degrees
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", gt)
    code, _, err = _cli(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                         "--errors", tmp_path / "e.csv", "--geo-crs", "EPSG:4326"], capsys)
    assert code == 2 and "--geo-crs" in err and not (tmp_path / "e.csv").exists()

"""Evaluation: known answers, Santiago parity with published numbers, CLI errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aerotrack.cli.main import main
from aerotrack.errors import InputError
from aerotrack.evaluation import (
    METRIC_KEYS,
    drop_exact_duplicates,
    drop_ignored,
    evaluate,
    evaluate_santiago,
    evaluate_sequences,
    fix_ground_truth,
    load_santiago,
)
from aerotrack.io.mot import write_mot


def _two_targets(n_frames: int = 20) -> np.ndarray:
    """Two well-separated targets moving right, every frame: ids 1 and 2."""
    rows = []
    for f in range(1, n_frames + 1):
        rows.append([f, 1, 10 + 2 * f, 10, 20, 10, 1, -1, -1, -1])
        rows.append([f, 2, 10 + 2 * f, 200, 20, 10, 1, -1, -1, -1])
    return np.asarray(rows, float)


# --------------------------------------------------------------------------- known answers

def test_perfect_prediction_scores_one():
    gt = _two_targets()
    pred = gt.copy()
    pred[:, 1] += 100  # ids need not agree, only be consistent
    r = evaluate(gt, pred)
    assert set(METRIC_KEYS) <= set(r)
    assert r["MOTA"] == pytest.approx(1.0)
    assert r["IDF1"] == pytest.approx(1.0)
    assert r["HOTA"] == pytest.approx(1.0, abs=1e-6)
    assert r["MOTP"] == pytest.approx(1.0)
    assert r["IDSW"] == 0
    assert (r["GT_IDs"], r["Pred_IDs"], r["GT_Dets"], r["Pred_Dets"]) == (2, 2, 40, 40)


def test_one_id_switch_is_counted():
    gt = _two_targets(20)
    pred = gt.copy()
    pred[(pred[:, 1] == 1) & (pred[:, 0] > 10), 1] = 7  # target 1 gets a new id halfway
    r = evaluate(gt, pred)
    assert r["IDSW"] == 1
    assert r["MOTA"] == pytest.approx(1 - 1 / 40)
    # IDF1: target 1 keeps its best id for 10 of 20 frames: IDTP = 20 + 10 of 40 + 40.
    assert r["IDF1"] == pytest.approx(2 * 30 / 80)
    assert r["HOTA"] < 0.95


def test_misses_and_false_positives():
    gt = _two_targets(10)
    pred = gt[gt[:, 1] == 1].copy()  # target 2 missed
    fp = pred.copy()
    fp[:, 1], fp[:, 3] = 9, 400  # a false track far away
    r = evaluate(gt, np.vstack([pred, fp]))
    assert (r["TP"], r["FN"], r["FP"]) == (10, 10, 10)
    assert r["MOTA"] == pytest.approx(0.0)


def test_iou_threshold_option():
    gt = _two_targets(10)
    pred = gt.copy()
    pred[:, 2] += 8  # IoU = 12 / 28 = 0.43
    assert evaluate(gt, pred)["TP"] == 0
    assert evaluate(gt, pred, iou_threshold=0.4)["TP"] == 20
    with pytest.raises(InputError, match="--iou"):
        evaluate(gt, pred, iou_threshold=1.5)


def test_predictions_past_the_ground_truth_are_not_scored():
    gt = _two_targets(10)
    extra = _two_targets(15)
    r = evaluate(gt, extra)
    assert r["FP"] == 0 and r["Pred_Dets"] == 20


def test_confidence_does_not_filter_ground_truth():
    gt = _two_targets(10)
    gt[:, 6] = 0.0  # MOTChallenge's loader would drop every row with conf 0
    assert evaluate(gt, gt)["GT_Dets"] == 20


def test_fix_ground_truth_reflects_and_drops_duplicates():
    gt = _two_targets(5)
    bad = gt.copy()
    bad[bad[:, 1] == 2, 2] += 20
    bad[bad[:, 1] == 2, 4] *= -1  # stored from the right edge
    bad = np.vstack([bad, bad[3:4]])
    fixed, fix = fix_ground_truth(bad)
    assert fix.reflected_rows == 5 and fix.reflected_ids == (2,)
    assert fix.duplicates == ((int(bad[3, 0]), int(bad[3, 1])),)
    np.testing.assert_allclose(fixed[np.lexsort((fixed[:, 1], fixed[:, 0]))], gt)
    assert "reflected 5" in fix.describe() and "duplicate" in fix.describe()
    # Kept as published, negative boxes match nothing: half the targets are missed.
    assert evaluate(bad, gt)["FN"] == 5
    assert evaluate(fixed, gt)["MOTA"] == pytest.approx(1.0)


def test_duplicate_with_different_box_is_refused():
    gt = _two_targets(3)
    other = gt[:1].copy()
    other[0, 2] += 5
    with pytest.raises(InputError, match="twice"):
        drop_exact_duplicates(np.vstack([gt, other]))


def test_ignore_regions_drop_predictions_inside():
    gt = _two_targets(10)
    fp = gt[gt[:, 1] == 1].copy()
    fp[:, 1], fp[:, 3] = 9, 400
    ignore = fp.copy()
    ignore[:, 2] -= 5
    ignore[:, 4] += 10
    kept, n = drop_ignored(np.vstack([gt, fp]), ignore)
    assert n == 10 and len(kept) == 20
    r = evaluate(gt, np.vstack([gt, fp]), ignore=ignore)
    assert r["FP"] == 0 and r["ignored_pred"] == 10


def test_sequences_combine_as_sums():
    a = _two_targets(10)
    b = _two_targets(30)
    pb = b[b[:, 1] == 1]
    res = evaluate_sequences({"a": (a, a), "b": (b, pb)})
    assert res["sequences"]["a"]["MOTA"] == pytest.approx(1.0)
    assert res["sequences"]["b"]["MOTA"] == pytest.approx(0.5)
    c = res["combined"]
    assert c["GT_Dets"] == 80 and c["FN"] == 30
    assert c["MOTA"] == pytest.approx(50 / 80)  # weighted by detections, not averaged


# --------------------------------------------------------------------------- Santiago parity

@pytest.mark.data
@pytest.mark.parametrize("tracks,mota,idf1", [("sort", 0.673, 0.837), ("bytetrack", 0.682, 0.842)])
def test_santiago_published_parity(shared_data, tracks, mota, idf1):
    r = evaluate_santiago(shared_data / "santiago_intersection_dfs", tracks)
    assert r["MOTA"] == pytest.approx(mota, abs=0.005)
    assert r["IDF1"] == pytest.approx(idf1, abs=0.005)
    assert r["IDSW"] == 0 and r["GT_IDs"] == 30


@pytest.mark.data
def test_santiago_corrected_ground_truth(shared_data):
    r = evaluate_santiago(shared_data / "santiago_intersection_dfs", "bytetrack", fix_gt=True)
    assert r["IDF1"] == pytest.approx(0.879, abs=0.005)
    assert r["MOTA"] == pytest.approx(0.757, abs=0.005)
    assert r["HOTA"] == pytest.approx(0.767, abs=0.005)


def test_unannotated_movers_lists_driving_tracks_the_ground_truth_leaves_out():
    from aerotrack.evaluation.santiago import unannotated_movers

    gt = _two_targets(20)
    rows = [r.copy() for r in gt]  # tracks 1 and 2 on the annotated targets
    for f in range(1, 21):
        rows.append([f, 3, 10 + 3 * f, 400, 20, 10, 1, -1, -1, -1])  # drives 57 px: listed
        rows.append([f, 4, 300, 400, 20, 10, 1, -1, -1, -1])  # parked: not listed
        rows.append([f, 5, 12 + 2 * f, 12, 20, 10, 1, -1, -1, -1])  # overlaps target 1
    pred = np.asarray(rows, float)
    pred[pred[:, 1] == 2, 2] += 15  # a poor box (IoU 0.14) is still not an unannotated vehicle
    pred[(pred[:, 1] == 2) & (pred[:, 0] == 5), 2] -= 15
    assert unannotated_movers(gt, pred, frames=(1, 20)) == [3]
    # outside the scoring window a track's overlap does not count, nor its rows
    assert unannotated_movers(gt, pred, frames=(6, 20)) == [2, 3]


@pytest.mark.data
def test_santiago_published_tracks_hold_unannotated_vehicles(shared_data):
    """ByteTrack's published tracks follow four vehicles the ground truth leaves out; without
    them its HOTA rises from 0.767 (benchmarks/santiago_gt.py)."""
    from aerotrack.evaluation.santiago import SANTIAGO_FRAMES, unannotated_movers

    gt, pred = load_santiago(shared_data / "santiago_intersection_dfs", "bytetrack")
    gt, _ = fix_ground_truth(gt)
    movers = unannotated_movers(gt, pred)
    assert movers == [40, 44, 77, 88]
    kept = evaluate(gt, pred[~np.isin(pred[:, 1], movers)], frames=SANTIAGO_FRAMES)
    assert kept["HOTA"] == pytest.approx(0.806, abs=0.005)


@pytest.mark.data
def test_santiago_loader_is_one_based(shared_data):
    gt, pred = load_santiago(shared_data / "santiago_intersection_dfs", "sort")
    assert gt[:, 0].min() == 1 and gt[:, 0].max() == 98 and len(gt) == 2600
    assert pred[:, 0].min() == 1


def test_santiago_scores_a_one_based_file_when_told_and_warns_when_not(shared_data, tmp_path,
                                                                       caplog):
    """aerotrack's own 1-based tracks.csv passed as a path was read as 0-based, silently."""
    s = shared_data / "santiago_intersection_dfs"
    _, pred = load_santiago(s, "bytetrack")
    write_mot(tmp_path / "tracks.csv", pred)  # 1-based, as aerotrack writes
    want = evaluate_santiago(s, pred)
    assert evaluate_santiago(s, tmp_path / "tracks.csv", zero_based=False)["HOTA"] == \
        pytest.approx(want["HOTA"], abs=1e-3)  # written rounded
    with caplog.at_level("WARNING", logger="aerotrack.evaluation.santiago"):
        caplog.clear()
        wrong = evaluate_santiago(s, tmp_path / "tracks.csv")
    assert wrong["HOTA"] < want["HOTA"] - 0.05
    assert "zero_based=False" in caplog.text


@pytest.mark.data
def test_cli_santiago_json(shared_data, capsys):
    s = shared_data / "santiago_intersection_dfs"
    code, out, err = _run(["eval", "--gt", str(s / "dfs_ground_truth.csv"), "--pred",
                           str(s / "baseline_tracks/yolo_bytetrack_detections_filtered.csv"),
                           "--zero-based", "--frames", "2:98", "--fix-gt", "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    assert list(res)[:len(METRIC_KEYS)] == list(METRIC_KEYS)  # the contract's keys, then counts
    assert res["IDF1"] == pytest.approx(0.879, abs=0.005)
    assert "reflected 375" in err and "duplicate" in err


# --------------------------------------------------------------------------- CLI

def _run(argv, capsys):
    """Run the console entry point; returns (exit code, stdout, stderr)."""
    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as exc:
        code = exc.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_cli_text_and_json(tmp_path, capsys):
    gt = _two_targets(10)
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", gt)
    code, out, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                           str(tmp_path / "pred.txt"), "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["MOTA"] == pytest.approx(1.0)
    code, out, _ = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                         str(tmp_path / "pred.txt")], capsys)
    assert code == 0
    assert "HOTA" in out and "IDF1" in out and "1.000" in out


def test_cli_missing_file(tmp_path, capsys):
    write_mot(tmp_path / "gt.txt", _two_targets(3))
    code, _, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                         str(tmp_path / "nope.txt")], capsys)
    assert code == 2
    assert err.strip().count("\n") == 0 and "nope.txt" in err and "not found" in err
    assert "Traceback" not in err


def test_cli_malformed_row_names_the_line(tmp_path, capsys):
    write_mot(tmp_path / "gt.txt", _two_targets(3))
    (tmp_path / "pred.txt").write_text("1,1,10,10,5,5,1\n2,1,10,abc,5,5,1\n")
    code, _, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                         str(tmp_path / "pred.txt")], capsys)
    assert code == 2 and "line 2" in err and err.strip().count("\n") == 0
    assert "Traceback" not in err


def test_cli_negative_size_in_pred_refused_but_accepted_in_gt(tmp_path, capsys):
    gt = _two_targets(3)
    neg = gt.copy()
    neg[0, 4] = -20
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "neg.txt", neg)
    code, _, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                         str(tmp_path / "neg.txt")], capsys)
    assert code == 2 and "negative" in err and err.strip().count("\n") == 0
    code, out, err = _run(["eval", "--gt", str(tmp_path / "neg.txt"), "--pred",
                           str(tmp_path / "gt.txt"), "--json"], capsys)
    assert code == 0 and "negative" in err
    assert json.loads(out)["MOTA"] == pytest.approx(4 / 6)  # one miss, one false positive


def test_cli_folders_pair_by_sequence(tmp_path, capsys):
    (tmp_path / "gt").mkdir()
    (tmp_path / "pred").mkdir()
    a, b = _two_targets(10), _two_targets(20)
    write_mot(tmp_path / "gt" / "S1_gt.txt", a)
    write_mot(tmp_path / "gt" / "S2_gt.txt", b)
    write_mot(tmp_path / "gt" / "S2_gt_whole.txt", b)  # skipped
    write_mot(tmp_path / "pred" / "S1.txt", a)
    write_mot(tmp_path / "pred" / "S2.txt", b[b[:, 1] == 1])
    code, out, err = _run(["eval", "--gt", str(tmp_path / "gt"), "--pred", str(tmp_path / "pred"),
                           "--json"], capsys)
    assert code == 0, err
    res = json.loads(out)
    assert set(res["sequences"]) == {"S1", "S2"}
    assert res["GT_Dets"] == 60 and res["MOTA"] == pytest.approx(40 / 60)


@pytest.mark.data
def test_cli_uavdt_folder_with_ignore_regions(shared_data, tmp_path, capsys):
    """Perfect predictions on UAVDT's ground truth score 1 with --ignore auto: ground-truth boxes
    inside ignore regions are dropped along with the predictions there."""
    u = shared_data / "uavdt_gt_only"
    (tmp_path / "pred").mkdir()
    for seq in ("M0101", "M0206"):
        (tmp_path / "pred" / f"{seq}.txt").write_text((u / f"{seq}_gt.txt").read_text())
    gts = [str(u / "M0101_gt.txt"), str(u / "M0206_gt.txt")]
    preds = [str(tmp_path / "pred" / "M0101.txt"), str(tmp_path / "pred" / "M0206.txt")]
    code, out, err = _run(["eval", "--gt", gts[0], "--gt", gts[1], "--pred", preds[0],
                           "--pred", preds[1], "--ignore", "auto", "--json"], capsys)
    assert code == 0, err
    res = json.loads(out)
    assert set(res["sequences"]) == {"M0101", "M0206"}
    assert res["IDF1"] == pytest.approx(1.0) and res["HOTA"] == pytest.approx(1.0, abs=1e-6)
    code, out, err = _run(["eval", "--gt", gts[0], "--pred", preds[0], "--pred", preds[1]], capsys)
    assert code == 2 and "one --pred per --gt" in err


@pytest.mark.data
def test_santiago_one_based_tracks_and_gt_zero_based_flag(shared_data, tmp_path, capsys):
    """aerotrack's own tracks are 1-based: the library takes them as an array, the CLI with
    --gt-zero-based; both must give the published baseline's score."""
    s = shared_data / "santiago_intersection_dfs"
    _, pred = load_santiago(s, "bytetrack")
    r = evaluate_santiago(s, pred)
    assert r["MOTA"] == pytest.approx(0.682, abs=0.005)
    write_mot(tmp_path / "tracks.csv", pred)
    code, out, err = _run(["eval", "--gt", str(s / "dfs_ground_truth.csv"), "--pred",
                           str(tmp_path / "tracks.csv"), "--gt-zero-based", "--frames", "2:98",
                           "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["IDF1"] == pytest.approx(0.842, abs=0.005)


# --------------------------------------------------------------------------- found by a probe

def _write(path, rows, sep=","):
    path.write_text("".join(sep.join(f"{v:g}" for v in r) + "\n" for r in rows))
    return path


def test_cli_zero_based_files_separated_by_tabs(tmp_path, capsys):
    """The 0-based shift used to split on commas and spaces only: tab-separated files were
    scored one frame off (HOTA 0.561 for a perfect prediction) or refused at frame 0."""
    gt = _two_targets(6)
    zero = gt.copy()
    zero[:, 0] -= 1
    _write(tmp_path / "gt0.txt", zero[:, :7], sep="\t")
    write_mot(tmp_path / "pred.txt", gt)
    code, out, err = _run(["eval", "--gt", str(tmp_path / "gt0.txt"), "--pred",
                           str(tmp_path / "pred.txt"), "--gt-zero-based", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["MOTA"] == pytest.approx(1.0)


def test_cli_zero_based_ignore_regions_are_shifted(tmp_path, capsys):
    """--ignore is numbered as the ground truth: with --zero-based its frame 0 is frame 1."""
    gt = _two_targets(4)
    zero = gt.copy()
    zero[:, 0] -= 1
    pred = np.vstack([zero, [[0, 9, 300, 300, 10, 10, 1, -1, -1, -1]]])  # a false alarm at 0
    write_mot(tmp_path / "gt.txt", gt)
    _write(tmp_path / "gt0.txt", zero)
    _write(tmp_path / "pred0.txt", pred)
    _write(tmp_path / "ign0.txt", [[0, -1, 290, 290, 40, 40, 1]])  # covers the false alarm
    code, out, err = _run(["eval", "--gt", str(tmp_path / "gt0.txt"), "--pred",
                           str(tmp_path / "pred0.txt"), "--zero-based", "--ignore",
                           str(tmp_path / "ign0.txt"), "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["MOTA"] == pytest.approx(1.0)  # the false alarm was ignored


@pytest.mark.parametrize("content, fragment", [
    (b"\xff\xfe\x00garbage\n", "cannot read"),
    (b"0.5,1,10,10,5,5,1\n", "line 1"),
    (b"-1,1,10,10,5,5,1\n", "got -1"),
])
def test_cli_zero_based_bad_files_are_one_line_errors(tmp_path, capsys, content, fragment):
    write_mot(tmp_path / "pred.txt", _two_targets(3))
    (tmp_path / "bad.txt").write_bytes(content)
    code, _, err = _run(["eval", "--gt", str(tmp_path / "bad.txt"), "--pred",
                         str(tmp_path / "pred.txt"), "--gt-zero-based"], capsys)
    assert code == 2 and "Traceback" not in err, err
    assert fragment in err and "bad.txt" in err and err.strip().count("\n") == 0, err


def test_repeated_frame_id_with_large_or_negative_ids(tmp_path, capsys):
    """(frame, id) used to be packed as frame * 1e9 + id: ids past 1e9 collided and the message
    named the wrong frame."""
    gt = _two_targets(2)
    big = gt.copy()
    big[big[:, 1] == 1, 1] = 1_500_000_000
    big[big[:, 1] == 2, 1] = 500_000_000
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "big.txt", big)
    code, out, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                           str(tmp_path / "big.txt"), "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["MOTA"] == pytest.approx(1.0)
    twice = np.vstack([gt, gt[2:3]])
    twice[-1, 2] += 5
    write_mot(tmp_path / "twice.txt", twice)
    code, _, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                         str(tmp_path / "twice.txt")], capsys)
    assert code == 2 and "(2, 1)" in err, err


def test_cli_gt_with_two_boxes_for_one_id_names_the_file(tmp_path, capsys):
    gt = _two_targets(2)
    bad = np.vstack([gt, gt[:1] + [0, 0, 5, 0, 0, 0, 0, 0, 0, 0]])
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "bad_gt.txt", bad)
    code, _, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--gt",
                         str(tmp_path / "bad_gt.txt"), "--pred", str(tmp_path / "gt.txt"),
                         "--pred", str(tmp_path / "gt.txt")], capsys)
    assert code == 2 and "--gt" in err and "bad_gt.txt" in err and "(1, 1)" in err, err


def test_cli_geo_error_uses_the_scoring_window(tmp_path, capsys):
    """--geo-crs measured every frame, --frames or not."""
    gt = _two_targets(4)
    gt[:, 7], gt[:, 8] = 500000.0, 4000000.0
    pred = gt.copy()
    pred[pred[:, 0] == 1, 7] += 500.0  # frame 1 is 500 m off
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", pred)
    code, out, err = _run(["eval", "--gt", str(tmp_path / "gt.txt"), "--pred",
                           str(tmp_path / "pred.txt"), "--geo-crs", "EPSG:32633", "--frames",
                           "2:4", "--json"], capsys)
    assert code == 0, err
    geo = json.loads(out)["geo_error"]
    assert geo["matches"] == 6 and geo["mean_m"] == pytest.approx(0.0, abs=1e-6)
    assert "same CRS" not in err
    # the prediction in UTM, the ground truth in lon/lat: kilometres apart, said so
    ll = gt.copy()
    ll[:, 7], ll[:, 8] = -115.2, 36.1
    write_mot(tmp_path / "ll.txt", ll)
    code, out, err = _run(["eval", "--gt", str(tmp_path / "ll.txt"), "--pred",
                           str(tmp_path / "pred.txt"), "--geo-crs", "EPSG:32633"], capsys)
    assert code == 0 and "same CRS" in err, err


def test_stray_huge_frame_number_is_scored_quickly(tmp_path, capsys):
    """TrackEval's arrays were built for every frame up to the last: one ground-truth row at
    frame 50 000 000 took minutes and gigabytes. Only occupied frames are handed over now (the
    metrics skip empty frames, so the scores are those of the full loop)."""
    gt = _two_targets(5)
    far = np.vstack([gt, [[50_000_000, 7, 10, 10, 20, 10, 1, -1, -1, -1]]])
    r = evaluate(far, gt)
    assert r["FN"] == 1 and r["TP"] == 10 and r["IDSW"] == 0


def test_sparse_frames_give_the_scores_of_every_frame():
    """Gaps (frames with neither true nor predicted boxes) do not change any score: compared
    with the same rows packed into consecutive frames."""
    rng = np.random.default_rng(3)
    gt = _two_targets(30)
    pred = gt.copy()
    pred[:, 2:4] += rng.normal(0, 3, (len(pred), 2))
    pred[(pred[:, 0] > 10) & (pred[:, 0] < 15) & (pred[:, 1] == 1), 1] = 2  # a swap
    pred[(pred[:, 0] > 10) & (pred[:, 0] < 15) & (pred[:, 1] == 2) & (pred[:, 3] < 100), 1] = 1
    pred = pred[~((pred[:, 0] == 20) & (pred[:, 1] == 1))]
    spread = lambda a: np.column_stack([a[:, 0] * 7 - 3, a[:, 1:]])
    a, b = evaluate(gt, pred), evaluate(spread(gt), spread(pred))
    for k in ("HOTA", "MOTA", "IDF1", "IDSW", "Frag", "MT", "TP", "FP", "FN"):
        assert a[k] == pytest.approx(b[k]), k


def test_evaluate_checks_its_arrays():
    gt = _two_targets(3)
    nan = gt.copy()
    nan[0, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        evaluate(gt, nan)
    with pytest.raises(InputError, match="repeated"):
        evaluate(gt, np.vstack([gt, gt[:1]]))
    zero = gt.copy()
    zero[:, 0] -= 1
    with pytest.raises(InputError, match="1-based"):
        evaluate(gt, zero)
    with pytest.raises(InputError, match="scoring window"):
        evaluate(gt, gt, frames=(0, 4))
    with pytest.raises(InputError, match="expected"):
        evaluate_sequences({"a": (gt,)})
    empty = evaluate(gt, np.zeros((0, 10)))
    assert np.isnan(empty["LocA"]) and empty["FN"] == len(gt)


def test_cli_motchallenge_folder_layout(tmp_path, capsys):
    """SEQ/gt/gt.txt (MOTChallenge) is read; a README.txt beside UAVDT's *_gt.txt is not a
    sequence."""
    for seq, n in (("A", 5), ("B", 8)):
        (tmp_path / "mot" / seq / "gt").mkdir(parents=True)
        write_mot(tmp_path / "mot" / seq / "gt" / "gt.txt", _two_targets(n))
    (tmp_path / "runs").mkdir()
    write_mot(tmp_path / "runs" / "A.txt", _two_targets(5))
    write_mot(tmp_path / "runs" / "B.txt", _two_targets(8))
    code, out, err = _run(["eval", "--gt", str(tmp_path / "mot"), "--pred",
                           str(tmp_path / "runs"), "--json"], capsys)
    assert code == 0, err
    assert set(json.loads(out)["sequences"]) == {"A", "B"}
    (tmp_path / "uavdt").mkdir()
    write_mot(tmp_path / "uavdt" / "A_gt.txt", _two_targets(5))
    (tmp_path / "uavdt" / "README.txt").write_text("UAVDT ground truth\n")
    code, out, err = _run(["eval", "--gt", str(tmp_path / "uavdt"), "--pred",
                           str(tmp_path / "runs"), "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["MOTA"] == pytest.approx(1.0)


def test_cli_regressions_found_by_a_second_probe(tmp_path, capsys):
    """Hidden macOS files in a ground-truth folder, a MOTChallenge sequence folder given
    itself, --frames with an open end, a hint when the predictions cover part of the ground
    truth's frames, and lon/lat scored with a projected --geo-crs."""
    (tmp_path / "mot" / "A" / "gt").mkdir(parents=True)
    write_mot(tmp_path / "mot" / "A" / "gt" / "gt.txt", _two_targets(20))
    (tmp_path / "mot" / "._A").write_bytes(b"\x00\x05\x16\x07")
    (tmp_path / "runs").mkdir()
    write_mot(tmp_path / "runs" / "A.txt", _two_targets(20))
    for gt in (tmp_path / "mot", tmp_path / "mot" / "A"):
        code, out, err = _run(["eval", "--gt", str(gt), "--pred", str(tmp_path / "runs"),
                               "--json"], capsys)
        assert code == 0 and json.loads(out)["MOTA"] == pytest.approx(1.0), err
    part = _two_targets(20)
    write_mot(tmp_path / "part.txt", part[part[:, 0] >= 11])
    gt_file = tmp_path / "mot" / "A" / "gt" / "gt.txt"
    code, out, err = _run(["eval", "--gt", str(gt_file), "--pred", str(tmp_path / "part.txt"),
                           "--json"], capsys)
    assert code == 0 and "--frames 11:20 scores only those" in err, err
    code, out, err = _run(["eval", "--gt", str(gt_file), "--pred", str(tmp_path / "part.txt"),
                           "--frames", "11:", "--json"], capsys)
    assert code == 0 and json.loads(out)["MOTA"] == pytest.approx(1.0), err
    ll = _two_targets(5)
    ll[:, 7], ll[:, 8] = -115.2, 36.1
    write_mot(tmp_path / "ll.txt", ll)
    code, out, err = _run(["eval", "--gt", str(tmp_path / "ll.txt"), "--pred",
                           str(tmp_path / "ll.txt"), "--geo-crs", "EPSG:32611"], capsys)
    assert code == 0 and "lon/lat degrees?" in err, err
    # the error line after the warning says what its metres are (it printed "median 0.00 m")
    assert "median 0.00 m" in out and "look like lon/lat degrees" in out, out
    code, out, err = _run(["eval", "--gt", str(tmp_path / "ll.txt"), "--pred",
                           str(tmp_path / "ll.txt"), "--geo-crs", "EPSG:32611", "--json"], capsys)
    assert "lon/lat" in json.loads(out)["geo_error"]["suspect"], out


# --------------------------------------------------------------------------- protocol (probe)

def test_rows_flagged_not_to_be_considered_are_pointed_out_and_can_be_left_out(tmp_path, capsys):
    """MOT16/17 and VisDrone mark rows not to score with 0 in the 7th column; they were counted
    silently (a tracker of the valid objects only scored MOTA 0.74 where TrackEval says 1.0)."""
    gt = _two_targets(10)
    flagged = gt[gt[:, 1] == 2].copy()
    flagged[:, 6] = 0
    gt = np.vstack([gt[gt[:, 1] == 1], flagged])
    only_valid = gt[gt[:, 1] == 1]
    r = evaluate(gt, only_valid, drop_flagged=True)
    assert (r["MOTA"], r["IDF1"], r["GT_Dets"]) == (pytest.approx(1.0), pytest.approx(1.0), 10)
    both = evaluate(gt, gt, drop_flagged=True)  # the flagged object tracked: not a false positive
    assert (both["MOTA"], both["FP"], both["Pred_Dets"]) == (pytest.approx(1.0), 0, 10)
    assert evaluate(gt, only_valid)["MOTA"] == pytest.approx(0.5)  # the contract: every row
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", only_valid)
    code, out, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                           "--json"], capsys)
    assert code == 0 and json.loads(out)["MOTA"] == pytest.approx(0.5), err
    assert "10 rows are flagged 0" in err and "--drop-flagged" in err
    code, out, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                           "--json", "--drop-flagged"], capsys)
    assert code == 0 and json.loads(out)["MOTA"] == pytest.approx(1.0), err


def test_classes_score_vehicles_of_a_mixed_ground_truth(tmp_path, capsys):
    """A VisDrone-like ground truth: a car (class 4), a pedestrian (1) and an ignored region (0)
    over a second car. A vehicle tracker is scored on the vehicles with --classes 4 (it scored
    the pedestrians it does not look for as misses, and a track on one as a false positive),
    and --ignore-classes 0 makes the region an ignore region; mistakes are one-line errors."""
    rows, pred = [], []
    for f in range(1, 21):
        rows += [[f, 1, 10 + 2 * f, 50, 30, 15, 1, 4, 0, 0], [f, 2, 200, 60 + f, 8, 20, 1, 1, 0, 0],
                 [f, 3, 400 + f, 300, 30, 15, 1, 4, 0, 0], [f, 0, 380, 280, 100, 60, 0, 0, 0, 0],
                 [f, 0, 600, 20, 40, 40, 0, 0, 0, 0]]  # regions share VisDrone's id 0
        pred += [[f, 7, 10 + 2 * f, 50, 30, 15, 1, -1, -1, -1],
                 [f, 8, 200, 60 + f, 8, 20, 1, -1, -1, -1]]  # a track on the pedestrian
    gt, pred = np.array(rows, float), np.array(pred, float)
    with pytest.raises(InputError, match="occurs twice"):  # regions sharing an id, as objects
        evaluate(gt, pred)
    plain = evaluate(gt[gt[:, 7] > 0], pred)
    assert (plain["FN"], plain["GT_IDs"]) == (20, 3)
    cars = evaluate(gt[gt[:, 7] > 0], pred, classes=[4])
    assert (cars["FP"], cars["FN"], cars["GT_IDs"]) == (0, 20, 2)  # the pedestrian's track: free
    vehicles = evaluate(gt, pred, classes=[4], ignore_classes=[0])
    assert (vehicles["MOTA"], vehicles["IDF1"], vehicles["GT_IDs"]) == (1.0, 1.0, 1)
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", pred)
    args = ["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt", "--json"]
    code, out, err = _run([*args, "--classes", "4", "--ignore-classes", "0"], capsys)
    assert code == 0 and json.loads(out)["MOTA"] == pytest.approx(1.0), err
    code, out, err = _run([*args, "--classes", "4", "--ignore-classes", "0", "--fix-gt"], capsys)
    assert code == 0 and json.loads(out)["MOTA"] == pytest.approx(1.0), err
    assert "flagged 0" not in err  # VisDrone's flagged rows are its ignored regions
    code, out, err = _run(args[:-1] + ["--classes", "4", "--ignore-classes", "0"], capsys)
    assert "0 predictions in ignore regions dropped" in out, out  # (said, as --ignore says it)
    for extra, msg in ((["--classes", "3"], "no ground-truth row of these classes in column 8"),
                       (["--classes", "car"], "expected class ids separated by commas"),
                       (["--classes", "4", "--class-column", "12"], "no class in column 12"),
                       (["--classes", "0"], "both hold 0"),
                       (["--classes", "4", "--class-column", "7"], "8 or more")):
        code, _, err = _run([*args, "--ignore-classes", "0", *extra], capsys)
        assert code == 2 and msg in err and "Traceback" not in err, (extra, err)
    for extra, msg in ((["--class-column", "9"], "only with --classes"),
                       (["--classes", "4"], "(frame, id) = (1, 0) occurs twice")):
        code, _, err = _run([*args, *extra], capsys)
        assert code == 2 and msg in err and "Traceback" not in err, (extra, err)


def test_a_motchallenge_sequence_is_scored_over_its_seqinfo_length(tmp_path, capsys):
    """Boxes invented after the last annotated frame but inside seqLength cost nothing."""
    seq = tmp_path / "gt" / "SEQ"
    (seq / "gt").mkdir(parents=True)
    write_mot(seq / "gt" / "gt.txt", _two_targets(10))
    (seq / "seqinfo.ini").write_text("[Sequence]\nname=SEQ\nseqLength=15\n")
    (tmp_path / "pred").mkdir()
    write_mot(tmp_path / "pred" / "SEQ.txt", _two_targets(20))
    code, out, err = _run(["eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred",
                           "--json"], capsys)
    assert code == 0, err
    r = json.loads(out)
    assert (r["FP"], r["Pred_Dets"]) == (10, 30)  # frames 11-15 counted, 16-20 past the sequence


def test_a_frame_numbering_mistake_is_warned_about(tmp_path, capsys):
    gt = _two_targets(30)
    write_mot(tmp_path / "gt.txt", gt)
    shifted = gt.copy()
    shifted[:, 0] += 1  # 1-based tracks read as 0-based and shifted once more
    write_mot(tmp_path / "pred.txt", shifted)
    code, _, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt"],
                        capsys)
    assert code == 0 and "better one frame later" in err
    write_mot(tmp_path / "pred.txt", gt)
    code, _, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt"],
                        capsys)
    assert code == 0 and "one frame" not in err


def test_unused_ignore_regions_beside_the_ground_truth_are_pointed_out(tmp_path, capsys):
    (tmp_path / "gt").mkdir()
    (tmp_path / "pred").mkdir()
    write_mot(tmp_path / "gt" / "M1_gt.txt", _two_targets(5))
    write_mot(tmp_path / "gt" / "M1_gt_ignore.txt", np.array([[1, -1, 500, 500, 50, 50, 1, -1, -1, -1]]))
    write_mot(tmp_path / "pred" / "M1.txt", _two_targets(5))
    code, _, err = _run(["eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred"], capsys)
    assert code == 0 and "--ignore auto" in err
    code, _, err = _run(["eval", "--gt", tmp_path / "gt", "--pred", tmp_path / "pred",
                         "--ignore", "auto"], capsys)
    assert code == 0 and "--ignore auto" not in err
    write_mot(tmp_path / "gt" / "M1_gt_whole.txt", _two_targets(5))  # UAVDT's other ground truth
    code, _, err = _run(["eval", "--gt", tmp_path / "gt" / "M1_gt_whole.txt", "--pred",
                         tmp_path / "pred" / "M1.txt"], capsys)
    assert code == 0 and "--ignore auto" in err


def test_json_has_the_counts_and_null_for_undefined_scores(tmp_path, capsys):
    write_mot(tmp_path / "gt.txt", _two_targets(5))
    (tmp_path / "pred.txt").write_text("")
    code, out, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt",
                           "--json"], capsys)
    assert code == 0, err
    r = json.loads(out)  # strict JSON: no NaN
    assert r["LocA"] is None and r["MOTP"] is None
    assert (r["TP"], r["FP"], r["FN"], r["ML"]) == (0, 0, 10, 2)


def test_non_integer_ids_are_refused(tmp_path, capsys):
    """TrackEval truncates them: 1000.3 and 1000 would be scored as one track."""
    gt = _two_targets(5)
    pred = gt.copy()
    pred[pred[:, 0] > 3, 1] += 0.3
    write_mot(tmp_path / "gt.txt", gt)
    np.savetxt(tmp_path / "pred.txt", pred, fmt="%g", delimiter=",")
    code, _, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt"],
                        capsys)
    assert code == 2 and "ids are integers" in err and "Traceback" not in err


def test_zero_size_ground_truth_boxes_are_pointed_out(tmp_path, capsys):
    """Santiago's 4 zero-area boxes made a perfect prediction score 0.997 with no word."""
    gt = _two_targets(5)
    gt[2, 4] = 0.0
    write_mot(tmp_path / "gt.txt", gt)
    write_mot(tmp_path / "pred.txt", _two_targets(5))
    code, _, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "pred.txt"],
                        capsys)
    assert code == 0 and "1 boxes with a zero width or height" in err, err


def test_folder_scoring_names_what_it_leaves_out_or_chooses(tmp_path, capsys):
    """A sequence folder without gt/gt.txt was left out of the scores silently, and of an empty
    SEQ.txt beside a run's SEQ/tracks.csv the empty file was scored without a word."""
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    for name in ("A", "B"):
        (gt_dir / name / "gt").mkdir(parents=True)
        (gt_dir / name / "seqinfo.ini").write_text("[Sequence]\nimDir=img1\n")
    write_mot(gt_dir / "A" / "gt" / "gt.txt", _two_targets(10))
    (gt_dir / "B" / "gt" / "GT.txt").write_text("")  # misnamed: B has no gt/gt.txt
    (pred_dir / "A").mkdir(parents=True)
    write_mot(pred_dir / "A" / "tracks.csv", _two_targets(10))
    (pred_dir / "A.txt").write_text("")
    code, _, err = _run(["eval", "--gt", gt_dir, "--pred", pred_dir], capsys)
    assert code == 0, err
    assert "1 sequence folder(s) without gt/gt.txt are not scored: B" in err, err
    assert "A.txt and A/tracks.csv for sequence 'A'" in err, err


def test_one_sequence_folder_scores_against_its_run_or_tracks_file(tmp_path, capsys):
    """`--gt SEQ --pred RUN` (the sequence's own run folder) looked for RUN/SEQ/tracks.csv, and
    `--gt SEQ --pred tracks.csv` was refused ("must be a folder"): both score now, alike."""
    seq = tmp_path / "SEQ"
    (seq / "gt").mkdir(parents=True)
    write_mot(seq / "gt" / "gt.txt", _two_targets(10))
    run = tmp_path / "run"
    run.mkdir()
    write_mot(run / "tracks.csv", _two_targets(10)[:15])
    got = []
    for pred in (run, run / "tracks.csv"):
        code, out, err = _run(["eval", "--gt", seq, "--pred", pred, "--json"], capsys)
        assert code == 0, err
        got.append(json.loads(out)["MOTA"])
    assert got[0] == got[1] == pytest.approx(0.75)


def test_a_sequence_without_objects_is_scored_among_others(tmp_path, capsys):
    """One empty gt.txt in a benchmark folder stopped the whole evaluation ("no rows"); TrackEval
    scores such a sequence (every prediction there a false positive). One empty ground truth
    alone is still an error."""
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    for name in ("A", "B"):
        (gt_dir / name / "gt").mkdir(parents=True)
        (pred_dir / name).mkdir(parents=True)
        write_mot(pred_dir / name / "tracks.csv", _two_targets(10))
    write_mot(gt_dir / "A" / "gt" / "gt.txt", _two_targets(10))
    (gt_dir / "B" / "gt" / "gt.txt").write_text("")
    code, out, err = _run(["eval", "--gt", gt_dir, "--pred", pred_dir, "--json"], capsys)
    assert code == 0 and "no object to find" in err, err
    res = json.loads(out)
    assert res["sequences"]["B"]["FP"] == 20 and res["FP"] == 20 and res["TP"] == 20
    code, _, err = _run(["eval", "--gt", gt_dir / "B" / "gt" / "gt.txt", "--pred",
                         pred_dir / "B" / "tracks.csv"], capsys)
    assert code == 2 and "no rows" in err, err


def test_a_run_folder_scores_beside_a_ground_truth_file(tmp_path, capsys):
    """`--gt gt.txt --pred RUN` was refused ("is a folder"), though a run folder stands for its
    tracks.csv beside a sequence folder; a folder without tracks.csv is still refused."""
    write_mot(tmp_path / "gt.txt", _two_targets(10))
    run = tmp_path / "run"
    run.mkdir()
    write_mot(run / "tracks.csv", _two_targets(10)[:15])
    got = []
    for pred in (run, run / "tracks.csv"):
        code, out, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", pred, "--json"],
                              capsys)
        assert code == 0, err
        got.append(json.loads(out)["MOTA"])
    assert got[0] == got[1] == pytest.approx(0.75)
    (tmp_path / "empty").mkdir()
    code, _, err = _run(["eval", "--gt", tmp_path / "gt.txt", "--pred", tmp_path / "empty"],
                        capsys)
    assert code == 2 and "is a folder" in err, err

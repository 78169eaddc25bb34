"""``aerotrack eval``: score tracks against a ground truth with TrackEval (class-agnostic boxes)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click
import numpy as np

from ..errors import InputError
from ..evaluation import (
    METRIC_KEYS,
    drop_exact_duplicates,
    evaluate_sequences,
    fix_ground_truth,
)
from ..evaluation.mot import EXTRA_KEYS, frame_offset_overlap, has_consider_flag, scored_rows
from ..io.mot import read_mot
from .common import PathArg

log = logging.getLogger(__name__)

_GT_SKIP_SUFFIXES = ("_gt_whole", "_gt_ignore", "_ignore")
_MOT_EXTS = (".txt", ".csv")


def _seq_name(path: Path) -> str:
    stem = path.stem
    if path.name in ("gt.txt", "tracks.csv"):  # MOTChallenge seq/gt/gt.txt or a run folder
        return path.parent.parent.name if path.parent.name == "gt" else path.parent.name
    return stem.removesuffix("_gt_whole").removesuffix("_gt")  # UAVDT's M0101_gt(_whole).txt


def _gt_files(folder: Path) -> list[Path]:
    """The ground-truth files of a folder: MOTChallenge's SEQ/gt/gt.txt, else UAVDT's *_gt.txt
    (a README.txt beside them is not a sequence), else every .txt and .csv file."""
    if (folder / "gt" / "gt.txt").is_file():  # one MOTChallenge sequence folder itself
        return [folder / "gt" / "gt.txt"]
    entries = [d for d in folder.iterdir() if not d.name.startswith(".")]  # macOS ._ files
    mot = sorted(d / "gt" / "gt.txt" for d in entries if (d / "gt" / "gt.txt").is_file())
    if mot:
        lost = sorted(d.name for d in entries if (d / "seqinfo.ini").is_file()
                      and not (d / "gt" / "gt.txt").is_file())
        if lost:  # a sequence left out of the scores without a word
            log.warning("--gt %s: %d sequence folder(s) without gt/gt.txt are not scored: %s",
                        folder, len(lost), ", ".join(lost))
        return mot
    files = sorted(p for p in entries if p.is_file() and p.suffix in _MOT_EXTS
                   and not p.stem.endswith(_GT_SKIP_SUFFIXES))
    named = [p for p in files if p.stem.endswith("_gt")]
    if named:
        return named
    if not files:
        raise InputError(f"--gt {folder}: folder holds no ground truth (SEQ/gt/gt.txt, "
                         "*_gt.txt, or .txt/.csv files)")
    return files


def _find_in(folder: Path, seq: str, option: str, candidates: list[str]) -> Path:
    found = [folder / c for c in candidates if (folder / c).is_file()]
    if len(found) > 1:  # (an empty SEQ.txt beside a run's SEQ/tracks.csv was scored silently)
        log.warning("%s %s: %s for sequence %r; scoring %s", option, folder,
                    " and ".join(p.name if p.parent == folder else f"{p.parent.name}/{p.name}"
                                 for p in found), seq, found[0])
    for p in found:
        return p
    raise InputError(f"{option} {folder}: no file for sequence {seq!r} "
                     f"(looked for {', '.join(candidates)})")


def _seq_length(gt_file: Path) -> int | None:
    """``seqLength`` of a MOTChallenge sequence (``SEQ/seqinfo.ini`` beside ``SEQ/gt/gt.txt``):
    the frames a tracker is scored on, which may run past the last annotated one."""
    if gt_file.parent.name != "gt":
        return None
    ini = gt_file.parent.parent / "seqinfo.ini"
    if not ini.is_file():
        return None
    import configparser

    cp = configparser.ConfigParser(interpolation=None)
    try:
        cp.read(ini, encoding="utf-8-sig")  # (a BOM, as the frame reader takes it)
        section = next((n for n in cp.sections() if n.lower() == "sequence"), None)
        n = cp.getint(section, "seqLength", fallback=None) if section else None
    except (configparser.Error, ValueError, UnicodeDecodeError):
        log.warning("%s: unreadable seqLength; the sequence is scored up to its last annotated "
                    "frame", ini)
        return None
    if n is not None and n < 1:
        log.warning("%s: seqLength %d is not a frame count; the sequence is scored up to its "
                    "last annotated frame", ini, n)
        return None
    return n


def _unused_ignore_hint(pairs) -> None:
    """UAVDT ships ignore regions beside its ground truth; scoring without them counts every
    vehicle in them (unannotated parking lots) as a false positive."""
    found = [g.parent / f"{_seq_name(g)}{suffix}.txt" for _, g, _ in pairs
             for suffix in ("_gt_ignore", "_ignore")
             if (g.parent / f"{_seq_name(g)}{suffix}.txt").is_file()]
    if found:
        log.warning("%d of %d ground truths have ignore regions beside them (e.g. %s) that are not "
                    "used: --ignore auto drops the boxes in them, as UAVDT's protocol does",
                    len(found), len(pairs), found[0])


def _frame_shift_hint(seqs: dict) -> None:
    """Warn when the predictions overlap the ground truth clearly better one frame off: a 0- or
    1-based numbering mistake (Santiago's published tracks scored with the wrong flag lost 0.17
    HOTA, silently)."""
    for name, (gt, pred, _) in seqs.items():
        if not len(gt) or not len(pred):
            continue
        at = {d: frame_offset_overlap(gt, pred, d) for d in (-1, 0, 1)}
        best = max((-1, 1), key=lambda d: at[d])
        if at[best] > 0.1 and at[best] > 1.15 * at[0]:
            log.warning("%s: the predictions overlap the ground truth better one frame %s (mean "
                        "best IoU %.2f against %.2f in the same frame): is one file numbered from "
                        "0 and the other from 1? (--zero-based, --gt-zero-based)",
                        name or "sequence", "later" if best > 0 else "earlier", at[best], at[0])


def _pair(gts: tuple[str, ...], preds: tuple[str, ...], ignores: tuple[str, ...]
          ) -> list[tuple[str, Path, Path, Path | None]]:
    """(name, gt file, pred file, ignore file or None) per sequence."""
    gpaths, ppaths = [Path(g) for g in gts], [Path(p) for p in preds]
    for opt, paths in (("--gt", gpaths), ("--pred", ppaths)):
        for p in paths:
            if not p.exists():
                raise InputError(f"{opt} {p}: file not found")
    one_seq = len(gpaths) == 1 and (gpaths[0] / "gt" / "gt.txt").is_file()
    if one_seq and len(ppaths) == 1 and ppaths[0].is_file():
        # one MOTChallenge sequence folder and its tracks file
        g = gpaths[0] / "gt" / "gt.txt"
        pairs = [(_seq_name(g), g, ppaths[0])]
    elif len(gpaths) == 1 and gpaths[0].is_dir():
        if len(ppaths) != 1 or not ppaths[0].is_dir():
            raise InputError("--pred: must be a folder when --gt is a folder")
        pairs = []
        for g in _gt_files(gpaths[0]):
            seq = _seq_name(g)
            # (a sequence folder's own run folder holds tracks.csv itself)
            pairs.append((seq, g, _find_in(ppaths[0], seq, "--pred",
                                           [f"{seq}.txt", f"{seq}.csv", f"{seq}/tracks.csv",
                                            *(["tracks.csv"] if one_seq else [])])))
    else:
        # a run folder stands for its tracks.csv beside ground-truth files (as it does beside a
        # sequence folder): `--gt gt.txt --pred run/` was refused
        ppaths = [p / "tracks.csv" if p.is_dir() and (p / "tracks.csv").is_file() else p
                  for p in ppaths]
        for opt, paths in (("--gt", gpaths), ("--pred", ppaths)):
            for p in paths:
                if p.is_dir():
                    raise InputError(f"{opt} {p}: is a folder; give folders as one --gt and one "
                                     "--pred, or files as repeated options")
        if len(gpaths) != len(ppaths):
            raise InputError(f"--pred: {len(ppaths)} files for {len(gpaths)} --gt files; "
                             "give one --pred per --gt, in the same order")
        pairs = [(_seq_name(g), g, p) for g, p in zip(gpaths, ppaths)]
    names = [n for n, _, _ in pairs]
    if len(set(names)) != len(names):
        pairs = [(f"{i + 1}:{n}", g, p) for i, (n, g, p) in enumerate(pairs)]

    out = []
    if not ignores:
        _unused_ignore_hint(pairs)
        return [(n, g, p, None) for n, g, p in pairs]
    if len(ignores) == 1 and (ignores[0] == "auto" or Path(ignores[0]).is_dir()):
        for n, g, p in pairs:
            seq = _seq_name(g)
            folder = g.parent if ignores[0] == "auto" else Path(ignores[0])
            out.append((n, g, p, _find_in(folder, seq, "--ignore",
                                          [f"{seq}_gt_ignore.txt", f"{seq}_ignore.txt"])))
        return out
    if len(ignores) != len(pairs):
        raise InputError(f"--ignore: {len(ignores)} files for {len(pairs)} sequences; give one per "
                         "--gt, a folder, or 'auto'")
    return [(n, g, p, Path(i)) for (n, g, p), i in zip(pairs, ignores)]


def _pred_in_crs(pred: np.ndarray, path: Path, geo_crs: str) -> np.ndarray:
    """``--pred``'s x, y in ``--geo-crs``: a run's tracks.csv holds them in its map's CRS
    (``summary.json`` ``map_crs`` beside it), which is converted; other files are taken as they
    are. A run on a UTM map scored with ``--geo-crs EPSG:4326`` against lon/lat ground truth gave
    a NaN geo error, and ``--json`` a traceback (a probe)."""
    if Path(path).name not in ("tracks.csv", "predicted.csv"):  # (a file of the user's beside
        return pred                                             # a run's results is not one)
    summary = Path(path).parent / "summary.json"
    try:
        named = json.loads(summary.read_text(encoding="utf-8")).get("map_crs")
    except (OSError, ValueError, AttributeError):
        return pred
    if not named:
        return pred
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    try:
        src, dst = CRS.from_user_input(named), CRS.from_user_input(geo_crs)
    except CRSError:
        return pred  # (geo_errors names a bad --geo-crs)
    if src == dst:
        return pred
    pred = pred.copy()
    ok = ~np.all(pred[:, 7:9] == -1, axis=1)
    if ok.any():
        t = Transformer.from_crs(src, dst, always_xy=True)
        pred[ok, 7], pred[ok, 8] = t.transform(pred[ok, 7], pred[ok, 8])
    log.info("--pred %s: x, y converted from the run's map CRS (%s, summary.json) to --geo-crs %s",
             path, named, geo_crs)
    return pred


def _parse_frames(text: str | None, last_gt: int | None = None) -> tuple[int, int] | None:
    """``FIRST:LAST`` (either end may be empty: 1, the ground truth's last frame)."""
    if text is None:
        return None
    try:
        a_text, b_text = text.split(":")
        a = int(a_text) if a_text.strip() else 1
        b = int(b_text) if b_text.strip() else int(last_gt or 10**9)
    except ValueError:
        raise InputError(
            f"--frames: expected FIRST:LAST (1-based, inclusive), got {text!r}") from None
    if a < 1 or b < a:
        raise InputError(f"--frames: expected 1 <= FIRST <= LAST, got {text!r}")
    return a, b


def _parse_classes(text: str | None, option: str) -> tuple[int, ...] | None:
    """``--classes 4,5,6,9``: integer class ids, or None."""
    if text is None:
        return None
    try:
        out = tuple(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        out = ()
    if not out:
        raise InputError(f"{option} {text!r}: expected class ids separated by commas (4,5,6,9)")
    return out


def _json_number(v):
    """NaN (an undefined score: nothing to match) as JSON's null; NaN is not JSON."""
    return None if isinstance(v, float) and not np.isfinite(v) else v


def _fmt(v: float, key: str) -> str:
    return f"{v:d}" if isinstance(v, int) else f"{v:.3f}"


def _table(rows: list[tuple[str, dict]]) -> str:
    keys = list(METRIC_KEYS)
    width = max(8, *(len(n) for n, _ in rows))
    head = f"{'sequence':<{width}} " + " ".join(f"{k:>9}" for k in keys)
    lines = [head]
    for name, r in rows:
        lines.append(f"{name:<{width}} " + " ".join(f"{_fmt(r[k], k):>9}" for k in keys))
    return "\n".join(lines)


def _write_errors(path: Path, seqs: dict, per_seq: dict, iou_threshold: float, by_class: dict,
                  drop_flagged: bool, frame_offset: int) -> None:
    """``eval --errors``: CLEAR's matching of the scored rows, errors to ``path`` (atomic), a
    line per sequence, and per target at -vv."""
    from ..evaluation.errors import KINDS, clear_matching, error_rows_csv, target_summaries
    from ..io.output import atomic_write_text

    matchings = {}
    for name, (g, p, ign) in seqs.items():
        g, p, _, _ = scored_rows(g, p, ignore=ign, frames=per_seq.get(name), name=name,
                                 quiet=True, drop_flagged=drop_flagged, **by_class)
        name = name or "sequence"  # (one pair's name may be empty)
        matchings[name] = m = clear_matching(g, p, iou_threshold=iou_threshold)
        n = np.bincount(m.kind, minlength=len(KINDS))
        lost = [t for t in target_summaries(m) if t.found < t.frames]
        lost.sort(key=lambda t: (t.found_fraction, -t.longest_miss, t.gt_id))
        log.info("%s: %d missed, %d false, %d ID switch%s%s", name, n[2], n[3], n[1],
                 "" if n[1] == 1 else "es", "; least found: " + ", ".join(
                     f"gt {t.gt_id} {t.found_percent}" for t in lost[:3]) if lost else "")
        for t in target_summaries(m):
            log.debug("%s gt %d: frames %d-%d, found %d/%d, tracks %s, switches %d, longest "
                      "miss %d frames", name, t.gt_id, t.first_frame + frame_offset,
                      t.last_frame + frame_offset, t.found, t.frames,
                      " ".join(f"{i}({n})" for i, n in t.tracks) or "none", t.switches,
                      t.longest_miss)
    atomic_write_text(path, error_rows_csv(matchings, frame_offset=frame_offset))
    log.info("errors -> %s", path)


def _coverage_hint(seqs: dict) -> None:
    """Say when the predictions cover only a part of the ground truth's frames (a --frames A:B
    run scored against a whole clip's ground truth counts every other frame as misses)."""
    for name, (gt, pred, _) in seqs.items():
        if not len(pred) or not len(gt):
            continue
        p0, p1 = int(pred[:, 0].min()), int(pred[:, 0].max())
        g0, g1 = int(gt[:, 0].min()), int(gt[:, 0].max())
        if (p1 - p0 + 1) < 0.8 * (g1 - g0 + 1):
            log.warning("%s: the predictions cover frames %d-%d of the ground truth's %d-%d; "
                        "the other frames count as misses (--frames %d:%d scores only those)",
                        name, p0, p1, g0, g1, p0, p1)


@click.command("eval")
@click.option("--gt", "gts", multiple=True, type=PathArg(), required=True, metavar="FILE|DIR",
              help="Ground truth (MOTChallenge rows, 1-based frames). Repeat for several "
                   "sequences, or give a folder: MOTChallenge's SEQ/gt/gt.txt, else UAVDT's "
                   "*_gt.txt (*_gt_whole and *_gt_ignore skipped), else every .txt/.csv.")
@click.option("--pred", "preds", multiple=True, type=PathArg(), required=True, metavar="FILE|DIR",
              help="Predicted tracks, one per --gt in the same order (a run folder stands for "
                   "its tracks.csv), or a folder holding SEQ.txt, SEQ.csv or SEQ/tracks.csv for "
                   "each ground-truth sequence SEQ.")
@click.option("--ignore", "ignores", multiple=True, type=PathArg(), metavar="FILE|DIR|auto",
              help="Ignore regions (MOT rows, e.g. UAVDT *_gt_ignore.txt): predicted and true boxes "
                   "whose centre or most of whose area lies in one are dropped. One per --gt, a "
                   "folder, or 'auto' (SEQ_gt_ignore.txt beside each ground truth).")
@click.option("--iou", "iou_threshold", type=float, default=0.5, show_default=True,
              help="IoU a match needs for MOTA/IDSW/Frag and IDF1 (HOTA integrates over "
                   "0.05..0.95).")
@click.option("--frames", "frames", default=None, metavar="FIRST:LAST",
              help="Score only these 1-based frames (either end may be empty); predictions "
                   "outside them are dropped (default: 1 to the ground truth's last frame).")
@click.option("--zero-based", is_flag=True,
              help="Both files number frames from 0 (as Santiago's published files do): add 1.")
@click.option("--gt-zero-based", is_flag=True,
              help="Only the ground truth numbers frames from 0 (e.g. Santiago's ground truth "
                   "against aerotrack's own 1-based tracks.csv).")
@click.option("--fix-gt", is_flag=True,
              help="Correct the ground truth first (reflect boxes with negative sizes, drop exact "
                   "duplicates), say what changed, and report the corrected score.")
@click.option("--geo-crs", "geo_crs", default=None, metavar="CRS",
              help="Also report the geo error: metres between the x, y columns of matched true and "
                   "predicted boxes, both in this CRS (e.g. EPSG:4326 for lon/lat). A run's "
                   "tracks.csv, in its map's CRS, is converted to it.")
@click.option("--drop-flagged", is_flag=True,
              help="Read a 7th ground-truth column holding only 0 and 1 as MOTChallenge's "
                   "'consider' flag (MOT16/17, VisDrone): rows flagged 0 are not scored, nor the "
                   "predictions matching them (IoU >= 0.5). Default: every row counts.")
@click.option("--classes", "classes", default=None, metavar="LIST",
              help="Score only ground-truth rows of these classes (e.g. 4,5,6,9: VisDrone's car, "
                   "van, truck, bus): rows of other classes (pedestrians) are not scored, nor the "
                   "predictions matching them (IoU >= 0.5): a class-agnostic protocol, not "
                   "MOT17's (there only distractor classes are free). Classes are in column 8 "
                   "(MOTChallenge, VisDrone), or --class-column (9 in UAVDT's *_gt_whole.txt).")
@click.option("--ignore-classes", "ignore_classes", default=None, metavar="LIST",
              help="Ground-truth rows of these classes are ignore regions, as --ignore (e.g. 0: "
                   "VisDrone's 'ignored regions').")
@click.option("--class-column", "class_column", type=int, default=8, show_default=True,
              help="1-based column of the ground truth's class (9 in UAVDT's *_gt_whole.txt).")
@click.option("--errors", "errors_path", type=PathArg(dir_okay=False, path_type=Path),
              default=None, metavar="FILE",
              help="Also write every error to this CSV, a row each: sequence, frame (numbered as "
                   "--pred's), kind (miss: a true box no track matched; false: a predicted box "
                   "matching no true box; switch: a match whose track is not the one that matched "
                   "the target before, previous_id), gt_id, track_id, previous_id, x, y, w, h (the "
                   "true box; the predicted one for false), iou (of a switch's match), near_id and "
                   "near_iou (a miss's best-overlapping predicted track, a false box's "
                   "best-overlapping target: a loose box, not a lost vehicle and a ghost). -1 or "
                   "empty when none. A line per target with -vv.")
@click.option("--json", "as_json", is_flag=True,
              help="Print one JSON object (HOTA, DetA, AssA, LocA, MOTA, MOTP, IDF1, IDSW, Frag, "
                   "GT_IDs, Pred_IDs, GT_Dets, Pred_Dets, then TP, FP, FN, MT, PT, ML, IDP, IDR, "
                   "HOTA(0); combined over sequences, with a 'sequences' entry when there are "
                   "several; an undefined score is null).")
def eval_command(gts, preds, ignores, iou_threshold, frames, zero_based, gt_zero_based, fix_gt,
                 drop_flagged, geo_crs, as_json, classes=None, ignore_classes=None,
                 class_column=8, errors_path=None):
    """Score tracks against a ground truth: HOTA, MOTA, IDF1 and counts (TrackEval).

    Boxes are class-agnostic; every ground-truth row counts whatever its confidence (rows
    flagged 0 in a MOTChallenge 'consider' column too, unless --drop-flagged). The ground truth may hold
    boxes with negative sizes and exact duplicate rows (published ground truths do): they are
    accepted with a warning (duplicates dropped, negative boxes kept, matching nothing) unless
    --fix-gt corrects them. Predictions with them are refused. A MOTChallenge sequence is scored
    over its seqinfo.ini seqLength (predictions after the last annotated frame count); other
    ground truths from frame 1 to their last frame.

    \b
    Examples:
      aerotrack eval --gt gt.txt --pred run/tracks.csv
      aerotrack eval --gt gt.txt --pred run/tracks.csv --json --iou 0.3
      aerotrack eval --gt uavdt/ --pred runs/ --ignore auto        # every *_gt.txt in uavdt/
      aerotrack eval --gt dfs_ground_truth.csv --pred yolo_bytetrack_detections_filtered.csv \\
          --zero-based --frames 2:98 --fix-gt                      # Santiago, corrected GT
      aerotrack eval --gt dfs_ground_truth.csv --pred run/tracks.csv --gt-zero-based \\
          --frames 2:98 --fix-gt                                   # Santiago, aerotrack's tracks
      aerotrack eval --gt visdrone/annotations/ --pred runs/ --classes 4,5,6,9 \\
          --ignore-classes 0                                       # vehicles of VisDrone-MOT
    """
    _parse_frames(frames)  # a malformed range: refused before any file is read
    classes = _parse_classes(classes, "--classes")
    ignore_classes = _parse_classes(ignore_classes, "--ignore-classes")
    if classes and ignore_classes and set(classes) & set(ignore_classes):
        raise InputError(f"--classes and --ignore-classes both hold "
                         f"{','.join(str(c) for c in sorted(set(classes) & set(ignore_classes)))}")
    if class_column != 8 and not (classes or ignore_classes):
        raise InputError(f"--class-column {class_column}: only with --classes or "
                         "--ignore-classes")
    # (the --ignore-classes rows are moved to the ignore regions as each ground truth is read)
    by_class = {"classes": classes, "class_column": class_column}
    seqs = {}
    lengths = {}
    gt_zero = zero_based or gt_zero_based  # ignore regions are numbered as the ground truth
    pairs = _pair(gts, preds, ignores)
    if errors_path is not None:
        from ..io.output import check_apart, check_writable

        if str(errors_path) == "-":
            raise InputError("--errors -: give a file name (the scores go to standard output)")
        # every file read, as resolved (`--ignore auto` finds ignore files beside the ground
        # truth: one of them was replaced by the errors), and the folders given
        check_apart(errors_path, "--errors",
                    [(opt, Path(q)) for opt, given in (("--gt", gts), ("--pred", preds),
                                                       ("--ignore", ignores))
                     for q in given if q != "auto"]
                    + [(opt, q) for _, g, p, ign in pairs
                       for opt, q in (("--gt", g), ("--pred", p), ("--ignore", ign))])
        check_writable(errors_path, "--errors")
    for name, g, p, ign in pairs:
        lengths[name] = _seq_length(g)
        # one sequence of several may hold no object (TrackEval scores it: every prediction a
        # false positive); one empty ground truth alone is a mistake
        gt = read_mot(g, option="--gt", strict=False, allow_empty=len(pairs) > 1,
                      zero_based=gt_zero)
        if not len(gt):
            log.warning("--gt %s: no rows: the sequence has no object to find, and every "
                        "prediction there counts as a false positive", g)
        pred = read_mot(p, option="--pred", strict=True, zero_based=zero_based, tracks=True)
        if not len(pred):
            log.warning("--pred %s: no rows: every ground-truth box counts as missed", p)
        if geo_crs is not None:
            pred = _pred_in_crs(pred, p, geo_crs)
        ignore = (read_mot(ign, option="--ignore", strict=False, zero_based=gt_zero)
                  if ign is not None else None)
        if ignore_classes:  # before the duplicate check: regions have no identity (VisDrone's 0)
            from ..evaluation.mot import split_ignore_classes

            gt, ignore = split_ignore_classes(gt, ignore, ignore_classes, class_column)
        if fix_gt:
            gt, fix = fix_ground_truth(gt, f"--gt {g}")
            log.info("--fix-gt %s: %s", g, fix.describe(-1 if gt_zero else 0))
        else:
            drop_exact_duplicates(gt, f"--gt {g}")  # refuses a (frame, id) with two boxes
        seqs[name] = (gt, pred, ignore)
        if has_consider_flag(gt) and not drop_flagged:
            flagged = gt[:, 6] == 0
            if classes:  # (VisDrone's flagged rows are its ignored regions, gone by now)
                from ..evaluation.mot import class_rows

                flagged &= class_rows(gt, classes, class_column)
            if flagged.any():
                log.warning("--gt %s: %d rows are flagged 0 in the 7th column (MOTChallenge's "
                            "'consider' flag?) and are scored like every row; --drop-flagged "
                            "leaves them out, as MOTChallenge's protocol does", g,
                            int(flagged.sum()))
    window = _parse_frames(frames, max(int(g[:, 0].max(initial=0)) for g, _, _ in seqs.values()))
    if window is None:
        _coverage_hint(seqs)
    _frame_shift_hint(seqs)
    per_seq = ({n: window for n in seqs} if window else
               {n: (1, max(n_len, int(seqs[n][0][:, 0].max(initial=0))))
                for n, n_len in lengths.items()
                if n_len is not None})
    if window is not None and not any(((g[:, 0] >= window[0]) & (g[:, 0] <= window[1])).any()
                                      for g, _, _ in seqs.values()):
        last = max(int(g[:, 0].max(initial=0)) for g, _, _ in seqs.values())
        raise InputError(f"--frames {frames}: no ground-truth rows in these frames (the ground "
                         f"truth ends at frame {last})")
    if classes:
        from ..evaluation.mot import class_rows

        if not any(class_rows(g, classes, class_column).any() for g, _, _ in seqs.values()):
            found = sorted({int(round(c)) for g, _, _ in seqs.values()
                            for c in g[:, class_column - 1]})
            raise InputError(f"--classes {','.join(str(c) for c in classes)}: no ground-truth row "
                             f"of these classes in column {class_column} (it holds "
                             f"{', '.join(str(c) for c in found[:12])})")
    res = evaluate_sequences(seqs, iou_threshold=iou_threshold, frames=per_seq or None,
                             drop_flagged=drop_flagged, **by_class)
    single = len(seqs) == 1
    geo = None
    if geo_crs is not None:
        from ..evaluation.geo import geo_errors

        # the rows the scores were computed on (window, ignore regions, duplicates); frames are
        # per sequence: offset them so sequences never mix
        off = 0
        parts_g, parts_p = [], []
        for name, (g, p, ign) in seqs.items():
            g, p, _, _ = scored_rows(g, p, ignore=ign, frames=per_seq.get(name), name=name,
                                     quiet=True, drop_flagged=drop_flagged, **by_class)
            g, p = g.copy(), p.copy()
            g[:, 0] += off
            p[:, 0] += off
            off += int(max(g[:, 0].max(initial=0), p[:, 0].max(initial=0))) + 1
            parts_g.append(g)
            parts_p.append(p)
        gt_all, pred_all = np.vstack(parts_g), np.vstack(parts_p)
        from pyproj import CRS

        try:
            projected = CRS.from_user_input(geo_crs).is_projected
            geographic = CRS.from_user_input(geo_crs).is_geographic
        except Exception:  # noqa: BLE001 - geo_errors names a bad CRS itself
            projected = geographic = False
        if geographic:  # metres read as degrees gave a NaN error (and --json a traceback)
            for option, rows in (("--gt", gt_all), ("--pred", pred_all)):
                v = rows[~np.all(rows[:, 7:9] == -1, axis=1), 7:9]
                if len(v) and (np.abs(v[:, 0]).max() > 360 or np.abs(v[:, 1]).max() > 90):
                    raise InputError(f"--geo-crs {geo_crs} is lon/lat, but {option}'s x, y "
                                     "are not degrees (up to "
                                     f"{np.abs(v[:, 0]).max():.0f}, {np.abs(v[:, 1]).max():.0f}):"
                                     " give the CRS they are in (a run folder's tracks.csv is "
                                     "converted from its map's)")
        xy = np.vstack([gt_all[:, 7:9], pred_all[:, 7:9]])
        xy = xy[~np.all(xy == -1, axis=1)]
        degrees = bool(projected and len(xy) and np.all(np.abs(xy[:, 0]) <= 180)
                       and np.all(np.abs(xy[:, 1]) <= 90))
        if degrees:
            log.warning("--geo-crs %s is a projected CRS (metres), but every x, y is within "
                        "+-180, +-90: lon/lat degrees? (EPSG:4326)", geo_crs)
        geo = geo_errors(gt_all, pred_all, geo_crs, iou_threshold=iou_threshold)
        if degrees:  # the numbers stay (a small local grid is possible), flagged as such
            geo["suspect"] = "x, y look like lon/lat degrees, read as metres of --geo-crs"
        if geo.get("matches") and geo.get("median_m", 0) > 10_000:
            # boxes that match in the frame but lie kilometres apart on the ground: the two files'
            # x, y are in different CRSs (a prediction on a UTM map against lon/lat ground truth
            # gave a median of 4 055 070 m, silently)
            log.warning("--geo-crs %s: matched boxes lie a median %.0f km apart: are --gt's and "
                        "--pred's x, y in the same CRS? (the ground truth's must be in %s too)",
                        geo_crs, geo["median_m"] / 1000, geo_crs)
    if errors_path is not None:  # after every check (--geo-crs refused metres as degrees)
        _write_errors(errors_path, seqs, per_seq, iou_threshold, by_class, drop_flagged,
                      frame_offset=-1 if zero_based else 0)
    if as_json:
        keys = (*METRIC_KEYS, *EXTRA_KEYS)
        out = {k: _json_number(res["combined"][k]) for k in keys}
        if geo is not None:
            out["geo_error"] = {k: _json_number(v) if isinstance(v, float) else v
                                for k, v in geo.items()}
        if not single:
            out["sequences"] = {n: {k: _json_number(r[k]) for k in keys}
                                for n, r in res["sequences"].items()}
        click.echo(json.dumps(out, allow_nan=False))
        return
    rows = list(res["sequences"].items())
    if not single:
        rows.append(("COMBINED", res["combined"]))
    click.echo(_table(rows))
    c = res["combined"]
    click.echo(f"TP {c['TP']}  FP {c['FP']}  FN {c['FN']}  MT {c['MT']}  PT {c['PT']}  ML {c['ML']}"
               f"  IDP {c['IDP']:.3f}  IDR {c['IDR']:.3f}  (IoU {iou_threshold:g}"
               + (f", {c['ignored_pred']} predictions in ignore regions dropped"
                  if ignores or ignore_classes else "")
               + (", corrected ground truth" if fix_gt else "") + ")")
    if geo is not None:
        click.echo(f"geo error over {geo['matches']} matched boxes: median {geo['median_m']:.2f} m, "
                   f"mean {geo['mean_m']:.2f} m, 90% {geo['p90_m']:.2f} m"
                   + (f" ({geo['suspect']}: see the warning)" if "suspect" in geo else ""))
    if any(np.isnan(float(c[k])) for k in ("HOTA", "MOTA", "IDF1")):
        log.warning("some scores are undefined (empty ground truth or predictions)")

"""MOTChallenge text files: ``frame,id,bb_left,bb_top,bb_width,bb_height,conf,x,y,z``.

Frames are 1-based in every file aerotrack reads or writes. Rows may have 6 to 10 columns on input
(missing conf defaults to 1, missing x, y, z to -1); output always has 10.
"""

from __future__ import annotations

import logging
import re
import weakref
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from .output import atomic_write

_log = logging.getLogger("aerotrack")

#: Frame numbers and coordinates beyond these are not from a video: 10^7 frames is 46 hours at
#: 60 frames/s (timestamps in milliseconds would pass for frame numbers and make the run step
#: through billions of empty frames); 10^8 is beyond any image, and beyond the metres of any
#: projected CRS (boxes in UTM metres are accepted).
MAX_FRAME = 10_000_000
MAX_COORD = 1e8

_HEADER_FIELD = re.compile(r"^[A-Za-z_]\S*$")  # a word: "conf%", "bb_left(px)" too
_HEADER_CELL = re.compile(r"^[A-Za-z_][^,]*$")  # a comma-separated header's cell: "w [px]" too
MOT_COLUMNS = ("frame", "id", "bb_left", "bb_top", "bb_width", "bb_height", "conf", "x", "y", "z")


def parse_mot_text(text: str, name: str = "<text>", *, min_columns: int = 6,
                   zero_based: bool = False) -> np.ndarray:
    """Parse MOT rows into an (N, 10) float64 array.

    Blank lines and lines starting with ``#`` are skipped; fields are comma-, tab- or
    space-separated. A first row whose every field is a word (a header such as
    ``frame,id,x,y,w,h,conf``, as exported by pandas and most detector scripts) is skipped too.
    With ``zero_based`` the file numbers frames from 0 and 1 is added to every frame.

    Raises
    ------
    FormatError
        A row has fewer than ``min_columns`` or more than 10 fields, a non-numeric or non-finite
        cell, or a frame number that is not a positive (zero_based: non-negative) integer. The
        message names the line.
    """
    return _parse(text, name, min_columns=min_columns, zero_based=zero_based)[0]


def _check_header_order(names: list[str], name: str, lineno: int) -> None:
    """A header row is skipped, not used: one that names the frame and id columns elsewhere than
    first and second (``id,frame,...``, as trajectory files often are) is refused rather than read
    in MOT order (ids taken for frames, the message then about a missing row)."""
    low = [n.strip().lower().split(" ")[0] for n in names]
    frame = next((k for k, n in enumerate(low) if n in ("frame", "frame_id", "frameid")),
                 None)
    ident = next((k for k, n in enumerate(low) if n in ("id", "track_id", "trackid", "track",
                                                          "object_id", "ped_id")), None)
    if frame is None or ident is None or (frame, ident) == (0, 1):
        return
    raise FormatError(f"{name} line {lineno}: its header puts {names[frame]!r} in column "
                      f"{frame + 1} and {names[ident]!r} in column {ident + 1}; the rows must be "
                      "in MOTChallenge's order frame,id,x,y,w,h,conf,x,y,z (reorder the columns)")


def _parse(text: str, name: str, *, min_columns: int = 6, zero_based: bool = False
           ) -> tuple[np.ndarray, np.ndarray]:
    """(rows, 1-based line number of each row) of :func:`parse_mot_text`."""
    rows: list[list[float]] = []
    linenos: list[int] = []
    first = True
    lowest = 0 if zero_based else 1
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if "," in s:
            cells = [p.strip() for p in s.split(",")]
            if first and all(_HEADER_CELL.match(c) for c in cells if c):  # "w [px]" too
                _check_header_order(cells, name, lineno)
                first = False
                continue
            if len(cells) > 7 and cells[-1] == "" and "" not in cells[:-1]:
                cells.pop()  # one trailing comma after a whole row (conf given)
            if "" in cells:  # an empty cell (pandas writes NaN so): splitting on runs of
                # separators shifted every later column and the row was read with wrong boxes;
                # an empty last cell is a missing conf, not a trailing comma (read as 1.0)
                k = cells.index("")
                raise FormatError(f"{name} line {lineno}: empty field (column {k + 1}"
                                  + (f", {MOT_COLUMNS[k]}" if k < len(MOT_COLUMNS) else "") + ")")
            parts = [q for p in cells for q in p.split()]
        else:
            parts = s.split()
        if first and all(_HEADER_FIELD.match(p) for p in parts):
            _check_header_order(parts, name, lineno)
            first = False
            continue
        first = False
        if not (min_columns <= len(parts) <= 10):
            hint = ("; separated by ';'? use commas, tabs or spaces"
                    if len(parts) < min_columns and ";" in s else "")
            raise FormatError(
                f"{name} line {lineno}: expected {min_columns} to 10 columns, found {len(parts)}"
                + hint)
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not _is_float(p))
            hint = "; UTF-16 text without its byte order mark? save it as UTF-8" \
                if "\x00" in bad else ""
            raise FormatError(f"{name} line {lineno}: non-numeric value {bad!r}{hint}") from None
        if not all(np.isfinite(vals)):
            raise FormatError(f"{name} line {lineno}: NaN or infinite value")
        if vals[0] < lowest or not float(vals[0]).is_integer():
            kind = "a non-negative integer (0-based)" if zero_based else \
                "a positive integer (1-based)"
            hint = ("; a 0-based file? (track: --detections-zero-based; eval: --zero-based / "
                    "--gt-zero-based; report: --gt-zero-based; predict: --zero-based)"
                    if not zero_based and vals[0] == 0 else "")
            raise FormatError(f"{name} line {lineno}: frame must be {kind}, got {parts[0]}{hint}")
        if zero_based:
            vals[0] += 1.0
        vals += [1.0, -1.0, -1.0, -1.0][len(vals) - 6:] if len(vals) < 10 else []
        rows.append(vals[:10])
        linenos.append(lineno)
    if not rows:
        return np.zeros((0, 10)), np.zeros(0, int)
    return np.asarray(rows, dtype=np.float64), np.asarray(linenos)


def _decode(raw: bytes, label: str) -> str:
    """A MOT file's text: UTF-8 (with or without a BOM), UTF-16 with its BOM (Windows "Unicode"
    text), else Latin-1 when no NUL byte says it is binary: numbers are ASCII in any of these, so a
    Latin-1 comment or header line is read (it gave a raw codec message) and a data row with other
    bytes is refused as non-numeric, naming its line."""
    import codecs

    try:
        if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
            return raw.decode("utf-16")
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        if b"\x00" in raw[:4096]:
            raise InputError(f"{label}: cannot read as text (a binary file, or an unknown "
                             "encoding): expected MOTChallenge text rows") from None
        return raw.decode("latin-1")


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def repeated_frame_id(rows: np.ndarray) -> np.ndarray:
    """Indices of the rows whose (frame, id) an earlier row already has (any ids, any size)."""
    if not len(rows):
        return np.zeros(0, int)
    _, first = np.unique(np.asarray(rows, np.float64)[:, :2], axis=0, return_index=True)
    seen = np.zeros(len(rows), bool)
    seen[first] = True
    return np.flatnonzero(~seen)


def read_mot(path: str | Path, *, option: str | None = None, strict: bool = True,
             allow_empty: bool = True, zero_based: bool = False, tracks: bool = False,
             detections: bool = False, lines: bool = False):
    """Read a MOTChallenge file into an (N, 10) array sorted by (frame, id), 1-based frames.

    Parameters
    ----------
    path : path
        The file.
    option : str, optional
        Command-line option the file came from, for messages (``--pred``).
    strict : bool
        Refuse boxes with a negative width or height and repeated (frame, id) rows
        (``--pred``, ``--detections``; rows with id -1, detections, may share a frame).
        Ground truth is read with ``strict=False``.
    allow_empty : bool
        Whether a file with no rows is acceptable.
    zero_based : bool
        The file numbers frames from 0 (Santiago's published files): 1 is added.
    tracks : bool
        The rows are tracks (``eval --pred``, ``predict``): every id must be >= 0. A file of
        detections (id -1) would otherwise be scored as one track with many boxes a frame.
    detections : bool
        The rows are detections (``--detections``): the id column is ignored (set to -1; a
        detector's class id there repeated (frame, id) pairs, which were refused).
    lines : bool
        Also return the file's line number of each (sorted) row, for messages.

    Raises
    ------
    InputError, FormatError
    """
    p = Path(path)
    label = f"{option} {p}" if option else str(p)
    if not p.exists():
        raise InputError(f"{label}: file not found")
    if p.is_dir():
        raise InputError(f"{label}: is a folder, expected a MOTChallenge text file")
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{label}: cannot read ({exc.strerror or exc})") from None
    text = _decode(raw, label)
    data, linenos = _parse(text, label, zero_based=zero_based)
    if detections and len(data):
        data[:, 1] = -1.0
        zero = (data[:, 4] == 0) | (data[:, 5] == 0)
        if zero.any():  # a degenerate box of a detector: nothing to track, not a broken file
            _log.warning("%s: %d box(es) of zero width or height dropped (first: line %d)", label,
                         int(zero.sum()), int(linenos[np.flatnonzero(zero)[0]]))
            data, linenos = data[~zero], linenos[~zero]
    if not len(data) and not allow_empty:
        raise InputError(f"{label}: no rows")
    shown = "0-based " if zero_based else ""
    if tracks and len(data) and np.any(data[:, 1] < 0):
        k = int(np.flatnonzero(data[:, 1] < 0)[0])
        raise FormatError(f"{label} line {linenos[k]}: track id {data[k, 1]:g}; tracks need ids "
                          ">= 0 (a file of detections, id -1, is not a tracks file)")
    if strict and len(data):
        neg = np.flatnonzero((data[:, 4] < 0) | (data[:, 5] < 0))
        if len(neg):
            raise FormatError(f"{label} line {linenos[neg[0]]}: negative box width or height")
        with_id = np.flatnonzero(data[:, 1] >= 0)
        rep = with_id[repeated_frame_id(data[with_id])]
        if len(rep):
            k = int(rep[0])
            frame = int(data[k, 0]) - (1 if zero_based else 0)
            raise FormatError(f"{label} line {linenos[k]}: repeated (frame, id) = ({frame}, "
                              f"{int(data[k, 1])}){' (' + shown.strip() + ' frame)' if shown else ''}")
    order = np.lexsort((data[:, 1], data[:, 0])) if len(data) else np.zeros(0, int)
    return (data[order], linenos[order]) if lines else data[order]


def format_mot_rows(rows: Iterable[Iterable[float]]) -> str:
    """Format 10-column rows: integer frame and id, 3 decimals for boxes, 7 for x, y, z
    (x, y may be degrees)."""
    out = []
    for r in rows:
        r = list(r)
        out.append(
            f"{int(r[0])},{int(r[1])},{r[2]:.3f},{r[3]:.3f},{r[4]:.3f},{r[5]:.3f},"
            f"{r[6]:.4f},{_num(r[7])},{_num(r[8])},{_num(r[9])}"
        )
    return "\n".join(out) + ("\n" if out else "")


def _num(v: float) -> str:
    return "-1" if v == -1 else f"{v:.7f}"


def write_mot(path: str | Path, rows: np.ndarray | Iterable[Iterable[float]]) -> None:
    """Write rows atomically as a 10-column MOTChallenge file (no header)."""
    arr = np.asarray(list(rows) if not isinstance(rows, np.ndarray) else rows, dtype=np.float64)
    if arr.size and arr.shape[1] < 10:
        pad = np.full((len(arr), 10 - arr.shape[1]), -1.0)
        arr = np.hstack([arr, pad])
    with atomic_write(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(format_mot_rows(arr))


#: Arrays :func:`check_detections` has checked (by id, with a weak reference to tell a reused
#: id): the command line checks a file's rows, then ``pipeline.run`` would check them again and
#: every warning came twice.
_CHECKED: dict[int, weakref.ref] = {}

#: A jump in a detections file's frame numbers past which ``check_detections`` warns.
FRAME_JUMP_WARN = 100_000


def check_detections(dets: np.ndarray, label: str, source=None, *, lines=None,
                     min_conf: float | None = None) -> None:
    """Refuse detection rows no video can have; warn about what is likely a mistake (the
    command line's ``--detections`` and the Python API's ``detections`` alike).

    ``dets`` is the (N, >= 7) array of :func:`read_mot` (1-based frames, frame pixels), ``label``
    what messages call it (``--detections FILE``), ``source`` the frames they go with (its
    ``count`` and ``size``, when known), ``lines`` the file's line number of each row (messages name them; without it, the
    row's place). Warned: an empty file, rows after the video's end, boxes mostly outside the
    frame (made on another image size), confidences outside [0, 1] (clipped), the boxes below
    ``min_conf`` (dropped by the pipeline, ``detection.min_conf``), many low-confidence boxes,
    tiny normalised boxes, and frame numbers that step by more than 1.
    """
    seen = _CHECKED.get(id(dets))
    if seen is not None and seen() is dets:  # (the command line checked them; the API again)
        return
    _CHECKED[id(dets)] = weakref.ref(dets)
    if not len(dets):
        _log.warning("%s: no detections in the file: nothing to track", label)
        return

    def line(k: int) -> str:
        return f"line {int(lines[k])}" if lines is not None else f"row {k + 1}"

    bad = (dets[:, 4] <= 0) | (dets[:, 5] <= 0)
    if bad.any():
        raise InputError(f"{label}: {line(int(bad.argmax()))} has a zero-size box")
    bad = dets[:, 0] > MAX_FRAME
    if bad.any():
        r = int(bad.argmax())
        raise InputError(f"{label}: {line(r)} has frame {dets[r, 0]:.0f}, beyond any video "
                         f"(more than {MAX_FRAME}); frames must be 1-based frame numbers, not times")
    bad = (np.abs(dets[:, 2:4]) > MAX_COORD).any(axis=1) | (dets[:, 4:6] > MAX_COORD).any(axis=1)
    if bad.any():
        r = int(bad.argmax())
        raise InputError(f"{label}: {line(r)} has a box beyond any image (a coordinate or size "
                         f"over {MAX_COORD:.0e})")
    n = len(dets)
    count = getattr(source, "count", None) if source is not None else None
    if count:
        late = dets[:, 0] > count
        if late.any():
            _log.warning("%s: %d row(s) after the input's last frame %d are ignored "
                        "(first: %s, frame %d)", label, int(late.sum()), count,
                        line(int(late.argmax())), int(dets[late.argmax(), 0]))
    size = getattr(source, "size", None) if source is not None else None
    if size:
        w, h = size
        cx, cy = dets[:, 2] + dets[:, 4] / 2, dets[:, 3] + dets[:, 5] / 2
        out = (cx < 0) | (cx > w) | (cy < 0) | (cy > h)
        if out.mean() > 0.05:
            _log.warning("%s: %d of %d boxes (%.0f%%) have their centre outside the %dx%d frame "
                        "(first: %s): made on another image size, or another video?", label,
                        int(out.sum()), n, 100 * out.mean(), w, h, line(int(out.argmax())))
    conf = dets[:, 6]
    outside = (conf < 0) | (conf > 1)
    if outside.any():
        below = int((conf < 0).sum())
        drop = (f"; the {below} below 0 become 0 and are dropped by detection.min_conf "
                f"{min_conf:g} (raw detector scores, as MOT17's DPM ones? rescale them to [0, 1] "
                "first, or --min-conf 0 keeps every box)") if below and min_conf else ""
        _log.warning("%s: %d confidence(s) outside [0, 1] (from %g to %g; first: %s) are clipped "
                     "to it%s", label, int(outside.sum()), float(conf.min()), float(conf.max()),
                     line(int(outside.argmax())), drop)
    conf = np.clip(conf, 0.0, 1.0)
    if min_conf is not None and min_conf > 0:
        low = conf < min_conf
        if low.all():
            _log.warning("%s: every box's confidence is below detection.min_conf %g (--min-conf): "
                        "nothing is tracked", label, min_conf)
        elif low.any():
            _log.info("%s: %d of %d boxes have a confidence below detection.min_conf %g "
                     "(--min-conf) and are dropped", label, int(low.sum()), n, min_conf)
        conf = conf[~low]
    if len(conf) and np.mean(conf < 0.25) > 0.2:
        _log.warning("%s: %.0f%% of the boxes kept have a confidence below 0.25; each is tracked "
                    "like any other (false alarms become tracks): --min-conf drops them",
                    label, 100 * np.mean(conf < 0.25))
    if np.median(np.maximum(dets[:, 4], dets[:, 5])) < 1.0:
        _log.warning("%s: the boxes are under a pixel (median longer side %.3g): coordinates "
                    "normalised to [0, 1]? aerotrack needs frame pixels", label,
                    float(np.median(np.maximum(dets[:, 4], dets[:, 5]))))
    frames = np.unique(dets[:, 0].astype(np.int64))
    if len(frames) >= 2 and not count:
        # a typo'd frame number far after the others: association walks every empty frame up
        # to it (a 5000000 in a 900-frame file ran for minutes, writing a checkpoint a second)
        gaps = np.diff(frames)
        k = int(np.argmax(gaps))
        if gaps[k] > max(FRAME_JUMP_WARN, 10 * len(frames)):
            r = int(np.flatnonzero(dets[:, 0] == frames[k + 1])[0])
            _log.warning("%s: frame %d (%s) comes %d frames after the one before it (%d), in a "
                         "file of %d frames with detections: a typo? Every frame between is "
                         "processed (empty)", label, int(frames[k + 1]), line(r), int(gaps[k]),
                         int(frames[k]), len(frames))
    if len(frames) >= 10:
        step = int(np.gcd.reduce(np.diff(frames)))
        if step > 1:
            _log.warning("%s: every frame number is %d apart from the next: detections on one "
                        "frame in %d only, or times instead of frame numbers? (frames are 1-based "
                        "frame numbers; frames between are bridged or missed)", label, step, step)

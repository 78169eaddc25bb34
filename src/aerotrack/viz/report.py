"""The offline HTML report of a run: one self-contained file, no network needed.

Everything is inline: CSS, a little JavaScript (table sorting, the frame scrubber, a self-check), the
pictures as PNG data URIs and the overlay video as a WebM (VP9) data URI. Nothing is fetched, so the
file can be mailed, archived or opened on an air-gapped machine, and it renders the same in ten
years.

Sections: summary numbers, per-stage timings, registration quality over time, the map and space-time
pictures, the overlay (video player and a JPEG frame scrubber), the track table, the evaluation
(when ground truth is given, or stored in ``summary.json`` under ``"eval"``; with ground truth also
where the errors are: :mod:`aerotrack.viz.errors`), the failures and the resolved configuration.

The page checks itself when it loads: it writes ``data-selfcheck`` on ``<html>`` with the number of
pictures that decoded, whether the video decoded, and the number of track rows shown (headless
browser tests read it).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import AerotrackError
from ..io.output import atomic_write_bytes, atomic_write_text
from .colours import id_hex
from .mapplot import figure_png, plot_map, plot_registration, plot_space_time
from .overlay import OverlayPainter, OverlayStyle, render_overlay
from .results import RunResults
from .trackstats import TrackStats, track_stats

log = logging.getLogger(__name__)

#: width (pixels) of the report's frames with their errors drawn, at most
ERROR_FRAME_WIDTH = 1280

METRIC_ORDER = ("HOTA", "DetA", "AssA", "LocA", "MOTA", "MOTP", "IDF1", "IDSW", "Frag", "GT_IDs",
                "Pred_IDs", "GT_Dets", "Pred_Dets")


@dataclass(frozen=True)
class ReportOptions:
    """What the report embeds.

    Attributes
    ----------
    video_width : int
        Width of the embedded overlay video (pixels). Wider is sharper but makes the file bigger.
    max_video_mb : float
        An overlay video larger than this is linked (relative path) rather than embedded
        (base64 makes it a third larger: a 3600-frame run's 19.5 MB video made a 31.8 MB page, and
        at 80 MB, the limit before, a page of about 107 MB is slow to open).
    scrubber_frames : int
        Frames in the JPEG scrubber (evenly spaced over the run; 0 disables it).
    scrubber_width : int
        Width of the scrubber's frames (pixels).
    trail_s : float
        Trail length of the overlay, seconds.
    render_video : bool
        Render ``DIR/overlay.webm`` from the input when it does not exist yet.
    """

    video_width: int = 960
    max_video_mb: float = 25.0
    scrubber_frames: int = 40
    scrubber_width: int = 800
    trail_s: float = 2.0
    render_video: bool = True


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _fmt(v: Any, digits: int = 3) -> str:
    if isinstance(v, bool) or v is None:
        return "–" if v is None else str(v)
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            return "–"
        return f"{v:,.{digits}f}"
    return html.escape(str(v))


@dataclass
class Evaluation:
    """The report's evaluation: the scores, where they come from, and (when the ground truth is
    at hand) CLEAR's box-by-box matching."""

    metrics: dict | None = None
    note: str = ""
    matching: Any = None  # aerotrack.evaluation.errors.Matching


def _evaluation(results: RunResults, gt_path: str | Path | None, *, zero_based: bool = False,
                fix_gt: bool = False, frames: tuple[int, int] | None = None) -> Evaluation:
    """Metrics of ``tracks.csv`` against ``gt_path`` (or stored ones) and the matching.
    ``zero_based``: the ground truth numbers frames from 0; ``fix_gt``: corrected first
    (:func:`aerotrack.evaluation.fix_ground_truth`), as ``eval`` does; ``frames``: the scoring
    window (1-based, inclusive), else the run's frames to the ground truth's last."""
    if gt_path is None:
        ev = results.summary.get("eval")
        return Evaluation(ev, "from summary.json") if isinstance(ev, dict) else Evaluation()
    try:
        from ..evaluation import evaluate
        from ..evaluation.errors import clear_matching
        from ..evaluation.mot import scored_rows
    except ImportError as exc:
        return Evaluation(None, f"evaluation unavailable ({exc})")
    from ..io.mot import read_mot

    gt = read_mot(gt_path, option="--gt", strict=False, allow_empty=False, zero_based=zero_based)
    if fix_gt:
        from ..evaluation import fix_ground_truth

        gt, _ = fix_ground_truth(gt, f"--gt {gt_path}")
    # the run's frames up to the ground truth's last, as `aerotrack eval` scores by default
    # (frames the annotators never reached are not false positives: Santiago's 99-100 were)
    gt_last = int(gt[:, 0].max())
    if frames is not None:
        first, last = frames
        which = "as asked"
    else:
        first = results.first_frame
        last = max(first, min(results.last_frame or gt_last, gt_last))
        which = "the run's, to the ground truth's last, as eval"
    metrics = evaluate(gt, results.tracks, frames=(first, last))
    g, p, _, _ = scored_rows(gt, results.tracks, frames=(first, last), quiet=True)
    return Evaluation(metrics, f"tracks.csv against {Path(gt_path).name}"
                      + (" (corrected)" if fix_gt else "") + f", frames {first}-{last} ({which})",
                      clear_matching(g, p))


def _error_frames(input_path: Path, results: RunResults, matching) -> list[tuple[int, str]]:
    """The worst frames (:func:`aerotrack.viz.errors.worst_frames`) with their errors drawn, as
    JPEG data URIs."""
    from ..io.frames import open_source
    from .errors import draw_errors, worst_frames

    wanted = worst_frames(matching, results.fps)
    if not wanted:
        return []
    source = open_source(input_path, results.fps)
    out = []
    for f in wanted:  # each sought on its own: two picked an hour apart decoded the hour
        for frame in source.frames(start=f, stop=f):
            img = draw_errors(frame.image, matching, frame.index, width=ERROR_FRAME_WIDTH)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
            if ok:
                out.append((frame.index, _data_uri(buf.tobytes(), "image/jpeg")))
    return out


def _scrubber_frames(input_path: Path, results: RunResults, opts: ReportOptions) -> list[tuple[int, str]]:
    from ..io.frames import open_source

    source = open_source(input_path, results.fps)
    first = results.first_frame  # the frames the run tracked (--frames A:B: A..B)
    last = results.last_frame or len(source)
    n = len(source) or last
    n = min(n, last) if last else n
    if n < first or opts.scrubber_frames <= 0:
        return []
    count = min(opts.scrubber_frames, n - first + 1)
    wanted = sorted(set(np.linspace(first, n, count).round().astype(int).tolist()))
    painter = OverlayPainter(results, OverlayStyle(trail_s=opts.trail_s))
    out = []
    wanted_set = set(wanted)
    for frame in source.frames(start=wanted[0], stop=wanted[-1]):
        if frame.index not in wanted_set:
            continue
        img = painter.draw(frame.image, frame.index)
        h, w = img.shape[:2]
        if w > opts.scrubber_width:
            img = cv2.resize(img, (opts.scrubber_width, int(round(h * opts.scrubber_width / w))),
                             interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
        if ok:
            out.append((frame.index, _data_uri(buf.tobytes(), "image/jpeg")))
    return out


def build_report(run_dir: str | Path, *, input_path: str | Path | None = None,
                 gt_path: str | Path | None = None, geomap=None, out_path: str | Path | None = None,
                 options: ReportOptions = ReportOptions(), progress=None,
                 gt_zero_based: bool = False, fix_gt: bool = False,
                 checked: bool = False, gt_frames: tuple[int, int] | None = None) -> Path:
    """Write ``DIR/report.html`` (or ``out_path``) for the run in ``run_dir``.

    Parameters
    ----------
    run_dir : path
        An output folder (the file contract).
    input_path : path, optional
        The run's input video or image folder, for the overlay video and scrubber (default: the
        ``"input"`` of ``summary.json`` when it exists). Without it the report has no player,
        unless ``DIR/overlay.webm`` exists.
    gt_path : path, optional
        Ground truth (MOTChallenge, 1-based frames): adds the evaluation section.
    geomap : GeoMap, optional
        The run's map (default: the ``"map"`` of ``summary.json`` when it exists).
    out_path : path, optional
    options : ReportOptions
    progress : callable, optional
        Called with the frames written while the overlay video is rendered.
    gt_zero_based, fix_gt : bool
        The ground truth numbers frames from 0 / is corrected first (as ``eval``'s options).
    gt_frames : (int, int), optional
        Scoring window (1-based, inclusive; ``eval --frames``), else the run's frames up to the
        ground truth's last.
    checked : bool
        ``input_path`` was already checked against the run (``aerotrack report --input``): its
        warnings are not given twice.

    Returns
    -------
    Path of the written report.
    """
    results = RunResults.load(run_dir)
    run_dir = results.path
    if geomap is None and results.map_path is not None:
        from ..geo import GeoMap

        try:
            geomap = GeoMap(results.map_path)
        except AerotrackError as exc:
            log.warning("map %s not used: %s", results.map_path, exc)
    given = input_path is not None  # (the command line checked a given --input already)
    input_path = Path(input_path) if input_path is not None else results.input_path
    if input_path is None and isinstance(results.summary.get("input"), str):
        from ..io.frames import is_stream_url

        named = results.summary["input"]
        log.info("report: no video player: the run's input %s %s; give --input (a recording "
                 "of it) for one", named, "was a live stream, which cannot be read again"
                 if is_stream_url(named) else "is not at hand")

    if input_path is not None and not (given and checked):  # before any work
        from ..io.frames import open_source

        results.check_input(open_source(input_path, results.fps), input_path,
                            "--input" if given else "the run's input")

    def first_image():
        return None if geomap is not None else results.reference_image(input_path)

    # pictures already written beside the results (by `aerotrack render`) are reused when newer
    # than tracks.csv
    t_tracks = (run_dir / "tracks.csv").stat().st_mtime

    def picture(name, make):
        p = run_dir / f"{name}.png"
        if p.is_file() and p.stat().st_mtime >= t_tracks:
            return p.read_bytes()
        fig = make()
        if fig is None:
            return None
        png = figure_png(fig)
        fresh.append((p, png))  # written with report.html: an interrupted report leaves neither
        return png

    fresh: list[tuple[Path, bytes]] = []

    pictures: dict[str, str] = {}
    for name, make in (("map", lambda: plot_map(results, geomap, background=first_image())),
                       ("spacetime", lambda: plot_space_time(results, geomap)),
                       ("registration", lambda: plot_registration(results))):
        png = picture(name, make)
        if png is not None:
            pictures[name] = _data_uri(png, "image/png")

    video_html = ""
    video_path = _report_video(run_dir, input_path, results, options, t_tracks, progress)
    if video_path is not None and video_path.exists() and options.max_video_mb > 0:
        size_mb = video_path.stat().st_size / 1e6
        src = (_data_uri(video_path.read_bytes(), "video/webm") if size_mb <= options.max_video_mb
               else html.escape(video_path.name))
        video_html = (f'<video id="player" controls loop muted playsinline preload="auto" '
                      f'src="{src}"></video>')
    scrub = _scrubber_frames(input_path, results, options) if input_path is not None else []
    stats = track_stats(results, geomap)
    evaluation = _evaluation(results, gt_path, zero_based=gt_zero_based, fix_gt=fix_gt,
                             frames=gt_frames)
    errors_html = _errors_section(evaluation.matching, results, input_path, options)
    if video_path is not None and video_path.parent != run_dir:
        video_path.unlink(missing_ok=True)  # rendered for this report only
    page = _page(results, stats, pictures, video_html, scrub, evaluation.metrics, evaluation.note,
                 geomap, input_path, counts=_counts_section(run_dir, t_tracks),
                 errors=errors_html)
    out = Path(out_path) if out_path is not None else run_dir / "report.html"
    atomic_write_text(out, page)
    out.chmod(0o644)
    for p, png in fresh:
        try:  # keep the pictures beside the results too (map.png, spacetime.png, ...)
            atomic_write_bytes(p, png)
            p.chmod(0o644)
        except OSError as exc:
            log.warning("%s not written: %s", p, exc)
    return out


def _video_width(path: Path) -> int:
    from ..io.frames import cv_path

    cap = cv2.VideoCapture(cv_path(path))
    try:
        return int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) if cap.isOpened() else 0
    finally:
        cap.release()


def _covers_run(path: Path, results: RunResults) -> bool:
    """Whether a video holds (about) as many frames as the run tracked: one `aerotrack render
    --start/--stop` made over a part of it is not the run's overlay. A count the container does
    not give (<= 0) is trusted."""
    from ..io.frames import cv_path

    cap = cv2.VideoCapture(cv_path(path))
    try:
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
    finally:
        cap.release()
    want = results.last_frame - results.first_frame + 1 if results.last_frame else 0
    return n <= 0 or want <= 0 or n >= 0.95 * want


def _report_video(run_dir: Path, input_path, results: RunResults, options: ReportOptions,
                  t_tracks: float, progress) -> Path | None:
    """The overlay video the report embeds: ``DIR/overlay.webm`` when it is newer than
    ``tracks.csv``, no wider than ``options.video_width`` and covers the run's frames; else, with the input, one rendered
    at that width over the run's frames: into ``DIR/overlay.webm`` when there is none (kept
    beside the results), into a temporary file otherwise (a user's own overlay is not
    replaced) or when the run folder cannot be written. None: no video."""
    video_path = run_dir / "overlay.webm"
    whole = video_path.is_file() and _covers_run(video_path, results)
    if video_path.is_file() and video_path.stat().st_mtime >= t_tracks \
            and 0 < _video_width(video_path) <= options.video_width and whole:
        return video_path
    if input_path is None or not options.render_video:
        if video_path.is_file() and not whole:
            log.warning("%s covers only part of the run's frames %d-%d (rendered with --start/"
                        "--stop?); embedded as it is: give the input to render the whole run",
                        video_path, results.first_frame, results.last_frame)
        return video_path if video_path.is_file() else None
    target = video_path
    if video_path.exists() or not os.access(run_dir, os.W_OK):
        import tempfile

        fd, tmp = tempfile.mkstemp(prefix="aerotrack-report-", suffix=".webm")
        os.close(fd)
        target = Path(tmp)
    log.info("rendering %s (frames %d-%d, %d px wide at most)", target, results.first_frame,
             results.last_frame, options.video_width)
    render_overlay(input_path, results, target,
                   style=OverlayStyle(trail_s=options.trail_s, max_width=options.video_width),
                   start=results.first_frame, stop=results.last_frame or None, progress=progress)
    return target


def write_visuals(run_dir: str | Path, *, input_path: str | Path | None = None,
                  gt_path: str | Path | None = None, geomap=None,
                  options: ReportOptions = ReportOptions()) -> dict[str, Path]:
    """Everything users look at, in one call: ``overlay.webm`` (when the input is known),
    ``map.png``, ``spacetime.png``, ``registration.png`` and ``report.html`` in the run folder.

    Returns a dict name -> path of what was written (keys ``overlay``, ``map``, ``spacetime``,
    ``registration``, ``report``).
    """
    from .mapplot import write_pictures

    results = RunResults.load(run_dir)
    if geomap is None and results.map_path is not None:
        from ..geo import GeoMap

        geomap = GeoMap(results.map_path)
    input_path = Path(input_path) if input_path is not None else results.input_path
    background = results.reference_image(input_path) if geomap is None else None
    written = {p.stem: p for p in write_pictures(results, geomap, background=background)}
    report = build_report(results.path, input_path=input_path, gt_path=gt_path, geomap=geomap,
                          options=options)
    if (results.path / "overlay.webm").exists():
        written["overlay"] = results.path / "overlay.webm"
    written["report"] = report
    return written


# -- HTML ------------------------------------------------------------------------------------------
# Self-contained by construction: the page may load nothing but its own inline data.
CSP = ("default-src 'none'; img-src data:; media-src data: 'self'; style-src 'unsafe-inline'; "
       "script-src 'unsafe-inline'")

CSS = """
:root{--fg:#1d2430;--mut:#5b6574;--bg:#f6f7f9;--card:#fff;--acc:#1f5fa8}
*{box-sizing:border-box}body{margin:0;font:15px/1.45 system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;
color:var(--fg);background:var(--bg)}header{background:#16202e;color:#fff;padding:18px 28px}
header h1{margin:0;font-size:24px}header p{margin:4px 0 0;color:#b9c3d0;font-size:14px}
main{max-width:1280px;margin:0 auto;padding:10px 24px 40px}section{background:var(--card);border-radius:8px;
padding:16px 20px;margin:16px 0;box-shadow:0 1px 3px rgba(0,0,0,.08)}h2{margin:0 0 10px;font-size:19px}
.cards{display:flex;flex-wrap:wrap;gap:10px}.card{flex:1 1 140px;background:var(--bg);border-radius:6px;padding:10px 12px}
.card b{display:block;font-size:22px}.card span{color:var(--mut);font-size:13px}
img.fig{max-width:100%;height:auto;display:block;margin:6px auto}.two{display:grid;grid-template-columns:1fr 1fr;gap:12px}
@media(max-width:900px){.two{grid-template-columns:1fr}}
table{border-collapse:collapse;width:100%;font-size:14px}th,td{padding:4px 8px;text-align:right;border-bottom:1px solid #e4e7ec}
th{cursor:pointer;background:#eef1f5;position:sticky;top:0}th:first-child,td:first-child{text-align:left}
.sw{display:inline-block;width:12px;height:12px;border-radius:3px;margin-right:6px;vertical-align:-1px;border:1px solid #0003}
.bar{height:14px;background:var(--acc);border-radius:3px}.tw{max-height:520px;overflow:auto}
video,#scrubimg{max-width:100%;display:block;margin:0 auto;background:#000}
.scrub{display:flex;gap:10px;align-items:center;margin-top:8px}.scrub input{flex:1}
button{font:inherit;padding:3px 12px}pre{background:var(--bg);padding:10px;overflow:auto;font-size:13px}
.note{color:var(--mut);font-size:13px}
"""

JS = r"""
(function(){
function sortTable(th){var t=th.closest('table'),i=[].indexOf.call(th.parentNode.children,th),
 b=t.tBodies[0],rows=[].slice.call(b.rows),asc=th.dataset.asc!=='1';th.dataset.asc=asc?'1':'0';
 rows.sort(function(a,c){var x=a.cells[i].dataset.v,y=c.cells[i].dataset.v,nx=parseFloat(x),ny=parseFloat(y);
 var r=(!isNaN(nx)&&!isNaN(ny))?nx-ny:String(x).localeCompare(String(y));return asc?r:-r});
 rows.forEach(function(r){b.appendChild(r)})}
document.querySelectorAll('th[data-sort]').forEach(function(th){th.addEventListener('click',function(){sortTable(th)})});
var data=document.getElementById('scrubdata');
if(data){var frames=JSON.parse(data.textContent),img=document.getElementById('scrubimg'),
 rng=document.getElementById('scrubrange'),lab=document.getElementById('scrublabel'),
 btn=document.getElementById('scrubplay'),timer=null;
 function show(i){img.src=frames[i][1];lab.textContent='frame '+frames[i][0];rng.value=i}
 rng.max=frames.length-1;rng.addEventListener('input',function(){show(+rng.value)});
 btn.addEventListener('click',function(){if(timer){clearInterval(timer);timer=null;btn.textContent='play'}
 else{timer=setInterval(function(){show((+rng.value+1)%frames.length)},250);btn.textContent='pause'}});
 show(0)}
function check(){var imgs=[].slice.call(document.images),ok=imgs.filter(function(i){return i.complete&&i.naturalWidth>0}).length;
 var v=document.getElementById('player'),res={images:imgs.length,images_ok:ok,
 track_rows:document.querySelectorAll('#tracks tbody tr').length,video:'none'};
 function done(){document.documentElement.dataset.selfcheck=JSON.stringify(res)}
 if(!v){done();return}
 if(v.readyState>=2){res.video='ok';res.video_width=v.videoWidth;done();return}
 var t=setTimeout(function(){res.video='timeout';done()},8000);
 v.addEventListener('loadeddata',function(){clearTimeout(t);res.video='ok';res.video_width=v.videoWidth;done()});
 v.addEventListener('error',function(){clearTimeout(t);res.video='error';done()});}
if(document.readyState==='complete')check();else window.addEventListener('load',check);
})();
"""


def _cards(results: RunResults, stats: list[TrackStats]) -> str:
    s = results.summary
    counts = s.get("counts", {}) if isinstance(s.get("counts"), dict) else {}
    n_frames = results.n_frames  # a --frames A:B run: B - A + 1, not B
    speeds = [t.mean_speed_kmh for t in stats if math.isfinite(t.mean_speed_kmh) and t.frames_in_view > 1]
    fails = s.get("registration_failures")
    n_fail = len(fails) if isinstance(fails, list) else fails if isinstance(fails, int) else None
    items = [
        (n_frames, "frames"), (f"{results.fps:g}", "frames / s"),
        (f"{(results.last_frame - results.first_frame + 1) / results.fps:.1f} s"
         if n_frames else "–", "duration"),
        (len(stats), "tracks"), (len(results.tracks), "rows in view"),
        (len(results.predicted), "predicted rows"),
        (sum(t.reacquisitions for t in stats), "re-acquisitions"),
        (counts.get("detections", len(results.detections) if results.detections is not None else None),
         "detections"),
        (n_fail, "registration failures"),
        (f"{np.median(speeds):.1f} km/h" if speeds else "–", "median track speed"),
    ]
    if isinstance(s.get("frames_per_second"), (int, float)):
        items.append((f"{s['frames_per_second']:g}", "processing frames / s"))
    return "".join(f'<div class="card"><b>{v if isinstance(v, str) else _fmt(v)}</b><span>{html.escape(k)}</span></div>'
                   for v, k in items if v is not None and v != "–")


def _timings(results: RunResults) -> str:
    t = results.timings
    if not t:
        return '<p class="note">summary.json holds no timings.</p>'
    top = max(t.values()) or 1.0
    total = sum(t.values())
    rows = "".join(
        f'<tr><td>{html.escape(k)}</td><td data-v="{v}">{v:.2f} s</td><td>{100 * v / total if total else 0:.0f} %</td>'
        f'<td style="width:50%"><div class="bar" style="width:{100 * v / top:.1f}%"></div></td></tr>'
        for k, v in sorted(t.items(), key=lambda kv: -kv[1]))
    return (f'<table><thead><tr><th>stage</th><th>time</th><th>share</th><th></th></tr></thead>'
            f'<tbody>{rows}</tbody><tfoot><tr><td>total</td><td>{total:.2f} s</td><td></td><td></td></tr></tfoot></table>')


def _track_table(stats: list[TrackStats]) -> str:
    unit = stats[0].unit if stats else "m"
    head = ["ID", "first frame", "last frame", "frames in view", "duration (s)", f"distance ({unit})",
            "mean speed (km/h)", "unobserved (s)", "predicted (s)", "re-acquisitions"]
    ths = "".join(f'<th data-sort="1">{html.escape(h)}</th>' for h in head)
    rows = []
    for t in stats:
        cells = [
            (t.id, f'<span class="sw" style="background:{id_hex(t.id)}"></span>{t.id}'),
            (t.first_frame, _fmt(t.first_frame)), (t.last_frame, _fmt(t.last_frame)),
            (t.frames_in_view, _fmt(t.frames_in_view)), (t.duration_s, _fmt(t.duration_s, 2)),
            (t.distance, _fmt(t.distance, 1)), (t.mean_speed_kmh, _fmt(t.mean_speed_kmh, 1)),
            (t.unobserved_s, _fmt(t.unobserved_s, 2)), (t.predicted_s, _fmt(t.predicted_s, 2)),
            (t.reacquisitions, _fmt(t.reacquisitions)),
        ]
        rows.append("<tr>" + "".join(
            f'<td data-v="{v if isinstance(v, (int, np.integer)) or (isinstance(v, float) and math.isfinite(v)) else -1}">{c}</td>'
            for v, c in cells) + "</tr>")
    return f'<div class="tw"><table id="tracks"><thead><tr>{ths}</tr></thead><tbody>{"".join(rows)}</tbody></table></div>'


def _metrics_table(metrics: dict) -> str:
    keys = [k for k in METRIC_ORDER if k in metrics] + [k for k in metrics if k not in METRIC_ORDER
                                                         and isinstance(metrics[k], (int, float))]
    cells = "".join(f'<div class="card"><b>{_fmt(metrics[k])}</b><span>{html.escape(k)}</span></div>'
                    for k in keys)
    return f'<div class="cards">{cells}</div>'


def _errors_section(matching, results: RunResults, input_path, options: ReportOptions) -> str:
    """The evaluation's error analysis: the timeline and per-target picture, the worst frames
    with their errors drawn (when the input is at hand), the per-target table and the tracks
    holding false positives; "" without a matching."""
    if matching is None or not len(matching):
        return ""
    from ..evaluation.errors import false_tracks, target_summaries
    from .errors import plot_errors

    e = html.escape
    parts = []
    fig = plot_errors(matching, results.fps, first_frame=results.first_frame)
    if fig is not None:
        parts.append(f'<h3>Errors over time</h3><img class="fig" alt="errors over time" '
                     f'src="{_data_uri(figure_png(fig), "image/png")}">')
    if input_path is not None:
        try:
            shots = _error_frames(Path(input_path), results, matching)
        except AerotrackError as exc:
            log.warning("report: error frames not drawn: %s", exc)
            shots = []
        if shots:
            parts.append('<h3>Frames with the most errors</h3><p class="note">Thin green: true '
                         'boxes found; yellow: missed; magenta: an ID switch (old -&gt; new track); '
                         'red: false positives (predicted boxes matching no true box).</p>'
                         + "".join(f'<figure><img class="fig" alt="frame {f}" src="{uri}">'
                                   f'<figcaption>frame {f}</figcaption></figure>'
                                   for f, uri in shots))
    rows = []
    for t in target_summaries(matching):
        tracks = " ".join(f'<span class="sw" style="background:{id_hex(i)}"></span>{i}'
                          f"&nbsp;({n})" for i, n in t.tracks) or "none"
        cells = [(t.gt_id, _fmt(t.gt_id)), (t.first_frame, _fmt(t.first_frame)),
                 (t.last_frame, _fmt(t.last_frame)), (t.frames, _fmt(t.frames)),
                 (t.found_fraction, t.found_percent),
                 (len(t.tracks), tracks), (t.switches, _fmt(t.switches)),
                 (t.longest_miss, _fmt(t.longest_miss))]
        rows.append("<tr>" + "".join(f'<td data-v="{v}">{c}</td>' for v, c in cells) + "</tr>")
    head = ["true ID", "first frame", "last frame", "frames", "found", "tracks (frames)",
            "ID switches", "longest miss (frames)"]
    ths = "".join(f'<th data-sort="1">{e(h)}</th>' for h in head)
    parts.append('<h3>True targets</h3><p class="note">CLEAR-MOT\'s matching at IoU 0.5 over '
                 'the frames named above (<code>aerotrack eval --errors</code> writes the same '
                 'rows, with its <code>--frames</code>); frames numbered from 1. Click a heading '
                 'to sort.</p>'
                 f'<div class="tw"><table id="targets"><thead><tr>{ths}</tr></thead>'
                 f'<tbody>{"".join(rows)}</tbody></table></div>')
    false = false_tracks(matching)
    if false:
        frows = "".join(f'<tr><td data-v="{i}"><span class="sw" style="background:{id_hex(i)}">'
                        f'</span>{i}</td><td data-v="{n}">{n}</td><td data-v="{k}">{k}</td>'
                        f'<td data-v="{k / n}">{100 * k / n:.0f} %</td></tr>'
                        for i, n, k in false)
        parts.append('<h3>Tracks with false positives</h3><p class="note">A track false in all '
                     'its frames is often a vehicle the ground truth leaves out (parked, or a '
                     'mover not annotated): look at it before calling it a ghost.</p>'
                     '<details><summary>' + f"{len(false)} tracks" + '</summary>'
                     '<div class="tw"><table id="false_tracks"><thead><tr><th data-sort="1">track'
                     '</th><th data-sort="1">boxes</th><th data-sort="1">false</th>'
                     f'<th data-sort="1">share</th></tr></thead><tbody>{frows}</tbody></table>'
                     '</div></details>')
    return "".join(parts)


def _counts_section(run_dir: Path, t_tracks: float) -> str:
    """The counts ``aerotrack count`` wrote into the run folder (newer than ``tracks.csv``): the
    lines' picture, totals per line and direction, and the turning movements; "" without them."""
    import csv

    files = [run_dir / n for n in ("counts.csv", "movements.csv")]
    if not all(f.is_file() and f.stat().st_mtime >= t_tracks for f in files):
        return ""
    try:
        with open(files[0], newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
        with open(files[1], newline="", encoding="utf-8") as fh:
            moves = list(csv.DictReader(fh))
        totals: dict[str, dict[str, int]] = {}
        for r in rows:
            totals.setdefault(r["line"], {"+": 0, "-": 0})[r["direction"]] += int(r["count"])
    except (OSError, KeyError, ValueError) as exc:
        log.warning("counts in %s not shown: %s", run_dir, exc)
        return ""
    od: dict[tuple[str, str], int] = {}
    for m in moves:
        if m.get("to_line"):
            od[(m["from_line"], m["to_line"])] = od.get((m["from_line"], m["to_line"]), 0) + 1
    e = html.escape
    table = ("<table><thead><tr><th>line</th><th>+</th><th>&minus;</th><th>total</th></tr></thead>"
             + "".join(f"<tr><td>{e(n)}</td><td>{t['+']}</td><td>{t['-']}</td>"
                       f"<td>{t['+'] + t['-']}</td></tr>" for n, t in totals.items())
             + "</table>")
    if od:
        table += ("<h3>Turning movements</h3><table><thead><tr><th>first line crossed</th>"
                  "<th>last line crossed</th><th>tracks</th></tr></thead>"
                  + "".join(f"<tr><td>{e(a)}</td><td>{e(b)}</td><td>{n}</td></tr>"
                            for (a, b), n in sorted(od.items())) + "</table>")
    png = run_dir / "count_lines.png"
    img = (f'<img class="fig" alt="count lines" src="{_data_uri(png.read_bytes(), "image/png")}">'
           if png.is_file() and png.stat().st_mtime >= t_tracks else "")
    return ('<section id="counts"><h2>Counts</h2><p class="note">From <code>aerotrack count</code> '
            "(counts.csv, crossings.csv, movements.csv): '+' crosses a line from its left to its "
            "right walking from its first point to its second, as seen on the screen.</p>"
            f"{table}{img}</section>")


def _page(results, stats, pictures, video_html, scrub, metrics, eval_note, geomap, input_path,
          counts: str = "", errors: str = "") -> str:
    full = results.path.resolve()
    name = html.escape("/".join(full.parts[-2:]) if len(full.parts) > 2 else full.name)
    when = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    what = []
    named = results.summary.get("input")
    if input_path is not None or isinstance(named, str):
        what.append(f"input {html.escape(str(input_path if input_path is not None else named))}")
    cut = results.summary.get("interrupted_at_frame")
    if isinstance(cut, int):
        what.append(f"interrupted: frames {results.first_frame}-{cut} only")
    if geomap is not None:
        what.append(f"map {html.escape(str(geomap.path))} ({html.escape(str(geomap.crs))}, "
                    f"{geomap.metres_per_pixel:.2f} m/px)")
    else:
        what.append(f"no map: positions in frame {results.first_frame}'s pixels")
    parts = [f'<section><h2>Summary</h2><div class="cards">{_cards(results, stats)}</div></section>']
    hints = results.summary.get("hints")
    if isinstance(hints, list) and hints:
        items = "".join(f"<li>{html.escape(str(h))}</li>" for h in hints)
        parts.append(f'<section id="hints"><h2>Warnings</h2><ul>{items}</ul></section>')
    if metrics:
        parts.append(f'<section id="evaluation"><h2>Evaluation</h2><p class="note">{html.escape(eval_note)}'
                     f'</p>{_metrics_table(metrics)}{errors}</section>')
    if video_html or scrub:
        player = f"<h3>Video</h3>{video_html}" if video_html else ""
        if scrub:
            data = json.dumps([[f, uri] for f, uri in scrub])
            player += ('<h3>Frame scrubber</h3><img id="scrubimg" alt="overlay frame">'
                       '<div class="scrub"><button id="scrubplay">play</button>'
                       '<input type="range" id="scrubrange" min="0" value="0" step="1">'
                       f'<span id="scrublabel"></span></div>'
                       f'<script type="application/json" id="scrubdata">{data}</script>')
        parts.append('<section><h2>Overlay</h2><p class="note">Solid boxes: targets in view. Dashed boxes '
                     'and circles: predicted positions of targets out of view, with their uncertainty '
                     '(label: seconds since last seen); arrows point to predicted targets outside the '
                     f'image. Lines: the last seconds of each track.</p>{player}</section>')
    where = "the map" if geomap is not None else f"frame {results.first_frame}"
    parts.append(f'<section><h2>Tracks on {where}</h2><img class="fig" alt="tracks on {where}" '
                 f'src="{pictures["map"]}"></section>')
    parts.append('<section><h2>Space-time view</h2><p class="note">Each track in (x, y, time), coloured by ID '
                 '(Yu &amp; Medioni 2007, fig. 6); dashed: predicted while out of view; stars: re-acquisitions.'
                 f'</p><img class="fig" alt="space-time view" src="{pictures["spacetime"]}"></section>')
    if counts:
        parts.append(counts)
    parts.append(f'<section><h2>Tracks</h2><p class="note">Click a heading to sort. Distance and speed '
                 f'use the in-view positions, smoothed over 0.5 s.</p>{_track_table(stats)}</section>')
    if "registration" in pictures:
        parts.append('<section><h2>Registration quality</h2><img class="fig" alt="registration quality" '
                     f'src="{pictures["registration"]}"></section>')
    parts.append(f'<section><h2>Per-stage timings</h2>{_timings(results)}</section>')
    fails = results.summary.get("registration_failures")
    if isinstance(fails, list) and fails:
        rows = "".join(f"<tr><td>{_fmt(f.get('frame'))}</td><td>{_fmt(f.get('status'))}</td>"
                       f"<td style='text-align:left'>{_fmt(f.get('reason'))}</td></tr>"
                       for f in fails[:500] if isinstance(f, dict))
        parts.append(f'<section><h2>Registration failures</h2><details><summary>{len(fails)} frames'
                     f'</summary><table><thead><tr><th>frame</th><th>status</th><th>reason</th></tr></thead>'
                     f'<tbody>{rows}</tbody></table></details></section>')
    cfg = results.path / "config.toml"
    if cfg.is_file():
        parts.append('<section><h2>Configuration</h2><details><summary>config.toml</summary>'
                     f'<pre>{html.escape(cfg.read_text(encoding="utf-8", errors="replace"))}</pre></details></section>')
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f'<meta http-equiv="Content-Security-Policy" content="{CSP}">'
        f'<title>aerotrack report: {name}</title><style>{CSS}</style></head><body>'
        f'<header><h1>aerotrack report: {name}</h1><p>{" · ".join(what)} · generated {when}</p></header>'
        f'<main>{"".join(parts)}</main><script>{JS}</script></body></html>\n'
    )

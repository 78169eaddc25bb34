"""Pictures of a run: tracks on the map, the space-time plot, registration quality over time.

Figures are built on :class:`matplotlib.figure.Figure` with the Agg canvas directly (no pyplot, no
global backend switch), so they work headless and in threads.

* :func:`plot_map`: tracks on the map raster (lon/lat axes and a scale bar), coloured by ID; in-view
  parts solid, predicted (out-of-view) parts dashed, re-acquisitions starred. Without a map, the
  tracks are drawn in the pixels of the run's first frame (frame 1, or A of ``--frames A:B``;
  through ``registration.csv``) over that frame when available.
* :func:`plot_space_time`: tracklets in (x, y, time), coloured by ID, as in Yu & Medioni's figure 6.
* :func:`plot_registration`: inliers, inlier ratio and reprojection error of ``registration.csv``
  over time, with the frames whose homography was carried forward or reset marked.

Every text is at least 1.5 % of the figure height.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from .colours import id_rgb
from .results import RunResults, TrackView
from .trackstats import metric_positions

DPI = 110
MIN_TEXT_FRAC = 0.015


def _figure(width_in: float, height_in: float, layout: str | None = None):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _font_pt(fig, frac: float = 0.017) -> float:
    """Font size (points) giving text ``frac`` of the figure height (never below 1.5 %)."""
    frac = max(frac, MIN_TEXT_FRAC)
    return fig.get_figheight() * 72.0 * frac / 0.72  # cap height ~0.72 em


def save_figure(fig, path: str | Path) -> Path:
    """Write a figure as PNG (atomically)."""
    from ..io.output import atomic_write_bytes

    atomic_write_bytes(path, figure_png(fig))
    return Path(path)


def figure_png(fig) -> bytes:
    """The figure's PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight", pad_inches=0.1)
    return buf.getvalue()


def _nice(x: float) -> float:
    if x <= 0 or not math.isfinite(x):
        return 1.0
    e = 10 ** math.floor(math.log10(x))
    for m in (5, 2, 1):
        if m * e <= x:
            return m * e
    return e


def _scale_bar(ax, units_per_metre: float, xlim, ylim, fs: float) -> None:
    """A scale bar in the lower left: ``units_per_metre`` world units per metre."""
    width_m = abs(xlim[1] - xlim[0]) / units_per_metre
    length_m = _nice(width_m / 5)
    L = length_m * units_per_metre
    x0 = min(xlim) + 0.04 * abs(xlim[1] - xlim[0])
    ybot, ytop = max(ylim), min(ylim)  # image axes: y grows downwards
    y0 = ybot - 0.05 * abs(ybot - ytop)
    import matplotlib.patheffects as pe

    ax.plot([x0, x0 + L], [y0, y0], color="black", lw=5, solid_capstyle="butt", zorder=20,
            path_effects=[pe.withStroke(linewidth=8, foreground="white")])
    label = f"{length_m:g} m" if length_m < 1000 else f"{length_m / 1000:g} km"
    ax.annotate(label, (x0 + L / 2, y0), xytext=(0, 6), textcoords="offset points", ha="center",
                va="bottom", fontsize=fs, zorder=22,
                path_effects=[pe.withStroke(linewidth=3, foreground="white")])


def _segments(tv: TrackView):
    """Yield (index array, observed flag) runs; predicted runs include their neighbouring observed
    points so the dashed part joins the solid parts."""
    n = len(tv.frames)
    i = 0
    while i < n:
        j = i
        while j + 1 < n and tv.observed[j + 1] == tv.observed[i] and tv.frames[j + 1] == tv.frames[j] + 1:
            j += 1
        if tv.observed[i]:
            yield np.arange(i, j + 1), True
        else:
            lo, hi = max(0, i - 1), min(n - 1, j + 1)
            yield np.arange(lo, hi + 1), False
        # a gap in frames between two observed runs with no predicted rows: join dashed
        if j + 1 < n and tv.observed[i] and tv.observed[j + 1] and tv.frames[j + 1] > tv.frames[j] + 1:
            yield np.array([j, j + 1]), False
        i = j + 1


def _draw_tracks(ax, tracks: list[TrackView], xy_of, fs: float, label: bool = True) -> None:
    import matplotlib.patheffects as pe

    halo = [pe.withStroke(linewidth=3.2, foreground="black")]
    for tv in tracks:
        xy = xy_of(tv)
        if not np.isfinite(xy).any():
            continue
        c = id_rgb(tv.id)
        for idx, obs in _segments(tv):
            p = xy[idx]
            p = p[np.all(np.isfinite(p), axis=1)]
            if len(p) < 2:
                continue
            if obs:
                ax.plot(p[:, 0], p[:, 1], color=c, lw=1.9, solid_capstyle="round", zorder=5,
                        path_effects=halo)
            else:
                ax.plot(p[:, 0], p[:, 1], color=c, lw=1.6, ls=(0, (3, 2)), zorder=4)
        obs_idx = np.flatnonzero(tv.observed & np.all(np.isfinite(xy), axis=1))
        if len(obs_idx):
            s = xy[obs_idx[0]]
            ax.plot(*s, "o", ms=4.5, mfc=c, mec="black", mew=0.8, zorder=6)
        for r in tv.reacquisitions():
            if np.all(np.isfinite(xy[r])):
                ax.plot(*xy[r], "*", ms=13, mfc=c, mec="black", mew=1.0, zorder=7)
    if label:
        _draw_labels(ax, tracks, xy_of, fs)


def _draw_labels(ax, tracks: list[TrackView], xy_of, fs: float) -> None:
    """ID labels at each track's last in-view point; longer tracks first, and a label that would
    overlap one already placed is left out (the colour still tells the track)."""
    import matplotlib.patheffects as pe

    ax.apply_aspect()
    px = fs * DPI / 72.0
    placed: list[tuple[float, float, float, float]] = []
    order = sorted(tracks, key=lambda tv: -int(tv.observed.sum()))
    xlim, ylim = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    for tv in order:
        xy = xy_of(tv)
        obs_idx = np.flatnonzero(tv.observed & np.all(np.isfinite(xy), axis=1))
        if not len(obs_idx):
            continue
        e = xy[obs_idx[-1]]
        if not (xlim[0] <= e[0] <= xlim[1] and ylim[0] <= e[1] <= ylim[1]):
            continue
        d = ax.transData.transform(e)
        text = f" {tv.id}"
        rect = (d[0], d[1] - 0.5 * px, d[0] + 0.62 * px * len(text), d[1] + 0.5 * px)
        if any(rect[0] < q[2] and q[0] < rect[2] and rect[1] < q[3] and q[1] < rect[3] for q in placed):
            continue
        placed.append(rect)
        ax.text(e[0], e[1], text, color=id_rgb(tv.id), fontsize=fs, fontweight="bold", zorder=8,
                va="center", path_effects=[pe.withStroke(linewidth=2.5, foreground="black")])


def _ground_px(geomap, at) -> tuple[float, float]:
    """Metres per map pixel along x and along y near ``at`` (map pixels), geodesic."""
    from pyproj import Geod

    c = np.asarray(at, dtype=np.float64)
    ll = geomap.pixel_to_lonlat(np.array([c, c + [10.0, 0.0], c + [0.0, 10.0]]))
    g = Geod(ellps="WGS84")
    mx = g.inv(ll[0, 0], ll[0, 1], ll[1, 0], ll[1, 1])[2] / 10.0
    my = g.inv(ll[0, 0], ll[0, 1], ll[2, 0], ll[2, 1])[2] / 10.0
    if not (mx > 0 and my > 0):
        return geomap.metres_per_pixel, geomap.metres_per_pixel
    return mx, my


def _legend(ax, fs: float) -> None:
    from matplotlib.lines import Line2D

    grey = (0.25, 0.25, 0.25)
    handles = [
        Line2D([], [], color=grey, lw=2, label="in view"),
        Line2D([], [], color=grey, lw=1.6, ls=(0, (3, 2)), label="predicted / out of view"),
        Line2D([], [], color=grey, marker="o", ls="", mec="black", label="start"),
        Line2D([], [], color=grey, marker="*", ms=12, ls="", mec="black", label="re-acquired"),
    ]
    ax.legend(handles=handles, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=4, fontsize=fs * 0.9,
              frameon=False, borderaxespad=0.2, handlelength=2.2)


def _extent(points: np.ndarray, bounds: tuple[float, float, float, float] | None, margin: float = 0.08):
    ok = points[np.all(np.isfinite(points), axis=1)]
    if not len(ok):
        return bounds
    x0, y0 = ok.min(axis=0)
    x1, y1 = ok.max(axis=0)
    span = max(x1 - x0, y1 - y0, 50.0)
    m = margin * span
    x0, x1, y0, y1 = x0 - m, x1 + m, y0 - m, y1 + m
    if bounds is not None:  # keep most of the view on the raster
        bx0, by0, bx1, by1 = bounds
        x0, y0 = max(x0, bx0 - 0.1 * (bx1 - bx0)), max(y0, by0 - 0.1 * (by1 - by0))
        x1, y1 = min(x1, bx1 + 0.1 * (bx1 - bx0)), min(y1, by1 + 0.1 * (by1 - by0))
    return x0, y0, x1, y1


def plot_map(results: RunResults, geomap=None, *, background: np.ndarray | None = None,
             metres_per_unit: float | None = None, title: str | None = None):
    """Tracks drawn on the map (or on the run's first frame without a map).

    Parameters
    ----------
    results : RunResults
    geomap : GeoMap, optional
        The run's map; positions are map pixels from the rows' map CRS ``x, y``.
    background : ndarray (H, W, 3) uint8 BGR, optional
        Without a map: the run's first frame (:meth:`RunResults.reference_image`), drawn under
        the tracks (that frame's pixels).
    metres_per_unit : float, optional
        Without a map: metres per pixel of that frame, for a scale bar.

    Returns
    -------
    matplotlib.figure.Figure
    """
    tracks = results.track_views(geomap)
    metres_per_unit = metres_per_unit or results.metres_per_unit
    fig = _figure(10.0, 8.0)
    fs = _font_pt(fig)
    ax = fig.add_axes((0.09, 0.08, 0.88, 0.86))
    # the view fits the in-view positions; predictions running far off are clipped by the axes
    allpts = (np.vstack([tv.world[tv.observed] for tv in tracks]) if tracks else np.zeros((0, 2)))
    # ``track --ground``: the world is a ground plane in metres, y north (not frame 1's pixels)
    ground = geomap is None and bool(results.summary.get("ground"))
    if geomap is not None:
        img = geomap.read_image()[..., ::-1]
        ax.imshow(img, extent=(0, geomap.width, geomap.height, 0), interpolation="bilinear", zorder=0)
        bounds = (0.0, 0.0, float(geomap.width), float(geomap.height))
    else:
        bounds = None
        if background is not None and not ground:
            bg = background[..., ::-1]
            ax.imshow(bg, extent=(0, bg.shape[1], bg.shape[0], 0), zorder=0)
            bounds = (0.0, 0.0, float(bg.shape[1]), float(bg.shape[0]))
        else:
            ax.set_facecolor((0.93, 0.93, 0.93))
        unit_per_m = 1.0 / metres_per_unit if metres_per_unit else None
    # clamped to the map's raster only: without a map a moving camera's tracks run far beyond
    # frame 1, and clamping to it left them out of the picture (a probe: 6 of truck4's 22)
    ext = _extent(allpts, bounds if geomap is not None else None) or (0, 0, 100, 100)
    ax.set_xlim(ext[0], ext[2])
    if ground:
        ax.set_ylim(ext[1], ext[3])
        if background is not None:
            _ground_background(ax, results, background, ext)
    else:
        ax.set_ylim(ext[3], ext[1])
    if geomap is not None:  # equal ground distances, even for lon/lat pixels that are not square
        mx, my = _ground_px(geomap, ((ext[0] + ext[2]) / 2, (ext[1] + ext[3]) / 2))
        ax.set_aspect(my / mx)
        unit_per_m = 1.0 / mx
    else:
        ax.set_aspect("equal")
    _draw_tracks(ax, tracks, lambda tv: tv.world, fs)
    _legend(ax, fs)
    ax.tick_params(labelsize=fs * 0.85)
    if geomap is not None:
        _lonlat_axes(ax, geomap, fs)
    elif ground:
        ax.set_xlabel("ground x (m)", fontsize=fs)
        ax.set_ylabel("ground y (m)", fontsize=fs)
    else:
        ax.set_xlabel(f"frame {results.first_frame} x (px)", fontsize=fs)
        ax.set_ylabel(f"frame {results.first_frame} y (px)", fontsize=fs)
    if unit_per_m:
        _scale_bar(ax, unit_per_m, ax.get_xlim(), ax.get_ylim(), fs)
    n_re = sum(len(tv.reacquisitions()) for tv in tracks)
    default = (f"{len(tracks)} track{'s' * (len(tracks) != 1)}, "
               f"{n_re} re-acquisition{'s' * (n_re != 1)}")
    outside = sum(1 for tv in tracks
                  if tv.observed.any() and not _any_inside(tv.world[tv.observed], ext))
    if outside:
        default += f" ({outside} outside the map's view)"
    ax.set_title(title or default, fontsize=fs * 1.1, pad=fs * 2.6)
    return fig


def _any_inside(points: np.ndarray, ext) -> bool:
    x0, y0, x1, y1 = ext
    return bool(np.any((points[:, 0] >= x0) & (points[:, 0] <= x1)
                       & (points[:, 1] >= y0) & (points[:, 1] <= y1)))


def _ground_background(ax, results: RunResults, background: np.ndarray, ext) -> None:
    """The run's first frame warped onto its ground plane (``track --ground``), under the
    tracks drawn in that plane's metres (north up)."""
    import cv2

    reg = results.registration.get(results.first_frame) if results.registration else None
    if reg is None:
        return
    x0, y0, x1, y1 = ext
    res = max(x1 - x0, y1 - y0) / 1200.0
    w, h = max(1, int(round((x1 - x0) / res))), max(1, int(round((y1 - y0) / res)))
    to_raster = np.array([[1 / res, 0, -x0 / res], [0, -1 / res, y1 / res], [0, 0, 1.0]])
    M = to_raster @ np.asarray(reg, np.float64).reshape(3, 3)
    rgba = cv2.cvtColor(background, cv2.COLOR_BGR2RGBA)
    img = cv2.warpPerspective(rgba, M, (w, h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
    ax.imshow(img, extent=(x0, x1, y0, y1), origin="upper", zorder=0)


def _lonlat_axes(ax, geomap, fs: float) -> None:
    """Label a map-pixel axis in lon/lat (exact for north-up rasters, otherwise map pixels)."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    t = geomap.transform
    if abs(t.b) > 1e-12 or abs(t.d) > 1e-12:
        ax.set_xlabel("map x (px)", fontsize=fs)
        ax.set_ylabel("map y (px)", fontsize=fs)
        return
    cx, cy = geomap.width / 2, geomap.height / 2

    def lon(x, _pos=None):
        return f"{geomap.pixel_to_lonlat(np.array([[x, cy]]))[0, 0]:.5f}°"

    def lat(y, _pos=None):
        return f"{geomap.pixel_to_lonlat(np.array([[cx, y]]))[0, 1]:.5f}°"

    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.yaxis.set_major_locator(MaxNLocator(6))
    ax.xaxis.set_major_formatter(FuncFormatter(lon))
    ax.yaxis.set_major_formatter(FuncFormatter(lat))
    ax.set_xlabel("longitude", fontsize=fs)
    ax.set_ylabel("latitude", fontsize=fs)


def plot_space_time(results: RunResults, geomap=None, *, metres_per_unit: float | None = None):
    """Tracks in (x, y, time), coloured by ID (Yu & Medioni 2007, fig. 6).

    x, y are metres east/north in a local frame with a map (or with ``metres_per_unit``), the run's
    first frame's pixels otherwise (y pointing down, as in the image). In-view parts solid, predicted parts dashed;
    each track's ID at its last in-view point.
    """
    tracks = results.track_views(geomap)
    metres_per_unit = metres_per_unit or results.metres_per_unit
    fig = _figure(10.0, 8.0)
    fs = _font_pt(fig)
    ax = fig.add_subplot(projection="3d")
    unit = "px"
    xs: dict[int, np.ndarray] = {}
    for tv in tracks:
        xy, unit = metric_positions(tv, geomap, metres_per_unit)
        if unit == "px":
            xy = xy * np.array([1.0, -1.0])  # so that the image's "up" is up in the plot
        xs[tv.id] = xy
    if unit == "m" and xs:  # metres about the centre of the tracks
        allxy = np.vstack(list(xs.values()))
        centre = np.nanmedian(allxy, axis=0) if np.isfinite(allxy).any() else np.zeros(2)
        xs = {k: v - centre for k, v in xs.items()}
    # limits from the in-view positions; predicted points beyond them are dropped (3-D axes do
    # not clip lines)
    obs = [xs[tv.id][tv.observed] for tv in tracks]
    obs = np.vstack(obs) if obs else np.zeros((0, 2))
    obs = obs[np.all(np.isfinite(obs), axis=1)]
    if len(obs):
        lo, hi = obs.min(axis=0), obs.max(axis=0)
        pad = 0.05 * np.maximum(hi - lo, 1.0)
        lo, hi = lo - pad, hi + pad
        for tv in tracks:
            xy = xs[tv.id]
            out = np.any((xy < lo) | (xy > hi), axis=1) & ~tv.observed
            xy[out] = np.nan
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    for tv in tracks:
        xy = xs[tv.id]
        t = (tv.frames - 1) / results.fps
        c = id_rgb(tv.id)
        for idx, obs in _segments(tv):
            ok = np.all(np.isfinite(xy[idx]), axis=1)
            if ok.sum() < 2:
                continue
            i = idx[ok]
            ax.plot(xy[i, 0], xy[i, 1], t[i], color=c, lw=1.8 if obs else 1.2,
                    ls="-" if obs else (0, (3, 2)))
        for r in tv.reacquisitions():
            if np.all(np.isfinite(xy[r])):
                ax.scatter([xy[r, 0]], [xy[r, 1]], [t[r]], marker="*", s=90, color=c,
                           edgecolors="black", linewidths=0.6, depthshade=False)
        seen = np.flatnonzero(tv.observed & np.all(np.isfinite(xy), axis=1))
        if len(seen):  # the ID at the track's last in-view point, as on map.png
            k = seen[-1]
            ax.text(xy[k, 0], xy[k, 1], t[k], f" {tv.id}", color=c, fontsize=fs * 0.75,
                    fontweight="bold")
    if unit == "m":
        ax.set_xlabel("east (m)", fontsize=fs, labelpad=10)
        ax.set_ylabel("north (m)", fontsize=fs, labelpad=10)
    else:
        ax.set_xlabel(f"frame {results.first_frame} x (px)", fontsize=fs, labelpad=10)
        ax.set_ylabel(f"frame {results.first_frame} −y (px)", fontsize=fs, labelpad=10)
    ax.set_zlabel("time (s)", fontsize=fs, labelpad=8)
    ax.tick_params(labelsize=fs * 0.8)
    ax.view_init(elev=22, azim=-58)
    ax.set_title(f"space-time view of {len(tracks)} tracks", fontsize=fs * 1.1)
    return fig


def plot_registration(results: RunResults):
    """Registration quality over time from ``registration.csv``.

    Panels: inliers, inlier ratio and median reprojection error (frame pixels) when those columns
    exist, and always the motion of the frame centre in world units per frame (from the
    homographies; metres with a scale, else map or frame-1 pixels); frames whose status is not
    ``ok``/``refined`` are shaded and counted.

    Returns None when the run has no ``registration.csv``.
    """
    reg = results.registration
    if reg is None or not len(reg):
        return None
    t = (reg.frames - 1) / results.fps
    panels = [(k, lbl) for k, lbl in (("inliers", "inliers"), ("inlier_ratio", "inlier ratio"),
                                       ("error", "error (px)")) if k in reg.extra
              and reg.extra[k].dtype != object and np.isfinite(reg.extra[k]).any()]
    w_img = _frame_size(results)
    centre = np.array([[w_img[0] / 2, w_img[1] / 2, 1.0]])
    cw = np.einsum("nij,j->ni", reg.H, centre[0])
    cw = cw[:, :2] / cw[:, 2:3]
    motion = np.r_[np.nan, np.hypot(*np.diff(cw, axis=0).T)]
    gaps = np.r_[False, np.diff(reg.frames) > 1]
    motion[gaps] = np.nan
    mpu = results.metres_per_unit
    if mpu:
        motion, unit = motion * mpu, "m"
    else:
        unit = "map px" if results.summary.get("registration_mode") == "map" else "frame-1 px"
    n = len(panels) + 1
    fig = _figure(12.0, 1.3 * n + 1.2, layout="constrained")
    fs = max(_font_pt(fig, 0.015), 11.0)
    axes = fig.subplots(n, 1, sharex=True)
    axes = np.atleast_1d(axes)
    status = reg.extra.get("status")
    bad = np.zeros(len(reg), bool)
    if status is not None and status.dtype == object:
        bad = np.array([str(s) not in ("ok", "refined", "") for s in status])
    for ax, (k, lbl) in zip(axes, panels):
        ax.plot(t, reg.extra[k], lw=1.2, color="#1f5fa8")
        ax.set_ylabel(lbl, fontsize=fs * 0.9)
    axes[-1].plot(t, motion, lw=1.2, color="#7a3fa0")
    axes[-1].set_ylabel(f"motion ({unit} / frame)", fontsize=fs * 0.9)
    axes[-1].set_xlabel("time (s)", fontsize=fs)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=fs * 0.9)
        for i in np.flatnonzero(bad):
            ax.axvspan(t[i] - 0.5 / results.fps, t[i] + 0.5 / results.fps, color="#e8553f", alpha=0.25, lw=0)
    missing = int(results.last_frame - len(reg)) if results.last_frame else 0
    what = "on the ground" if mpu else f"in {unit}"
    if results.summary.get("stabilised"):
        # (flat zero lines with no word: a probe took them for a failed registration)
        title = (f"no registration: the input was given as stabilised (--stabilised), so "
                 f"every one of its {len(reg)} frames has the identity homography")
    else:
        title = (f"registration: {len(reg)} frames, {int(bad.sum())} not ok (shaded), "
                 f"{max(missing, 0)} without a homography; motion = the frame centre's, {what}")
    axes[0].set_title(title, fontsize=fs)
    fig.align_ylabels(axes)
    return fig


def _frame_size(results: RunResults) -> tuple[float, float]:
    """(width, height) of the video, from summary.json or guessed from the boxes."""
    s = results.summary
    inp = s.get("input") if isinstance(s.get("input"), dict) else {}
    for v in (s.get("frame_size"), s.get("size"), inp.get("size"), inp.get("frame_size"),
              (inp.get("width"), inp.get("height"))):
        if isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(a, (int, float)) for a in v):
            return float(v[0]), float(v[1])
    rows = results.tracks
    if len(rows):
        return float(np.percentile(rows[:, 2] + rows[:, 4], 99)), float(np.percentile(rows[:, 3] + rows[:, 5], 99))
    return 640.0, 480.0


def write_pictures(results: RunResults, geomap=None, *, background: np.ndarray | None = None,
                   folder: str | Path | None = None) -> list[Path]:
    """Write ``map.png``, ``spacetime.png`` and (with ``registration.csv``) ``registration.png``.

    Parameters
    ----------
    results : RunResults
    geomap : GeoMap, optional
    background : ndarray (H, W, 3) uint8 BGR, optional
        Frame 1, drawn under the tracks when there is no map.
    folder : path, optional
        Where to write (default: the run's folder).
    """
    folder = Path(folder) if folder is not None else results.path
    out = [save_figure(plot_map(results, geomap, background=background), folder / "map.png"),
           save_figure(plot_space_time(results, geomap), folder / "spacetime.png")]
    reg = plot_registration(results)
    if reg is not None:
        out.append(save_figure(reg, folder / "registration.png"))
    for p in out:
        p.chmod(0o644)
    return out

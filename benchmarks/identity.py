"""Identity through gaps: re-acquisition rate and IDF1 with and without global linking, and an
ablation of the linker's cues and motion methods.

Until the scenario generator and the full pipeline are available, this benchmark cuts real ground
truth into tracklets: the Stanford Drone scenes' Car, Bus, Cart, Biker and Skater tracks (the SDD
``lost`` rows are natural gaps, "exits"), plus synthetic occlusions of 0.5-4 s hidden at random
(seeded) in the visible stretches. The linker then has to rejoin them. There are no frames in the
SDD subset, so appearance is simulated (a six-colour palette of histograms with noise, so about one
target pair in six look alike); the ablation switches each cue off in turn and swaps the motion
method.

Metrics (contract definitions where they exist):

* re-acquisition rate: for every gap of >= 15 frames between two visible stretches of a true
  target, success when the majority predicted ID over its last 10 visible frames before the gap
  equals the one over the first 10 after; reported separately for occlusions and exits;
* IDF1 of the in-view points (predicted points excluded) against the truth, for the tracklets alone
  (local association's output) and for the linked tracks;
* MPE of the predicted points inside linked gaps at 1, 2 and 4 s into the gap, metres.

Run: /tmp/venv/bin/python benchmarks/identity.py [--seeds 0 1 2] [--scenes ...]
Writes benchmarks/results/identity.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from prediction import DATA, QUERY_CLASSES, SCALES  # noqa: E402

from aerotrack.association.linking import GlobalLinker  # noqa: E402
from aerotrack.config import ContextConfig, LinkingConfig  # noqa: E402
from aerotrack.types import Track, TrackPoint  # noqa: E402

FPS = 30.0


def load_sdd_all(path: Path):
    """{id: (frames (n,), xy px (n, 2), lost (n,) bool)} for the query classes, and labels."""
    rows: dict[int, list] = {}
    labels = {}
    for line in path.read_text().splitlines():
        p = line.split()
        if len(p) < 10:
            continue
        lab = p[9].strip('"')
        if lab not in QUERY_CLASSES:
            continue
        i = int(p[0])
        x0, y0, x1, y1 = map(float, p[1:5])
        rows.setdefault(i, []).append((int(p[5]) + 1, (x0 + x1) / 2, (y0 + y1) / 2, p[6] == "1"))
        labels[i] = lab
    out = {}
    for i, r in rows.items():
        r.sort()
        a = np.array(r, dtype=np.float64)
        out[i] = (a[:, 0].astype(np.int64), a[:, 1:3], a[:, 3].astype(bool))
    return out, labels


PALETTE = np.array([  # 8-bin colour histograms of six common vehicle colours (simulated)
    [.50, .20, .10, .05, .05, .04, .03, .03], [.05, .05, .10, .20, .30, .15, .10, .05],
    [.03, .03, .04, .05, .10, .20, .25, .30], [.20, .20, .15, .15, .10, .10, .05, .05],
    [.05, .30, .30, .15, .10, .05, .03, .02], [.10, .10, .10, .10, .15, .15, .15, .15]])


def cut(tracks, rng, mpp, occl_every_s=(4.0, 8.0), occl_len_s=(0.5, 4.0), min_move_m=3.0,
        hist_noise=0.02):
    """Tracklets (list[Track]), their true ids, and the hidden (kind, id, first, last) gaps.

    SDD has no frames, so appearance is simulated: each target draws one of six palette colours
    (about one pair in six are look-alikes), plus a small per-target offset and per-observation
    noise ``hist_noise``.
    """
    tl, truth, gaps = [], [], []
    for i, (fr, xy, lost) in tracks.items():
        if np.hypot(*(xy.max(axis=0) - xy.min(axis=0))) * mpp < min_move_m:
            continue  # standing objects are trivial to rejoin and say nothing
        colour = np.clip(PALETTE[rng.integers(len(PALETTE))] + rng.normal(0, hist_noise / 2, 8), 1e-3, None)
        hidden = lost.copy()
        t = fr[0] + int(rng.uniform(*occl_every_s) * FPS)
        while t < fr[-1]:
            n = int(rng.uniform(*occl_len_s) * FPS)
            hidden |= (fr >= t) & (fr < t + n)
            t += n + int(rng.uniform(*occl_every_s) * FPS)
        vis = ~hidden
        # runs of visible frames
        edges = np.flatnonzero(np.diff(np.concatenate([[0], vis.astype(int), [0]])))
        runs = list(zip(edges[::2], edges[1::2]))
        runs = [(a, b) for a, b in runs if b - a >= 3]
        for k, (a, b) in enumerate(runs):
            pts = []
            for j in range(a, b):
                h = np.clip(colour + rng.normal(0, hist_noise, 8), 1e-3, None)
                pts.append(TrackPoint(int(fr[j]), np.array([xy[j, 0] - 5, xy[j, 1] - 5, 10, 10]),
                                      xy[j].copy(), 1.0, hist=h / h.sum()))
            tl.append(Track(0, pts))
            truth.append(i)
            if k + 1 < len(runs):
                g0, g1 = b, runs[k + 1][0]
                kind = "exit" if lost[g0:g1].mean() > 0.5 else "occlusion"
                gaps.append((kind, i, int(fr[b - 1]), int(fr[runs[k + 1][0]])))
    return tl, truth, gaps


def point_ids(tracks: list[Track]) -> dict[tuple[int, int], int]:
    """(frame, round(x*1000)) -> predicted id, for in-view points."""
    out = {}
    for t in tracks:
        for p in t.points:
            if p.kind != "predicted":
                out[(p.frame, int(round(p.world[0] * 1000)), int(round(p.world[1] * 1000)))] = t.id
    return out


def scores(tracks, tl, truth, gaps, true_xy, mpp):
    ids = point_ids(tracks)
    gt = {}
    for t, i in zip(tl, truth):
        for p in t.points:
            gt[(p.frame, int(round(p.world[0] * 1000)), int(round(p.world[1] * 1000)))] = i
    # IDF1 on points (every GT point is present once, predicted points excluded)
    pairs = Counter((gt[k], ids[k]) for k in gt if k in ids)
    g_ids = sorted({g for g, _ in pairs})
    p_ids = sorted({p for _, p in pairs})
    M = np.zeros((len(g_ids), len(p_ids)))
    gi = {g: n for n, g in enumerate(g_ids)}
    pi = {p: n for n, p in enumerate(p_ids)}
    for (g, p), c in pairs.items():
        M[gi[g], pi[p]] = c
    r, c = linear_sum_assignment(-M)
    idtp = M[r, c].sum()
    idf1 = 2 * idtp / (len(gt) + len(ids))
    # re-acquisition per gap (>= 15 frames)
    by_frame = {}
    for t in tracks:
        for p in t.points:
            if p.kind != "predicted":
                by_frame[(t.id, p.frame)] = p
    per_id_frames = {}
    for k, v in gt.items():
        per_id_frames.setdefault(v, []).append(k)
    res = {"occlusion": [0, 0], "exit": [0, 0]}
    for kind, i, f0, f1 in gaps:
        if f1 - f0 - 1 < 15:
            continue
        keys = sorted(per_id_frames[i])
        before = [ids[k] for k in keys if k[0] <= f0][-10:]
        after = [ids[k] for k in keys if k[0] >= f1][:10]
        ok = Counter(before).most_common(1)[0][0] == Counter(after).most_common(1)[0][0]
        res[kind][0] += ok
        res[kind][1] += 1
    # error of the predicted points inside linked gaps (between two in-view points of one track)
    errs = {30: [], 60: [], 120: []}
    for t in tracks:
        obs = [gt.get((p.frame, int(round(p.world[0] * 1000)), int(round(p.world[1] * 1000))))
               for p in t.points if p.kind != "predicted"]
        obs = [o for o in obs if o is not None]
        if not obs:
            continue
        i = Counter(obs).most_common(1)[0][0]
        fr, xy = true_xy[i]
        last_seen = max(p.frame for p in t.points if p.kind != "predicted")
        last_obs = None
        for p in t.points:
            if p.kind != "predicted":
                last_obs = p.frame
                continue
            j = np.searchsorted(fr, p.frame)
            if last_obs is None or p.frame > last_seen or j >= len(fr) or fr[j] != p.frame:
                continue
            k = p.frame - last_obs
            if k in errs:
                errs[k].append(float(np.hypot(*(p.world - xy[j]))) * mpp)
    return idf1, res, {f"{n / FPS:g}s": (float(np.mean(v)) if v else float("nan"), len(v))
                       for n, v in errs.items()}


VARIANTS = {
    "full: context + appearance": (LinkingConfig(), ContextConfig()),
    "motion only (context)": (LinkingConfig(weight_appearance=0.0), ContextConfig()),
    "appearance only + gates": (LinkingConfig(weight_motion=0.0), ContextConfig()),
    "gates only": (LinkingConfig(weight_motion=0.0, weight_appearance=0.0), ContextConfig()),
    "kalman + appearance": (LinkingConfig(), ContextConfig(method="kalman")),
    "constant-velocity + appearance": (LinkingConfig(), ContextConfig(method="constant-velocity")),
    "paper + appearance": (LinkingConfig(), ContextConfig(method="paper")),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCALES))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "identity.json"))
    args = ap.parse_args(argv)
    agg = {name: {"idf1": [], "occlusion": [0, 0], "exit": [0, 0], "mpe": {}, "seconds": 0.0}
           for name in ["tracklets only", *VARIANTS]}
    for scene in args.scenes:
        tracks, labels = load_sdd_all(DATA / scene / "annotations.txt")
        mpp = SCALES[scene]
        true_xy = {i: (fr[~lost], xy[~lost]) for i, (fr, xy, lost) in tracks.items()}
        for seed in args.seeds:
            rng = np.random.default_rng(seed)
            tl, truth, gaps = cut(tracks, rng, mpp)
            if not tl:
                continue
            alone = [Track(k + 1, list(t.points)) for k, t in enumerate(tl)]
            idf1, res, _ = scores(alone, tl, truth, gaps, true_xy, mpp)
            a = agg["tracklets only"]
            a["idf1"].append(idf1)
            for kk in ("occlusion", "exit"):
                a[kk][0] += res[kk][0]
                a[kk][1] += res[kk][1]
            for name, (lc, cc) in VARIANTS.items():
                t0 = time.perf_counter()
                linked = GlobalLinker(lc, cc, FPS, metres_per_unit=mpp).link(
                    [Track(0, list(t.points)) for t in tl])
                dt = time.perf_counter() - t0
                idf1, res, mpe = scores(linked, tl, truth, gaps, true_xy, mpp)
                a = agg[name]
                a["idf1"].append(idf1)
                a["seconds"] += dt
                for kk in ("occlusion", "exit"):
                    a[kk][0] += res[kk][0]
                    a[kk][1] += res[kk][1]
                for n, (v, cnt) in mpe.items():
                    a["mpe"].setdefault(n, []).extend([v] * cnt if cnt else [])
    out = {"protocol": {"scenes": args.scenes, "seeds": args.seeds, "fps": FPS,
                        "source": "SDD ground truth cut into tracklets (lost rows = exits, "
                                  "random 0.5-4 s occlusions every 4-8 s)"},
           "results": {}}
    print(f"{'variant':<30} {'IDF1':>6} {'reacq occl':>14} {'reacq exit':>14} "
          f"{'MPE 1s':>7} {'2s':>6} {'4s':>6} {'time s':>7}")
    for name, a in agg.items():
        oc, ex = a["occlusion"], a["exit"]
        row = {"IDF1": float(np.mean(a["idf1"])) if a["idf1"] else float("nan"),
               "reacq_occlusion": oc[0] / oc[1] if oc[1] else float("nan"), "n_occlusion": oc[1],
               "reacq_exit": ex[0] / ex[1] if ex[1] else float("nan"), "n_exit": ex[1],
               "gap_MPE_m": {n: float(np.mean(v)) if v else float("nan") for n, v in a["mpe"].items()},
               "seconds": a["seconds"]}
        out["results"][name] = row
        m = row["gap_MPE_m"]
        print(f"{name:<30} {row['IDF1']:6.3f} {row['reacq_occlusion']:6.3f} ({oc[1]:4d}) "
              f"{row['reacq_exit']:6.3f} ({ex[1]:4d}) {m.get('1s', float('nan')):7.2f} "
              f"{m.get('2s', float('nan')):6.2f} {m.get('4s', float('nan')):6.2f} {a['seconds']:7.1f}")
    out["config"] = {"linking": dataclasses.asdict(LinkingConfig()), "context": dataclasses.asdict(ContextConfig())}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()

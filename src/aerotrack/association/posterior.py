"""Terms of the local-association posterior (Yu & Medioni eqs. 4-10), in log space.

For a partition ``omega`` of the window's observations into tracks and false alarms,

    log P(omega | Y) = sum_k [ -c_birth * [k born in the window]
                               + sum_links (motion + appearance + missed-detection terms) ]
                       - lambda * sum_{same-frame pairs both in tracks} IoU          (eq. 10)

* **motion** (eqs. 5-8): each link ``y_{t1} -> y_{t2}`` of a track is scored by the Kalman motion
  likelihood of ``y_{t2}`` given the track's filtered state at ``t1``, as a log-likelihood ratio
  against the false-alarm hypothesis of eq. 7:
  ``0.5 * (gate^2 - d^2) - 0.5 * log(det S / det R)``, with ``d^2`` the squared Mahalanobis
  distance of the innovation, ``S`` its covariance and ``R`` the observation noise. This is
  ``log N(e; 0, S)`` (eq. 8) minus the log-density of a uniform false alarm taken equal to the
  likelihood, at the gate boundary, of a perfectly known state. The paper leaves the false-alarm
  density unspecified; this choice is unit-free, forbids links outside the gate (the graph has no
  such edge), and keeps eq. 8's ``det S`` so that uncertain predictions (new tracks, long gaps)
  earn less: without it, cutting a track and restarting it with a vague velocity would pay.
* **missed detections**: ``-miss_cost`` per frame skipped by a link, so that long gaps are bridged
  only by consistent motion.
* **appearance** (eq. 9, with the minus sign that makes it a likelihood):
  ``-0.5 * app_weight * sum_c (P_i(c) - P_j(c)) log(P_i(c) / P_j(c))`` between linked blobs.
* **birth** (prior on the number of tracks): ``-c_birth`` for each track born in the window; it
  stops the sampler from explaining noise with short tracks.
* **false alarms**: an unassigned observation scores 0; the terms above are relative to it.
* **interaction** (eq. 10): two observations of the same frame that overlap cannot both be true
  targets; ``-lambda * IoU`` for each such pair that is assigned to tracks.
"""

from __future__ import annotations

import numpy as np

from ..kalman import (
    mahalanobis_nb,
    measurement_noise_nb,
    predict_nb,
    process_noise_nb,
    transition_nb,
    update_nb,
)

try:
    from numba import njit
except ImportError:  # pragma: no cover
    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f



def iou_xywh_centre(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU (N, M) of boxes given as (centre x, centre y, w, h) rows."""
    a = np.asarray(a, float).reshape(-1, 4)
    b = np.asarray(b, float).reshape(-1, 4)
    ax0, ay0 = a[:, 0] - a[:, 2] / 2, a[:, 1] - a[:, 3] / 2
    ax1, ay1 = a[:, 0] + a[:, 2] / 2, a[:, 1] + a[:, 3] / 2
    bx0, by0 = b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2
    bx1, by1 = b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2
    iw = np.clip(np.minimum(ax1[:, None], bx1[None]) - np.maximum(ax0[:, None], bx0[None]), 0, None)
    ih = np.clip(np.minimum(ay1[:, None], by1[None]) - np.maximum(ay0[:, None], by0[None]), 0, None)
    inter = iw * ih
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def left_edge_pairs(x0: np.ndarray, wmax: float, groups: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pairs ``(i, j)`` of boxes that can touch: in one group (a frame), the second's
    left edge ``x0`` within ``wmax`` (the widest box) of the first's. Boxes sorted by group, then
    by left edge, are compared at distances 1, 2, ... in that order until no pair is within reach,
    so the work grows with how many boxes one box's width holds, not with the square of a frame's
    boxes (1000 vehicles a frame made linking take minutes; 3000 made association's (n, n) IoU
    matrix 0.48 s a frame). Pairs come in that order, indices as given."""
    x0 = np.asarray(x0, dtype=np.float64)
    n = len(x0)
    g = np.zeros(n, np.int64) if groups is None else np.asarray(groups)
    order = np.lexsort((x0, g))
    xs, gs = x0[order], g[order]
    out_i, out_j = [], []
    d = 1
    while d < n:
        r = np.flatnonzero((gs[:-d] == gs[d:]) & (xs[d:] <= xs[:-d] + wmax))
        if not len(r):
            break
        out_i.append(order[r])
        out_j.append(order[r + d])
        d += 1
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)


def iou_pairs(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs ``i < j`` of boxes (centre x, centre y, w, h rows) that overlap, with their IoU,
    ordered by (i, j): what ``np.nonzero(np.triu(iou_xywh_centre(z, z), 1) > 0)`` gives, without
    the (n, n) matrix (:func:`left_edge_pairs`); the IoU is computed as
    :func:`iou_xywh_centre` computes it."""
    z = np.asarray(z, float).reshape(-1, 4)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(z) < 2:
        return empty
    finite = np.isfinite(z[:, 2])
    wmax = float(np.abs(z[finite, 2]).max()) if finite.any() else 0.0
    i, j = left_edge_pairs(z[:, 0] - z[:, 2] / 2, wmax)
    if not len(i):
        return empty
    i, j = np.minimum(i, j), np.maximum(i, j)
    a, b = z[i], z[j]
    ax0, ay0 = a[:, 0] - a[:, 2] / 2, a[:, 1] - a[:, 3] / 2
    ax1, ay1 = a[:, 0] + a[:, 2] / 2, a[:, 1] + a[:, 3] / 2
    bx0, by0 = b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2
    bx1, by1 = b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2
    iw = np.clip(np.minimum(ax1, bx1) - np.maximum(ax0, bx0), 0, None)
    ih = np.clip(np.minimum(ay1, by1) - np.maximum(ay0, by0), 0, None)
    inter = iw * ih
    union = a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(union > 0, inter / union, 0.0)
    keep = iou > 0
    i, j, iou = i[keep], j[keep], iou[keep]
    o = np.lexsort((j, i))
    return i[o], j[o], iou[o]


#: d^2 recorded for a partial link (see :func:`link_step`): a partial observation has no
#: Mahalanobis distance of its own, and the negative value marks the link.
PARTIAL_D2 = -1.0


@njit(cache=True)
def inside_fraction(z, xp, max_area):
    """Fraction of box ``z``'s area (centre x, y, w, h) inside box ``xp[:4]``; 0 unless ``z``'s
    area is at most ``max_area`` times ``xp``'s."""
    az = abs(z[2] * z[3])
    ab = abs(xp[2] * xp[3])
    if az <= 0.0 or az > max_area * ab:
        return 0.0
    iw = min(z[0] + 0.5 * abs(z[2]), xp[0] + 0.5 * abs(xp[2])) - max(z[0] - 0.5 * abs(z[2]),
                                                                      xp[0] - 0.5 * abs(xp[2]))
    ih = min(z[1] + 0.5 * abs(z[3]), xp[1] + 0.5 * abs(xp[3])) - max(z[1] - 0.5 * abs(z[3]),
                                                                      xp[1] - 0.5 * abs(xp[3]))
    if iw <= 0.0 or ih <= 0.0:
        return 0.0
    return iw * ih / az


@njit(cache=True)
def partial_ok(z, xp, params):
    """Whether ``z`` may be a partial observation of the predicted box ``xp[:4]``.

    ``params[7]`` is the partial link's score (0 disables partial links), ``params[8]`` the
    share of ``z``'s area that must lie inside the prediction, ``params[10]`` the largest ratio of
    ``z``'s area to the prediction's.
    """
    if params.shape[0] < 11 or params[7] <= 0.0:
        return False
    return inside_fraction(z, xp, params[10]) >= params[8]


def partial_candidates(z: np.ndarray, z_prev: np.ndarray, min_inside: float, max_area: float
                       ) -> np.ndarray:
    """Which of one frame's observations may be a *part* of a target (partial links,
    :func:`link_step`): those that lie inside (at least ``min_inside`` of their area, and at most
    ``max_area`` of the other's area) at most one observation of the previous frame.

    A fragment of a vehicle lies inside that vehicle's box one frame earlier. When it also lies
    inside a second box there, it is between two vehicles (a convoy, a queue, a car beside a bus),
    and which one it belongs to is not known from geometry: it is then never taken as a part, and
    can only be a whole observation (of a target of its own). The paper has no partial
    observations; the test depends only on the observations (not on the partition), so the
    posterior stays a sum of per-track terms.

    Parameters
    ----------
    z : ndarray (n, 4)
        This frame's observations ``[x, y, w, h]`` (centre and size), metres.
    z_prev : ndarray (m, 4)
        The previous frame's observations, same units (m = 0: every one may be a part).
    min_inside, max_area : float
        ``partial_min_inside`` and ``partial_max_area`` of the association config.

    Returns
    -------
    ndarray (n,) bool
    """
    z = np.asarray(z, dtype=np.float64).reshape(-1, 4)
    z_prev = np.asarray(z_prev, dtype=np.float64).reshape(-1, 4)
    if not len(z) or not len(z_prev):
        return np.ones(len(z), dtype=bool)
    # inside_fraction for every pair, vectorised: (n, m)
    a, b = np.abs(z[:, None, :]), np.abs(z_prev[None, :, :])
    za, zb = a[..., 2] * a[..., 3], b[..., 2] * b[..., 3]
    iw = (np.minimum(z[:, None, 0] + 0.5 * a[..., 2], z_prev[None, :, 0] + 0.5 * b[..., 2])
          - np.maximum(z[:, None, 0] - 0.5 * a[..., 2], z_prev[None, :, 0] - 0.5 * b[..., 2]))
    ih = (np.minimum(z[:, None, 1] + 0.5 * a[..., 3], z_prev[None, :, 1] + 0.5 * b[..., 3])
          - np.maximum(z[:, None, 1] - 0.5 * a[..., 3], z_prev[None, :, 1] - 0.5 * b[..., 3]))
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where((za > 0) & (za <= max_area * zb), inter / za, 0.0)
    return np.count_nonzero(frac >= min_inside, axis=1) <= 1


@njit(cache=True)
def partial_allowed(f, f_whole, params):
    """Whether an observation at frame ``f`` may be partial after the last whole one at
    ``f_whole`` (``params[11]``: the longest run, frames)."""
    return params.shape[0] > 11 and abs(f - f_whole) <= params[11]


#: :func:`link_step`'s d^2 of a link refused by :func:`gap_motion_ok` (outside every gate).
REFUSED_D2 = 1e12


@njit(cache=True)
def gap_motion_ok(x, P, dt, z, params):
    """Whether a link bridging ``dt`` seconds of missed detections is physically possible.

    The Kalman gate alone lets a track that coasted for most of a second take a detection that
    implies a reversal or a jump into the next lane: its white-noise acceleration (``accel_std``,
    high enough to follow the frame-to-frame jitter of blob centres) spreads the prediction over
    metres, and a vehicle passing the other way under the same occluder falls inside. Over such
    a gap the observation's offset from the constant-velocity prediction ``x + v dt`` is split
    along and across the track's heading (when it moves faster than 2 m/s; else both limits are
    the larger), and each part may be at most ``a dt^2 / 2`` for the largest acceleration along
    (``params[12]``, m/s^2; 0 disables) or across (``params[14]``) plus one standard deviation
    of the predicted position (the filtered velocity's over ``dt`` and both ends' position
    noise). ``params[13]``: the shortest gap tested, seconds (over shorter ones the noise
    dominates). Ours, not Yu & Medioni's.
    """
    if params.shape[0] < 15 or params[12] <= 0.0 or dt < params[13]:
        return True
    if params.shape[0] > 15 and params[15] > 0.0:
        # a box whose area differs from the track's is a part of the vehicle (coming out from
        # under a tree, or going in): its centre runs ahead of the vehicle's
        ratio = abs(z[2] * z[3]) / max(abs(x[2] * x[3]), 1e-12)
        if abs(ratio - 1.0) > params[15]:
            return True
    s = 0.5 * (abs(z[2]) + abs(z[3]))
    sp2 = params[2] * params[2] + (params[3] * s) ** 2
    ex = z[0] - x[0] - x[4] * dt
    ey = z[1] - x[1] - x[5] * dt
    speed = np.sqrt(x[4] * x[4] + x[5] * x[5])
    a_along, a_across = params[12], params[14]
    if speed > 2.0:
        ux, uy = x[4] / speed, x[5] / speed
        e_al, e_ac = ex * ux + ey * uy, -ex * uy + ey * ux
        v_al = ux * ux * P[4, 4] + 2.0 * ux * uy * P[4, 5] + uy * uy * P[5, 5]
        v_ac = uy * uy * P[4, 4] - 2.0 * ux * uy * P[4, 5] + ux * ux * P[5, 5]
    else:
        e_al, e_ac = ex, ey
        v_al, v_ac = P[4, 4], P[5, 5]
        a_along = a_across = max(a_along, a_across)
    lim_al = 0.5 * a_along * dt * dt + np.sqrt(v_al * dt * dt + 2.0 * sp2)
    lim_ac = 0.5 * a_across * dt * dt + np.sqrt(v_ac * dt * dt + 2.0 * sp2)
    return abs(e_al) <= lim_al and abs(e_ac) <= lim_ac


@njit(cache=True)
def link_step(x, P, dt, z, params, partial=False):
    """One Kalman link: predict ``dt`` s ahead from (x, P), update with ``z``.

    Returns the posterior x, P, the squared Mahalanobis distance d^2 and
    ``log N(z; Hx, S) - log N(0; 0, R)``, the motion log-likelihood (eq. 8) relative to that of
    a perfectly predicted observation (so that it does not depend on units).

    **Partial observations.** A blob detector sometimes returns only part of a vehicle (a
    fragment in one frame, the whole in the next). Under the whole-box model such a link fails
    the gate on size, and the fragments then form a second track interleaved with the vehicle's
    own (each taking the frames the other misses). ``params`` (11,) = the Kalman parameters
    (``ConstantVelocityKF.as_array``), the partial link score ``c_part``, the minimum share of
    the observation inside the predicted box, the gate ``gate^2``, the largest area ratio of a
    part to the prediction, and the longest run (frames) from a whole observation to a partial
    one; ``partial`` says whether this link may be partial at all (the caller knows the frame of
    the track's last whole observation: a run of parts is bridged like a run of missed
    detections and is bounded the same way, so a track that started on a merged blob cannot live
    on as a part of it). When the whole-box link fails the gate while ``z`` is clearly smaller
    than the predicted box and lies inside it, the link is partial: the observation tells that
    the target is there, not where its centre or its size is, so the state is the prediction
    (no update), and the link scores ``c_part`` (returned as ``rel = c_part - 0.5 * gate^2``
    with ``d^2 =`` :data:`PARTIAL_D2`). The paper has no such term; it is the likelihood of the
    hidden observation type (whole or part) at its maximum. An earlier version updated the
    position with the part's centre (noise widened by the spread ``(W - w)^2 / 12`` of a part
    inside the whole): parts on the same side of the box run after run (the half of a vehicle
    not absorbed by the background, a neighbour's edge inside the box) dragged the track off
    its vehicle and onto the next one in a queue. Presence only, measured over seeds 0-2
    (HOTA / IDF1 against partial links off): Santiago +0.014 / +0.023, generated scenes
    default:0 +0.022 / +0.019 and convoy:2 +0.017 / +0.053, where updating the position lost
    0.011 / 0.023 on Santiago.
    """
    xp, Pp = predict_nb(x, P, transition_nb(dt), process_noise_nb(dt, params[0], params[1]))
    if not gap_motion_ok(x, P, dt, z, params):
        return xp, Pp, REFUSED_D2, -0.5 * REFUSED_D2
    R = measurement_noise_nb(z[2:4], params[2], params[3], params[4], params[5])
    xn, Pn, ll, d2 = update_nb(xp, Pp, z, R)
    logdet_r = 0.0
    for i in range(4):
        logdet_r += np.log(R[i, i])
    rel = ll + 2.0 * np.log(2.0 * np.pi) + 0.5 * logdet_r
    if partial and d2 > params[9] and partial_ok(z, xp, params):
        return xp, Pp, PARTIAL_D2, params[7] - 0.5 * params[9]
    return xn, Pn, d2, rel


@njit(cache=True)
def run_track(x0, P0, f0, has_prior, zs, frames, fps, params, f_whole, pok):
    """Filter a track's window observations ``zs`` (n, 4, metres) at ``frames`` (n,).

    Starts from the prior state (x0, P0) at frame f0 when ``has_prior``, else initiates at zs[0].
    ``f_whole`` is the frame of the last whole (not partial) observation before zs (-1: f0);
    ``pok`` (n,) bool which observations may be partial (:func:`partial_candidates`).
    Returns states (n, 6), covariances (n, 6, 6), squared Mahalanobis distances (n,), relative
    motion log-likelihoods (n,, see :func:`link_step`) and frame gaps (n,) of each incoming link
    (0 for a first observation without prior).
    """
    n = zs.shape[0]
    xs = np.zeros((n, 6))
    Ps = np.zeros((n, 6, 6))
    d2 = np.zeros(n)
    rel = np.zeros(n)
    gaps = np.zeros(n, dtype=np.int64)
    if n == 0:
        return xs, Ps, d2, rel, gaps
    if has_prior:
        x = x0.copy()
        P = P0.copy()
        fprev = f0
        start = 0
    else:
        R = measurement_noise_nb(zs[0, 2:4], params[2], params[3], params[4], params[5])
        x = np.zeros(6)
        x[:4] = zs[0]
        P = np.zeros((6, 6))
        P[:4, :4] = R
        P[4, 4] = params[6] * params[6]
        P[5, 5] = params[6] * params[6]
        xs[0] = x
        Ps[0] = P
        fprev = frames[0]
        start = 1
    if f_whole < 0 or not has_prior:
        f_whole = fprev
    for i in range(start, n):
        g = frames[i] - fprev
        x, P, d2[i], rel[i] = link_step(x, P, abs(g) / fps, zs[i], params,
                                        pok[i] and partial_allowed(frames[i], f_whole, params))
        if d2[i] >= 0:
            f_whole = frames[i]
        gaps[i] = abs(g)
        xs[i] = x
        Ps[i] = P
        fprev = frames[i]
    return xs, Ps, d2, rel, gaps


@njit(cache=True)
def _d2_predicted(xp, Pp, z, params):
    """Squared Mahalanobis distance of ``z`` from a predicted state, and
    ``log det S - log det R`` (how much the prediction's uncertainty widens the likelihood)."""
    S = Pp[:4, :4].copy()
    logdet_r = 0.0
    for i in range(2):
        s = abs(z[2 + i])
        r_pos = params[2] * params[2] + (params[3] * s) ** 2
        r_size = params[4] * params[4] + (params[5] * s) ** 2
        S[i, i] += r_pos
        S[i + 2, i + 2] += r_size
        logdet_r += np.log(r_pos) + np.log(r_size)
    e = np.empty(4)
    for i in range(4):
        e[i] = z[i] - xp[i]
    d2, logdet_s = mahalanobis_nb(S, e)
    if not np.isfinite(d2):
        return np.inf, 0.0
    return d2, logdet_s - logdet_r


@njit(cache=True)
def children_scores(x, P, f_end, h_end, lh_end, Z, F, LAB, H, LH, fps, params, reach_mps, gate2,
                    miss_cost, app_weight, f_whole, POK):
    """Link log-likelihood ratios from a track end to free candidate nodes.

    (x, P) is the track's state at frame ``f_end`` (reverse-time state for backward moves);
    Z (m, 4), F (m,), LAB (m,) the candidates' observations (metres), frames and labels; H, LH
    (m, B) their histograms and log-histograms (B = 0: appearance off). Returns the indices of
    the free candidates inside eq. 3's reach and the gate, and their link scores. ``f_whole``:
    the frame of the track's last whole observation (partial links, see :func:`link_step`);
    POK (m,) bool which candidates may be partial (:func:`partial_candidates`).
    """
    m = Z.shape[0]
    idx = np.empty(m, dtype=np.int64)
    w = np.empty(m)
    cnt = 0
    last_gap = -1
    xp = x
    Pp = P
    B = H.shape[1]
    for j in range(m):
        if LAB[j] >= 0:
            continue
        gap = abs(F[j] - f_end)
        dt = gap / fps
        r = reach_mps * dt + 0.25 * (Z[j, 2] + Z[j, 3])
        dx = Z[j, 0] - x[0]
        dy = Z[j, 1] - x[1]
        if dx * dx + dy * dy > r * r:
            continue
        if gap != last_gap:
            xp, Pp = predict_nb(x, P, transition_nb(dt), process_noise_nb(dt, params[0], params[1]))
            last_gap = gap
        if not gap_motion_ok(x, P, dt, Z[j], params):
            continue
        d2, dlogdet = _d2_predicted(xp, Pp, Z[j], params)
        if d2 <= gate2:
            s = 0.5 * (gate2 - d2 - dlogdet)
        elif POK[j] and partial_allowed(F[j], f_whole, params) and partial_ok(Z[j], xp, params):
            s = params[7]  # a part of the target (see link_step)
        else:
            continue
        s -= miss_cost * (gap - 1)
        if B > 0 and app_weight > 0 and h_end.shape[0] == B:
            kl = 0.0
            for b in range(B):
                kl += (h_end[b] - H[j, b]) * (lh_end[b] - LH[j, b])
            s -= 0.5 * app_weight * kl
        idx[cnt] = j
        w[cnt] = s
        cnt += 1
    return idx[:cnt], w[:cnt]


@njit(cache=True)
def score_matrix(X, P, FE, HE, LHE, Z, F, H, LH, fps, params, reach_mps, gate2, miss_cost,
                 app_weight, FW, POK):
    """Link scores (K, N) from K track ends (states X (K, 6), P (K, 6, 6) at frames FE (K,),
    histograms HE, LHE (K, B), last whole observations at frames FW (K,)) to N new
    observations (POK (N,): which may be partial); -inf where there is no edge or the gate
    fails. The Hungarian initialisation of each frame uses it."""
    K = X.shape[0]
    N = Z.shape[0]
    out = np.full((K, N), -np.inf)
    lab = np.full(N, -1, dtype=np.int64)
    for k in range(K):
        idx, w = children_scores(X[k], P[k], FE[k], HE[k], LHE[k], Z, F, lab, H, LH, fps, params,
                                 reach_mps, gate2, miss_cost, app_weight, FW[k], POK)
        for i in range(idx.shape[0]):
            out[k, idx[i]] = w[i]
    return out


@njit(cache=True)
def append_link(xs, Ps, d2s, gaps, links, apps, f_end, z, f, h_prev, lh_prev, h, lh, fps, params,
                gate2, miss_cost, app_weight, f_whole, pok):
    """A track's cached arrays with one observation ``z`` at frame ``f`` appended (one Kalman
    link from its last state at ``f_end``, last whole observation at ``f_whole``; ``pok``: may
    ``z`` be partial); returns the new arrays, the link's d^2 and score."""
    n = xs.shape[0]
    gap = f - f_end
    xn, Pn, d2, rel = link_step(xs[n - 1], Ps[n - 1], abs(gap) / fps, z, params,
                                pok and partial_allowed(f, f_whole, params))
    link = 0.5 * gate2 + rel - miss_cost * max(abs(gap) - 1, 0)
    app = 0.0
    if h.shape[0] > 0 and app_weight > 0:
        kl = 0.0
        for b in range(h.shape[0]):
            kl += (h_prev[b] - h[b]) * (lh_prev[b] - lh[b])
        app = -0.5 * app_weight * kl
    link += app
    xs2 = np.empty((n + 1, 6))
    Ps2 = np.empty((n + 1, 6, 6))
    d22 = np.empty(n + 1)
    gaps2 = np.empty(n + 1, dtype=np.int64)
    links2 = np.empty(n + 1)
    apps2 = np.empty(n + 1)
    xs2[:n] = xs
    Ps2[:n] = Ps
    d22[:n] = d2s
    gaps2[:n] = gaps
    links2[:n] = links
    apps2[:n] = apps
    xs2[n] = xn
    Ps2[n] = Pn
    d22[n] = d2
    gaps2[n] = abs(gap)
    links2[n] = link
    apps2[n] = app
    return xs2, Ps2, d22, gaps2, links2, apps2, d2, link


@njit(cache=True)
def switch_candidates(label, prev, frame, Z, base, lo, hi, tid, fp, fn, zp, zn, fps, reach_mps,
                      max_gap):
    """Candidates y of a switch after a track's consecutive nodes at frames ``fp`` -> ``fn``
    (positions zp, zn), among store indices lo..hi (the frames after ``fp`` within the gap).

    y must lie in another track within eq. 3's reach of zp, and either its predecessor (eq. 11;
    ``prev`` holds gids, ``base`` turns them into store indices) lies before ``fn``, within the
    gap and within reach of zn, or it has none (a track head; the caller keeps the heads of tracks
    born in the window). Returns the store indices (regular, heads).
    """
    m = hi - lo
    reg = np.empty(m, dtype=np.int64)
    heads = np.empty(m, dtype=np.int64)
    nr = 0
    nh = 0
    for j in range(lo, hi):
        if label[j] < 0 or label[j] == tid:
            continue
        dt1 = (frame[j] - fp) / fps
        r1 = reach_mps * dt1 + 0.25 * (Z[j, 2] + Z[j, 3])
        dx = Z[j, 0] - zp[0]
        dy = Z[j, 1] - zp[1]
        if dx * dx + dy * dy > r1 * r1:
            continue
        if prev[j] < 0:
            heads[nh] = j
            nh += 1
            continue
        q = prev[j] - base
        fq = frame[q]
        if fq >= fn or fq < fn - max_gap:
            continue
        dt2 = (fn - fq) / fps
        r2 = reach_mps * dt2 + 0.25 * (zn[2] + zn[3])
        dx = Z[q, 0] - zn[0]
        dy = Z[q, 1] - zn[1]
        if dx * dx + dy * dy > r2 * r2:
            continue
        reg[nr] = j
        nr += 1
    return reg[:nr], heads[:nh]

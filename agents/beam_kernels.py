"""numba kernels of the beam decoder's per-pulse work: the token features of every hypothesis, the
choice of the surviving extensions, and the label update of their feature state.

They compute exactly what `deint_env.features.TrackFeatures` does (`arrays`, `label`) for anchored
rows, one pulse at a time and without numpy's per-call overhead, which at a beam of a few
hypotheses is most of the cost; `tests/test_agents_beam.py` checks the two agree.  `deint_env`
keeps the numpy reference (its core dependencies exclude numba).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from baselines.jit_cache import guard
from baselines.survivor import same_last
from deint_env.features import CLIP, PERIOD_GATE, PRIOR_WEIGHT


@njit(cache=True, inline="always")
def _clip(x: float) -> float:
    if not math.isfinite(x):
        return 0.0
    return min(max(x, -CLIP), CLIP)


@njit(cache=True, inline="always")
def _resid(x: float) -> float:
    return x - max(np.rint(x), 1.0)


@njit(cache=True)
def token_arrays(period, anchor, count, amp_mean, amp_scale, prior_period, k, n, window, win_amp, first_toa,
                 labelled, scalars, has_amp, version, max_tracks, lookahead):
    """(tracks (k, n, F), pulse (G,)) float32 of hypotheses 0..k-1 for the pulse window[1] (anchored
    rows; the pulse features are the same for every hypothesis)."""
    v3 = version >= 3
    n_ahead = 4 if v3 else 2
    n_tok = 13 + (1 if v3 else 0) + n_ahead * lookahead
    tracks = np.empty((k, n, n_tok), np.float32)
    pulse = np.empty(8 + 2 * lookahead, np.float32)
    t, prev = window[1], window[0]
    unit = (t - first_toa) / max(labelled, 1)
    if not (labelled > 0 and unit > 0):
        unit = np.nan
    jit = scalars[2]
    amp_t = win_amp[1]
    for r in range(k):
        for i in range(n):
            p, a, c = period[r, i], anchor[r, i], count[r, i]
            since = (t - a) / p
            nn = max(np.rint(since), 1.0)
            row = tracks[r, i]
            row[0] = 1.0
            row[1] = 1.0 if c > 0 else 0.0
            row[2] = _clip(math.log1p(c))
            row[3] = 1.0 if math.isfinite(p) else 0.0
            row[4] = 1.0 if math.isfinite(a) else 0.0
            row[5] = _clip(since)
            row[6] = _clip(since - nn)
            row[7] = _clip(nn - 1.0)
            row[8] = _clip((t - prev) / p)
            row[9] = _clip(math.log(p / unit)) if p / unit > 0 else 0.0
            row[10] = _clip((t - a) / unit)
            row[11] = _clip((amp_t - amp_mean[r, i]) / amp_scale[r, i]) if has_amp else 0.0
            row[12] = _clip(p / prior_period[r, i] - 1.0)
            j0 = 13
            p_sigma = 0.0
            if v3:
                p_sigma = p / max(jit, 1e-3 * p)
                row[13] = _clip((since - nn) * p_sigma)
                j0 = 14
            for j in range(1, lookahead + 1):
                tj = window[1 + j]
                ahead = _resid((tj - a) / p)
                ahead_self = _resid((tj - t) / p)
                o = j0 + n_ahead * (j - 1)
                row[o] = _clip(ahead)
                row[o + 1] = _clip(ahead_self)
                if v3:
                    row[o + 2] = _clip(ahead * p_sigma)
                    row[o + 3] = _clip(ahead_self * p_sigma)
    pulse[0] = 1.0
    pulse[1] = 0.0 if math.isfinite(prev) else 1.0
    pulse[2] = 0.0
    pulse[3] = _clip(n / max_tracks)
    pulse[4] = _clip(scalars[0])
    pulse[5] = _clip(scalars[1])
    pulse[6] = _clip(jit / unit)
    pulse[7] = 1.0 if has_amp else 0.0
    for j in range(1, lookahead + 1):
        tj = window[1 + j]
        pulse[6 + 2 * j] = 1.0 if math.isfinite(tj) else 0.0
        pulse[7 + 2 * j] = _clip((tj - t) / unit)
    return tracks, pulse


@njit(cache=True)
def select(cand, anchor, t, beam, merge):
    """The (at most `beam`) best extensions of hypotheses (rows of `cand`, (k, n + 1) scores; column n
    spurious): (parent, label, score) in descending score, with `merge` keeping only the best of
    extensions whose tracks all last fired on the same pulses (`same_last`, pulses keyed by their times)."""
    k, m1 = cand.shape
    n = m1 - 1
    flat = cand.ravel()
    order = np.argsort(-flat, kind="mergesort")  # stable: ties in row-major order
    parent = np.empty(beam, np.int64)
    label = np.empty(beam, np.int64)
    score = np.empty(beam)
    got = 0
    for c in order:
        if got == beam:
            break
        b, lab = c // m1, c % m1
        if merge:
            dup = False
            for q in range(got):
                if same_last(anchor[b, :n], lab, anchor[parent[q], :n], label[q], t):
                    dup = True
                    break
            if dup:
                continue
        parent[got], label[got], score[got] = b, lab, flat[c]
        got += 1
    return parent[:got], label[:got], score[:got]


@njit(cache=True)
def extend(parent, label, n, t, amp, period, anchor, count, span_time, span_periods, amp_mean, prior_period):
    """Rows 0..len(parent)-1 become copies of their parents, each then labels pulse (t, amp) with its
    label (a track < n; n = spurious), updating its feature state as `TrackFeatures.label` does."""
    m = parent.shape[0]
    for arr in (period, anchor, span_time, span_periods, amp_mean):
        tmp = arr[parent].copy()
        arr[:m] = tmp
    tmpc = count[parent].copy()
    count[:m] = tmpc
    for r in range(m):
        i = label[r]
        if i >= n:
            continue
        c, p, a = count[r, i], period[r, i], anchor[r, i]
        d = t - a
        used = c > 0
        known = used and math.isfinite(p)
        nn = max(np.rint(d / p if known else 1.0), 1.0)
        gate = known and abs(d - nn * p) <= PERIOD_GATE * p
        if gate:
            span_time[r, i] += d
            span_periods[r, i] += nn
            p0 = prior_period[r, i]
            period[r, i] = (PRIOR_WEIGHT * p0 + span_time[r, i]) / (PRIOR_WEIGHT + span_periods[r, i])
        anchor[r, i] = t
        count[r, i] = c + 1
        mean = amp_mean[r, i]
        amp_mean[r, i] = mean + (amp - mean) / (c + 1) if used and math.isfinite(mean) else amp


@njit(cache=True)
def keep_rows(keep, pending, score, period, anchor, count, span_time, span_periods, amp_mean):
    """Compact the hypotheses to rows `keep` (ascending)."""
    m = keep.shape[0]
    for arr in (period, anchor, span_time, span_periods, amp_mean):
        tmp = arr[keep].copy()
        arr[:m] = tmp
    tmpc = count[keep].copy()
    count[:m] = tmpc
    tmpp = pending[keep].copy()
    pending[:m] = tmpp
    tmps = score[keep].copy()
    score[:m] = tmps


guard(globals())

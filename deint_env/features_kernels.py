"""The token features of `deint_env.features.TrackFeatures.arrays`, compiled.

At one episode a step, the numpy form of the features cost about 140 us a pulse (some 80 array calls on
(1, M) arrays, each mostly call overhead); this kernel computes the same values in one call.  It keeps
the numpy form's float64 operations one for one, in its order, so every feature is bit for bit what the
numpy expressions give (tests/test_batch_play.py holds the two to equality).  The logarithms are the
exception: numpy's `log`/`log1p` may use SIMD implementations whose last bit differs from the C
library's that compiled code calls, so the caller computes those two features with numpy and passes
them in.  Every observation of the token envs and of the `agent` policy comes from here, so the env
and the policy see the same features.

Division by zero gives inf or NaN, as numpy's does under `errstate(divide="ignore")`
(`error_model="numpy"`); NaN and inf features become 0 and the rest are clipped to [-clip, clip].
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _maximum(a, b):
    """np.maximum of two floats: NaN if either is NaN (Python's max would drop a NaN `a`)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@njit(cache=True, inline="always")
def _resid(x):
    return x - _maximum(np.rint(x), 1.0)


@njit(cache=True, inline="always")
def _value(x, clip):
    """An observation value as the numpy form makes it: 0 where not finite, else clipped."""
    return min(max(x, -clip), clip) if np.isfinite(x) else 0.0


@njit(cache=True, error_model="numpy")
def token_arrays(win_toa, win_amp, unit, exists, count, period, anchor, prior_period, amp_mean, amp_scale, blind,
                 has_amp, scalars, n_labels, log_count, log_period_unit, max_tracks, lookahead, v3, n_token, n_pulse,
                 clip):
    """(tracks (N, M, F), pulse (N, G)) float32 from TrackFeatures' state arrays (its `arrays`); `unit`:
    each row's time unit u (NaN before it is known), `log_count`, `log_period_unit`: log1p(count) and
    log(period / u) (numpy's, module doc)."""
    n_rows, m = exists.shape
    tracks = np.zeros((n_rows, m, n_token), np.float32)
    pulse = np.zeros((n_rows, n_pulse), np.float32)
    base = 14 if v3 else 13  # the look-ahead features' first column (after z in layout 3)
    per_ahead = 4 if v3 else 2
    for r in range(n_rows):
        t, prev = win_toa[r, 1], win_toa[r, 0]
        if not np.isfinite(t):
            continue  # a step that labels nothing: every feature 0
        u = unit[r]
        jitter = scalars[r, 2]
        pv = pulse[r]
        pv[0] = 1.0
        pv[1] = 0.0 if np.isfinite(prev) else 1.0
        pv[2] = 1.0 if blind[r] else 0.0
        pv[3] = n_labels[r] / max_tracks
        pv[4] = _value(scalars[r, 0], clip)
        pv[5] = _value(scalars[r, 1], clip)
        pv[6] = _value(jitter / u, clip)
        pv[7] = 1.0 if has_amp[r] else 0.0
        for j in range(1, lookahead + 1):
            tj = win_toa[r, 1 + j]
            pv[6 + 2 * j] = 1.0 if np.isfinite(tj) else 0.0
            pv[7 + 2 * j] = _value((tj - t) / u, clip)
        amp = win_amp[r, 1]
        for i in range(m):
            if not exists[r, i]:
                continue
            row = tracks[r, i]
            p, a = period[r, i], anchor[r, i]
            since = (t - a) / p
            n = _maximum(np.rint(since), 1.0)
            p_sigma = p / _maximum(jitter, 1e-3 * p)
            row[0] = 1.0
            row[1] = 1.0 if count[r, i] > 0 else 0.0
            row[2] = _value(log_count[r, i], clip)
            row[3] = 1.0 if np.isfinite(p) else 0.0
            row[4] = 1.0 if np.isfinite(a) else 0.0
            row[5] = _value(since, clip)
            row[6] = _value(since - n, clip)
            row[7] = _value(n - 1, clip)
            row[8] = _value((t - prev) / p, clip)
            row[9] = _value(log_period_unit[r, i], clip)
            row[10] = _value((t - a) / u, clip)
            if has_amp[r]:
                row[11] = _value((amp - amp_mean[r, i]) / (np.abs(amp) + 1e-12 if blind[r] else amp_scale[r, i]), clip)
            row[12] = _value(p / prior_period[r, i] - 1.0, clip)
            if v3:
                row[13] = _value((since - n) * p_sigma, clip)
            for j in range(1, lookahead + 1):
                tj = win_toa[r, 1 + j]
                ahead = _resid((tj - a) / p)
                ahead_self = _resid((tj - t) / p)
                k = base + per_ahead * (j - 1)
                row[k] = _value(ahead, clip)
                row[k + 1] = _value(ahead_self, clip)
                if v3:
                    row[k + 2] = _value(ahead * p_sigma, clip)
                    row[k + 3] = _value(ahead_self * p_sigma, clip)
    return tracks, pulse


@njit(cache=True)
def label_rows(actions, n_labels, win_toa, win_amp, labelled, count, period, anchor, span_time, span_periods,
               prior_period, amp_mean, gate_frac, prior_weight):
    """`TrackFeatures.label` in place: each ready row's label (a track below its n_labels; anything else
    is spurious and moves no track) updates that track's period, anchor, count and amplitude mean, then
    the labelled pulse becomes the row's previous one.  The numpy form's operations, one for one."""
    for r in range(actions.shape[0]):
        t = win_toa[r, 1]
        if not np.isfinite(t):
            continue  # not ready: its action labels nothing
        labelled[r] += 1
        i = actions[r]
        if 0 <= i < n_labels[r]:
            c, p, a = count[r, i], period[r, i], anchor[r, i]
            d = t - a
            used = c > 0
            known = used and np.isfinite(p)
            n = _maximum(np.rint(d / p if known else 1.0), 1.0)
            gate = known and np.abs(d - n * p) <= gate_frac * p
            span_t = span_time[r, i] + (d if gate else 0.0)
            span_n = span_periods[r, i] + (n if gate else 0.0)
            first_interval = used and not np.isfinite(p) and d > 0  # blind: a track's second pulse
            if first_interval:
                span_t, span_n = d, 1.0
            p0 = prior_period[r, i]
            if gate or first_interval:
                period[r, i] = ((prior_weight * p0 + span_t) / (prior_weight + span_n) if np.isfinite(p0)
                                else span_t / _maximum(span_n, 1.0))
            span_time[r, i], span_periods[r, i] = span_t, span_n
            anchor[r, i] = t
            count[r, i] = c + 1
            mean = amp_mean[r, i]
            amp = win_amp[r, 1]
            amp_mean[r, i] = mean + (amp - mean) / (c + 1) if used and np.isfinite(mean) else amp
        win_toa[r, 0] = t
        win_toa[r, 1] = np.nan

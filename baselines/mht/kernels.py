"""mht's compiled beam: one pulse's step (`step`), the look-ahead (`_future`), N-scan pruning, the rates and
the driver (`_run`); docs/mht.md.  Its interpreted form (`.py_func`) labels identically (tests/test_mht.py)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from baselines.jit_cache import guard
from baselines.kalman_jit import drift_terms, kf_predict_steps, kf_update, kf_update_div
from baselines.mht.scorer import _learned, _pulse_terms, scorer_views
from baselines.mht.start import _restart_period
from baselines.mht.state import (_BRANCH, _CACHE, _INSERTION, _LEARNED, _LOG_2PI, _PRIOR_MEAN, _PRIOR_WEIGHT, _Q_FLOOR,
                                 _R_FLOOR, _R_ZERO, _WINDOW, P_TT, P_TX, P_XX, PERIOD, TAU, beam_views, scratch_views)
from baselines.survivor import same_last


@njit(cache=True, nogil=True)
def _future(toa, n_seen, k, t, tau, ptt, ptx, pxx, look, gate2, jitter_var, interval_var, drift, log_q, log_1mq, st,
            order, dll, src):
    """The best log-likelihood of a track's next `look` arrivals after it took pulse k with the filtered
    block (t, tau, ptt, ptx, pxx): a small tree search over the buffered pulses in each arrival's gate
    (a hit: log(1 - q) + log N(e; 0, S), the KF updated (2.15); or a miss: log q, the KF coasted (2.8)).
    An arrival beyond the buffer ends the search (nothing known yet).  Depth-first with the explicit
    stack `st` (rows: t, tau, ptt, ptx, pxx, steps, total, depth); `order`: (_BRANCH,) work row.  With
    descriptor likelihoods (`dll` not None: docs/mht.md, "Descriptor likelihoods") a hit on pulse j also
    scores min(dll[j, src], 0): a pulse the track's emitter explains worse than the background counts against
    the continuation, a better one counts as its TOA alone (the whole dll, ~+12 nats a hit on pdw-v0, made
    a first pulse's 6-arrival look-ahead outweigh every later 2-arrival one: tracks called their own
    pulses spurious to keep it).  So no hit scores more than without descriptors (the bound below)."""
    if look <= 0:
        return 0.0
    newest = toa[n_seen - 1]
    # branch and bound: no arrival scores more than a hit with S = R (its least variance), a miss, or
    # the 0 of an arrival beyond the buffer
    most = max(log_1mq - 0.5 * (_LOG_2PI + math.log(jitter_var)), log_q, 0.0)
    st[0, 0], st[0, 1], st[0, 2], st[0, 3], st[0, 4] = t, tau, ptt, ptx, pxx
    st[0, 5], st[0, 6], st[0, 7] = 1.0, 0.0, 0.0
    top = 1
    best = -1e300
    while top > 0:
        top -= 1
        t, tau, ptt, ptx, pxx = st[top, 0], st[top, 1], st[top, 2], st[top, 3], st[top, 4]
        steps, total, depth = st[top, 5], st[top, 6], st[top, 7]
        d_xx, d_tx, d_tt = drift_terms(drift, t, steps)
        pred, p_tx, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, interval_var)
        p_tx = p_tx + d_tx
        p_xx = p_xx + d_xx
        s = p_xx + jitter_var
        half = math.sqrt(gate2 * s)
        if depth >= look or pred + half > newest:
            if total > best:
                best = total
            continue
        if total + (look - depth) * most <= best:
            continue
        st[top, 5], st[top, 6], st[top, 7] = steps + 1.0, total + log_q, depth + 1.0  # the miss branch
        top += 1
        # hits: at most _BRANCH pulses of the gate, a window around the predicted arrival (the last pulse
        # before it and the next ones), pushed farthest first so that the nearest is searched first (a
        # good bound early)
        lo = np.searchsorted(toa[k + 1:n_seen], pred - half) + k + 1
        hi = np.searchsorted(toa[k + 1:n_seen], pred + half) + k + 1
        c = np.searchsorted(toa[k + 1:n_seen], pred) + k + 1
        if hi - lo > _BRANCH:
            lo = max(lo, c - _BRANCH // 2)
            hi = min(hi, lo + _BRANCH)
        left, right = c - 1, c
        nb = hi - lo
        for r in range(nb):  # nearest first, merging outwards from the predicted arrival
            if right < hi and (left < lo or toa[right] - pred < pred - toa[left]):
                order[r] = right
                right += 1
            else:
                order[r] = left
                left -= 1
        for r in range(nb - 1, -1, -1):
            j = order[r]
            e = toa[j] - pred
            st[top, 0], st[top, 1], st[top, 2], st[top, 3], st[top, 4] = kf_update_div(t, pred, ptt + d_tt, p_tx, p_xx,
                                                                                      e, s, jitter_var)
            st[top, 5] = 1.0
            st[top, 6] = total + log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
            if dll is not None:  # (None: numba compiles the branch out)
                st[top, 6] += min(dll[j, src], 0.0)
            st[top, 7] = depth + 1.0
            top += 1
    return best


@njit(cache=True, nogil=True)
def prior_ahead(toa, n_seen, c, cfg, log_q, log_1mq, w, dll=None):
    """The look-ahead of the tracks not started yet (hypothesis 0 of beam `c`, before the first pulse): each
    track's best first arrival and `look_start` arrivals after it among the buffered pulses, from its prior
    block (`_future` from before pulse 0).  A started track carries the look-ahead of its last update; a
    track not started carried none (0), so a child starting it, whose look-ahead is a sum of log-densities
    (negative), ranked below the child calling its first pulse spurious, by the whole look-ahead: with the
    spurious rate at the unknown rate's prior mean (5 %), a dense scene's tracks of long period never
    started, their pulses all went spurious and the estimated rate ran away (issue #22).  With the prior's
    look-ahead, starting on the track's own first pulse costs nothing more than its hit there.  `dll`: the
    descriptor log-likelihood ratios (`_run`; None: TOA only)."""
    total = 0.0
    for i in range(c.blk.shape[1]):
        b = c.blk[0, i]
        if c.arrivals[0, i] == 0:
            c.h[0, i] = _future(toa, n_seen, -1, b[PERIOD], b[TAU], b[P_TT], b[P_TX], b[P_XX], cfg.look_start + 1,
                                cfg.gate2, cfg.jitter_var, cfg.interval_var, cfg.drift, log_q, log_1mq, w.stack,
                                w.branch, dll, i)
        total += c.h[0, i]
    c.ahead[0] = total


# `step` is one function of ~230 lines on purpose (the 120-line rule's measured exception): split into
# named helpers (the candidates, a restart's candidate, their ranking, the children) it cost mht 15-20 %
# of its time on core/robust/agile-v0's first test seeds as compiled calls (each passes the beams' and work
# arrays' ~40 array structs) and ~9 % as inline="always" helpers (numba's IR inlining); the minima of 4
# repeats, fresh processes alternating with the unsplit code, which the Kalman and survivor helpers leave
# within 1 % of the old hand-written step.
@njit(cache=True, nogil=True)
def step(toa, n_seen, k, size, c, x, zob, prior, width, look, cfg, log_q, log_1mq, log_rho, w, net, learned, dll=None):
    """Extend the beam `c` (size hypotheses) with pulse k into `x`; returns the new size.  Children are
    ranked by score + look-ahead (the sum of every track's look-ahead score), so an assignment whose
    track has no good continuation loses at once instead of a period later.  A learned scorer `net`
    (`Scorer`; none: w1 has no rows) corrects every candidate's score if `learned`.  `dll` (pulses, N): the
    descriptor log-likelihood ratio a track taking a pulse adds (`_run`; None: TOA only, and numba compiles
    the descriptor terms out: tested at run time, they cost mht 20-25 % of its time on core-v0)."""
    y = toa[k]
    n = c.blk.shape[1]
    ring = c.label.shape[1]
    gate2, jitter_var, interval_var = cfg.gate2, cfg.jitter_var, cfg.interval_var
    w.used[:] = 0
    x_q = x_r = x_n = 0.0  # the learned scorer's features of this pulse
    learned = learned and net.w1.shape[0] > 0
    if learned:
        x_q, x_r, x_n = 0.2 * log_q, 0.2 * (log_rho - math.log(cfg.pulse_rate)), 0.5 * math.log(n)
        _pulse_terms(net, w, x_q, x_r, x_n)
    nc = 0
    for b in range(size):
        first = nc
        for i in range(n):
            t = c.blk[b, i, PERIOD]
            tau = c.blk[b, i, TAU]
            near = max(1.0, np.floor((y - tau) / t + 0.5))
            ptt = c.blk[b, i, P_TT]
            ptx = c.blk[b, i, P_TX]
            # the nearest arrival, and (when that is not it) the very next one: with a period still
            # uncertain, "no miss" must stay a candidate
            for which in range(2):
                if which == 1 and near == 1.0:
                    break
                steps = near if which == 0 else 1.0
                d_xx, d_tx, d_tt = drift_terms(cfg.drift, t, steps)
                pred, p_tx, p_xx = kf_predict_steps(t, tau, ptt, ptx, c.blk[b, i, P_XX], steps, interval_var)
                p_tx = p_tx + d_tx
                s = p_xx + d_xx + jitter_var
                e = y - pred
                if e * e > gate2 * s:
                    continue
                m = steps - 1.0
                miss = 0.0
                if m > 0.0:
                    miss = max(m * log_q, cfg.log_gap)
                # the track's look-ahead after taking y (cached per source, last pulse and steps)
                depth = look
                if c.arrivals[b, i] == 0:
                    depth = cfg.look_start
                hv = 0.0
                found = False
                for q in range(w.used[i]):
                    if w.cache_last[i, q] == c.last[b, i] and w.cache_steps[i, q] == steps:
                        hv = w.cache_val[i, q]
                        found = True
                        break
                if not found:
                    # (var tau_m taken back from S: the bits the look-ahead has always had)
                    u_t, u_tau, u_tt, u_tx, u_xx = kf_update_div(t, pred, ptt + d_tt, p_tx, s - jitter_var, e, s,
                                                                 jitter_var)
                    hv = _future(toa, n_seen, k, u_t, u_tau, u_tt, u_tx, u_xx, depth, gate2, jitter_var,
                                 interval_var, cfg.drift, log_q, log_1mq, w.stack, w.branch, dll, i)
                    if w.used[i] < _CACHE:
                        q = w.used[i]
                        w.cache_last[i, q], w.cache_steps[i, q], w.cache_val[i, q] = c.last[b, i], steps, hv
                        w.used[i] += 1
                w.parent[nc] = b
                w.source[nc] = i
                w.steps[nc] = steps
                ls = math.log(s)
                w.score[nc] = c.score[b] + log_1mq + miss - 0.5 * (_LOG_2PI + ls + e * e / s)
                if dll is not None:
                    w.score[nc] += dll[k, i]
                w.log_s[nc] = ls
                w.h[nc] = hv
                w.rank[nc] = w.score[nc] + c.ahead[b] - c.h[b, i] + hv
                w.e[nc] = e
                w.s[nc] = s
                nc += 1
                # the same hit, the period jumping after it (steps + 0.5 marks it), when the hit deviates by
                # jump_z deviations or more
                if cfg.jump > 0.0 and e * e >= cfg.jump_z2 * s:
                    # (the look-ahead's cache and call repeat the hit's above: as a helper function, inlined
                    # or called, they cost lmht 11-20 % of its time per pulse)
                    qj = (cfg.jump * t) * (cfg.jump * t)
                    hj = 0.0
                    found = False
                    for q in range(w.used[i]):
                        if w.cache_last[i, q] == c.last[b, i] and w.cache_steps[i, q] == steps + 0.5:
                            hj = w.cache_val[i, q]
                            found = True
                            break
                    if not found:
                        u_t, u_tau, u_tt, u_tx, u_xx = kf_update_div(t, pred, ptt + d_tt, p_tx, s - jitter_var, e, s,
                                                                     jitter_var)
                        hj = _future(toa, n_seen, k, u_t, u_tau, u_tt + qj, u_tx, u_xx, depth, gate2, jitter_var,
                                     interval_var, cfg.drift, log_q, log_1mq, w.stack, w.branch, dll, i)
                        if w.used[i] < _CACHE:
                            q = w.used[i]
                            w.cache_last[i, q], w.cache_steps[i, q], w.cache_val[i, q] = c.last[b, i], steps + 0.5, hj
                            w.used[i] += 1
                    base = w.score[nc - 1]
                    w.score[nc - 1] = base + cfg.log_stay
                    w.rank[nc - 1] += cfg.log_stay
                    w.parent[nc] = b
                    w.source[nc] = i
                    w.steps[nc] = steps + 0.5
                    w.score[nc] = base + cfg.log_jump
                    w.log_s[nc] = ls
                    w.h[nc] = hj
                    w.rank[nc] = w.score[nc] + c.ahead[b] - c.h[b, i] + hj
                    w.e[nc] = e
                    w.s[nc] = s
                    nc += 1
            # a track silent for `dead` arrivals or more may restart here: the source was off (or lost)
            # and is back with a phase uniform over its period, its period from the prior
            # (counted with the longest plausible period: a period still unknown restarts nothing)
            if y - tau >= (cfg.dead + 1.0) * t and y - tau >= (cfg.dead + 1.0) * (t + 4.0 * math.sqrt(ptt)):
                hv = 0.0
                found = False
                for q in range(w.used[i]):
                    if w.cache_last[i, q] == -2:
                        hv = w.cache_val[i, q]
                        found = True
                        break
                if not found:
                    rt, rtt = _restart_period(t, ptt, prior[i, PERIOD], prior[i, P_TT])
                    hv = _future(toa, n_seen, k, rt, y, rtt, 0.0, jitter_var, cfg.look_restart,
                                 gate2, jitter_var, interval_var, cfg.drift, log_q, log_1mq, w.stack, w.branch, dll, i)
                    if w.used[i] < _CACHE:
                        q = w.used[i]
                        w.cache_last[i, q], w.cache_steps[i, q], w.cache_val[i, q] = -2, -1.0, hv
                        w.used[i] += 1
                w.parent[nc] = b
                w.source[nc] = i
                w.steps[nc] = -near  # negative: a restart after `near` arrivals
                w.score[nc] = c.score[b] + log_1mq + cfg.log_gap - math.log(prior[i, PERIOD])
                if dll is not None:
                    w.score[nc] += dll[k, i]
                w.h[nc] = hv
                w.rank[nc] = w.score[nc] + c.ahead[b] - c.h[b, i] + hv
                nc += 1
        w.parent[nc] = b
        w.source[nc] = -1
        w.score[nc] = c.score[b] + log_rho
        w.rank[nc] = w.score[nc] + c.ahead[b]
        nc += 1
        if learned:
            _learned(net, w, first, nc, c.score[b], c.ahead[b], c.arrivals[b], c.blk[b], x_q, x_r, x_n)
    # the children within `margin` of the best are sorted (a NaN rank is kept, sorted last, as without a
    # margin); stable: ties keep parent order (deterministic)
    top = w.rank[0]
    for j in range(1, nc):
        top = max(top, w.rank[j])
    floor = top - cfg.margin
    order = w.order
    m = 0
    if nc <= _INSERTION:
        # by insertion into the work row: no allocation (argsort's arrays cost more than the sort here)
        for j in range(nc):
            r = w.rank[j]
            if r < floor:
                continue
            p = m
            if r == r:  # not NaN: before every NaN and every lower rank
                while p > 0:
                    q = w.rank[order[p - 1]]
                    if q == q and not r > q:
                        break
                    order[p] = order[p - 1]
                    p -= 1
            order[p] = j
            m += 1
    else:
        near = np.empty(nc, np.int64)
        for j in range(nc):
            if not w.rank[j] < floor:
                near[m] = j
                m += 1
        near = near[:m]
        order[:m] = near[np.argsort(-w.rank[near], kind="mergesort")]
    slot = k % ring
    mask = zob.shape[1] - 1
    out = 0
    for pos in range(m):
        if out == width:
            break
        j = order[pos]
        b = w.parent[j]
        i = w.source[j]
        h = c.key[b]
        if i >= 0:
            h = h ^ zob[i, c.last[b, i] & mask] ^ zob[i, k & mask]
        dup = False
        for o in range(out):  # the same last pulse for every source: keep the better only
            if x.key[o] == h and same_last(c.last[b], i, x.last[o], -1, k):
                dup = True
                break
        if dup:
            continue
        _copy(c, b, x, out)
        x.key[out] = h
        x.score[out] = w.score[j]
        x.ahead[out] = w.rank[j] - w.score[j]
        if i >= 0 and w.steps[j] < 0:  # a restart at y
            rt, rtt = _restart_period(c.blk[b, i, PERIOD], c.blk[b, i, P_TT], prior[i, PERIOD], prior[i, P_TT])
            x.blk[out, i, PERIOD] = rt
            x.blk[out, i, TAU] = y
            x.blk[out, i, P_TT] = rtt
            x.blk[out, i, P_TX] = 0.0
            x.blk[out, i, P_XX] = jitter_var
            x.arrivals[out, i] += int(-w.steps[j])
            x.last[out, i] = k
            x.h[out, i] = w.h[j]
            x.label[out, slot] = i
            x.missed[out, slot] = 0  # an on/off switch, not misses
        elif i >= 0:
            steps = math.floor(w.steps[j])
            t = c.blk[b, i, PERIOD]
            ptt = c.blk[b, i, P_TT]
            # (2.8) applied `steps` times: tau' = tau + steps T, P' = F^steps P F^steps' + Q (the period's
            # random walk, `drift_terms`, in Q; w.s[j] holds S, its var tau term included), then (2.15)
            d_xx, d_tx, d_tt = drift_terms(cfg.drift, t, steps)
            pred, p_tx, _ = kf_predict_steps(t, c.blk[b, i, TAU], ptt, c.blk[b, i, P_TX], c.blk[b, i, P_XX], steps,
                                             interval_var)
            (x.blk[out, i, PERIOD], x.blk[out, i, TAU], x.blk[out, i, P_TT], x.blk[out, i, P_TX],
             x.blk[out, i, P_XX]) = kf_update(t, pred, ptt + d_tt, p_tx + d_tx, w.s[j] - jitter_var, w.e[j], w.s[j],
                                              jitter_var)
            if w.steps[j] != steps:  # the period jumps after this hit
                x.blk[out, i, P_TT] += (cfg.jump * t) * (cfg.jump * t)
            x.arrivals[out, i] += int(steps)
            x.last[out, i] = k
            x.h[out, i] = w.h[j]
            x.label[out, slot] = i
            x.missed[out, slot] = int(steps) - 1
        else:
            x.label[out, slot] = n
            x.missed[out, slot] = 0
        out += 1
    return out


@njit(cache=True, nogil=True, inline="always")
def _copy(c, b, x, out):
    """Hypothesis b of beam c into slot `out` of beam x (its tracks and label rings; the scalars are the
    caller's): element loops, as numba's row assignments cost ~3x more at these sizes."""
    for i in range(c.blk.shape[1]):
        for f in range(5):
            x.blk[out, i, f] = c.blk[b, i, f]
        x.arrivals[out, i] = c.arrivals[b, i]
        x.last[out, i] = c.last[b, i]
        x.h[out, i] = c.h[b, i]
    for j in range(c.label.shape[1]):
        x.label[out, j] = c.label[b, j]
        x.missed[out, j] = c.missed[b, j]


@njit(cache=True, nogil=True)
def _prune(size, decided, label, c):
    """N-scan pruning: keep (in order) the hypotheses that gave pulse `decided` the label `label`."""
    slot = decided % c.label.shape[1]
    out = 0
    for b in range(size):
        if c.label[b, slot] == label:
            if out != b:
                _copy(c, b, c, out)
                c.key[out] = c.key[b]
                c.score[out] = c.score[b]
                c.ahead[out] = c.ahead[b]
            out += 1
    return out


@njit(cache=True, nogil=True)
def rates(cfg, counts, span=0.0):
    """The per-pulse constants: stated rates, or the online estimates from the decided labels
    (counts = hits, misses, spurious) with the weak Beta prior, checked against the pulse count.
    Every decided pulse is a hit or spurious and every arrival a hit or a miss, so spurious - misses =
    pulses - arrivals; and the arrivals the sources made are known without the labels: R span, R the
    sources' pulse rate and `span` the decided pulses' time span.  A track that has lost its source
    decides no arrivals, so its misses are never counted while its source's pulses are called
    spurious: the labels' spurious rate then rose without bound on a clean channel (a higher rate made
    spurious calls cheaper, losing more tracks: 16 dense sources, 0.18 of the labels right, issue #22).
    So each count is held to what the pulse count allows (misses <= R span - hits, spurious <= pulses -
    R span + misses), over at least R span arrivals."""
    hits, misses, spurious = counts[0], counts[1], counts[2]
    expected = cfg.pulse_rate * span
    arrivals = max(hits + misses, expected)
    if span > 0.0:
        misses = min(misses, max(expected - hits, 0.0))
        spurious = min(spurious, max(hits + spurious + misses - expected, 0.0))
    q = cfg.known_q
    if math.isnan(q):
        q = (misses + _PRIOR_MEAN * _PRIOR_WEIGHT) / (arrivals + _PRIOR_WEIGHT)
    r = cfg.known_r
    if math.isnan(r):
        r = (spurious + _PRIOR_MEAN * _PRIOR_WEIGHT) / (arrivals + _PRIOR_WEIGHT)
    q = min(max(q, _Q_FLOOR), 0.9)
    r = max(r, _R_FLOOR) if r > 0 else _R_ZERO
    return math.log(q), math.log1p(-q), math.log(r * cfg.pulse_rate)


@njit(cache=True, nogil=True)
def decision_rates(cfg, counts, toa, n_labels):
    """`rates` while the next pulse to decide is n_labels: from the buffered start's chains' counts until
    the decisions cover it (`MHT._window_rates`), then from the decided labels."""
    if n_labels < counts[_WINDOW + 3]:
        return rates(cfg, counts[_WINDOW:], toa[counts[_WINDOW + 3] - 1] - toa[0])
    return rates(cfg, counts, toa[n_labels - 1] - toa[0] if n_labels > 0 else 0.0)


# the views of the flat work buffers (state.Flat, scorer.FlatScorer), made inside the driver
_beam_views = njit(cache=True, nogil=True)(beam_views)
_scratch_views = njit(cache=True, nogil=True)(scratch_views)
_scorer_views = njit(cache=True, nogil=True)(scorer_views)


@njit(cache=True, nogil=True)
def _run(toa, n_seen, ended, k, size, cur_f, cur_i, nxt_f, nxt_i, cap, zob, prior, w_f, w_i, look, settings, counts,
         labels, n_labels, net_f, net_rows, net_cols, net_hidden, dll):
    """Process pulses k, k+1, ... while their look-ahead is buffered (or their decision is due, or
    the stream `ended`): extend the beam, decide pulse k - nscan from the best hypothesis and prune
    the rest (N-scan).  Decided labels go to labels[n_labels:].  Returns (k, size, swapped, n_labels):
    `swapped` when the beam now lives in `nxt`.  The beams (`cap` hypotheses), the scratch (its look-ahead
    depth `look`) and the scorer come as their flat buffers (`state.Flat`, `scorer.FlatScorer`: arrays, not
    NamedTuples, which numba types argument by argument on every call).  `settings`: `pack(cfg, fit)`, fit
    the search while the misfit gate is closed.  `dll`: (at least n_seen, N) descriptor log-likelihood ratios
    of pulse k for track i (no columns: TOA only, and the kernels get None, compiled without the terms;
    docs/mht.md, "Descriptor likelihoods")."""
    cfg, fit = settings[0], settings[1]
    n = prior.shape[0]
    ring = cfg.nscan + 1
    cur = _beam_views(cur_f, cur_i, cap, n, ring)
    nxt = _beam_views(nxt_f, nxt_i, cap, n, ring)
    net = _scorer_views(net_f, net_rows, net_cols, net_hidden)
    w = _scratch_views(w_f, w_i, cap * (5 * n + 1), n, look, net_hidden)
    newest = toa[n_seen - 1]
    swapped = False
    while k < n_seen:
        y = toa[k]
        if counts[_LEARNED] == 0 and _misfit(cfg, counts) >= cfg.misfit:
            counts[_LEARNED] = 1
        c = cfg if counts[_LEARNED] == 1 else fit  # (`MHT`: `misfit`)
        starting = y <= cfg.start_until
        ahead = cfg.horizon
        width = c.beam
        if starting:
            ahead = cfg.horizon_start
            width = cfg.start_beam
        if not ended and n_seen - 1 - k < cfg.reserve and newest < y + ahead:
            break
        log_q, log_1mq, log_rho = decision_rates(cfg, counts, toa, n_labels)
        if k == 0:  # (a joint start, `cfg.initiate`, was made before: `MHT._joint_start`)
            if cfg.prior_ahead:
                if dll.shape[1] > 0:
                    prior_ahead(toa, n_seen, cur, cfg, log_q, log_1mq, w, dll)
                else:
                    prior_ahead(toa, n_seen, cur, cfg, log_q, log_1mq, w)
        if swapped:
            a, b = nxt, cur
        else:
            a, b = cur, nxt
        if dll.shape[1] > 0:
            size = step(toa, n_seen, k, size, a, b, zob, prior, width, c.look, c, log_q, log_1mq, log_rho, w, net,
                        counts[_LEARNED] == 1, dll)
        else:
            size = step(toa, n_seen, k, size, a, b, zob, prior, width, c.look, c, log_q, log_1mq, log_rho, w, net,
                        counts[_LEARNED] == 1)
        swapped = not swapped
        decided = k - cfg.nscan
        if decided >= 0:
            slot = decided % ring
            label = b.label[0, slot]
            count(counts, label, b.missed[0, slot], n)
            labels[n_labels] = label
            n_labels += 1
            size = _prune(size, decided, label, b)
        k += 1
    if ended and k == n_seen:  # the best hypothesis labels the undecided tail
        best = cur
        if swapped:
            best = nxt
        for j in range(n_labels, n_seen):
            slot = j % ring
            count(counts, best.label[0, slot], best.missed[0, slot], n)
            labels[j] = best.label[0, slot]
        n_labels = n_seen
    return k, size, swapped, n_labels


@njit(cache=True, nogil=True)
def _misfit(cfg, counts):
    """How strongly the decided labels reject the stated miss and spurious rates (nats; 0 for fewer
    misses or spurious pulses than stated): the log-likelihood ratio of the observed rates against the
    stated ones (floored as `rates` floors them; a rate the priors leave unknown is held to the weak
    prior's mean, 5 %), binomial for misses per arrival, Poisson for spurious pulses per arrival.  Merged
    pulses (missed arrivals), agile sources and lost tracks (misses and spurious pulses) raise it;
    pulses mht's model describes do not."""
    a = counts[0] + counts[1]
    if a == 0:
        return 0.0
    out = 0.0
    m = counts[1]
    q0 = _PRIOR_MEAN if math.isnan(cfg.known_q) else min(max(cfg.known_q, _Q_FLOOR), 0.9)
    if m > q0 * a:
        p = m / a
        out += m * math.log(p / q0) + ((a - m) * math.log((1.0 - p) / (1.0 - q0)) if m < a else 0.0)
    s = counts[2]
    mu = (_PRIOR_MEAN if math.isnan(cfg.known_r) else max(cfg.known_r, _R_FLOOR)) * a
    if s > mu:
        out += s * math.log(s / mu) - (s - mu)
    return out


@njit(cache=True, nogil=True)
def count(counts, label, missed, n):
    if label == n:
        counts[2] += 1
    else:
        counts[0] += 1
        counts[1] += missed



guard(globals())

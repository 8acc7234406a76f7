"""mht's compiled track start: pulse chains (`_chain`), the joint start of a crowded scene (`initiate`), the
prior-consistency test's chains (`_explained`) and a labelling's log-likelihood (`_loglik`); docs/mht.md."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from baselines.jit_cache import guard
from baselines.kalman_jit import drift_terms, kf_predict_steps, kf_update_div
from baselines.mht.state import _INIT_BEAM, _INIT_BRANCH, _LOG_2PI, P_TT, P_TX, P_XX, PERIOD, TAU

@njit(cache=True, nogil=True)
def _chain(toa, end, j, blk, look, cfg, log_q, log_1mq, used, path, fit, dll, src):
    """Track initiation: the best log-likelihood of a track (prior block `blk`) whose first arrival is
    pulse j, over its first look + 1 arrivals among pulses 0..end-1 not `used` by tracks already
    started: a beam search (_INIT_BEAM partial chains, the _INIT_BRANCH nearest unused pulses and a
    miss per arrival; a hit log(1 - q) + log N(e; 0, S), a miss log q; an arrival beyond pulse end-1
    ends the chain).  The best chain's pulses go to `path` (-1: a miss, -2: beyond the buffer), its
    final KF block to `fit`.  With descriptor likelihoods (`dll` not None) a hit on pulse jj also scores
    dll[jj, src], src the track."""
    t, tau, ptt, ptx, pxx = blk[PERIOD], blk[TAU], blk[P_TT], blk[P_TX], blk[P_XX]
    jv, iv = cfg.jitter_var, cfg.interval_var
    m_cap = _INIT_BEAM * (_INIT_BRANCH + 1)
    st = np.empty((_INIT_BEAM, 6))  # t, tau, ptt, ptx, pxx, steps since the last hit
    tot = np.empty(_INIT_BEAM)
    pth = np.full((_INIT_BEAM, look + 1), -1, np.int64)
    nst = np.empty((_INIT_BEAM, 6))
    ntot = np.empty(_INIT_BEAM)
    npth = np.empty((_INIT_BEAM, look + 1), np.int64)
    c_par = np.empty(m_cap, np.int64)
    c_j = np.empty(m_cap, np.int64)
    c_v = np.empty(m_cap)
    # the first arrival: pulse j (one step from the prior block, whose tau is the phase minus T)
    size = 1
    st[0, 0], st[0, 1], st[0, 2], st[0, 3], st[0, 4], st[0, 5] = t, tau, ptt, ptx, pxx, 1.0
    tot[0] = 0.0
    newest = toa[end - 1]
    for d in range(look + 1):
        nc = 0
        for m in range(size):
            t, tau, ptt, ptx, pxx, steps = st[m, 0], st[m, 1], st[m, 2], st[m, 3], st[m, 4], st[m, 5]
            pred, _, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, iv)
            s = p_xx + drift_terms(cfg.drift, t, steps)[0] + jv
            half = math.sqrt(cfg.gate2 * s)
            if d == 0:
                c_par[nc], c_j[nc] = m, j
                e = toa[j] - pred
                c_v[nc] = tot[m] + log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
                if dll is not None:
                    c_v[nc] += dll[j, src]
                nc += 1
                continue
            if pred + half > newest:  # nothing known yet: the chain ends as it is
                c_par[nc], c_j[nc], c_v[nc] = m, -2, tot[m]
                nc += 1
                continue
            c_par[nc], c_j[nc], c_v[nc] = m, -1, tot[m] + log_q
            nc += 1
            lo = np.searchsorted(toa[:end], pred - half)
            hi = np.searchsorted(toa[:end], pred + half)
            c = np.searchsorted(toa[:end], pred)
            left, right = c - 1, c
            taken = 0
            while taken < _INIT_BRANCH and (left >= lo or right < hi):  # the nearest unused pulses
                if right < hi and (left < lo or toa[right] - pred < pred - toa[left]):
                    jj = right
                    right += 1
                else:
                    jj = left
                    left -= 1
                if used[jj]:
                    continue
                e = toa[jj] - pred
                c_par[nc], c_j[nc] = m, jj
                c_v[nc] = tot[m] + log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
                if dll is not None:
                    c_v[nc] += dll[jj, src]
                nc += 1
                taken += 1
        order = np.argsort(-c_v[:nc], kind="mergesort")
        new = 0
        for r in order:
            if new == _INIT_BEAM:
                break
            m, jj = c_par[r], c_j[r]
            t, tau, ptt, ptx, pxx, steps = st[m, 0], st[m, 1], st[m, 2], st[m, 3], st[m, 4], st[m, 5]
            npth[new] = pth[m]
            ntot[new] = c_v[r]
            if jj == -2:
                nst[new] = st[m]
                npth[new, d] = -2
            elif jj == -1:
                nst[new, :5] = st[m, :5]
                nst[new, 5] = steps + 1.0
                npth[new, d] = -1
            else:  # (2.8) `steps` times, then (2.15)
                d_xx, d_tx, d_tt = drift_terms(cfg.drift, t, steps)
                pred, p_tx, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, iv)
                s = p_xx + d_xx + jv
                # (var tau_m taken back from S, as the look-ahead does: the same bits as before)
                nst[new, 0], nst[new, 1], nst[new, 2], nst[new, 3], nst[new, 4] = kf_update_div(
                    t, pred, ptt + d_tt, p_tx + d_tx, s - jv, toa[jj] - pred, s, jv)
                nst[new, 5] = 1.0
                npth[new, d] = jj
            new += 1
        size = new
        st[:size], tot[:size], pth[:size] = nst[:size], ntot[:size], npth[:size]
    path[:] = pth[0]
    fit[:] = st[0, :5]
    return tot[0]


@njit(cache=True, nogil=True)
def _best_start(toa, end, blk, look, cfg, log_q, log_1mq, used, path, fit, dll, src):
    """The best first pulse of a track (prior block `blk`) among the unused pulses in its first
    arrival's gate, and its chain's log-likelihood ratio (-inf: none)."""
    t, tau, ptt, ptx, pxx = blk[PERIOD], blk[TAU], blk[P_TT], blk[P_TX], blk[P_XX]
    pred, _, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, 1.0, cfg.interval_var)
    half = math.sqrt(cfg.gate2 * (p_xx + cfg.jitter_var))
    lo = np.searchsorted(toa[:end], pred - half)
    hi = np.searchsorted(toa[:end], pred + half)
    best, best_j = -np.inf, -1
    for j in range(lo, hi):
        if not used[j]:
            v = _chain(toa, end, j, blk, look, cfg, log_q, log_1mq, used, path, fit, dll, src)
            if v > best:
                best, best_j = v, j
    return best, best_j


@njit(cache=True, nogil=True)
def _own_train(path):
    """A chain is a track's own pulse train when at least half of its known arrivals (and 2) are hits."""
    hits = 0
    known = 0
    for jj in path:
        hits += jj >= 0
        known += jj != -2
    return hits >= max(2, (known + 1) // 2)


@njit(cache=True, nogil=True)
def _mark(path, used, flag):
    for jj in path:
        if jj >= 0:
            used[jj] = flag


@njit(cache=True, nogil=True)
def _in_first_gate(blk, y, cfg):
    pred, _, p_xx = kf_predict_steps(blk[PERIOD], blk[TAU], blk[P_TT], blk[P_TX], blk[P_XX], 1.0, cfg.interval_var)
    e = y - pred
    return e * e <= cfg.gate2 * (p_xx + cfg.jitter_var)


@njit(cache=True, nogil=True)
def _crossed(ba, bb, fa, fb):
    """Each of two chains' fitted periods lies nearer the other track's prior period than its own (in the
    priors' deviations): a chain started on its own first pulse that went on along the other's train."""
    def z2(f, b):
        return (f[PERIOD] - b[PERIOD]) ** 2 / b[P_TT]
    return z2(fa, ba) > z2(fa, bb) and z2(fb, bb) > z2(fb, ba)


@njit(cache=True, nogil=True)
def _start_two(toa, end, bx, by, jx, jy, look, cfg, log_q, log_1mq, used, px, py, fx, fy, js, dll, ix, iy):
    """Two tracks (prior blocks bx, by) started one after the other: x's chain from pulse jx, then y's
    from pulse jy among the pulses x's chain left (-1: the track's best first pulse, `_best_start`).
    Returns the chains' total log-likelihood (-inf: a track found no first pulse); their pulses go to
    px, py, their fits to fx, fy and their first pulses to js (ix, iy: the tracks, for `dll`)."""
    if jx < 0:
        jx = _best_start(toa, end, bx, look, cfg, log_q, log_1mq, used, px, fx, dll, ix)[1]
        if jx < 0:
            return -np.inf
    v = _chain(toa, end, jx, bx, look, cfg, log_q, log_1mq, used, px, fx, dll, ix)
    _mark(px, used, True)
    if jy < 0:
        jy = _best_start(toa, end, by, look, cfg, log_q, log_1mq, used, py, fy, dll, iy)[1]
    if jy >= 0:
        v += _chain(toa, end, jy, by, look, cfg, log_q, log_1mq, used, py, fy, dll, iy)
    else:
        v = -np.inf
    _mark(px, used, False)
    js[0], js[1] = jx, jy
    return v


@njit(cache=True, nogil=True)
def initiate(toa, end, blk, cfg, log_q, log_1mq, dll=None):
    """Joint track initiation on the first `end` pulses (a dense start puts many sources' first arrivals
    in each other's phase gates; judged one track at a time, a track takes a neighbour's pulse train as
    readily as its own).  Greedy, in order of prior period: each track's best pulse chain (`_chain`) is
    taken and its pulses are then unavailable to the tracks after it.  The order matters because every
    m-th pulse of a source of period T is a train of period m T, so a long-period track's chain may be a
    faster source's harmonic, never the reverse (a fast chain on a slow train misses most arrivals);
    judged by chain value instead, a slow track whose prior sat near a harmonic took it, and its own
    source was lost.  For the same reason every chain covers the whole buffered start (at least
    `look_init` arrivals): a fast track's chain of 16 arrivals left its later pulses free for a slow
    track's harmonic.  Then pairwise re-starts: two started tracks whose first pulses lie in each
    other's gates, or whose chains went on along each other's trains (`_crossed`), are started anew in
    the best of six ways (`_start_two`: on their own first pulses, on
    each other's, or each on its best pulse left, each with either chain chosen first -- two sources of
    near-equal period and phase: the chain chosen first may hop onto the other's train, and the greedy
    gives the first track judged the train its prior fits best, not the pair's best assignment).  A
    started track's prior phase becomes its chain's first pulse (deviation sigma_w) and its period the
    chain's fit, so the beam starts it there.  Only tracks whose first arrival's gate is narrower than a
    period take part; a track with no pulse train of its own (`_own_train`) is left to the beam.  `dll`: the
    descriptor log-likelihood ratios each hit of a chain adds (`kernels._run`; None: TOA only)."""
    n = blk.shape[0]
    look = max(cfg.look_init, int(math.ceil((toa[end - 1] - toa[0]) / np.min(blk[:, PERIOD]))))
    used = np.zeros(end, np.bool_)
    path = np.empty(look + 1, np.int64)
    fit = np.empty(5)
    first = np.full(n, -1, np.int64)
    paths = np.full((n, look + 1), -1, np.int64)
    fits = np.empty((n, 5))
    started = np.zeros(n, np.bool_)
    for i in np.argsort(blk[:, PERIOD]):
        p_xx = kf_predict_steps(blk[i, PERIOD], blk[i, TAU], blk[i, P_TT], blk[i, P_TX], blk[i, P_XX], 1.0,
                                cfg.interval_var)[2]
        if not 2.0 * math.sqrt(cfg.gate2 * (p_xx + cfg.jitter_var)) < blk[i, PERIOD]:
            continue
        j = _best_start(toa, end, blk[i], look, cfg, log_q, log_1mq, used, path, fit, dll, i)[1]
        if j < 0:
            continue
        first[i] = j
        _chain(toa, end, j, blk[i], look, cfg, log_q, log_1mq, used, path, fit, dll, i)
        if not _own_train(path):
            continue
        _mark(path, used, True)
        started[i], paths[i], fits[i] = True, path, fit
    path2 = np.empty(look + 1, np.int64)
    fit2 = np.empty(5)
    best_a, best_b = np.empty(look + 1, np.int64), np.empty(look + 1, np.int64)
    fit_a, fit_b = np.empty(5), np.empty(5)
    js = np.empty(2, np.int64)
    for _ in range(4):  # a cascade (tracks each on a neighbour's train) is undone one pair per pass
        swapped = False
        for a in range(n):
            for b in range(a + 1, n):
                if not (started[a] and started[b] and (_in_first_gate(blk[a], toa[first[b]], cfg)
                                                       and _in_first_gate(blk[b], toa[first[a]], cfg)
                                                       or _crossed(blk[a], blk[b], fits[a], fits[b]))):
                    continue
                _mark(paths[a], used, False)
                _mark(paths[b], used, False)
                # the pair started anew, six ways: on their first pulses, on each other's, or each on
                # its best pulse left (`_best_start`), each with a's chain chosen first or b's (two
                # sources of near-equal phase and period: a chain chosen first may hop onto the other's
                # train, so the order matters)
                fa, fb = first[a], first[b]
                best = -np.inf
                for way in range(6):
                    ja, jb = (fa, fb) if way < 2 else ((fb, fa) if way < 4 else (-1, -1))
                    if way % 2 == 0:
                        v = _start_two(toa, end, blk[a], blk[b], ja, jb, look, cfg, log_q, log_1mq, used, path,
                                       path2, fit, fit2, js, dll, a, b)
                        ja, jb = js[0], js[1]
                    else:
                        v = _start_two(toa, end, blk[b], blk[a], jb, ja, look, cfg, log_q, log_1mq, used, path2,
                                       path, fit2, fit, js, dll, b, a)
                        ja, jb = js[1], js[0]
                    if v > best and (way < 2 or (_own_train(path) and _own_train(path2))):
                        best = v
                        first[a], first[b] = ja, jb
                        best_a[:], best_b[:], fit_a[:], fit_b[:] = path, path2, fit, fit2
                if first[a] != fa or first[b] != fb:
                    swapped = True
                paths[a], paths[b], fits[a], fits[b] = best_a, best_b, fit_a, fit_b
                _mark(paths[a], used, True)
                _mark(paths[b], used, True)
        # a track left without a train of its own whose first gate holds a started track's first pulse:
        # it takes that chain when the started track then finds another train of its own
        for b in range(n):
            if started[b] or first[b] < 0:
                continue
            for a in range(n):
                if not (started[a] and _in_first_gate(blk[b], toa[first[a]], cfg)):
                    continue
                _mark(paths[a], used, False)
                _chain(toa, end, first[a], blk[b], look, cfg, log_q, log_1mq, used, path, fit, dll, b)
                if _own_train(path):
                    _mark(path, used, True)
                    v, j = _best_start(toa, end, blk[a], look, cfg, log_q, log_1mq, used, path2, fit2, dll, a)
                    if j >= 0:
                        _chain(toa, end, j, blk[a], look, cfg, log_q, log_1mq, used, path2, fit2, dll, a)
                    if j >= 0 and _own_train(path2):
                        started[b], first[b], paths[b], fits[b] = True, first[a], path, fit
                        first[a], paths[a], fits[a] = j, path2, fit2
                        _mark(paths[a], used, True)
                        swapped = True
                        break
                    _mark(path, used, False)
                _mark(paths[a], used, True)
        if not swapped:
            break
    for i in range(n):
        if started[i]:
            # the prior x_{1|0}: the phase at the first pulse (deviation sigma_w), the period the
            # chain's fit (its variance 4 times the fit's): tau = phi - T
            t = fits[i, PERIOD]
            var_t = 4.0 * fits[i, P_TT]
            blk[i, PERIOD] = t
            blk[i, TAU] = toa[first[i]] - t
            blk[i, P_TT] = var_t
            blk[i, P_TX] = -var_t
            blk[i, P_XX] = cfg.jitter_var + var_t


@njit(cache=True, nogil=True)
def _explained(toa, end, blk, cfg, log_q, log_1mq, looks, fitted, dll):
    """Prior-consistency test: the buffered pulses 0..end-1 the tracks (blocks `blk`) explain.  Track by
    track (in index order) its best pulse chain (`_best_start`, `looks[i]` arrivals: the whole window)
    among the pulses earlier tracks have not taken; its hits are taken.  Returns the pulses taken; a
    track whose chain is its own train (`_own_train`) gets in `fitted[i]` the block it starts from when
    restarted on it (as `initiate` starts a track: phase the chain's first pulse, period its fit),
    the others `blk[i]`.  Also returns the arrivals the taken chains missed.  `dll`: the descriptor
    log-likelihood ratios the chains' hits add (None: TOA only)."""
    n = blk.shape[0]
    used = np.zeros(end, np.bool_)
    missed = 0
    for i in range(n):
        fitted[i] = blk[i]
        path = np.empty(looks[i] + 1, np.int64)
        fit = np.empty(5)
        v, j = _best_start(toa, end, blk[i], looks[i], cfg, log_q, log_1mq, used, path, fit, dll, i)
        if j < 0:
            continue
        _chain(toa, end, j, blk[i], looks[i], cfg, log_q, log_1mq, used, path, fit, dll, i)
        _mark(path, used, True)
        missed += np.sum(path == -1)
        if _own_train(path):
            var_t = 4.0 * fit[P_TT]
            fitted[i, PERIOD], fitted[i, TAU] = fit[PERIOD], toa[j] - fit[PERIOD]
            fitted[i, P_TT], fitted[i, P_TX], fitted[i, P_XX] = var_t, -var_t, cfg.jitter_var + var_t
    return int(np.sum(used)), int(missed)


@njit(cache=True, nogil=True)
def _loglik(toa, labels, blk, cfg, log_q, log_1mq, log_rho):
    """The log-likelihood of a labelling of toa under the tracks' prior blocks `blk`, scored as `step`
    scores it (a hit after m misses log(1 - q) + max(m log q, log p_gap) + log N(e; 0, S), the nearest
    arrival or the next one, whichever is likelier; a restart log(1 - q) + log p_gap - log T; spurious
    log rho), each track's KF updated with its pulses (2.8), (2.15)."""
    n = blk.shape[0]
    b = blk.copy()
    jv, iv = cfg.jitter_var, cfg.interval_var
    total = 0.0
    for k in range(toa.shape[0]):
        i = labels[k]
        if i >= n:
            total += log_rho
            continue
        y = toa[k]
        t, tau, ptt, ptx, pxx = b[i, PERIOD], b[i, TAU], b[i, P_TT], b[i, P_TX], b[i, P_XX]
        near = max(1.0, np.floor((y - tau) / t + 0.5))
        best, best_steps = -np.inf, 1.0
        for steps in (near, 1.0):
            pred, _, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, iv)
            s = p_xx + drift_terms(cfg.drift, t, steps)[0] + jv
            e = y - pred
            v = log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
            if steps > 1.0:
                v += max((steps - 1.0) * log_q, cfg.log_gap)
            if v > best:
                best, best_steps = v, steps
        restart = log_1mq + cfg.log_gap - math.log(blk[i, PERIOD])
        # the source was off and is back (after `dead` silent arrivals, as in `step`): restart at y
        if y - tau >= (cfg.dead + 1.0) * (t + 4.0 * math.sqrt(ptt)) and restart > best:
            total += restart
            rt, rtt = _restart_period(t, ptt, blk[i, PERIOD], blk[i, P_TT])
            b[i, PERIOD], b[i, TAU], b[i, P_TT], b[i, P_TX], b[i, P_XX] = rt, y, rtt, 0.0, jv
            continue
        total += best
        steps = best_steps
        d_xx, d_tx, d_tt = drift_terms(cfg.drift, t, steps)
        pred, p_tx, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, iv)
        s = p_xx + d_xx + jv
        b[i, PERIOD], b[i, TAU], b[i, P_TT], b[i, P_TX], b[i, P_XX] = kf_update_div(
            t, pred, ptt + d_tt, p_tx + d_tx, s - jv, y - pred, s, jv)
    return total



@njit(cache=True, nogil=True)
def _restart_period(t, ptt, prior_t, prior_tt):
    """The period a restarting track starts from: its own estimate, unless that has left the prior by
    more than 2 prior deviations (a track captured by a neighbour), then the prior's."""
    if (t - prior_t) ** 2 > 4.0 * prior_tt:
        return prior_t, prior_tt
    return t, ptt


guard(globals())

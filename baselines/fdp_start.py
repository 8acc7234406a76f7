"""fdp's robust start (`initiate`, issue 10's track initiation; `fdp:start=lookahead`): each source's first
pulse chosen by a look-ahead chain search, compiled (`_chain`, `_claim`).  See baselines/fdp.py."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from baselines.jit_cache import guard
from baselines.kalman import Block, DLMModel, innovation, predict, prior_block, update
from baselines.kalman_jit import kf_predict_steps, kf_update_div
from deint_env.episode import Priors

_START_GATE = 4.0  # a source's candidate first pulses: within this many deviations of its phase
_START_BRANCH = 8  # pulses tried per arrival in a candidate's chain (the nearest in the gate)
_START_MISS_FLOOR = 0.05  # a chain's miss probability floor: a missed arrival costs -log(0.05) = 3


@njit(cache=True, nogil=True)
def _chain(toa, n_seen, k, t, tau, ptt, ptx, pxx, look, gate2, jv, ivar, log_rho, miss_cost, taken, path):
    """The least cost of a source's next `look` arrivals after it took pulse k (the filtered block t,
    tau, ptt, ptx, pxx): a small tree search over the buffered pulses not `taken` by another source,
    each arrival either a hit on one of the `_START_BRANCH` pulses nearest its prediction within the
    gate, costing 0.5 (e^2/S + log 2 pi S) + log rho (the pulse's NLL under the source against the
    density rho of all pulses), or a miss (`miss_cost`); arrivals beyond the buffer cost 0.  The best
    chain's pulses (-1: a miss) go to `path`.  Depth first on an explicit stack (rows: t, tau, ptt,
    ptx, pxx, steps, total, depth, pulse), branch and bound."""
    newest = toa[n_seen - 1]
    st = np.empty((look * (_START_BRANCH + 1) + 2, 9))
    st[0, 0], st[0, 1], st[0, 2], st[0, 3], st[0, 4] = t, tau, ptt, ptx, pxx
    st[0, 5], st[0, 6], st[0, 7], st[0, 8] = 1.0, 0.0, 0.0, k
    trail = np.full(look + 1, -1, np.int64)  # the pulses of the chain being searched, by depth
    path[:] = -1
    least = min(0.5 * math.log(2.0 * math.pi * jv) + log_rho, 0.0)  # no arrival costs less (S >= R)
    top, best = 1, np.inf
    while top > 0:
        top -= 1
        t, tau, ptt, ptx, pxx = st[top, 0], st[top, 1], st[top, 2], st[top, 3], st[top, 4]
        steps, total, depth = st[top, 5], st[top, 6], int(st[top, 7])
        trail[depth] = int(st[top, 8])
        # (2.8) `steps` times (the arrivals missed since the last hit, and this one)
        pred, p_tx, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, ivar)
        s = p_xx + jv
        half = math.sqrt(gate2 * s)
        if depth >= look or pred - half > newest:
            if total < best:
                best = total
                path[:] = -1
                path[:depth] = trail[1:depth + 1]
            continue
        if total + (look - depth) * least >= best:
            continue
        st[top, 5], st[top, 6], st[top, 7], st[top, 8] = steps + 1.0, total + miss_cost, depth + 1.0, -1.0
        top += 1  # the miss
        c = np.searchsorted(toa[:n_seen], pred)
        left, right = c - 1, max(c, k + 1)
        tried = 0
        while tried < _START_BRANCH:  # the nearest free hits within the gate, outwards from pred
            if right < n_seen and (left <= k or toa[right] - pred < pred - toa[left]):
                j = right
                right += 1
            elif left > k:
                j = left
                left -= 1
            else:
                break
            e = toa[j] - pred
            if e * e > gate2 * s:
                break
            if taken[j]:
                continue
            tried += 1
            st[top, 0], st[top, 1], st[top, 2], st[top, 3], st[top, 4] = kf_update_div(t, pred, ptt, p_tx, p_xx, e, s, jv)
            st[top, 5] = 1.0
            st[top, 6] = total + 0.5 * (e * e / s + math.log(2.0 * math.pi * s)) + log_rho
            st[top, 7], st[top, 8] = depth + 1.0, j
            top += 1
    return best


@njit(cache=True, nogil=True)
def _claim(toa, n_seen, k, t, tau, ptt, ptx, pxx, path, gate2, jv, ivar, owner, src):
    """Give source `src` (in `owner`) the pulses of its chosen chain: its first pulse k, the best chain's pulses
    (`path`), then, with the KF it has built, the nearest free pulse within the gate of each later
    arrival in the buffer (ending after 3 misses in a row: the track is lost, claim no more)."""
    owner[k] = src
    steps, misses, q = 1.0, 0, 0
    while True:
        pred, p_tx, p_xx = kf_predict_steps(t, tau, ptt, ptx, pxx, steps, ivar)
        s = p_xx + jv
        if pred - math.sqrt(gate2 * s) > toa[n_seen - 1] or misses >= 3:
            return
        j = -1
        if q < path.size:
            j = path[q]
            q += 1
        else:  # beyond the searched chain: the nearest free pulse in the gate
            c = np.searchsorted(toa[:n_seen], pred)
            for cand in (c - 1, c):
                if k < cand < n_seen and owner[cand] < 0 and (toa[cand] - pred) ** 2 <= gate2 * s:
                    if j < 0 or abs(toa[cand] - pred) < abs(toa[j] - pred):
                        j = cand
        if j < 0:
            steps += 1.0
            misses += 1
            continue
        t, tau, ptt, ptx, pxx = kf_update_div(t, pred, ptt, p_tx, p_xx, toa[j] - pred, s, jv)
        owner[j] = src
        steps, misses, k = 1.0, 0, j


def initiate(toa: np.ndarray, priors: Priors, model: DLMModel, gate: float, look: int) -> Priors:
    """Robust start (issue 10's track initiation): each source's first pulse chosen by look-ahead, so
    that in a dense scene, where many first arrivals fall within each other's phase gates, no source
    starts on a neighbour's pulse.  Sources are taken in order of increasing prior period (the most
    arrivals to judge by first).  A source's candidates are the free pulses within `gate` deviations
    of its prior phase; a candidate costs its NLL against the prior plus the best chain of the
    source's next `look` arrivals after it (`_chain`); the least wins unless every arrival missed
    costs less (then the source keeps its prior), and the winner's chain, followed through the
    buffer, is the source's (`_claim`), so a later source neither starts on nor is judged by pulses
    that an earlier one explains (a long period is otherwise matched by a harmonic of a short one).
    Then two sources each of whose first pulses lies in the other's phase gate (close periods and
    phases) swap them when that costs less for the pair (their chains judged on the pulses no other
    source claimed): the greedy order alone gives the first of them its pick.
    Returns the priors with the chosen phases known to the jitter: the FDP then starts every source
    on its own pulse.  Sources with an unknown phase keep their priors."""
    b = prior_block(priors)
    jv, ivar, gate2 = model.jitter_var, model.interval_var, gate * gate
    stated = priors.missing_prob if np.isfinite(priors.missing_prob) else 0.0
    miss = -math.log(max(_START_MISS_FLOOR, stated))
    log_rho = math.log(float(np.sum(1.0 / priors.period)))
    owner = np.full(toa.size, -1, np.int64)  # the source whose chain holds each pulse
    preds = {i: predict(b.take(slice(i, i + 1)), model) for i in range(priors.n_labels) if np.isfinite(priors.phase[i])}
    gated = {i: (lambda e, s: e * e <= gate2 * s)(*innovation(pred, toa, model)) for i, pred in preds.items()}

    def candidate(i: int, k: int, free: np.ndarray) -> tuple[float, Block, np.ndarray]:
        """Source i starting on pulse k: its cost, its block after k, its best chain's pulses."""
        e, s = innovation(preds[i], toa[k:k + 1], model)
        blk = update(preds[i], e, s, model)
        path = np.empty(look, np.int64)
        cost = 0.5 * (e[0] ** 2 / s[0] + math.log(2.0 * math.pi * s[0])) + log_rho + _chain(
            toa, toa.size, k, blk.period[0], blk.tau[0], blk.p_tt[0], blk.p_tx[0], blk.p_xx[0], look, gate2, jv,
            ivar, log_rho, miss, ~free, path)
        return cost, blk, path

    def claim(i: int, k: int, blk: Block, path: np.ndarray) -> None:
        _claim(toa, toa.size, k, blk.period[0], blk.tau[0], blk.p_tt[0], blk.p_tx[0], blk.p_xx[0], path, gate2, jv,
               ivar, owner, i)

    order = [int(i) for i in np.argsort(priors.period, kind="stable") if int(i) in preds]
    pick: dict[int, int] = {}
    for i in order:
        free = owner < 0
        best, chosen = (look + 1) * miss, None
        for k in np.flatnonzero(gated[i] & free):
            cost, blk, path = candidate(i, int(k), free)
            if cost < best:
                best, chosen = cost, (int(k), blk, path)
        if chosen is not None:
            pick[i] = chosen[0]
            claim(i, *chosen)
    for a, i in enumerate(order):  # pairwise swaps of first pulses
        for j in order[a + 1:]:
            if i not in pick or j not in pick or not (gated[i][pick[j]] and gated[j][pick[i]]):
                continue
            free = (owner < 0) | (owner == i) | (owner == j)
            keep_i, keep_j = candidate(i, pick[i], free), candidate(j, pick[j], free)
            swap_i, swap_j = candidate(i, pick[j], free), candidate(j, pick[i], free)
            if swap_i[0] + swap_j[0] < keep_i[0] + keep_j[0]:
                owner[(owner == i) | (owner == j)] = -1
                pick[i], pick[j] = pick[j], pick[i]
                claim(i, pick[i], *swap_i[1:])
                claim(j, pick[j], *swap_j[1:])
    phase, phase_std = priors.phase.copy(), priors.phase_std.copy()
    for i, k in pick.items():
        phase[i], phase_std[i] = toa[k], math.sqrt(jv)
    return dataclasses.replace(priors, phase=phase, phase_std=phase_std)


guard(globals())

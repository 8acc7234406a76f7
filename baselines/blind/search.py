"""Sequence search: extract one pulse train of a given PRI from the pulses not yet assigned.

From a seed pulse, the next arrival is predicted from a straight line fitted to the train's last
`memory` matched pulses (so slowly modulated PRIs are followed too); the nearest free pulse within the
gate joins the train, and an empty gate counts as a missing pulse (the prediction steps one more PRI).
The walk stops after `max_miss` consecutive misses.  Several seeds (the first free pulses) are tried
and the longest train is kept; it is accepted only if it is long and dense enough (see `accept`).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np


class Chain(NamedTuple):
    """A train found by the search: pulse indices (into the searched array) and each pulse's period
    count k (t_j ~ a + k_j T), and how many predicted arrivals it had."""

    index: np.ndarray
    k: np.ndarray
    n_slots: int


@numba.njit(cache=True)
def _walk(t, free, seed, pri, pri_unc, sigma, max_miss, memory, slack, curve):  # pragma: no cover - numba
    n = t.size
    idx = np.empty(n, np.int64)
    ks = np.empty(n, np.int64)
    idx[0] = seed
    ks[0] = 0
    m = 1
    k = 0
    miss = 0
    slope = pri
    t_end = t[n - 1]
    while True:
        k += 1
        # local line through the last `memory` matches: prediction and slope (the PRI)
        lo = max(0, m - memory)
        cnt = m - lo
        if cnt >= 2:
            sk = 0.0
            st = 0.0
            for q in range(lo, m):
                sk += ks[q]
                st += t[idx[q]]
            mk = sk / cnt
            mt = st / cnt
            skk = 0.0
            skt = 0.0
            for q in range(lo, m):
                dk = ks[q] - mk
                skk += dk * dk
                skt += dk * (t[idx[q]] - mt)
            slope = skt / skk
            pred = mt + slope * (k - mk)
            if curve and cnt >= 6:
                # a parabola through them instead: a PRI that keeps changing (wobulation) is followed
                # without the lag of a line's mean slope
                s3 = 0.0
                s4 = 0.0
                sk2t = 0.0
                for q in range(lo, m):
                    dk = ks[q] - mk
                    s3 += dk * dk * dk
                    s4 += dk * dk * dk * dk
                    sk2t += (dk * dk - skk / cnt) * (t[idx[q]] - mt)
                # t - mt = b dk + c (dk^2 - skk / cnt): the normal equations of the centred regressors
                a11 = skk
                a12 = s3
                a22 = s4 - skk * skk / cnt
                det = a11 * a22 - a12 * a12
                if det > 1e-12 * a11 * a22:
                    b = (a22 * skt - a12 * sk2t) / det
                    c = (a11 * sk2t - a12 * skt) / det
                    dk = k - mk
                    pred = mt + b * dk + c * (dk * dk - skk / cnt)
            unc = min(pri_unc, 4.0 * sigma / (ks[m - 1] - ks[lo]))
        else:
            pred = t[idx[0]] + pri * k
            unc = pri_unc
        gate = 3.0 * sigma + (unc + slack) * (k - ks[m - 1])
        if pred - gate > t_end:
            break
        j = np.searchsorted(t, pred - gate)
        best = -1
        bd = gate
        while j < n and t[j] <= pred + gate:
            if free[j] and j != idx[m - 1]:
                d = abs(t[j] - pred)
                if d <= bd:
                    bd = d
                    best = j
            j += 1
        if best >= 0 and best > idx[m - 1]:
            idx[m] = best
            ks[m] = k
            m += 1
            miss = 0
        else:
            miss += 1
            if miss > max_miss:
                break
    return idx[:m].copy(), ks[:m].copy()


def accept(chain: Chain, min_pulses: int, min_fill: float, chance: float = 0.0) -> bool:
    """A train must have `min_pulses` pulses and fill `min_fill` of the arrivals its span predicts,
    and clearly more than a walk at a wrong PRI would by chance (`chance`: the probability that a
    gate holds some free pulse anyway), by three binomial standard deviations."""
    return _accept(chain.index.size, int(chain.k[-1]) - int(chain.k[0]) + 1, min_pulses, min_fill, chance)


@numba.njit(cache=True)
def _accept(n, slots, min_pulses, min_fill, chance):  # pragma: no cover - numba
    need = max(min_fill, chance + 3.0 * np.sqrt(chance * (1.0 - chance) / slots))
    return n >= min_pulses and n >= need * slots


@numba.njit(cache=True)
def _best_walk(t, free, seeds, pri, pri_unc, sigma, max_miss, memory, slack, curve, min_pulses, min_fill,
               chance):  # pragma: no cover - numba
    """The longest acceptable walk over the seeds (the first of equal length); empty if none."""
    best_i = np.empty(0, np.int64)
    best_k = np.empty(0, np.int64)
    for s in seeds:
        idx, ks = _walk(t, free, s, pri, pri_unc, sigma, max_miss, memory, slack, curve)
        if _accept(idx.size, ks[-1] - ks[0] + 1, min_pulses, min_fill, chance) and idx.size > best_i.size:
            best_i, best_k = idx, ks
    return best_i, best_k


class Pool(NamedTuple):
    """What the searches over one set of free pulses share: the free pulses, the evenly spread seeds
    for trains that start late, and the free pulses' density."""

    cand: np.ndarray
    rest: np.ndarray
    density: float


def pool(t: np.ndarray, free: np.ndarray, n_seeds: int = 16) -> Pool:
    cand = np.flatnonzero(free)
    rest = cand[np.linspace(0, cand.size - 1, n_seeds // 2).astype(np.int64)] if cand.size else cand
    density = cand.size / max(float(t[cand[-1]] - t[cand[0]]), 1e-300) if cand.size else 0.0
    return Pool(cand, rest, density)


def sequence_search(t: np.ndarray, free: np.ndarray, pri: float, pri_unc: float, sigma: float, *,
                    n_seeds: int = 16, max_miss: int = 3, memory: int = 16, min_pulses: int = 6,
                    min_fill: float = 0.8, slack: float = 0.0, curve: bool = False,
                    shared: Pool | None = None) -> Chain | None:
    """The longest acceptable train of PRI ~ `pri` (+- `pri_unc`) among the free pulses, or None.

    Seeds are the free pulses in the first 1.5 PRI after the first free pulse (a train present from
    the start has one there) and, for trains that start later, free pulses spread over the rest.
    (memory: how many recent pulses the predicting line is fitted to; a short memory and some `slack`
    (a PRI change per pulse the gate allows) follow a modulated PRI; `curve`: predict from a parabola
    through them (from 6 pulses on) instead of a line; `shared`: `pool(t, free, n_seeds)` when many
    searches run on one set of free pulses.)"""
    p = shared if shared is not None else pool(t, free, n_seeds)
    cand = p.cand
    if cand.size < min_pulses:
        return None
    head = cand[t[cand] <= t[cand[0]] + 1.5 * pri + 3 * sigma][:n_seeds]
    chance = float(-np.expm1(-p.density * 2 * (3.0 * sigma + slack)))  # a free pulse in the gate anyway
    idx, ks = _best_walk(t, free, np.unique(np.concatenate([head, p.rest])), float(pri), float(pri_unc),
                         float(sigma), max_miss, memory, float(slack), bool(curve), min_pulses, float(min_fill),
                         chance)
    return Chain(idx, ks, int(ks[-1]) + 1) if idx.size else None

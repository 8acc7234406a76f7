"""A learned correction of `mht`'s candidate scores (the `lmht` agent's network, `agents.lmht`).

Per pulse and parent hypothesis, `mht._step` lists the candidates: track i after m misses, track i
restarting, spurious.  Their hand-written log-likelihood increments plus look-ahead change,
base_j = rank_j - (score_b + ahead_b), are the logits of mht's local choice.  `apply` adds a
learned f(x_j) to every candidate's score (so to its rank too): one small ReLU network shared by
all candidates of every kind over the per-candidate features `x_j` below (no source index among
them: the scorer is permutation-equivariant over tracks, the spurious candidate flagged by a kind
bit and described by scene features).  An "off" scorer (`Scorer.off()`, w1 with no rows) is never
called, so mht's labels stay bit-identical.

Features (FEATURES, version FEATURE_VERSION; scaled to O(1)):
  0-2  kind: a hit, a restart, spurious
  3    z = e / sqrt(S) (hit: the normalised innovation)
  4    z^2 / 4
  5    log(sqrt(S) / T) / 5 (hit: the prediction's spread relative to the period)
  6    log(1 + m): m misses before a hit, or the arrivals silent before a restart
  7    log(1 + arrivals) / 3 of the track so far
  8    (h' - h) / 10, the track's look-ahead after minus before taking the pulse, clipped to +-3
  9    (base_j - base_spurious) / 10, clipped to +-3 (mht's own log-likelihood ratio to spurious)
  10   log(sqrt(P_TT) / T) / 5, the track's period uncertainty
  11   log q / 5, the miss probability in use
  12   log r / 5, the spurious rate per source pulse in use
  13   the number of track candidates of this parent / 4
  14   (max_j base_j - base_spurious) / 10, clipped to +-3: how well the pulse is explained at all
  15   log(N) / 2, N the sources
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

FEATURES = ("hit", "restart", "spurious", "z", "z2", "log_spread", "log_misses", "log_arrivals", "ahead_change",
            "llr_spurious", "log_period_std", "log_q", "log_r", "candidates", "best_llr", "log_sources")
N_FEATURES = len(FEATURES)
FEATURE_VERSION = 1


class Scorer(NamedTuple):
    """f(x) = w2 . relu(x W1 + b1) + b2 (W1: (N_FEATURES, H), b1: (H,), w2: (H,), b2: (1,))."""

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray

    @classmethod
    def off(cls) -> Scorer:
        return cls(np.zeros((0, N_FEATURES)), np.zeros(0), np.zeros(0), np.zeros(1))


@njit(cache=True, nogil=True)
def mlp(net, x):
    """f(x) for one feature row."""
    hidden = net.b1.shape[0]
    out = net.b2[0]
    for u in range(hidden):
        a = net.b1[u]
        for f in range(x.shape[0]):
            a += x[f] * net.w1[f, u]
        if a > 0.0:
            out += a * net.w2[u]
    return out


@njit(cache=True, nogil=True)
def _clip3(v):
    return min(3.0, max(-3.0, v))


@njit(cache=True, nogil=True)
def apply(net, w, lo, hi, score, ahead, h, arrivals, blk, log_q, log_rho, pulse_rate):
    """Features of the candidates lo..hi-1 of one parent (its spurious candidate last) into w.feat,
    and f added to their scores and ranks.  score, ahead: the parent's; h, arrivals, blk: its tracks'."""
    n = h.shape[0]
    base_sp = w.rank[hi - 1] - score - ahead
    best = base_sp
    for j in range(lo, hi - 1):
        best = max(best, w.rank[j] - score - ahead)
    log_r = log_rho - math.log(pulse_rate)
    for j in range(lo, hi):
        x = w.feat[j]
        x[:] = 0.0
        i = w.source[j]
        base = w.rank[j] - score - ahead
        if i < 0:
            x[2] = 1.0
        else:
            t = blk[i, 0]
            if w.steps[j] < 0:  # a restart after -steps silent arrivals
                x[1] = 1.0
                x[6] = math.log1p(-w.steps[j])
            else:
                x[0] = 1.0
                z = w.e[j] / math.sqrt(w.s[j])
                x[3] = z
                x[4] = 0.25 * z * z
                x[5] = 0.1 * math.log(w.s[j] / (t * t))
                x[6] = math.log(w.steps[j])
            x[7] = math.log1p(arrivals[i]) / 3.0
            x[8] = _clip3(0.1 * (w.h[j] - h[i]))
            x[9] = _clip3(0.1 * (base - base_sp))
            x[10] = 0.1 * math.log(max(blk[i, 2], 1e-300) / (t * t))
        x[11] = 0.2 * log_q
        x[12] = 0.2 * log_r
        x[13] = 0.25 * (hi - 1 - lo)
        x[14] = _clip3(0.1 * (best - base_sp))
        x[15] = 0.5 * math.log(n)
        f = mlp(net, x)
        w.score[j] += f
        w.rank[j] += f

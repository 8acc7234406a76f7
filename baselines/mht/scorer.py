"""The learned scorer hook of mht (the `lmht` agent, agents/lmht.py): its features, its network
`Scorer`, and the compiled code that scores mht's candidates with it (docs/mht.md)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from baselines.jit_cache import guard

# Per pulse and parent hypothesis, `step` lists the candidates: track i after m misses, track i
# restarting, spurious.  Their hand-written log-likelihood increments plus look-ahead change,
# base_j = rank_j - (score_b + ahead_b), are the logits of mht's local choice.  `_learned` adds a
# learned f(x_j) - f(x_spurious) to every candidate's score (so to its rank too; the spurious
# candidate's stays mht's).  The difference matters: a local softmax is blind to a term shared by a
# parent's candidates, so the part of f constant over them is not learned -- yet it would shift that
# parent's score against the other parents' (features 12-13 differ between hypotheses).  f is one
# small ReLU network shared by all candidates of every kind, over the per-candidate features x_j below
# (no source index among them: the scorer is permutation-equivariant over tracks, the spurious
# candidate flagged by a kind bit and described by scene features).  An "off" scorer (`Scorer.off()`,
# w1 with no rows) is never called, so mht's labels stay bit-identical.
#
# Features (FEATURES, version FEATURE_VERSION; scaled to O(1)):
#   0-2  kind: a hit, a restart, spurious
#   3    |z|, z = e / sqrt(S) (hit: the normalised innovation).  Not its sign: along the true labelling a
#        pulse before a track's predicted arrival is more often another source's (the track's own is
#        still to come) -- a bias that holds only on the right hypothesis, and that the beam's wrong
#        ones (a track that has let its pulse pass) would exploit
#   4    z^2 / 4
#   5    log(sqrt(S) / T) / 5 (hit: the prediction's spread relative to the period)
#   6    log(1 + m): m misses before a hit, or the arrivals silent before a restart
#   7    log(1 + arrivals) / 3 of the track so far
#   8    (base_j - base_spurious) / 10, clipped to +-3 (mht's own log-likelihood ratio to spurious)
#   9    log(sqrt(P_TT) / T) / 5, the track's period uncertainty
#   10   log q / 5, the miss probability in use
#   11   log r / 5, the spurious rate per source pulse in use
#   12   the number of track candidates of this parent / 4
#   13   (max_j base_j - base_spurious) / 10, clipped to +-3: how well the pulse is explained at all
#   14   log(N) / 2, N the sources
# Not the look-ahead change h' - h on its own: given it, the local loss learns to cancel ~40 % of it
# (the look-ahead's pulses are counted again when taken), which is right for one hypothesis and
# wrong for the beam, where the look-ahead is what keeps two tracks from swapping at their start.
# For the same reason a track's first pulse keeps mht's score: which of two tracks of like periods
# starts on which pulse train is a whole-hypothesis choice the local loss does not see (trained
# there, the scorer swapped two such tracks of an 8-source pulse file of tests/test_lmht.py: accuracy
# 0.68, mht 0.99).

FEATURES = ("hit", "restart", "spurious", "abs_z", "z2", "log_spread", "log_misses", "log_arrivals", "llr_spurious",
            "log_period_std", "log_q", "log_r", "candidates", "best_llr", "log_sources")
N_FEATURES = len(FEATURES)
FEATURE_VERSION = 1
# the features equal for every candidate of a pulse, of one parent, and a candidate's own: their
# hidden-layer terms are summed once per pulse, per parent, per candidate
_PULSE = tuple(FEATURES.index(f) for f in ("log_q", "log_r", "log_sources"))
_PARENT = tuple(FEATURES.index(f) for f in ("candidates", "best_llr"))
_OWN = tuple(f for f in range(N_FEATURES) if f not in _PULSE + _PARENT)


class Scorer(NamedTuple):
    """f(x) = w2 . relu(clip(x, lo, hi) W1 + b1) + b2 (W1: (N_FEATURES, H), b1: (H,), w2: (H,), b2: (1,);
    lo, hi: (N_FEATURES,), the range of the training features: a scene unlike them (a jitter far
    smaller than any trained on) is scored as the nearest trained one, not by a ReLU's extrapolation)."""

    lo: np.ndarray
    hi: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray

    @classmethod
    def off(cls) -> Scorer:
        return cls(np.zeros(N_FEATURES), np.zeros(N_FEATURES), np.zeros((0, N_FEATURES)), np.zeros(0), np.zeros(0),
                   np.zeros(1))


class FlatScorer(NamedTuple):
    """A `Scorer` in one float64 buffer, lo, hi, w1, b1, w2, b2 in turn (w1: rows x cols; b1 and w2: `hidden`):
    one array for numba to unbox on each driver call, not six (`state.Flat`)."""

    f: np.ndarray
    rows: int
    cols: int
    hidden: int

    @classmethod
    def of(cls, net: Scorer) -> FlatScorer:
        rows, cols = net.w1.shape
        if net.lo.shape != (N_FEATURES,) or net.hi.shape != (N_FEATURES,) or net.b1.shape != net.w2.shape \
                or net.b2.shape != (1,):
            raise ValueError(f"not a scorer's shapes: {[a.shape for a in net]}")
        return cls(np.concatenate([a.ravel() for a in net]).astype(np.float64), rows, cols, net.b1.shape[0])


def scorer_views(f: np.ndarray, rows: int, cols: int, hidden: int) -> Scorer:
    """The Scorer whose arrays are f's parts (`FlatScorer`)."""
    w = 2 * N_FEATURES + rows * cols
    return Scorer(f[:N_FEATURES], f[N_FEATURES:2 * N_FEATURES], f[2 * N_FEATURES:w].reshape((rows, cols)),
                  f[w:w + hidden], f[w + hidden:w + 2 * hidden], f[w + 2 * hidden:w + 2 * hidden + 1])


@njit(cache=True, nogil=True)
def mlp(net, x, acc):
    """f(x) for one feature row (acc: (H,) work array)."""
    acc[:] = net.b1
    for f in range(x.shape[0]):
        v = min(max(x[f], net.lo[f]), net.hi[f])
        for u in range(acc.shape[0]):
            acc[u] += v * net.w1[f, u]
    out = net.b2[0]
    for u in range(acc.shape[0]):
        if acc[u] > 0.0:
            out += acc[u] * net.w2[u]
    return out


@njit(cache=True, nogil=True)
def _clip3(v):
    return min(3.0, max(-3.0, v))


@njit(cache=True, nogil=True, inline="always")
def _hidden_of(net, features, x, acc):
    """acc += the first layer's terms of `features` (indices) of the row x, clipped as `mlp` clips."""
    for f in features:
        v = min(max(x[f], net.lo[f]), net.hi[f])
        if v != 0.0:  # most rows are sparse: a candidate has one kind bit, spurious no track features
            for u in range(net.w1.shape[1]):
                acc[u] += v * net.w1[f, u]


@njit(cache=True, nogil=True, inline="always")
def _output(net, acc):
    out = net.b2[0]
    for u in range(net.w2.shape[0]):
        if acc[u] > 0.0:
            out += acc[u] * net.w2[u]
    return out


@njit(cache=True, nogil=True)
def _pulse_terms(net, w, x_q, x_r, x_n):
    """Once per pulse, into w.hidden[2]: b1 plus the terms of the pulse's features (rates, sources); into
    w.hidden[3]: the terms of a spurious candidate's own features (its kind bit, the rest 0)."""
    base, sp = w.hidden[2], w.hidden[3]
    x = w.hidden[4, :N_FEATURES]
    for f in range(N_FEATURES):
        x[f] = 0.0
    x[2] = 1.0
    x[10] = x_q
    x[11] = x_r
    x[14] = x_n
    for u in range(net.b1.shape[0]):
        base[u] = net.b1[u]
        sp[u] = 0.0
    _hidden_of(net, _PULSE, x, base)
    _hidden_of(net, _OWN, x, sp)


@njit(cache=True, nogil=True, inline="always")
def _learned(net, w, lo, hi, score, ahead, arrivals, blk, x_q, x_r, x_n):
    """Features of the candidates lo..hi-1 of one parent (its spurious candidate last) into w.feat[:hi - lo],
    and f(x_j) - f(x_spurious) added to their scores and ranks.  score, ahead: the parent's; arrivals,
    blk: its tracks'; x_q, x_r, x_n: the pulse's features (`_pulse_terms` has summed their terms).  f
    is `mlp` with its first layer summed in parts: the pulse's, the parent's, a candidate's own."""
    base_sp = w.rank[hi - 1] - score - ahead
    best = base_sp
    for j in range(lo, hi - 1):
        best = max(best, w.rank[j] - score - ahead)
    x_c, x_b = 0.25 * (hi - 1 - lo), _clip3(0.1 * (best - base_sp))
    prev = -1  # a track's candidates are consecutive: its own features are computed once
    x_a = x_p = log_t2 = 0.0
    for j in range(lo, hi):
        x = w.feat[j - lo]
        for f in range(N_FEATURES):
            x[f] = 0.0
        i = w.source[j]
        if i < 0:
            x[2] = 1.0
        else:
            if i != prev:
                prev = i
                log_t2 = 2.0 * math.log(blk[i, 0])
                x_a = math.log1p(arrivals[i]) / 3.0
                x_p = 0.1 * (math.log(max(blk[i, 2], 1e-300)) - log_t2)
            if w.steps[j] < 0:  # a restart after -steps silent arrivals
                x[1] = 1.0
                x[6] = math.log1p(-w.steps[j])
            else:
                x[0] = 1.0
                z = w.e[j] / math.sqrt(w.s[j])
                x[3] = abs(z)
                x[4] = 0.25 * z * z
                x[5] = 0.1 * (w.log_s[j] - log_t2)
                if w.steps[j] >= 2.0:  # misses (a jump's candidate: steps + 0.5)
                    x[6] = math.log(math.floor(w.steps[j]))
            x[7] = x_a
            x[8] = _clip3(0.1 * (w.rank[j] - score - ahead - base_sp))
            x[9] = x_p
        x[10] = x_q
        x[11] = x_r
        x[12] = x_c
        x[13] = x_b
        x[14] = x_n
    shared, acc, sp = w.hidden[0], w.hidden[1], w.hidden[3]
    h = net.b1.shape[0]
    for u in range(h):
        shared[u] = w.hidden[2, u]
    _hidden_of(net, _PARENT, w.feat[hi - 1 - lo], shared)
    for u in range(h):
        acc[u] = shared[u] + sp[u]
    f_sp = _output(net, acc)
    for j in range(lo, hi - 1):
        if arrivals[w.source[j]] == 0:  # a track's first pulse: mht's own score (module comment above)
            continue
        for u in range(h):
            acc[u] = shared[u]
        _hidden_of(net, _OWN, w.feat[j - lo], acc)
        f = _output(net, acc) - f_sp
        w.score[j] += f
        w.rank[j] += f



guard(globals())

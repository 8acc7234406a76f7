"""`mht`: a gated multi-hypothesis tracker (hypothesis-oriented MHT as a beam search) on the DLM of MK94.

A hypothesis is one labelling of the pulses so far; its state is MK94's per-source KF blocks
(`baselines.kalman`: (T, tau) and their 2x2 covariance, (2.7)-(2.8)), the number of arrivals each
source has made (pulses taken plus arrivals missed) and its log-likelihood score.  Per pulse y:

- Gating.  For every hypothesis and source, the source's next arrival nearest to y is its k-th
  predicted arrival after its last pulse, k = max(1, round((y - tau) / T)); k - 1 arrivals were
  missed (k = 1 is tried too, for a period still uncertain).  The k-step prediction of (2.8) (closed
  form, cumulative jitter added k times; with `drift` > 0 the period's random walk too, `_drift_terms`)
  gives the innovation e and its variance S = H P H' + R
  (2.15); the source is a candidate only when e^2 <= gate^2 S.  Only gated candidates are scored,
  looked ahead and updated, so the expensive part of a pulse grows with the number of gated
  candidates, not with the number of sources N (the gate test itself is a few flops per source).
- Agile periods (`jump` > 0).  A hit is a candidate twice: as it is (score + log(1 - p)) and with the
  track's period jumping after it (score + log p, P_TT += (jump T)^2; p = _JUMP_P): a switching DLM
  whose hypotheses choose when a period moves, so a drifting, sliding or wobulated PRI is followed
  while a constant one keeps its certainty.  With `jump_z` a jump may follow only a hit at least that
  many deviations off (p = 0 after the others): the evidence a period moved, and far fewer candidates.
  (A random walk on every period, `drift`, follows the
  agile PRIs too, but lets two tracks of near-equal periods swap where their trains cross.)
- Scores (proper log-likelihoods, densities per unit time).  "Source i after m = k - 1 misses":
  log(1 - q) + m log q + log N(e; 0, S), q the miss probability (an explicit per-arrival miss), a
  long run of misses costing at most `log p_gap`.  "Spurious": log rho, rho the intensity of DM89's
  Bernoulli spurious impulses read as a Poisson stream: spurious_rate r (per source pulse) times
  the sources' pulse rate sum_i 1/T_i.  Comparing the two is Theorem 1's MAP test (21)-(24) made
  part of the hypothesis score instead of a hard decision.
- Look-ahead ranking (MK94 III's idea: judge an assignment by the errors that follow it).  Pulses
  are buffered (the policy's lag) so that, when a track takes a pulse, a small tree search over the
  buffered pulses scores its next `look` arrivals (`_future`); children are ranked by score plus the
  sum of their tracks' look-ahead scores.  A pulse given to the wrong track then loses at once,
  instead of a period later when the beam has long forgotten the alternative.
- Beam.  The best `beam` distinct children survive.  Two children whose sources all last fired on
  the same pulses continue identically up to their period estimates, so only the better is kept
  (the survivor rule of MK94's FDP (3.2)); they are found by a Zobrist hash of the per-source last
  pulses.
- Fixed lag and N-scan pruning.  Pulse k - nscan is labelled with the best hypothesis's label for it,
  and every hypothesis disagreeing on that pulse is dropped (N-scan pruning), so later decisions are
  consistent with earlier ones.
- Track initiation.  In dense scenes the first arrivals of many sources fall within each other's
  phase gates, and a tracker without look-ahead lets a neighbour capture a source's first pulse.  A
  track's first pulse is judged by `look_start` (6) arrivals ahead, and until the longest prior period
  has passed the beam is `start_beam` wide.  In a crowded start (32 sources: a first arrival's gate
  holds ~20 pulses) that is not enough: each track's 6-arrival look-ahead, judged alone, finds a
  neighbour's pulse train (or a harmonic of one) about as good as its own.  There the tracks are
  started jointly (`_initiate`): each track's best chain of arrivals over the whole buffered start
  (`look_init` (16) periods of the longest source, at most lag - nscan pulses), the tracks in order of
  prior period (a slow track's chain may be a harmonic of a faster source's train, never the
  reverse), each track's pulses then taken, pairs of tracks whose first gates overlap re-started
  jointly (a greedy assignment with pairwise re-starts), and each started track's prior becomes its
  chain's first pulse and period.
- Restart (MK94 VI-C-3's dropouts and onsets).  A track silent for `dead` arrivals in a row may
  restart at a pulse: the source was off and is back, log p_gap + log(1/T) (a phase uniform over its
  period), its period kept (or reset to the prior when it has left the prior by more than 2
  deviations: a captured track), judged by `look_restart` (default `look_start`) arrivals ahead.  A source that
  starts late, stops, or was captured by a neighbour at the start is picked up again.
- Prior-consistency test (`MHT._vet`).  A gated tracker trusts its priors: a prior that is confidently
  wrong (MK94 V-B-2's x_{1|0} = (60, 96) with Sigma = I for true periods (11, 80)) gates out the true
  pulses, and the spurious hypothesis, always available, explains them, so the track never learns (a
  prior T = 60 even locks on every fifth pulse of the T = 11 train).  FDP does not fail so: it gives
  every pulse to some source, so its KF learns the period from the errors (MK94's point).  So, once
  the start is buffered (the pulses up to pulse 0's initiation look-ahead, which the beam waits for
  anyway), the priors are tested against it: track by track, the best pulse chain from the prior
  over the whole window (`_explained`, pulses taken by earlier tracks excluded), and the pulses all
  the chains explain.  Under the priors the unexplained ones are spurious, r / (1 + r) of the pulses
  (r the stated rate, 0.05 if unknown); when more than that plus 10 % of the window is unexplained
  the priors are rejected and the tracks restarted from MK94's FDP run over the window
  (`_fdp_start`: a track's period the FDP's final estimate, its phase the first pulse FDP gave it),
  each then polished by its best chain over the window (phase its first pulse, period its KF fit, as
  `_initiate` starts a track: FDP's period carries its early mistakes, ~5 % on MK94 V-B-2's T = 80).
  The restart is kept only when it explains at least 10 % more of the window and leaves at most half
  as many pulses unexplained (on agile-v0 a constant-period KF explains a modulated train poorly
  whatever its start; a restart that explains little more is not taken).  FDP runs from the same
  priors, so track identities keep the priors' order (labels are scored against it).  The test needs
  priors that predict each source's pulses: it runs when every track's first arrival is predicted to
  within a period (its gate's half-width; a vague period or an unknown phase predicts nothing to test,
  the beam's own start handles those) and with at most 12 sources (FDP's full tree costs N^4 a
  pulse).  A start the priors explain is labelled exactly as without the test.
- Multi-start (`MHT._multistart`), when the priors predict no first arrival (a vague period or an
  unknown phase; at most 12 sources).  The priors then say little the beam can start from (MK94 VI-A-2's
  x_{1|0} = (4, 27) with Sigma = 10^6 I, VI-B's x_{1|0} = 1 for all three tracks), and the beam's own start
  is a gamble: a track locks on a harmonic (T = 90 for a T = 30 train, its other pulses called spurious),
  or two tracks of identical priors split one train.  Two things help.  (1) The relative frequencies
  pi_i (the priors' `source_prob`, MK94 IV-2's known a priori probabilities) predict each period from
  the window's pulse rate lambda: T_i = (1 - q) / (pi_i lambda), known to 10 %, combined with the
  stated period (a product of Gaussians): the informed prior (a uniform pi, MK94 VI-B's "no a priori
  information", is not used).  (2) Three whole initialisations -- the informed prior, the stated priors
  and FDP's start (`_fdp_start`) -- each start a beam over the buffered window; each beam's labelling of
  the window is scored alike (`_loglik`: the labelling's log-likelihood, as `_step` scores it, under
  the informed prior) and the likeliest starts the real beam.  A track that labelling gave fewer than 3
  pulses, or whose period over the window left the informed prior's gate, learnt nothing and starts from
  the informed prior, which is also the prior a restarting track falls back on.  Last, tracks of
  exchangeable priors have no identity of their own: when the first label is due, each track reports the
  label whose informed period fits its estimate best (`_identities`, an assignment in log-period), so
  labels follow the priors where those are confident and the relative frequencies where they are not.
  The start costs three window-long beam runs once; the per-pulse cost is unchanged.
- Unknown rates.  A rate the priors do not state (NaN) is estimated online from the decided labels
  with a weak Beta prior (mean 0.05, worth 20 arrivals): q = (misses + 1) / (arrivals + 20),
  r = (spurious + 1) / (arrivals + 20), each count held to what the pulse count allows (`_rates`: a
  lost track's pulses are not spurious pulses), and before the decisions cover the buffered start
  from that window's net excess or deficit of pulses over the sources' arrivals (`MHT._window_rates`).
  Stated rates are used as given (floored so a log stays finite).
- A track not started yet carries the look-ahead of its prior (`_prior_ahead`), as a started one
  carries that of its last update, when the priors predict every first arrival.

The driver (`_run`: a batch of buffered pulses per call, decisions and rate estimates included) is
compiled by numba (a core dependency: the blind deinterleavers' loops need it too); its interpreted
form (`.py_func`) gives identical labels (tested), ~100x slower.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from scipy.optimize import linear_sum_assignment

from baselines.kalman import DLMModel, prior_block
from deint_env.episode import Priors
from deint_env.errors import NotApplicable


_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
_Q_FLOOR = 1e-3  # miss probability floor: a merged or lost pulse stays explainable
_R_FLOOR = 1e-3  # spurious-rate floor of an estimated (or stated nonzero) rate
_R_ZERO = 1e-6  # the rate used when the priors state 0: a pulse no track can explain stays spurious
_PRIOR_MEAN, _PRIOR_WEIGHT = 0.05, 20.0  # the weak Beta prior of an unknown rate
_LEARNED = 3  # counts[_LEARNED] (after the decided hits, misses, spurious pulses): the misfit gate is open
# counts[_WINDOW:_WINDOW + 4]: the buffered start's hits, misses and spurious pulses by the prior chains that
# explain it (`MHT._vet`) and its pulses: unknown rates are estimated from them until decisions cover it
_WINDOW = 4
# mht's own restart and look-ahead depths (its defaults), also those of a closed misfit gate (`misfit`)
_DEAD, _LOOK = 3, 2
_HASH_BITS = 12  # Zobrist table: per source, 2^12 entries indexed by the last pulse's index
_LOG_2PI = math.log(2.0 * math.pi)
# block fields of the state array (per hypothesis, per source)
PERIOD, TAU, P_TT, P_TX, P_XX = range(5)


class Beam(NamedTuple):
    """A beam of up to `capacity` hypotheses (the first `size` are live).  blk: (B, N, 5) KF blocks;
    arrivals: (B, N) arrivals made (taken + missed); last: (B, N) index of the source's last pulse
    (-1 none); key: (B,) Zobrist hash of `last`; score: (B,) log-likelihood; h: (B, N) each track's
    look-ahead score, ahead: (B,) their sum; label, missed: (B, L) ring buffers over the last
    L = nscan + 1 pulses (label N = spurious; the misses before the pulse)."""

    blk: np.ndarray
    arrivals: np.ndarray
    last: np.ndarray
    key: np.ndarray
    score: np.ndarray
    h: np.ndarray
    ahead: np.ndarray
    label: np.ndarray
    missed: np.ndarray

    @classmethod
    def empty(cls, capacity: int, n: int, ring: int) -> Beam:
        return cls(np.zeros((capacity, n, 5)), np.zeros((capacity, n), np.int64), np.full((capacity, n), -1, np.int64),
                   np.zeros(capacity, np.uint64), np.zeros(capacity), np.zeros((capacity, n)), np.zeros(capacity),
                   np.zeros((capacity, ring), np.int64), np.zeros((capacity, ring), np.int64))


class Scratch(NamedTuple):
    """Per-pulse work arrays: the candidates (parent, source or -1, steps, score, rank, e, S, look-ahead;
    the learned scorer's features of one parent's candidates, row j - first), the look-ahead cache per source (last pulse, steps, value; `used`
    entries), the search stack, the learned scorer's work rows (`hidden`: a parent's hidden-layer sum, a
    candidate's, the pulse's, a spurious candidate's own terms, and a feature row), each candidate's
    log S, the children's order, and the look-ahead's pulse order."""

    parent: np.ndarray
    source: np.ndarray
    steps: np.ndarray
    score: np.ndarray
    rank: np.ndarray
    e: np.ndarray
    s: np.ndarray
    h: np.ndarray
    feat: np.ndarray
    cache_last: np.ndarray
    cache_steps: np.ndarray
    cache_val: np.ndarray
    used: np.ndarray
    stack: np.ndarray
    hidden: np.ndarray
    log_s: np.ndarray
    order: np.ndarray
    branch: np.ndarray

    @classmethod
    def empty(cls, candidates: int, n: int, look: int, hidden: int) -> Scratch:
        c = candidates
        return cls(np.zeros(c, np.int64), np.zeros(c, np.int64), np.zeros(c), np.zeros(c), np.zeros(c), np.zeros(c),
                   np.zeros(c), np.zeros(c), np.zeros((5 * n + 1, N_FEATURES)), np.zeros((n, _CACHE), np.int64),
                   np.zeros((n, _CACHE)), np.zeros((n, _CACHE)), np.zeros(n, np.int64),
                   np.zeros(((look + 1) * (_BRANCH + 1) + 2, 8)), np.zeros((5, max(hidden, N_FEATURES))), np.zeros(c),
                   np.zeros(c, np.int64), np.zeros(_BRANCH, np.int64))


class Settings(NamedTuple):
    """What the compiled driver needs besides the beam (one argument for numba)."""

    gate2: float
    jitter_var: float
    interval_var: float
    log_gap: float
    pulse_rate: float
    known_q: float  # NaN: estimate
    known_r: float  # NaN: estimate
    start_until: float  # track initiation lasts while pulses are earlier than this
    horizon_start: float  # look-ahead (time) buffered before a pulse is processed, during initiation
    horizon: float  # and after it
    beam: int
    start_beam: int
    nscan: int
    look_start: int  # arrivals looked ahead when a track takes its first pulse
    look_restart: int  # arrivals looked ahead when a track restarts
    look: int  # and later
    dead: int  # arrivals a track must have missed in a row before it may restart
    reserve: int  # lag - nscan: a pulse this far behind the newest is processed whatever the look-ahead
    initiate: bool  # joint track initiation on the buffered start (`_initiate`)
    look_init: int  # and the arrivals its pulse chains look ahead (at least: a chain covers the buffer)
    margin: float  # children ranked more than this (nats) below the best are dropped (inf: the beam only)
    drift: float  # a period's random walk: its change per arrival has deviation drift * T (0: a constant period)
    jump: float  # a period's jump after a hit (probability _JUMP_P): deviation jump * T (0: none)
    log_jump: float  # log _JUMP_P
    log_stay: float  # log(1 - _JUMP_P)
    jump_z2: float  # a jump is tried after a hit whose e^2 / S is at least this
    misfit: float  # the misfit gate opens once the decided labels reject the stated rates by this (nats)
    prior_ahead: bool  # the priors predict every first arrival: unstarted tracks carry its look-ahead (`_prior_ahead`)


# ---------------------------------------------------------------------------------------------------
# the learned scorer (the `lmht` agent, agents/lmht.py).  Kept in this file: numba caches a kernel
# keyed on its own file's content, with its callees compiled in, so a callee in another file could
# change without `_step`'s cache noticing.
# ---------------------------------------------------------------------------------------------------
# Per pulse and parent hypothesis, `_step` lists the candidates: track i after m misses, track i
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


_BRANCH = 3  # look-ahead: pulses tried per arrival (a window around the predicted arrival)
_INIT_BEAM, _INIT_BRANCH = 8, 5  # initiation: partial pulse chains kept per arrival, pulses tried per arrival
_CACHE = 8  # look-ahead values cached per source and pulse
_JUMP_P = 0.01  # a period jump's probability per hit (`jump`)
_INSERTION = 64  # children sorted by insertion up to this many candidates, else by argsort
# the prior-consistency test (`MHT._vet`)
_VET_MAX_SOURCES = 12  # FDP's full tree costs N^4 a pulse: larger scenes are not tested
_VET_SLACK = 0.1  # unexplained pulses allowed beyond the spurious rate, and the gain a restart must bring
_VET_LOOK = 256  # at most this many arrivals per chain
_RATE_REL = 0.1  # relative deviation of a period from the relative frequencies and the window's pulse rate


@njit(cache=True, nogil=True, inline="always")
def _drift_terms(drift, t, m):
    """A period's random walk in MK94's order (kalman.predict: tau' = tau + T, then T' = T + w, var w = q,
    q = (drift T)^2 for the current estimate T): what m predictions from a filtered block add to
    var tau_m, cov(T_m, tau_m) and var T_m.  tau_m = tau + m T + sum_{i<m} (m-1-i) w_i, so
    var tau_m += q sum_{k<m} k^2 = q (m-1) m (2m-1) / 6,  cov += q (m-1) m / 2,  var T_m += m q.
    With drift = 0 every term is 0.0, and adding it changes no bit."""
    q = (drift * t) * (drift * t)
    return q * ((m - 1.0) * m * (2.0 * m - 1.0) / 6.0), q * ((m - 1.0) * m / 2.0), q * m


@njit(cache=True, nogil=True)
def _future(toa, n_seen, k, t, tau, ptt, ptx, pxx, look, gate2, jitter_var, interval_var, drift, log_q, log_1mq, st,
            order):
    """The best log-likelihood of a track's next `look` arrivals after it took pulse k with the filtered
    block (t, tau, ptt, ptx, pxx): a small tree search over the buffered pulses in each arrival's gate
    (a hit: log(1 - q) + log N(e; 0, S), the KF updated (2.15); or a miss: log q, the KF coasted (2.8)).
    An arrival beyond the buffer ends the search (nothing known yet).  Depth-first with the explicit
    stack `st` (rows: t, tau, ptt, ptx, pxx, steps, total, depth); `order`: (_BRANCH,) work row."""
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
        d_xx, d_tx, d_tt = _drift_terms(drift, t, steps)
        p_tx = ptx + steps * ptt + d_tx
        p_xx = pxx + 2.0 * steps * ptx + steps * steps * ptt + steps * interval_var + d_xx
        s = p_xx + jitter_var
        pred = tau + steps * t
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
            g, r_s = e / s, jitter_var / s
            st[top, 0], st[top, 1], st[top, 2] = t + p_tx * g, pred + p_xx * g, ptt + d_tt - p_tx * p_tx / s
            st[top, 3], st[top, 4], st[top, 5] = p_tx * r_s, p_xx * r_s, 1.0
            st[top, 6] = total + log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
            st[top, 7] = depth + 1.0
            top += 1
    return best


@njit(cache=True, nogil=True)
def _chain(toa, end, j, blk, look, cfg, log_q, log_1mq, used, path, fit):
    """Track initiation: the best log-likelihood of a track (prior block `blk`) whose first arrival is
    pulse j, over its first look + 1 arrivals among pulses 0..end-1 not `used` by tracks already
    started: a beam search (_INIT_BEAM partial chains, the _INIT_BRANCH nearest unused pulses and a
    miss per arrival; a hit log(1 - q) + log N(e; 0, S), a miss log q; an arrival beyond pulse end-1
    ends the chain).  The best chain's pulses go to `path` (-1: a miss, -2: beyond the buffer), its
    final KF block to `fit`."""
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
            d_xx = _drift_terms(cfg.drift, t, steps)[0]
            s = pxx + 2.0 * steps * ptx + steps * steps * ptt + steps * iv + d_xx + jv
            pred = tau + steps * t
            half = math.sqrt(cfg.gate2 * s)
            if d == 0:
                c_par[nc], c_j[nc] = m, j
                e = toa[j] - pred
                c_v[nc] = tot[m] + log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
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
                d_xx, d_tx, d_tt = _drift_terms(cfg.drift, t, steps)
                s = pxx + 2.0 * steps * ptx + steps * steps * ptt + steps * iv + d_xx + jv
                p_tx = ptx + steps * ptt + d_tx
                p_xx = s - jv
                e = toa[jj] - (tau + steps * t)
                g, r_s = e / s, jv / s
                nst[new, 0], nst[new, 1] = t + p_tx * g, tau + steps * t + p_xx * g
                nst[new, 2], nst[new, 3] = ptt + d_tt - p_tx * p_tx / s, p_tx * r_s
                nst[new, 4], nst[new, 5] = p_xx * r_s, 1.0
                npth[new, d] = jj
            new += 1
        size = new
        st[:size], tot[:size], pth[:size] = nst[:size], ntot[:size], npth[:size]
    path[:] = pth[0]
    fit[:] = st[0, :5]
    return tot[0]


@njit(cache=True, nogil=True)
def _best_start(toa, end, blk, look, cfg, log_q, log_1mq, used, path, fit):
    """The best first pulse of a track (prior block `blk`) among the unused pulses in its first
    arrival's gate, and its chain's log-likelihood ratio (-inf: none)."""
    t, tau, ptt, ptx, pxx = blk[PERIOD], blk[TAU], blk[P_TT], blk[P_TX], blk[P_XX]
    s = pxx + 2.0 * ptx + ptt + cfg.interval_var + cfg.jitter_var
    half = math.sqrt(cfg.gate2 * s)
    lo = np.searchsorted(toa[:end], tau + t - half)
    hi = np.searchsorted(toa[:end], tau + t + half)
    best, best_j = -np.inf, -1
    for j in range(lo, hi):
        if not used[j]:
            v = _chain(toa, end, j, blk, look, cfg, log_q, log_1mq, used, path, fit)
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
    s = blk[P_XX] + 2.0 * blk[P_TX] + blk[P_TT] + cfg.interval_var + cfg.jitter_var
    e = y - (blk[TAU] + blk[PERIOD])
    return e * e <= cfg.gate2 * s


@njit(cache=True, nogil=True)
def _start_two(toa, end, bx, by, jx, jy, look, cfg, log_q, log_1mq, used, px, py, fx, fy, js):
    """Two tracks (prior blocks bx, by) started one after the other: x's chain from pulse jx, then y's
    from pulse jy among the pulses x's chain left (-1: the track's best first pulse, `_best_start`).
    Returns the chains' total log-likelihood (-inf: a track found no first pulse); their pulses go to
    px, py, their fits to fx, fy and their first pulses to js."""
    if jx < 0:
        jx = _best_start(toa, end, bx, look, cfg, log_q, log_1mq, used, px, fx)[1]
        if jx < 0:
            return -np.inf
    v = _chain(toa, end, jx, bx, look, cfg, log_q, log_1mq, used, px, fx)
    _mark(px, used, True)
    if jy < 0:
        jy = _best_start(toa, end, by, look, cfg, log_q, log_1mq, used, py, fy)[1]
    if jy >= 0:
        v += _chain(toa, end, jy, by, look, cfg, log_q, log_1mq, used, py, fy)
    else:
        v = -np.inf
    _mark(px, used, False)
    js[0], js[1] = jx, jy
    return v


@njit(cache=True, nogil=True)
def _initiate(toa, end, blk, cfg, log_q, log_1mq):
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
    other's gates are started anew in the best of six ways (`_start_two`: on their own first pulses, on
    each other's, or each on its best pulse left, each with either chain chosen first -- two sources of
    near-equal period and phase: the chain chosen first may hop onto the other's train, and the greedy
    gives the first track judged the train its prior fits best, not the pair's best assignment).  A
    started track's prior phase becomes its chain's first pulse (deviation sigma_w) and its period the
    chain's fit, so the beam starts it there.  Only tracks whose first arrival's gate is narrower than a
    period take part; a track with no pulse train of its own (`_own_train`) is left to the beam."""
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
        s = blk[i, P_XX] + 2.0 * blk[i, P_TX] + blk[i, P_TT] + cfg.interval_var + cfg.jitter_var
        if not 2.0 * math.sqrt(cfg.gate2 * s) < blk[i, PERIOD]:
            continue
        j = _best_start(toa, end, blk[i], look, cfg, log_q, log_1mq, used, path, fit)[1]
        if j < 0:
            continue
        first[i] = j
        _chain(toa, end, j, blk[i], look, cfg, log_q, log_1mq, used, path, fit)
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
                if not (started[a] and started[b] and _in_first_gate(blk[a], toa[first[b]], cfg)
                        and _in_first_gate(blk[b], toa[first[a]], cfg)):
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
                                       path2, fit, fit2, js)
                        ja, jb = js[0], js[1]
                    else:
                        v = _start_two(toa, end, blk[b], blk[a], jb, ja, look, cfg, log_q, log_1mq, used, path2,
                                       path, fit2, fit, js)
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
                _chain(toa, end, first[a], blk[b], look, cfg, log_q, log_1mq, used, path, fit)
                if _own_train(path):
                    _mark(path, used, True)
                    v, j = _best_start(toa, end, blk[a], look, cfg, log_q, log_1mq, used, path2, fit2)
                    if j >= 0:
                        _chain(toa, end, j, blk[a], look, cfg, log_q, log_1mq, used, path2, fit2)
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
def _explained(toa, end, blk, cfg, log_q, log_1mq, looks, fitted):
    """Prior-consistency test: the buffered pulses 0..end-1 the tracks (blocks `blk`) explain.  Track by
    track (in index order) its best pulse chain (`_best_start`, `looks[i]` arrivals: the whole window)
    among the pulses earlier tracks have not taken; its hits are taken.  Returns the pulses taken; a
    track whose chain is its own train (`_own_train`) gets in `fitted[i]` the block it starts from when
    restarted on it (as `_initiate` starts a track: phase the chain's first pulse, period its fit),
    the others `blk[i]`.  Also returns the arrivals the taken chains missed."""
    n = blk.shape[0]
    used = np.zeros(end, np.bool_)
    missed = 0
    for i in range(n):
        fitted[i] = blk[i]
        path = np.empty(looks[i] + 1, np.int64)
        fit = np.empty(5)
        v, j = _best_start(toa, end, blk[i], looks[i], cfg, log_q, log_1mq, used, path, fit)
        if j < 0:
            continue
        _chain(toa, end, j, blk[i], looks[i], cfg, log_q, log_1mq, used, path, fit)
        _mark(path, used, True)
        missed += np.sum(path == -1)
        if _own_train(path):
            var_t = 4.0 * fit[P_TT]
            fitted[i, PERIOD], fitted[i, TAU] = fit[PERIOD], toa[j] - fit[PERIOD]
            fitted[i, P_TT], fitted[i, P_TX], fitted[i, P_XX] = var_t, -var_t, cfg.jitter_var + var_t
    return int(np.sum(used)), int(missed)


@njit(cache=True, nogil=True)
def _loglik(toa, labels, blk, cfg, log_q, log_1mq, log_rho):
    """The log-likelihood of a labelling of toa under the tracks' prior blocks `blk`, scored as `_step`
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
            s = pxx + 2.0 * steps * ptx + steps * steps * ptt + steps * iv + _drift_terms(cfg.drift, t, steps)[0] + jv
            e = y - (tau + steps * t)
            v = log_1mq - 0.5 * (_LOG_2PI + math.log(s) + e * e / s)
            if steps > 1.0:
                v += max((steps - 1.0) * log_q, cfg.log_gap)
            if v > best:
                best, best_steps = v, steps
        restart = log_1mq + cfg.log_gap - math.log(blk[i, PERIOD])
        # the source was off and is back (after `dead` silent arrivals, as in `_step`): restart at y
        if y - tau >= (cfg.dead + 1.0) * (t + 4.0 * math.sqrt(ptt)) and restart > best:
            total += restart
            rt, rtt = _restart_period(t, ptt, blk[i, PERIOD], blk[i, P_TT])
            b[i, PERIOD], b[i, TAU], b[i, P_TT], b[i, P_TX], b[i, P_XX] = rt, y, rtt, 0.0, jv
            continue
        total += best
        steps = best_steps
        d_xx, d_tx, d_tt = _drift_terms(cfg.drift, t, steps)
        s = pxx + 2.0 * steps * ptx + steps * steps * ptt + steps * iv + d_xx + jv
        p_tx = ptx + steps * ptt + d_tx
        p_xx = s - jv
        g, r_s = (y - (tau + steps * t)) / s, jv / s
        b[i, PERIOD], b[i, TAU] = t + p_tx * g, tau + steps * t + p_xx * g
        b[i, P_TT], b[i, P_TX], b[i, P_XX] = ptt + d_tt - p_tx * p_tx / s, p_tx * r_s, p_xx * r_s
    return total


@njit(cache=True, nogil=True)
def _prior_ahead(toa, n_seen, c, cfg, log_q, log_1mq, w):
    """The look-ahead of the tracks not started yet (hypothesis 0 of beam `c`, before the first pulse): each
    track's best first arrival and `look_start` arrivals after it among the buffered pulses, from its prior
    block (`_future` from before pulse 0).  A started track carries the look-ahead of its last update; a
    track not started carried none (0), so a child starting it, whose look-ahead is a sum of log-densities
    (negative), ranked below the child calling its first pulse spurious, by the whole look-ahead: with the
    spurious rate at the unknown rate's prior mean (5 %), a dense scene's tracks of long period never
    started, their pulses all went spurious and the estimated rate ran away (issue #22).  With the prior's
    look-ahead, starting on the track's own first pulse costs nothing more than its hit there."""
    total = 0.0
    for i in range(c.blk.shape[1]):
        b = c.blk[0, i]
        if c.arrivals[0, i] == 0:
            c.h[0, i] = _future(toa, n_seen, -1, b[PERIOD], b[TAU], b[P_TT], b[P_TX], b[P_XX], cfg.look_start + 1,
                                cfg.gate2, cfg.jitter_var, cfg.interval_var, cfg.drift, log_q, log_1mq, w.stack,
                                w.branch)
        total += c.h[0, i]
    c.ahead[0] = total


@njit(cache=True, nogil=True)
def _restart_period(t, ptt, prior_t, prior_tt):
    """The period a restarting track starts from: its own estimate, unless that has left the prior by
    more than 2 prior deviations (a track captured by a neighbour), then the prior's."""
    if (t - prior_t) ** 2 > 4.0 * prior_tt:
        return prior_t, prior_tt
    return t, ptt


@njit(cache=True, nogil=True)
def _step(toa, n_seen, k, size, c, x, zob, prior, width, look, cfg, log_q, log_1mq, log_rho, w, net, learned):
    """Extend the beam `c` (size hypotheses) with pulse k into `x`; returns the new size.  Children are
    ranked by score + look-ahead (the sum of every track's look-ahead score), so an assignment whose
    track has no good continuation loses at once instead of a period later.  A learned scorer `net`
    (`Scorer`; none: w1 has no rows) corrects every candidate's score if `learned`."""
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
                d_xx, d_tx, d_tt = _drift_terms(cfg.drift, t, steps)
                s = (c.blk[b, i, P_XX] + 2.0 * steps * ptx + steps * steps * ptt + steps * interval_var + d_xx
                     + jitter_var)
                e = y - (tau + steps * t)
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
                    p_tx = ptx + steps * ptt + d_tx
                    p_xx = s - jitter_var
                    g, r_s = e / s, jitter_var / s
                    hv = _future(toa, n_seen, k, t + p_tx * g, tau + steps * t + p_xx * g,
                                 ptt + d_tt - p_tx * p_tx / s, p_tx * r_s, p_xx * r_s, depth, gate2, jitter_var,
                                 interval_var, cfg.drift, log_q, log_1mq, w.stack, w.branch)
                    if w.used[i] < _CACHE:
                        q = w.used[i]
                        w.cache_last[i, q], w.cache_steps[i, q], w.cache_val[i, q] = c.last[b, i], steps, hv
                        w.used[i] += 1
                w.parent[nc] = b
                w.source[nc] = i
                w.steps[nc] = steps
                ls = math.log(s)
                w.score[nc] = c.score[b] + log_1mq + miss - 0.5 * (_LOG_2PI + ls + e * e / s)
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
                        p_tx = ptx + steps * ptt + d_tx
                        p_xx = s - jitter_var
                        g, r_s = e / s, jitter_var / s
                        hj = _future(toa, n_seen, k, t + p_tx * g, tau + steps * t + p_xx * g,
                                     ptt + d_tt - p_tx * p_tx / s + qj, p_tx * r_s, p_xx * r_s, depth, gate2,
                                     jitter_var, interval_var, cfg.drift, log_q, log_1mq, w.stack,
                                     w.branch)
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
                                 gate2, jitter_var, interval_var, cfg.drift, log_q, log_1mq, w.stack, w.branch)
                    if w.used[i] < _CACHE:
                        q = w.used[i]
                        w.cache_last[i, q], w.cache_steps[i, q], w.cache_val[i, q] = -2, -1.0, hv
                        w.used[i] += 1
                w.parent[nc] = b
                w.source[nc] = i
                w.steps[nc] = -near  # negative: a restart after `near` arrivals
                w.score[nc] = c.score[b] + log_1mq + cfg.log_gap - math.log(prior[i, PERIOD])
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
            if x.key[o] == h:
                same = True
                for s_ in range(n):
                    want = k if s_ == i else c.last[b, s_]
                    if x.last[o, s_] != want:
                        same = False
                        break
                if same:
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
            jumped = w.steps[j] != steps
            t = c.blk[b, i, PERIOD]
            ptt = c.blk[b, i, P_TT]
            ptx = c.blk[b, i, P_TX]
            # (2.8) applied `steps` times: tau' = tau + steps T, P' = F^steps P F^steps' + Q (the period's
            # random walk, `_drift_terms`, in Q; w.s[j] holds its var tau term)
            d_xx, d_tx, d_tt = _drift_terms(cfg.drift, t, steps)
            p_tx = ptx + steps * ptt + d_tx
            p_xx = w.s[j] - jitter_var
            inv_s = 1.0 / w.s[j]
            g = w.e[j] * inv_s
            r_s = jitter_var * inv_s
            # (2.15), written as in kalman.update (P R / S: no cancellation)
            x.blk[out, i, PERIOD] = t + p_tx * g
            x.blk[out, i, TAU] = c.blk[b, i, TAU] + steps * t + p_xx * g
            x.blk[out, i, P_TT] = ptt + d_tt - p_tx * p_tx * inv_s
            if jumped:
                x.blk[out, i, P_TT] += (cfg.jump * t) * (cfg.jump * t)
            x.blk[out, i, P_TX] = p_tx * r_s
            x.blk[out, i, P_XX] = p_xx * r_s
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
def _rates(cfg, counts, span=0.0):
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
def _run(toa, n_seen, ended, k, size, cur, nxt, zob, prior, w, cfg, fit, counts, labels, n_labels, net):
    """Process pulses k, k+1, ... while their look-ahead is buffered (or their decision is due, or
    the stream `ended`): extend the beam, decide pulse k - nscan from the best hypothesis and prune
    the rest (N-scan).  Decided labels go to labels[n_labels:].  Returns (k, size, swapped, n_labels):
    `swapped` when the beam now lives in `nxt`."""
    n = cur.blk.shape[1]
    ring = cfg.nscan + 1
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
        if n_labels < counts[_WINDOW + 3]:  # decisions do not cover the buffered start yet: its chains' counts
            log_q, log_1mq, log_rho = _rates(cfg, counts[_WINDOW:], toa[counts[_WINDOW + 3] - 1] - toa[0])
        else:
            log_q, log_1mq, log_rho = _rates(cfg, counts, toa[n_labels - 1] - toa[0] if n_labels > 0 else 0.0)
        if k == 0:  # the pulses up to y + ahead (all buffered by now, whatever the batching)
            if cfg.initiate:
                end = min(cfg.reserve + 1, np.searchsorted(toa[:n_seen], y + ahead, side="right"))
                _initiate(toa, end, cur.blk[0], cfg, log_q, log_1mq)
            if cfg.prior_ahead:
                _prior_ahead(toa, n_seen, cur, cfg, log_q, log_1mq, w)
        if swapped:
            a, b = nxt, cur
        else:
            a, b = cur, nxt
        size = _step(toa, n_seen, k, size, a, b, zob, prior, width, c.look, c, log_q, log_1mq, log_rho, w, net,
                     counts[_LEARNED] == 1)
        swapped = not swapped
        decided = k - cfg.nscan
        if decided >= 0:
            slot = decided % ring
            label = b.label[0, slot]
            _count(counts, label, b.missed[0, slot], n)
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
            _count(counts, best.label[0, slot], best.missed[0, slot], n)
            labels[j] = best.label[0, slot]
        n_labels = n_seen
    return k, size, swapped, n_labels


@njit(cache=True, nogil=True)
def _misfit(cfg, counts):
    """How strongly the decided labels reject the stated miss and spurious rates (nats; 0 for fewer
    misses or spurious pulses than stated): the log-likelihood ratio of the observed rates against the
    stated ones (floored as `_rates` floors them; a rate the priors leave unknown is held to the weak
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
def _count(counts, label, missed, n):
    if label == n:
        counts[2] += 1
    else:
        counts[0] += 1
        counts[1] += missed


# Work arrays of finished policies by shape, for the next reset: fresh ones cost their page faults anew
# every episode (~0.3 ms for a 256-hypothesis start beam of 3 sources: 0.3 us a pulse of a 1000-pulse
# episode, more than the act calls)
_SPARE: dict[tuple[int, ...], list[tuple[Beam, Beam, Scratch]]] = {}
_SPARE_MAX = 2


@functools.lru_cache(maxsize=64)
def _zobrist(n: int) -> np.ndarray:
    """The Zobrist keys (per source, 2^_HASH_BITS random words), the same for every episode: made once
    per number of sources (reset runs per episode; making them took 54 us)."""
    rng = np.random.default_rng(0x5EED)
    return rng.integers(0, np.iinfo(np.int64).max, size=(n, 1 << _HASH_BITS), dtype=np.int64).astype(np.uint64)


class MHT:
    """Policy `mht`.  Parameters: `beam` (hypotheses kept), `start_beam` (kept during track
    initiation), `nscan` (pulses between a pulse and its decision: the N-scan depth), `look` (arrivals
    looked ahead to start a track), `lag` (the env lag: pulses are buffered so the initiation
    look-ahead sees `look` periods of the longest source, but never longer than lag - nscan pulses),
    `gate` (in innovation standard deviations), `p_gap` (a source switching off and on again: the most
    a run of misses costs), `rates` ("priors": the priors' missing/spurious rates, estimating those
    they leave unknown; "estimate": estimate both online whatever the priors say), `batch` (pulses
    buffered per call of the compiled driver; labels do not depend on it), `dead` (arrivals a track
    must have missed in a row before it may restart), `dense` (tracks are started jointly, `_initiate`,
    when every track's phase is known to within a period and the first arrivals' gates hold this many
    pulses on average: 32 sources of scale-v0 hold ~21, 16 sources ~8, core-v0 at most ~6, where the
    beam's own start is as good; 0: whenever the phases are known), `look_restart` (arrivals looked
    ahead to restart a silent track; default `look_start`), `look_init`
    (the joint start buffers this many periods of the longest source; each pulse chain it judges has
    at least this many arrivals and covers the buffered start), `margin` (children ranked more than this
    many nats below the best child are dropped: an adaptive beam, cheaper where one hypothesis leads
    clearly; inf: the fixed beam only), `margin_per_source` (the margin is at least this many nats per
    source: a hypothesis's score sums over its tracks, so more sources spread the children's scores
    wider), `per_source` (at most this many hypotheses per source are kept,
    rounded up, within `beam`: few sources leave fewer ambiguities to carry; inf: `beam`), `drift`
    (a period's random walk: the relative deviation of its change per arrival, `_drift_terms`; 0: a
    constant period, MK94's DLM; it lets tracks of near-equal periods swap where their trains cross),
    `jump` (a period jump after a hit, with probability _JUMP_P: its relative deviation; each hit is then
    a candidate twice, with and without the jump, and the hypotheses choose -- agile PRIs are
    followed while a constant period stays constant; 0: no jumps), `jump_z` (a jump only after a hit
    |e| >= jump_z sqrt(S); 0: after every hit).  `scorer`: a learned correction of the
    candidates' scores (`Scorer`, the `lmht` agent); None: the hand-written scores.  `misfit` (nats):
    the scorer and `dead`, `look`, `look_restart`, `jump` apply from the first pulse at which the
    decided labels reject the stated miss and spurious rates by at least this much (`_misfit`), to the
    episode's end; before it, where the model fits, mht's defaults (restarts after 3 silent arrivals
    judged `look_start` ahead, hits judged 2 ahead, no jumps); 0: from the start.  Priors that state
    merging (a coincidence resolution, which the hand-written likelihood leaves out) have them from the
    start.  `wide_from` (with `misfit`): from this many sources on, the search before the gate opens is
    also mht's own, `beam` hypotheses and no margin (`per_source` and the margins then narrow only the
    open gate's search); 0: never."""

    def __init__(self, beam: int = 32, start_beam: int = 256, nscan: int = 24, look_start: int = 6, look: int = _LOOK,
                 lag: int = 1024, gate: float = 4.0, p_gap: float = 1e-6, rates: str = "priors", batch: int = 64,
                 dead: int = _DEAD, dense: float = 12.0, look_init: int = 16, margin: float = math.inf,
                 margin_per_source: float = 0.0,
                 per_source: float = math.inf, look_restart: int | None = None, drift: float = 0.0,
                 jump: float = 0.0, jump_z: float = 0.0, misfit: float = 0.0, wide_from: int = 0,
                 scorer: Scorer | None = None):
        for name, v, lo in (("beam", beam, 1), ("start_beam", start_beam, 1), ("nscan", nscan, 0),
                            ("look_start", look_start, 0), ("look", look, 0), ("lag", lag, 0), ("batch", batch, 1),
                            ("dead", dead, 1), ("look_init", look_init, 1), ("wide_from", wide_from, 0)):
            if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= 100_000:
                raise ValueError(f"{name}={v!r} must be an integer in [{lo}, 100000]")
        if nscan > lag:
            raise ValueError(f"nscan={nscan} must be <= lag={lag}")
        if not gate > 0:
            raise ValueError(f"gate={gate!r} must be > 0")
        if not 0 < p_gap < 1:
            raise ValueError(f"p_gap={p_gap!r} must be in (0, 1)")
        if rates not in ("priors", "estimate"):
            raise ValueError(f"rates={rates!r} must be one of priors, estimate")
        self.beam, self.start_beam, self.nscan, self.lag = beam, max(start_beam, beam), nscan, lag
        self.reserve = lag - nscan
        self.look_start, self.look, self.dead = look_start, look, dead
        if look_restart is not None and (not isinstance(look_restart, int) or isinstance(look_restart, bool)
                                         or not 0 <= look_restart <= look_start):
            raise ValueError(f"look_restart={look_restart!r} must be an integer in [0, look_start={look_start}]")
        self.look_restart = look_start if look_restart is None else look_restart
        if not dense >= 0:
            raise ValueError(f"dense={dense!r} must be >= 0 (0: always start tracks jointly)")
        self.gate, self.p_gap, self.rates, self.batch = float(gate), float(p_gap), rates, batch
        self.dense, self.look_init = float(dense), look_init
        if not margin > 0:
            raise ValueError(f"margin={margin!r} must be > 0 (inf: no score threshold)")
        self.margin = float(margin)
        if not 0.0 <= margin_per_source < math.inf:
            raise ValueError(f"margin_per_source={margin_per_source!r} must be a finite number >= 0 (0: margin alone)")
        self.margin_per_source = float(margin_per_source)
        if not per_source > 0:
            raise ValueError(f"per_source={per_source!r} must be > 0 (inf: `beam` whatever the number of sources)")
        self.per_source = float(per_source)
        if not 0.0 <= drift < math.inf:
            raise ValueError(f"drift={drift!r} must be a finite number >= 0 (0: a constant period)")
        self.drift = float(drift)
        if not 0.0 <= jump < math.inf:
            raise ValueError(f"jump={jump!r} must be a finite number >= 0 (0: no period jumps)")
        self.jump = float(jump)
        if not 0.0 <= jump_z < math.inf:
            raise ValueError(f"jump_z={jump_z!r} must be a finite number >= 0 (0: a jump may follow every hit)")
        self.jump_z = float(jump_z)
        if not 0.0 <= misfit < math.inf:
            raise ValueError(f"misfit={misfit!r} must be a finite number >= 0 (0: open from the start)")
        self.misfit = float(misfit)
        self.wide_from = wide_from
        self.net = Scorer.off() if scorer is None else scorer

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if priors.blind:
            raise NotApplicable("mht needs priors (an anchored scenario)")
        n = self.n = priors.n_labels
        model = DLMModel.from_priors(priors, min_jitter=_MIN_JITTER_REL * float(np.min(priors.period)))
        # an unknown phase: the first arrival is somewhere in the first period
        known = np.isfinite(priors.phase)
        phase = np.where(known, priors.phase, 0.5 * priors.period)
        phase_std = np.where(known, priors.phase_std, priors.period / math.sqrt(12.0))
        b = prior_block(Priors(n_labels=n, period=priors.period, phase=phase, period_std=priors.period_std,
                               phase_std=phase_std))
        self.prior = np.ascontiguousarray(np.stack(list(b), axis=-1))
        self.cur, self.nxt, self.scratch = self._work_arrays()
        self.cur.blk[0] = self.prior
        self.size = 1
        self.zob = _zobrist(n)
        # the key of "no pulse yet": every source's entry for last = -1 (index mask)
        self.cur.key[0] = np.bitwise_xor.reduce(self.zob[:, -1])
        t_max = float(np.max(priors.period))
        stated = self.rates == "priors"
        # a dense start: the first arrivals' gates hold `dense` pulses or more on average (the sources'
        # pulse rate times the gate's width), so tracks are started jointly (`_initiate`) -- when every
        # track can take part (its first gate narrower than its period: a track whose phase is unknown
        # would compete for the pulses outside the joint assignment)
        p = self.prior
        first_s = p[:, P_XX] + 2.0 * p[:, P_TX] + p[:, P_TT] + model.interval_var + model.jitter_var
        width = 2.0 * self.gate * np.sqrt(first_s)
        initiate = (bool(np.all(width < p[:, PERIOD]))
                    and float(np.mean(width)) * float(np.sum(1.0 / priors.period)) >= self.dense)
        self.cfg = Settings(
            gate2=self.gate ** 2, jitter_var=model.jitter_var, interval_var=model.interval_var,
            log_gap=math.log(self.p_gap), pulse_rate=float(np.sum(1.0 / priors.period)),
            known_q=float(priors.missing_prob) if stated else math.nan,
            known_r=float(priors.spurious_rate) if stated else math.nan,
            start_until=float(np.max(phase + 4.0 * phase_std)) + t_max,
            horizon_start=(max(self.look_start, self.look_init if initiate else 0) + 0.5) * t_max * 1.05
            + 4.0 * float(np.max(phase_std)),
            horizon=(max(self.look, self.look_start, _LOOK if self.misfit > 0 else 0) + 0.5) * t_max * 1.05,
            beam=self.beam if math.isinf(self.per_source) else min(self.beam, math.ceil(self.per_source * n)),
            start_beam=self.start_beam, nscan=self.nscan, look_start=self.look_start, look_restart=self.look_restart,
            look=self.look, dead=self.dead, reserve=self.reserve, initiate=initiate, look_init=self.look_init,
            margin=max(self.margin, self.margin_per_source * n), drift=self.drift, jump=self.jump,
            log_jump=math.log(_JUMP_P), log_stay=math.log1p(-_JUMP_P), jump_z2=self.jump_z ** 2,
            misfit=0.0 if priors.coincidence_resolution > 0 else self.misfit,
            # only priors that predict every first arrival (the gate narrower than a period) promise a start: a
            # vague period or an unknown phase promises a chain anywhere, harmonics and other sources' trains
            # included, that a track's own start need not match (noise-free CM00 scenes lost every track)
            prior_ahead=bool(np.all(0.5 * width < p[:, PERIOD])))
        # the search while the misfit gate is closed
        self.fit = self.cfg._replace(dead=_DEAD, look=_LOOK, look_restart=self.look_start, jump=0.0, jump_z2=0.0)
        if 0 < self.wide_from <= n:  # a wider search where the model fits: dense scenes lose fewer tracks
            self.fit = self.fit._replace(beam=self.beam, margin=math.inf)
        self.priors, self.vetted = priors, False  # the prior-consistency test is still to run (`_vet`)
        # it runs when every track's first arrival is predicted to within a period (its gate's half-width; a
        # vague period or phase fails this): then the priors predict where each source's pulses are
        self.vettable = self.cfg.prior_ahead
        self.perm = np.arange(n + 1)  # the label each track reports (`_identities`); spurious stays n
        self.identify = None  # (periods, variances) the tracks' identities are to be settled by
        # decided hits, misses, spurious; whether the misfit gate is open (`_misfit`)
        self.counts = np.zeros(_WINDOW + 4, np.int64)
        self.toa = np.zeros(1024)
        self.labels = np.zeros(1024, np.int64)
        self.n_seen = self.n_labels = 0
        self.due: list[int] = []  # labels reported or ready to be (`_due`)
        self.wake = 1  # act calls `_wake` when n_seen reaches this
        self.k = 0  # next pulse to process
        self.called = 0  # pulses seen at the last driver call
        self.ended = False
        self.steps = 0

    def _work_arrays(self) -> tuple[Beam, Beam, Scratch]:
        """The two beams and the scratch for this episode: this policy's own or a finished one's of the same
        shape (`_SPARE`), cleared to what fresh ones hold, else fresh ones."""
        cap, n, ring = self.start_beam, self.n, self.nscan + 1
        look, hidden = max(self.look, self.look_start), self.net.b1.shape[0]
        key = (cap, n, ring, look, hidden)
        spare = _SPARE.get(key)
        if getattr(self, "work_key", None) == key:
            work = self.cur, self.nxt, self.scratch
        elif spare:
            work = spare.pop()
        else:
            self.work_key = key
            # per parent: up to two arrivals (each also with a period jump, `jump`) and a restart per source
            # (`_step`), and the spurious hypothesis
            return (Beam.empty(cap, n, ring), Beam.empty(cap, n, ring),
                    Scratch.empty(cap * (5 * n + 1), n, look, hidden))
        self.work_key = key
        for arrays in work:
            for a in arrays:
                a.fill(0)
        work[0].last.fill(-1)
        work[1].last.fill(-1)
        return work

    def __del__(self) -> None:
        # its work arrays go to the next policy of this shape (at most _SPARE_MAX sets are kept per shape)
        key = getattr(self, "work_key", None)
        if key is not None:
            spare = _SPARE.setdefault(key, [])
            # (a shallow copy of a policy shares its arrays: they are handed on once)
            if len(spare) < _SPARE_MAX and not any(w[0] is self.cur for w in spare):
                spare.append((self.cur, self.nxt, self.scratch))

    def act(self, obs: dict[str, Any]) -> int:
        # runs once a step (twice a pulse at the default lag): kept lean, the work is in the driver
        if obs["valid"]:
            n = self.n_seen
            self.toa[n] = obs["toa"][0]
            self.n_seen = n = n + 1
            if n >= self.wake:
                self._wake()
        elif not self.ended:
            self.ended = True
            if self.n_seen:
                self._run()
        t = self.steps - self.lag  # step t labels pulse t - lag
        self.steps += 1
        if t < 0:
            return 0
        if t < len(self.due):
            return self.due[t]
        return self._due(t)

    def _wake(self) -> None:
        """The buffer grown when full; the driver called every `batch` pulses (its call costs far more than
        a pulse) or when a decision is due; `wake` set to the next pulse count needing either."""
        n = self.n_seen
        if n == self.toa.size:
            self.toa = np.concatenate([self.toa, np.zeros(n)])
            self.labels = np.concatenate([self.labels, np.zeros(n, np.int64)])
        if n - self.called >= self.batch or n - 1 - self.k >= self.reserve:
            self._run()
        self.wake = min(self.toa.size, self.called + self.batch, self.k + 1 + self.reserve)

    def _due(self, t: int) -> int:
        """Label t once `due` (the reported labels, Python ints: a list index is the cheapest step) lacks it:
        the labels decided since are appended, the tracks' identities settled first if they are pending."""
        if t >= self.n_labels:
            return 0
        if self.identify is not None:
            # the tracks' identities from all the beam has seen when the first label is due
            self.perm[:self.n] = self._identities(self.labels[:self.n_labels], self.cur.blk[0], *self.identify)
            self.identify = None
        self.due.extend(self.perm[self.labels[len(self.due):self.n_labels]].tolist())
        return self.due[t]

    def _run(self) -> None:
        self.called = self.n_seen
        if not self.vetted:
            cfg, y0 = self.cfg, self.toa[0]
            ahead = cfg.horizon_start if y0 <= cfg.start_until else cfg.horizon
            # what the driver needs before it processes pulse 0 (`_run`): its look-ahead buffered, or the lag's
            # end, or the stream's
            if self.ended or self.n_seen - 1 >= cfg.reserve or self.toa[self.n_seen - 1] >= y0 + ahead:
                self.vetted = True
                end = min(cfg.reserve + 1, int(np.searchsorted(self.toa[:self.n_seen], y0 + ahead, side="right")))
                self._vet(end)
        self.k, self.size, swapped, self.n_labels = _run(
            self.toa, self.n_seen, self.ended, self.k, self.size, self.cur, self.nxt, self.zob, self.prior,
            self.scratch, self.cfg, self.fit, self.counts, self.labels, self.n_labels, self.net)
        if swapped:
            self.cur, self.nxt = self.nxt, self.cur

    def _vet(self, end: int) -> None:
        """The prior-consistency test and the data-driven restart, or for priors that predict no first
        arrival the multi-start (see the module docstring): the first `end` pulses (what the driver has
        buffered before it labels pulse 0) against the priors."""
        n, cfg = self.n, self.cfg
        unknown = math.isnan(cfg.known_q) or math.isnan(cfg.known_r)
        if end < 2 * n or not (n <= _VET_MAX_SOURCES or (unknown and self.vettable)):
            return
        if not self.vettable:
            self._multistart(end)
            return
        toa = self.toa[:end]
        log_q, log_1mq, _ = _rates(cfg, self.counts)
        fitted = np.empty_like(self.prior)
        explained, missed = _explained(toa, end, self.prior, cfg, log_q, log_1mq, self._looks(toa, self.prior), fitted)
        self._window_rates(end, explained, missed)
        # the pulses the sources are not expected to explain: spurious ones, r per source pulse (an unknown
        # r the window's net excess of pulses: read as the weak prior's 5 %, it let a dense start's priors
        # pass that left a source unexplained -- 0.91 of 8 sources' labels right, 0.97 when told 0)
        r = cfg.known_r
        if math.isnan(r):
            r = self.counts[_WINDOW + 2] / max(self.counts[_WINDOW] + self.counts[_WINDOW + 1], 1)
        allowed = end * (r / (1.0 + r) + _VET_SLACK)
        if n > _VET_MAX_SOURCES or end - explained <= allowed:
            return
        blk = self._fdp_start(toa)
        again, missed = _explained(toa, end, blk, cfg, log_q, log_1mq, self._looks(toa, blk), fitted)
        # the restart must explain 10 % more of the window and half of what the priors left unexplained; the
        # tracks start from their chains over the window from FDP's estimates (what the test has just found:
        # a period FDP learnt early from wrong pulses is polished by the chain's KF)
        if again - explained >= _VET_SLACK * end and end - again <= 0.5 * (end - explained):
            self.prior[:] = fitted
            self.cur.blk[0] = fitted
            self._window_rates(end, again, missed)

    def _window_rates(self, end: int, explained: int, missed: int) -> None:
        """Unknown rates are estimated from the buffered start until the decisions cover it: the weak prior
        alone (5 %) made spurious calls cheap while a dense start was searched, and its tracks lost their
        sources (8 sources, 800 pulses: 0.71 of the labels right, 0.78 with this, 0.80 told 0).  The
        chains of the start (`_explained`, one track at a time, greedy) bound the counts: the pulses they
        leave are at most the spurious ones, the arrivals they skip at most the misses.  In a dense start
        those come in pairs -- a chain takes a neighbour's near-coincident pulse, skips its own arrival and
        leaves its pulse -- which are no evidence of a missed or a spurious pulse; the pulse count is: pulses beyond
        the sources' arrivals (R span, plus half an arrival per source at the window's edges) are
        spurious, arrivals beyond the pulses missed.  So each count is the net one, within its bound."""
        if math.isnan(self.cfg.known_q) or math.isnan(self.cfg.known_r):
            arrivals = self.cfg.pulse_rate * (self.toa[end - 1] - self.toa[0]) + 0.5 * self.n
            spurious = min(end - explained, max(0, round(end - arrivals)))
            missed = min(missed, max(0, round(arrivals - end)))
            self.counts[_WINDOW:] = end - spurious, missed, spurious, end

    def _multistart(self, end: int) -> None:
        """Vague priors: the start chosen among whole initialisations by the likelihood of the buffered
        window (see the module docstring).  Each candidate's beam labels the window; the labellings are
        scored alike (`_loglik`, under the informed prior) and the likeliest candidate starts the beam.
        Its tracks are later given the labels whose informed periods fit them best (`_identities`)."""
        cfg = self.cfg
        toa = np.ascontiguousarray(self.toa[:end])
        log_q, log_1mq, log_rho = _rates(cfg, self.counts)
        rate, rate_var = self._rate_periods(toa)
        informed = self._rate_start(toa, rate, rate_var)
        cands = [informed, self._fdp_start(toa)]
        if not np.array_equal(informed, self.prior):  # the relative frequencies said something
            cands.append(self.prior.copy())
        best, best_ll = None, -np.inf
        for blk in cands:
            labels, fin = self._window(toa, blk)
            ll = _loglik(toa, labels, informed, cfg, log_q, log_1mq, log_rho)
            if ll > best_ll:
                best, best_ll = (blk, labels, fin), ll
        blk, labels, fin = best
        # a track the winning labelling gave fewer than 3 pulses of the window has learnt nothing from it, and
        # one whose period over the window left the informed prior's gate learnt a wrong period: they start
        # from the informed prior
        few = np.bincount(labels, minlength=self.n + 1)[:self.n] < 3
        far = (fin[:, PERIOD] - rate) ** 2 > cfg.gate2 * (rate_var + np.maximum(fin[:, P_TT], 0.0))
        blk = np.where((few | far)[:, None], informed, blk)
        self.prior[:] = informed
        self.cur.blk[0] = blk
        self.identify = rate, rate_var  # the tracks' identities are settled at the first label (`act`)

    def _window(self, toa: np.ndarray, blk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The beam started from blocks `blk` run over the window `toa` (as if the stream ended there): its
        labels and its best hypothesis's final blocks."""
        n, ring, cap = self.n, self.nscan + 1, self.start_beam
        cur, nxt = Beam.empty(cap, n, ring), Beam.empty(cap, n, ring)
        cur.blk[0] = blk
        cur.key[0] = self.cur.key[0]
        labels = np.zeros(toa.size, np.int64)
        _, _, swapped, _ = _run(toa, toa.size, True, 0, 1, cur, nxt, self.zob, blk, self.scratch, self.cfg, self.fit,
                                self.counts.copy(), labels, 0, self.net)
        return labels, (nxt if swapped else cur).blk[0].copy()

    def _rate_periods(self, toa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each track's period and its variance from the stated priors combined with the known relative
        frequencies pi_i (MK94 IV-2, the priors' `source_prob`): source i's pulses arrive at pi_i times
        the window's pulse rate lambda (less the spurious share), and a source emits (1 - q) / T_i, so
        T_i = (1 - q) / (pi_i lambda (1 - r / (1 + r))), known to _RATE_REL (the window's rate and merged
        pulses); the two Gaussians are multiplied."""
        pri = self.priors
        t, var = pri.period.astype(float), pri.period_std.astype(float) ** 2
        pi = np.asarray(pri.source_prob, dtype=float)
        # uniform pi is MK94 VI-B's "no a priori information" (pi_i = 1/4 for a PT run that assumes N = 4):
        # it tells no track from another, and its rate-implied period only divides the pulse rate by a guessed N
        if pi.size != self.n or not np.all(pi > 0) or np.all(pi == pi[0]) or toa[-1] <= toa[0]:
            return t, var
        q = 0.05 if math.isnan(self.cfg.known_q) else self.cfg.known_q
        r = 0.05 if math.isnan(self.cfg.known_r) else self.cfg.known_r
        lam = (toa.size - 1) / (toa[-1] - toa[0]) / (1.0 + r)
        t_rate = (1.0 - q) / (pi * lam)
        var_rate = (_RATE_REL * t_rate) ** 2
        var_c = 1.0 / (1.0 / var + 1.0 / var_rate)
        return var_c * (t / var + t_rate / var_rate), var_c

    def _rate_start(self, toa: np.ndarray, t: np.ndarray, var: np.ndarray) -> np.ndarray:
        """Prior blocks with the periods of `_rate_periods`; a phase the priors do not know to within the
        period is uniform over the first period after the window's first pulse."""
        pri = self.priors
        known = np.isfinite(pri.phase) & (pri.phase_std < t / math.sqrt(12.0))
        phase = np.where(known, pri.phase, toa[0] + 0.5 * t)
        phase_std = np.where(known, pri.phase_std, t / math.sqrt(12.0))
        b = prior_block(Priors(n_labels=self.n, period=t, phase=phase, period_std=np.sqrt(var), phase_std=phase_std))
        return np.ascontiguousarray(np.stack(list(b), axis=-1))

    def _identities(self, labels: np.ndarray, fin: np.ndarray, t: np.ndarray, var: np.ndarray) -> np.ndarray:
        """Which label each track reports: the assignment of tracks to the priors' labels that maximises
        the priors' log-density of the tracks' periods (in log-period: a period's prior N(t_i, var_i) and
        the track's estimate with its variance).  A track given fewer than 2 of the labels decided so far
        says nothing.  Tracks started from exchangeable priors (MK94 VI-B's x_{1|0} = 1 for all) are so told
        apart by the relative frequencies; distinct confident priors keep their order."""
        n = self.n
        cost = np.zeros((n, n))
        counts = np.bincount(labels[labels < n], minlength=n)
        for j in range(n):
            tj = fin[j, PERIOD]
            if counts[j] < 2 or not tj > 0:
                continue
            v = var / t ** 2 + max(fin[j, P_TT], 0.0) / tj ** 2
            cost[j] = -0.5 * (np.log(v) + (math.log(tj) - np.log(t)) ** 2 / v)
        rows, cols = linear_sum_assignment(-cost)
        perm = np.arange(n)
        perm[rows] = cols
        return perm

    def _looks(self, toa: np.ndarray, blk: np.ndarray) -> np.ndarray:
        """Arrivals a track's chain needs to cover the buffered window (at most `_VET_LOOK`)."""
        span = toa[-1] - toa[0]
        return np.minimum(np.ceil(span / blk[:, PERIOD]) + 1, _VET_LOOK).astype(np.int64)

    def _fdp_start(self, toa: np.ndarray) -> np.ndarray:
        """New prior blocks from MK94's FDP (`baselines.fdp`, as published) run over the buffered pulses:
        FDP gives every pulse to some source, so its KF learns a period from a wrong prior.  A track's
        period is the FDP's final estimate (variance 4x its own), its phase the first pulse the FDP gave it
        that lies on that estimate's grid of arrivals; a track given fewer than 3 pulses keeps its prior."""
        from baselines.fdp import CompiledFDPCore  # here: only a rejected prior needs it
        core = CompiledFDPCore(self.priors, "lookahead", False, "phase", math.inf)
        labels = core.decide_all(np.ascontiguousarray(toa), 3)
        state = core.best_state()
        blk = self.prior.copy()
        jv, iv, g2 = self.cfg.jitter_var, self.cfg.interval_var, self.cfg.gate2
        for i in range(self.n):
            mine = np.flatnonzero(labels == i)
            if mine.size < 3:
                continue
            t, last, var_t = state[i, PERIOD], state[i, TAU], state[i, P_TT]
            if not (t > 0.0 and math.isfinite(last) and var_t >= 0.0):  # lost (e.g. jitter beyond the period)
                continue
            m = np.round((last - toa[mine]) / t)
            resid = toa[mine] - (last - m * t)
            on = np.flatnonzero(resid ** 2 <= g2 * (jv + m * iv + m * m * var_t))
            first = toa[mine[on[0]] if on.size else mine[0]]
            var_t = 4.0 * var_t
            blk[i] = (t, first - t, var_t, -var_t, jv + var_t)  # tau = phi - T, as `_initiate` starts a track
        return blk

    def estimates(self) -> dict[str, np.ndarray]:
        blk, arr = self.cur.blk[0], self.cur.arrivals[0]
        period, phase = np.empty(self.n), np.empty(self.n)
        period[self.perm[:self.n]] = blk[:, PERIOD]
        phase[self.perm[:self.n]] = blk[:, TAU] - (np.maximum(arr, 1) - 1) * blk[:, PERIOD]
        return {"period": period, "phase": phase}

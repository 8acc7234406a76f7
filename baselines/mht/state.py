"""mht's state: the block fields, its constants, and the arrays the compiled kernels work on (docs/mht.md)."""

from __future__ import annotations

import math
import typing
from typing import NamedTuple

import numpy as np

from baselines.mht.scorer import N_FEATURES

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
_BRANCH = 3  # look-ahead: pulses tried per arrival (a window around the predicted arrival)
_INIT_BEAM, _INIT_BRANCH = 8, 5  # initiation: partial pulse chains kept per arrival, pulses tried per arrival
_CACHE = 8  # look-ahead values cached per source and pulse
_JUMP_P = 0.01  # a period jump's probability per hit (`jump`)
_INSERTION = 64  # children sorted by insertion up to this many candidates, else by argsort


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
    initiate: bool  # joint track initiation on the buffered start (`initiate`)
    look_init: int  # and the arrivals its pulse chains look ahead (at least: a chain covers the buffer)
    margin: float  # children ranked more than this (nats) below the best are dropped (inf: the beam only)
    drift: float  # a period's random walk: its change per arrival has deviation drift * T (0: a constant period)
    jump: float  # a period's jump after a hit (probability _JUMP_P): deviation jump * T (0: none)
    log_jump: float  # log _JUMP_P
    log_stay: float  # log(1 - _JUMP_P)
    jump_z2: float  # a jump is tried after a hit whose e^2 / S is at least this
    misfit: float  # the misfit gate opens once the decided labels reject the stated rates by this (nats)
    prior_ahead: bool  # the priors predict every first arrival: unstarted tracks carry its look-ahead (`prior_ahead`)


# Settings as numba sees them: one record per Settings, packed in an array.  A NamedTuple argument is
# unboxed field by field on every call (~5 us for Settings' 28 fields); an array of records is one buffer
# (~0.4 us): at lag 3 the driver is called once a pulse, where cfg and fit cost mht a third of its time.
SETTINGS = np.dtype((np.record, [(name, {float: np.float64, int: np.int64, bool: np.bool_}[kind])
                                 for name, kind in typing.get_type_hints(Settings).items()]), align=True)


def pack(*rows: Settings) -> np.ndarray:
    """`rows` as an array of `SETTINGS` records (each row's fields by name, as numba's code reads them)."""
    return np.array([tuple(r) for r in rows], SETTINGS)


# The beams and the scratch as flat buffers (the scorer: `scorer.FlatScorer`).  numba unboxes every array argument on every call
# (~0.2 us each): as NamedTuples of arrays, the driver's two beams, scratch and scorer were 42 arrays, 11 us
# an empty call -- half of mht's time at lag 3, where the driver runs once a pulse.  Each set now lives in
# two buffers (float64, int64) that the driver views as the NamedTuples the kernels take (`beam_views`,
# `scratch_views`, `scorer_views`: plain functions, compiled in kernels.py, run as they are by Python).


class Flat(NamedTuple):
    """A Beam's or the Scratch's arrays laid out in two buffers: f (float64), i (int64)."""

    f: np.ndarray
    i: np.ndarray


def beam_views(f: np.ndarray, i: np.ndarray, cap: int, n: int, ring: int) -> Beam:
    """The Beam of `cap` hypotheses, n sources and ring L whose arrays are f[:cap (6n + 2)] and
    i[:cap (2n + 1 + 2L)] (`new_beam`)."""
    a, r = cap * n, cap * ring
    blk = f[:5 * a].reshape((cap, n, 5))
    score = f[5 * a:5 * a + cap]
    h = f[5 * a + cap:6 * a + cap].reshape((cap, n))
    ahead = f[6 * a + cap:6 * a + 2 * cap]
    arrivals = i[:a].reshape((cap, n))
    last = i[a:2 * a].reshape((cap, n))
    key = i[2 * a:2 * a + cap].view(np.uint64)
    label = i[2 * a + cap:2 * a + cap + r].reshape((cap, ring))
    missed = i[2 * a + cap + r:2 * a + cap + 2 * r].reshape((cap, ring))
    return Beam(blk, arrivals, last, key, score, h, ahead, label, missed)


def new_beam(cap: int, n: int, ring: int) -> tuple[Flat, Beam]:
    """A fresh beam (zeros, no source's last pulse: -1): its buffers and their views."""
    flat = Flat(np.zeros(cap * (6 * n + 2)), np.zeros(cap * (2 * n + 1 + 2 * ring), np.int64))
    beam = beam_views(flat.f, flat.i, cap, n, ring)
    beam.last.fill(-1)
    return flat, beam


def scratch_views(f: np.ndarray, i: np.ndarray, c: int, n: int, look: int, hidden: int) -> Scratch:
    """The Scratch for c candidates, n sources, `look` arrivals looked ahead and a scorer's `hidden` units,
    whose arrays are f and i (`new_scratch`)."""
    steps, score, rank, e, s, h = f[:c], f[c:2 * c], f[2 * c:3 * c], f[3 * c:4 * c], f[4 * c:5 * c], f[5 * c:6 * c]
    o = 6 * c
    feat = f[o:o + (5 * n + 1) * N_FEATURES].reshape((5 * n + 1, N_FEATURES))
    o += (5 * n + 1) * N_FEATURES
    cache_steps = f[o:o + n * _CACHE].reshape((n, _CACHE))
    cache_val = f[o + n * _CACHE:o + 2 * n * _CACHE].reshape((n, _CACHE))
    o += 2 * n * _CACHE
    rows = (look + 1) * (_BRANCH + 1) + 2  # the look-ahead's search stack
    stack = f[o:o + rows * 8].reshape((rows, 8))
    o += rows * 8
    width = max(hidden, N_FEATURES)
    work = f[o:o + 5 * width].reshape((5, width))
    log_s = f[o + 5 * width:o + 5 * width + c]
    parent, source, order = i[:c], i[c:2 * c], i[2 * c:3 * c]
    cache_last = i[3 * c:3 * c + n * _CACHE].reshape((n, _CACHE))
    o = 3 * c + n * _CACHE
    used = i[o:o + n]
    branch = i[o + n:o + n + _BRANCH]
    return Scratch(parent, source, steps, score, rank, e, s, h, feat, cache_last, cache_steps, cache_val, used, stack,
                   work, log_s, order, branch)


def new_scratch(c: int, n: int, look: int, hidden: int) -> tuple[Flat, Scratch]:
    """A fresh scratch: its buffers and their views."""
    floats = 7 * c + (5 * n + 1) * N_FEATURES + 2 * n * _CACHE + 8 * ((look + 1) * (_BRANCH + 1) + 2) + 5 * max(hidden, N_FEATURES)
    flat = Flat(np.zeros(floats), np.zeros(3 * c + n * _CACHE + n + _BRANCH, np.int64))
    return flat, scratch_views(flat.f, flat.i, c, n, look, hidden)

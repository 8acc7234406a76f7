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

"""Blind deinterleaving of one window of pulses: detect a PRI, extract its train, repeat.

1. A detector (CDIF, SDIF or the PRI transform) proposes PRI candidates from the pulses still free;
   the sequence search tries them smallest first and the first acceptable train is removed; then
   detection starts again on the pulses left (the loop of Mardia and of Milojevic & Popovic), until
   no candidate gives a train.
2. Trains of one period (within 4 standard deviations of their line fits) are sub-trains of one
   stagger (or a constant train extracted at a multiple of its PRI) and become one train.
3. Re-association (ours; `align=False` skips it): the greedy walks settle each pulse once, so where
   trains cross a pulse may have gone to the wrong one.  Each train's estimated emission schedule
   (its fitted lattice, or its own pulses for a modulated train) is extended over the window and the
   pulses are aligned to the union of the schedules by the MAP alignment `genie` uses with the true
   schedule (`baselines.genie.genie_labels`), here with estimated parameters only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable, NamedTuple

import numpy as np

from baselines.blind.histograms import Candidate
from baselines.blind.pri_models import line_fit, single_train_model, stagger_model
from baselines.blind.search import Chain, sequence_search
from baselines.genie import genie_labels
from deint_env.modulation import PRIModel

# detector(free toas, sigma, pri_min, pri_max) -> candidate lists, one per difference level
Detector = Callable[[np.ndarray, float, float, float], Iterable[list[Candidate]]]


@dataclass(frozen=True)
class SearchParams:
    sigma: float  # TOA noise std (known, or estimated by the policy)
    pri_min: float
    pri_max: float
    min_pulses: int = 6
    min_fill: float = 0.8
    max_miss: int = 3
    max_trains: int = 32
    missing_prob: float = 0.01  # for the re-association
    spurious_rate: float = 0.01  # spurious pulses per received pulse, for the re-association


class FoundTrain(NamedTuple):
    pulses: np.ndarray  # indices into the window, time-ordered
    model: PRIModel
    phase: float  # estimated first emission in the window
    schedule: np.ndarray  # estimated emission times over the window


class Deinterleaving(NamedTuple):
    labels: np.ndarray  # train number per pulse, -1 = spurious
    trains: list[FoundTrain]


def extract_chains(t: np.ndarray, detect: Detector, p: SearchParams) -> list[Chain]:
    free = np.ones(t.size, dtype=bool)
    chains: list[Chain] = []
    while free.sum() >= p.min_pulses and len(chains) < p.max_trains:
        found = None
        for level in detect(t[free], p.sigma, p.pri_min, p.pri_max):
            for cand in sorted(level, key=lambda c: c.pri):
                found = sequence_search(t, free, cand.pri, cand.unc, p.sigma, max_miss=p.max_miss,
                                        min_pulses=p.min_pulses, min_fill=p.min_fill)
                if found is not None:
                    break
            if found is not None:
                break
        if found is None:
            break
        chains.append(found)
        free[found.index] = False
    return chains


def group_chains(t: np.ndarray, chains: list[Chain]) -> list[list[int]]:
    """Chains whose periods agree within 4 combined standard deviations (greedy, in found order)."""
    fits = [line_fit(t[c.index], c.k) for c in chains]
    groups: list[list[int]] = []
    for i, f in enumerate(fits):
        for g in groups:
            h = fits[g[0]]
            if abs(f.period - h.period) <= 4 * math.hypot(f.period_std, h.period_std) + 1e-9 * f.period:
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


def _lattice(origin: float, period: float, t0: float, t1: float) -> np.ndarray:
    k0 = math.floor((t0 - origin) / period) - 1
    k1 = math.ceil((t1 - origin) / period) + 1
    return origin + period * np.arange(k0, k1 + 1)


def _span(t: np.ndarray, c: Chain, period: float) -> tuple[float, float]:
    """A train's schedule covers its own span and 1.5 periods either side (emitters come and go)."""
    return float(t[c.index[0]]) - 1.5 * period, float(t[c.index[-1]]) + 1.5 * period


def deinterleave(t: np.ndarray, detect: Detector, p: SearchParams, align: bool = True) -> Deinterleaving:
    t = np.ascontiguousarray(t, dtype=np.float64)
    labels = np.full(t.size, -1, dtype=np.int64)
    if t.size == 0:
        return Deinterleaving(labels, [])
    chains = extract_chains(t, detect, p)
    lo, hi = float(t[0]) - 4 * p.sigma, float(t[-1]) + 4 * p.sigma
    models, schedules = [], []
    for g in group_chains(t, chains):
        fits = [line_fit(t[chains[i].index], chains[i].k) for i in g]
        for i in g:
            labels[chains[i].index] = len(models)
        if len(g) > 1:
            w = np.array([1.0 / max(f.period_std, 1e-12) ** 2 for f in fits])
            frame = float(np.sum(w * [f.period for f in fits]) / w.sum())
            origins = np.array([f.origin for f in fits])
            models.append(stagger_model(frame, origins, p.sigma))
            sched = np.concatenate([_lattice(f.origin, frame, *_span(t, chains[i], frame)) for i, f in zip(g, fits)])
        else:
            c = chains[g[0]]
            model = single_train_model(t[c.index], c.k, p.sigma)
            models.append(model)
            sched = _lattice(fits[0].origin, fits[0].period, *_span(t, c, fits[0].period)) \
                if model.kind == "constant" else t[c.index]
        schedules.append(np.sort(sched[(sched >= lo) & (sched <= hi)]))
    if align and schedules:
        src = np.concatenate([np.full(s.size, i) for i, s in enumerate(schedules)])
        span = max(hi - lo, 1e-300)
        labels = genie_labels(t, np.concatenate(schedules), src, max(p.sigma, 1e-9 * span), p.missing_prob,
                              p.spurious_rate * t.size / span, 0.0).astype(np.int64)
    trains = []
    for i, (m, s) in enumerate(zip(models, schedules)):
        pulses = np.flatnonzero(labels == i)
        trains.append(FoundTrain(pulses, m, float(t[pulses[0]]) if pulses.size else math.nan, s))
    return Deinterleaving(labels, trains)

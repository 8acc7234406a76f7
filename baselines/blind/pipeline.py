"""Blind deinterleaving of one window of pulses: detect a PRI, extract its train, repeat.

1. A detector (CDIF, SDIF or the PRI transform) proposes PRI candidates from the pulses still free;
   the sequence search tries them smallest first and the first acceptable train is removed; then
   detection starts again on the pulses left (the loop of Mardia and of Milojevic & Popovic), until
   no candidate gives a train.
   Then modulated trains are looked for among the pulses left (`agile_chains`), and chains the walk
   lost and found again are joined (`stitch`).
2. Trains whose periods are multiples of one another (within 4 standard deviations of their line
   fits) are sub-trains of one stagger (or a constant train extracted in pieces at multiples of its
   PRI) and become one train (`group_chains`, `pri_models.stagger_model`).
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
from baselines.blind.noise import check_magnitude
from baselines.blind.pri_models import line_fit, single_train_model, stagger_model
from baselines.blind.search import Chain, pool, sequence_search
from deint_env.oracle import genie_labels
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
    # candidate PRIs tried per train extracted: bounds a window's time where a smeared histogram (a
    # sweeping train, too fine a bin for the noise) puts thousands of chance peaks over the threshold
    # (28,000 in one pass of a deep saw-tooth with the noise unknown: 12 s for 1000 pulses).  Simulated
    # agile scenes made blind need up to ~2,000 before a train is found; no label of them changes.
    max_tries: int = 2048
    missing_prob: float = 0.0  # for the re-association (the priors' channel statistics)
    spurious_rate: float = 0.0  # spurious pulses per received pulse, for the re-association


class FoundTrain(NamedTuple):
    pulses: np.ndarray  # indices into the window, time-ordered
    model: PRIModel
    phase: float  # estimated first emission in the window
    schedule: np.ndarray  # estimated emission times over the window


class Deinterleaving(NamedTuple):
    labels: np.ndarray  # train number per pulse, -1 = spurious
    trains: list[FoundTrain]


def take_chains(free: np.ndarray, least: int, room: int, find: Callable[[], Chain | None]) -> list[Chain]:
    """The extraction loop: chains found one at a time (`find()`, None: no more), each taking its pulses
    from `free`, while at least `least` pulses are free and fewer than `room` chains are taken."""
    chains: list[Chain] = []
    while free.sum() >= least and len(chains) < room:
        found = find()
        if found is None:
            break
        chains.append(found)
        free[found.index] = False
    return chains


def extract_chains(t: np.ndarray, detect: Detector, p: SearchParams) -> list[Chain]:
    free = np.ones(t.size, dtype=bool)
    chains = take_chains(free, p.min_pulses, p.max_trains, lambda: _constant_chain(t, free, detect, p))
    chains.extend(agile_chains(t, free, p, len(chains)))
    return stitch(t, chains, p.sigma)


def _constant_chain(t: np.ndarray, free: np.ndarray, detect: Detector, p: SearchParams) -> Chain | None:
    """The first train the detector's candidate PRIs give among the free pulses (levels in order, each
    level's PRIs from the shortest; at most `max_tries` searches)."""
    shared = pool(t, free)
    tries = 0
    for level in detect(t[free], p.sigma, p.pri_min, p.pri_max):
        for cand in sorted(level, key=lambda c: c.pri):
            found = sequence_search(t, free, cand.pri, cand.unc, p.sigma, max_miss=p.max_miss,
                                    min_pulses=p.min_pulses, min_fill=p.min_fill, shared=shared)
            tries += 1
            if found is not None:
                return found
            if tries >= p.max_tries:
                return None
    return None


def _edge_pri(t: np.ndarray, c: Chain, last: bool) -> float:
    """The PRI at one end of a chain: its last (or first) three pulses' span per period."""
    i = c.index[-3:] if last else c.index[:3]
    k = c.k[-3:] if last else c.k[:3]
    return float((t[i[-1]] - t[i[0]]) / max(int(k[-1] - k[0]), 1))


def stitch(t: np.ndarray, chains: list[Chain], sigma: float) -> list[Chain]:
    """Join a chain to one that starts where it ends: not overlapping, the PRIs at the junction within
    5 %, and the second chain's first pulse where the first chain's end predicts it (+-3 sigma plus
    5 % of a PRI per step): a train the walk lost and found again, as where a modulated PRI crosses
    another train's.  The joined chain counts its periods across the gap."""
    out = sorted(chains, key=lambda c: float(t[c.index[0]]))
    joined = True
    while joined:
        joined = False
        for a in range(len(out)):
            ca = out[a]
            if ca.index.size < 3:
                continue
            pa = _edge_pri(t, ca, last=True)
            for b in range(len(out)):
                cb = out[b]
                if b == a or cb.index.size < 3 or cb.index[0] <= ca.index[-1]:
                    continue
                pb = _edge_pri(t, cb, last=False)
                gap = float(t[cb.index[0]] - t[ca.index[-1]])
                steps = max(1, round(gap / pa))
                if abs(pa - pb) <= 0.05 * pa and steps <= 4 and abs(gap - steps * pa) <= 3 * sigma + 0.05 * pa * steps:
                    k = np.concatenate([ca.k, cb.k - cb.k[0] + ca.k[-1] + steps])
                    out[a] = Chain(np.concatenate([ca.index, cb.index]), k, int(k[-1]) + 1)
                    del out[b]
                    joined = True
                    break
            if joined:
                break
    return out


def agile_chains(t: np.ndarray, free: np.ndarray, p: SearchParams, n_found: int) -> list[Chain]:
    """Modulated trains (sliding, wobulated) among the pulses the constant-PRI loop left: their
    differences spread over a band of PRIs, so the candidates are the peaks of a coarse histogram
    (bins 5 % of the PRI wide, the first three difference levels), and the walk fits its predicting
    line to the last 5 pulses only (where no candidate gives a train that way, a parabola to the last 8) and widens its
    gate by 4 % of the PRI, so it follows the PRI as it moves."""
    return take_chains(free, 3 * p.min_pulses, p.max_trains - n_found, lambda: _agile_chain(t, free, p))


def _agile_chain(t: np.ndarray, free: np.ndarray, p: SearchParams) -> Chain | None:
    tf = t[free]
    if not p.pri_min > 0:  # coincident pulses and no TOA noise: no band of PRIs to histogram
        return None
    edges = np.exp(np.arange(math.log(p.pri_min), math.log(p.pri_max), 0.05))
    if edges.size < 3:
        return None
    h = sum(np.histogram(tf[c:] - tf[:-c], edges)[0] for c in (1, 2, 3))
    with np.errstate(over="ignore"):  # bins past 1e154 (a pri_max of 1e300) hold no difference: an inf centre, unused
        centre = np.sqrt(edges[:-1] * edges[1:])
    for bend in (False, True):  # lines first, for every candidate; parabolas where none passes
        for i in np.argsort(-h)[:5]:
            if h[i] < p.min_pulses:
                break
            found = sequence_search(t, free, float(centre[i]), 0.1 * float(centre[i]), p.sigma,
                                    memory=8 if bend else 5, max_miss=p.max_miss, min_pulses=3 * p.min_pulses,
                                    min_fill=p.min_fill, slack=0.04 * float(centre[i]), curve=bend)
            if found is not None:
                return found
    return None


def _off_lattice(fit, sigma: float) -> bool:
    """A chain whose residuals about its line are 10 TOA-noise deviations (a drifting or modulated PRI
    followed by the walk), not a lattice with a few wrong pulses (2 to 8 deviations)."""
    return fit.resid_std > 10 * sigma + 1e-3 * fit.period


def merge_interleaved(t: np.ndarray, chains: list[Chain], sigma: float) -> list[Chain]:
    """Off-lattice chains (`_off_lattice`: a drifting or modulated PRI) of one period within 2 %
    that overlap in time are pieces of one train taken every m-th pulse (the walk at m times its PRI):
    their union is one chain, its period counts from its gaps in units of the median gap."""
    fits = [line_fit(t[c.index], c.k) for c in chains]
    off = [i for i, f in enumerate(fits) if _off_lattice(f, sigma)]
    used: set[int] = set()
    out = [c for i, c in enumerate(chains) if i not in off]
    for i in sorted(off, key=lambda i: fits[i].period):
        if i in used:
            continue
        span = (t[chains[i].index[0]], t[chains[i].index[-1]])
        mates = [j for j in off if j not in used and abs(fits[j].period - fits[i].period) <= 0.02 * fits[i].period
                 and min(span[1], t[chains[j].index[-1]]) - max(span[0], t[chains[j].index[0]])
                 > 0.5 * min(span[1] - span[0], t[chains[j].index[-1]] - t[chains[j].index[0]])]
        used.update(mates)
        if len(mates) < 2:
            out.extend(chains[j] for j in mates)
            continue
        idx = np.unique(np.concatenate([chains[j].index for j in mates]))
        gaps = np.diff(t[idx])
        k = np.concatenate([[0], np.cumsum(np.maximum(1, np.round(gaps / np.median(gaps))))]).astype(np.int64)
        out.append(Chain(idx, k, int(k[-1]) + 1))
    return out


class Group(NamedTuple):
    """Chains that are one train: a frame period F (a multiple of every chain's period) and the phase
    of every sub-train of period F they hold (a chain of period F / n holds n); `extra`: chains of the
    train that are no sub-train of it (labelled with it, not modelled)."""

    chains: list[int]
    frame: float
    origins: np.ndarray
    extra: tuple[int, ...] = ()


def group_chains(t: np.ndarray, chains: list[Chain], sigma: float = math.inf) -> list[Group]:
    """Chains whose periods are (integer multiples of) one another within 4 combined standard
    deviations are one train: the sub-trains of a stagger, or a constant train extracted in pieces at
    multiples of its PRI.  Greedy, by increasing period.  A chain off a lattice (`_off_lattice`: a
    modulated train followed by the agile walk) is a train of its own.

    A long periodic PRI (a sweep, wobulation or dwell cycle of M pulses) is found as M sub-trains at
    its frame; the walks also string its pulses from one sub-train to the next, at the frame minus one
    PRI or so.  Such chains, within 5 % of the frame of a group of 8 or more sub-trains that
    `stagger_model` finds modulated, and of no group of their own larger than 3 chains, join it as
    `extra`."""
    fits = [line_fit(t[c.index], c.k) for c in chains]
    members: list[list[int]] = []
    for i in sorted(range(len(fits)), key=lambda i: fits[i].period):
        f = fits[i]
        if _off_lattice(f, sigma):
            members.append([i])
            continue
        for g in members:
            if _off_lattice(fits[g[0]], sigma):
                continue
            h = fits[g[0]]  # the group's smallest period
            n = round(f.period / h.period)
            if n >= 1 and abs(f.period - n * h.period) <= 4 * math.hypot(f.period_std, n * h.period_std) \
                    + 1e-9 * f.period:
                g.append(i)
                break
        else:
            members.append([i])
    groups = []
    for g in members:
        big = max(fits[i].period for i in g)
        mult = [max(1, round(big / fits[i].period)) for i in g]
        est = np.array([m * fits[i].period for i, m in zip(g, mult)])
        w = np.array([1.0 / max(m * fits[i].period_std, 1e-12) ** 2 for i, m in zip(g, mult)])
        frame = float(np.sum(w * est) / w.sum())
        origins = np.concatenate([fits[i].origin + fits[i].period * np.arange(m) for i, m in zip(g, mult)])
        groups.append(Group(g, frame, origins))
    # hosts: groups of 8 or more sub-trains whose frame holds a sweep, wobulation or dwell cycle (not a
    # constant train extracted at multiples of its PRI, whose frame another train's period may be near)
    big = [j for j, g in enumerate(groups) if g.origins.size >= 8 and math.isfinite(sigma) and stagger_model(
        g.frame, g.origins, max([sigma] + [fits[i].resid_std for i in g.chains]))[0].kind in
        ("sliding", "sinusoidal", "dwell_switch")]
    out, extra = [], {j: [] for j in big}
    for j, g in enumerate(groups):
        host = None if j in extra or len(g.chains) > 3 else next(
            (b for b in big if abs(g.frame - groups[b].frame) <= 0.05 * groups[b].frame), None)
        if host is None:
            out.append(j)
        else:
            extra[host].extend(g.chains)
    return [groups[j]._replace(extra=tuple(extra.get(j, ()))) for j in out]


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
    check_magnitude(t)
    chains = merge_interleaved(t, extract_chains(t, detect, p), p.sigma)
    lo, hi = float(t[0]) - 4 * p.sigma, float(t[-1]) + 4 * p.sigma
    models, schedules = [], []
    for g in group_chains(t, chains, p.sigma):
        for i in g.chains + list(g.extra):
            labels[chains[i].index] = len(models)
        c = chains[g.chains[0]]
        if g.origins.size > 1:
            scatter = max([p.sigma] + [line_fit(t[chains[i].index], chains[i].k).resid_std for i in g.chains])
            model, phases = stagger_model(g.frame, g.origins, scatter)
            models.append(model)
            frame = model.period if model.kind == "constant" else g.frame
            first = min(float(t[chains[i].index[0]]) for i in g.chains) - 1.5 * frame
            last = max(float(t[chains[i].index[-1]]) for i in g.chains) + 1.5 * frame
            sched = np.concatenate([_lattice(o, frame, first, last) for o in phases])
        else:
            model = single_train_model(t[c.index], c.k, p.sigma)
            models.append(model)
            # a lattice only for a train that sits on one (a joined or modulated train: its own pulses)
            on_lattice = model.kind in ("constant", "drifting") and line_fit(t[c.index], c.k).resid_std <= 3 * p.sigma
            sched = _lattice(g.origins[0], g.frame, *_span(t, c, g.frame)) if on_lattice else t[c.index]
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

"""The scoring oracle: the known-parameter MAP labelling, the ceiling of the normalised score
(docs/design.md section 6).  The runner scores every episode against it, and the `genie` policy
(baselines/genie.py) plays it.

The genie knows every source's noise-free emission schedule (the true parameters: periods, phases,
modulation and the realised cumulative jitter) and the channel statistics, but not which emissions
were missed or merged, nor the TOA noise, nor the spurious pulses.  Its labelling is the MAP
alignment of the received TOAs y_1 < ... < y_n to the sorted schedule s_1 < ... < s_m: every
received pulse is matched to one emission or called spurious, every emission is received at most
once, and matches keep their order (for equal-variance Gaussian noise an optimal matching never
crosses: swapping two crossed pairs lowers sum (y - s)^2).  With nothing missed or spurious this is
"the k-th received pulse is the k-th scheduled arrival".

Negative log-likelihood of an alignment: a match costs (y - s)^2 / (2 sigma^2) + log(sigma sqrt(2 pi))
- log(1 - p_i), a skipped emission -log p_i, a spurious pulse -log lambda (lambda: spurious pulses per
unit time), where p_i is the chance emission i is not received on its own: missed, or merged into a
neighbour closer than the coincidence resolution.  The dynamic programme runs over the received
pulses with, as state, the last schedule index matched; only emissions within 7 sigma of a pulse can
be matched (a truncation of probability < 1e-11), and every state left of the current window is
collapsed into one, so a pulse costs O(candidates) and the whole episode O(n).
"""

from __future__ import annotations

import math

import numpy as np

from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable

_WINDOW_SIGMAS = 7.0
_FLOOR = 1e-12  # probabilities of 0 would make an alignment impossible rather than just unlikely
# Priors-file genie (`priors_genie_labels`): the schedule it builds and the emissions each pulse is
# compared with are bounded, so that memory and time stay linear in the pulses.
MAX_EMISSIONS_PER_PULSE, MAX_EMISSIONS_EXTRA = 1000, 1_000_000
MAX_CANDIDATES_PER_PULSE = 1000


def genie_labels(toa: np.ndarray, schedule_toa: np.ndarray, schedule_source: np.ndarray, jitter_std: float,
                 missing_prob: float, spurious_intensity: float, resolution: float) -> np.ndarray:
    """MAP source of each received pulse (-1 = spurious) given the true schedule; see module doc."""
    order = np.argsort(schedule_toa, kind="stable")
    s, src = schedule_toa[order], schedule_source[order]
    n, m = toa.size, s.size
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    spacing = float(np.median(np.diff(s))) if m > 1 else 1.0
    # floored so that 1 / sigma^2 stays finite (coincident emissions made the median spacing 0: 1e-309 squared is 0)
    sigma = max(jitter_std, 1e-9 * max(spacing, 1e-140))
    # p_i: missed, or merged with a neighbour (the pair lands closer than `resolution`; either may
    # survive, so each member is absorbed with half the pair's probability).
    p_merge = np.zeros(m)
    if resolution > 0 and m > 1:
        from scipy.special import ndtr  # here: scipy.special costs a blind policy's start-up 0.1-0.2 s

        d = np.diff(s)
        scale = sigma * math.sqrt(2.0)
        pair = ndtr((resolution - d) / scale) - ndtr((-resolution - d) / scale)
        p_merge[1:] += 0.5 * pair
        p_merge[:-1] += 0.5 * pair
    p = np.clip(missing_prob + (1.0 - missing_prob) * p_merge, _FLOOR, 1.0 - _FLOOR)
    # A match of emission i costs (y - s_i)^2 / (2 sigma^2) + offset_i, with the skip of i already
    # paid for in the state value (see _align).
    offset = (math.log(sigma * math.sqrt(2 * math.pi)) - np.log1p(-p) + np.log(p)).tolist()
    spur = -math.log(max(spurious_intensity, _FLOOR / max(spacing, 1e-300)))
    w = _WINDOW_SIGMAS * sigma
    lo = np.searchsorted(s, toa - w, side="left")
    hi = np.searchsorted(s, toa + w, side="right")
    matched = _align(toa.tolist(), s.tolist(), offset, lo.tolist(), hi.tolist(), 0.5 / sigma**2, spur)
    labels = np.full(n, -1, dtype=np.int64)
    rows = [j for j, i in matched]
    labels[rows] = src[[i for j, i in matched]]
    return labels


def _align(y, s, offset, lo, hi, inv2var, spur):
    """The DP.  State: the last schedule index matched, m (-1: none).  Its value is
    V(m) = cost - C[m+1], C being the prefix sums of skip costs, so moving from state m to a match of
    emission i costs V(m) + (y - s_i)^2 / (2 sigma^2) + offset_i with the skips in between free of
    bookkeeping.  A spurious pulse adds `spur` to every state (kept as a running offset).  States
    left of the window are folded into `base`.  Nodes (pulse, emission, parent) record the matches
    for backtracking."""
    node_j, node_i, node_parent = [], [], []
    base_v, base_node = 0.0, -1  # the folded states: best value and its path
    states: dict[int, list] = {}  # m -> [stored value, node]; true value = stored + shift
    keys: list[int] = []  # the states' m, increasing
    shift = 0.0
    for j, yj in enumerate(y):
        a, b = lo[j], hi[j]
        # fold states that no future pulse can extend differently
        k = 0
        while k < len(keys) and keys[k] < a:
            v, nd = states.pop(keys[k])
            if v + shift < base_v:
                base_v, base_node = v + shift, nd
            k += 1
        if k:
            del keys[:k]
        new = []
        added = False
        best_v, best_node, q = base_v, base_node, 0
        for i in range(a, b):
            while q < len(keys) and keys[q] < i:  # prefix minimum over states m < i
                v, nd = states[keys[q]]
                if v + shift < best_v:
                    best_v, best_node = v + shift, nd
                q += 1
            d = yj - s[i]
            new.append((i, best_v + d * d * inv2var + offset[i], best_node))
        shift += spur  # every existing state calls pulse j spurious
        base_v += spur
        for i, v, parent in new:
            old = states.get(i)
            if old is None or v < old[0] + shift:
                node_j.append(j), node_i.append(i), node_parent.append(parent)
                if old is None:
                    keys.append(i)
                    added = True
                states[i] = [v - shift, len(node_j) - 1]
        if added:
            keys.sort()
    best_v, best_node = base_v, base_node
    for v, nd in states.values():
        if v + shift < best_v:
            best_v, best_node = v + shift, nd
    out = []
    while best_node >= 0:
        out.append((node_j[best_node], node_i[best_node]))
        best_node = node_parent[best_node]
    return out


def episode_genie_labels(episode: Episode) -> np.ndarray:
    """Genie labels (label ids, n_labels = spurious) for a simulated episode, from its truth."""
    truth = episode.truth
    if truth is None:
        raise DeintError("genie needs the episode's truth (a simulated episode, or true parameters in the priors)")
    counts = np.diff(truth.schedule_offsets)
    sched_src = np.repeat(np.arange(truth.n_sources), counts)
    pri = episode.priors
    spec_rate = float(np.sum(1.0 / truth.period))
    src = genie_labels(episode.toa, truth.schedule_toa, sched_src, pri.jitter_std, pri.missing_prob,
                       pri.spurious_rate * spec_rate, pri.coincidence_resolution)
    return np.where(src < 0, episode.n_labels, src)


def priors_genie_labels(toa: np.ndarray, priors: Priors) -> np.ndarray:
    """Genie labels from true constant-PRI parameters given as priors (the `deint label` case).

    Refuses (NotApplicable) the episodes whose schedule would not fit in memory or time linear in the
    pulses: TOAs stored more coarsely than a hundredth of the shortest period (near 1e300), a span
    holding more than MAX_EMISSIONS_PER_PULSE emissions per pulse (+ MAX_EMISSIONS_EXTRA: one
    outlying TOA, or a tiny period), or more than MAX_CANDIDATES_PER_PULSE emissions within a pulse's
    matching window (periods far below the TOA noise)."""
    if priors.blind or not np.all(np.isfinite(priors.phase)):
        raise DeintError("genie needs the true period and phase of every source in the priors file "
                         "('period' and 'phase')")
    _check_schedule_size(toa, priors)
    resolution = priors.coincidence_resolution
    t_end = float(toa[-1]) + 8 * priors.jitter_std + resolution + 1.0
    sched, srcs = [], []
    for i, (t, ph) in enumerate(zip(priors.period, priors.phase)):
        k = np.arange(max(0, int(math.floor((float(toa[0]) - 8 * priors.jitter_std - ph) / t)) - 1),
                      int(math.ceil((t_end - ph) / t)) + 1)
        k = k[k >= 0]
        sched.append(ph + k * t), srcs.append(np.full(k.size, i))
    rate = float(np.sum(1.0 / priors.period))
    # rates a file leaves unknown (NaN): the genie labels as if there were no misses or spurious pulses
    missing, spurious = np.nan_to_num([priors.missing_prob, priors.spurious_rate])
    src = genie_labels(toa, np.concatenate(sched), np.concatenate(srcs), priors.jitter_std, float(missing),
                       float(spurious) * rate, resolution)
    return np.where(src < 0, priors.n_labels, src)


def _check_schedule_size(toa: np.ndarray, priors: Priors) -> None:
    n = toa.size
    if n == 0:
        return
    period, sigma = priors.period, priors.jitter_std
    t_min = float(np.min(period))
    step = max(math.ulp(float(toa[0])), math.ulp(float(toa[-1])))
    if not step <= t_min / 100:
        raise NotApplicable(f"genie: TOAs up to {max(abs(toa[0]), abs(toa[-1])):.3g} are stored in float64 steps of "
                            f"{step:.3g}, too coarse for the shortest period {t_min:.3g}")
    far = float(np.max(np.abs(priors.phase)))
    if not math.ulp(far) <= t_min / 100:  # a phase of 1e30 put the schedule's indices beyond int64
        raise NotApplicable(f"genie: phases up to {far:.3g} are stored in float64 steps of {math.ulp(far):.3g}, too "
                            f"coarse for the shortest period {t_min:.3g}")
    span = float(toa[-1]) - float(toa[0]) + 16 * sigma + 2 * priors.coincidence_resolution + 2.0
    emissions = float(np.sum(span / period))
    limit = MAX_EMISSIONS_PER_PULSE * n + MAX_EMISSIONS_EXTRA
    if not emissions <= limit:
        raise NotApplicable(f"genie: the {n} pulses span {span:.3g} time units, {emissions:.3g} emissions of the "
                            f"true schedule (periods down to {t_min:.3g}); at most {limit} "
                            f"({MAX_EMISSIONS_PER_PULSE} per pulse + {MAX_EMISSIONS_EXTRA}) fit in bounded memory")
    candidates = float(np.sum(2 * _WINDOW_SIGMAS * sigma / period))
    if not candidates <= MAX_CANDIDATES_PER_PULSE:
        raise NotApplicable(f"genie: {candidates:.3g} emissions lie within {_WINDOW_SIGMAS:g} sigma = "
                            f"{_WINDOW_SIGMAS * sigma:.3g} of each pulse (periods down to {t_min:.3g}); at most "
                            f"{MAX_CANDIDATES_PER_PULSE} keep the alignment's time bounded")

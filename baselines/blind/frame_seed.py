"""Whole agile trains found by their frame: the pulses of a train whose PRI pattern repeats (`frame_trains`).

A train whose PRIs repeat every M pulses (a stagger's levels, a saw-tooth sweep's cycle; a constant PRI, M = 1)
has every pulse followed one frame F = M x mean PRI later by its own next cycle's pulse at the same position, up
to the TOA noise alone: its difference histogram has a sharp peak at F however spread its single PRIs are.  For
each sharp peak, each pulse is linked to the pulse one frame later (or two or three, over missed pulses); the
chains of links are the train's cycle positions, each as long as the record holds cycles, while chance links
among other pulses make short chains.  The pulses of the long chains are the train, whole, with no PRI model
assumed: a fit over them (`train_fit.fit_train`) finds the model.  The frame's multiples are peaks too, often
stronger, and chains a multiple apart link other trains' pulses: a peak's train is taken at the least peak it is
a multiple of that chains most of it (`_frame_train`).  A jittered train (a renewal process) has no sharp peak (its
arrivals drift) and is not found here.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import median_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

# the pair tolerance, in white-noise deviations of a difference (sqrt 2 sigma_w): a frame pair's offset is the
# two pulses' noise alone
TOL_SIGMAS = 4.0
MIN_CYCLES = 4  # frames longer than a quarter of the record make chains too short to tell from chance
HOPS = 3  # a link may skip up to HOPS - 1 frames (the pulse one frame later missed)
# pulses in a chain of the train's; chance chains among the record's pulses are shorter, and so are those of
# another train's pulses whose sums of a few PRIs happen to match the frame at one or two cycle positions
MIN_CHAIN, CHAIN_SHARE = 3, 0.1
BACKGROUND_BINS = 101  # the running median of the histogram that stands for chance pairs
MIN_Z = 8.0  # a peak's excess over chance, in deviations of the chance count
# the share of a peak's excess within +-tol of its centre against within +-5 tol: a jittered train's peaks are
# wide (its arrivals drift), a frame's sharp
SHARP = 0.6
TOP_PEAKS = 12  # the strongest peaks tried as frames (each after the peaks it is a multiple of: `_frame_train`)
DIVISOR_SHARE = 1 / 3  # `_frame_train`
# a train of fewer pulses than this share of the largest one found is a piece: a wobulation's near-frame (a whole
# number of pulses near a whole number of its cycles) chains a few cycle positions, as does a sum of some of a
# stagger's levels.  Radars' pulse counts differ by their PRIs (3:1 at most in the independent generator); pieces
# left out, the slot goes to another labelling's train (seed 3's wobulations with missing pulses: 0.64 -> 0.81,
# 0.40 -> 0.95, 0.32 -> 0.39)
PIECE_SHARE = 0.25
# the bins the white noise is measured in where it is not stated, in median pulse spacings: far narrower than any
# noise a frame peak is told by
PROBE_TOL = 0.004
POSITION_SHARE = 0.5  # a cycle position's pulses, against the median position's


def _differences(toa: np.ndarray, max_lag: float) -> np.ndarray:
    hi = np.searchsorted(toa, toa + max_lag, side="right")
    n = hi - np.arange(toa.size) - 1
    first = np.repeat(np.arange(toa.size), n)
    second = first + 1 + np.arange(first.size) - np.repeat(np.cumsum(n) - n, n)
    return toa[second] - toa[first]


def _peaks(d: np.ndarray, tol: float, max_lag: float, sharp: float = SHARP, top: int | None = None) -> list[float]:
    """The `top` strong peaks (default all: a strong peak's frame may rank far down, `_frame_train`) of the
    differences' histogram (bins `tol` wide), strongest first, of which `sharp` of the excess lies within +-tol of
    the centre: each one's median difference."""
    counts = np.histogram(d, bins=np.arange(0.0, max_lag + tol, tol))[0].astype(np.float64)
    bg = median_filter(counts, size=BACKGROUND_BINS, mode="nearest")
    pair = counts[:-1] + counts[1:]  # +-tol about each inner edge
    excess = pair - 2 * bg[:-1]
    wide = np.convolve(counts - bg, np.ones(10), mode="same")[:-1]
    z = excess / np.sqrt(2 * bg[:-1] + 1)
    local = np.r_[False, (pair[1:-1] >= pair[:-2]) & (pair[1:-1] > pair[2:]), False]
    good = np.flatnonzero(local & (z >= MIN_Z) & (excess >= sharp * np.maximum(wide, excess)))
    out = []
    for i in good[np.argsort(-excess[good])][:top]:
        lo = (i + 1) * tol
        out.append(float(np.median(d[(d >= lo - tol) & (d < lo + tol)])))
    return out


def _chained(toa: np.ndarray, frame: float, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The pulses in long chains (`MIN_CHAIN` pulses, and `CHAIN_SHARE` of the frames the record spans) that have
    an emission count (`_counts`), and their counts: each pulse linked to its nearest pulse 1..HOPS frames later
    (the fewest frames first), each pulse the link of one pulse at most (the fewest frames, then the nearest): so
    the chains are paths, and another pulse's chance link cannot join a train's chain midway."""
    n = toa.size
    link = [], [], []  # from, to, rank
    for k in range(1, HOPS + 1):
        target = toa + k * frame
        j = np.clip(np.searchsorted(toa, target), 1, n - 1)
        j = np.where(np.abs(toa[j - 1] - target) < np.abs(toa[j] - target), j - 1, j)
        off = np.abs(toa[j] - target)
        hit = np.flatnonzero((off <= tol) & (j != np.arange(n)))
        link[0].append(hit)
        link[1].append(j[hit])
        link[2].append(k + off[hit] / (2 * tol))  # k first, then the offset
    src, dst, rank = (np.concatenate(x) for x in link)
    order = np.argsort(rank, kind="stable")
    src, dst = src[order], dst[order]
    # greedy one-to-one matching by rank: a pulse keeps its best outgoing and its best incoming link
    keep = np.zeros(src.size, dtype=bool)
    out_used, in_used = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    for e in range(src.size):
        a, b = src[e], dst[e]
        if not out_used[a] and not in_used[b]:
            keep[e] = out_used[a] = in_used[b] = True
    graph = coo_matrix((np.ones(int(keep.sum())), (src[keep], dst[keep])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    size = np.bincount(comp)
    least = max(MIN_CHAIN, math.ceil(CHAIN_SHARE * float(toa[-1] - toa[0]) / frame))
    own = np.flatnonzero(size[comp] >= least)
    counts = _counts(toa[own], comp[own], frame, tol)
    return own[counts >= 0], counts[counts >= 0]


def _counts(t: np.ndarray, chain: np.ndarray, frame: float, tol: float) -> np.ndarray:
    """Each chained pulse's emission count: its cycle times the pulses a cycle holds plus its position in the
    cycle, the positions being the clusters of the pulses' phases in the frame (-1: a phase of no cluster, or of
    one with few pulses).  The
    frame is refitted over the chains (cycles against times within each chain): the links alone leave it too
    uncertain for phases taken over the whole record."""
    if t.size < 2:
        return np.full(t.size, -1)
    # each pulse's cycle within its chain, from the chain's first pulse
    rough = np.round((t - t[0]) / frame)
    _, first = np.unique(chain, return_index=True)
    base = np.zeros(chain.max() + 1)
    base[chain[first]] = rough[first]
    cyc = rough - base[chain]
    tc = t - np.bincount(chain, t)[chain] / np.bincount(chain)[chain]
    cc = cyc - np.bincount(chain, cyc)[chain] / np.bincount(chain)[chain]
    if np.sum(cc * cc) > 0:
        frame = float(np.sum(cc * tc) / np.sum(cc * cc))
    phase = np.mod(t - t[0], frame)
    order = np.argsort(phase)
    ps = phase[order]
    gaps = np.diff(np.r_[ps, ps[0] + frame])
    cuts = np.flatnonzero(gaps > 3 * tol)
    if cuts.size == 0:
        return np.full(t.size, -1)
    # clusters of phases, the first one after the widest gap starting the cycle
    start = int(cuts[np.argmax(gaps[cuts])]) + 1
    rolled = np.roll(np.arange(t.size), -start)
    shifted = np.mod(phase - ps[start % t.size], frame)
    sp = shifted[order[rolled]]
    cluster = np.zeros(t.size, dtype=np.int64)
    cluster[order[rolled]] = np.r_[0, np.cumsum(np.diff(sp) > 3 * tol)]
    members = np.bincount(cluster)
    centre = np.bincount(cluster, shifted) / members
    # a cycle position holds a pulse of most cycles; a few pulses of like phase are chance links' (a pulse one
    # frame before a chain's first, say)
    real = members >= max(MIN_CHAIN, POSITION_SHARE * float(np.median(members)))
    if not real.any():
        return np.full(t.size, -1)
    position = np.cumsum(real) - 1
    cycle = np.round((t - t[0] - ps[start % t.size] - centre[cluster]) / frame).astype(np.int64)
    counts = (position.max() + 1) * cycle + position[cluster]
    return np.where(real[cluster], counts - counts[real[cluster]].min(), -1)


def _white_noise(d: np.ndarray, spacing: float, max_lag: float) -> float:
    """The white TOA noise from the strongest frame peak, found in bins far narrower than any noise: the spread of
    its differences (median absolute deviation, clipped to 3 deviations until it settles, from a window of
    10 bins: chance pairs, flat, would widen a window left to grow) over sqrt 2.  0 where no peak shows."""
    tol = PROBE_TOL * spacing
    if not tol > 0:  # most pulses coincide (equal TOAs): no bins to measure in, no frame
        return 0.0
    found = _peaks(d, tol, max_lag, sharp=0.0, top=1)
    if not found:
        return 0.0
    near = d[np.abs(d - found[0]) <= 10 * tol]
    dev = 0.0
    for _ in range(20):
        centre = float(np.median(near))
        new = 1.4826 * float(np.median(np.abs(near - centre)))
        if not new > 0 or new == dev:
            break
        dev, near = new, near[np.abs(near - centre) <= 3 * new]
    return dev / math.sqrt(2)


def _frame_train(t: np.ndarray, frame: float, peaks: list[float], tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The train chained at `frame` (`_chained`), or at the least peak it is a whole multiple of whose train holds
    `DIVISOR_SHARE` of its pulses or more: a train's frame multiples are peaks too and may outrank its frame, and
    chains a multiple apart, skipping up to `HOPS` multiples, link other trains' pulses (seed 4, staggered files: 5
    frames of a 5-level stagger first, its train holding 148 pulses of another radar; a common multiple of two
    2-level staggers' frames, 23 x 23.92 and 21 x 26.20, first, the frame 23.92 the 57th peak, the train at the
    multiple both radars').  A divisor that is a sum of some of a train's levels chains a few of its positions
    alone (seed 0: 72 pulses of a 5-level stagger's 300, a quarter of the multiple's train)."""
    whole = _chained(t, frame, tol)
    for p in sorted(p for p in peaks if p < frame and abs(frame - round(frame / p) * p) <= tol):
        hit = _chained(t, p, tol)
        if hit[0].size and hit[0].size >= DIVISOR_SHARE * whole[0].size:
            return hit
    return whole


def frame_trains(toa: np.ndarray, white_noise: float, max_trains: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Up to `max_trains` trains found whole by their frames: (sorted pulse indices, each one's emission count from
    the frame).  The strongest peak's train first, then the same among the pulses left (a train's many frame
    multiples would outrank other trains); pieces (`PIECE_SHARE`) left out.  With no white noise stated (0) it is
    measured from the strongest frame peak."""
    toa = np.asarray(toa, dtype=np.float64)
    if toa.size < 2 * MIN_CHAIN:
        return []
    max_lag = float(toa[-1] - toa[0]) / MIN_CYCLES
    if not white_noise > 0:
        white_noise = _white_noise(_differences(toa, max_lag), float(np.median(np.diff(toa))), max_lag)
    tol = TOL_SIGMAS * math.sqrt(2) * white_noise
    left = np.arange(toa.size)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    while len(out) < max_trains and left.size >= 2 * MIN_CHAIN and tol > 0 and max_lag >= 10 * tol:
        t = toa[left]
        peaks = _peaks(_differences(t, max_lag), tol, max_lag)
        found = next((hit for frame in peaks[:TOP_PEAKS] if (hit := _frame_train(t, frame, peaks, tol))[0].size),
                     None)
        if found is None:
            break
        own, counts = found
        out.append((left[own], counts))
        left = np.delete(left, own)
    return [(own, counts) for own, counts in out if own.size >= PIECE_SHARE * max(o.size for o, _ in out)]

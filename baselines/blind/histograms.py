"""Difference histograms of the TOAs and their PRI-detection thresholds.

CDIF (Mardia, "New techniques for the deinterleaving of repetitive sequences", IEE Proc. F 136(4),
1989): the histograms of the level-c differences t_{k+c} - t_k are *accumulated* over c = 1, 2, ...;
after each level, an interval tau whose count and whose double's count (2 tau) both exceed the
threshold x * D / tau (D the observation time: a train of PRI tau has about D / tau intervals) is a PRI
candidate, tried smallest first by sequence search.

SDIF (Milojevic & Popovic, "Improved algorithm for the deinterleaving of radar pulses", IEE Proc. F
139(1), 1992): the level-c histogram alone (not accumulated), against the threshold
x (E - c) exp(-tau / (k N)) (E pulses, N bins, tau in bins): the level-c intervals of random pulses
decay exponentially; x and k are the paper's experimental constants.  Peaks over it are candidates,
smallest first.

Both return candidates level by level; the pipeline runs the sequence search on each and, after a
train is extracted, starts again from level 1 on the pulses left (the papers' loop).
"""

from __future__ import annotations

from typing import Iterator, NamedTuple

import numpy as np


class Candidate(NamedTuple):
    pri: float
    unc: float  # half a bin: how far the true PRI may be from `pri`
    strength: float  # the histogram value (or transform magnitude) over its threshold


def _bins(t: np.ndarray, pri_min: float, pri_max: float, width: float) -> np.ndarray:
    return np.arange(pri_min, pri_max + width, width)


def _peaks(h: np.ndarray, over: np.ndarray) -> np.ndarray:
    """Bins over their threshold that are local maxima (ties: the first)."""
    left = np.concatenate([[-np.inf], h[:-1]])
    right = np.concatenate([h[1:], [-np.inf]])
    return np.flatnonzero(over & (h > left) & (h >= right))


def cdif_candidates(t: np.ndarray, pri_min: float, pri_max: float, width: float, *, x: float = 0.5,
                    max_level: int = 8) -> Iterator[list[Candidate]]:
    """Per difference level, the CDIF candidates (smallest PRI first)."""
    edges = _bins(t, pri_min, pri_max, width)
    centre = 0.5 * (edges[:-1] + edges[1:])
    acc = np.zeros(centre.size)
    duration = float(t[-1] - t[0]) if t.size else 0.0
    thr = x * duration / centre
    for c in range(1, min(max_level, t.size - 1) + 1):
        acc += np.histogram(t[c:] - t[:-c], edges)[0]
        # the double's bin: the histogram at 2 tau must pass its own threshold as well (Mardia's test)
        j2 = np.searchsorted(edges, 2 * centre) - 1
        ok2 = (j2 < centre.size) & (acc[np.clip(j2, 0, centre.size - 1)] > thr[np.clip(j2, 0, centre.size - 1)])
        ok2 |= 2 * centre > pri_max  # a double beyond the histogram cannot be checked
        over = (acc > thr) & ok2
        yield [Candidate(float(centre[i]), width / 2, float(acc[i] / thr[i])) for i in _peaks(acc, over)]


def sdif_candidates(t: np.ndarray, pri_min: float, pri_max: float, width: float, *, x: float = 0.1,
                    k: float = 0.3, max_level: int = 8) -> Iterator[list[Candidate]]:
    """Per difference level, the SDIF candidates (smallest PRI first)."""
    edges = _bins(t, pri_min, pri_max, width)
    centre = 0.5 * (edges[:-1] + edges[1:])
    n_bins = centre.size
    tau_bins = (centre - pri_min) / width
    e = t.size
    for c in range(1, min(max_level, e - 1) + 1):
        h = np.histogram(t[c:] - t[:-c], edges)[0].astype(np.float64)
        thr = x * (e - c) * np.exp(-tau_bins / (k * n_bins))
        yield [Candidate(float(centre[i]), width / 2, float(h[i] / thr[i])) for i in _peaks(h, h > thr)]

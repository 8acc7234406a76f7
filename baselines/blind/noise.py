"""The TOA noise of an unlabelled pulse record, measured from the pulses themselves.

Two noises make a periodic train's arrivals wander: white TOA noise sigma_w (each arrival off its
lattice by an independent error) and PRI jitter sigma_v (each interval off the mean by an independent
error: a renewal process, whose arrivals drift as a random walk).  Over m periods a train's
difference t_{k+m} - t_k - m T then has variance

    s_m^2 = 2 sigma_w^2 + m sigma_v^2,

so the widths of a train's difference peaks at T, 2T and 3T tell the two apart (the same decomposition
as the Allan-variance reading of clock noise: white phase noise is flat in m, a random-walk phase grows
with m).  The peaks are found and measured as in the difference-histogram PRI analysis of
Mardia (1989) and Wiley (ELINT: The Interception and Analysis of Radar Signals, 2006, ch. 12): the
strongest peaks of the histogram of TOA differences against the level random pulses would give, then,
for each peak T, every pulse's nearest neighbour m T later; the spread of those offsets (a median
absolute deviation, iteratively clipped at 3 deviations so that the flat floor of chance neighbours is
cut away) is s_m.  A modulated train (stagger levels, a sweep, a wobulation) only widens its peaks, so
the narrowest of the strong peaks measures the noise common to all trains.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from deint_env.episode import MAX_MAGNITUDE
from deint_env.errors import NotApplicable

_MAD = 1.4826  # MAD -> standard deviation for a normal sample


class Noise(NamedTuple):
    toa: float  # sigma_w, white TOA noise
    pri: float  # sigma_v, PRI jitter (per interval, cumulative)
    period: float  # the PRI of the peak they were measured on (NaN if none)

    @property
    def walk(self) -> float:
        """The deviation of one interval of a train: what a walk predicting one PRI ahead must gate."""
        return math.sqrt(self.toa ** 2 + self.pri ** 2)


def _candidates(t: np.ndarray, d_max: float, rel: float = 0.01, top: int = 6) -> np.ndarray:
    """The PRIs of the strongest peaks of the histogram of differences up to d_max (bins `rel` wide in
    log d), strength = count over the count of pairs random pulses would put in the bin."""
    n = t.size
    span = float(t[-1] - t[0])
    lo = max(span / max(n - 1, 1) * 0.25, 1e-300)
    if not d_max > 2 * lo:
        return np.empty(0)
    edges = np.exp(np.arange(math.log(lo), math.log(d_max) + rel, rel))
    h = np.zeros(edges.size - 1)
    c = 1
    while c < n:
        d = t[c:] - t[:-c]
        if d.size == 0 or d.min() > d_max:
            break
        h += np.histogram(d, edges)[0]
        c += 1
    centre = np.sqrt(edges[:-1] * edges[1:])
    expected = n * (n / span) * centre * rel  # random pulses: n rho pairs per unit separation
    ratio = h / np.maximum(expected, 1e-300)
    left, right = np.r_[-np.inf, ratio[:-1]], np.r_[ratio[1:], -np.inf]
    peaks = np.flatnonzero((ratio > left) & (ratio >= right) & (ratio > 2.0) & (h >= 6))
    return centre[peaks[np.argsort(-ratio[peaks])][:top]]


def _offsets(t: np.ndarray, lag: float) -> np.ndarray:
    """For every pulse, the offset of the pulse nearest to it + lag from that point."""
    target = t + lag
    j = np.clip(np.searchsorted(t, target), 1, t.size - 1)
    near = np.where(np.abs(t[j] - target) < np.abs(t[j - 1] - target), t[j], t[j - 1])
    keep = target <= t[-1]
    return (near - target)[keep]


def _core(d: np.ndarray, width: float) -> tuple[float, float, int]:
    """(centre, deviation, count) of the peak in offsets d, within +-width: median and MAD, clipped
    to 3 deviations until they settle (the chance offsets spread flat over the window)."""
    d = d[np.abs(d) <= width]
    centre, dev = 0.0, width
    for _ in range(30):
        if d.size < 4:
            break
        centre = float(np.median(d))
        new = _MAD * float(np.median(np.abs(d - centre)))
        d = d[np.abs(d - centre) <= 3 * max(new, 1e-300)]
        if new <= 0 or abs(new - dev) <= 1e-3 * dev:
            dev = new
            break
        dev = new
    return centre, dev, int(d.size)


def check_magnitude(toa: np.ndarray) -> None:
    """Refuse (NotApplicable) TOAs the blind PRI analysis cannot run on: it squares PRIs and the TOA noise,
    which overflowed float64 (a traceback) for TOAs of 1e300."""
    top = float(np.abs(toa).max(initial=0.0))
    if not top <= MAX_MAGNITUDE:
        raise NotApplicable(f"TOAs up to {top:.3g}: the blind PRI analysis handles TOAs up to {MAX_MAGNITUDE:g} in "
                            "size")


def estimate_noise(toa: np.ndarray) -> Noise:
    """The white TOA noise and PRI jitter of the trains in `toa` (sorted), from the narrowest of the
    strongest difference peaks (module doc).  A record with no periodic peak gives zeros and NaN."""
    t = np.ascontiguousarray(toa, dtype=np.float64)
    check_magnitude(t)
    if t.size < 12:
        return Noise(0.0, 0.0, math.nan)
    span = float(t[-1] - t[0])
    gap = span / (t.size - 1)
    best: tuple[float, float, float, float] | None = None  # (s_1, sigma_w, sigma_v, T)
    for period in _candidates(t, min(16 * gap, span / 6)):
        widths = []
        for m in (1, 2, 3):
            centre, dev, count = _core(_offsets(t, m * period), 0.05 * m * period)
            # a train's peak: its pulses' successors, at least a quarter of the slots a train of that PRI has
            if count < max(6, 0.25 * span / (m * period)) or dev <= 0:
                break
            widths.append(dev)
            if m == 1:
                period = period + centre  # refined: later peaks are looked for at m times it
        if not widths:
            continue
        s2 = np.square(widths)
        if len(widths) >= 2:  # s_m^2 = 2 sw^2 + m sv^2, least squares with both terms >= 0
            m = np.arange(1, len(widths) + 1, dtype=np.float64)
            slope = max(float(np.polyfit(m, s2, 1)[0]), 0.0)
            white = max(float(np.mean(s2 - slope * m)), 0.0) / 2
            if white == 0.0:
                slope = float(np.sum(m * s2) / np.sum(m * m))
        else:
            slope, white = 0.0, float(s2[0]) / 2
        cand = (float(widths[0]), math.sqrt(white), math.sqrt(slope), float(period))
        if best is None or cand[0] < best[0]:
            best = cand
    if best is None:
        return Noise(0.0, 0.0, math.nan)
    return Noise(best[1], best[2], best[3])

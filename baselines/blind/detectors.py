"""The three PRI detectors as `pipeline.Detector`s, with their bin widths set from the TOA noise."""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from baselines.blind.histograms import Candidate, cdif_candidates, sdif_candidates
from baselines.blind.pri_transform import pri_transform_candidates


def check_number(name: str, value: object, low: float, high: float, *, low_open: bool = True,
                 high_open: bool = False) -> float:
    """`value` as a float if it is a finite number in the range (low, high] (or as the flags say), else
    one ValueError line naming the parameter, its value and the range."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
    if not ok:
        lo, hi = "(" if low_open else "[", ")" if high_open else "]"
        raise ValueError(f"{name}={value!r} is invalid: a number in {lo}{low:g}, {high:g}{hi}")
    return float(value)


def _levels(t: np.ndarray, pri_max: float) -> int:
    """Difference levels needed to reach pri_max: about as many pulses as fall in pri_max."""
    mean_gap = float(t[-1] - t[0]) / max(t.size - 1, 1)
    return int(min(max(2, math.ceil(1.5 * pri_max / max(mean_gap, 1e-300))), 256))


class CDIF:
    """Mardia's cumulative difference histogram (threshold x D / tau, double-interval check)."""

    def __init__(self, x: float = 0.5):
        self.x = check_number("x", x, 0, 100)  # the threshold's multiple of D / tau

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        if t.size < 3:
            return iter(())
        width = max(3.0 * sigma, pri_max / 2000)
        return cdif_candidates(t, pri_min, pri_max, width, x=self.x, max_level=_levels(t, pri_max))


class SDIF:
    """Milojevic & Popovic's sequential difference histogram (threshold x (E - c) exp(-tau / (k N)))."""

    def __init__(self, x: float = 0.1, k: float = 0.3):
        # x: the threshold's share of the pulses left (E - c); k: its exponential decay over tau / N
        self.x, self.k = check_number("x", x, 0, 1), check_number("k", k, 0, 100)

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        if t.size < 3:
            return iter(())
        width = max(3.0 * sigma, pri_max / 2000)
        return sdif_candidates(t, pri_min, pri_max, width, x=self.x, k=self.k, max_level=_levels(t, pri_max))


class PRITransform:
    """Nishiguchi & Kobayashi's jitter-robust PRI transform (one 'level': all peaks at once)."""

    def __init__(self, eps: float = 0.01, alpha: float = 0.3, beta: float = 0.15, gamma: float = 4.0):
        # eps: the relative jitter a bin tolerates; alpha, beta: the peak thresholds' shares; gamma: the noise
        # threshold's multiple of its standard deviation
        self.eps = check_number("eps", eps, 0, 1, high_open=True)
        self.alpha, self.beta = check_number("alpha", alpha, 0, 1), check_number("beta", beta, 0, 1)
        self.gamma = check_number("gamma", gamma, 0, 1000)

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        width = pri_min * 1e-3  # the minimum spacing: bins are tau^2 / (8 D) apart (see bin_centres)
        yield pri_transform_candidates(t, pri_min, pri_max, width, eps=self.eps, sigma=sigma, alpha=self.alpha,
                                       beta=self.beta, gamma=self.gamma)

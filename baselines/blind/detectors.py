"""The three PRI detectors as `pipeline.Detector`s, with their bin widths set from the TOA noise."""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from baselines.blind.histograms import Candidate, cdif_candidates, sdif_candidates
from baselines.blind.pri_transform import pri_transform_candidates
from deint_env.params import Param, declare


def _number(name: str, default: float, meaning: str, high: float, high_open: bool = False) -> Param:
    """A detector's threshold: a number in (0, high] (or (0, high))."""
    return Param(name, float, default, meaning, low=0, high=high, low_open=True, high_open=high_open)


def _levels(t: np.ndarray, pri_max: float) -> int:
    """Difference levels needed to reach pri_max: about as many pulses as fall in pri_max."""
    mean_gap = float(t[-1] - t[0]) / max(t.size - 1, 1)
    return int(min(max(2, math.ceil(1.5 * pri_max / max(mean_gap, 1e-300))), 256))


class CDIF:
    """Mardia's cumulative difference histogram (threshold x D / tau, double-interval check)."""

    PARAMS = declare(_number("x", 0.5, "CDIF: the threshold's multiple of D / tau", 100))

    def __init__(self, x: float = 0.5):
        self.PARAMS.check(locals())
        self.x = float(x)

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        if t.size < 3:
            return iter(())
        width = max(3.0 * sigma, pri_max / 2000)
        return cdif_candidates(t, pri_min, pri_max, width, x=self.x, max_level=_levels(t, pri_max))


class SDIF:
    """Milojevic & Popovic's sequential difference histogram (threshold x (E - c) exp(-tau / (k N)))."""

    PARAMS = declare(_number("x", 0.1, "SDIF: the threshold's share of the pulses left (E - c)", 1),
                     _number("k", 0.3, "SDIF: the threshold's exponential decay over tau / N", 100))

    def __init__(self, x: float = 0.1, k: float = 0.3):
        self.PARAMS.check(locals())
        self.x, self.k = float(x), float(k)

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        if t.size < 3:
            return iter(())
        width = max(3.0 * sigma, pri_max / 2000)
        return sdif_candidates(t, pri_min, pri_max, width, x=self.x, k=self.k, max_level=_levels(t, pri_max))


class PRITransform:
    """Nishiguchi & Kobayashi's jitter-robust PRI transform (one 'level': all peaks at once)."""

    PARAMS = declare(_number("eps", 0.01, "the relative jitter a bin tolerates", 1, high_open=True),
                     _number("alpha", 0.3, "the threshold alpha T_obs / tau: its share of the intervals a train "
                             "would have", 1),
                     _number("beta", 0.15, "the threshold beta C: its share of the bin's pair count (coherence)", 1),
                     _number("gamma", 4.0, "the noise threshold's multiple of its standard deviation", 1000))

    def __init__(self, eps: float = 0.01, alpha: float = 0.3, beta: float = 0.15, gamma: float = 4.0):
        self.PARAMS.check(locals())
        self.eps, self.alpha, self.beta, self.gamma = float(eps), float(alpha), float(beta), float(gamma)

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        width = pri_min * 1e-3  # the minimum spacing: bins are tau^2 / (8 D) apart (see bin_centres)
        yield pri_transform_candidates(t, pri_min, pri_max, width, eps=self.eps, sigma=sigma, alpha=self.alpha,
                                       beta=self.beta, gamma=self.gamma)

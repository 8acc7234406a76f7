"""The three PRI detectors as `pipeline.Detector`s, with their bin widths set from the TOA noise."""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from baselines.blind.histograms import Candidate, cdif_candidates, sdif_candidates
from baselines.blind.pri_transform import pri_transform_candidates


def _levels(t: np.ndarray, pri_max: float) -> int:
    """Difference levels needed to reach pri_max: about as many pulses as fall in pri_max."""
    mean_gap = float(t[-1] - t[0]) / max(t.size - 1, 1)
    return int(min(max(2, math.ceil(1.5 * pri_max / max(mean_gap, 1e-300))), 256))


class CDIF:
    """Mardia's cumulative difference histogram (threshold x D / tau, double-interval check)."""

    def __init__(self, x: float = 0.5):
        self.x = x

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        if t.size < 3:
            return iter(())
        width = max(3.0 * sigma, pri_max / 2000)
        return cdif_candidates(t, pri_min, pri_max, width, x=self.x, max_level=_levels(t, pri_max))


class SDIF:
    """Milojevic & Popovic's sequential difference histogram (threshold x (E - c) exp(-tau / (k N)))."""

    def __init__(self, x: float = 0.1, k: float = 0.3):
        self.x, self.k = x, k

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        if t.size < 3:
            return iter(())
        width = max(3.0 * sigma, pri_max / 2000)
        return sdif_candidates(t, pri_min, pri_max, width, x=self.x, k=self.k, max_level=_levels(t, pri_max))


class PRITransform:
    """Nishiguchi & Kobayashi's jitter-robust PRI transform (one 'level': all peaks at once)."""

    def __init__(self, eps: float = 0.01, alpha: float = 0.3, beta: float = 0.15, gamma: float = 4.0):
        self.eps, self.alpha, self.beta, self.gamma = eps, alpha, beta, gamma

    def __call__(self, t: np.ndarray, sigma: float, pri_min: float, pri_max: float) -> Iterator[list[Candidate]]:
        width = pri_min * 1e-3  # the minimum spacing: bins are tau^2 / (8 D) apart (see bin_centres)
        yield pri_transform_candidates(t, pri_min, pri_max, width, eps=self.eps, sigma=sigma, alpha=self.alpha,
                                       beta=self.beta, gamma=self.gamma)

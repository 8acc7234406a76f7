"""The PRI transform, jitter-robust version (Nishiguchi & Kobayashi, "Improved algorithm for
estimating pulse repetition intervals", IEEE Trans. AES 36(2), 2000).

The PRI transform of TOAs t_1 < ... < t_N is D(tau) = sum_{m<n} delta(tau - (t_n - t_m))
exp(2 pi i t_n / (t_n - t_m)): the differences of a periodic train add with one phase at its PRI
and with alternating phases at its multiples, so the subharmonics that plague difference
histograms cancel.  The improved algorithm makes it survive jitter:
- overlapping bins: bin k (centre tau_k, centres b apart) takes every difference within eps tau_k of
  tau_k (plus, here, 2 sqrt(2) sigma_w: our TOA jitter is absolute, the paper's PRI jitter relative),
  so a jittered difference still reaches its bin;
- shifted time origins: the phase (t_n - O_k) / (t_n - t_m) is measured from a per-bin origin O_k
  instead of t = 0, and O_k follows the pairs: it starts at the bin's first pair's first pulse and
  moves forward by whole bin periods tau_k to within one tau_k of each new pair's t_m (from t = 0
  the jitter of each difference, multiplied by t_n / tau, would scramble the phases of late pulses;
  our reading moves the origin in steps of tau_k so that a subharmonic's alternating phases, and a
  random pair's random one, are kept, which needs bins within T^2 / (4 D) of the PRI: `bin_centres`).
Detection: |D_k| must exceed the three thresholds of the paper: alpha T_obs / tau_k (the intervals a
train of that PRI would have), beta C_k (C_k the bin's pair count: coherence) and
gamma sqrt(T_obs rho^2 w_k) (rho the pulse density, w_k the bin width: the random-pair noise level).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from baselines.blind.histograms import Candidate


@numba.njit(cache=True)
def _transform(t, centres, half, pri_min, pri_max, eps, jit, shift):  # pragma: no cover - numba
    kb = centres.size
    d_re = np.zeros(kb)
    d_im = np.zeros(kb)
    count = np.zeros(kb)
    origin = np.full(kb, -np.inf) if shift else np.zeros(kb)
    n = t.size
    hmax = half[kb - 1]
    for j in range(1, n):
        for m in range(j - 1, -1, -1):
            tau = t[j] - t[m]
            if tau < pri_min - hmax:
                continue
            if tau > pri_max + hmax:
                break
            # the bins whose acceptance interval [tau_k - half_k, tau_k + half_k] can hold tau
            reach = 1.1 * eps * tau + jit + 1e-12
            k0 = np.searchsorted(centres, (tau - reach) / (1.0 + 1.1 * eps))
            k1 = np.searchsorted(centres, (tau + reach) / (1.0 - 1.1 * eps), side="right")
            for k in range(k0, min(k1, kb)):
                if abs(tau - centres[k]) > half[k]:
                    continue
                if shift:
                    if origin[k] == -np.inf:  # the bin's first pair: its first pulse is the origin
                        origin[k] = t[m]
                    elif t[m] - origin[k] >= centres[k]:  # shift by whole bin periods, up to t_m
                        origin[k] += centres[k] * math.floor((t[m] - origin[k]) / centres[k])
                ph = 2.0 * math.pi * (t[j] - origin[k]) / tau
                d_re[k] += math.cos(ph)
                d_im[k] += math.sin(ph)
                count[k] += 1.0
    return np.sqrt(d_re * d_re + d_im * d_im), count


def bin_centres(pri_min: float, pri_max: float, duration: float, min_width: float) -> np.ndarray:
    """Bin centres spaced tau^2 / (8 D) apart (at least min_width): a bin's origin moves in steps of its
    centre tau_k, so over a record of duration D a train of PRI T keeps its phase only if
    |tau_k - T| D / T < T / 4, i.e. |tau_k - T| < T^2 / (4 D)."""
    out = [pri_min]
    while out[-1] < pri_max:
        out.append(out[-1] + max(out[-1] ** 2 / (8.0 * max(duration, 1e-300)), min_width))
    return np.asarray(out)


def pri_transform(t: np.ndarray, pri_min: float, pri_max: float, width: float, eps: float,
                  sigma: float, improved: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(bin centres, |D_k|, pair counts C_k, bin half-widths) of the jitter-robust PRI transform;
    improved=False gives the original transform (disjoint bins `width` apart, phases from t = 0)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    duration = float(t[-1] - t[0]) if t.size > 1 else 1.0
    if improved:
        centres = bin_centres(pri_min, pri_max, duration, width)
        jit = 2 * math.sqrt(2) * sigma
        half = np.maximum(eps * centres + jit, 0.5 * np.diff(centres, append=centres[-1] + width))
    else:
        centres = np.arange(pri_min + width / 2, pri_max, width)
        jit = 0.0
        half = np.full(centres.size, width / 2)
        eps = 0.0
    mag, count = _transform(t, centres, half, pri_min, pri_max, eps, float(np.max(half)) if not improved else jit,
                            bool(improved))
    return centres, mag, count, half


def pri_transform_candidates(t: np.ndarray, pri_min: float, pri_max: float, width: float, *, eps: float = 0.01,
                             sigma: float = 0.0, alpha: float = 0.3, beta: float = 0.15,
                             gamma: float = 4.0) -> list[Candidate]:
    """Peaks of |D| over the paper's three thresholds, smallest PRI first."""
    if t.size < 3:
        return []
    centres, mag, count, half = pri_transform(t, pri_min, pri_max, width, eps, sigma)
    t_obs = float(t[-1] - t[0])
    rho = t.size / max(t_obs, 1e-300)
    thr = np.maximum.reduce([alpha * t_obs / centres, beta * count, gamma * np.sqrt(t_obs * rho**2 * 2 * half)])
    over = mag > thr
    left = np.concatenate([[-np.inf], mag[:-1]])
    right = np.concatenate([mag[1:], [-np.inf]])
    peaks = np.flatnonzero(over & (mag > left) & (mag >= right))
    # the overlapping bins make a flat-topped peak eps tau wide: the PRI is known to about that
    return [Candidate(float(centres[i]), float(eps * centres[i] + sigma + width), float(mag[i] / thr[i]))
            for i in peaks]

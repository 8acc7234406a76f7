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
from deint_env.errors import DeintError, NotApplicable

MAX_BINS = 1_000_000  # PRI bins of one transform (the suites need ~10^4)


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
            # coincident pulses (equal TOAs: steps below float64's at 1e15) have no PRI; their phase divided by 0
            if tau < pri_min - hmax or tau <= 0.0:
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
    # no two pulses of the record are further apart than its duration, so bins past twice it stay empty; without
    # this stop a pri_max of 1e300 squared the centres past float64 (OverflowError)
    pri_max = min(pri_max, max(2.0 * duration, pri_min))
    while out[-1] < pri_max:
        out.append(out[-1] + max(out[-1] ** 2 / (8.0 * max(duration, 1e-300)), min_width))
        if len(out) > MAX_BINS:  # pri_min=1e-9 over a record of 5000 asked for ~10^8 bins (GiBs, minutes)
            raise NotApplicable(f"PRIs from {pri_min:.3g} to {pri_max:.3g} over a record of {duration:.3g} need more "
                                f"than {MAX_BINS} PRI bins; raise pri_min")
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
    """Peaks of |D| over the paper's three thresholds, smallest PRI first (none from coincident pulses)."""
    if t.size < 3 or not t[-1] > t[0]:
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


@numba.njit(cache=True)
def _transform_nk(t, centres, eps, zeta0):  # pragma: no cover - numba
    """The paper's own origin rule on K bins of relative half-width eps (see `pri_transform_nk`)."""
    kb = centres.size
    d_re = np.zeros(kb)
    d_im = np.zeros(kb)
    count = np.zeros(kb)
    origin = np.full(kb, np.nan)
    step = centres[1] - centres[0]
    lo = centres[0] - step / 2
    for j in range(1, t.size):
        for m in range(j - 1, -1, -1):
            tau = t[j] - t[m]
            if tau > centres[kb - 1] * (1.0 + eps):
                break
            # bin k takes tau when (1 - eps) tau_k <= tau <= (1 + eps) tau_k
            k0 = max(int(math.ceil((tau / (1.0 + eps) - lo) / step - 0.5)), 0)
            k1 = min(int(math.floor((tau / (1.0 - eps) - lo) / step - 0.5)), kb - 1)
            for k in range(k0, k1 + 1):
                if math.isnan(origin[k]):
                    origin[k] = t[j]
                # move the origin to t_j when t_j lies a whole number nu of bin periods after it: one
                # period from a pair that starts at the origin, or nu >= 2 within relative error zeta0
                eta0 = (t[j] - origin[k]) / centres[k]
                nu = math.floor(eta0 + 0.5)
                if (nu == 1 and t[m] == origin[k]) or (nu >= 2 and abs(eta0 / nu - 1.0) <= zeta0):
                    origin[k] = t[j]
                ph = 2.0 * math.pi * (t[j] - origin[k]) / centres[k]
                d_re[k] += math.cos(ph)
                d_im[k] += math.sin(ph)
                count[k] += 1.0
    return np.sqrt(d_re * d_re + d_im * d_im), count


def pri_transform_nk(t: np.ndarray, tau_min: float, tau_max: float, n_bins: int, eps: float,
                     zeta0: float = 0.03) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(bin centres, |D_k|, pair counts C_k, bin widths b_k = 2 eps tau_k) of the improved transform as the
    paper states it: K bins tau_k = tau_min + (k - 1/2)(tau_max - tau_min)/K, overlapping (bin k takes every
    difference within eps tau_k of tau_k, eps the largest relative jitter), phases (t_n - O_k) / tau_k from
    a per-bin origin O_k that is the bin's first pair's later pulse and is moved to t_n whenever t_n lies
    about a whole number of bin periods after it (`_transform_nk`).  Resetting the origin at the train's own
    pulses keeps the phase of a mean PRI near 0 even on a coarse grid of K bins, where `pri_transform`'s
    whole-period steps need bins within T^2 / (4 D) of the PRI."""
    if not 0.0 < eps < 1.0 or n_bins < 2 or not tau_max > tau_min >= 0.0:
        raise DeintError("pri_transform_nk needs 0 < eps < 1, n_bins >= 2 and 0 <= tau_min < tau_max")
    t = np.ascontiguousarray(np.sort(t), dtype=np.float64)
    centres = tau_min + (np.arange(n_bins) + 0.5) * (tau_max - tau_min) / n_bins
    mag, count = _transform_nk(t, centres, float(eps), float(zeta0))
    return centres, mag, count, 2.0 * eps * centres


def original_pri_transform(t: np.ndarray, tau_min: float, tau_max: float, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """(bin centres, |D_k|) of the original transform on K disjoint bins, phases 2 pi t_n / (t_n - t_m) from t = 0."""
    t = np.ascontiguousarray(np.sort(t), dtype=np.float64)
    width = (tau_max - tau_min) / n_bins
    centres = tau_min + (np.arange(n_bins) + 0.5) * width
    i, j = np.triu_indices(t.size, 1)
    tau = t[j] - t[i]
    keep = (tau > tau_min) & (tau <= tau_max)
    k = np.minimum(((tau[keep] - tau_min) / width).astype(np.int64), n_bins - 1)
    d = np.bincount(k, np.cos(2 * np.pi * t[j][keep] / tau[keep]), n_bins) \
        + 1j * np.bincount(k, np.sin(2 * np.pi * t[j][keep] / tau[keep]), n_bins)
    return centres, np.abs(d)


def nk_thresholds(t: np.ndarray, centres: np.ndarray, count: np.ndarray, widths: np.ndarray, alpha: float = 0.3,
                  beta: float = 0.15, gamma: float = 4.0) -> np.ndarray:
    """The paper's detection level per bin: max(alpha T / tau_k, beta C_k, gamma sqrt(T rho^2 b_k))."""
    t_obs = float(t.max() - t.min())
    rho = t.size / t_obs
    return np.maximum.reduce([alpha * t_obs / centres, beta * count, gamma * np.sqrt(t_obs * rho**2 * widths)])


def threshold_peaks(centres: np.ndarray, mag: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """One PRI per run of adjacent bins over the threshold (overlapping bins spread a peak over
    about 2 eps tau / step bins): the centre of the run's largest bin."""
    over = np.concatenate([[False], mag > thr, [False]])
    starts = np.flatnonzero(~over[:-1] & over[1:])
    ends = np.flatnonzero(over[:-1] & ~over[1:])
    return np.array([centres[s + np.argmax(mag[s:e])] for s, e in zip(starts, ends)])

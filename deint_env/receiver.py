"""The receiver's waveform front end: Dai & Mendel's detection-oriented Kalman filter (DM89) for
Bernoulli-Gaussian spike trains, and its two uses in deint-bench (docs/design.md section 8):

(a) the waveform front end `detect_pulses`: the pulse train sampled onto a grid of spikes
    mu(k) = q(k) r(k), convolved with a channel response v(k), plus white noise n(k) (DM89 (1)-(3)),
    then detected online by the DOKF, so misses and false alarms come from detection (the simulator's
    `ScenarioSpec.waveform`);
(b) the innovation test `is_spurious` for trackers (baselines/pt.py imports it from here): Theorem 1's
    MAP rule (21)-(24) applied to a tracker's innovation, "spurious pulse" against "the predicted source's pulse".

The filter.  The channel V(z) = B(z)/A(z) is realised in controllable canonical form (`realize`):
x(k) = Phi x(k-1) + gamma mu(k-d), z(k) = h'x(k) + n(k), h' Phi^k gamma = v(k + d), where d is the
number of leading zeros of v: d = 0 is DM89's model (4)-(6), d = 1 is (7)-(8), whose detector
(Corollary 1, (27)-(30)) is the same with v(1) for v(0) and q(k-1|k) for q(k|k); the code takes any d.
Per sample: the innovation (10)-(11), the MAP detector (12) with the threshold T(k) of (21)-(22), the
gain and covariances (14)-(17) with the input variance sigma_r^2 only when a spike was detected (16),
and the amplitude estimate of Theorem 2 (25)-(26).  `DOKF` runs R independent channels at once
(arrays with a leading run axis), so one time loop serves one long run or many short ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from deint_env.scenario import DM89_CHANNEL  # noqa: F401  (DM89 section 4's ARMA channel; re-exported)


class StateSpace(NamedTuple):
    """A realisation (Phi, gamma, h) of v(k) = h' Phi^(k-d) gamma (k >= d), v(k) = 0 for k < d."""

    phi: np.ndarray
    gamma: np.ndarray
    h: np.ndarray
    delay: int

    @property
    def v_first(self) -> float:
        """v(d) = h' gamma: v(0) of (6) when d = 0, v(1) of (9) when d = 1."""
        return float(self.h @ self.gamma)

    def impulse_response(self, n: int) -> np.ndarray:
        v = np.zeros(n)
        x = self.gamma.copy()
        for k in range(self.delay, n):
            v[k] = self.h @ x
            x = self.phi @ x
        return v


def realize(b, a) -> StateSpace:
    """Controllable canonical form of V(z) = (b0 + b1 z^-1 + ...) / (a0 + a1 z^-1 + ...).

    With w(k) = mu(k-d) - a1 w(k-1) - ... (a normalised to a0 = 1) and the state
    x(k) = (w(k), ..., w(k-n+1)), the output is z(k) = sum_i b_{d+i} w(k-i): Phi is the companion
    matrix of a, gamma = e_1 and h the numerator after its d leading zeros."""
    b = np.trim_zeros(np.atleast_1d(np.asarray(b, dtype=np.float64)), "b")
    a = np.trim_zeros(np.atleast_1d(np.asarray(a, dtype=np.float64)), "b")
    if a.size == 0 or a[0] == 0:
        raise ValueError("channel denominator must have a nonzero leading coefficient a0")
    if b.size == 0 or not np.any(b):
        raise ValueError("channel numerator must not be all zeros")
    b, a = b / a[0], a / a[0]
    delay = int(np.flatnonzero(b)[0])
    b = b[delay:]
    n = max(a.size - 1, b.size)
    phi = np.zeros((n, n))
    phi[0, : a.size - 1] = -a[1:]
    phi[1:, :-1] += np.eye(n - 1)
    gamma = np.zeros(n)
    gamma[0] = 1.0
    h = np.zeros(n)
    h[: b.size] = b
    return StateSpace(phi, gamma, h, delay)


def threshold(eta0, v_first: float, sigma_r: float, lam: float):
    """Theorem 1, (21)-(22): T = v^2 sigma_r^2 xi (1 + xi) {ln(1 + 1/xi) - 2 ln(lam / (1 - lam))} with
    xi = eta0 / (v^2 sigma_r^2), eta0 the innovation variance under q = 0 (15)-(16)."""
    return _threshold(np.asarray(eta0, dtype=np.float64), v_first * v_first * sigma_r * sigma_r, _log_odds(lam))


def _log_odds(lam: float) -> float:
    return -2.0 * math.log(lam / (1.0 - lam))


def _threshold(eta0, g, log_odds):
    """(21) with g = eta1 - eta0 = v^2 sigma_r^2: g xi (1 + xi) = eta0 eta1 / g, 1 + 1/xi = eta1 / eta0."""
    return eta0 * (eta0 + g) / g * (np.log1p(g / eta0) + log_odds)


def is_spurious(e, s, lam: float, spread_var):
    """Theorem 1's MAP rule on a tracker's innovation e with variance s (q = 0: the pulse is the
    predicted source's) against q = 1: a spurious pulse, an extra impulse of variance `spread_var` on
    top of s (e.g. T^2 / 12, a uniform arrival over one period).  `lam` is the probability that a
    received pulse is spurious; a priors' spurious_rate r (spurious per source pulse) gives
    lam = r / (1 + r).  Elementwise; lam = 0 never calls a pulse spurious."""
    if lam <= 0.0:
        return np.zeros(np.shape(e), dtype=bool) if np.ndim(e) else False
    if lam >= 1.0:
        return np.ones(np.shape(e), dtype=bool) if np.ndim(e) else True
    e, s, spread_var = np.asarray(e, dtype=np.float64), np.asarray(s, dtype=np.float64), np.asarray(spread_var)
    # (21) with eta0 = s and eta1 - eta0 = spread_var in the role of v^2(0) sigma_r^2
    out = e * e > _threshold(s, spread_var, _log_odds(lam))
    return out if out.ndim else bool(out)


class DOKF:
    """The detection-oriented Kalman filter (10)-(17) on R independent runs of one channel.

    `step(z)` takes the R samples z(k) and returns (q_hat, mu_hat): the detection of q(k-d) and the
    amplitude estimate mu_hat(k-d|k) of Theorem 2 (25)-(26) / (30).  x(0) = 0 is known (DM89 section 2),
    so P(0|0) = 0."""

    def __init__(self, system: StateSpace, lam: float, sigma_r: float, sigma_n: float, runs: int = 1):
        if not 0.0 < lam < 1.0:
            raise ValueError(f"lam={lam!r} must be in (0, 1)")
        if not sigma_r > 0 or not sigma_n > 0:
            raise ValueError("sigma_r and sigma_n must be > 0")
        self.sys = system
        self.lam, self.sigma_r, self.sigma_n = float(lam), float(sigma_r), float(sigma_n)
        n = system.phi.shape[0]
        self.x = np.zeros((runs, n))
        self.p = np.zeros((runs, n, n))
        self._phi_t = system.phi.T.copy()
        self._g = system.v_first ** 2 * sigma_r ** 2  # eta1 - eta0
        self._log_odds = _log_odds(lam)
        self._input_var = sigma_r * sigma_r * np.outer(system.gamma, system.gamma)  # sigma_r^2 gamma gamma'
        self._input_h = sigma_r * sigma_r * system.v_first * system.gamma  # sigma_r^2 gamma gamma' h
        self._gain = system.v_first * sigma_r * sigma_r  # (26) without 1 / eta_q

    def step(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self.sys.h
        x_pred = self.x @ self._phi_t  # (11)
        innov = z - x_pred @ h  # (10)
        p0 = self.sys.phi @ self.p @ self._phi_t  # P_0(k|k-1) of (16)
        ph = p0 @ h
        eta0 = ph @ h + self.sigma_n ** 2  # (15) under q = 0
        q = innov * innov > _threshold(eta0, self._g, self._log_odds)  # (12), (21)-(22)
        qf = q.astype(np.float64)
        ph += qf[:, None] * self._input_h  # P_q(k|k-1) h, P_q of (16)
        eta = eta0 + qf * self._g  # (15): eta_1 = eta_0 + v^2 sigma_r^2
        k = ph / eta[:, None]  # (14)
        self.x = x_pred + k * innov[:, None]  # (13)
        # (17): (I - K h') P_q = P_q - K (P_q h)'
        self.p = p0 + qf[:, None, None] * self._input_var - k[:, :, None] * ph[:, None, :]
        mu = qf * (self._gain / eta) * innov  # (25)-(26)
        return q, mu


def run_dokf(z: np.ndarray, system: StateSpace, lam: float, sigma_r: float,
             sigma_n: float) -> tuple[np.ndarray, np.ndarray]:
    """The DOKF over observations z of shape (N,) or (R, N).  Returns (q_hat, mu_hat) aligned with
    the input spikes: q_hat[..., j] is the detection of q(j), made online at sample j + d; the last d
    spikes are never decided (False, 0)."""
    z = np.asarray(z, dtype=np.float64)
    zz = np.atleast_2d(z)
    runs, n = zz.shape
    f = DOKF(system, lam, sigma_r, sigma_n, runs)
    q = np.zeros((runs, n), dtype=bool)
    mu = np.zeros((runs, n))
    d = system.delay
    for k in range(n):
        qk, mk = f.step(zz[:, k])
        if k >= d:
            q[:, k - d], mu[:, k - d] = qk, mk
    return (q[0], mu[0]) if z.ndim == 1 else (q, mu)


def match_detections(detected: np.ndarray, spikes: np.ndarray, tolerance: int = 1) -> np.ndarray:
    """One-to-one matching of detected sample indices to true spike sample indices (both sorted and
    unique): exact hits first, then within +-tolerance samples, nearest first and, at equal distance,
    late before early (a spike shows in z from its own sample on).  Returns, per detection, the index
    of its spike, or -1 (a false alarm)."""
    out = np.full(detected.size, -1, dtype=np.int64)
    taken = np.zeros(spikes.size, dtype=bool)
    for dist in range(tolerance + 1):
        for sign in ((0,) if dist == 0 else (-1, 1)):
            free = np.flatnonzero(out < 0)
            target = detected[free] + sign * dist
            j = np.searchsorted(spikes, target)
            ok = j < spikes.size
            ok[ok] = spikes[j[ok]] == target[ok]
            for i, jj in zip(free[ok].tolist(), j[ok].tolist()):
                if not taken[jj]:
                    taken[jj] = True
                    out[i] = jj
    return out


@dataclass(frozen=True)
class Detection:
    """What the front end delivers.  toa: detected times (sample index x sample period), sorted;
    amplitude: Theorem 2's estimates; pulse: per detection, the true pulse it is (the largest spike
    contribution when pulses coincide on one sample) or -1 for a false alarm; detection: per true
    pulse, the detection that carries it or -1 (missed; coincident pulses share one detection)."""

    toa: np.ndarray
    amplitude: np.ndarray
    pulse: np.ndarray
    detection: np.ndarray

    @property
    def n_false_alarms(self) -> int:
        return int(np.count_nonzero(self.pulse < 0))

    @property
    def n_missed(self) -> int:
        return int(np.count_nonzero(self.detection < 0))


def detect_pulses(toa, amplitude, sample_period: float, channel, noise_std: float, lam: float, sigma_r: float,
                  rng: np.random.Generator, tolerance: int = 1) -> Detection:
    """The waveform front end (a): pulses -> spikes on the grid k * sample_period (pulse at sample
    round(toa / Ts), its amplitude as the spike height; coincident spikes add) -> channel
    `channel` = (b, a) (e.g. `DM89_CHANNEL`) -> plus N(0, noise_std^2) noise drawn from `rng` -> the
    DOKF with spike probability `lam` per sample and spike spread `sigma_r` -> detections.  A
    detection within +-`tolerance` samples of a true spike is that spike's pulse; others are false
    alarms.  For a pulse train, lam ~ (pulses per unit time) x Ts and sigma_r ~ the rms amplitude.
    TOAs must be finite and >= 0; the cost is one DOKF step (~20 us) per sample up to the last TOA."""
    from scipy.signal import lfilter

    toa = np.asarray(toa, dtype=np.float64)
    amplitude = np.broadcast_to(np.asarray(amplitude, dtype=np.float64), toa.shape)
    if not sample_period > 0:
        raise ValueError(f"sample_period={sample_period!r} must be > 0")
    if toa.size and (not np.all(np.isfinite(toa)) or toa.min() < 0):
        raise ValueError("toa must be finite and >= 0")
    system = realize(*channel)
    idx = np.rint(toa / sample_period).astype(np.int64)
    n = (int(idx.max()) if idx.size else 0) + system.delay + tolerance + 1
    mu = np.zeros(n)
    np.add.at(mu, idx, amplitude)
    z = lfilter(*channel, mu) + noise_std * rng.standard_normal(n)
    q, mu_hat = run_dokf(z, system, lam, sigma_r, noise_std)
    det = np.flatnonzero(q)
    spikes, inverse = np.unique(idx, return_inverse=True)
    spike_of_det = match_detections(det, spikes, tolerance)
    # each spike's primary pulse: the largest |amplitude| among the pulses on that sample
    order = np.lexsort((-np.abs(amplitude), inverse))
    primary = order[np.searchsorted(inverse[order], np.arange(spikes.size))]
    pulse = np.where(spike_of_det >= 0, primary[spike_of_det], -1)
    det_of_spike = np.full(spikes.size, -1, dtype=np.int64)
    det_of_spike[spike_of_det[spike_of_det >= 0]] = np.flatnonzero(spike_of_det >= 0)
    return Detection(toa=det * sample_period, amplitude=mu_hat[det], pulse=pulse, detection=det_of_spike[inverse])

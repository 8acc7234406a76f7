"""EKF bank on the sampled pulse-count signal (Conroy & Moore 2000, "CM00"): policy `ekf-bank`.

Signal model (CM00 section II).  The receiver is sampled every `Ts` (time units of the episode) from
an origin t0; y_k is the number of pulses received with TOA <= t0 + k Ts.  Each train i has a PRF
f_i, here in cycles per *sample* (f_i = Ts / T_i), and a phase theta_i in [0, 2 pi): its pulse n >= 0
arrives at sample (2 pi n + theta_i) / (2 pi f_i).  The state x = (f_1..f_M, theta_1..theta_M) is
constant (Q = 0), (1)-(2).  By default Ts is the shortest prior period / 10 rounded down to two
significant digits (CM00 sampled at 100 kHz, ~10x the highest PRF): a round rate rather than one tied
to the priors, since a grid commensurate with a train sees only a few sub-sample phases of it.

Counting convention.  CM00's (3) writes h^(i) = f k - theta/2pi - r = floor(f k - theta/2pi).  For
theta in [0, 2 pi) that is the number of pulses n >= 0 at or before sample k *minus one* (it is -1
before the first pulse), so we count
    count_i(k) = floor(f k - u) + floor(u) + 1,   u = theta / 2 pi,
which is exactly the number of train-i pulses in [t0, t0 + k Ts] for u in [0, 1), and for any u the
number of pulses of the train extended periodically in both directions -- so a phase that an update
pushes out of [0, 2 pi) is still the same train (the model is 2 pi-periodic in theta).  Summed over
trains it matches the observed y_k exactly on a noise-free train (tests check it).

Smoothing (4) with A = 1 and the same +1: h^s_i = (f k - u + 1/2) + sin(2 pi (f k - u)) / pi, whose
derivatives are CM00's (7): dh/df = k (1 + 2 cos), dh/dtheta = -(1 + 2 cos) / 2 pi.  The EKF (6)-(8)
linearises with these but innovates with the *non-smooth* count, y_k - h_k(x_hat) ("the nonsmooth
estimate of the input signal is used in the state update").  Internally the phase is kept in cycles,
u = theta / 2 pi (P0_uu = (pi^2/3) / (2 pi)^2 = 1/12, dh/du = -(1 + 2 cos)): the EKF is invariant
under a linear change of state coordinates, so this is the same filter with one multiply less per
sample.  P0 = diag(f_hat^2 / 100, pi^2 / 3) (a 10 % PRF error, a uniform phase), R = 10, or 20 when
the TOA jitter is at least 40 % of the shortest prior period (CM00 IV-B used 20 at 51 and 72 %).

The bank (CM00 IV-A): K filters start at the prior PRFs and at independent uniform random phases
(from `policy_rng`), or, when the priors give phases, filter 0 at them and the others drawn around
them; all K run at once as (K, 2M) states and (K, 2M, 2M) covariances (rank-one updates in place).
The filter with the least mean squared prediction error sum_k (y_k - h_k)^2 / k is the estimate.

Policy.  Online, lag 0.  At the j-th pulse (TOA t_j) the bank is advanced through every sample
before t_j (the count there is j - 1, constant since the previous pulse), then the pulse is labelled
with the best filter's trains: the train whose nearest predicted arrival is closest to t_j, in time
(`label_scale="time"`, the default: the TOA noise is the same for every train) or in units of each
train's period (`"period"`; measured worse on the CM00 scenarios).  The pulse's own count step
enters at the next sample.  The time origin t0 is 0 (the scenarios' origin, where every train's first
pulse lies within a period) unless the first TOA is further than the longest prior period from it;
then counting starts at the first pulse.
It never labels a pulse spurious: the count model has no spurious or missing pulses.

Limits.  An episode the sampled signal cannot represent in bounded time is refused as not applicable
(`NotApplicable`, at the pulse that shows it): a pulse more than MAX_SAMPLES_PER_PULSE samples per
pulse seen (plus MAX_SAMPLES_EXTRA) from the origin -- one outlying TOA, or a prior period so short
that the sampling step is tiny against the TOAs' span -- and a TOA whose float64 resolution is coarser
than the sampling step (TOAs near 1e300).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from deint_env.episode import Priors
from deint_env.errors import NotApplicable
from deint_env.params import SEED, Param, declare
from deint_env.policies import policy_rng

TWO_PI = 2.0 * math.pi
R_LOW, R_HIGH, R_SWITCH = 10.0, 20.0, 0.4  # CM00 IV-B: R = 10, or 20 from sigma_w / T_min = 51 %
# The run time is linear in the samples processed, so they are bounded by the pulses seen: at pulse j,
# at most MAX_SAMPLES_PER_PULSE (j + 1) + MAX_SAMPLES_EXTRA samples since the origin.  Every test
# episode of the published anchored suites stays over 9,700 samples inside (the most per pulse: up to
# 465 at the first pulses and ~130 later in MK94's single source with jitter 100 x its period; <= 10
# on CM00's scenarios).
MAX_SAMPLES_PER_PULSE, MAX_SAMPLES_EXTRA = 400, 10_000


# ---------------------------------------------------------------------------------------------------
# the signal model (CM00 (3), (4), (7)) in the paper's coordinates, for tests and figures
# ---------------------------------------------------------------------------------------------------
def pulse_count(f: np.ndarray, theta: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """Non-smooth count of each train at sample k: floor(f k - u) + floor(u) + 1, u = theta / 2 pi."""
    u = np.asarray(theta) / TWO_PI
    return np.floor(np.asarray(f) * k - u) + np.floor(u) + 1.0


def smooth_count(f: np.ndarray, theta: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """One-term Fourier smoothing of `pulse_count` (CM00 (4), A = 1, plus the count's +1)."""
    a = np.asarray(f) * k - (np.asarray(theta) / TWO_PI)
    return a + 0.5 + np.floor(np.asarray(theta) / TWO_PI) + np.sin(TWO_PI * a) / math.pi


def smooth_count_jacobian(f: np.ndarray, theta: np.ndarray, k: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(dh^s/df, dh^s/dtheta) per train, CM00 (7)."""
    c = np.cos(TWO_PI * np.asarray(f) * k - np.asarray(theta))
    return k * (1.0 + 2.0 * c), -(1.0 + 2.0 * c) / TWO_PI


def round_down(x: float, digits: int = 2) -> float:
    """x rounded down to `digits` significant digits."""
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return math.floor(x / scale * (1 + 1e-12)) * scale


def default_r(priors: Priors) -> float:
    return R_HIGH if priors.jitter_std >= R_SWITCH * float(np.min(priors.period)) else R_LOW


# ---------------------------------------------------------------------------------------------------
# the sampled-count policy frame shared by `ekf-bank` and `ekf-coupled`
# ---------------------------------------------------------------------------------------------------
PARAMS = declare(
    Param("n_filters", int, 16, "K: filters in the bank (random phase initialisations)", low=1, high=4096),
    Param("oversample", float, 10.0, "the least samples per shortest prior period (Ts = that period / oversample)",
          low=2),
    Param("ts", float, None, "the sample period (none: from oversample)", low=0, low_open=True, optional=True),
    Param("r", float, None, "the measurement noise R (none: 10, or 20 for jitter >= 40 % of the shortest period)",
          low=0, low_open=True, optional=True),
    Param("prf_std", float, 0.1, "the relative PRF std of P0 (CM00: 0.1)", low=0, high=1, low_open=True,
          high_open=True),
    Param("label_scale", str, "time", "labels from the predicted arrivals' distance in time or in periods",
          choices=("period", "time")),
    SEED,
)


class SampledBank:
    """Clock, bank initialisation, labelling and estimates of a bank of count-signal filters.

    Subclasses keep f, u as (K, M) arrays (cycles per sample, cycles) and implement
    `_init_filters(f0, u0, u_var)` and `_advance(k_stop, y)`: process samples self._k .. k_stop - 1,
    whose observed count is y, adding each filter's squared prediction errors to `sse`.
    """

    lag = 0
    name = "a sampled-count bank"

    def __init__(self, n_filters: int, oversample: float, ts: float | None, r: float | None,
                 prf_std: float, label_scale: str, seed: int | None):
        PARAMS.check(locals())
        self.n_filters, self.oversample, self.ts, self.r = n_filters, float(oversample), ts, r
        self.prf_std, self.label_scale, self.seed = float(prf_std), label_scale, seed

    # -- reset ----------------------------------------------------------------------------------------
    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self._priors = priors
        self.m = priors.n_labels
        self.Ts = float(self.ts) if self.ts is not None else round_down(float(np.min(priors.period)) / self.oversample)
        self.R = float(self.r) if self.r is not None else default_r(priors)
        self._rng = policy_rng(info, self.seed)
        self._t0: float | None = None
        self._k = 0  # next sample to process
        self._j = 0  # pulses received so far
        self.sse = np.zeros(self.n_filters)

    def _start(self, t: float) -> None:
        """First pulse: fix the origin and draw the initial states."""
        p = self._priors
        self._t0 = 0.0 if abs(t) < float(np.max(p.period)) else t
        known = p.phase_known
        u0 = self._rng.random((self.n_filters, self.m))
        u_var = np.full(self.m, 1.0 / 12.0)  # pi^2 / 3 in cycles^2: a uniform phase
        if known.any():
            mean = ((p.phase[known] - self._t0) / p.period[known]) % 1.0
            sd = np.minimum(p.phase_std[known] / p.period[known], 0.5)
            u0[:, known] = mean + sd * self._rng.standard_normal((self.n_filters, int(known.sum())))
            u0[0, known] = mean
            u_var[known] = np.minimum(sd * sd, 1.0 / 12.0)
        self._init_filters(self.Ts / p.period, u0, u_var)

    def _init_filters(self, f0: np.ndarray, u0: np.ndarray, u_var: np.ndarray) -> None:
        """Set up the bank from the prior PRFs f0 (M,), initial phases u0 (K, M) and their variances."""
        raise NotImplementedError

    def _advance(self, k_stop: int, y: float) -> None:
        raise NotImplementedError

    # -- acting ---------------------------------------------------------------------------------------
    def act(self, obs: dict[str, Any]) -> int:
        t = float(obs["toa"][0])
        if self._t0 is None:
            self._start(t)
        k_stop = self._samples_before(t)  # samples strictly before t: count j (pulses 0..j-1)
        if k_stop > self._k:
            self._advance(k_stop, float(self._j))
        self._j += 1
        b = self.best
        a = self.f[b] * ((t - self._t0) / self.Ts) - self.u[b]  # cycles since each train's pulse 0
        d = np.abs(a - np.round(a))
        if self.label_scale == "time":
            d = d / np.abs(self.f[b])
        return int(np.argmin(d))

    def _samples_before(self, t: float) -> int:
        """ceil((t - t0) / Ts), refusing (NotApplicable) a pulse that would take unbounded time."""
        if not math.ulp(t) <= self.Ts:
            raise NotApplicable(f"{self.name}: pulse {self._j} has TOA {t:.6g}, stored in float64 steps of "
                                f"{math.ulp(t):.3g}, coarser than the sampling step Ts = {self.Ts:.3g}: the count "
                                "signal cannot be sampled")
        k = (t - self._t0) / self.Ts
        limit = MAX_SAMPLES_PER_PULSE * (self._j + 1) + MAX_SAMPLES_EXTRA
        if not k <= limit:
            raise NotApplicable(f"{self.name}: pulse {self._j} (TOA {t:.6g}) lies {k:.3g} sampling steps "
                                f"(Ts = {self.Ts:.3g}) after the origin {self._t0:.6g}; at most {limit} are allowed "
                                f"by pulse {self._j} ({MAX_SAMPLES_PER_PULSE} per pulse + {MAX_SAMPLES_EXTRA}), "
                                "as the time grows with the span over the sampling step")
        return math.ceil(k)

    @property
    def best(self) -> int:
        """The filter with the least mean squared prediction error (CM00 IV-A)."""
        return int(np.argmin(self.sse))

    @property
    def mse(self) -> np.ndarray:
        return self.sse / max(self._k, 1)

    def estimates(self) -> dict[str, np.ndarray]:
        """Period Ts / f and phase = first arrival at or after the origin, of the best filter."""
        if self._t0 is None:
            return {"period": self._priors.period.copy(), "phase": self._priors.phase.copy()}
        b = self.best
        f = self.f[b]
        return {"period": self.Ts / f, "phase": self._t0 + (self.u[b] % 1.0) * self.Ts / f}


class EKFBank(SampledBank):
    """CM00's EKF on the sampled pulse count, a bank of K random phase initialisations (`ekf-bank`).

    Parameters: `n_filters` K; `oversample` the least number of samples per shortest prior period
    (Ts = shortest prior period / oversample, rounded down to two significant digits; CM00 sampled
    at 100 kHz for PRFs up to ~8 kHz); `ts` the sample period (overrides `oversample`); `r` the
    measurement noise R (default 10, or 20 for jitter >= 40 % of the shortest prior period); `prf_std`
    the relative PRF std of P0 (CM00: 0.1); `label_scale` "time" or "period"; `seed`.  Declared: `PARAMS`.
    """

    PARAMS = PARAMS

    name = "ekf-bank"

    def __init__(self, n_filters: int = 16, oversample: float = 10.0, ts: float | None = None,
                 r: float | None = None, prf_std: float = 0.1, label_scale: str = "time",
                 seed: int | None = None):
        super().__init__(n_filters, oversample, ts, r, prf_std, label_scale, seed)

    def _init_filters(self, f0: np.ndarray, u0: np.ndarray, u_var: np.ndarray) -> None:
        kf, m = self.n_filters, self.m
        n = 2 * m
        # Filter b's state is x[b].ravel() = (f_1..f_M, u_1..u_M).  Every per-sample operand is a
        # contiguous array (numpy costs several times more per call on strided views at these sizes).
        self.x = np.empty((kf, 2, m))
        self.x[:, 0, :], self.x[:, 1, :] = f0, u0
        self.f, self.u = self.x[:, 0, :], self.x[:, 1, :]
        self.P = np.zeros((kf, n, n))
        i = np.arange(m)
        self.P[:, i, i] = (self.prf_std * f0) ** 2  # P0 = diag(f^2 / 100, pi^2 / 3)
        self.P[:, m + i, m + i] = u_var
        c = np.array([[[0.0, -1.0], [0.0, 1.0], [0.0, -TWO_PI]]])  # w = c x = (f k - u, u, 2 pi (f k - u))
        coef = np.array([[[0.0], [-1.0]]])  # H = g (x) (k, -1)
        w, wf = np.empty((kf, 3, m)), np.empty((kf, 3, m))
        g, h = np.empty((kf, 1, m)), np.empty((kf, 2, m))
        ph, s, gain, outer = np.empty((kf, n, 1)), np.empty((kf, 1, 1)), np.empty((kf, n)), np.empty((kf, n, n))
        ones = np.concatenate([np.ones(n), np.zeros(m)])  # sums floor(f k - u) + floor(u) over trains
        self._work = (self.x, self.x.reshape(kf, n), self.P, c, coef, w, wf, wf.reshape(kf, 3 * m), w[:, 2:3, :],
                      ones, g, h, h.reshape(kf, n, 1), h.reshape(kf, 1, n), ph, ph[:, :, 0], ph.reshape(kf, 1, n),
                      s, s[:, 0, :], gain, gain[:, :, None], outer)
        self._err = np.empty((64, kf))  # innovations of one inter-pulse stretch

    def _advance(self, k_stop: int, y: float) -> None:
        (x3, x, P, c, coef, w, wf, wflat, ang, ones, g, h, hcol, hrow, ph, phc, phrow, s, s1, gain, gcol,
         outer) = self._work
        k0, R = self._k, self.R
        if k_stop - k0 > self._err.shape[0]:
            self._err = np.empty((2 * (k_stop - k0), self.n_filters))
        err, y0 = self._err, y - self.m
        multiply, matmul = np.multiply, np.matmul
        for i, k in enumerate(range(k0, k_stop)):
            c[0, 0, 0] = coef[0, 0, 0] = k
            c[0, 2, 0] = TWO_PI * k
            matmul(c, x3, out=w)
            np.floor(w, out=wf)
            e = np.subtract(y0, matmul(wflat, ones), out=err[i])  # y_k - h_k(x_hat), non-smooth, (8)
            np.cos(ang, out=g)
            g *= 2.0
            g += 1.0  # 1 + 2 cos(2 pi (f k - u))
            multiply(g, coef, out=h)  # H = (k g, -g), (7)
            matmul(P, hcol, out=ph)  # P H'
            matmul(hrow, ph, out=s)  # H P H'
            s1 += R
            np.divide(phc, s1, out=gain)  # K_k, (8)
            multiply(gcol, phrow, out=outer)
            P -= outer  # P - K H P (Q = 0)
            multiply(gain, e[:, None], out=gain)
            x += gain
        e = err[:k_stop - k0]
        self.sse += np.einsum("ik,ik->k", e, e)
        self._k = k_stop

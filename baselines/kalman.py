"""The batched Kalman core for the DLM of MK94 (2.7)-(2.11), shared by tree search, FDP and PT.

MK94's state is x = (T, tau) for all N sources (2.6), with F(X_{k+1}) adding T_i to tau_i for the
active source (2.8) and H picking tau of the active source.  With a block-diagonal prior
Sigma_{1|0} (every published example: a multiple of I) the sources never couple: F and H touch one
source's (T_i, tau_i) at a time, so the covariance stays block-diagonal with one 2x2 block per
source and a pulse updates one block in O(1) instead of the O(N^2) of section II-H.  A hypothesis
(a source sequence) is therefore N independent blocks, and many hypotheses are arrays of blocks.

A block is five arrays of any common shape (structure of arrays, so every step is a few elementwise
numpy operations over all hypotheses at once): `period` T, `tau` (the last arrival), and the packed
covariance `p_tt`, `p_tx`, `p_xx` (var T, cov(T, tau), var tau).

Conventions (see docs/design.md section 8 on (2.3)): a block starts at tau = phi - T with
var tau = var phi + var T and cov(T, tau) = -var T, so that `predict` puts the source's first pulse
at its phase phi with variance var phi and no correlation with T.  `predict` is F of (2.8), plus
MK94 II-C-2's stochastic sources: T <- alpha T + v_T (drift) and an interval noise on tau
(cumulative jitter); `update` is (2.15) for the block's source.

The compiled trackers (baselines/mht, baselines/fdp) run the same filter one block at a time in numba:
baselines/kalman_jit.py is their only copy of it (a module of its own, so that a policy without kernels
does not load numba), held to `predict` and `update` by tests/test_kalman_compiled.py.

Pulse amplitudes (2.11) are one more independent scalar per source (`AmplitudeBlock`).  The RLS form
(2.12)-(2.17) is `RLSBlock`: theta = (T, phi) with regressor (n, 1) for the source's n-th pulse.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from deint_env.episode import Priors


@dataclass(frozen=True)
class DLMModel:
    """Noise of the DLM: R = sigma_w^2 (2.7); MK94 II-C-2's alpha and drift variance on T; the
    cumulative-jitter variance added to each interval."""

    jitter_var: float
    alpha: float = 1.0
    drift_var: float = 0.0
    interval_var: float = 0.0

    @classmethod
    def from_priors(cls, priors: Priors, min_jitter: float = 0.0) -> DLMModel:
        """R from the priors' jitter (floored at `min_jitter` so a noise-free channel keeps S > 0)."""
        return cls(jitter_var=max(priors.jitter_std, min_jitter) ** 2, interval_var=priors.pri_jitter_std ** 2)


class Block(NamedTuple):
    period: np.ndarray
    tau: np.ndarray
    p_tt: np.ndarray
    p_tx: np.ndarray
    p_xx: np.ndarray

    def take(self, index) -> Block:
        return Block(*(a[index] for a in self))

    def put(self, index, other: Block) -> None:
        for a, b in zip(self, other):
            a[index] = b

    def copy(self) -> Block:
        return Block(*(a.copy() for a in self))


def initial_block(period: np.ndarray, phase: np.ndarray, period_std: np.ndarray, phase_std: np.ndarray) -> Block:
    """The prior x_{1|0}, Sigma_{1|0} as blocks, with tau = phi - T so the first pulse predicts at phi."""
    period = np.asarray(period, dtype=np.float64)
    var_t = np.asarray(period_std, dtype=np.float64) ** 2 * np.ones_like(period)
    var_phi = np.asarray(phase_std, dtype=np.float64) ** 2 * np.ones_like(period)
    return Block(period.copy(), np.asarray(phase, dtype=np.float64) - period, var_t.copy(), -var_t,
                 var_phi + var_t)


def prior_block(priors: Priors, unknown_phase_std: float = 1e6) -> Block:
    """Blocks from a policy's priors.  An unknown phase gets a huge variance around 0, so the first
    pulse given to the source sets its phase (the update below stays exact in that limit)."""
    phase = np.where(np.isfinite(priors.phase), priors.phase, 0.0)
    phase_std = np.where(np.isfinite(priors.phase_std), priors.phase_std, unknown_phase_std * priors.period)
    return initial_block(priors.period, phase, priors.period_std, phase_std)


def predict(b: Block, m: DLMModel) -> Block:
    """F of (2.8) for the block's source: the next arrival tau' = tau + T, then T' = alpha T."""
    a = m.alpha
    p_tt = b.p_tt
    if a == 1.0:
        return Block(b.period, b.tau + b.period, p_tt + m.drift_var if m.drift_var else p_tt, p_tt + b.p_tx,
                     p_tt + 2.0 * b.p_tx + b.p_xx + m.interval_var)
    return Block(a * b.period, b.tau + b.period, a * a * p_tt + m.drift_var, a * (p_tt + b.p_tx),
                 p_tt + 2.0 * b.p_tx + b.p_xx + m.interval_var)


def innovation(pred: Block, y: np.ndarray | float, m: DLMModel) -> tuple[np.ndarray, np.ndarray]:
    """One-step prediction error e (2.15) and its variance S = H Sigma H' + R."""
    return y - pred.tau, pred.p_xx + m.jitter_var


def update(pred: Block, e: np.ndarray, s: np.ndarray, m: DLMModel) -> Block:
    """The measurement update (2.15) for the block's source.  var tau and cov(T, tau) are written as
    P * R / S rather than P - P^2 / S: exact, and free of cancellation when a phase is unknown."""
    inv_s = 1.0 / s
    g = e * inv_s
    r_inv_s = m.jitter_var * inv_s
    return Block(pred.period + pred.p_tx * g, pred.tau + pred.p_xx * g, pred.p_tt - pred.p_tx * pred.p_tx * inv_s,
                 pred.p_tx * r_inv_s, pred.p_xx * r_inv_s)


def overdue(pred: Block, y: np.ndarray | float, m: DLMModel, gate: float) -> np.ndarray:
    """MK94 VI-C-3's dropout test for coasting: a source whose predicted arrival lies more than `gate`
    innovation deviations plus half a period before y has missed it."""
    return y - pred.tau > gate * np.sqrt(pred.p_xx + m.jitter_var) + 0.5 * pred.period


class AmplitudeBlock(NamedTuple):
    """(2.11): the source's amplitude a, a constant observed in white noise of variance R_a."""

    mean: np.ndarray
    var: np.ndarray

    def update(self, amp: np.ndarray | float, r: float) -> tuple[AmplitudeBlock, np.ndarray, np.ndarray]:
        e, s = amp - self.mean, self.var + r
        k = self.var / s
        return AmplitudeBlock(self.mean + k * e, self.var * r / s), e, s


class RLSBlock(NamedTuple):
    """The RLS estimator (2.17) on the parameterised DLM (2.12)-(2.13) for one source:
    y = phi + n T for the source's n-th pulse (n = 0, 1, ...), theta = (T, phi), regressor (n, 1).
    RLS ignores sigma_w (P is the covariance in units of R); with Q = 0 its prediction errors equal the
    KF's, as MK94 II-F notes."""

    period: np.ndarray
    phase: np.ndarray
    p_tt: np.ndarray
    p_tp: np.ndarray
    p_pp: np.ndarray
    n: np.ndarray

    @classmethod
    def from_priors(cls, priors: Priors, jitter_var: float) -> RLSBlock:
        b = prior_block(priors)
        scale = 1.0 / jitter_var
        phase = b.tau + b.period
        return cls(b.period.copy(), phase, b.p_tt * scale, np.zeros_like(phase), (b.p_xx - b.p_tt) * scale,
                   np.zeros_like(phase))

    def predict(self) -> np.ndarray:
        return self.phase + self.n * self.period

    def update(self, y: np.ndarray | float) -> tuple[RLSBlock, np.ndarray, np.ndarray]:
        """(2.17): returns the new block, the prediction error e and 1 + eta' P eta."""
        n = self.n
        e = y - (self.phase + n * self.period)
        pe_t = self.p_tt * n + self.p_tp  # P eta
        pe_p = self.p_tp * n + self.p_pp
        denom = 1.0 + n * pe_t + pe_p
        g = e / denom
        return (RLSBlock(self.period + pe_t * g, self.phase + pe_p * g, self.p_tt - pe_t * pe_t / denom,
                         self.p_tp - pe_t * pe_p / denom, self.p_pp - pe_p * pe_p / denom, n + 1), e, denom)


def phase_estimate(b: Block, n_assigned: np.ndarray) -> np.ndarray:
    """phi = tau - (n - 1) T: the first arrival of the line through the filtered (T, tau), which for
    a constant period is the smoothed phase estimate (MK94 II-G's fixed-interval smoother)."""
    return b.tau - (np.asarray(n_assigned) - 1) * b.period


# ---- the general linear-Gaussian block (agile PRI models, `baselines.pri_models`) -------------------
class LinearBlock(NamedTuple):
    """A batched linear-Gaussian state of any dimension d: mean `x` (..., d) and covariance `p`
    (..., d, d).  The DLM's 2x2 `Block` is the case x = (T, tau); PRI models with more parameters
    (stagger levels, a ramp, a sinusoid's quadratures) augment it (see `baselines.pri_models`)."""

    x: np.ndarray
    p: np.ndarray

    def take(self, index) -> LinearBlock:
        return LinearBlock(self.x[index], self.p[index])


def linear_predict(b: LinearBlock, f: np.ndarray, q: np.ndarray, c: np.ndarray | None = None) -> LinearBlock:
    """x' = F x + c, P' = F P F' + Q, with F, Q and the known input c broadcast over the batch."""
    x = (f @ b.x[..., None])[..., 0]
    if c is not None:
        x = x + c
    return LinearBlock(x, f @ b.p @ np.swapaxes(f, -1, -2) + q)


def linear_innovation(b: LinearBlock, y: np.ndarray | float, index: int, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Innovation of a scalar measurement of state component `index` (H = e_index) and its variance."""
    return y - b.x[..., index], b.p[..., index, index] + r


def linear_update(b: LinearBlock, e: np.ndarray, s: np.ndarray, index: int, r: float) -> LinearBlock:
    """The KF update for H = e_index, in Joseph form (I - K H) P (I - K H)' + K R K', which stays
    symmetric and positive when a prior variance is huge (an unknown phase)."""
    k = b.p[..., :, index] / s[..., None]
    x = b.x + k * e[..., None]
    d = b.x.shape[-1]
    if np.isfinite(k).all():
        # I - K H is I less K in column `index`: a copy and one column instead of a broadcast product per
        # state, the same bits while K is finite (K H's other columns are zeros); renewal-ml's hot path
        a = np.broadcast_to(np.eye(d), b.p.shape).copy()
        a[..., :, index] -= k
    else:
        a = np.eye(d) - k[..., :, None] * np.eye(d)[index]
    p = a @ b.p @ np.swapaxes(a, -1, -2) + r * k[..., :, None] * k[..., None, :]
    return LinearBlock(x, p)

"""Coupled per-train EKFs with inhibitory cells and fourth-order learning (Lagunas & Pages, "LP"),
applied to CM00's pulse-count model: policy `ekf-coupled`.

LP track several tones with one small EKF per tone instead of one joint EKF; EKF i's input is the
received signal minus the other EKFs' regenerated outputs through adaptive weights ("inhibitory
cells"), g_i = x - sum_j c_ij y_j, with c learnt by the fourth-order rule (12),
c_ij(n+1) = c_ij(n) + mu_ij y_i y_j |y_j|^2, a stochastic gradient step on (int y_i y_j)^2 (9)-(11) that
pushes the regenerated outputs towards orthogonality, with asymmetric rates mu_ij != mu_ji ("with
symmetrical learning, the two EKFs will track the same signal").

On pulse counts.  Train i's predicted count (see `baselines.ekf`) splits into a ramp, its mean
m_i = f_i k - u_i + floor(u_i) + 1/2, and a zero-mean sawtooth o_i = floor(f_i k - u_i) - (f_i k - u_i)
+ 1/2 (count_i = m_i + o_i).  A ramp cannot be left in another train's input (EKF i would read it
as a PRF error), so the others' ramps are always removed and the cells act on the oscillating part:
EKF i (state (f_i, u_i), the 2-state version of CM00's (6)-(8)) is fed
    g_i = y_k - sum_{j != i} (m_j + c_ij o_j),
and innovates with the non-smooth g_i - count_i = (y_k - sum_j count_j) + sum_{j != i} (1 - c_ij) o_j.
c = 1 everywhere is CM00's joint innovation with a block-diagonal covariance; c = 0 leaves every other
train's sawtooth in the input as noise.  The regenerated output y_i of the learning rule is train i's
*smoothed* oscillating part, s_i = sin(2 pi (f_i k - u_i)) / pi (the A = 1 term of CM00 (4)): a tone at
the train's PRF, LP's setting.  Rates: mu_ij = mu (1 + asym) for i < j and mu (1 - asym) for i > j
(LP's 1.2 / 0.8 is asym = 0.2); c is kept in [0, 1] (it is a fraction of a signal to subtract).

Everything else is `ekf-bank`'s: sampling, P0 and R per train, a bank of K random phase
initialisations (each member a full set of M coupled EKFs) with the least mean squared prediction
error of the total count y_k - sum_j count_j chosen, labels from the chosen member's predicted
arrivals, estimates as in `ekf-bank`.

Outcome (`deint reproduce cm00-tables-4-5`): on CM00's failure case this does not do better than
`ekf-bank`.  The joint EKF's trap there is two tracks at the same PRF half a period apart, jointly
mimicking one train at twice the rate; their tones are anti-correlated (s_2 = -s_1), so (12) lowers
c_12 rather than raising it.  The coupled members never fall into that trap (their tracks are kept
apart), but without the cross-covariances of the joint EKF the freed tracks mostly fail to lock.
"""

from __future__ import annotations

import math

import numpy as np

from baselines.ekf import PARAMS as EKF_PARAMS
from baselines.ekf import TWO_PI, SampledBank
from deint_env.params import Param, ParamSet


class EKFCoupled(SampledBank):
    """M per-train EKFs coupled through learnt inhibitory cells (LP (12)), in a bank of K.

    Parameters as `ekf-bank`, plus: `mu` the learning rate of (12); `asym` the asymmetry of the rates
    (mu_ij = mu (1 +- asym)); `c0` the initial cell weights.
    """

    name = "ekf-coupled"
    PARAMS = ParamSet(EKF_PARAMS.params[:-1] + (
        Param("mu", float, 1.0, "the learning rate of LP (12)", low=0),
        Param("asym", float, 0.2, "the asymmetry of the rates: mu_ij = mu (1 +- asym)", low=0, high=1, high_open=True),
        Param("c0", float, 0.0, "the initial cell weights", low=0, high=1),
        EKF_PARAMS["seed"]))

    def __init__(self, n_filters: int = 16, oversample: float = 10.0, ts: float | None = None,
                 r: float | None = None, prf_std: float = 0.1, label_scale: str = "time",
                 mu: float = 1.0, asym: float = 0.2, c0: float = 0.0, seed: int | None = None):
        super().__init__(n_filters, oversample, ts, r, prf_std, label_scale, seed)
        self.PARAMS.check(locals())
        self.mu, self.asym, self.c0 = float(mu), float(asym), float(c0)

    def _init_filters(self, f0: np.ndarray, u0: np.ndarray, u_var: np.ndarray) -> None:
        kf, m = self.n_filters, self.m
        self.f = np.repeat(f0[None], kf, axis=0)
        self.u = u0.copy()
        self.pff = np.repeat(((self.prf_std * f0) ** 2)[None], kf, axis=0)
        self.pfu = np.zeros((kf, m))
        self.puu = np.repeat(u_var[None], kf, axis=0)
        off = ~np.eye(m, dtype=bool)
        self.c = np.where(off, self.c0, 0.0)[None].repeat(kf, axis=0)  # c_ij, zero diagonal
        self._mu = self.mu * np.where(np.triu(off), 1 + self.asym, 1 - self.asym) * off  # mu_ij, asymmetric
        self._off = off.astype(float)

    def _advance(self, k_stop: int, y: float) -> None:
        R, f, u, pff, pfu, puu, c, mu, off, sse = (self.R, self.f, self.u, self.pff, self.pfu, self.puu, self.c,
                                                    self._mu, self._off, self.sse)
        m = self.m
        for k in range(self._k, k_stop):
            a = f * k - u
            fl = np.floor(a)
            osc = fl - a + 0.5  # o_j: the non-smooth sawtooth around train j's ramp
            e_all = y - (fl.sum(axis=1) + np.floor(u).sum(axis=1) + m)  # y_k - sum_j count_j
            e = e_all[:, None] + np.matmul(off - c, osc[:, :, None])[:, :, 0]  # g_i - count_i
            ang = TWO_PI * a
            g = 1.0 + 2.0 * np.cos(ang)
            phf = g * (k * pff - pfu)  # P_i H_i', H_i = g (k, -1), (7)
            phu = g * (k * pfu - puu)
            s = g * (k * phf - phu) + R
            kf, ku = phf / s, phu / s
            f += kf * e
            u += ku * e
            pff -= kf * phf
            pfu -= kf * phu
            puu -= ku * phu
            tone = np.sin(ang) / math.pi  # regenerated output y_i
            c += mu * (tone[:, :, None] * (tone ** 3)[:, None, :])  # (12)
            np.clip(c, 0.0, off, out=c)
            sse += e_all * e_all
        self._k = k_stop

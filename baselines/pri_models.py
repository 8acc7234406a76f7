"""PRI models as linear state-space models on the shared Kalman core (`kalman.LinearBlock`).

Every model here writes a source's n-th PRI (n = its emission index, 0 at its phase) as a regression
on a parameter vector theta that evolves linearly:

    PRI_n = phi(n) . theta_n,    theta_{n+1} = A theta_n + v_n,   v_n ~ N(0, Q),
    tau_{n+1} = tau_n + PRI_n (+ cumulative jitter),   y = tau_n + w   (MK94 (2.7)-(2.8))

so the state (tau, theta) is MK94's (T, tau) augmented, F(n) = [[1, phi(n)'], [0, A]] and H picks
tau.  The kinds (`deint_env.scenario.Modulation` defines the simulated ones):
- ``constant``: theta = T, phi = 1: MK94's DLM itself.
- ``drifting``: theta = T, A = alpha, Q = drift variance: MK94 II-C-2's stochastic source.
- ``stagger``: theta = the m sub-PRIs, phi(n) = e_{n mod m}: the cycle position is n, carried by
  the emission count, so the state is augmented with the levels, not with a discrete position.
- ``dwell_switch``: theta = the m dwell PRIs, phi(n) = e_{(n // c) mod m} (c pulses a dwell).
- ``sliding``: theta = (T, T depth), phi(n) = (1, (n mod L)/(L - 1) - 1/2): the saw-tooth's ramp,
  its slope a state (the PRI rate per cycle), reset every L pulses.
- ``sinusoidal``: theta = (T, a, b), phi(n) = (1, sin(2 pi n / L), cos(2 pi n / L)): a wobulation of
  known period L and unknown phase psi is linear in its quadratures (a, b) = T depth (cos psi, sin psi).
- ``trend``: theta = (T, dT), A = [[1, 1], [0, 1]], phi = (1, 0): a PRI with a rate state driven by
  noise (a local linear trend), for a sliding or wobulated PRI whose cycle is not known.
- ``switch``: theta = T drawn afresh around the prior period at each pulse (A = 0 and a known input):
  with ``constant`` in an IMM, a PRI that holds and switches at unknown pulses (dwell and switch with
  unknown dwells, a saw-tooth's reset), the broad member of a model bank.

A `PRIModel` is the model of one source up to its scale: `build(period, period_std, ...)` gives its
arrays for a source of prior mean period T (theta's prior mean T * `unit`, covariance from the
period's spread plus the unknown shape parameters' own spread).  `from_modulation` builds the model a
prior `Modulation` names; `DEFAULT_BANK` is the bank a tracker runs when the priors name none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deint_env.errors import DeintError
from deint_env.scenario import Modulation

KINDS = ("constant", "drifting", "stagger", "dwell_switch", "sliding", "sinusoidal", "trend", "switch")
TAU = 0  # the arrival's index in the state; theta follows


@dataclass(frozen=True, eq=False)
class PRIModel:
    """PRI_n = table[n mod len(table)] . theta, theta' = transition theta + N(0, noise * T^2).

    `unit`: theta's prior mean per unit period; `spread`: the prior std of each theta component per
    unit period beyond the period's own uncertainty (a shape parameter the priors do not give)."""

    kind: str
    table: np.ndarray  # (L, d)
    transition: np.ndarray  # (d, d)
    noise: np.ndarray  # (d, d), relative to T^2
    unit: np.ndarray  # (d,)
    spread: np.ndarray  # (d,)
    family: str = ""  # models of one non-empty family share theta's meaning: IMM mixes their states
    offset: np.ndarray | None = None  # (d,) b: theta' = A theta + b T + v (a PRI drawn afresh around T)
    anchored: bool = False  # the unknown shape keeps the cycle's mean PRI at T (spread only across levels)

    @property
    def dim(self) -> int:
        return self.table.shape[1]

    def mean_pri(self, theta: np.ndarray) -> np.ndarray:
        """The PRI averaged over the model's cycle (the period a constant-PRI view would see)."""
        return theta[..., :self.dim] @ self.table.mean(axis=0)


def _model(kind: str, table, transition=None, noise=None, unit=None, spread=None, family: str = "", offset=None,
           anchored: bool = False) -> PRIModel:
    table = np.atleast_2d(np.asarray(table, dtype=np.float64))
    d = table.shape[1]
    return PRIModel(kind, table,
                    np.eye(d) if transition is None else np.asarray(transition, dtype=np.float64),
                    np.zeros((d, d)) if noise is None else np.asarray(noise, dtype=np.float64),
                    np.ones(d) if unit is None else np.asarray(unit, dtype=np.float64),
                    np.zeros(d) if spread is None else np.asarray(spread, dtype=np.float64), family,
                    None if offset is None else np.asarray(offset, dtype=np.float64), anchored)


# theta_0 is the PRI in force (and theta_1, if any, its rate): these models' states mix (IMM)
PRI_FAMILY = "pri"


def constant() -> PRIModel:
    return _model("constant", [[1.0]], family=PRI_FAMILY)


def drifting(alpha: float, drift_std_rel: float) -> PRIModel:
    """MK94 II-C-2: T' = alpha T + v, var v = (drift_std_rel T)^2."""
    return _model("drifting", [[1.0]], [[alpha]], [[drift_std_rel ** 2]], family=PRI_FAMILY)


def stagger(m: int, pattern: tuple[float, ...] | None = None, spread: float = 0.3) -> PRIModel:
    """m sub-PRIs; a known pattern fixes their ratios (only the scale is uncertain), an unknown one
    starts every level at T with relative std `spread` about their mean, which stays at T (a stagger's
    mean PRI is the source's period)."""
    unit = np.ones(m) if pattern is None else np.asarray(pattern) / np.mean(pattern)
    return _model("stagger", np.eye(m), unit=unit, spread=np.full(m, 0.0 if pattern is not None else spread),
                  anchored=pattern is None)


def dwell_switch(pattern: tuple[float, ...], cycle: int) -> PRIModel:
    m = len(pattern)
    table = np.repeat(np.eye(m), cycle, axis=0)
    return _model("dwell_switch", table, unit=np.asarray(pattern) / np.mean(pattern))


def sliding(depth: float, cycle: int) -> PRIModel:
    ramp = np.arange(cycle) / (cycle - 1) - 0.5
    return _model("sliding", np.stack([np.ones(cycle), ramp], axis=1), unit=[1.0, depth])


def sinusoidal(cycle: int, depth: float) -> PRIModel:
    w = 2 * np.pi * np.arange(cycle) / cycle
    # psi uniform: a and b have mean 0 and second moment (T depth)^2 / 2 each
    return _model("sinusoidal", np.stack([np.ones(cycle), np.sin(w), np.cos(w)], axis=1), unit=[1.0, 0.0, 0.0],
                  spread=[0.0, depth / np.sqrt(2), depth / np.sqrt(2)])


def trend(rate_std: float = 0.02, rate_noise: float = 0.006) -> PRIModel:
    return _model("trend", [[1.0, 0.0]], [[1.0, 1.0], [0.0, 1.0]], [[0.0, 0.0], [0.0, rate_noise ** 2]],
                  unit=[1.0, 0.0], spread=[0.0, rate_std], family=PRI_FAMILY)


def switch(spread: float = 0.25) -> PRIModel:
    """A PRI drawn afresh around the period at every pulse, T' = T_prior + v with std `spread` T: in an
    IMM with `constant` (stay), the switch of a dwell-and-switch or a saw-tooth's reset."""
    return _model("switch", [[1.0]], [[0.0]], [[spread ** 2]], family=PRI_FAMILY, offset=[1.0])


def from_modulation(mod: Modulation, period: float) -> PRIModel:
    """The model of a source whose priors name its modulation (its deterministic parameters: the
    per-episode draws, a sinusoid's phase and a drift's path, stay unknown)."""
    k = mod.kind
    if k == "constant":
        return constant()
    if k == "drifting":
        return drifting(mod.alpha, mod.drift_std / period)
    if k == "stagger":
        return stagger(len(mod.pattern), mod.pattern)
    if k == "dwell_switch":
        return dwell_switch(mod.pattern, mod.cycle)
    if k == "sliding":
        return sliding(mod.depth, mod.cycle)
    if k == "sinusoidal":
        return sinusoidal(mod.cycle, mod.depth)
    raise DeintError(f"modulation kind {k!r} has no PRI model; known: {', '.join(KINDS)}")


def default_bank() -> tuple[PRIModel, ...]:
    """The bank run for a source whose modulation the priors do not name: constant, a rate state, 2-
    and 3-position stagger with unknown levels, and a switching PRI."""
    return constant(), trend(), stagger(2), stagger(3), switch()


@dataclass(frozen=True, eq=False)
class BankArrays:
    """The models of N sources x M bank slots padded to a common theta dimension D (padding: zero
    regressor, zero variance, identity transition), as arrays ready for batched filtering.

    table (N, M, L, D) with per-slot cycle `length` (N, M); `f` (N, M, D+1, D+1) F without its
    regressor row; `q` (N, M, D+1, D+1) the process noise (interval noise on tau included); `x0`, `p0`
    the prior (N, M, D+1) and (N, M, D+1, D+1); `valid` (N, M) slots holding a model."""

    table: np.ndarray
    length: np.ndarray
    f: np.ndarray
    q: np.ndarray
    c: np.ndarray  # (N, M, D+1): the known input b T of models with an offset
    x0: np.ndarray
    p0: np.ndarray
    valid: np.ndarray
    same_family: np.ndarray  # (N, M, M): slots i, j hold models of one family (IMM mixes their states)
    models: tuple[tuple[PRIModel, ...], ...]

    def regressor(self, n: np.ndarray) -> np.ndarray:
        """phi(n) for emission counts n (..., N): shape (..., N, M, D)."""
        i = np.arange(self.length.shape[0])[:, None]
        j = np.arange(self.length.shape[1])[None, :]
        return self.table[i, j, n[..., :, None] % self.length]

    def transition(self, n: np.ndarray) -> np.ndarray:
        """F(n) (..., N, M, D+1, D+1): tau' = tau + phi(n) . theta; theta' = A theta."""
        f = np.broadcast_to(self.f, n.shape[:-1] + self.f.shape).copy()
        f[..., TAU, 1:] = self.regressor(n)
        return f


def build_bank(banks: list[tuple[PRIModel, ...]], period: np.ndarray, period_std: np.ndarray, phase: np.ndarray,
               phase_std: np.ndarray, interval_var: float) -> BankArrays:
    """Stack each source's bank (source i: period[i] etc.) into `BankArrays`."""
    n, m = len(banks), max(len(b) for b in banks)
    d = max(model.dim for b in banks for model in b)
    length = max(model.table.shape[0] for b in banks for model in b)
    table = np.zeros((n, m, length, d))
    cycle = np.ones((n, m), dtype=np.int64)
    f = np.broadcast_to(np.eye(d + 1), (n, m, d + 1, d + 1)).copy()
    q = np.zeros((n, m, d + 1, d + 1))
    c = np.zeros((n, m, d + 1))
    x0 = np.zeros((n, m, d + 1))
    p0 = np.zeros((n, m, d + 1, d + 1))
    valid = np.zeros((n, m), dtype=bool)
    for i, bank in enumerate(banks):
        t, t_std = float(period[i]), float(period_std[i])
        for j, model in enumerate(bank):
            k, L = model.dim, model.table.shape[0]
            table[i, j, :L, :k] = model.table
            cycle[i, j] = L
            f[i, j, 1:k + 1, 1:k + 1] = model.transition
            q[i, j, 1:k + 1, 1:k + 1] = model.noise * t * t
            q[i, j, TAU, TAU] = interval_var
            if model.offset is not None:
                c[i, j, 1:k + 1] = model.offset * t
            x0[i, j, TAU] = phase[i]
            x0[i, j, 1:k + 1] = t * model.unit
            # the scale's uncertainty moves every level together; the shape's spread is independent
            shape = np.diag((t * model.spread) ** 2)
            if model.anchored:  # spread only across the levels: their mean is the period
                centre = np.eye(k) - 1.0 / k
                shape = centre @ shape @ centre
            p0[i, j, 1:k + 1, 1:k + 1] = t_std ** 2 * np.outer(model.unit, model.unit) + shape
            p0[i, j, TAU, TAU] = phase_std[i] ** 2
            valid[i, j] = True
    same = np.eye(m, dtype=bool)[None].repeat(n, axis=0)
    for i, bank in enumerate(banks):
        for j, a in enumerate(bank):
            for k, b in enumerate(bank):
                same[i, j, k] |= bool(a.family) and a.family == b.family
    return BankArrays(table, cycle, f, q, c, x0, p0, valid, same, tuple(banks))

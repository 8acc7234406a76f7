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
- ``sliding``: theta = (T, T depth), phi(n) = (1, ((n + o) mod L)/(L - 1) - 1/2): the saw-tooth's ramp,
  its slope a state (the PRI rate per cycle), reset every L pulses (depth: the sweep over T, whatever
  the priors' `relative_to`).
- ``sinusoidal``: theta = (T, a, b), phi(n) = (1, sin(2 pi n / L), cos(2 pi n / L)): a wobulation of
  known period L and unknown phase psi is linear in its quadratures (a, b) = T depth (cos psi, sin psi).
  A cycle L that is not a whole number of pulses has no finite table: theta = (T, s, c) rotates instead,
  (s, c)_{n+1} = R(2 pi / L) (s, c)_n with s_n = T depth sin(2 pi n / L + psi), and phi = (1, 1, 0).
- ``random_stagger``: theta = T; PRI_n = T u[s_n] with the level s_n random (i.i.d. or Markov), so the
  next arrival is a mixture over level sequences, not one Gaussian: `baselines.agile` scores it as the
  renewal density it is (`JumpLevels`); its table [[1]] gives the mean PRI T.
- random cycle position (``Modulation.random_start``): one model per cycle offset o, a bank whose
  model probabilities find the offset.
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

KINDS = ("constant", "drifting", "stagger", "dwell_switch", "sliding", "sinusoidal", "random_stagger", "trend",
         "switch")
TAU = 0  # the arrival's index in the state; theta follows


@dataclass(frozen=True, eq=False)
class JumpLevels:
    """A PRI switching among K levels at random: PRI_n = T ratio[s_n], P(s_n = j | s_{n-1} = i) =
    transition[i, j] (i.i.d. levels: every row the same), the first interval's level from `start`."""

    ratio: np.ndarray  # (K,)
    transition: np.ndarray  # (K, K), row-stochastic
    start: np.ndarray  # (K,)

    def sequences(self, r_max: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The runs of r = 0..r_max intervals after an interval of level a, grouped by (level counts,
        last level), as columns: S (C,) the run's length over T, r (C,), the last level (C,; -1 for
        the empty run, which keeps a) and log P(run | a) (K, C) (-inf where impossible)."""
        k = self.ratio.size
        prob: dict[tuple[tuple[int, ...], int], np.ndarray] = {}
        cur = {((0,) * k, a): np.eye(k)[a] for a in range(k)}  # (counts, last) -> P(run | a) for each a
        for _ in range(r_max):
            nxt: dict[tuple[tuple[int, ...], int], np.ndarray] = {}
            for (counts, last), p in cur.items():
                for j in range(k):
                    step = p * self.transition[last, j]
                    if step.any():
                        key = (tuple(c + (i == j) for i, c in enumerate(counts)), j)
                        nxt[key] = nxt.get(key, 0.0) + step
            prob.update(nxt)
            cur = nxt
        counts = np.array([c for c, _ in prob], dtype=np.float64).reshape(-1, k)
        with np.errstate(divide="ignore"):
            logp = np.log(np.stack(list(prob.values()), axis=1)) if prob else np.zeros((k, 0))
        return (np.r_[0.0, counts @ self.ratio], np.r_[0, counts.sum(axis=1)].astype(np.int64),
                np.r_[-1, [last for _, last in prob]].astype(np.int64), np.hstack([np.zeros((k, 1)), logp]))


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
    jumps: JumpLevels | None = None  # random_stagger: the level process (scored by `baselines.agile`)

    @property
    def dim(self) -> int:
        return self.table.shape[1]

    def mean_pri(self, theta: np.ndarray) -> np.ndarray:
        """The PRI averaged over the model's cycle (the period a constant-PRI view would see)."""
        return theta[..., :self.dim] @ self.table.mean(axis=0)


def _model(kind: str, table, transition=None, noise=None, unit=None, spread=None, family: str = "", offset=None,
           anchored: bool = False, jumps: JumpLevels | None = None) -> PRIModel:
    table = np.atleast_2d(np.asarray(table, dtype=np.float64))
    d = table.shape[1]
    return PRIModel(kind, table,
                    np.eye(d) if transition is None else np.asarray(transition, dtype=np.float64),
                    np.zeros((d, d)) if noise is None else np.asarray(noise, dtype=np.float64),
                    np.ones(d) if unit is None else np.asarray(unit, dtype=np.float64),
                    np.zeros(d) if spread is None else np.asarray(spread, dtype=np.float64), family,
                    None if offset is None else np.asarray(offset, dtype=np.float64), anchored, jumps)


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


def dwell_switch(pattern: tuple[float, ...], cycle: int, dwells: tuple[int, ...] = (), offset: int = 0,
                 unit: np.ndarray | None = None) -> PRIModel:
    """Level j held `cycle` pulses (or dwells[j]); unit: the level PRIs over T (default pattern / mean)."""
    m = len(pattern)
    table = np.roll(np.repeat(np.eye(m), dwells if dwells else cycle, axis=0), -offset, axis=0)
    return _model("dwell_switch", table, unit=np.asarray(pattern) / np.mean(pattern) if unit is None else unit)


def sliding(depth: float, cycle: int, offset: int = 0) -> PRIModel:
    ramp = (np.arange(cycle) + offset) % cycle / (cycle - 1) - 0.5
    return _model("sliding", np.stack([np.ones(cycle), ramp], axis=1), unit=[1.0, depth])


def sinusoidal(cycle: int | float, depth: float) -> PRIModel:
    if not float(cycle).is_integer():  # rotate the quadratures: PRI_n = T + s_n
        c, s = np.cos(2 * np.pi / cycle), np.sin(2 * np.pi / cycle)
        return _model("sinusoidal", [[1.0, 1.0, 0.0]], [[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]],
                      unit=[1.0, 0.0, 0.0], spread=[0.0, depth / np.sqrt(2), depth / np.sqrt(2)])
    cycle = int(cycle)
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


def random_stagger(mod: Modulation) -> PRIModel:
    """PRI_n = T ratio[s_n] with the levels of a `random_stagger` modulation (see `JumpLevels`)."""
    m = len(mod.pattern)
    start = mod.level_probs()
    trans = np.array(mod.transition) if mod.transition else np.repeat(start[None], m, axis=0)
    return _model("random_stagger", [[1.0]], jumps=JumpLevels(mod.level_ratios(), trans, start))


def bank_from_modulation(mod: Modulation, period: float) -> tuple[PRIModel, ...]:
    """The bank of a source whose priors name its modulation: its model, or, when the cycle position
    of its first pulse is random (`random_start`), one model per position."""
    if not mod.random_start:
        return (from_modulation(mod, period),)
    n = mod.cycle_length
    if mod.kind == "stagger":
        return tuple(stagger(n, tuple(np.roll(mod.pattern, -o))) for o in range(n))
    if mod.kind == "dwell_switch":
        return tuple(dwell_switch(mod.pattern, mod.cycle, mod.dwells, o, mod.level_ratios()) for o in range(n))
    return tuple(sliding(mod.sliding_depth(), mod.cycle, o) for o in range(n))


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
        return dwell_switch(mod.pattern, mod.cycle, mod.dwells, unit=mod.level_ratios() if mod.dwells else None)
    if k == "sliding":
        return sliding(mod.sliding_depth(), mod.cycle)
    if k == "random_stagger":
        return random_stagger(mod)
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

    # The trackers need phi and F of a few (source, slot) pairs per pulse: gathering just those is much
    # cheaper than `regressor` of every pair, and gives the same values.
    def phi(self, i: np.ndarray, j: np.ndarray, n: np.ndarray) -> np.ndarray:
        """phi(n) of source i's slot j at emission count n (index arrays of one broadcast shape): (..., D)."""
        return self.table[i, j, n % self.length[i, j]]

    def transition_of(self, i: np.ndarray, n: np.ndarray) -> np.ndarray:
        """F(n) of every slot of the sources i (K,) at their counts n (K,): (K, M, D+1, D+1); tau' = tau +
        phi(n) . theta, theta' = A theta."""
        f = self.f[i]  # a copy (fancy index), filled in below
        f[..., TAU, 1:] = self.phi(i[:, None], np.arange(self.f.shape[1]), n[:, None])
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

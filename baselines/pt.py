"""The probabilistic teacher (MK94 section IV): policies `pt-prior` and `pt-post`; and `dokf`, the same
tracker taught by its own MAP decisions with DM89's spurious-pulse test.

At each pulse y_{k+1} the teacher picks the active source at random and then runs the KF update of
that source only, (4.4) (Agrawala's learning with a probabilistic teacher, MK94 ref. [6]):
- `pt-post`, Step 1 as published: the a-posteriori probabilities (4.1) with the Gaussian
  approximation (4.2), f(X_{k+1} = e_j | y_{k+1}, ...) ~ pi_j N[y_{k+1}; H x^j_{k+1|k}, Omega^j],
  x^j_{k+1|k} and Omega^j from (4.3), i.e. every source's one-step prediction;
- `pt-prior`, MK94 IV-2: the a-priori probabilities pi instead ("instead of using the a posteriori
  probabilities in Step 1, one can use the a priori probability estimate"), so only the chosen
  source is predicted: O(1) per pulse.
pi is the priors' `source_prob` (by default the known relative pulse rates, MK94 IV-2).

State: the per-source 2x2 blocks (T, tau) of `baselines.kalman` (MK94's (2.7)-(2.8) with a
block-diagonal Sigma_{1|0}, so (4.3) costs O(1) per source instead of the published O(N^3)), started
by `kalman.prior_block`: tau = phi - T, so a source's first pulse is predicted at its phase.

Labels.  The PT's decision is the sampled source (`label="sample"`, the paper).  `label="map"`
labels each pulse with the most probable source under the same model (the argmax of (4.1)) while
still learning from the sample (a variant, not published: `pt-post:label=map`).

`dokf` (teacher "decision"): DM89's detect-then-filter carried over to the DLM: each pulse is
assigned to the argmax of (4.1), or called spurious by Theorem 1 (below), and that decision, not a
sample, drives the update, as DM89's q_hat(k|k) drives (16)-(17) (Agrawala's decision-directed
learning, against which ref. [6] sets the PT).

Spurious pulses (only when the priors' spurious_rate r > 0): before deciding, the most probable
source's innovation goes through DM89's Theorem 1 test (`deint_env.receiver.is_spurious`, lambda =
r / (1 + r), spread T_j^2 / 12: a uniform arrival over one period); a pulse it calls spurious gets
the spurious label and updates nothing.  pt-prior has no Step 1 (its choice ignores y), so no test.
The DLM has no missing-pulse state, so a true pulse rejected by the test (or lost, or taken by the
wrong source) desynchronises its track for good: the track goes on predicting the lost pulse and
every later pulse of its source looks spurious.  Two remedies from MK94 VI-C-3 (dropouts):
`coast=True` (the rule of `fdp`'s `dropout`) predicts a source overdue at y by more than `gate`
standard deviations plus half a period through its missed arrivals, without measurements, so it
picks its pulses up where they are; `reset_after=k` "resets" a source coasted through more than k
arrivals in a row (a detected dropout; needs coasting) by raising its arrival variance to at least T^2/12, so a track
biased by a wrongly taken pulse, or a source that starts late, is acquired again.  Both are off in
pt-post (the paper); `dokf` uses coast=True, reset_after=4 (chosen on robust-v0 train seeds: a
smaller k loses sources of near-equal period whose pulses merge several times in a row).

An unknown spurious rate (NaN in the priors, or `rates="estimate"`) is estimated online from the
tracker's own decisions with a weak Beta prior (mean 0.05, worth 20 pulses): lambda = (spurious
called + 1) / (pulses + 20), so Theorem 1's threshold follows the channel.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import Any

import numpy as np

from deint_env.receiver import is_spurious
from baselines.kalman import (Block, DLMModel, innovation, overdue, phase_estimate, predict, prior_block,
                              update)
from deint_env.episode import Priors
from deint_env.policies import policy_rng

_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
_CHUNK = 4096  # uniforms drawn per refill: one per pulse, so labels do not depend on the chunking
_MAX_COAST = 64  # missed arrivals skipped per pulse at most
_PRIOR_MEAN, _PRIOR_WEIGHT = 0.05, 20.0  # the weak Beta prior of an unknown spurious fraction
RATES = ("priors", "estimate")
LABELS = ("sample", "map")
TEACHERS = ("prior", "posterior", "decision")


class ProbabilisticTeacher:
    """MK94 IV's PT with `teacher` "prior" (IV-2), "posterior" (Step 1, (4.1)-(4.3)) or "decision"
    (the MAP decision teaches: `dokf`); `label`, `coast`, `gate`, `reset_after`: see the module doc.
    `seed`: the policy's own seed (default: the runner's policy_seed)."""

    lag = 0

    def __init__(self, teacher: str, label: str = "sample", seed: int | None = None, coast: bool = False,
                 gate: float = 5.0, reset_after: int | None = None, rates: str = "priors"):
        if teacher not in TEACHERS:
            raise ValueError(f"teacher={teacher!r} must be one of {', '.join(TEACHERS)}")
        if label not in LABELS:
            raise ValueError(f"label={label!r} must be one of {', '.join(LABELS)}")
        if coast and teacher == "prior":
            raise ValueError("coast needs a posterior: the a-priori teacher's sources are always overdue")
        if not gate > 0:
            raise ValueError(f"gate={gate!r} must be > 0")
        if reset_after is not None and (not isinstance(reset_after, int) or reset_after < 1):
            raise ValueError(f"reset_after={reset_after!r} must be None or an integer >= 1")
        if rates not in RATES:
            raise ValueError(f"rates={rates!r} must be one of {', '.join(RATES)}")
        self.teacher, self.label, self.seed, self.rates = teacher, label, seed, rates
        self.coast, self.gate, self.reset_after = bool(coast), float(gate), reset_after

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self.n = priors.n_labels
        self.model = DLMModel.from_priors(priors, min_jitter=_MIN_JITTER_REL * float(np.min(priors.period)))
        self.blocks = prior_block(priors)  # arrays of N: the filtered (T, tau) of every source
        self.arrivals = np.zeros(self.n, dtype=np.int64)  # pulses taken + arrivals coasted through, per source
        self.missed = np.zeros(self.n, dtype=np.int64)  # arrivals coasted through since the last update
        pi = np.asarray(priors.source_prob, dtype=np.float64)
        self.log_pi = np.log(pi)
        self._cum_pi = np.cumsum(pi / pi.sum()).tolist()
        self._cum_pi[-1] = math.inf  # u < 1 always lands on a source
        r = priors.spurious_rate
        self._estimate = self.rates == "estimate" or math.isnan(r)
        self._lam = _PRIOR_MEAN if self._estimate else r / (1.0 + r)
        self._pulses = self._called = 0  # pulses seen, called spurious (for an estimated rate)
        self._rng = policy_rng(info, self.seed)
        self._u: list[float] = []
        self._posterior = self.teacher != "prior" or self.label == "map"

    def _uniform(self) -> float:
        if not self._u:
            self._u = self._rng.random(_CHUNK).tolist()[::-1]
        return self._u.pop()

    def posterior(self, y: float) -> tuple[np.ndarray, Block, np.ndarray, np.ndarray]:
        """(4.1)-(4.3): log f(X_{k+1} = e_j | y_{k+1}, Y_k, X_k) up to a constant, with every source's
        prediction, its innovation e_j and variance Omega_j."""
        b, m = self.blocks, self.model
        pred = predict(b, m)
        if self.coast:  # VI-C-3: skip the missed arrivals of every source overdue at y
            for _ in range(_MAX_COAST):
                late = overdue(pred, y, m, self.gate)
                if not late.any():
                    break
                b = Block(*(np.where(late, new, old) for new, old in zip(pred, b)))
                self.missed += late
                self.arrivals += late
                if self.reset_after is not None:  # a dropout: open the arrival up to a whole period
                    lost = self.missed > self.reset_after
                    b = b._replace(p_xx=np.where(lost, np.maximum(b.p_xx, b.period ** 2 / 12.0), b.p_xx))
                pred = predict(b, m)
            self.blocks = b
        e, s = innovation(pred, y, m)
        return self.log_pi - 0.5 * (np.log(s) + e * e / s), pred, e, s

    def act(self, obs: dict[str, Any]) -> int:
        if not int(obs["valid"]):
            return 0
        y = float(obs["toa"][0])
        u = self._uniform() if self.teacher != "decision" else 0.0  # one draw per pulse: reproducible
        if not self._posterior:  # pt-prior, sampled labels: only the chosen block is touched
            j = bisect_right(self._cum_pi, u)
            b = self.blocks
            pred = predict(Block(float(b.period[j]), float(b.tau[j]), float(b.p_tt[j]), float(b.p_tx[j]),
                                 float(b.p_xx[j])), self.model)
            e, s = innovation(pred, y, self.model)
            b.put(j, update(pred, e, s, self.model))
            self.arrivals[j] += 1
            return j
        logp, pred, e, s = self.posterior(y)
        best = int(np.argmax(logp))
        if self._estimate:
            self._lam = (self._called + _PRIOR_MEAN * _PRIOR_WEIGHT) / (self._pulses + _PRIOR_WEIGHT)
            self._pulses += 1
        if self._lam > 0 and self.teacher != "prior" and is_spurious(
                float(e[best]), float(s[best]), self._lam, float(pred.period[best]) ** 2 / 12.0):
            self._called += 1
            return self.n
        if self.teacher == "prior":
            j = bisect_right(self._cum_pi, u)
        elif self.teacher == "decision":
            j = best
        else:
            cum = np.cumsum(np.exp(logp - logp[best]))
            j = min(int(np.searchsorted(cum, u * cum[-1], side="right")), self.n - 1)
        self.blocks.put(j, update(pred.take(j), e[j], s[j], self.model))  # (4.4)
        self.arrivals[j] += 1
        self.missed[j] = 0
        return best if self.label == "map" else j

    def estimates(self) -> dict[str, np.ndarray]:
        return {"period": self.blocks.period.copy(), "phase": phase_estimate(self.blocks, self.arrivals)}


class PTPrior(ProbabilisticTeacher):
    """`pt-prior`: MK94 IV-2, the source drawn from the known a-priori probabilities pi."""

    def __init__(self, label: str = "sample", seed: int | None = None):
        super().__init__("prior", label, seed)


class PTPost(ProbabilisticTeacher):
    """`pt-post`: MK94 IV, the source drawn from the a-posteriori probabilities (4.1)-(4.3)."""

    def __init__(self, label: str = "sample", seed: int | None = None, coast: bool = False, gate: float = 5.0,
                 reset_after: int | None = None, rates: str = "priors"):
        super().__init__("posterior", label, seed, coast, gate, reset_after, rates)


class DOKFTracker(ProbabilisticTeacher):
    """`dokf`: the PT's tracker taught by its own MAP decisions, with DM89's Theorem 1 spurious test,
    coasting through missed arrivals and dropout resets (deterministic: it draws nothing)."""

    def __init__(self, coast: bool = True, gate: float = 5.0, reset_after: int | None = 4, rates: str = "priors"):
        super().__init__("decision", "map", None, coast, gate, reset_after, rates)

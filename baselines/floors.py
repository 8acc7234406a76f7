"""The floors: `random` (uniform labels) and `nearest-prior` (the priors' schedules, never updated)."""

from __future__ import annotations

from typing import Any

import numpy as np

from deint_env.episode import Priors
from deint_env.params import SEED, Param, declare
from deint_env.policies import policy_rng


class RandomPolicy:
    """Uniformly random labels over all n_labels + 1 actions (spurious included)."""

    lag = 0

    PARAMS = declare(SEED)

    def __init__(self, seed: int | None = None):
        self.PARAMS.check(locals())
        self.seed = seed

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self._rng = policy_rng(info, self.seed)
        self._n = priors.n_labels + 1

    def act(self, obs: dict[str, Any]) -> int:
        return int(self._rng.integers(self._n))


class NearestPrior:
    """Labels each pulse with the prior track whose predicted arrival phi_i + n T_i is nearest, using
    the priors as given and never updating them.  An unknown phase is taken as the first pulse's
    TOA.  With spurious pulses possible, a pulse further than `gate` prior-jitter deviations (plus
    the spread the period uncertainty has grown to) from every prediction is called spurious."""

    lag = 0

    PARAMS = declare(Param("gate", float, 4.0, "spurious beyond this many prior deviations from every prediction",
                           low=0, low_open=True))

    def __init__(self, gate: float = 4.0):
        self.PARAMS.check(locals())
        self.gate = gate

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self._priors = priors
        self._phase = priors.phase.copy()
        self._unknown = ~np.isfinite(self._phase)
        self._spurious = priors.spurious_rate > 0

    def act(self, obs: dict[str, Any]) -> int:
        p = self._priors
        y = float(obs["toa"][0])
        if self._unknown.any():
            self._phase[self._unknown] = y
            self._unknown[:] = False
        n = np.maximum(np.round((y - self._phase) / p.period), 0.0)
        resid = np.abs(y - (self._phase + n * p.period))
        best = int(np.argmin(resid))
        if self._spurious:
            spread = np.hypot(p.jitter_std, n * p.period_std)
            if resid[best] > self.gate * max(spread[best], 1e-12):
                return p.n_labels
        return best

"""A deint-bench policy in one module: each pulse goes to the track whose next arrival is predicted
nearest, and that track then follows the pulse (its phase moves to it, its period leans towards the
interval it measured).  `nearest-prior` keeps the priors' schedules; following corrects a prior period
that is slightly off, whose prediction error otherwise grows with every period."""

from __future__ import annotations

from typing import Any

import numpy as np

from deint_env.episode import Priors
from deint_env.policies import PolicyInfo


class Follower:
    lag = 0  # it labels each pulse as it arrives, seeing no later pulse: the online division

    def __init__(self, gain: float = 0.05):
        if not 0 <= gain <= 1:
            raise ValueError(f"gain={gain!r} is invalid: a number in [0, 1]")
        self.gain = gain

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        # priors are public: one prior period and phase per track (a phase may be unknown: NaN)
        self.period = np.array(priors.period, dtype=float)
        self.last = np.array(priors.phase, dtype=float) - self.period  # so the first prediction is the phase

    def act(self, obs: dict[str, Any]) -> int:
        toa = float(obs["toa"][0])
        unknown = ~np.isfinite(self.last)
        self.last[unknown] = toa - self.period[unknown]  # an unknown phase: assume the first pulse is its
        periods = np.maximum(np.round((toa - self.last) / self.period), 1)  # whole periods since each track fired
        track = int(np.argmin(np.abs(toa - (self.last + periods * self.period))))
        interval = (toa - self.last[track]) / periods[track]
        self.period[track] += self.gain * (interval - self.period[track])
        self.last[track] = toa
        return track

    def estimates(self) -> dict[str, np.ndarray]:
        """Optional: each track's period and its last arrival (its phase, modulo the period), scored
        against the truth as period and phase errors."""
        return {"period": self.period.copy(), "phase": self.last.copy()}


# The entry point names this: deint-bench registers every PolicyInfo in it.  Blind scenarios give no
# prior tracks to follow, so the policy declares that it plays anchored ones only; the runner then
# records a blind scenario as not applicable instead of calling reset.
POLICIES = (
    PolicyInfo("follower", "deint_follower:Follower", modes=("anchored",), version=1,
               description="nearest predicted arrival; the chosen track follows the pulse (a tutorial policy)"),
)

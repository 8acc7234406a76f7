"""`genie`: the oracle ceiling as a policy.  It plays the known-parameter MAP labelling of
`deint_env.oracle` (see its docstring), which the runner also uses to normalise every score."""

from __future__ import annotations

from typing import Any

from deint_env.episode import Priors
from deint_env.errors import DeintError
from deint_env.params import declare
from deint_env.oracle import episode_genie_labels, priors_genie_labels


class Genie:
    """The oracle ceiling: MAP labels from the true schedule (or true constant-PRI priors)."""

    PARAMS = declare()
    lag = 0
    oracle = True

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        episode = info.get("episode")
        if episode is not None and episode.truth is not None:
            self._labels = episode_genie_labels(episode).tolist()
        elif episode is not None:
            self._labels = priors_genie_labels(episode.toa, priors).tolist()
        else:
            raise DeintError("genie is an oracle: it must be handed the episode (info['episode'])")
        self._k = 0

    def act(self, obs: dict[str, Any]) -> int:
        label = self._labels[self._k]
        self._k += 1
        return label

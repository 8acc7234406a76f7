"""The experts behaviour cloning and DAgger imitate (`deint train --algo dagger|bc --expert NAME`).

- `truth`: the simulator's truth (`agents.imitation.expert_actions`): each pulse's source, or in blind
  mode the agent's own track of the pulse's true predecessor.
- any registered reference policy spec (`mht`, `fdp`, `dokf`, `genie`, ...): the labels that policy
  gives the episode when it plays it itself (computed once per episode, at the policy's own lag),
  so the learner copies the policy's decisions, its mistakes included.  Oracle specs (`genie`) see
  the episode as the runner lets them.  Anchored scenarios only: a blind reference's track names are
  its own, not the learner's, so its labels are not actions the learner could be scored on.

A reference expert labels the episode as it would label it alone, not from the states the learner's
labels lead to; for anchored labels that is still the right target (the label of a pulse names its
source whatever the learner did before), which is why DAgger with such an expert still makes sense.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from deint_env.errors import DeintError
from deint_env.policies import is_oracle, make_policy, policy_info, parse_policy_spec
from deint_env.runner import play

TRUTH = "truth"


class Expert(Protocol):
    name: str

    def actions(self, env, max_tracks: int) -> np.ndarray:
        """The expert's token action (track index, or max_tracks = spurious) for each sub-env's described pulse."""


class TruthExpert:
    name = TRUTH

    def actions(self, env, max_tracks: int) -> np.ndarray:
        from agents.imitation import expert_actions

        return expert_actions(env, max_tracks)


class ReferenceExpert:
    """A reference policy's own labels of each sub-env's current episode, as token actions."""

    def __init__(self, spec: str):
        name, _ = parse_policy_spec(spec)
        info = policy_info(name)  # one line naming the known policies when unknown
        if info.learned:
            raise DeintError(f"--expert {spec!r} is a learned agent; imitate a reference policy or the truth")
        if "anchored" not in info.modes:  # else refused at the first episode, under a running progress bar
            raise DeintError(f"--expert {spec!r} plays blind scenarios only; imitate an anchored reference policy "
                             "(mht, fdp, genie, ...) or the truth")
        self.name = spec
        self.policy = make_policy(spec)
        self.oracle = is_oracle(spec)
        self._episodes: list[object] = []
        self._labels: list[np.ndarray] = []

    def labels(self, episode) -> np.ndarray:
        """The policy's labels of `episode` (the env's label convention: n_labels = spurious)."""
        if episode.blind:
            raise DeintError(f"--expert {self.name!r} plays anchored scenarios only; imitate the truth on blind ones "
                             "(--expert truth)")
        return play(self.policy, episode, oracle=self.oracle, clustering=False).labels

    def actions(self, env, max_tracks: int) -> np.ndarray:
        feats, base = env.features, env.env.unwrapped
        if len(self._episodes) != env.num_envs:
            self._episodes, self._labels = [None] * env.num_envs, [np.empty(0, np.int64)] * env.num_envs
        out = np.full(env.num_envs, max_tracks, np.int64)
        for i in np.flatnonzero(feats.ready).tolist():
            episode = base.episodes[i]
            if self._episodes[i] is not episode:  # a new episode in this sub-env: label it once
                self._episodes[i], self._labels[i] = episode, self.labels(episode)
            label = int(self._labels[i][int(feats.labelled[i])])
            out[i] = label if label < episode.n_labels else max_tracks
        return out


def make_expert(spec: str) -> Expert:
    return TruthExpert() if spec == TRUTH else ReferenceExpert(spec)

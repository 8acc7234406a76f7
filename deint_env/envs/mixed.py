"""A native vector env that samples a scenario per episode: whole-suite training and curricula."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

from deint_env.envs.deinterleave import DeinterleaveEnv, check_reset_options
from deint_env.envs.vector import DeinterleaveVectorEnv
from deint_env.episode import Episode
from deint_env.errors import DeintError, shown
from deint_env.sim.streams import check_seed
from deint_env.simulate import simulate, simulate_many
from deint_env.suites import SPLITS, SuiteEntry, find_entry, list_suites, load_suite


def select_entries(suite: str | None = None, scenarios: Sequence[str] | None = None,
                   tags: Sequence[str] | None = None) -> list[tuple[str, SuiteEntry]]:
    """(qualified name, entry) of every scenario of `suite` (or of the named `scenarios`) carrying
    all `tags`; one line naming the problem when nothing is left."""
    if suite is None and not scenarios:
        raise DeintError("name a suite or some scenarios to sample from")
    chosen: list[tuple[str, SuiteEntry]] = []
    if suite is not None:
        if suite not in list_suites():
            raise DeintError(f"suite {suite!r} is unknown; known suites: {', '.join(list_suites())}")
        chosen += [(f"{suite}/{e.name}", e) for e in load_suite(suite)]
    for name in scenarios or ():
        if "/" not in name:
            raise DeintError(f"scenario {name!r}: name it as SUITE/SCENARIO")
        chosen.append((name, find_entry(name)))
    if tags:
        chosen = [(n, e) for n, e in chosen if set(tags) <= set(e.tags)]
    if not chosen:
        where = suite or shown(list(scenarios or ()))
        raise DeintError(f"no scenario of {where} has the tags {shown(list(tags or ()))}")
    return chosen


def split_seeds(entry: SuiteEntry, split: str) -> range:
    """The episode seeds of `entry` in `split` (`SuiteEntry.seeds`)."""
    return entry.seeds(split)


def widest_entry(entries: list[tuple[str, SuiteEntry]], split: str) -> SuiteEntry:
    """The entry with the most labels (it sets the action space), after checking `split` and that the
    entries are all anchored or all blind, and all with pulse descriptors or all without (one
    observation space)."""
    if split not in SPLITS:
        raise DeintError(f"split={split!r} is invalid: one of {', '.join(SPLITS)}")
    if len({e.spec.blind for _, e in entries}) > 1:
        raise DeintError("the selected scenarios mix anchored and blind ones; train on one kind at a time")
    if len({e.spec.has_descriptors for _, e in entries}) > 1:
        raise DeintError("the selected scenarios mix ones with pulse descriptors (pdw) and TOA-only ones; their "
                         "observations differ: select one kind (e.g. tags=['pdw'])")
    return max((e for _, e in entries), key=lambda e: e.spec.n_labels)


def draw_episode(entries: list[tuple[str, SuiteEntry]], split: str, rng: np.random.Generator) -> tuple[int, int]:
    """(entry index, episode seed): a scenario drawn uniformly, then a seed of its `split`."""
    e = int(rng.integers(len(entries)))
    seed_range = split_seeds(entries[e][1], split)
    return e, seed_range[int(rng.integers(len(seed_range)))]


class MixedScenarioEnv(DeinterleaveEnv):
    """The single env of `MixedScenarioVectorEnv`: each reset draws a scenario of `select_entries(suite,
    scenarios, tags)` and a seed of its `split` from the env's generator, so `reset(seed=s)` plays the
    episode sub-env 0 of the vector env plays after `reset(seed=s)`.  The action space is the widest
    scenario's (label L = spurious for every episode), as in the vector env."""

    def __init__(self, suite: str | None = None, scenarios: Sequence[str] | None = None,
                 tags: Sequence[str] | None = None, split: str = "train", lag: int = 0,
                 render_mode: str | None = None, clustering_metrics: bool = True):
        self.entries = select_entries(suite, scenarios, tags)
        widest = widest_entry(self.entries, split)
        super().__init__(widest.spec, lag=lag, render_mode=render_mode, clustering_metrics=clustering_metrics)
        self.seed_split = split
        self.scenario_names = [n for n, _ in self.entries]

    def _fits(self, episode: Episode) -> bool:
        return episode.n_labels <= self.n_labels and episode.blind == self.blind

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        check_reset_options(options)
        # (re)seeds the draw: DeinterleaveEnv.reset would simulate its own scenario
        gym.Env.reset(self, seed=None if seed is None else check_seed(seed))
        e, episode_seed = draw_episode(self.entries, self.seed_split, self.np_random)
        return self.load_episode(simulate(self.entries[e][1].spec, episode_seed))


class MixedScenarioVectorEnv(DeinterleaveVectorEnv):
    """`DeinterleaveVectorEnv` whose sub-envs draw a scenario and a seed of its `split` per episode.

    Scenarios come from `select_entries(suite, scenarios, tags)`, uniformly; episode seeds from the
    scenario's `split` seed range only: "train" (its train range but the last `VALIDATION_SEEDS`),
    "validation" (those last seeds) or "test" (never played by "train" or "validation").  The action space
    is `Discrete(L + 1)` for the largest label count L among the scenarios; label L is spurious for
    every episode, and a label beyond an episode's own tracks is simply wrong (the token features
    mask them).  All scenarios must be anchored, or all blind.  `reset(seed=s)` seeds sub-env i's
    sampler with s + i.  The reset and autoreset infos carry `scenario`, `episode_seed`, `n_labels`
    and `n_pulses` per started sub-env; its priors are `episodes[i].priors`.
    """

    def __init__(self, num_envs: int = 1, suite: str | None = None, scenarios: Sequence[str] | None = None,
                 tags: Sequence[str] | None = None, split: str = "train", lag: int = 0,
                 clustering_metrics: bool = False, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP):
        self.entries = select_entries(suite, scenarios, tags)
        widest = widest_entry(self.entries, split)
        super().__init__(num_envs, scenario=widest.spec, lag=lag, clustering_metrics=clustering_metrics,
                         autoreset_mode=autoreset_mode)
        # The parent's `split` is one scenario's seed ranges (None here); this env's split names the range
        # every sampled scenario's seed is drawn from.
        self.seed_split = split
        self.scenario_names = [n for n, _ in self.entries]

    def _start(self, rows: list[int], seeds: list[int | None], infos: dict[str, Any]) -> None:
        picks: list[tuple[int, int]] = []  # (entry index, episode seed) per row
        for i, seed in zip(rows, seeds):
            self.episodes[i] = None
            if seed is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seed)
            picks.append(draw_episode(self.entries, self.seed_split, self._rngs[i]))
        episodes: list[Any] = [None] * len(rows)
        for e in sorted({p[0] for p in picks}):  # one simulate_many call per scenario
            at = [j for j, p in enumerate(picks) if p[0] == e]
            for j, ep in zip(at, simulate_many(self.entries[e][1].spec, [picks[j][1] for j in at])):
                episodes[j] = ep
        self._load(rows, episodes)
        self._add_infos(infos, {"scenario": [self.entries[e][0] for e, _ in picks],
                                "episode_seed": [s for _, s in picks],
                                "n_labels": [ep.n_labels for ep in episodes],
                                "n_pulses": [len(ep) for ep in episodes]}, rows)

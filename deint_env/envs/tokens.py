"""Entry points of `deint_env/DeinterleaveTokens-v0`: the token-feature env, single and batched.

    env = gym.make("deint_env/DeinterleaveTokens-v0", scenario="core-v0/core-n6-spread4-jitter0.05")
    envs = gym.make_vec("deint_env/DeinterleaveTokens-v0", num_envs=16, scenario=..., max_tracks=8)
    envs = gym.make_vec("deint_env/DeinterleaveTokens-v0", num_envs=16, suite="core-v0", split="train")

`gym.make_vec` gives the native vector env with the features computed for all sub-envs at once
(`TrackTokensVector`); with `suite=` (and optionally `tags=`, `split=`) its sub-envs sample a
scenario per episode.  (`gym.make_vec(..., wrappers=[...])` runs per-env wrappers and so needs
`vectorization_mode="sync"`; this id is the fast route.)
"""

from __future__ import annotations

from typing import Any, Sequence

from gymnasium.vector import AutoresetMode

from deint_env.envs.deinterleave import DEFAULT_SCENARIO, DeinterleaveEnv
from deint_env.envs.mixed import MixedScenarioVectorEnv
from deint_env.envs.vector import DeinterleaveVectorEnv
from deint_env.wrappers import TrackTokens, TrackTokensVector


def make_tokens_env(scenario: Any = DEFAULT_SCENARIO, lag: int = 0, max_tracks: int = 8, flat: bool = False,
                    render_mode: str | None = None, clustering_metrics: bool = True) -> TrackTokens:
    return TrackTokens(DeinterleaveEnv(scenario, lag=lag, render_mode=render_mode,
                                       clustering_metrics=clustering_metrics), max_tracks=max_tracks, flat=flat)


def make_tokens_vector_env(num_envs: int = 1, scenario: Any = None, lag: int = 0, max_tracks: int = 8,
                           flat: bool = False, suite: str | None = None, scenarios: Sequence[str] | None = None,
                           tags: Sequence[str] | None = None, split: str = "train",
                           clustering_metrics: bool = False, render_mode: str | None = None,
                           autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP) -> TrackTokensVector:
    if suite is not None or scenarios:
        env = MixedScenarioVectorEnv(num_envs, suite=suite, scenarios=scenarios, tags=tags, split=split, lag=lag,
                                     clustering_metrics=clustering_metrics, autoreset_mode=autoreset_mode)
    else:
        env = DeinterleaveVectorEnv(num_envs, scenario=scenario or DEFAULT_SCENARIO, lag=lag,
                                    render_mode=render_mode, clustering_metrics=clustering_metrics,
                                    autoreset_mode=autoreset_mode)
    return TrackTokensVector(env, max_tracks=max_tracks, flat=flat)

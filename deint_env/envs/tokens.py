"""Entry points of `deint_env/DeinterleaveTokens-v0`: the token-feature env, single and batched.

    env = gym.make("deint_env/DeinterleaveTokens-v0", scenario="core-v0/core-n6-spread4-jitter0.05")
    env = gym.make("deint_env/DeinterleaveTokens-v0", suite="core-v0", split="validation", lag=2)
    envs = gym.make_vec("deint_env/DeinterleaveTokens-v0", num_envs=16, scenario=..., max_tracks=8)
    envs = gym.make_vec("deint_env/DeinterleaveTokens-v0", num_envs=16, suite="core-v0", split="train")

Both take the same keywords (the vector env also `num_envs` and `autoreset_mode`).  With `suite=` (and
optionally `tags=`, `scenarios=`) each episode samples a scenario and a seed of `split` (default
"train"); with one `scenario`, `split` restricts its seeds (default None: any seed).  `gym.make_vec`
gives the native vector env with the features computed for all sub-envs at once (`TrackTokensVector`);
sub-env 0 of `make_vec(..., num_envs=N).reset(seed=s)` plays the single env's `reset(seed=s)` episode.
(`gym.make_vec(..., wrappers=[...])` runs per-env wrappers and so needs `vectorization_mode="sync"`;
this id is the fast route.)
"""

from __future__ import annotations

from typing import Any, Sequence

from gymnasium.vector import AutoresetMode

from deint_env.envs.deinterleave import DEFAULT_SCENARIO, DeinterleaveEnv
from deint_env.envs.mixed import MixedScenarioEnv, MixedScenarioVectorEnv
from deint_env.envs.vector import DeinterleaveVectorEnv
from deint_env.errors import DeintError
from deint_env.wrappers import TrackTokens, TrackTokensVector


def _sampled(scenario: Any, suite: str | None, scenarios: Sequence[str] | None) -> bool:
    """Whether episodes sample a scenario (suite= or scenarios=) rather than play the one `scenario`."""
    if suite is None and not scenarios:
        return False
    if scenario is not None:
        raise DeintError("name one scenario= or a suite= / scenarios= to sample from, not both")
    return True


def make_tokens_env(scenario: Any = None, lag: int = 0, max_tracks: int = 8, flat: bool = False,
                    suite: str | None = None, scenarios: Sequence[str] | None = None,
                    tags: Sequence[str] | None = None, split: str | None = None,
                    clustering_metrics: bool = True, render_mode: str | None = None) -> TrackTokens:
    if _sampled(scenario, suite, scenarios):
        env: DeinterleaveEnv = MixedScenarioEnv(suite, scenarios, tags, split or "train", lag=lag,
                                                render_mode=render_mode, clustering_metrics=clustering_metrics)
    else:
        env = DeinterleaveEnv(scenario or DEFAULT_SCENARIO, lag=lag, render_mode=render_mode,
                              clustering_metrics=clustering_metrics, split=split)
    return TrackTokens(env, max_tracks=max_tracks, flat=flat)


def make_tokens_vector_env(num_envs: int = 1, scenario: Any = None, lag: int = 0, max_tracks: int = 8,
                           flat: bool = False, suite: str | None = None, scenarios: Sequence[str] | None = None,
                           tags: Sequence[str] | None = None, split: str | None = None,
                           clustering_metrics: bool = False, render_mode: str | None = None,
                           autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP) -> TrackTokensVector:
    if _sampled(scenario, suite, scenarios):
        env = MixedScenarioVectorEnv(num_envs, suite=suite, scenarios=scenarios, tags=tags, split=split or "train",
                                     lag=lag, clustering_metrics=clustering_metrics, autoreset_mode=autoreset_mode)
    else:
        env = DeinterleaveVectorEnv(num_envs, scenario=scenario or DEFAULT_SCENARIO, lag=lag,
                                    render_mode=render_mode, clustering_metrics=clustering_metrics, split=split,
                                    autoreset_mode=autoreset_mode)
    return TrackTokensVector(env, max_tracks=max_tracks, flat=flat)

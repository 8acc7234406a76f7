"""Playing a policy over episodes through the env (docs/design.md section 5): `play` one episode,
`play_batch` several in lock-step.  The runner (`deint_env.runner`, which re-exports both) plays every
job with them; `deint label` imports them from here, without the runner's pool, results files and
tables (start-up time, benchmarks/bench_startup.py)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from deint_env.envs.deinterleave import DeinterleaveEnv
from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.policies import BatchPolicy, Policy


@dataclass
class PlayResult:
    labels: np.ndarray
    metrics: dict[str, Any]
    estimates: dict[str, np.ndarray] | None
    seconds: float  # the policy's own time: reset + every act


def check_label(action: Any, n_labels: int) -> None:
    """A label must be an exact integer (a Python int or a numpy integer; bool is not one) in
    [0, n_labels]: 1.7 is not silently truncated, nor "1" parsed."""
    if isinstance(action, (bool, np.bool_)) or not isinstance(action, (int, np.integer)):
        raise DeintError(f"action={action!r} is invalid: a label is an integer (int or numpy integer) in "
                         f"[0, {n_labels}] ({n_labels} = spurious), not a {type(action).__name__}")


def play(policy: Policy, episode: Episode, *, policy_seed: int = 0, oracle: bool = False,
         clustering: bool = True, scored: bool = True) -> PlayResult:
    """Run `policy` over `episode` through the env; the policy sees observations and public priors.
    `scored=False`: labels only (`PlayResult.metrics` empty)."""
    env = DeinterleaveEnv.for_episode(episode, lag=policy.lag, clustering_metrics=clustering, scored=scored)
    obs, info = env.load_episode(episode)
    info["policy_seed"] = int(policy_seed)
    if oracle:
        info["episode"] = episode
    priors = Priors.from_info(info["priors"])
    clock = time.perf_counter
    t0 = clock()
    policy.reset(priors, info)
    spent = clock() - t0
    step, act, n_labels = env.step, policy.act, episode.n_labels
    while True:
        t0 = clock()
        action = act(obs)
        spent += clock() - t0
        if type(action) is not int:  # the common case costs one type test
            check_label(action, n_labels)
        obs, _, terminated, _, info = step(action)
        if terminated:
            break
    estimates = None
    if hasattr(policy, "estimates"):
        est = policy.estimates()
        estimates = {k: np.asarray(v, dtype=np.float64) for k, v in est.items()} if est is not None else None
    return PlayResult(env.labels.copy(), env.metrics() if scored else {}, estimates, spent)


def play_batch(policy: BatchPolicy, episodes: Sequence[Episode], *, policy_seeds: Sequence[int] | None = None,
               clustering: bool = True, scored: bool = True) -> list[PlayResult | NotApplicable]:
    """Play `episodes` in lock-step through one env each, as `play` plays one: each step the policy labels
    the next pulse of every episode still running in one `act_batch` call (`BatchPolicy`); a finished
    episode drops out.  The labels are those `play` gives each episode alone (the protocol's promise,
    held by tests/test_batch_play.py).  Per episode: its PlayResult, or the NotApplicable its `reset_row`
    raised.  The policy's time (`reset_batch`, every `reset_row` and `act_batch`) is one figure for the
    batch, so each result's `seconds` is its share by pulses: every episode gets the batch's time per
    pulse.  `policy_seeds`: per episode (default 0).  A failure of the policy (an exception, a bad
    label) is raised: which episode caused it is not known (`run_batch` replays the jobs alone)."""
    k = len(episodes)
    seeds = [0] * k if policy_seeds is None else list(policy_seeds)
    clock = time.perf_counter
    t0 = clock()
    policy.reset_batch(k)
    spent = clock() - t0
    outcomes: list[PlayResult | NotApplicable | None] = [None] * k
    envs: dict[int, DeinterleaveEnv] = {}
    obs: dict[int, dict[str, Any]] = {}
    for i, episode in enumerate(episodes):
        env = DeinterleaveEnv.for_episode(episode, lag=policy.lag, clustering_metrics=clustering, scored=scored)
        obs[i], info = env.load_episode(episode)
        info["policy_seed"] = int(seeds[i])
        priors = Priors.from_info(info["priors"])
        t0 = clock()
        try:
            policy.reset_row(i, priors, info)
        except NotApplicable as e:
            outcomes[i] = e
            continue
        finally:
            spent += clock() - t0
        envs[i] = env
    live = sorted(envs)
    keys = list(obs[live[0]]) if live else []
    while live:
        rows = np.array(live, np.int64)
        batch = {key: np.stack([obs[i][key] for i in live]) for key in keys}
        t0 = clock()
        labels = policy.act_batch(rows, batch)
        spent += clock() - t0
        labels = labels.tolist() if isinstance(labels, np.ndarray) else list(labels)
        if len(labels) != len(live):
            raise DeintError(f"act_batch returned {len(labels)} labels for {len(live)} episodes")
        still = []
        for i, action in zip(live, labels):
            env = envs[i]
            if type(action) is not int:
                check_label(action, env.n_labels)
            obs[i], _, terminated, _, _ = env.step(action)
            if terminated:
                outcomes[i] = PlayResult(env.labels.copy(), env.metrics() if scored else {}, None, 0.0)
            else:
                still.append(i)
        live = still
    pulses = sum(len(episodes[i]) for i in envs)
    return [replace(o, seconds=spent * len(e) / max(pulses, 1)) if isinstance(o, PlayResult) else o
            for o, e in zip(outcomes, episodes)]

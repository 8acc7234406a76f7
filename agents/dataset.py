"""Demonstrations as Minari datasets (`deint dataset`): a reference policy playing the episodes of a
suite's (or some scenarios') seed split, recorded with Minari's `DataCollector(record_infos=True)`.

Each episode is `simulate(scenario, seed)` for the first `seeds` seeds of the split of each chosen
scenario, played by the policy itself (`deint_env.runner.play`, at the policy's own lag, which is
also the env's lag), so the recorded actions are exactly the policy's decisions:

- `env="raw"`: `deint_env/Deinterleave-v0`, action = the policy's label (n_labels = spurious); all
  scenarios must have one number of labels (the spaces of a dataset are fixed);
- `env="tokens"`: `deint_env/DeinterleaveTokens-v0` (`max_tracks`), action = the track index
  (max_tracks = spurious), any mix of scenarios up to max_tracks labels.

Every info (reset and steps; the same keys and types throughout, as Minari needs) carries, besides
the env's own keys, `pulse` (the index of the pulse this step labels, -1 before the first labelled
pulse and at reset), `true_label` (its source in the env's label convention, n_labels = spurious;
anchored scenarios: the right label; blind: the source id, not a track name) and `reference_label`
(the policy's label of it); both -1 where `pulse` is -1.  During the first `lag` steps no pulse is
labelled and the action (spurious) is ignored by the env.  The priors' `modulation` (agile-v2's: a list of
dicts, which HDF5 cannot hold) is recorded as its JSON text.

The dataset is written into a temporary directory beside its destination and renamed into place only
when complete; an existing dataset is never overwritten.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import EnvSpec

from deint_env.envs.deinterleave import DeinterleaveEnv
from deint_env.envs.mixed import select_entries, split_seeds
from deint_env.envs.tokens import make_tokens_env
from deint_env.errors import DeintError
from deint_env.policies import is_oracle, make_policy
from deint_env.registration import ENTRY, TOKENS_ID
from deint_env.runner import play
from deint_env.simulate import simulate

FLAVOURS = ("raw", "tokens")
NO_PULSE = -1


@dataclass(frozen=True)
class DatasetConfig:
    dataset_id: str  # Minari's (namespace/)name-vN
    policy: str = "fdp"
    suite: str | None = None
    scenarios: tuple[str, ...] = ()
    tags: tuple[str, ...] = ()
    split: str = "train"
    seeds: int = 2  # episodes per scenario: the split's first seeds
    env: str = "raw"
    max_tracks: int = 8  # tokens flavour
    root: Path | None = None  # datasets directory (default: Minari's, MINARI_DATASETS_PATH or ~/.minari/datasets)


def recovery_spec(config: DatasetConfig, scenarios: list[str], lag: int) -> EnvSpec:
    """The env a dataset records as its `env_spec` (Minari's `recover_environment()` makes it): the
    flavour's env on the dataset's scenarios and split, at the policy's lag; several scenarios are
    sampled per episode (`deint_env.envs.mixed`), as the token env does with `scenarios=`."""
    where: dict[str, Any] = {"scenario": scenarios[0]} if len(scenarios) == 1 else {"scenarios": scenarios}
    kwargs = {**where, "split": config.split, "lag": lag}
    if config.env == "tokens":
        return EnvSpec(TOKENS_ID, "deint_env.envs.tokens:make_tokens_env",
                       kwargs={**kwargs, "max_tracks": config.max_tracks})
    entry = ENTRY if len(scenarios) == 1 else "deint_env.envs.mixed:MixedScenarioEnv"
    return EnvSpec("deint_env/Deinterleave-v0", entry, kwargs=kwargs)


class DemoEnv(gym.Env):
    """Plays `reset(seed=s, options={"scenario": name})`'s episode with the chosen flavour, and adds
    the label keys to every info (module doc).  Built once per dataset; one inner env per scenario."""

    metadata = {"render_modes": []}

    def __init__(self, config: DatasetConfig, scenarios: list[str], lag: int):
        self.config, self.lag = config, lag
        self._inner: dict[str, gym.Env] = {name: self._make(name) for name in scenarios}
        first = next(iter(self._inner.values()))
        self.observation_space, self.action_space = first.observation_space, first.action_space
        for name, env in self._inner.items():
            if env.observation_space != self.observation_space or env.action_space != self.action_space:
                raise DeintError(f"--env raw: {name} has other spaces than {scenarios[0]} (another number of labels); "
                                 "record one number of sources per dataset, or use --env tokens")
        self._env: gym.Env = first
        self.spec = recovery_spec(config, scenarios, lag)
        self._k = 0
        self._truth = self._reference = np.empty(0, np.int64)
        self._spurious = 0

    def _make(self, name: str) -> gym.Env:
        if self.config.env == "tokens":
            return make_tokens_env(name, lag=self.lag, max_tracks=self.config.max_tracks, clustering_metrics=False)
        return DeinterleaveEnv(name, lag=self.lag, clustering_metrics=False)

    def load(self, scenario: str, truth: np.ndarray, reference: np.ndarray, n_labels: int) -> None:
        self._env, self._truth, self._reference = self._inner[scenario], truth, reference
        self._spurious = self.config.max_tracks if self.config.env == "tokens" else n_labels

    def action_of(self, label: int, n_labels: int) -> int:
        """The env action naming `label` (n_labels = spurious)."""
        return self._spurious if label >= n_labels else label

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        obs, info = self._env.reset(seed=seed)
        self._k = 0
        return obs, {**recordable(info), "pulse": NO_PULSE, "true_label": NO_PULSE, "reference_label": NO_PULSE}

    def step(self, action):
        j = self._k - self.lag
        self._k += 1
        obs, reward, terminated, truncated, info = self._env.step(action)
        extra = ({"pulse": j, "true_label": int(self._truth[j]), "reference_label": int(self._reference[j])} if j >= 0
                 else {"pulse": NO_PULSE, "true_label": NO_PULSE, "reference_label": NO_PULSE})
        return obs, float(reward), terminated, truncated, {**recordable(info), **extra}


def recordable(info: dict[str, Any]) -> dict[str, Any]:
    """`info` with the priors' modulations as JSON text: a list of dicts has no HDF5 type (h5py's TypeError)."""
    priors = info.get("priors")
    if not isinstance(priors, dict) or "modulation" not in priors:
        return info
    return {**info, "priors": {**priors, "modulation": json.dumps(priors["modulation"])}}


@contextmanager
def _datasets_path(path: Path) -> Iterator[None]:
    """Minari reads its datasets directory from MINARI_DATASETS_PATH at each call."""
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield
    finally:
        if old is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def _check(config: DatasetConfig) -> tuple[Path, dict[str, Any]]:
    from minari.dataset.minari_dataset import parse_dataset_id

    if config.env not in FLAVOURS:
        raise DeintError(f"--env {config.env!r} is unknown; one of {', '.join(FLAVOURS)}")
    if config.seeds < 1:
        raise DeintError(f"--seeds={config.seeds} must be >= 1")
    # Minari's id grammar, (namespace/)name-vN; a versioned id, so a re-export never overwrites.  Each
    # part starts with a letter, digit or underscore: an id is a path under the datasets root, and a
    # part of dots ("../../x-v0") would leave it.
    bad = f"dataset id {config.dataset_id!r} is invalid: write NAMESPACE/NAME-vN, e.g. deint/core-fdp-v0"
    if not re.fullmatch(r"\w[\w.-]*(/\w[\w.-]*)*-v\d+", config.dataset_id):
        raise DeintError(bad)
    try:
        parse_dataset_id(config.dataset_id)
    except ValueError:
        raise DeintError(bad) from None
    # absolute: Minari joins a relative MINARI_DATASETS_PATH (the temporary folder below) onto itself again
    root = (Path(config.root) if config.root is not None else Path(
        os.environ.get("MINARI_DATASETS_PATH") or Path.home() / ".minari" / "datasets")).absolute()
    if (root / config.dataset_id).exists():
        raise DeintError(f"dataset {config.dataset_id} already exists in {root}; choose another name or version")
    entries = select_entries(config.suite, config.scenarios, config.tags)
    for name_, entry in entries:
        if config.seeds > len(split_seeds(entry, config.split)):
            raise DeintError(f"--seeds={config.seeds}: {name_} has {len(split_seeds(entry, config.split))} "
                             f"{config.split} seeds")
        if config.env == "tokens" and entry.spec.n_labels > config.max_tracks:
            raise DeintError(f"{name_} has {entry.spec.n_labels} labels; --max-tracks is {config.max_tracks}")
    return root, dict(entries)


def write_dataset(config: DatasetConfig, progress: bool = False):
    """Record the demonstrations and create the Minari dataset; returns (its directory, episode count)."""
    from minari import DataCollector

    root, entries = _check(config)
    scenarios = list(entries)
    policy = make_policy(config.policy)
    oracle = is_oracle(config.policy)
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".deint-dataset-", dir=root))
    try:
        env = DemoEnv(config, scenarios, policy.lag)
        with _datasets_path(tmp), warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # Minari's reminders of metadata we fill in below
            collector = DataCollector(env, record_infos=True)
            episodes = 0
            for name in scenarios:
                first = split_seeds(entries[name], config.split).start
                for seed in range(first, first + config.seeds):
                    episode = simulate(entries[name].spec, seed)
                    labels = play(policy, episode, oracle=oracle, clustering=False).labels
                    n = episode.n_labels
                    truth = np.where(episode.source >= 0, episode.source, n).astype(np.int64)
                    env.load(name, truth, labels.astype(np.int64), n)
                    collector.reset(seed=seed)
                    terminated = False
                    for k in range(len(episode) + policy.lag):
                        j = k - policy.lag
                        action = env.action_of(int(labels[j]), n) if j >= 0 else env.action_of(n, n)
                        _, _, terminated, _, _ = collector.step(action)
                    if not terminated:
                        raise DeintError(f"{name} seed {seed}: the episode did not end after its {len(episode)} pulses")
                    episodes += 1
                    if progress:
                        print(f"  {name} seed {seed}: {len(episode)} pulses", flush=True)
            collector.create_dataset(  # no eval_env: Minari's recover_environment(eval_env=True) gives env_spec's
                config.dataset_id, algorithm_name=f"deint-bench reference policy {config.policy}",
                author="deint-bench", author_email="none", code_permalink="deint dataset",
                description=(f"{config.policy} playing the first {config.seeds} {config.split} seeds of "
                             f"{', '.join(scenarios)} ({config.env} env, lag {policy.lag}); infos hold pulse, "
                             "true_label and reference_label"))
            collector.close()
        dest = root / config.dataset_id
        dest.parent.mkdir(parents=True, exist_ok=True)
        namespace_meta = (tmp / config.dataset_id).parent / "namespace_metadata.json"
        if namespace_meta.is_file() and not (dest.parent / namespace_meta.name).exists():
            shutil.copy2(namespace_meta, dest.parent / namespace_meta.name)
        os.rename(tmp / config.dataset_id, dest)  # complete: one rename puts it in place
        return dest, episodes
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

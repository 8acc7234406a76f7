"""What `deint train` is asked (`TrainConfig`, documented in agents.train) and what it returns
(`TrainResult`): kept apart from the trainers so each algorithm's module can import them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deint_env.errors import check


@dataclass(frozen=True)
class TrainConfig:
    out: Path
    algo: str = "maskable-ppo"
    suite: str | None = None
    scenarios: tuple[str, ...] = ()
    tags: tuple[str, ...] = ()
    lag: int = 0
    n_envs: int | None = None  # None: the YAML's
    timesteps: int | None = None  # None: the YAML's n_timesteps
    time_budget: float | None = None  # seconds of training, checked every env step
    seed: int = 0
    eval_every: int = 50_000
    eval_episodes: int = 32
    hyperparams_file: Path | None = None
    into_package: bool = False
    progress: bool = True
    expert: str = "truth"  # dagger / bc: "truth" or a reference policy spec (agents.experts)


@dataclass
class TrainResult:
    last: Path
    best: Path | None
    timesteps: int
    seconds: float
    evaluations: list[dict[str, Any]] = field(default_factory=list)


def hp_int(hp: dict[str, Any], key: str, default: int, hi: int, where: str, prefix: str = "") -> int:
    """The YAML entry's `key` as an integer in [1, hi] (a whole float such as 1e6 too), else one line."""
    value = hp.get(key, default)
    check(whole(value, hi), f"{where}: {prefix}{key}", value, f"an integer in [1, {hi:g}]")
    return int(value)


def whole(value: Any, hi: int) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) \
        and float(value).is_integer() and 1 <= value <= hi

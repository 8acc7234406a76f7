"""The policy protocol (DESIGN section 5) and the policy registry.

A policy has `reset(priors, info)` and `act(obs) -> label`, declares the `lag` it needs, and may
expose `estimates()` -> {"period": array, "phase": array} (one entry per label track) for the
estimation metrics.  Evaluation hands a policy only the observations and the public priors; an
*oracle* (`oracle = True`, e.g. `genie`) is also handed the whole episode in `info["episode"]` and is
reported as a ceiling, never as a method.  Stochastic policies draw from `info["policy_seed"]`.

Every policy has a registered name and keyword parameters; on the command line it is written
`NAME` or `NAME:key=value,key=value` (e.g. `fdp:lookahead=4`).
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from deint_env.episode import Priors
from deint_env.errors import DeintError

# Modules whose import registers their policies (baselines first: the floors and the ceiling).
# deint_env.tdc registers the TDC model adapter; it imports h5py only when it reads or writes a file.
PROVIDERS = ("baselines", "agents", "deint_env.tdc")


@runtime_checkable
class Policy(Protocol):
    lag: int

    def reset(self, priors: Priors, info: dict[str, Any]) -> None: ...

    def act(self, obs: dict[str, Any]) -> int: ...


@dataclass(frozen=True)
class PolicyInfo:
    name: str
    factory: Callable[..., Policy] | str  # a callable, or "module:attribute" imported on first use
    oracle: bool = False
    description: str = ""
    extra: str | None = None  # the optional dependency set it needs, e.g. "rl"
    kind: str = "reference"  # 'reference' | 'learned' | 'oracle' | 'adapter': leaderboards show it
    version: int = 1  # bump when the policy's behaviour changes: results of other versions are replayed

    def load(self) -> Callable[..., Policy]:
        if callable(self.factory):
            return self.factory
        module, attr = self.factory.split(":")
        try:
            return getattr(importlib.import_module(module), attr)
        except ImportError as e:
            hint = f"; install it with: pip install 'deint-bench[{self.extra}]'" if self.extra else ""
            raise DeintError(f"policy {self.name!r} needs {e.name or 'a missing module'}{hint}") from None


_REGISTRY: dict[str, PolicyInfo] = {}
_loaded = False


def register_policy(name: str, factory: Callable[..., Policy] | str, *, oracle: bool = False,
                    description: str = "", extra: str | None = None) -> None:
    """Register a policy factory under `name` (idempotent for the same factory)."""
    info = PolicyInfo(name, factory, oracle, description, extra)
    old = _REGISTRY.get(name)
    if old is not None and old.factory != factory:
        raise ValueError(f"policy name {name!r} is already registered to {old.factory!r}")
    _REGISTRY[name] = info


def _load_providers() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for module in PROVIDERS:
            importlib.import_module(module)


def list_policies() -> list[PolicyInfo]:
    _load_providers()
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]


def policy_info(name: str) -> PolicyInfo:
    _load_providers()
    if name not in _REGISTRY:
        raise DeintError(f"policy {name!r} is unknown; known policies: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def _parse_value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parse_policy_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """'fdp:lookahead=4,variant=x' -> ('fdp', {'lookahead': 4, 'variant': 'x'})."""
    if not isinstance(spec, str) or not spec.strip():
        raise DeintError(f"policy={spec!r} is invalid: write NAME or NAME:key=value,key=value")
    name, _, rest = spec.strip().partition(":")
    kwargs: dict[str, Any] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or not key.strip().isidentifier():
            raise DeintError(f"policy parameter {item!r} in {spec!r} is invalid: write key=value")
        kwargs[key.strip()] = _parse_value(value.strip())
    return name.strip(), kwargs


def canonical_spec(name: str, kwargs: dict[str, Any]) -> str:
    """The one way to write a policy with its parameters (keys sorted): result files key on it."""
    if not kwargs:
        return name
    return name + ":" + ",".join(f"{k}={kwargs[k]}" for k in sorted(kwargs))


def make_policy(spec: str) -> Policy:
    """Build a registered policy from 'NAME' or 'NAME:key=value,...'; unknown keys are an error."""
    name, kwargs = parse_policy_spec(spec)
    info = policy_info(name)
    factory = info.load()
    params = inspect.signature(factory).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        allowed = [k for k, p in params.items() if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
        for key in kwargs:
            if key not in allowed:
                raise DeintError(f"policy {name!r} has no parameter {key!r}; its parameters: "
                                 f"{', '.join(allowed) or 'none'}")
    try:
        policy = factory(**kwargs)
    except (TypeError, ValueError) as e:
        raise DeintError(f"policy {spec!r}: {e}") from None
    if not isinstance(policy, Policy):
        raise DeintError(f"policy {name!r} does not implement reset(priors, info), act(obs) and lag")
    return policy


def is_oracle(spec: str) -> bool:
    return policy_info(parse_policy_spec(spec)[0]).oracle


def policy_rng(info: dict[str, Any], seed: int | None) -> np.random.Generator:
    """A policy's generator: its own `seed` parameter if given, else the runner's `policy_seed`."""
    return np.random.default_rng(seed if seed is not None else info.get("policy_seed", 0))

"""The policy protocol (docs/design.md section 5) and the one policy registry.

A policy has `reset(priors, info)` and `act(obs) -> label`, declares the `lag` it needs, and may
expose `estimates()` -> {"period": array, "phase": array} (one entry per label track) for the
estimation metrics.  Evaluation hands a policy only the observations and the public priors; an
*oracle* (kind "oracle", e.g. `genie`) is also handed the whole episode in `info["episode"]` and is
reported as a ceiling, never as a method.  Stochastic policies draw from `info["policy_seed"]`.

Every policy has a registered name, metadata (`PolicyInfo`: kind, the modes it plays, limits, a
version, a description) and keyword parameters; on the command line it is written `NAME` or
`NAME:key=value,key=value` (e.g. `fdp:lookahead=4`).

Registration.  A provider is a module attribute holding a sequence of `PolicyInfo`s, named in the
entry point group `deint_bench.policies` of its distribution's metadata, e.g. in pyproject.toml::

    [project.entry-points."deint_bench.policies"]
    my-policies = "my_package.policies:POLICIES"

deint-bench's own providers (`baselines:POLICIES`, `agents:POLICIES`) are declared there too, and
are also loaded by name (`BUILTIN_PROVIDERS`) so that a source tree works without being installed.
Factories are "module:attribute" strings imported on first use, so listing policies imports neither
torch nor a third party's model code; building a third-party policy runs that package's code.
"""

from __future__ import annotations

import importlib
import inspect
import math
import re
import weakref
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable, shown

GROUP = "deint_bench.policies"
# The providers shipped in this repository (also declared under GROUP in pyproject.toml; a test checks
# that the two agree): loaded even when the installed metadata is older than the source tree.
BUILTIN_PROVIDERS = {"baselines": "baselines:POLICIES", "agents": "agents:POLICIES"}
KINDS = ("reference", "learned", "oracle", "adapter")
MODES = ("anchored", "blind")
MAX_SEED = 2**63


@runtime_checkable
class Policy(Protocol):
    lag: int

    def reset(self, priors: Priors, info: dict[str, Any]) -> None: ...

    def act(self, obs: dict[str, Any]) -> int: ...


@runtime_checkable
class BatchPolicy(Policy, Protocol):
    """A policy that also plays K episodes in lock-step (`deint_env.runner.play_batch`), as a vectorised
    policy serves SB3's `evaluate_policy` over a VecEnv: one call per step for the pulses of all K, so a
    network's forward pass and a policy's per-call overheads are paid once for K pulses.

    `reset_batch(K)` makes K idle rows; `reset_row(row, priors, info)` starts an episode in one (it may
    raise NotApplicable: that episode is not played); each step, `act_batch(rows, obs)` gets the rows whose
    episodes are still running and their raw observations stacked (`obs[key][i]` is row `rows[i]`'s, as `act`
    would get it) and returns their labels in that order.  A finished episode's row drops out of `rows`.
    A row's labels must not depend on the other rows: a batch labels exactly as each episode alone.  A
    batched play collects no `estimates()`."""

    def reset_batch(self, n: int) -> None: ...

    def reset_row(self, row: int, priors: Priors, info: dict[str, Any]) -> None: ...

    def act_batch(self, rows: np.ndarray, obs: dict[str, np.ndarray]) -> np.ndarray: ...


@dataclass(frozen=True)
class Limits:
    """What a policy's defaults can play (None: no limit); parameters may move them (tree's max_pulses)."""

    max_sources: int | None = None
    max_pulses: int | None = None


@dataclass(frozen=True)
class PolicyInfo:
    """A registered policy.  `version` is bumped whenever the policy's labels change for the same
    episode and parameters: results are keyed on it.  `extra`: the optional dependency set it needs."""

    name: str
    factory: Callable[..., Policy] | str  # a callable, or "module:attribute" imported on first use
    kind: str = "reference"
    modes: tuple[str, ...] = MODES
    limits: Limits = field(default_factory=Limits)
    version: int = 1
    description: str = ""
    extra: str | None = None
    required: tuple[str, ...] = ()  # parameters every spec must name (agent's checkpoint, tdc's model)
    provider: str = ""  # the entry point (or "register_policy") it came from
    # the built policy's own `version` keys its results (a learned checkpoint's hash, a tuned preset's)
    instance_version: bool = False
    # learned policies: the parameters that switch the learned part off ("network=off"), played beside
    # the policy on every board so that its row can show what the learning adds (its learned share)
    ablation: str | None = None
    # (division, parameters) for the divisions its defaults' lag does not reach, e.g. mht's
    # ("online", "lag=3,nscan=3"): boards play each as a row of its own (deint_env.divisions)
    division_params: tuple[tuple[str, str], ...] = ()
    # "module:function" listing the specs of this policy a suite's board plays, given the suite name
    # (a tuned entry: one per preset made for that suite); imported only when a board is built
    variants: str | None = None
    # the declared parameters (deint_env.params.ParamSet), or "module:attribute" naming them; None: the
    # factory's own `PARAMS` attribute, if it has one (`declaration()`)
    params: Any = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name or any(c in ":,=" or c.isspace() for c in self.name):
            raise ValueError(f"policy {self.name!r}: the name is invalid: a non-empty string without ':', ',', '=' "
                             f"or spaces (a spec is NAME:key=value,...)")
        if self.kind not in KINDS:
            raise ValueError(f"policy {self.name!r}: kind={self.kind!r} is invalid: one of {', '.join(KINDS)}")
        if not self.modes or any(m not in MODES for m in self.modes):
            raise ValueError(f"policy {self.name!r}: modes={self.modes!r} is invalid: a non-empty subset of {MODES}")
        if isinstance(self.version, bool) or not isinstance(self.version, int) or self.version < 1:
            raise ValueError(f"policy {self.name!r}: version={self.version!r} is invalid: an integer >= 1")
        if self.ablation is not None and parse_policy_spec(f"{self.name}:{self.ablation}")[1] == {}:
            raise ValueError(f"policy {self.name!r}: ablation={self.ablation!r} is invalid: key=value parameters")

    @property
    def oracle(self) -> bool:
        return self.kind == "oracle"

    @property
    def learned(self) -> bool:
        return self.kind == "learned"

    def load(self) -> Callable[..., Policy]:
        if callable(self.factory):
            return self.factory
        module, attr = self.factory.split(":")
        try:
            return getattr(importlib.import_module(module), attr)
        except ImportError as e:
            hint = f"; install it with: pip install 'deint-bench[{self.extra}]'" if self.extra else ""
            raise DeintError(f"policy {self.name!r} needs {e.name or 'a missing module'}{hint}") from None

    def declaration(self) -> Any:
        """The policy's declared parameters (a `deint_env.params.ParamSet`), or None; imports the factory
        (or the module `params` names)."""
        if self.params is None:
            return getattr(self.load(), "PARAMS", None)
        if isinstance(self.params, str):
            module, attr = self.params.split(":")
            return getattr(importlib.import_module(module), attr)
        return self.params


_REGISTRY: dict[str, PolicyInfo] = {}
_loaded = False  # every provider loaded, the entry points' too
_builtins_loaded = False  # the BUILTIN_PROVIDERS loaded


def _add(info: PolicyInfo) -> None:
    old = _REGISTRY.get(info.name)
    if old is not None and (old.factory, old.kind, old.modes) != (info.factory, info.kind, info.modes):
        raise DeintError(f"policy name {info.name!r} is registered twice: by {old.provider or 'register_policy'} "
                         f"({old.factory!r}) and by {info.provider or 'register_policy'} ({info.factory!r})")
    _REGISTRY[info.name] = info


def register_policy(name: str, factory: Callable[..., Policy] | str, **metadata: Any) -> None:
    """Register a policy at run time (notebooks, tests); `metadata`: the other `PolicyInfo` fields."""
    _load_builtin_providers()  # a shipped name is refused now, not at the next lookup
    _add(PolicyInfo(name, factory, provider="register_policy", **metadata))


def providers() -> dict[str, str]:
    """Provider name -> "module:attribute": the entry points of GROUP, and the built-in ones."""
    from importlib.metadata import entry_points  # here: reading the metadata costs every `deint` start-up

    found = {ep.name: ep.value for ep in entry_points(group=GROUP)}
    for name, value in BUILTIN_PROVIDERS.items():
        if found.setdefault(name, value) != value:
            raise DeintError(f"entry point {name!r} of {GROUP} names {found[name]}, not deint-bench's {value}")
    return found


def _load_provider(name: str, value: str) -> None:
    module, _, attr = value.partition(":")
    where = f"policy provider {name!r} ({value}, entry point group {GROUP})"
    try:
        infos = getattr(importlib.import_module(module), attr)
    except ImportError as e:
        raise DeintError(f"{where}: cannot import {e.name or module}") from None
    except AttributeError:
        raise DeintError(f"{where}: {module} has no attribute {attr!r}") from None
    if isinstance(infos, (str, bytes)) or not isinstance(infos, Sequence) or \
            not all(isinstance(i, PolicyInfo) for i in infos):
        raise DeintError(f"{where}: must be a sequence of deint_env.policies.PolicyInfo")
    for info in infos:
        _add(PolicyInfo(**{**info.__dict__, "provider": name}))


def _load_builtin_providers() -> None:
    global _builtins_loaded
    if not _builtins_loaded:
        _builtins_loaded = True
        for name, value in sorted(BUILTIN_PROVIDERS.items()):
            _load_provider(name, value)


def _load_providers() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        _load_builtin_providers()
        for name, value in sorted(providers().items()):
            if name not in BUILTIN_PROVIDERS:
                _load_provider(name, value)


def list_policies() -> list[PolicyInfo]:
    _load_providers()
    return [_REGISTRY[k] for k in sorted(_REGISTRY)]


def policy_info(name: str) -> PolicyInfo:
    """The registered policy `name`.  A shipped policy is found without reading the installed entry points
    (start-up time); a clash of a third party's name with it is reported by `list_policies`."""
    if name not in _REGISTRY:
        _load_builtin_providers()
    if name not in _REGISTRY:
        _load_providers()
    if name not in _REGISTRY:
        raise DeintError(f"policy {name!r} is unknown; known policies: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def default_policies() -> list[str]:
    """The policies leaderboards and benchmarks run by default: every one deint-bench ships (a third
    party's installed policies join only when named) except those that need a parameter named (an
    adapter's model, a checkpoint) and those whose defaults have a pulse limit (tree: short trains only)."""
    return [p.name for p in list_policies() if p.provider in BUILTIN_PROVIDERS and not p.required
            and p.limits.max_pulses is None]


def tuned_specs(suite: str) -> list[str]:
    """The specs shipped policies list for `suite`'s board (`PolicyInfo.variants`: the tuned presets)."""
    out: list[str] = []
    for info in list_policies():
        if info.variants and info.provider in BUILTIN_PROVIDERS:
            module, attr = info.variants.split(":")
            out += [s for s in getattr(importlib.import_module(module), attr)(suite)
                    if parse_policy_spec(s)[0] == info.name]
    return list(dict.fromkeys(out))


def division_specs(name: str) -> list[str]:
    """The specs of `name` in the other divisions (`PolicyInfo.division_params`), canonical."""
    info = policy_info(name)
    return [canonical_spec(*parse_policy_spec(f"{name}:{params}")) for _, params in info.division_params]


def _parse_value(text: str, where: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    if re.fullmatch(r"[+-]?[0-9]+", text):  # ASCII digits: str.isdigit() also passes '²', which int() refuses
        if len(text.lstrip("+-")) > 19 or abs(int(text)) >= MAX_SEED:
            raise DeintError(f"{where} is out of range: integers in policy parameters are below 2^63 in size")
        return int(text)
    if not text.isascii() or "_" in text:  # float() reads '1_0' as 10 and non-ASCII digits: not numbers here
        return text
    try:
        value = float(text)
    except ValueError:
        return text
    if not math.isfinite(value):
        raise DeintError(f"{where} is invalid: numbers in policy parameters are finite")
    return value


def parse_policy_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """'fdp:lookahead=4,variant=x' -> ('fdp', {'lookahead': 4, 'variant': 'x'})."""
    if not isinstance(spec, str) or not spec.strip():
        raise DeintError(f"policy={spec!r} is invalid: write NAME or NAME:key=value,key=value")
    name, _, rest = spec.strip().partition(":")
    kwargs: dict[str, Any] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not key.isidentifier():
            raise DeintError(f"policy parameter {item!r} in {spec!r} is invalid: write key=value")
        if key in kwargs:
            raise DeintError(f"policy parameter {key!r} is given twice in {spec!r}; give each parameter once")
        kwargs[key] = _parse_value(value.strip(), f"policy parameter {item!r} in {spec!r}")
    return name.strip(), kwargs


def canonical_spec(name: str, kwargs: dict[str, Any]) -> str:
    """The one way to write a policy with its parameters (keys sorted): result files key on it."""
    if not kwargs:
        return name
    return name + ":" + ",".join(f"{k}={kwargs[k]}" for k in sorted(kwargs))


def make_policy(spec: str, *, checked: bool = False) -> Policy:
    """Build a registered policy from 'NAME' or 'NAME:key=value,...'; unknown keys are an error.

    Its `act` refuses to run before the first `reset(priors, info)` (a DeintError saying so).  `checked=True`:
    every `act` first checks the observation it is given, as the env makes them (for observations built by
    hand, not from the env): a mapping with 'toa' (one finite TOA, not before the last one since the reset)
    and 'valid' (0 or 1); anything else is a DeintError (a ValueError) naming the key.  It costs every pulse;
    the default costs none."""
    if not isinstance(checked, (bool, np.bool_)):
        raise DeintError(f"checked={checked!r} is invalid: True or False")
    name, kwargs = parse_policy_spec(spec)
    info = policy_info(name)
    missing = [k for k in info.required if k not in kwargs]
    if missing:
        raise DeintError(f"policy {name!r} needs {', '.join(f'{k}=...' for k in missing)}: write "
                         f"{name}:{','.join(f'{k}=VALUE' for k in info.required)}")
    factory = info.load()
    declared = info.declaration()
    params = inspect.signature(factory).parameters
    if declared is not None:  # the declaration names and checks every parameter (deint_env.params)
        for key in kwargs:
            if key not in declared:
                raise DeintError(f"policy {name!r} has no parameter {key!r}; its parameters: "
                                 f"{', '.join(declared.names) or 'none'}")
        try:
            declared.validate(kwargs)
        except DeintError as e:
            raise DeintError(f"policy {spec!r}: {e}") from None
    elif not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        allowed = [k for k, p in params.items() if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
        for key in kwargs:
            if key not in allowed:
                raise DeintError(f"policy {name!r} has no parameter {key!r}; its parameters: "
                                 f"{', '.join(allowed) or 'none'}")
    if "seed" in kwargs:
        check_policy_seed(kwargs["seed"], f"policy {spec!r}: seed")
    try:
        policy = factory(**kwargs)
    except (TypeError, ValueError, OverflowError) as e:
        raise DeintError(f"policy {spec!r}: {e}") from None
    if not isinstance(policy, Policy):
        raise DeintError(f"policy {name!r} does not implement reset(priors, info), act(obs) and lag")
    _check_modes(policy, info, bool(checked))
    return policy


def _check_modes(policy: Policy, info: PolicyInfo, checked: bool = False) -> None:
    """The one check of the priors' type, of the modes a policy plays and of its track limit
    (`Limits.max_sources`), from the registry: its `reset` (and a BatchPolicy's `reset_row`) refuses priors
    that are no `Priors` (a TypeError), and a scenario of another mode, or with more prior tracks (a blind
    one's label budget) than it handles, as not applicable, before the policy sees it.  (An instance
    attribute wraps the bound method, so the policy stays itself: its type and attributes are untouched.)
    Until the first reset, an instance attribute `act` says to reset first (the policy's own `act` would
    fail on state its reset makes); the reset removes it, so `act` is the policy's own again, or, `checked`,
    puts a `_CheckedAct` in its place."""
    limit = info.limits.max_sources

    def check(priors: Priors) -> None:
        if not isinstance(priors, Priors):  # the env's info["priors"] (a dict), None: an AttributeError inside
            raise TypeError(f"policy {info.name!r}: priors={type(priors).__name__} is invalid: a deint_env.Priors "
                            f"(Priors.from_info(info['priors']) gives one)")
        mode = "blind" if priors.blind else "anchored"
        if mode not in info.modes:
            why = ("needs priors: it plays anchored scenarios only, and blind scenarios have none" if mode == "blind"
                   else "plays blind scenarios only: it clusters pulses and has no prior tracks")
            raise NotApplicable(f"policy {info.name!r} {why}")
        if limit is not None and priors.n_labels > limit:
            what = "a label budget" if priors.blind else "prior tracks"
            raise NotApplicable(f"policy {info.name!r} handles at most {limit} tracks; this episode has "
                                f"{priors.n_labels} {what}")

    # the wrappers hold the bound methods weakly: a strong one would make a reference cycle (policy ->
    # wrapper -> method -> policy), and the policy, its work arrays with it, would outlive its episode until
    # the cyclic garbage collector ran
    def weak(bound: Callable[..., None]) -> Callable[[], Callable[..., None]]:
        return weakref.WeakMethod(bound) if inspect.ismethod(bound) else lambda: bound

    reset = weak(policy.reset)
    this = weakref.ref(policy)

    def checked_reset(priors: Priors, episode_info: dict[str, Any]) -> None:
        check(priors)
        method = reset()
        if method is None:  # the policy is gone (`make_policy(spec).reset(...)`): nothing to reset
            return
        method(priors, episode_info)
        # after the policy's own reset: that of a registry-built policy inside it (a tuned preset's) has run first
        obj = this()
        if obj is None:
            return
        state = vars(obj)
        act = state.get("act")
        if isinstance(act, _NotReset):
            del state["act"]  # the policy's own `act` again: no cost per pulse
        if checked:
            if isinstance(act, _CheckedAct):
                act.last = -math.inf
            else:
                state["act"] = _CheckedAct(info.name, weak(obj.act))

    if "act" not in vars(policy):  # a policy that sets its own `act` in __init__ keeps it
        policy.act = _NotReset(info.name)  # type: ignore[method-assign]
    policy.reset = checked_reset  # type: ignore[method-assign]
    if isinstance(policy, BatchPolicy):  # a batch's episodes pass the same check
        reset_row = weak(policy.reset_row)

        def checked_reset_row(row: int, priors: Priors, episode_info: dict[str, Any]) -> None:
            check(priors)
            method = reset_row()
            if method is not None:
                method(row, priors, episode_info)

        policy.reset_row = checked_reset_row  # type: ignore[method-assign]


def spec_version(spec: str, policy: Policy | None = None) -> int | str:
    """What results of `spec` are keyed on: a learned agent's own `version` (its checkpoint's content
    hash, so retraining to the same path never reuses old results) or a tuned entry's (its preset's),
    else the registry's `version`.  Only those policies are built for it (when `policy` is not given)."""
    info = policy_info(parse_policy_spec(spec)[0])
    if info.kind != "learned" and not info.instance_version:
        return info.version
    own = getattr(policy if policy is not None else make_policy(spec), "version", None)
    return own if own is not None else info.version


def ablation_spec(spec: str) -> str | None:
    """`spec` with its learned part switched off (the registry's `ablation` parameters), canonical; None
    for a policy without one."""
    name, kwargs = parse_policy_spec(spec)
    info = policy_info(name)
    if info.ablation is None:
        return None
    return canonical_spec(name, {**kwargs, **parse_policy_spec(f"{name}:{info.ablation}")[1]})


def is_oracle(spec: str) -> bool:
    return policy_info(parse_policy_spec(spec)[0]).oracle


def check_policy_seed(seed: object, what: str = "policy seed") -> int:
    """A policy seed is an integer in [0, 2^63), as numpy's generators take it."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < MAX_SEED:
        raise DeintError(f"{what}={seed!r} is invalid: an integer in [0, 2^63)")
    return int(seed)


def policy_rng(info: dict[str, Any], seed: int | None) -> np.random.Generator:
    """A policy's generator: its own `seed` parameter if given, else the runner's `policy_seed`."""
    return np.random.default_rng(check_policy_seed(seed if seed is not None else info.get("policy_seed", 0)))


class _NotReset:
    """A registry-built policy's `act` until its first reset."""

    def __init__(self, name: str) -> None:
        self.name = name

    def __call__(self, obs: dict[str, Any]) -> int:
        raise DeintError(f"policy {self.name!r}: act(obs) before any reset: call reset(priors, info) first")


class _CheckedAct:
    """`make_policy(checked=True)`'s `act`: the policy's own (held weakly, as its reset is) behind a check of
    each observation; `last` is the last TOA since the reset."""

    def __init__(self, name: str, act: Callable[[], Callable[[dict[str, Any]], int] | None]) -> None:
        self.name, self.act, self.last = name, act, -math.inf

    def __call__(self, obs: dict[str, Any]) -> int:
        where = f"policy {self.name!r}: act(obs)"
        if not isinstance(obs, Mapping):
            raise DeintError(f"{where}: obs={shown(obs)} is invalid: a dict with 'toa' and 'valid', as the env gives")
        for key in ("toa", "valid"):
            if key not in obs:
                raise DeintError(f"{where}: obs has no {key!r} (its keys: {shown(sorted(map(str, obs)))}); the env's "
                                 f"observations have 'toa' and 'valid'")
        valid = obs["valid"]
        if isinstance(valid, (bool, np.bool_)) or not isinstance(valid, (int, np.integer)) or valid not in (0, 1):
            raise DeintError(f"{where}: obs['valid']={shown(valid)} is invalid: 0 or 1 (1: a pulse, 0: padding)")
        try:
            toa = np.asarray(obs["toa"], dtype=np.float64)
        except (TypeError, ValueError):
            toa = None
        if toa is None or toa.shape != (1,):
            raise DeintError(f"{where}: obs['toa']={shown(obs['toa'])} is invalid: an array of one TOA, as the env "
                             f"gives")
        if valid:
            t = float(toa[0])
            if not math.isfinite(t):
                raise DeintError(f"{where}: obs['toa']={t!r} is invalid: a finite TOA")
            if t < self.last:
                raise DeintError(f"{where}: obs['toa']={t!r} is invalid: TOAs do not decrease (the last one: "
                                 f"{self.last!r})")
            self.last = t
        act = self.act()
        if act is None:
            raise DeintError(f"{where}: the policy is gone")
        return act(obs)

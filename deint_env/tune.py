"""Tuning a reference policy's parameters on validation seeds: `deint tune` (issue #23, item 2).

A reference is tuned by the rules a learned agent follows: every choice is made on the validation
split (the last seeds of each scenario's train range, `deint_env.suites`), never on a test seed, under
a stated budget of episode plays.  The search is successive halving (Jamieson & Talwalkar 2016; the
inner loop of Li et al.'s Hyperband): rung 0 plays every candidate on the first k validation seeds of
every scenario, the best 1/eta by mean normalised score go on to eta times the seeds, and so on until
one is left.  The candidates are the policy's defaults, then `Space.known` configurations (a previous
choice worth trying), then draws from the space with a fixed seed; a candidate whose built policy's
`lag` does not fit the division is rejected before it plays.

Plays go through `deint_env.runner.evaluate(split="validation")` into a results file in the work
directory, so an interrupted tune resumes (finished episodes are not replayed) and a rerun replays
nothing and writes the same preset, byte for byte.  The preset (`baselines/presets/POLICY/SUITE.DIVISION
.json`) records the chosen parameters, the search and the command that made it; `baselines.tuned`
registers it as `POLICY-tuned:suite=SUITE`.
"""

from __future__ import annotations

import importlib
import inspect
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, NamedTuple

import numpy as np

from deint_env.divisions import admits, check_division
from deint_env.errors import DeintError
from deint_env.formats.files import check_output, write_text
from deint_env.policies import canonical_spec, check_policy_seed, make_policy, policy_info
from deint_env.suites import load_suite

METHOD = "successive halving"
# How many draws per wanted candidate before giving up: rejected draws (a lag outside the division, an
# invalid combination such as mht's nscan > lag) and repeats are redrawn.
DRAWS_PER_CONFIG = 50
MAX_CONFIGS = 1000  # about a second to draw and build; rung 0 plays each candidate on every scenario anyway
MAX_BUDGET = 10**9  # plays: more than any search spends (MAX_CONFIGS candidates on every validation seed)


# ---------------------------------------------------------------------------------------------------
# search spaces
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Choice:
    """One of `values` (the policy's default among them, where it has one)."""

    values: tuple[Any, ...]

    def draw(self, rng: np.random.Generator) -> Any:
        return self.values[int(rng.integers(len(self.values)))]


@dataclass(frozen=True)
class Range:
    """A number in [low, high], uniform (or log-uniform); floats kept to 3 significant digits so that
    specs stay short and print as they parse."""

    low: float
    high: float
    log: bool = False
    integer: bool = False

    def draw(self, rng: np.random.Generator) -> int | float:
        if self.log:
            x = math.exp(rng.uniform(math.log(self.low), math.log(self.high)))
        else:
            x = rng.uniform(self.low, self.high)
        return int(round(x)) if self.integer else float(f"{x:.3g}")


@dataclass(frozen=True)
class Space:
    """A policy's search space: its parameters, the divisions it can be tuned for (each with the
    parameters fixed there: mht online is `lag=3,nscan=3`), and known configurations tried first.
    `perturb` > 0: each draw redraws about that many parameters of a base candidate (the defaults and
    the known configurations in turn) and keeps the rest, a local search for a large space around
    hand-tuned defaults, where a draw of every parameter at once is nearly always worse; 0: every
    parameter drawn."""

    params: dict[str, Choice | Range]
    divisions: dict[str, dict[str, Any]]
    known: tuple[dict[str, Any], ...] = ()
    perturb: int = 0

    def draw(self, rng: np.random.Generator, i: int) -> dict[str, Any]:
        """The i-th draw."""
        if not self.perturb:
            return {k: p.draw(rng) for k, p in self.params.items()}
        bases = ({}, *self.known)
        params = dict(bases[i % len(bases)])
        keys = list(self.params)
        chosen = rng.random(len(keys)) < self.perturb / len(keys)
        chosen[int(rng.integers(len(keys)))] = True  # at least one
        params.update({k: self.params[k].draw(rng) for k, c in zip(keys, chosen) if c})
        return params


# lmht's search settings (agents.lmht.SEARCH: a choice made on train seeds), copied so that listing the
# space imports no torch; tests/test_tune.py checks that the two agree.
LMHT_SEARCH: dict[str, Any] = {"beam": 64, "margin": 12.0, "margin_per_source": 4.0, "per_source": 4.0, "dead": 1,
                               "look_restart": 2, "look": 1, "jump": 0.04, "jump_z": 2.0, "misfit": 10.0,
                               "wide_from": 6, "nscan": 48}

SPACES: dict[str, Space] = {
    # every key of LMHT_SEARCH, each with mht's default and lmht's value among its choices; nscan <= lag
    # is mht's own rule (a draw breaking it is rejected), so low-latency keeps nscan <= 64.  Deep N-scans
    # (192) held 0.933 against the default's 0.905 on core-v0's hardest scenarios (validation seeds)
    "mht": Space(
        params={"beam": Choice((16, 32, 64, 128)), "margin": Choice((math.inf, 8.0, 12.0, 20.0)),
                "margin_per_source": Choice((0.0, 2.0, 4.0, 8.0)), "per_source": Choice((math.inf, 2.0, 4.0, 8.0)),
                "dead": Choice((1, 2, 3)), "look_restart": Choice((None, 1, 2, 4)), "look": Choice((1, 2, 3)),
                "jump": Choice((0.0, 0.02, 0.04, 0.08)), "jump_z": Choice((0.0, 1.0, 2.0, 3.0)),
                "misfit": Choice((0.0, 5.0, 10.0, 20.0)), "wide_from": Choice((0, 4, 6, 8)),
                "nscan": Choice((12, 24, 48, 96, 192, 384)), "gate": Choice((3.0, 4.0, 5.0)),
                "drift": Choice((0.0, 0.002, 0.01))},
        divisions={"online": {"lag": 3, "nscan": 3}, "low-latency": {"lag": 64}, "offline": {}},
        known=(LMHT_SEARCH,), perturb=2),
    # lookahead <= 3 (+1 with supernumerary) and the prior start keep fdp online; start=lookahead waits
    # `start_lag` pulses (offline)
    "fdp": Space(
        params={"lookahead": Choice((1, 2, 3)), "accumulate": Choice(("lookahead", "sequence")),
                "init": Choice(("phase", "mk94")), "cost": Choice(("raw", "likelihood")),
                "missing": Choice((False, True)), "supernumerary": Choice((False, True)),
                "spurious_penalty": Choice((0.0, 2.0, 5.0, 10.0)), "dropout": Choice((False, True)),
                "gate": Range(3.0, 8.0), "tree_gate": Choice((None, 3.0, 4.0, 6.0)),
                "start": Choice(("prior", "lookahead"))},
        divisions={"online": {}, "low-latency": {}, "offline": {}}),
    "dokf": Space(
        params={"coast": Choice((True, False)), "gate": Range(3.0, 8.0),
                "reset_after": Choice((None, 2, 3, 4, 6, 8)), "rates": Choice(("priors", "estimate")),
                "beam_margin": Choice((5.0, 10.0, 20.0))},
        divisions={"online": {}, "low-latency": {}, "offline": {}}),
    "renewal-ml": Space(
        params={"beam": Choice((None, 16, 32, 64, 128)), "lag": Choice((4, 8, 16, 32, 64)),
                "gate": Range(3.0, 8.0), "switch": Choice((0.001, 0.01, 0.05)),
                "identify": Choice((0, 50, 100, 200)), "margin": Choice((10.0, 20.0, 40.0)),
                "reset_after": Choice((2, 4, 8))},
        divisions={"online": {"lag": 3}, "low-latency": {}, "offline": {}}),
    # a window of w pulses decides with lag w - 1: the histogram methods are offline (or low-latency
    # with windows of at most 65 pulses, too few for a PRI histogram: not declared)
    "cdif": Space(
        params={"x": Choice((0.3, 0.4, 0.5, 0.6, 0.7)), "window": Choice((500, 1000, 2000)),
                "min_pulses": Choice((4, 5, 6, 8)), "min_fill": Choice((0.6, 0.7, 0.8, 0.9)),
                "max_miss": Choice((2, 3, 4, 6)), "presort_eps": Range(0.1, 1.0, log=True),
                "align": Choice((True, False))},
        divisions={"offline": {}}),
}


def space_of(policy: str) -> Space:
    policy_info(policy)  # one line for an unknown policy
    if policy not in SPACES:
        raise DeintError(f"policy {policy!r} has no search space; tunable policies: {', '.join(SPACES)}")
    return SPACES[policy]


# ---------------------------------------------------------------------------------------------------
# candidates
# ---------------------------------------------------------------------------------------------------
class Candidate(NamedTuple):
    params: dict[str, Any]  # those that differ from the policy's defaults
    spec: str  # canonical


def _defaults(policy: str) -> dict[str, Any]:
    """The factory's keyword defaults: a parameter at its default is left out of the spec, so that
    `mht:beam=32` and `mht` are one candidate (and one results key)."""
    factory = policy_info(policy).load()
    # a class passes **kw up its bases (cdif's window is HistogramPolicy's): their defaults count too
    inits = [c.__init__ for c in inspect.getmro(factory) if "__init__" in vars(c)] if inspect.isclass(factory) \
        else [factory]
    out: dict[str, Any] = {}
    for init in inits:
        for k, p in inspect.signature(init).parameters.items():
            if p.default is not inspect.Parameter.empty:
                out.setdefault(k, p.default)
    return out


def candidates(policy: str, division: str, n: int, seed: int = 0) -> list[Candidate]:
    """Up to `n` distinct candidates that fit `division`: the defaults, the known configurations, then
    draws from the space (rng seeded by `seed`).  The division's fixed parameters apply to each."""
    space = space_of(policy)
    check_division(division)
    if division not in space.divisions:
        raise DeintError(f"{policy} cannot be tuned for division {division!r}: its lag does not fit; "
                         f"divisions: {', '.join(space.divisions)}")
    fixed, defaults = space.divisions[division], _defaults(policy)
    rng = np.random.default_rng(seed)
    out: list[Candidate] = []
    seen: set[str] = set()

    def offer(params: dict[str, Any]) -> None:
        params = {k: v for k, v in {**params, **fixed}.items() if not (k in defaults and defaults[k] == v)}
        spec = canonical_spec(policy, params)
        if spec in seen:
            return
        seen.add(spec)
        try:
            built = make_policy(spec)
        except DeintError:  # an invalid combination (mht's nscan > lag): not a candidate
            return
        if admits(division, getattr(built, "lag", None)):
            out.append(Candidate(params, spec))

    for params in ({}, *space.known):
        if len(out) < n:
            offer(dict(params))
    for i in range(DRAWS_PER_CONFIG * n):
        if len(out) >= n:
            break
        offer(space.draw(rng, i))
    if not out:
        raise DeintError(f"{policy} has no configuration whose lag fits division {division!r}")
    return out


# ---------------------------------------------------------------------------------------------------
# the schedule
# ---------------------------------------------------------------------------------------------------
class Rung(NamedTuple):
    configs: int
    seeds: int  # validation seeds per scenario


def _rungs(n: int, eta: int, k0: int, max_seeds: int) -> list[Rung]:
    sizes = [n]
    while sizes[-1] > 1:
        sizes.append(max(1, sizes[-1] // eta))
    return [Rung(c, min(k0 * eta**r, max_seeds)) for r, c in enumerate(sizes)]


def plays(rungs: list[Rung], n_scenarios: int) -> int:
    """Distinct episodes a schedule plays: a survivor's earlier seeds are not replayed (each rung's
    seeds extend the last's)."""
    total, before = 0, 0
    for r in rungs:
        total += r.configs * (r.seeds - before) * n_scenarios
        before = r.seeds
    return total


def schedule(n: int, eta: int, budget: int, n_scenarios: int, max_seeds: int) -> list[Rung]:
    """The rungs for `n` candidates that fit `budget` plays: the most rung-0 seeds that fit; if even
    one seed does not, fewer candidates (the first ones: defaults and known configurations first)."""
    if not isinstance(eta, int) or isinstance(eta, bool) or not 2 <= eta <= MAX_CONFIGS:  # more keeps 1 after rung 0
        raise DeintError(f"eta={eta!r} is invalid: an integer in [2, {MAX_CONFIGS}]")
    while n >= 1:
        if plays(_rungs(n, eta, 1, max_seeds), n_scenarios) <= budget:
            k0 = 1
            while k0 < max_seeds and plays(_rungs(n, eta, k0 + 1, max_seeds), n_scenarios) <= budget:
                k0 += 1
            return _rungs(n, eta, k0, max_seeds)
        n -= 1
    raise DeintError(f"budget={budget} is too small: one play of each of the {n_scenarios} scenarios needs "
                     f"{n_scenarios}")


# ---------------------------------------------------------------------------------------------------
# the search
# ---------------------------------------------------------------------------------------------------
class RungResult(NamedTuple):
    seeds: int
    configs: int
    kept: int
    best_mean: float
    best_spec: str


class TuneResult(NamedTuple):
    preset: dict[str, Any]
    path: Path
    rungs: list[RungResult]


def check_not_test_seeds(suite: str, pairs: Iterable[tuple[str, int]]) -> None:
    """Refuse (scenario, seed) pairs of `suite` that are not validation seeds: a choice made on a
    test seed would leak the test split into a reference (the guard behind `evaluate(split=
    "validation")`)."""
    entries = {e.name: e for e in load_suite(suite)}
    for scenario, seed in pairs:
        if seed not in entries[scenario].seeds("validation"):
            raise DeintError(f"seed {seed} of {suite}/{scenario} is not a validation seed: tuning reads "
                             "validation seeds only")


def default_preset_path(policy: str, suite: str, division: str) -> Path:
    """Where `POLICY-tuned` reads the preset: its factory module's `preset_path` (reached through the
    registry: deint_env imports no policy package)."""
    info = policy_info(f"{policy}-tuned")
    module = importlib.import_module(str(info.factory).partition(":")[0])
    return Path(module.preset_path(policy, suite, division))


def command_line(policy: str, suite: str, division: str, budget: int, configs: int, eta: int, seed: int,
                 scenarios: tuple[str, ...]) -> str:
    """The `deint tune` command that makes this preset (options that cannot change it left out)."""
    cmd = (f"deint tune {policy} --suite {suite} --division {division} --budget {budget} --configs {configs} "
           f"--eta {eta} --seed {seed}")
    return cmd + (f" --scenarios {','.join(scenarios)}" if scenarios else "")


def _mean_scores(records: list, specs: set[str]) -> dict[str, float]:
    """Each spec's mean normalised score over its records; an episode it cannot play (a fault, out of
    its scope) scores 0, random's level.  Summed in a fixed order: reruns choose the same."""
    by_spec: dict[str, list[tuple[str, int, float]]] = {s: [] for s in specs}
    for r in records:
        if r.policy in by_spec:
            score = r.get("score") if r.fault is None else None
            by_spec[r.policy].append((r.scenario, r.seed, 0.0 if score is None else float(score)))
    return {s: math.fsum(x for *_, x in sorted(v)) / max(len(v), 1) for s, v in by_spec.items()}


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text)  # refuses a link, FIFO or device node; replaces the file only once written


def tune(policy: str, suite: str, *, division: str = "offline", budget: int = 2000, configs: int = 27,
         eta: int = 3, seed: int = 0, workers: int = 1, out: str | os.PathLike | None = None,
         work: str | os.PathLike | None = None, scenarios: Iterable[str] = (), progress: bool = True,
         log: Callable[[str], None] = print) -> TuneResult:
    """Tune `policy` on the validation seeds of `suite` (or some of its scenarios) for `division`
    within `budget` plays; write the preset to `out` (default `default_preset_path`)."""
    from deint_env import __version__
    from deint_env.runner import check_workers, evaluate

    suite_obj = load_suite(suite)
    names = tuple(scenarios)
    for name in names:
        suite_obj.entry(name)  # one line for a scenario not in the suite
    entries = [e for e in suite_obj if not names or e.name in names]
    # the candidates are drawn and built before the budget cuts them: an unbounded count never ends
    if not isinstance(configs, int) or isinstance(configs, bool) or not 1 <= configs <= MAX_CONFIGS:
        raise DeintError(f"configs={configs!r} is invalid: an integer in [1, {MAX_CONFIGS}]")
    check_policy_seed(seed, "seed")  # numpy's generators take no negative seed
    check_workers(workers)  # before the schedule is printed
    if not isinstance(budget, int) or isinstance(budget, bool) or not 1 <= budget <= MAX_BUDGET:  # before any build
        raise DeintError(f"budget={budget!r} is invalid: an integer in [1, 10^9] (episode plays)")
    pool = candidates(policy, division, configs, seed)
    n_valid = min(len(e.seeds("validation")) for e in entries)
    rungs = schedule(len(pool), eta, budget, len(entries), n_valid)
    pool = pool[:rungs[0].configs]
    work_dir = Path(work) if work is not None else Path("runs") / "tune" / f"{policy}-{suite}-{division}"
    results = work_dir / "results.jsonl"
    # the preset is written after every play: a path that cannot take it must fail now, not then
    path = Path(out) if out is not None else default_preset_path(policy, suite, division)
    check_output(path)
    if os.path.realpath(path) == os.path.realpath(results):
        raise DeintError(f"--out {path} is the plays' results file {results}; name a different preset file")
    if os.path.realpath(path) == os.path.realpath(work_dir):  # made a folder below, it failed only after every play
        raise DeintError(f"--out {path} is the work folder --work {work_dir}; name a preset file (in it or elsewhere)")
    work_dir.mkdir(parents=True, exist_ok=True)
    targets = [f"{suite}/{e.name}" for e in entries] if names else [suite]

    log(f"tuning {policy} on {suite} ({len(entries)} scenarios, validation seeds) for division {division}: "
        f"{METHOD}, eta={eta}, {len(pool)} candidates, {plays(rungs, len(entries))} of {budget} plays")
    for i, r in enumerate(rungs):
        log(f"  rung {i}: {r.configs} candidates x {r.seeds} seeds x {len(entries)} scenarios")

    alive, done = list(pool), []
    for i, rung in enumerate(rungs):
        log(f"rung {i}: {len(alive)} candidates on {rung.seeds} seeds per scenario")
        specs = [c.spec for c in alive]
        records = [rec for t in targets for rec in evaluate(specs, t, split="validation", max_seeds=rung.seeds,
                                                             workers=workers, out=results, progress=progress)]
        check_not_test_seeds(suite, ((r.scenario, r.seed) for r in records))
        means = _mean_scores(records, set(specs))
        # ties: the earlier candidate (defaults first), so reruns choose the same
        ranked = sorted(range(len(alive)), key=lambda j: (-means[alive[j].spec], j))
        kept = rungs[i + 1].configs if i + 1 < len(rungs) else 1
        best = alive[ranked[0]]
        done.append(RungResult(rung.seeds, len(alive), kept, round(means[best.spec], 6), best.spec))
        log(f"  best {means[best.spec]:.4f}: {best.spec}")
        alive = [alive[j] for j in sorted(ranked[:kept])]
        final = (best, means[best.spec], len([r for r in records if r.policy == best.spec]))

    best, mean, episodes = final
    suite_hash = suite_obj.content_hash
    preset = {
        "policy": policy, "base_version": policy_info(policy).version, "suite": suite, "suite_hash": suite_hash,
        "division": division, "scenarios": list(names) or None,
        "params": {k: best.params[k] for k in sorted(best.params)}, "spec": best.spec,
        "validation": {"seeds_per_scenario": rungs[-1].seeds, "mean_score": round(mean, 6), "episodes": episodes},
        "search": {"method": METHOD, "eta": eta, "budget": budget, "configs": len(pool), "seed": seed,
                   "plays": plays(rungs, len(entries)), "rungs": [r._asdict() for r in done]},
        "command": command_line(policy, suite, division, budget, configs, eta, seed, names),
        "package_version": __version__,
    }
    _write_atomic(path, json.dumps(preset, indent=2, allow_nan=False) + "\n")
    return TuneResult(preset, path, done)

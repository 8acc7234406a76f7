"""Running a suite's test episodes and aggregating them into leaderboard tables.

`build(scope, policies)` plays every policy on every test episode of the scope through
`deint_env.runner.evaluate` (resumable: finished episodes in `results.jsonl` are never played again),
then `write(folder, scope)` aggregates every complete entry of `results.jsonl` (policies and
submissions) and writes the folder's files (see `deint_env.leaderboard`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, NamedTuple

import numpy as np

from deint_env import metrics, stats
from deint_env.aggregate import aggregate_entry
from deint_env.divisions import DIVISIONS
from deint_env.leaderboard import history, ranking, timing
from deint_env.errors import DeintError
from deint_env import policies
from deint_env.policies import spec_version
from deint_env.results import EpisodeRecord, json_ready, read_records, results_lock
from deint_env.runner import evaluate
from deint_env.suites import TAGS, SuiteEntry, list_suites, load_suite

DEFAULT_ROOT = Path("leaderboards")
RESULTS = "results.jsonl"
BOARD = "leaderboard.json"
SUFFIX = " (submitted)"  # a submission's entry is its name and this (deint_env.leaderboard.submit)


def published_suites(root: str | os.PathLike = DEFAULT_ROOT) -> list[str]:
    """The suites with a leaderboard under `root` (a folder named after the suite holding leaderboard.json):
    publishing a new one is building it once; `deint leaderboard --all` then rebuilds it as it was built
    (`board_policies`, `Scope.of_folder`)."""
    root = Path(root)
    return [s for s in list_suites() if (root / s / BOARD).is_file()]


class BoardFile(NamedTuple):
    """What a rebuild reads back from a leaderboard.json: the suite, its scope and the specs it played."""

    suite: str
    scenarios: tuple[str, ...] | None
    max_seeds: int | None
    specs: list[str]


def read_board(folder: Path) -> BoardFile:
    """The fields of `folder`'s leaderboard.json that a rebuild uses, checked field by field: a file that
    is not JSON, too deep, or has a field of the wrong type is one `DeintError` line naming the file
    and the field."""
    path = folder / BOARD
    try:
        board = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        raise DeintError(f"{path}: is not a leaderboard file (not readable JSON); remove it or regenerate "
                         f"the folder") from None

    def field(value: Any, name: str, ok: bool, what: str) -> Any:
        if not ok:
            raise DeintError(f"{path}: field {name} is {json.dumps(value)[:40]}, not {what}; remove the file or "
                             f"regenerate the folder")
        return value

    def strings(value: Any, name: str) -> list[str]:
        return field(value, name, isinstance(value, list) and all(isinstance(v, str) for v in value),
                     "a list of strings")

    def counts(value: Any, name: str) -> list[str]:  # {spec: episodes}
        ok = isinstance(value, dict) and all(type(n) is int and n >= 0 for n in value.values())
        return list(field(value, name, ok, "an object of episode counts"))

    field(board, "(the whole file)", isinstance(board, dict), "a JSON object")
    for key in ("suite", "scope", "rows", "incomplete", "stale"):
        field(board.get(key), key, key in board, "present")
    suite = field(board["suite"], "suite", isinstance(board["suite"], str), "a suite name")
    scope = field(board["scope"], "scope", isinstance(board["scope"], dict), "an object")
    names = scope.get("scenarios")
    if names is not None:
        names = tuple(strings(names, "scope.scenarios"))
    max_seeds = scope.get("max_seeds")
    field(max_seeds, "scope.max_seeds", max_seeds is None or (type(max_seeds) is int and max_seeds >= 1),
          "null or an integer >= 1")
    rows = field(board["rows"], "rows", isinstance(board["rows"], list), "a list")
    specs = []
    for i, row in enumerate(rows):
        field(row, f"rows[{i}]", isinstance(row, dict), "an object")
        field(row.get("policy"), f"rows[{i}].policy", isinstance(row.get("policy"), str), "a policy spec")
        field(row.get("submitted"), f"rows[{i}].submitted", isinstance(row.get("submitted"), bool), "true or false")
        if not row["submitted"]:
            specs.append(row["policy"])
    specs += counts(board["incomplete"], "incomplete") + counts(board["stale"], "stale")
    return BoardFile(suite, names, max_seeds, specs)


def board_policies(folder: Path) -> list[str]:
    """The policy specs a leaderboard was built with, as its leaderboard.json records them: every
    entry's `policy` (the canonical spec, parameters included), then those left incomplete or stale
    (a run that did not finish, or an older version), submissions aside (they are scored, not played).

    A data file never chooses code to import: a recorded spec of an adapter (a policy whose parameters
    name a module to run, e.g. `tdc:model=module:Name`) is refused; name it with --policies to run it."""
    specs = list(dict.fromkeys(s for s in read_board(folder).specs if not s.endswith(SUFFIX)))
    for spec in specs:
        name = policies.parse_policy_spec(spec)[0]  # as it is played: ' tdc:...' is tdc
        if any(info.name == name and info.kind == "adapter" for info in policies.list_policies()):
            raise DeintError(f"{folder / BOARD}: records {spec!r}, whose parameters name code to import; a "
                             f"leaderboard file does not choose what runs: name it with --policies to rebuild it")
    return specs


def default_policies() -> list[str]:
    """The reference policies, as the policy registry names them (`deint_env.policies.default_policies`)."""
    return policies.default_policies()


def plays_suite(spec: str, suite: str) -> bool:
    """Whether the policy of `spec` plays some scenario of `suite` (its modes: anchored, blind)."""
    modes = {"blind" if e.spec.blind else "anchored" for e in load_suite(suite)}
    return bool(modes & set(policies.policy_info(policies.parse_policy_spec(spec)[0]).modes))


def board_entries(suite: str) -> list[str]:
    """What a board plays by default: every shipped policy (`default_policies`) in every division its
    parameters reach (`policies.division_specs`), each tuned preset made for the suite, and beside every
    learned entry its ablation.  Policies that cannot play the suite's mode (blind, anchored) are left out."""
    specs = []
    for name in filter(lambda n: plays_suite(n, suite), default_policies()):
        specs += [name] + policies.division_specs(name)
    specs += policies.tuned_specs(suite)
    specs += [a for a in map(policies.ablation_spec, specs) if a is not None]
    return list(dict.fromkeys(specs))


@dataclass(frozen=True)
class Scope:
    """The episodes a leaderboard scores: every test seed of every scenario of `suite`, or (for smoke
    runs and tests) some scenarios and the first `max_seeds` test seeds of each."""

    suite: str
    scenarios: tuple[str, ...] | None = None
    max_seeds: int | None = None

    def __post_init__(self) -> None:
        load_suite(self.suite)  # one line for an unknown suite
        if self.max_seeds is not None and (not isinstance(self.max_seeds, int) or self.max_seeds < 1):
            raise DeintError(f"max_seeds={self.max_seeds!r} is invalid: an integer >= 1")
        if self.scenarios is not None:
            if not self.scenarios:
                raise DeintError("scenarios=() is invalid: name at least one scenario")
            for name in self.scenarios:
                load_suite(self.suite).entry(name)

    def entries(self) -> list[SuiteEntry]:
        suite = load_suite(self.suite)
        if self.scenarios is None:
            return list(suite)
        wanted = set(self.scenarios)
        return [e for e in suite if e.name in wanted]  # suite order

    def seeds(self, entry: SuiteEntry) -> list[int]:
        return list(entry.test)[: self.max_seeds]

    def episodes(self) -> list[tuple[SuiteEntry, int]]:
        return [(e, s) for e in self.entries() for s in self.seeds(e)]

    def to_json(self) -> dict[str, Any]:
        return {"scenarios": list(self.scenarios) if self.scenarios is not None else None,
                "max_seeds": self.max_seeds}

    @classmethod
    def of_folder(cls, folder: Path, suite: str) -> Scope:
        """The scope an existing leaderboard folder was built with (the whole suite if none)."""
        if not (folder / BOARD).exists():
            return cls(suite)
        board = read_board(folder)
        if board.suite != suite:
            raise DeintError(f"{folder / BOARD}: is the leaderboard of {board.suite}, not {suite}")
        return cls(suite, board.scenarios, board.max_seeds)


def workers_default() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def build(scope: Scope, policies: Iterable[str], *, workers: int | None = None, root: str | os.PathLike = DEFAULT_ROOT,
          progress: bool = True, reps: int = 2000, executor: str = "local",
          address: str | None = None) -> tuple[Path, dict[str, Any]]:
    """Play `policies` on the scope's test episodes (resuming `results.jsonl`) on the local process
    pool or a Ray cluster (`executor`, `address`: see `runner.evaluate`), then write the folder.
    Returns the folder and the leaderboard (as in leaderboard.json)."""
    folder = Path(root) / scope.suite
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DeintError(f"{folder}: cannot create the leaderboard folder ({e.strerror or e})") from None
    policies = list(policies)
    with results_lock(folder / RESULTS):  # one build at a time: its run and its publishing
        if policies:
            targets = [scope.suite] if scope.scenarios is None else [f"{scope.suite}/{e.name}" for e in scope.entries()]
            for target in targets:
                evaluate(policies, target, split="test", max_seeds=scope.max_seeds,
                         workers=workers or workers_default(), out=folder / RESULTS, progress=progress,
                         executor=executor, address=address)
        return folder, write(folder, scope, reps=reps)


def write(folder: Path, scope: Scope, records: list[EpisodeRecord] | None = None,
          reps: int = 2000) -> dict[str, Any]:
    """Aggregate `records` (default: the folder's results.jsonl) and publish every file of the folder
    together (`render.publish`: all are staged first, so a failure leaves the old folder as it was),
    holding the results file's writer lock."""
    from deint_env.leaderboard import episodes, plots, render

    with results_lock(folder / RESULTS):
        records = read_records(folder / RESULTS) if records is None else records
        current = current_versions(records)
        records = without_superseded(records, current)
        board, profiles = aggregate(records, scope, reps=reps, current=current)
        looks = history.update(history.read(folder), board["rows"])
        add_looks_and_timings(board, looks, timing.read(folder, board["suite"]))
        board["examples"], pictures = episodes.examples(scope.entries())
        files = {RESULTS: results_text(records), history.HISTORY: history.text(looks), **pictures}
        files.update(render.render_all(board))
        files.update(plots.render_all(board, profiles))
        obsolete = [p.name for p in folder.glob("*.png") if p.name not in files]
        render.publish(folder, files, obsolete)
    return board


def add_looks_and_timings(board: dict[str, Any], looks: list[history.Look], timings: dict[str, Any] | None) -> None:
    """Each row's test-look count, and its speed from the board's one timing run (none without one:
    times from the scoring runs are never shown, they come from many runs and processes).  A timing of
    another version of the row's policy than the one scored (or of an unrecorded one) is not shown: the
    policy changed since the timing run, and `board["timing"]["stale"]` names it."""
    board["timing"] = None if timings is None else {k: timings[k] for k in ("date", "machine", "method", "reference")}
    stale = []
    for r in board["rows"]:
        r["test_looks"] = history.test_looks(looks, r)
        t = (timings or {}).get("policies", {}).get(r["policy"]) or {}
        if t and t.get("version") != r.get("policy_version"):
            stale.append(r["policy"])
            t = {}
        r["us_per_pulse"], r["vs_fdp"] = t.get("us_per_pulse"), t.get("vs_fdp")
        if t.get("batch", 1) > 1:  # timed playing that many episodes in lock-step (timing.py): the page says so
            r["timing_batch"] = t["batch"]
    if board["timing"] is not None:
        board["timing"]["stale"] = stale


def results_text(records: list[EpisodeRecord]) -> str:
    """results.jsonl in canonical order (policy, scenario, seed): reruns leave it byte-identical."""
    key = lambda r: (r.policy, r.scenario, r.seed, r.scenario_hash, r.policy_version)  # noqa: E731
    return "".join(r.line() for r in sorted(records, key=key))


# ---------------------------------------------------------------------------------------------------
# aggregation
# ---------------------------------------------------------------------------------------------------
def plot_settings(entries: list[SuiteEntry]) -> dict[str, list[Any]]:
    """The scenario settings worth a score-vs-setting plot: numbers with at least two values, and
    labels with two to eight values; each with its sorted values."""
    out: dict[str, list[Any]] = {}
    for key in sorted({k for e in entries for k in e.settings}):
        values = {e.settings[key] for e in entries if key in e.settings
                  and isinstance(e.settings[key], (int, float, str)) and not isinstance(e.settings[key], bool)}
        numeric = all(not isinstance(v, str) for v in values)
        if len(values) >= 2 and (numeric or len(values) <= 8):
            out[key] = sorted(values, key=lambda v: (isinstance(v, str), v))
    return out


def setting_group(key: str, value: Any) -> str:
    return f"setting:{key}={json.dumps(value)}"


def _groups(entries: list[SuiteEntry]) -> tuple[dict[str, list[str]], list[str]]:
    """Bootstrap groups: "all", one per tag ("tag:jitter") and one per plotted setting value."""
    tags = [t for t in TAGS if any(t in e.tags for e in entries)]
    groups = {"all": [e.name for e in entries]}
    groups.update({f"tag:{t}": [e.name for e in entries if t in e.tags] for t in tags})
    for key, values in plot_settings(entries).items():
        for v in values:
            groups[setting_group(key, v)] = [e.name for e in entries if e.settings.get(key) == v]
    return groups, tags


def current_versions(records: list[EpisodeRecord]) -> dict[str, int | str | None]:
    """Each played policy spec's current version (`policies.spec_version`: the registry's, or a learned
    agent's checkpoint hash); None for a submission or a policy not registered here."""
    out: dict[str, int | str | None] = {}
    for r in records:
        if r.policy not in out:
            try:
                out[r.policy] = None if r.submitted else spec_version(r.policy)
            except DeintError:
                out[r.policy] = None
    return out


def without_superseded(records: list[EpisodeRecord],
                       current: dict[str, int | str | None]) -> list[EpisodeRecord]:
    """Drop the stale records (another version of their policy than `current_versions`) whose episode
    has been replayed at the current version; a stale record not yet replayed stays, counted as stale."""

    def episode(r: EpisodeRecord) -> tuple:
        return r.policy, r.scenario, r.scenario_hash, r.seed

    replayed = {episode(r) for r in records if r.policy_version == current[r.policy]}
    return [r for r in records if current[r.policy] in (None, r.policy_version) or episode(r) not in replayed]


def aggregate(records: list[EpisodeRecord], scope: Scope, reps: int = 2000, seed: int = 0,
              current: dict[str, int | str | None] | None = None,
              ) -> tuple[dict[str, Any], dict[str, tuple[np.ndarray, ...]]]:
    """The leaderboard (JSON-ready, floats unrounded) and each entry's performance profile.  Records of
    another version of their policy than the current one (`current`, default `current_versions`) are
    stale: counted, never aggregated."""
    from deint_env import __version__

    suite = load_suite(scope.suite)
    entries = scope.entries()
    expected = {(e.name, e.spec.content_hash, s) for e, s in scope.episodes()}
    by_policy: dict[str, dict[tuple, EpisodeRecord]] = {}
    stale: dict[str, int] = {}
    current = current_versions(records) if current is None else current
    for r in records:
        key = (r.scenario, r.scenario_hash, r.seed)
        if key not in expected:
            continue
        version = current[r.policy]
        if version is not None and r.policy_version != version:
            stale[r.policy] = stale.get(r.policy, 0) + 1
            continue
        by_policy.setdefault(r.policy, {})[key] = r
    groups, tags = _groups(entries)
    order = {e.name: i for i, e in enumerate(entries)}
    seeds = min((len(scope.seeds(e)) for e in entries), default=0)
    intervals = seeds >= ranking.MIN_SEEDS  # fewer seeds: intervals would mislead, so none are shown
    rows, profiles, strata_of, incomplete = [], {}, {}, {}
    for policy in sorted(by_policy):
        got = by_policy[policy]
        if len(got) < len(expected):
            incomplete[policy] = len(got)
            continue
        recs = sorted(got.values(), key=lambda r: (order[r.scenario], r.seed))
        agg = aggregate_entry(recs, groups, taus=stats.TAUS, reps=reps, seed=seed, intervals=intervals)
        strata_of[policy], profiles[policy], est = agg.strata, agg.profile, agg.groups
        row = dict(agg.row)
        row["version"] = ",".join(sorted({r.version for r in recs}))
        row["policy_version"] = None if recs[0].submitted else recs[0].policy_version
        row["tags"] = {t: _flat(est[f"tag:{t}"], sum(len(agg.strata.get(s, ())) for s in groups[f"tag:{t}"]))
                       for t in tags}
        row["by_setting"] = {key: [{"value": v, **_flat(est[setting_group(key, v)])} for v in values]
                             for key, values in plot_settings(entries).items()}
        rows.append(row)
    complete = {p: got for p, got in by_policy.items() if p not in incomplete}
    ranking.assign_divisions(rows)
    ranking.learned_shares(rows, complete, intervals=intervals, reps=reps, seed=seed)
    comparisons = ranking.rank(rows, strata_of, intervals=intervals, reps=reps, seed=seed)
    board = {
        "format": "deint-leaderboard", "format_version": 1,
        "suite": suite.name, "suite_version": suite.version, "suite_hash": suite.content_hash,
        "package_version": __version__, "rliable_version": stats.rliable_version(),
        "scope": scope.to_json(), "scenarios": len(entries), "episodes": len(expected), "tags": tags,
        "bootstrap": {"reps": reps, "seed": seed, "confidence": stats.CONFIDENCE, "strata": "scenarios",
                      "interval": "percentile"},
        "seeds_per_scenario": seeds, "intervals": intervals, "divisions": dict(DIVISIONS),
        "rows": rows, "probability_of_improvement": [c._asdict() for c in comparisons],
        "incomplete": incomplete, "stale": stale,
        "metrics": [{"key": m.key, "label": m.label, "aggregate": m.aggregate, "higher_is_better": m.higher_is_better}
                    for m in metrics.METRICS],  # how to read each row's metric columns
    }
    return json_ready(board), profiles


def _flat(est: dict[str, tuple[float, float, float]], scored: int | None = None) -> dict[str, Any]:
    out = {}
    for name, (p, lo, hi) in est.items():
        out[name], out[f"{name}_low"], out[f"{name}_high"] = p, lo, hi
    if scored is not None:
        out["scored"] = scored
    return out

"""Scenario suites: named, versioned lists of scenarios (bsuite style: settings + tags) kept as JSON data.

Each suite file `deint_env/suites/<name>.json` holds the scenarios, their tags and settings, and two
disjoint seed ranges, `train` and `test`.  They make three splits (`SuiteEntry.seeds`): "train" (the
train range but its last `VALIDATION_SEEDS`: training agents), "validation" (those last seeds: every
choice -- a preset, a checkpoint, a version, a search setting) and "test" (the only seeds a
leaderboard scores, looked at once per finished version).  A suite's content hash covers everything that could move a score; `HISTORY.json` records
the hash of every published version, and a published version never changes: a change makes a new
version (`core-v1`) with its own entry.  `deint_env/suites/build.py` wrote the files.
"""

from __future__ import annotations

import functools
import hashlib
import json
from dataclasses import dataclass
from importlib import resources
from typing import Any, Iterator

from deint_env.errors import DeintError
from deint_env.scenario import ScenarioSpec

TAGS = ("jitter", "missing", "spurious", "agile", "scale", "blind", "paper", "pdw")
SPLITS = ("train", "validation", "test")
# The last seeds of every train range are held out of training for validation; the rule is the same
# for every suite, so it is not part of a suite's content (validation seeds never move a test score).
VALIDATION_SEEDS = 1000


@dataclass(frozen=True)
class SeedRange:
    start: int
    stop: int

    def __post_init__(self) -> None:
        if not (isinstance(self.start, int) and isinstance(self.stop, int) and 0 <= self.start < self.stop):
            raise DeintError(f"seed range [{self.start}, {self.stop}) is invalid: need 0 <= start < stop")

    def __iter__(self) -> Iterator[int]:
        return iter(range(self.start, self.stop))

    def __len__(self) -> int:
        return self.stop - self.start

    def overlaps(self, other: SeedRange) -> bool:
        return self.start < other.stop and other.start < self.stop


@dataclass(frozen=True)
class SuiteEntry:
    spec: ScenarioSpec
    tags: tuple[str, ...]
    settings: dict[str, Any]
    train: SeedRange
    test: SeedRange

    @property
    def name(self) -> str:
        return self.spec.name

    def seeds(self, split: str) -> range:
        """The episode seeds of `split`: "train" (the train range but its last `VALIDATION_SEEDS`),
        "validation" (those last seeds; half the range if it is short) or "test"."""
        if split not in SPLITS:
            raise DeintError(f"split={split!r} is invalid: one of {', '.join(SPLITS)}")
        if split == "test":
            return range(self.test.start, self.test.stop)
        cut = self.train.stop - min(VALIDATION_SEEDS, len(self.train) // 2)
        return range(self.train.start, cut) if split == "train" else range(cut, self.train.stop)


@dataclass(frozen=True)
class Suite:
    name: str
    version: int
    description: str
    entries: tuple[SuiteEntry, ...]

    def __iter__(self) -> Iterator[SuiteEntry]:
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def entry(self, scenario: str) -> SuiteEntry:
        for e in self.entries:
            if e.name == scenario:
                return e
        raise DeintError(f"scenario {scenario!r} is not in suite {self.name}; it has: "
                         + ", ".join(e.name for e in self.entries))

    def content(self) -> dict[str, Any]:
        """Everything that could move a score (the description excluded)."""
        return {"name": self.name, "version": self.version, "scenarios": [
            {"spec": e.spec.to_dict(), "tags": list(e.tags), "settings": e.settings,
             "train": [e.train.start, e.train.stop], "test": [e.test.start, e.test.stop]} for e in self.entries]}

    @property
    def content_hash(self) -> str:
        blob = json.dumps(self.content(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def to_json_dict(self) -> dict[str, Any]:
        return {"description": self.description, **self.content()}

    @classmethod
    def from_json_dict(cls, d: dict[str, Any]) -> Suite:
        try:
            entries = []
            for s in d["scenarios"]:
                tags = tuple(s.get("tags", ()))
                bad = [t for t in tags if t not in TAGS]
                if bad:
                    raise DeintError(f"tag {bad[0]!r} is unknown; allowed: {', '.join(TAGS)}")
                train, test = SeedRange(*s["train"]), SeedRange(*s["test"])
                if train.overlaps(test):
                    raise DeintError(f"{s['spec'].get('name')}: train seeds {list(s['train'])} overlap test "
                                     f"seeds {list(s['test'])}")
                entries.append(SuiteEntry(ScenarioSpec.from_dict(s["spec"]), tags, dict(s.get("settings", {})),
                                          train, test))
            suite = cls(name=d["name"], version=int(d["version"]), description=d.get("description", ""),
                        entries=tuple(entries))
        except KeyError as e:
            raise DeintError(f"suite file is missing key {e.args[0]!r}") from None
        names = [e.name for e in entries]
        if len(set(names)) != len(names):
            dup = next(n for n in names if names.count(n) > 1)
            raise DeintError(f"suite {suite.name}: scenario name {dup!r} appears twice")
        return suite


def _suite_dir():
    return resources.files("deint_env") / "suites"


@functools.cache
def list_suites() -> tuple[str, ...]:
    return tuple(sorted(p.name[:-5] for p in _suite_dir().iterdir()
                        if p.name.endswith(".json") and p.name != "HISTORY.json"))


@functools.cache
def load_suite(name: str) -> Suite:
    if name not in list_suites():
        raise DeintError(f"suite {name!r} is unknown; known suites: {', '.join(list_suites())}")
    suite = Suite.from_json_dict(json.loads((_suite_dir() / f"{name}.json").read_text()))
    if suite.name != name:
        raise DeintError(f"suite file {name}.json names itself {suite.name!r}")
    return suite


@functools.cache
def history() -> dict[str, list[dict[str, Any]]]:
    return json.loads((_suite_dir() / "HISTORY.json").read_text())


def find_entry(name: str) -> SuiteEntry:
    """A scenario by 'suite/scenario', or by bare scenario name when the suites that have it agree on
    it (a new suite version repeats the scenarios it keeps): then the first such suite's entry."""
    if "/" in name:
        suite, scenario = name.split("/", 1)
        return load_suite(suite).entry(scenario)
    hits = [(s, e) for s in list_suites() for e in load_suite(s) if e.name == name]
    if not hits:
        raise DeintError(f"scenario {name!r} is unknown; name one as SUITE/SCENARIO (see `deint suites`)")
    if len({e.spec.content_hash for _, e in hits}) > 1:
        raise DeintError(f"scenario {name!r} is in several suites ({', '.join(s for s, _ in hits)}) and differs "
                         "between them; name it as SUITE/SCENARIO")
    return hits[0][1]


def resolve_scenario(scenario: ScenarioSpec | str | dict[str, Any]) -> ScenarioSpec:
    """A ScenarioSpec from a spec, a spec dict, or a (suite-qualified) scenario name."""
    if isinstance(scenario, ScenarioSpec):
        return scenario
    if isinstance(scenario, dict):
        return ScenarioSpec.from_dict(scenario)
    if isinstance(scenario, str):
        return find_entry(scenario).spec
    raise DeintError(f"scenario={scenario!r} is invalid: a ScenarioSpec, a dict or a scenario name")

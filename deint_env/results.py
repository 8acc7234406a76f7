"""Episode records and the JSON-lines results files that hold them.

A results file has one `EpisodeRecord` per line (flat JSON, keys sorted).  It is written by one
process at a time: `results_lock` takes an exclusive `fcntl.flock` on a sidecar `.<name>.lock`
(the results file itself is replaced by leaderboard rebuilds, so it cannot carry the lock), and a
second writer is refused at once with one line.  The lock is re-entrant within a process (a
leaderboard build holds it across its run and its publishing; the runner takes it again inside).

Reading (`read_records`) validates every line -- JSON that is not a record (`{}`, `5`, `null`) is one
`DeintError` line naming the file and line -- and drops duplicate keys: the first record of a key
wins, except that a fault record gives way to a later record of the same key that played (a rerun
retries faults).  Appending (`ResultsWriter`) first repairs the file's end: a last record without
its newline gets one, and a torn last line (a run killed mid-write) is cut off.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from deint_env.errors import DeintError
from deint_env.formats.files import check_output, read_bytes, short_name
from deint_env.suites import SPLITS

_write = os.write  # the one place bytes reach a results file (tests simulate a full disk here)


# ---------------------------------------------------------------------------------------------------
# the record
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RecordKey:
    """What identifies an episode's result: the policy as it behaves (canonical spec and the registry's
    behaviour version), the scenario (name and content hash) and the seed."""

    policy: str
    scenario: str
    scenario_hash: str
    seed: int
    policy_version: int | str = 1


# Fields every record has, with their JSON types; everything else is a metric (`EpisodeRecord.metrics`).
_IDENTITY: dict[str, tuple[type, ...]] = {
    "policy": (str,), "scenario": (str,), "scenario_hash": (str,), "seed": (int,), "split": (str,),
    "suite": (str, type(None)), "suite_hash": (str, type(None)), "tags": (list,), "settings": (dict,),
    "oracle": (bool,), "lag": (int, type(None)), "n_sources": (int,), "version": (str,), "applicable": (bool,),
}
_OPTIONAL: dict[str, tuple[type, ...]] = {
    "policy_version": (int, str), "submitted": (bool,), "reason": (str,), "fault": (str,),
}
# The ranges of the integer fields and of the metrics that have one (a fraction, a correlation, a count or
# a size): a record outside them was not written by a run, and would be averaged into a summary as it is.
_FRACTION, _CORRELATION, _SIZE = (0.0, 1.0, "in [0, 1]"), (-1.0, 1.0, "in [-1, 1]"), (0.0, math.inf, ">= 0")
_RANGES: dict[str, tuple[float, float, str]] = {
    "seed": (0, 2**63 - 1, "in [0, 2^63)"), **dict.fromkeys(("lag", "n_sources", "n_pulses"), _SIZE),
    **dict.fromkeys(("accuracy", "matched_accuracy", "link_accuracy", "genie_accuracy", "random_accuracy", "pe",
                     "mean_pe", "spurious_precision", "spurious_recall", "cluster_f1", "v_measure", "homogeneity",
                     "completeness"), _FRACTION),
    **dict.fromkeys(("ami", "ari", "cluster_mcc"), _CORRELATION),
    **dict.fromkeys(("us_per_pulse", "period_crlb_ratio", "period_rel_error", "phase_error"), _SIZE),
}


@dataclass(frozen=True)
class EpisodeRecord:
    """One played (or refused, or faulted) episode.  `metrics` holds the per-episode metrics, the genie
    and random accuracies, the normalised `score` and `us_per_pulse` (None where not finite).

    `applicable=False` with a `reason`: the policy cannot play the scenario (not retried).  `fault`: the
    policy failed on the episode (its error, one line); the episode is not scored and a rerun retries it.
    Records written before `policy_version` existed read as version 1.
    """

    policy: str
    scenario: str
    scenario_hash: str
    seed: int
    split: str
    suite: str | None
    suite_hash: str | None
    tags: tuple[str, ...]
    settings: Mapping[str, Any]
    oracle: bool
    lag: int | None
    n_sources: int
    version: str  # the package version that played it
    applicable: bool = True
    policy_version: int | str = 1  # the registry's version, or a learned agent's checkpoint hash
    submitted: bool = False
    reason: str | None = None
    fault: str | None = None
    metrics: Mapping[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> RecordKey:
        return RecordKey(self.policy, self.scenario, self.scenario_hash, self.seed, self.policy_version)

    @property
    def played(self) -> bool:
        """Scored: applicable and not faulted."""
        return self.applicable and self.fault is None

    def get(self, name: str) -> Any:
        """A field's or a metric's value (None if the record has neither)."""
        return getattr(self, name) if name in _FIELDS else self.metrics.get(name)

    def to_json(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "metrics"}
        out["tags"] = list(self.tags)
        for name in ("submitted", "reason", "fault"):  # written only where they say something
            if not out[name]:
                del out[name]
        return json_ready({**self.metrics, **out})

    def line(self) -> str:
        return json.dumps(self.to_json(), sort_keys=True) + "\n"

    @classmethod
    def from_json(cls, data: Any, where: str = "record") -> EpisodeRecord:
        """Validate and build; a bad record is one `DeintError` line starting with `where`."""
        if not isinstance(data, dict):
            raise DeintError(f"{where}: is not a results record (a JSON object), but {json.dumps(data)[:40]}")
        missing = [k for k in _IDENTITY if k not in data]
        if missing:
            raise DeintError(f"{where}: is not a results record: it has no {', '.join(missing)}")
        for k, types in {**_IDENTITY, **_OPTIONAL}.items():
            if k in data and (not isinstance(data[k], types) or (bool not in types and isinstance(data[k], bool))):
                raise DeintError(f"{where}: field {k!r} is {json.dumps(data[k])[:40]}, not a {types[0].__name__}")
        if not all(isinstance(t, str) for t in data["tags"]):
            raise DeintError(f"{where}: field 'tags' is {json.dumps(data['tags'])[:40]}, not a list of strings")
        known = {**{k: data[k] for k in _IDENTITY}, **{k: data[k] for k in _OPTIONAL if k in data}}
        known["tags"] = tuple(known["tags"])
        metrics = {k: v for k, v in data.items() if k not in known}
        for k, v in metrics.items():  # only pe is a list (one per source): a list accuracy reached a sum (TypeError)
            if k == "pe" and isinstance(v, list):
                if len(v) != data["n_sources"] or not all(_metric_value(x) for x in v):
                    raise DeintError(f"{where}: metric 'pe' is {json.dumps(v)[:40]}, not a list of "
                                     f"{data['n_sources']} numbers or nulls (one per source)")
            elif not _metric_value(v):
                raise DeintError(f"{where}: metric {k!r} is {json.dumps(v)[:40]}, not a number or null")
        if data["split"] not in SPLITS:
            raise DeintError(f"{where}: field 'split' is {json.dumps(data['split'])[:40]}, not one of "
                             f"{', '.join(SPLITS)}")
        for k, (lo, hi, allowed) in _RANGES.items():
            values = data.get(k) if isinstance(data.get(k), list) else [data.get(k)]
            if any(x is not None and not lo - 1e-9 <= x <= hi + 1e-9 for x in values):
                raise DeintError(f"{where}: field {k!r} is {json.dumps(data[k])[:40]}; a run writes values {allowed}")
        return cls(**known, metrics=metrics)


def _metric_value(x: Any) -> bool:
    """A metric as records hold it: a finite number (not a boolean) or null (undefined or not finite)."""
    return x is None or (isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x))


_FIELDS = frozenset(f.name for f in fields(EpisodeRecord)) - {"metrics"}


def json_ready(x: Any) -> Any:
    """Plain JSON types; NaN and infinities become null (strict JSON has neither)."""
    if isinstance(x, dict):
        return {k: json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_ready(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


# ---------------------------------------------------------------------------------------------------
# locking
# ---------------------------------------------------------------------------------------------------
_held: dict[str, list[Any]] = {}  # lock path -> [fd, depth] of the locks this process holds


def lock_path(path: str | os.PathLike) -> Path:
    path = Path(path)
    name = short_name(path.name)  # a long name is cut, and told apart from others cut alike by its hash
    tag = "" if name == path.name else "." + hashlib.sha256(os.fsencode(path.name)).hexdigest()[:16]
    return path.with_name(f".{name}{tag}.lock")


@contextlib.contextmanager
def results_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold the exclusive writer lock of the results file `path`, or raise one `DeintError` line if
    another process holds it.  Re-entrant within a process; the sidecar is removed on release."""
    lock = lock_path(path)
    name = str(lock.resolve())
    if name in _held:
        _held[name][1] += 1
        try:
            yield
        finally:
            _held[name][1] -= 1
        return
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise DeintError(f"{path}: cannot create its lock file {lock.name} ({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise DeintError(f"{path}: another process is writing this results file (it holds {lock.name}); "
                             f"wait for it to finish or write elsewhere") from None
        # The holder before us may have removed the sidecar between our open and our lock: then we
        # hold a lock on a file nobody else can see, so start over on the current one.
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    _held[name] = [fd, 1]
    try:
        yield
    finally:
        del _held[name]
        with contextlib.suppress(FileNotFoundError):
            os.unlink(lock)
        os.close(fd)


# ---------------------------------------------------------------------------------------------------
# reading and appending
# ---------------------------------------------------------------------------------------------------
def _repair_end(path: Path) -> None:
    """Make the file end with a newline after its last whole record: a last record without its newline
    gets one; a torn last line (not JSON) is cut off.  Call with the lock held."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return
    if not data or data.endswith(b"\n"):
        return
    start = data.rfind(b"\n") + 1
    try:
        json.loads(data[start:])
        whole = True
    except (ValueError, RecursionError):  # a deeply nested torn line is no record either
        whole = False
    # A torn record is the start of one line as `EpisodeRecord.line` writes it: printable ASCII (JSON
    # escapes the rest) that does not already hold a whole object.  Anything else (records separated by
    # CRs alone, say) is not ours to cut off.
    tail = data[start:]
    if not whole and (not tail.startswith(b"{") or not all(32 <= b < 127 for b in tail) or _leading_object(tail)):
        raise DeintError(f"{path}: is not a results file (its last line is not a record); write elsewhere")
    try:
        if whole:
            with open(path, "ab") as f:
                f.write(b"\n")
        else:
            os.truncate(path, start)
    except OSError as e:
        raise DeintError(f"{path}: cannot repair its last line ({e.strerror or e})") from None


def _leading_object(tail: bytes) -> bool:
    try:
        json.JSONDecoder().raw_decode(tail.decode("ascii"))
        return True
    except (ValueError, RecursionError):
        return False


def read_records(path: str | os.PathLike) -> list[EpisodeRecord]:
    """The records of a results file, validated, without duplicate keys (see the module docstring:
    first wins, a fault gives way to a later played record).  Reading takes no lock: an unterminated
    last line that is not JSON (being written, or torn) is skipped; the next writer repairs it."""
    path = Path(path)
    if not path.exists():
        return []
    try:
        text = read_bytes(path, "results").decode("utf-8")
    except UnicodeDecodeError as e:
        raise DeintError(f"{path}: cannot read ({e})") from None
    return parse_records(text, str(path))


def parse_records(text: str, name: str) -> list[EpisodeRecord]:
    out: dict[RecordKey, EpisodeRecord] = {}
    lines = text.split("\n")
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
        except (ValueError, RecursionError):
            if n == len(lines) and line.startswith("{"):  # the unterminated last line: a record being written
                break
            raise DeintError(f"{name}: line {n} is not a JSON record; fix or remove it") from None
        rec = EpisodeRecord.from_json(data, f"{name}: line {n}")
        old = out.get(rec.key)
        if old is None or (old.fault is not None and rec.fault is None):
            out[rec.key] = rec
    return list(out.values())


class ResultsWriter:
    """Appends records to a results file, one `os.write` per line (never a torn record but for a
    kill mid-write, which `read_records` repairs).  Use inside `results_lock(path)`."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        check_output(self.path)  # appending through a link or to a device would write what is not ours
        _repair_end(self.path)
        try:
            self.fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        except OSError as e:
            raise DeintError(f"{self.path}: cannot open for writing ({e.strerror or e})") from None

    def append(self, rec: EpisodeRecord) -> None:
        data = rec.line().encode("utf-8")
        try:
            while data:
                data = data[_write(self.fd, data):]
        except OSError as e:
            raise DeintError(f"{self.path}: cannot write ({e.strerror or e})") from None

    def close(self) -> None:
        os.close(self.fd)

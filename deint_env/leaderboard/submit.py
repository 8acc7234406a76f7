"""Submissions: labels made outside deint-bench, scored exactly like the reference policies.

A submission is one file per suite holding the labels of every test episode.  JSON lines (UTF-8),
one object per line::

    {"format": "deint-submission", "version": 1, "suite": "core-v0", "name": "my-method"}
    {"scenario": "core-n2-spread1.5-jitter0.05", "seed": 1000000, "labels": [0, 1, 1, -1, 0]}
    {"scenario": "core-n2-spread1.5-jitter0.05", "seed": 1000001, "labels": [1, 0, 0, 1, 0]}

The first line, the header, is optional (its `suite` must match, its `name` is the default entry
name).  Then one line per test episode -- every test seed of every scenario of the suite
(`deint suites SUITE` lists the scenarios; each one's test seeds are the range "test": [start, stop)
of `deint_env/suites/<suite>.json`), each exactly once, in any order.  `labels` holds one
integer per pulse of the episode that `deint_env.simulate(spec, seed)` makes (equivalently
`deint simulate SUITE/SCENARIO --seed S`), in TOA order: -1 = spurious, 0..n_labels-1 = a track.  In
anchored scenarios track i is prior source i; in blind ones (a label budget L) the naming is free and
links are scored.  The same convention as `deint label`'s label files.

NPZ variant (`.npz` from `numpy.savez`/`savez_compressed`, read with `allow_pickle=False`): one 1-D
integer array per episode named "<scenario>/<seed>", and optionally 0-d arrays `format`, `version`,
`suite` and `name` as the header.

Validation executes nothing from the file.  A file is refused, with one line naming the episode and
the problem, when it is not valid JSON / NPZ, an episode is missing, repeated or not a test episode
of the suite, a label count differs from the episode's pulse count, or a label is not an integer in
[-1, n_labels-1] (NaN included).  An accepted file is scored with the runner's metrics and the same
per-episode genie and random references, and appears in the suite's tables as "NAME (submitted)".
`export` writes a policy's own labels in this format: an example, and a check that a submission
scores exactly as the policy run directly.
"""

from __future__ import annotations

import io
import json
import os
import re
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deint_env.errors import DeintError, NotApplicable
from deint_env.formats import from_file_labels, read_bytes, to_file_labels
from deint_env.formats.files import write_bytes, write_text
from deint_env.formats.json_files import check_depth
from deint_env.formats.npz import read_npz
from deint_env.leaderboard.build import BOARD, DEFAULT_ROOT, RESULTS, SUFFIX, Scope, write
from deint_env.progress import progress_bar
from deint_env.results import EpisodeRecord, json_ready, read_records, results_lock
from deint_env.runner import check_workers, reference_accuracies
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.suites import load_suite

FORMAT = "deint-submission"
VERSION = 1
HEADER_KEYS = ("format", "version", "suite", "name")
EPISODE_KEYS = ("scenario", "seed", "labels")
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9 ._+:=,-]{0,63}")


class _NonFinite:
    """What NaN / Infinity (not JSON, but Python writes them) parse to, so a check can name them."""

    def __init__(self, text: str):
        self.text = text


@dataclass
class Item:
    where: str  # "line 7" or "array 'scenario/seed'"
    scenario: Any
    seed: Any
    labels: Any


# ---------------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------------
def read_submission(path: str | os.PathLike) -> tuple[dict[str, Any], list[Item]]:
    """(header, items) of a submission file, NPZ when it is a zip archive, else JSON lines."""
    path = Path(path)
    raw = read_bytes(path, "submission")
    return _read_npz(path, raw) if raw[:4] == b"PK\x03\x04" else _read_jsonl(path, raw)


def _guess_episode(line: str) -> str:
    """' (scenario X, seed S)' read off a line that is not JSON, when it shows them."""
    scenario = re.search(r'"scenario"\s*:\s*"([^"]*)"', line)
    seed = re.search(r'"seed"\s*:\s*(-?\d+)', line)
    if not scenario:
        return ""
    return f" (scenario {scenario.group(1)}" + (f", seed {seed.group(1)})" if seed else ")")


def _read_jsonl(path: Path, raw: bytes) -> tuple[dict[str, Any], list[Item]]:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DeintError(f"{path}: is neither UTF-8 JSON lines nor an NPZ archive") from None
    lines = text.split("\n")
    header: dict[str, Any] = {}
    items = []
    first = True
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        check_depth(line, f"{path}: line {n}")
        try:
            obj = json.loads(line, parse_constant=_NonFinite)
        except json.JSONDecodeError as e:
            torn = " (the file looks truncated)" if n == len(lines) else ""
            raise DeintError(f"{path}: line {n}{_guess_episode(line)}: is not valid JSON ({e.msg} at column "
                             f"{e.colno}){torn}") from None
        except ValueError as e:  # an integer past Python's digit limit
            raise DeintError(f"{path}: line {n}{_guess_episode(line)}: {e}") from None
        if not isinstance(obj, dict):
            raise DeintError(f"{path}: line {n}: is not a JSON object; each line is "
                             '{"scenario": NAME, "seed": S, "labels": [...]}')
        if "format" in obj:
            if not first:
                raise DeintError(f"{path}: line {n}: a header line (with 'format') may only be the first line")
            header = _check_header(path, f"line {n}", obj)
        else:
            items.append(Item(f"line {n}", obj.get("scenario"), obj.get("seed"), obj))
        first = False
    return header, items


def _check_header(path: Path, where: str, obj: dict[str, Any]) -> dict[str, Any]:
    bad = [k for k in obj if k not in HEADER_KEYS]
    if bad:
        raise DeintError(f"{path}: {where}: unknown header key {bad[0]!r}; a header has {', '.join(HEADER_KEYS)}")
    if obj.get("format") != FORMAT:
        raise DeintError(f"{path}: {where}: format={obj.get('format')!r} is invalid: {FORMAT!r}")
    version = obj.get("version", VERSION)
    if isinstance(version, (bool, np.bool_)) or version != VERSION:  # true == 1 in Python, not in the format
        raise DeintError(f"{path}: {where}: version={obj['version']!r} is not supported: {VERSION}")
    for key in ("suite", "name"):
        if key in obj and not isinstance(obj[key], str):
            raise DeintError(f"{path}: {where}: {key}={obj[key]!r} is invalid: a string")
    return obj


def _read_npz(path: Path, raw: bytes) -> tuple[dict[str, Any], list[Item]]:
    header: dict[str, Any] = {}
    items = []
    for key, arr in read_npz(raw, str(path)).items():
        where = f"array {key!r}"
        m = re.fullmatch(r"(.+)/(\d+)", key)
        if key in HEADER_KEYS:
            if isinstance(arr, str) or arr.ndim != 0 or arr.dtype.kind not in "iuU":
                raise DeintError(f"{path}: {where}: a header field is a 0-d string or integer array")
            header[key] = arr.item()
        elif m is None:
            raise DeintError(f"{path}: {where}: is neither a header field ({', '.join(HEADER_KEYS)}) "
                             f"nor an episode named <scenario>/<seed>")
        else:
            items.append(Item(where, m.group(1), int(m.group(2)), arr))
    return (_check_header(path, "header arrays", header) if header else header), items


# ---------------------------------------------------------------------------------------------------
# checking and scoring
# ---------------------------------------------------------------------------------------------------
def _keys_problem(item: Item) -> str | None:
    if not isinstance(item.labels, dict):  # NPZ: the array name gave scenario and seed
        return None
    missing = [k for k in EPISODE_KEYS if k not in item.labels]
    if missing:
        return f"has no {missing[0]!r}; an episode line has {', '.join(EPISODE_KEYS)}"
    extra = [k for k in item.labels if k not in EPISODE_KEYS]
    if extra:
        return f"unknown key {extra[0]!r}; an episode line has {', '.join(EPISODE_KEYS)}"
    return None


def _labels(item: Item, hi: int) -> np.ndarray | str:
    """The item's labels as int64, or what is wrong with them (each must be an integer in [-1, hi])."""
    rule = f"labels are integers in [-1, {hi}] (-1 = spurious, 0..{hi} = tracks)"
    if isinstance(item.labels, dict):
        labels = item.labels["labels"]
        if not isinstance(labels, list):
            return f"labels is not a list; {rule}"
        for i, v in enumerate(labels):
            if type(v) is not int:
                what = f"is {v.text}" if isinstance(v, _NonFinite) else f"= {json.dumps(v)} is not an integer"
                return f"label at pulse {i} {what}; {rule}"
            if not -1 <= v <= hi:
                return f"label {v} at pulse {i} is out of range; {rule}"
        return np.asarray(labels, dtype=np.int64)
    arr = item.labels
    if isinstance(arr, str):
        return arr
    if arr.ndim != 1:
        return f"the labels array has shape {arr.shape}; it must be 1-D, one label per pulse"
    if arr.dtype.kind == "f" and np.isnan(arr).any():
        return f"label at pulse {int(np.flatnonzero(np.isnan(arr))[0])} is NaN; {rule}"
    if arr.dtype.kind not in "iu":
        return f"the labels array has dtype {arr.dtype}, not an integer type; {rule}"
    bad = np.flatnonzero((arr > hi) | (arr < -1)) if arr.dtype.kind == "i" else np.flatnonzero(arr > hi)
    if bad.size:
        return f"label {arr[bad[0]]} at pulse {int(bad[0])} is out of range; {rule}"
    return arr.astype(np.int64)


def _check_name(name: str | None) -> str:
    if name is None:
        raise DeintError("name the entry: --name NAME (or a 'name' in the file's header)")
    if not NAME.fullmatch(name):
        raise DeintError(f"name={name!r} is invalid: 1-64 characters, letters, digits, space and ._+:=,- "
                         f"(starting with a letter or digit)")
    return name


def episode_record(scope: Scope, entry: Any, seed: int, episode: Any, file_labels: np.ndarray,
                   policy: str) -> EpisodeRecord:
    """A results record for labels made elsewhere: the fields and metrics of `runner.run_job`."""
    from deint_env import __version__
    from deint_env.metrics import label_metrics, normalised_score

    suite = load_suite(scope.suite)
    labels = from_file_labels(file_labels, episode.n_labels)
    metrics = label_metrics(labels, episode.source, episode.mask, episode.n_labels, episode.blind, clustering=True)
    genie_acc, random_acc = reference_accuracies(episode)
    rec = {"suite": suite.name, "suite_hash": suite.content_hash, "scenario": entry.name,
           "scenario_hash": entry.spec.content_hash, "tags": list(entry.tags), "settings": entry.settings,
           "split": "test", "seed": seed, "policy": policy, "oracle": False, "submitted": True, "lag": None,
           "n_sources": episode.truth.n_sources, "version": __version__, "applicable": True, **metrics,
           "genie_accuracy": genie_acc, "random_accuracy": random_acc,
           "score": normalised_score(metrics["accuracy"], random_acc, genie_acc), "us_per_pulse": None}
    return EpisodeRecord.from_json(json_ready(rec))


def score_submission(path: str | os.PathLike, scope: Scope, name: str | None = None,
                     progress: bool = True) -> tuple[str, list[EpisodeRecord]]:
    """Validate a submission against the scope's test episodes and score it: (entry name, records).
    The first problem found is one `DeintError` line naming the file, the place and the episode."""
    path = Path(path)
    header, items = read_submission(path)
    if header.get("suite") not in (None, scope.suite):
        raise DeintError(f"{path}: the header names suite {header['suite']!r}, not {scope.suite!r}")
    name = _check_name(name if name is not None else header.get("name"))
    entries = {e.name: e for e in scope.entries()}
    first_at: dict[tuple[str, int], str] = {}
    records = []
    bar = progress_bar(len(items), desc=f"scoring {name}", enabled=progress)
    for item in items:
        episode_name = f"scenario {item.scenario}, seed {item.seed}"

        def fail(problem: str) -> DeintError:
            return DeintError(f"{path}: {item.where} ({episode_name}): {problem}")

        problem = _keys_problem(item)
        if problem:
            raise fail(problem)
        if not isinstance(item.scenario, str):
            raise fail("scenario is not a scenario name (a string)")
        if type(item.seed) is not int:
            raise fail("seed is not an integer")
        entry = entries.get(item.scenario)
        if entry is None:
            where = f"suite {scope.suite}" if scope.scenarios is None else "this leaderboard's scenarios"
            raise fail(f"an extra episode: the scenario is not in {where}")
        seeds = scope.seeds(entry)
        if item.seed not in seeds:
            raise fail(f"an extra episode: the scored test seeds of this scenario are {seeds[0]}..{seeds[-1]}")
        key = (item.scenario, item.seed)
        if key in first_at:
            raise fail(f"the episode appears twice (first at {first_at[key]})")
        first_at[key] = item.where
        labels = _labels(item, entry.spec.n_labels - 1)
        if isinstance(labels, str):
            raise fail(labels)
        episode = simulate(entry.spec, item.seed)
        if labels.size != len(episode):
            raise fail(f"{labels.size} labels for the episode's {len(episode)} pulses: one label per pulse, "
                       f"in TOA order")
        records.append(episode_record(scope, entry, item.seed, episode, labels, name + SUFFIX))
        bar.update()
    bar.close()
    missing = [(e.name, s) for e, s in scope.episodes() if (e.name, s) not in first_at]
    if missing:
        more = f" (and {len(missing) - 1} more missing episodes)" if len(missing) > 1 else ""
        raise DeintError(f"{path}: scenario {missing[0][0]}, seed {missing[0][1]}: the episode is missing{more}; "
                         f"a submission labels every test episode")
    return name, records


def submit(path: str | os.PathLike, suite: str, name: str | None = None, *, root: str | os.PathLike = DEFAULT_ROOT,
           reps: int = 2000, progress: bool = True) -> tuple[str, dict[str, Any]]:
    """Score a submission into the suite's leaderboard folder (replacing an earlier one of the same
    name) and rewrite its files.  A refused file changes nothing.  Returns (entry name, leaderboard)."""
    folder = Path(root) / suite
    scope = Scope.of_folder(folder, suite)
    name, new = score_submission(path, scope, name, progress=progress)
    policy = name + SUFFIX
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DeintError(f"{folder}: cannot create the leaderboard folder ({e.strerror or e})") from None
    with results_lock(folder / RESULTS):
        records = [r for r in read_records(folder / RESULTS) if r.policy != policy] + new
        return policy, write(folder, scope, records, reps=reps)


# ---------------------------------------------------------------------------------------------------
# export
# ---------------------------------------------------------------------------------------------------
def _labels_of(job: tuple[dict[str, Any], int, str]) -> list[int]:
    """A policy's labels of one episode, as the runner plays it (file convention)."""
    from deint_env.policies import is_oracle, make_policy
    from deint_env.runner import play

    spec_dict, seed, policy = job
    spec = ScenarioSpec.from_dict(spec_dict)
    episode = simulate(spec, seed)
    try:
        result = play(make_policy(policy), episode, policy_seed=seed, oracle=is_oracle(policy), clustering=False)
    except NotApplicable as e:
        raise DeintError(f"policy {policy} cannot play scenario {spec.name} (seed {seed}): {e}; a submission "
                         f"needs labels for every test episode") from None
    return to_file_labels(result.labels, episode.n_labels).tolist()


def export(scope: Scope, policy: str, path: str | os.PathLike, *, workers: int = 1, progress: bool = True) -> int:
    """Write `policy`'s labels of the scope's test episodes as a submission (NPZ if `path` ends in
    .npz, else JSON lines); returns the number of episodes."""
    from deint_env.policies import canonical_spec, make_policy, parse_policy_spec

    check_workers(workers)  # 10^20 reached the process pool (OverflowError), 0 played in this process
    path = Path(path)
    if not path.resolve().parent.is_dir():
        raise DeintError(f"{path}: cannot write: directory {path.parent} does not exist")
    if (path.resolve().parent / BOARD).exists():
        raise DeintError(f"{path}: lies in a leaderboard folder, whose files `deint leaderboard` writes; write the "
                         f"labels elsewhere")
    make_policy(policy)  # one line for an unknown policy or parameter
    spec = canonical_spec(*parse_policy_spec(policy))
    episodes = scope.episodes()
    jobs = [(e.spec.to_dict(), s, spec) for e, s in episodes]
    bar = progress_bar(len(jobs), desc=f"export {spec}", enabled=progress)
    labels = []
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for lab in pool.map(_labels_of, jobs, chunksize=4):
                labels.append(lab)
                bar.update()
    else:
        for job in jobs:
            labels.append(_labels_of(job))
            bar.update()
    bar.close()
    header = {"format": FORMAT, "version": VERSION, "suite": scope.suite, "name": spec}
    if path.suffix == ".npz":
        arrays = {f"{e.name}/{s}": np.asarray(lab, dtype=np.int64) for (e, s), lab in zip(episodes, labels)}
        arrays.update({k: np.asarray(v) for k, v in header.items()})
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        write_bytes(path, buf.getvalue())
    else:
        lines = [json.dumps(header)] + [
            json.dumps({"scenario": e.name, "seed": s, "labels": lab}, separators=(",", ":"))
            for (e, s), lab in zip(episodes, labels)]
        write_text(path, "\n".join(lines) + "\n")
    return len(jobs)

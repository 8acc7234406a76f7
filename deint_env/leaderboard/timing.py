"""A board's speed columns, from one timing run on one machine.

Scores are replayed across many runs and processes (resumable, parallel); their wall-clock times are
not comparable.  So a board's µs/pulse come from one separate run, `deint leaderboard --time`: in one
process, one policy after another, each warmed up on one untimed episode (numba compiles, caches
fill), then timed on the first test seed of every scenario of the scope (the policy's own time: reset
and every act, as `runner.play` measures it; scenarios longer than `MAX_PULSES` are timed on that many
pulses).  A policy that plays episodes in lock-step (`deint_env.policies.BatchPolicy`, as the runner
plays it: `runner.batch_size`) is timed so too, on its episodes in near-equal batches of at most
`runner.BATCH`, each episode's time being its batch's time per pulse; its row records the batch size
(`batch`, 1 for one episode at a time) and the board says so; its warm-up is one untimed lock-step
play of all the episodes.  The row shows the median µs/pulse over those episodes and its ratio to
`fdp`'s median on the same reference episodes (core-v0's, so blind boards have one too), measured in
that run.  On core-v0's own board fdp's row is that reference: timed once more at the run's start it
measured 31.7 µs/pulse against its row's 21.5 later in the same process (a fresh process's first
minutes), and a ratio must not depend on which of two timings of one policy it divides by.  `timings.json` records the machine and date beside the numbers.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import statistics
from pathlib import Path
from typing import Any, Iterable, NamedTuple

import numpy as np

from deint_env.errors import DeintError, NotApplicable, shown
from deint_env.formats.files import write_all

TIMINGS = "timings.json"
REFERENCE = "fdp"
REFERENCE_SUITE = "core-v0"


class Timing(NamedTuple):
    policy: str
    us_per_pulse: float | None  # median over the timed episodes (None: it plays none of them)
    episodes: int
    batch: int = 1  # episodes played in lock-step (a BatchPolicy's batch), 1: one at a time


MAX_PULSES = 20_000  # a timed episode's length at most: scale-v0's 10^6-pulse episodes take minutes to hours


def _episodes(suite: str, scenarios: tuple[str, ...] | None = None) -> list[Any]:
    from deint_env.simulate import simulate
    from deint_env.suites import load_suite

    return [simulate(e.spec.replace(n_pulses=min(e.spec.n_pulses, MAX_PULSES)), e.test.start)
            for e in load_suite(suite) if scenarios is None or e.name in scenarios]


def time_policy(spec: str, episodes: list[Any]) -> Timing:
    """Median µs/pulse of `spec` over `episodes`, after one untimed episode it can play; a BatchPolicy's
    episodes in lock-step (module doc)."""
    from deint_env.policies import is_oracle, make_policy
    from deint_env.runner import batch_size, play

    if batch_size(spec) > 1:
        return _time_batched(spec, episodes)
    oracle, warm, us = is_oracle(spec), False, []
    for episode in episodes:
        try:
            if not warm:
                play(make_policy(spec), episode, oracle=oracle, scored=False)
                warm = True
            res = play(make_policy(spec), episode, oracle=oracle, scored=False)
        except NotApplicable:
            continue
        us.append(1e6 * res.seconds / max(len(episode), 1))
    return Timing(spec, statistics.median(us) if us else None, len(us))


def _time_batched(spec: str, episodes: list[Any]) -> Timing:
    """A BatchPolicy's timing: its warm-up is one untimed lock-step play of all `episodes`, which also tells
    those it plays; those are then timed in near-equal batches of at most BATCH."""
    from deint_env.policies import make_policy
    from deint_env.runner import BATCH, play_batch

    warm = play_batch(make_policy(spec), episodes, scored=False)
    mine = [e for e, r in zip(episodes, warm) if not isinstance(r, NotApplicable)]
    if not mine:
        return Timing(spec, None, 0)
    size = -(-len(mine) // -(-len(mine) // BATCH))
    batches = [mine[i:i + size] for i in range(0, len(mine), size)]
    us = [1e6 * r.seconds / max(len(e), 1)
          for b in batches for r, e in zip(play_batch(make_policy(spec), b, scored=False), b)]
    return Timing(spec, statistics.median(us), len(us), max(len(b) for b in batches))


def run(folder: Path, suite: str, specs: Iterable[str], scenarios: tuple[str, ...] | None = None,
        progress: bool = True) -> dict[str, Any]:
    """Time every spec on the scope's episodes and fdp on the reference episodes; write timings.json."""
    from deint_env.policies import spec_version
    from deint_env.progress import progress_bar

    specs = list(dict.fromkeys(specs))
    episodes = _episodes(suite, scenarios)
    own_row = suite == REFERENCE_SUITE and scenarios is None and REFERENCE in specs
    bar = progress_bar(len(specs) + (not own_row), f"timing {suite}", progress)
    reference = None
    if not own_row:
        reference = time_policy(REFERENCE, _episodes(REFERENCE_SUITE))
        bar.update(1)
    timings = {}
    for spec in specs:
        timings[spec] = time_policy(spec, episodes)
        bar.update(1)
    bar.close()
    if own_row:
        reference = timings[REFERENCE]
    rows = {spec: {"us_per_pulse": t.us_per_pulse, "episodes": t.episodes, "batch": t.batch,
                   "vs_fdp": None if t.us_per_pulse is None else t.us_per_pulse / reference.us_per_pulse,
                   "version": spec_version(spec)}  # a row's speed is shown only for this version
            for spec, t in timings.items()}
    out = {"format": "deint-timings", "suite": suite, "date": datetime.date.today().isoformat(),
           "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                       "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
                       "python": platform.python_version(), "numpy": np.__version__,
                       "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None},
           "method": f"median over the first test seed of each scenario (at most {MAX_PULSES} pulses), after one "
                     "untimed episode; one process; a policy that plays episodes in lock-step (the runner batches "
                     "it) timed so, each episode at its batch's time per pulse",
           "reference": {"policy": REFERENCE, "suite": REFERENCE_SUITE, "us_per_pulse": reference.us_per_pulse,
                         "measured": "its own row" if own_row else "before the rows"},
           "policies": rows}
    write_all([(folder / TIMINGS, json.dumps(out, indent=1, sort_keys=True) + "\n")])
    return out


def read(folder: Path, suite: str | None = None) -> dict[str, Any] | None:
    """The timing run of the board in `folder` (None: none), its fields checked; `suite`: the board's."""
    path = folder / TIMINGS
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("format") != "deint-timings" or not isinstance(data.get("policies"), dict):
            raise ValueError
    except (OSError, UnicodeDecodeError, ValueError, AttributeError, RecursionError):
        raise DeintError(f"{path}: is not a timings file; remove it or rerun deint leaderboard --time") from None
    _check_fields(path, data)
    if suite is not None and data.get("suite") != suite:  # another board's times would be shown as this one's
        raise DeintError(f"{path}: field suite is {shown(data.get('suite'))}, not {suite!r} (its board's); "
                         "remove it or rerun deint leaderboard --time")
    return data


def _check_fields(path: Path, data: dict[str, Any]) -> None:
    """The fields the board and its page read, as `time_all` writes them (a string speed, a NaN or a null
    reference reached the page as a wrong number or a TypeError)."""
    def need(field: str, value: Any, ok: bool, want: str) -> None:
        if not ok:
            raise DeintError(f"{path}: field {field} is {shown(value)}, not {want}; remove it or rerun deint "
                             "leaderboard --time")

    def speed(field: str, value: Any) -> None:
        need(field, value, value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)
                                             and math.isfinite(value) and value >= 0), "null or a number >= 0")

    for key in ("date", "method"):
        need(key, data.get(key), isinstance(data.get(key), str), "a string")
    machine, reference = data.get("machine"), data.get("reference")
    need("machine", machine, isinstance(machine, dict), "an object")
    for key in ("processor", "python"):
        need(f"machine.{key}", machine.get(key), isinstance(machine.get(key), str), "a string")
    cpus = machine.get("cpus")
    need("machine.cpus", cpus, cpus is None or (type(cpus) is int and cpus >= 1), "null or an integer >= 1")
    need("reference", reference, isinstance(reference, dict), "an object")
    need("reference.suite", reference.get("suite"), isinstance(reference.get("suite"), str), "a string")
    speed("reference.us_per_pulse", reference.get("us_per_pulse"))
    for spec, row in data["policies"].items():
        need(f"policies[{spec!r}]", row, isinstance(row, dict), "an object")
        for key in ("us_per_pulse", "vs_fdp"):
            speed(f"policies[{spec!r}].{key}", row.get(key))
        batch = row.get("batch", 1)
        need(f"policies[{spec!r}].batch", batch, type(batch) is int and batch >= 1, "an integer >= 1")

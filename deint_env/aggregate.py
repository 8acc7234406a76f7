"""The one aggregation path: an entry's episode records -> its table row.

Both `deint run`'s summary (`runner.summarise`) and the leaderboard (`leaderboard.build.aggregate`)
call `aggregate_entry`; every metric of `deint_env.metrics.METRICS` is reduced as the table says, and
the normalised score gets its IQM and mean with stratified-bootstrap intervals (`deint_env.stats`,
strata = scenarios).  Scored episodes are the played ones (`EpisodeRecord.played`): episodes a
policy cannot play (not applicable) and episodes where it failed (faults) count in `episodes` and
lower `coverage`; faults are listed in the row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from deint_env import metrics, stats
from deint_env.errors import DeintError
from deint_env.metrics import SCORE
from deint_env.results import EpisodeRecord

Triple = tuple[float, float, float]


@dataclass(frozen=True)
class EntryAggregate:
    row: dict[str, Any]  # JSON-ready but for NaN: the table row
    strata: dict[str, list[float]]  # scenario -> scores, for the probability of improvement
    groups: dict[str, dict[str, Triple]]  # group -> {"iqm": ..., "mean": ...}
    profile: tuple[np.ndarray, ...] | None  # the performance profile with its band (with `taus`)


def entry_kind(rec: EpisodeRecord) -> str:
    """'submitted' for outside labels, else the registry's kind ('reference', 'learned', 'oracle',
    'adapter'), or 'unregistered' for a policy this installation does not have."""
    from deint_env.policies import parse_policy_spec, policy_info

    if rec.submitted:
        return "submitted"
    try:
        return policy_info(parse_policy_spec(rec.policy)[0]).kind
    except DeintError:
        return "unregistered"


def _finite(values: Iterable[Any]) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(v)]


def aggregate_entry(recs: Sequence[EpisodeRecord], groups: Mapping[str, Sequence[str]], *,
                    taus: np.ndarray | None = None, reps: int = 2000, seed: int = 0,
                    intervals: bool = True) -> EntryAggregate:
    """Aggregate one entry's records (in stratum order: the order sets the point estimates' float
    summation).  `groups` maps a group name to the scenarios it pools and must have "all"."""
    first = recs[0]
    played = [r for r in recs if r.played]
    strata: dict[str, list[float]] = {}
    for r in played:
        if r.get(SCORE) is not None:
            strata.setdefault(r.scenario, []).append(r.get(SCORE))
    est, profile = stats.estimates(strata, groups, taus, reps=reps, seed=seed, intervals=intervals)
    row: dict[str, Any] = {
        "policy": first.policy, "kind": entry_kind(first), "oracle": first.oracle, "submitted": first.submitted,
        "episodes": len(recs), "played": len(played), "scored": sum(map(len, strata.values())),
        "coverage": len(played) / len(recs),
        "faults": [{"scenario": r.scenario, "seed": r.seed, "error": r.fault} for r in recs if r.fault is not None],
    }
    for name in ("iqm", "mean"):
        row[f"{SCORE}_{name}"], row[f"{SCORE}_{name}_low"], row[f"{SCORE}_{name}_high"] = est["all"][name]
    for m in metrics.METRICS:
        row[m.key] = m.reduce(_finite(r.get(m.key) for r in played))
    return EntryAggregate(row, strata, est, profile)

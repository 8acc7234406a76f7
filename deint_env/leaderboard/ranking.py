"""How a board ranks its rows: within latency divisions, by score mean, with honest ties, and with
each learned entry's share of its score measured against its own ablation.

- **Divisions** (`deint_env.divisions`): a row belongs to the tightest division its lag fits; ranks
  restart in each division, so a policy that decides 1024 pulses late never outranks one that decides
  at once.
- **Ranks.** Rows are ordered by score mean.  A row shares the rank of the row above it when the
  probability of improvement between them (rliable, scenario-stratified bootstrap) has an interval
  that includes 0.5: the data cannot tell them apart, so they are shown as "1=", "1=".  With fewer
  than `MIN_SEEDS` seeds per scenario there are no intervals: ranks follow the means and the board
  says that they are untested.
- **Learned share.** A learned policy's ablation (the registry's `ablation` parameters: its learned
  output switched off) is played beside it; the share is the paired mean difference of their scores
  on the same episodes, with its stratified-bootstrap interval.  Only a share whose interval lies
  above 0 earns the marker "learned"; otherwise the row is marked "search" with the reason.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, NamedTuple

from deint_env import stats
from deint_env.divisions import DIVISIONS, division_of
from deint_env.errors import DeintError
from deint_env.metrics import SCORE
from deint_env.policies import ablation_spec
from deint_env.results import EpisodeRecord

MIN_SEEDS = stats.MIN_SEEDS  # fewer seeds per scenario than this: no intervals, ranks untested


class Comparison(NamedTuple):
    """The probability of improvement between two adjacent ranked rows of a division."""

    division: str
    x: str
    y: str
    p: float
    low: float
    high: float
    scenarios: int
    tied: bool


def rankable(row: dict[str, Any]) -> bool:
    score = row[f"{SCORE}_mean"]
    return (not row["oracle"] and row.get("ablation_of") is None and row["coverage"] >= 1
            and score is not None and math.isfinite(score))


def assign_divisions(rows: list[dict[str, Any]]) -> None:
    for r in rows:
        lag = r.get("lag")
        r["division"] = division_of(None if lag is None or lag != lag else int(lag))


def rank(rows: list[dict[str, Any]], strata_of: Mapping[str, Mapping[str, list[float]]], *, intervals: bool,
         reps: int, seed: int) -> list[Comparison]:
    """Order `rows` (division, then ranked by score mean, then the rest) and set each row's `rank` (an
    int or None) and `rank_label` ("2", "2=" for a tie, "" unranked).  Returns the comparisons between
    adjacent ranked rows (with `intervals`; none without)."""
    order = {d: i for i, d in enumerate(DIVISIONS)}

    def key(r):
        score = r[f"{SCORE}_mean"]
        scored = score is not None and math.isfinite(score)
        group = 0 if rankable(r) or (r["oracle"] and scored) else 1 if scored else 2
        return order[r["division"]], group, -score if scored else 0.0, r["policy"]

    rows.sort(key=key)
    comparisons: list[Comparison] = []
    for division in DIVISIONS:
        ranked = [r for r in rows if r["division"] == division and rankable(r)]
        for i, r in enumerate(ranked):
            r["rank"] = i + 1
            if i and intervals:
                prev = ranked[i - 1]
                p, lo, hi, n = stats.probability_of_improvement(strata_of[prev["policy"]], strata_of[r["policy"]],
                                                                reps=reps, seed=seed)
                tied = lo <= 0.5 <= hi
                comparisons.append(Comparison(division, prev["policy"], r["policy"], p, lo, hi, n, tied))
                if tied:
                    r["rank"] = prev["rank"]
        shared = {r["rank"] for i, r in enumerate(ranked) if i and r["rank"] == ranked[i - 1]["rank"]}
        for r in ranked:
            r["rank_label"] = f"{r['rank']}=" if r["rank"] in shared else str(r["rank"])
    for r in rows:
        if not rankable(r):
            r["rank"], r["rank_label"] = None, ""
    return comparisons


def learned_shares(rows: list[dict[str, Any]], records: Mapping[str, Mapping[tuple, EpisodeRecord]], *,
                   intervals: bool, reps: int, seed: int) -> None:
    """Mark every ablation row (`ablation_of`) and give every learned row its `ablation`, `learned_share`
    (with `_low`, `_high`) and `marker`: "learned" when the share's interval lies above 0, else
    "search" with `marker_reason`."""
    by_policy = {r["policy"]: r for r in rows}
    for r in rows:
        r.setdefault("ablation_of", None)
    for r in rows:
        if r["kind"] != "learned" or r["submitted"] or not r.get("played"):
            continue
        try:
            ablation = ablation_spec(r["policy"])
        except DeintError:
            ablation = None
        r["ablation"] = ablation
        r["learned_share"] = r["learned_share_low"] = r["learned_share_high"] = None
        if ablation == r["policy"]:  # an ablation row itself: measured, not marked
            r["marker"] = r["marker_reason"] = None
            continue
        if ablation is None:
            r["marker"], r["marker_reason"] = "learned", "no ablation declared"
            continue
        if ablation in by_policy:
            by_policy[ablation]["ablation_of"] = r["policy"]
        if ablation not in records or ablation not in by_policy:
            r["marker"], r["marker_reason"] = "unverified", f"its ablation {ablation} was not played"
            continue
        strata: dict[str, list[float]] = {}
        own, off = records[r["policy"]], records[ablation]
        for k, rec in own.items():
            a, b = rec.get(SCORE), off[k].get(SCORE) if k in off else None
            if a is not None and b is not None:
                strata.setdefault(rec.scenario, []).append(a - b)
        if not strata:
            r["marker"], r["marker_reason"] = "unverified", f"no episode scored by both it and {ablation}"
            continue
        est, _ = stats.estimates(strata, {"all": list(strata)}, None, reps=reps, seed=seed, intervals=intervals)
        share, lo, hi = est["all"]["mean"]
        r["learned_share"], r["learned_share_low"], r["learned_share_high"] = share, lo, hi
        if intervals and lo > 0:
            r["marker"], r["marker_reason"] = "learned", f"learned share {share:+.4f} [{lo:+.4f}, {hi:+.4f}] excludes 0"
        elif intervals:
            r["marker"] = "search"
            r["marker_reason"] = (f"learned share {share:+.4f} [{lo:+.4f}, {hi:+.4f}] "
                                  + ("is below 0: the network costs score" if hi < 0 else "includes 0"))
        else:
            r["marker"], r["marker_reason"] = "search", f"learned share {share:+.4f}, untested (too few seeds)"

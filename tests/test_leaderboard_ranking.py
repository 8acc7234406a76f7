"""Ranks a reviewer accepts (issue 23): divisions by lag, ranks by mean with ties the data cannot
separate, learned entries measured against their ablation, test looks counted, one timing run."""

from __future__ import annotations

import json
from typing import Any, NamedTuple

import numpy as np
import pytest

from deint_env.divisions import admits, division_of
from deint_env.errors import DeintError
from deint_env.leaderboard import history, ranking
from deint_env.leaderboard.build import add_looks_and_timings, board_entries
from deint_env.policies import ablation_spec, division_specs, make_policy

pytest.importorskip("rliable")


def row(policy: str, mean: float, lag: int = 0, kind: str = "reference", **kw: Any) -> dict[str, Any]:
    return {"policy": policy, "score_mean": mean, "lag": lag, "kind": kind, "oracle": kind == "oracle",
            "coverage": 1.0, "played": 10, "submitted": False, "policy_version": kw.pop("version", 1), **kw}


def strata(rng: np.random.Generator, centre: float, spread: float = 0.02, scenarios: int = 6, seeds: int = 10):
    return {f"s{k}": list(centre + spread * rng.standard_normal(seeds)) for k in range(scenarios)}


def test_divisions_follow_the_declared_lag():
    assert [division_of(lag) for lag in (0, 3, 4, 64, 65, 1024, None)] == \
        ["online", "online", "low-latency", "low-latency", "offline", "offline", "offline"]
    assert admits("offline", 0) and admits("low-latency", 3) and not admits("online", 16)
    with pytest.raises(DeintError, match="lag=-1 is invalid"):
        division_of(-1)
    for name in ("mht", "lmht", "renewal-ml", "cdif", "dagger-beam"):  # each variant's lag lies in its division
        for spec in division_specs(name):
            lag = make_policy(spec).lag
            assert division_of(lag) != division_of(make_policy(name).lag), spec


def test_ranks_restart_per_division_and_ties_share_a_rank():
    rng = np.random.default_rng(0)
    rows = [row("a", 0.90, lag=0), row("b", 0.899, lag=3), row("c", 0.50, lag=2), row("d", 0.99, lag=1024),
            row("g", 1.0, kind="oracle"), row("e", 0.95, lag=16)]
    strata_of = {"a": strata(rng, 0.90), "b": strata(rng, 0.899), "c": strata(rng, 0.50), "d": strata(rng, 0.99),
                 "e": strata(rng, 0.95), "g": strata(rng, 1.0, 0)}
    ranking.assign_divisions(rows)
    comparisons = ranking.rank(rows, strata_of, intervals=True, reps=200, seed=0)
    by = {r["policy"]: r for r in rows}
    assert [r["policy"] for r in rows] == ["g", "a", "b", "c", "e", "d"]  # divisions in order, means within
    assert (by["a"]["rank_label"], by["b"]["rank_label"], by["c"]["rank_label"]) == ("1=", "1=", "3")
    assert by["e"]["rank_label"] == "1" and by["d"]["rank_label"] == "1" and by["g"]["rank"] is None
    assert [(c.x, c.y, c.tied) for c in comparisons] == [("a", "b", True), ("b", "c", False)]
    # without intervals (fewer than 3 seeds) ranks follow the means and nothing is called a tie
    ranking.rank(rows, strata_of, intervals=False, reps=200, seed=0)
    assert (by["a"]["rank_label"], by["b"]["rank_label"]) == ("1", "2")


class Rec(NamedTuple):
    scenario: str
    score: float

    def get(self, key: str) -> float:
        return self.score


def _records(scores: dict[str, list[float]]) -> dict[tuple, Rec]:
    return {(s, i): Rec(s, v) for s, vs in scores.items() for i, v in enumerate(vs)}


@pytest.mark.parametrize("gain, marker", [(0.05, "learned"), (0.0, "search")])
def test_a_learned_entry_is_marked_learned_only_when_its_share_excludes_zero(gain, marker):
    rng = np.random.default_rng(1)
    base = strata(rng, 0.8, 0.05)
    noise = {s: list(0.002 * rng.standard_normal(len(v))) for s, v in base.items()}
    learned = {s: [b + gain + n for b, n in zip(v, noise[s])] for s, v in base.items()}
    off = ablation_spec("lmht")
    assert off == "lmht:network=off"
    rows = [row("lmht", 0.8 + gain, kind="learned", lag=1024), row(off, 0.8, kind="learned", lag=1024)]
    ranking.learned_shares(rows, {"lmht": _records(learned), off: _records(base)}, intervals=True, reps=300, seed=0)
    lm, ab = rows
    assert ab["ablation_of"] == "lmht" and lm["ablation"] == off
    assert lm["learned_share"] == pytest.approx(gain, abs=0.003)
    assert lm["marker"] == marker, lm["marker_reason"]
    assert ranking.rankable(lm) and not ranking.rankable(ab)  # the ablation is shown, never ranked


def test_an_unplayed_ablation_leaves_the_entry_unverified():
    rows = [row("dagger", 0.8, kind="learned", lag=3)]
    ranking.learned_shares(rows, {"dagger": {}}, intervals=True, reps=100, seed=0)
    assert rows[0]["marker"] == "unverified" and "dagger:network=off" in rows[0]["marker_reason"]


def test_test_looks_count_the_versions_scored_before(tmp_path):
    looks = history.update([], [row("mht", 0.9, version=5), row("mht:lag=3,nscan=3", 0.8, version=5),
                                row("fdp", 0.8, version=2), row("genie", 1.0, kind="oracle")])
    assert looks == [history.Look("mht", "5"), history.Look("fdp", "2")]
    looks = history.update(looks, [row("mht", 0.91, version=6)])
    board = {"rows": [row("mht", 0.91, version=6), row("fdp", 0.8, version=2), row("genie", 1.0, kind="oracle"),
                      row("dokf", 0.7, version=5)]}
    timings = {"date": "d", "machine": {}, "method": "m", "reference": {"us_per_pulse": 10.0},
               "policies": {"mht": {"us_per_pulse": 25.0, "vs_fdp": 2.5, "version": 6},
                            "dokf": {"us_per_pulse": 40.0, "vs_fdp": 4.0, "version": 4}}}
    add_looks_and_timings(board, looks, timings)
    assert [r["test_looks"] for r in board["rows"]] == [1, 0, None, 0]
    assert (board["rows"][0]["us_per_pulse"], board["rows"][0]["vs_fdp"]) == (25.0, 2.5)
    assert board["rows"][1]["us_per_pulse"] is None  # not timed in that run: no time from elsewhere
    # timed at version 4, scored at 5: its speed is not shown, and the page says why
    assert (board["rows"][3]["us_per_pulse"], board["timing"]["stale"]) == (None, ["dokf"])
    (tmp_path / history.HISTORY).write_text(history.text(looks))
    assert history.read(tmp_path) == looks
    (tmp_path / history.HISTORY).write_text(json.dumps({"looks": 5}))
    with pytest.raises(DeintError, match="is not a test-look history"):
        history.read(tmp_path)


def test_a_board_plays_every_division_and_each_learned_entrys_ablation():
    specs = board_entries("core-v0")
    assert {"mht", "mht:lag=3,nscan=3", "mht:lag=64", "lmht", "lmht:network=off", "fdp"} <= set(specs)
    assert "cdif" not in specs and "seq" not in specs  # blind-only policies cannot play core-v0
    assert {"cdif", "cdif:window=65", "seq", "seq:network=off"} <= set(board_entries("blind-v0"))
    divisions = {division_of(make_policy(s).lag) for s in specs if s.startswith("mht")}
    assert divisions == {"online", "low-latency", "offline"}


@pytest.mark.parametrize("suite,specs,timed_first", [("core-v0", ["mht", "fdp"], False),
                                                     ("robust-v0", ["mht", "fdp"], True),
                                                     ("core-v0", ["mht"], True)])
def test_the_speed_ratio_divides_by_fdps_own_row_on_its_reference_suite(tmp_path, monkeypatch, suite, specs,
                                                                        timed_first):
    """On core-v0's board fdp's row is the reference (one timing of one policy, not two that disagree);
    elsewhere fdp is timed on core-v0's episodes before the rows."""
    from deint_env.leaderboard import timing

    calls = []

    def fake(spec, episodes):
        calls.append(spec)
        us = {"mht": 30.0, "fdp": 20.0 if len(calls) > 1 else 31.7}[spec]  # the first timing runs slow
        return timing.Timing(spec, us, 1)

    monkeypatch.setattr(timing, "time_policy", fake)
    monkeypatch.setattr(timing, "_episodes", lambda suite, scenarios=None: [])
    out = timing.run(tmp_path, suite, specs, progress=False)
    assert calls == (["fdp"] if timed_first else []) + specs
    assert out["reference"]["measured"] == ("before the rows" if timed_first else "its own row")
    assert out["policies"]["mht"]["vs_fdp"] == pytest.approx(30.0 / out["reference"]["us_per_pulse"])
    assert out["reference"]["us_per_pulse"] == (31.7 if timed_first else 20.0)
    assert timing.read(tmp_path) == out

"""The one metric table: a metric added there shows in the runner's summary and the leaderboard; both
aggregate through one path; one table formatter; no import cycle between the leaderboard modules."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import subprocess
import sys

import numpy as np
import pytest

from deint_env import aggregate, metrics, policies, runner
from deint_env.leaderboard import Scope, build
from deint_env.metrics import Metric
from deint_env.tables import markdown_table, text_table

TARGET = "paper-v0/mk94-two-var1"
SCOPE = Scope("core-v0", ("core-n2-spread1.5-jitter0.05",), max_seeds=2)


@pytest.fixture(scope="module")
def records():
    return runner.evaluate(["genie", "random"], TARGET, max_seeds=3, progress=False)


def test_a_metric_added_to_the_table_shows_everywhere(records, tmp_path, monkeypatch):
    link = Metric("spurious_recall", "spurious recall", ".4f", "median", summary=True)
    monkeypatch.setattr(metrics, "METRICS", metrics.METRICS + (link,))
    rows = runner.summarise(records, reps=100)
    for row in rows:
        played = [r.get("spurious_recall") for r in records if r.policy == row["policy"]]
        assert row["spurious_recall"] == float(np.median(played))  # reduced as the table says
    table = runner.format_table(rows)
    assert "spurious recall" in table.splitlines()[0]
    assert format(rows[0]["spurious_recall"], ".4f") in table

    folder, board = build(SCOPE, ["random"], workers=1, root=tmp_path, progress=False, reps=100)
    assert board["rows"][0]["spurious_recall"] is not None
    assert "| spurious recall |" in (folder / "README.md").read_text()
    assert "spurious recall" in (folder / "index.html").read_text()
    assert "spurious_recall" in next(csv.reader(io.StringIO((folder / "leaderboard.csv").read_text())))
    assert "spurious_recall" in json.loads((folder / "leaderboard.json").read_text())["rows"][0]


def test_runner_and_leaderboard_aggregate_alike(records, tmp_path):
    """runner.summarise and the leaderboard are one path: the same records give the same numbers."""
    folder, board = build(SCOPE, ["genie", "random"], workers=1, root=tmp_path, progress=False, reps=300)
    recs = runner.read_records(folder / "results.jsonl")
    rows = {r["policy"]: r for r in runner.summarise(recs, reps=300)}
    for brow in board["rows"]:
        srow = rows[brow["policy"]]
        for key in ("score_iqm", "score_iqm_low", "score_iqm_high", "score_mean", "score_mean_low", "score_mean_high",
                    "accuracy", "mean_pe", "v_measure", "period_rel_error", "coverage", "episodes", "played"):
            same = srow[key] == brow[key] or (brow[key] is None and srow[key] != srow[key])  # no interval: NaN, None
            assert same, key
    assert board["intervals"] is False and all(r["score_mean_low"] is None for r in board["rows"])  # 2 seeds

def test_summary_rows_follow_the_table(records):
    rows = runner.summarise(records, reps=100)
    genie = next(r for r in rows if r["policy"] == "genie")
    assert genie["episodes"] == 3 and genie["score_mean"] == 1.0 and genie["faults"] == []
    assert {m.key for m in metrics.METRICS} <= set(genie)
    assert genie["score_iqm_low"] <= genie["score_iqm"] <= genie["score_iqm_high"]
    assert aggregate.entry_kind(next(r for r in records if r.policy == "random")) == "reference"


def test_one_formatter():
    assert text_table(["a", "bb"], [["xxx", "y"]]) == "a    bb\n---  --\nxxx  y"
    assert markdown_table(["a|b"], [["1"]]) == ["| a\\|b |", "|---|", "| 1 |"]


def test_leaderboard_modules_import_without_a_cycle():
    """plots and build each import on their own (build <-> plots was a cycle through TAUS)."""
    for module in ("deint_env.leaderboard.plots", "deint_env.leaderboard.build", "deint_env.leaderboard.render"):
        code = f"import {module}"
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
    import ast
    import pathlib

    plots = ast.parse(pathlib.Path(sys.modules["deint_env.leaderboard.build"].__file__).with_name("plots.py")
                      .read_text())
    imported = {n.module for n in ast.walk(plots) if isinstance(n, ast.ImportFrom)}
    assert "deint_env.leaderboard.build" not in imported


def test_leaderboard_rows_say_whether_an_entry_is_learned(tmp_path, monkeypatch):
    policies.list_policies()
    learned = dataclasses.replace(policies.policy_info("random"), kind="learned")
    monkeypatch.setitem(policies._REGISTRY, "random", learned)
    folder, board = build(SCOPE, ["random", "genie"], workers=1, root=tmp_path, progress=False, reps=100)
    rows = {r["policy"]: r for r in board["rows"]}
    assert rows["random"]["kind"] == "learned"
    assert rows["genie"]["kind"] == policies.policy_info("genie").kind  # read from the registry
    assert "| random (learned) |" in (folder / "README.md").read_text()
    table = list(csv.DictReader(io.StringIO((folder / "leaderboard.csv").read_text())))
    assert {r["policy"]: r["kind"] for r in table}["random"] == "learned"
    assert "random (learned)" in runner.format_table(runner.summarise(runner.read_records(folder / "results.jsonl"),
                                                                       reps=100))


def test_the_leaderboard_says_how_each_metric_reads(tmp_path):
    _, board = build(SCOPE, ["random"], workers=1, root=tmp_path, progress=False, reps=100)
    described = {m["key"]: m for m in board["metrics"]}
    assert list(described) == [m.key for m in metrics.METRICS]
    assert described["mean_pe"]["higher_is_better"] is False and described["accuracy"]["higher_is_better"] is True
    assert described["period_rel_error"]["aggregate"] == "median"

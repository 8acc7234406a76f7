"""`deint reproduce`: the MK94 KF/FDP experiments run (quick mode) and write their figure and table."""

from __future__ import annotations

import json

import pytest

from baselines.reproduce import list_experiments, run_experiment
from deint_env.cli import main

pytest.importorskip("matplotlib")
MK94 = ["mk94-fig3", "mk94-fig4-5", "mk94-fig6", "mk94-fig7", "mk94-fig8", "mk94-fig12"]


@pytest.mark.parametrize("name", MK94)
def test_experiment_writes_figure_and_table(name, tmp_path):
    report = run_experiment(name, tmp_path, quick=True)
    assert report.rows and all({"quantity", "ours", "paper"} <= set(r) for r in report.rows)
    for f in report.files:
        assert (tmp_path / f).stat().st_size > 1000 and f.endswith(".png")
    saved = json.loads((tmp_path / f"{name}.json").read_text())
    assert saved["rows"] == report.rows
    assert (tmp_path / f"{name}.txt").read_text().startswith(name)


def test_fig3_kf_converges_with_small_jitter(tmp_path):
    rows = {r["quantity"]: r["ours"] for r in run_experiment("mk94-fig3", tmp_path, quick=True).rows}
    assert abs(float(rows["sigma_w=3: period estimate after 100 pulses (mean over seeds)"]) - 11.0) < 0.2


def test_cli_lists_and_runs_experiments(tmp_path, capsys):
    assert main(["reproduce"]) == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in MK94) and set(MK94) <= set(list_experiments())
    assert main(["reproduce", "mk94-fig3", "--out", str(tmp_path), "--quick"]) == 0
    assert "mk94-fig3" in capsys.readouterr().out and (tmp_path / "mk94-fig3.png").exists()
    assert main(["reproduce", "nope"]) == 2
    assert "unknown" in capsys.readouterr().err

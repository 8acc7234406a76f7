"""`deint reproduce`: the MK94 KF/FDP experiments run (quick mode) and write their figure and table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.fdp import FDP
from baselines.genie import Genie
from baselines.reproduce import list_experiments, run_experiment
from baselines.reproduce.mk94 import SUITE, fig4_spec, pe_runs
from deint_env import make_policy
from deint_env.cli import main
from deint_env.suites import find_entry

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


# ---- the published accumulation (3.2) against the genie (Figs. 4-5) ------------------------------
def _gap_to_genie(var: float, seeds: list[int], prior_var: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """P_e (seed, source) of fdp (defaults, Delta = 3) and of the genie on the Fig. 4/5 scenario."""
    spec = fig4_spec(var, prior_var)
    return pe_runs(spec, seeds, lambda: FDP(lookahead=3)), pe_runs(spec, seeds, Genie)


def test_fdp_default_is_the_published_accumulation():
    assert FDP().accumulate == "lookahead" and make_policy("fdp").accumulate == "lookahead"
    assert make_policy("fdp:accumulate=sequence").accumulate == "sequence"


@pytest.mark.parametrize("var", [0.5, 1.0, 2.0])
def test_literal_fdp_is_at_genie_level_on_a_few_seeds(var):
    seeds = list(find_entry(f"{SUITE}/mk94-two-var{var:g}").test)[:3]
    fdp, genie = _gap_to_genie(var, seeds)
    assert np.all(np.abs(fdp.mean(axis=0) - genie.mean(axis=0)) <= 0.02)


@pytest.mark.slow
def test_literal_fdp_is_at_genie_level_up_to_jitter_variance_2():
    """The ten test seeds, sigma_w^2 <= 2.  With Sigma = 10 I every mean P_e is within 0.02 of the
    genie's.  With the paper's Sigma = I, too, up to sigma_w^2 = 1; at 1.5 and 2 one seed (1000004)
    loses source 2 at the start (measured P_e ~0.5), the nine others stay within 0.02."""
    for var in (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0):
        seeds = list(find_entry(f"{SUITE}/mk94-two-var{var:g}").test)
        fdp, genie = _gap_to_genie(var, seeds, prior_var=10.0)
        assert np.all(np.abs(fdp.mean(axis=0) - genie.mean(axis=0)) <= 0.02), var
        fdp, genie = _gap_to_genie(var, seeds)
        lost = np.any(fdp > 0.3, axis=1)
        assert lost.sum() <= (0 if var <= 1.0 else 1), var
        assert np.all(np.abs(fdp[~lost].mean(axis=0) - genie[~lost].mean(axis=0)) <= 0.02), var

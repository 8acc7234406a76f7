"""`deint reproduce`: the MK94 KF/FDP experiments run (quick mode) and write their figure and table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.fdp import FDP
from baselines.genie import Genie
from baselines.reproduce import list_experiments, run_experiment
from baselines.reproduce.mk94 import MK94_FIG12_PERIODS, SUITE, fig4_spec, fig12_runs, pe_runs, startup_failure
from deint_env import make_policy
from deint_env.cli import main
from deint_env.runner import play
from deint_env.simulate import simulate
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
    loses the start (measured P_e (0.35, 0.69); see the test below), the nine others stay within 0.02.
    Ten seeds are too few for a rate: on 100 train seeds Delta = 3 loses 8 and 13 start-ups at 1.5 and
    2 with Sigma = I, and 12 and 14 with Sigma = 10 I (measured; the Sigma = 10 I row is no cure)."""
    for var in (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0):
        seeds = list(find_entry(f"{SUITE}/mk94-two-var{var:g}").test)
        fdp, genie = _gap_to_genie(var, seeds, prior_var=10.0)
        assert np.all(np.abs(fdp.mean(axis=0) - genie.mean(axis=0)) <= 0.02), var
        fdp, genie = _gap_to_genie(var, seeds)
        lost = np.any(fdp > 0.3, axis=1)
        assert lost.sum() <= (0 if var <= 1.0 else 1), var
        assert np.all(np.abs(fdp[~lost].mean(axis=0) - genie[~lost].mean(axis=0)) <= 0.02), var


# ---- Fig. 12 on paper-v1: the paper's end point and start-up failures ---------------------------
def test_startup_failure_flags_a_lost_source():
    ep = simulate(find_entry(f"{SUITE}/mk94-missing-two").spec, 1000000)
    assert not startup_failure(play(Genie(), ep, oracle=True).labels, ep)
    assert startup_failure(np.zeros(len(ep), dtype=np.int64), ep)  # everything called source 1


def test_fig12_standard_fails_and_modified_can_end_at_the_papers_estimates():
    """Measured: the standard FDP loses source 2 at the start on every test seed; the modified one
    (VI-A) on seed 1000004 tracks both and ends at (10.00, 29.99), the paper's (10.01, 29.98)."""
    _, _, failed = fig12_runs(SUITE, {}, [1000000, 1000001], quick=False)
    assert failed.all()
    _, finals, failed = fig12_runs(SUITE, {"missing": True}, [1000004], quick=False)
    assert not failed[0] and np.all(np.abs(finals[0] - MK94_FIG12_PERIODS) <= 0.3)


@pytest.mark.slow
def test_fig12_shares_on_the_test_seeds():
    """The ten test seeds (measured: start-up failures 10 / 4 / 1 of 10 for standard / modified /
    coasting; within 0.3 of (10.01, 29.98): 0 / 2 / 0; coasting within 0.3 of the truth: 9)."""
    seeds = list(find_entry(f"{SUITE}/mk94-missing-two").test)
    _, std_finals, std_failed = fig12_runs(SUITE, {}, seeds, quick=False)
    _, mod_finals, mod_failed = fig12_runs(SUITE, {"missing": True}, seeds, quick=False)
    _, coast_finals, coast_failed = fig12_runs(SUITE, {"dropout": True}, seeds, quick=False)
    assert std_failed.all() and mod_failed.mean() <= 0.5 and coast_failed.mean() <= 0.2
    near = [np.mean(np.all(np.abs(f - MK94_FIG12_PERIODS) <= 0.3, axis=1)) for f in (std_finals, mod_finals)]
    assert near[0] == 0.0 and near[1] >= 0.1
    assert np.mean(np.all(np.abs(coast_finals - (11.0, 30.0)) <= 0.3, axis=1)) >= 0.8


def test_fig45_seed_1000004_loses_the_start_by_swapping_pulses_4_and_5():
    """Why Delta = 3 with the paper's Sigma_{1|0} = I loses a test seed at sigma_w^2 = 1.5 (a genuine
    start-up failure, not an implementation slip).  The first three pulses (3.09, 4.81, 13.47) get the
    right sources; the KF of that path then predicts source 1 at ~23.2 and source 2 at ~25.1, because
    the prior T2 = 22 lies 5 prior deviations from the true 17 and a source's first pulse (predicted at
    its phase) says nothing about its period.  The next two pulses, 23.03 (source 2, jitter +2.0) and
    25.41 (source 1), fit the swapped sources far better than the true ones, FDP swaps them, and the
    wrong tracks never recover (accuracy ~0.5 over every 100 pulses) while the genie labels them right."""
    from baselines.kalman import DLMModel, innovation, predict, prior_block, update

    ep = simulate(fig4_spec(1.5), 1000004)
    assert ep.source[:5].tolist() == [0, 1, 0, 1, 0]
    model = DLMModel.from_priors(ep.priors)
    b = prior_block(ep.priors)
    for k, src in enumerate((0, 1, 0)):  # (2.15) on the true sources of the first three pulses
        pred = predict(b.take(src), model)
        e, s = innovation(pred, ep.toa[k], model)
        b.put(src, update(pred, e, s, model))
    nxt = predict(b, model).tau  # next arrivals of sources 1 and 2 on the true path
    assert abs(nxt[0] - 23.2) < 0.1 and abs(nxt[1] - 25.1) < 0.1
    true_cost = (ep.toa[3] - nxt[1]) ** 2 + (ep.toa[4] - nxt[0]) ** 2
    swapped_cost = (ep.toa[3] - nxt[0]) ** 2 + (ep.toa[4] - nxt[1]) ** 2
    assert swapped_cost < 0.2 and true_cost > 8.0
    fdp = play(FDP(lookahead=3), ep)
    assert fdp.labels[:5].tolist() == [0, 1, 0, 0, 1]
    assert play(Genie(), ep, oracle=True).labels[:5].tolist() == [0, 1, 0, 1, 0]
    correct = fdp.labels == ep.source
    assert all(correct[i:i + 100].mean() < 0.6 for i in range(0, len(ep), 100))

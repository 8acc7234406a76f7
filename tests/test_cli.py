"""The `deint` command: simulate -> label -> score round trips, one-line errors, atomic outputs, runs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from deint_env import policies
from deint_env.cli import main
from deint_env.policies import PolicyInfo, make_policy
from deint_env.runner import play
from deint_env.simulate import simulate
from deint_env.suites import resolve_scenario
from hostile_cli import deint_script

SCENARIO = "paper-v0/mk94-two-var1"


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def deint(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def ok(capsys, *argv) -> str:
    code, out, err = deint(capsys, *argv)
    assert code == 0, err
    return out


def fails(capsys, *argv, expected: str) -> str:
    code, out, err = deint(capsys, *argv)
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("deint: error: "), err
    assert expected in lines[0], lines[0]
    return lines[0]


def score_json(capsys, labels, truth, *extra) -> dict:
    return json.loads(ok(capsys, "score", labels, "--truth", truth, "--json", *extra))


# ---- the round trips ----------------------------------------------------------------------------------
@pytest.mark.parametrize("scenario, seed", [(SCENARIO, 5), ("robust-v0/robust-merged1", 2),
                                            ("robust-v0/robust-spurious0.1", 1)])
def test_genie_with_true_priors_matches_play(capsys, scenario, seed):
    ok(capsys, "simulate", scenario, "--seed", seed, "-o", "p.csv", "--true-priors-out", "true.json")
    ok(capsys, "label", "p.csv", "--policy", "genie", "--priors", "true.json", "-o", "l.csv")
    got = score_json(capsys, "l.csv", "p.csv")
    direct = play(make_policy("genie"), simulate(resolve_scenario(scenario), seed), oracle=True)
    assert got["accuracy"] == direct.metrics["accuracy"]
    assert got["mean_pe"] == pytest.approx(direct.metrics["mean_pe"])


def test_design_command_sequence_with_public_priors(capsys):
    ok(capsys, "simulate", SCENARIO, "--seed", 3, "-o", "p.csv", "--priors-out", "pr.json")
    assert json.load(open("pr.json"))["period"] == [10.0, 22.0]  # the paper's priors, not the truth
    ok(capsys, "label", "p.csv", "--policy", "genie", "--priors", "pr.json", "-o", "l.csv")
    got = score_json(capsys, "l.csv", "p.csv")
    assert {"accuracy", "mean_pe", "matched_accuracy", "v_measure", "ari"} <= got.keys()
    assert 0 <= got["accuracy"] <= 1 and got["n_pulses"] == 500
    table = ok(capsys, "score", "l.csv", "--truth", "p.csv")
    assert "matched_accuracy" in table and "pe[source 1]" in table


def test_label_with_prior_periods_and_policy_parameters(capsys):
    ok(capsys, "simulate", SCENARIO, "--seed", 1, "-o", "p.csv")
    ok(capsys, "label", "p.csv", "--policy", "nearest-prior:gate=3", "--n-sources", 2, "--prior-periods", "11,17",
       "-o", "l.csv")
    assert score_json(capsys, "l.csv", "p.csv")["n_labels"] == 2
    ok(capsys, "label", "p.csv", "--policy", "random:seed=4", "--prior-periods", "11,17", "-o", "r1.csv")
    ok(capsys, "label", "p.csv", "--policy", "random", "--seed", 4, "--prior-periods", "11,17", "-o", "r2.csv")
    assert open("r1.csv").read() == open("r2.csv").read()


def test_scenario_file_amplitudes_and_no_truth(capsys, tmp_path):
    spec = resolve_scenario(SCENARIO).replace(name="amp", n_pulses=50, amplitudes=True)
    (tmp_path / "s.json").write_text(spec.to_json())
    ok(capsys, "simulate", "s.json", "--seed", 0, "-o", "p.csv")
    assert open("p.csv").readline() == "toa,amplitude,source\n"
    ok(capsys, "simulate", "s.json", "--seed", 0, "-o", "n.csv", "--no-truth")
    assert open("n.csv").readline() == "toa,amplitude\n"
    ok(capsys, "label", "n.csv", "--policy", "random", "--prior-periods", "11,17", "-o", "l.csv")
    fails(capsys, "score", "l.csv", "--truth", "n.csv", expected="n.csv: has no 'source' column")


def test_blind_round_trip(capsys):
    ok(capsys, "simulate", "blind-v0/blind-n2to5-jitter0.1", "--seed", 2, "-o", "p.csv", "--priors-out", "pr.json")
    assert json.load(open("pr.json"))["blind"] is True
    ok(capsys, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "l.csv")
    blind = score_json(capsys, "l.csv", "p.csv", "--blind")
    assert blind["blind"] and blind["accuracy"] == blind["link_accuracy"]
    ok(capsys, "label", "p.csv", "--policy", "random", "--n-sources", 6, "-o", "l6.csv")


# ---- one-line errors ------------------------------------------------------------------------------------
PULSES = {"unsorted.csv": "toa\n1\n3\n2\n", "nan.csv": "toa\n1\nnan\n", "notoa.csv": "amplitude\n1\n",
          "extra.csv": "toa,phase\n1,2\n"}


@pytest.mark.parametrize("name, expected", [
    ("unsorted.csv", "unsorted.csv: line 4: toa=2.0 is smaller than the previous line's toa=3.0"),
    ("nan.csv", "nan.csv: line 3: toa=nan is not finite"),
    ("notoa.csv", "notoa.csv: line 1: no 'toa' column"),
    ("extra.csv", "extra.csv: line 1: column 'phase' is unknown"),
    ("missing.csv", "missing.csv: no such file"),
])
def test_bad_pulse_file_is_one_line(capsys, tmp_path, name, expected):
    for n, text in PULSES.items():
        (tmp_path / n).write_text(text)
    fails(capsys, "label", name, "--policy", "random", "--prior-periods", "1,2", "-o", "l.csv", expected=expected)


@pytest.fixture
def simulated(capsys):
    ok(capsys, "simulate", SCENARIO, "--seed", 3, "-o", "p.csv", "--priors-out", "pr.json")
    ok(capsys, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "l.csv")


def test_bad_label_files_are_one_line(capsys, tmp_path, simulated):
    lines = open("l.csv").read().splitlines()
    (tmp_path / "short.csv").write_text("\n".join(lines[:-1]) + "\n")
    bad = lines[:]
    bad[5] = bad[5].rsplit(",", 1)[0] + ",7"
    (tmp_path / "range.csv").write_text("\n".join(bad) + "\n")
    fails(capsys, "score", "short.csv", "--truth", "p.csv", expected="short.csv: has 499 labels but p.csv has 500")
    fails(capsys, "score", "range.csv", "--truth", "p.csv", "--n-labels", 2,
          expected="range.csv: line 6: label='7' is invalid; label must be an integer in [-1, 1]")
    assert score_json(capsys, "range.csv", "p.csv")["n_labels"] == 8  # without --n-labels: largest label + 1


@pytest.mark.parametrize("argv, expected", [
    (["label", "p.csv", "--policy", "nosuch", "--priors", "pr.json"], "policy 'nosuch' is unknown; known policies:"),
    (["label", "p.csv", "--policy", "random:bogus=1", "--priors", "pr.json"], "has no parameter 'bogus'"),
    (["label", "p.csv", "--policy", "random", "--priors", "bad.json"], "bad.json: line 1 column 13: not valid JSON"),
    (["label", "p.csv", "--policy", "random", "--priors", "key.json"], "key.json: key 'sigma' is unknown"),
    (["label", "p.csv", "--policy", "random", "--priors", "none.json"], "none.json: no such file"),
    (["label", "p.csv", "--policy", "random"], "the policy needs priors"),
    (["label", "p.csv", "--policy", "random", "--n-sources", 3, "--prior-periods", "1,2"], "must agree"),
    (["label", "p.csv", "--policy", "random", "--priors", "pr.json", "--lag", 2], "runs with lag 0"),
    (["label", "p.csv", "--policy", "genie", "--prior-periods", "11,17"], "genie needs the true period and phase"),
    (["label", "p.csv", "--policy", "random", "--priors", "pr.json", "--seed", "x"], "invalid int value"),
    (["simulate", "paper-v0/nosuch", "--seed", 1], "scenario 'nosuch' is not in suite paper-v0"),
    (["simulate", "nosuch", "--seed", 1], "scenario 'nosuch' is unknown"),
    (["simulate", SCENARIO, "--seed", -1], "seed=-1 is invalid"),
    (["simulate", "bad.json", "--seed", 1], "bad.json: line 1 column 13"),
    (["score", "l.csv", "--truth", "l.csv"], "l.csv: line 1: column 'label' is unknown"),
    (["run", "--policy", "random", "--suite", "nosuch"], "suite 'nosuch' is unknown"),
    (["run", "--policies", "random:seed=1", "--scenario", SCENARIO], "--policies='random:seed=1' is invalid"),
    (["run", "--policy", "random", "--scenario", "core-v0"], "names a suite; use --suite core-v0"),
    (["suites", "nosuch"], "suite 'nosuch' is unknown"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_bad_input_is_one_line(capsys, tmp_path, simulated, argv, expected):
    (tmp_path / "bad.json").write_text('{"period": [')
    (tmp_path / "key.json").write_text('{"period": [1], "sigma": 2}')
    if argv[0] in ("label", "simulate"):
        argv = [*argv, "-o", "out.csv"]
    fails(capsys, *argv, expected=expected)
    assert not (tmp_path / "out.csv").exists()


class BadLabel:
    lag = 0

    def reset(self, priors, info):
        pass

    def act(self, obs):
        return 99


class Lagged:
    def __init__(self, lag: int = 0):
        self.lag = lag

    def reset(self, priors, info):
        self.n = priors.n_labels

    def act(self, obs):
        return self.n


def test_label_outside_the_action_space(capsys, simulated, monkeypatch):
    policies.list_policies()
    monkeypatch.setitem(policies._REGISTRY, "bad-label", PolicyInfo("bad-label", BadLabel))
    before = open("l.csv").read()
    fails(capsys, "label", "p.csv", "--policy", "bad-label", "--priors", "pr.json", "-o", "l.csv",
          expected="action=99 is invalid: a label in [0, 2]")
    assert open("l.csv").read() == before


def test_lag_sets_a_lag_parameter(capsys, simulated, monkeypatch):
    policies.list_policies()
    monkeypatch.setitem(policies._REGISTRY, "lagged", PolicyInfo("lagged", Lagged))
    ok(capsys, "label", "p.csv", "--policy", "lagged", "--priors", "pr.json", "--lag", 3, "-o", "l.csv")
    assert score_json(capsys, "l.csv", "p.csv")["spurious_precision"] == 0.0  # every pulse labelled spurious
    fails(capsys, "label", "p.csv", "--policy", "lagged:lag=1", "--priors", "pr.json", "--lag", 3, "-o", "l.csv",
          expected="runs with lag 1")


# ---- outputs are atomic -----------------------------------------------------------------------------------
def test_failed_label_keeps_the_old_output(capsys, tmp_path, simulated):
    before = open("l.csv").read()
    fails(capsys, "label", "p.csv", "--policy", "nosuch", "--priors", "pr.json", "-o", "l.csv", expected="nosuch")
    fails(capsys, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "p.csv",
          expected="is the same file as the input PULSES")
    assert open("l.csv").read() == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_interrupted_label_keeps_the_old_output(capsys, tmp_path, simulated, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("deint_env.play.play", interrupted)  # where `deint label` takes it from
    before = open("l.csv").read()
    code, out, err = deint(capsys, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "l.csv")
    assert code == 130 and err == "deint: interrupted\n"
    assert open("l.csv").read() == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_simulate_writes_nothing_when_an_output_is_invalid(capsys, tmp_path):
    fails(capsys, "simulate", SCENARIO, "--seed", 1, "-o", "p.csv", "--priors-out", "no-dir/pr.json",
          expected="no-dir/pr.json: cannot write: directory no-dir does not exist")
    assert not list(tmp_path.iterdir())


# ---- run, suites, policies ------------------------------------------------------------------------------------
def test_run_resumes(capsys, tmp_path):
    argv = ["run", "--policies", "genie,random", "--scenario", SCENARIO, "--max-seeds", 2, "--out", "tmp"]
    code, out, err = deint(capsys, *argv)
    assert code == 0, err
    assert "genie (oracle)" in out and "random" in out and "tmp" in err
    first = (tmp_path / "tmp").read_text()
    assert len(first.splitlines()) == 4
    rows = json.loads(ok(capsys, *argv, "--json"))
    assert (tmp_path / "tmp").read_text() == first  # resumed: nothing new appended
    genie = next(r for r in rows if r["policy"] == "genie")
    assert genie["episodes"] == 2 and genie["score_mean"] == 1.0


def test_interrupted_run_resumes(capsys, tmp_path, monkeypatch):
    import deint_env.runner as runner

    real, calls = runner.run_job, []

    def flaky(job):
        calls.append(job)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(job)

    monkeypatch.setattr(runner, "run_job", flaky)
    argv = ["run", "--policies", "random,genie", "--scenario", SCENARIO, "--max-seeds", 2, "--out", "res.jsonl",
            "--no-progress"]
    code, out, err = deint(capsys, *argv)
    assert code == 130 and out == ""
    assert err == "deint: interrupted; 2 of 4 episodes are saved in res.jsonl, rerun to resume\n"
    monkeypatch.setattr(runner, "run_job", real)
    code, out, err = deint(capsys, *argv)
    assert code == 0 and "(2 played now)" in err
    assert len((tmp_path / "res.jsonl").read_text().splitlines()) == 4


def test_run_default_results_file(capsys, tmp_path):
    ok(capsys, "run", "--policy", "random", "--policies", "random", "--scenario", "mk94-two-var1",
       "--max-seeds", 1, "--no-progress")  # the same policy twice runs once
    assert len((tmp_path / "runs" / "paper-v0" / "mk94-two-var1-test.jsonl").read_text().splitlines()) == 1


def test_suites_and_policies(capsys):
    listing = ok(capsys, "suites")
    assert "core-v0" in listing and "paper-v0" in listing
    core = ok(capsys, "suites", "core-v0")
    assert "core-n2-spread1.5-jitter0.05" in core
    data = json.loads(ok(capsys, "suites", "paper-v0", "--json"))
    assert data["suite"] == "paper-v0" and data["status"].split()[0] in ("published", "unpublished", "CHANGED")
    assert any(e["scenario"] == "mk94-two-var1" for e in data["entries"])
    table = ok(capsys, "policies")
    assert "genie" in table and "oracle" in table and "random" in table


def test_help_and_version(capsys):
    code, out, _ = deint(capsys, "--help")
    assert code == 0 and "simulate" in out and "score" in out
    code, out, _ = deint(capsys, "--version")
    assert code == 0 and out.startswith("deint-bench ")


# ---- the installed script ------------------------------------------------------------------------------------
def test_console_script_end_to_end(tmp_path):
    exe = deint_script()
    run = lambda *a: subprocess.run([exe, *map(str, a)], cwd=tmp_path, capture_output=True, text=True)
    r = run("simulate", SCENARIO, "--seed", 2, "-o", "p.csv", "--true-priors-out", "t.json")
    assert r.returncode == 0, r.stderr
    assert run("label", "p.csv", "--policy", "genie", "--priors", "t.json", "-o", "l.csv").returncode == 0
    r = run("score", "l.csv", "--truth", "p.csv", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["accuracy"] > 0.8
    (tmp_path / "u.csv").write_text("toa\n2\n1\n")
    r = run("label", "u.csv", "--policy", "random", "--prior-periods", "1", "-o", "x.csv")
    assert r.returncode == 2 and r.stderr.splitlines() == [
        "deint: error: u.csv: line 3: toa=1.0 is smaller than the previous line's toa=2.0; "
        "pulses must be sorted by increasing toa"]


TOY_KERNEL = '''
import numba

from baselines.floors import RandomPolicy


@numba.njit(cache=True)
def bump(x):
    return x + 1


class Toy(RandomPolicy):
    def act(self, obs):
        bump(1)
        return super().act(obs)
'''


def test_label_says_it_compiles_only_when_a_kernel_is_not_cached(tmp_path):
    """One "compiling" line on the run that compiles the policy's kernel into an empty numba cache, none
    on the next run, which loads it from there."""
    (tmp_path / "toy_kernel.py").write_text(TOY_KERNEL)
    assert main(["simulate", SCENARIO, "--seed", "0", "-o", "p.csv", "--priors-out", "p.json"]) == 0
    code = ("import sys\n"
            "from deint_env.policies import register_policy\n"
            "from deint_env.cli import main\n"
            "register_policy('toy', 'toy_kernel:Toy')\n"
            "sys.exit(main(['label', 'p.csv', '--priors', 'p.json', '--policy', 'toy', '-o', 'l.csv']))")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), str(Path(__file__).resolve().parents[1])])}
    runs = [subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, env=env)
            for _ in range(2)]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr + runs[1].stderr
    notice = "deint: compiling toy's kernels (first run after an install or update; cached for later calls) ..."
    assert runs[0].stderr.splitlines()[0] == notice
    assert "compiling" not in runs[1].stderr and "labelled" in runs[1].stderr

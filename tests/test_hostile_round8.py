"""Hostile inputs, round eight (docs/hostile-round8.md): legal but extreme policy parameters that overflowed
(mht's gate and jump_z squared, pri-transform's bins past a pri_max of 1e300) or ran for minutes (fdp's
start_look, agent-beam's beam with decision_lag), `deint tune` tuning the whole suite for `--scenarios ''` and
failing after every play for an `--out` that is its `--work` folder, a blind `--expert` refused under a running
progress bar, results records with a list accuracy, a pe of the wrong length or an unknown split, `evaluate`
given a ScenarioSpec, and error lines broken by a numpy array's repr."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import deint_env
from deint_env.cli import main
from deint_env.errors import DeintError, shown
from deint_env.results import EpisodeRecord
from hostile_cli import one_line


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def pulses(capsys):
    assert main(["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o", "p.csv", "--priors-out", "pr.json"]) == 0
    capsys.readouterr()


# ---- legal extremes of policy parameters -----------------------------------------------------------
@pytest.mark.parametrize("spec", ["mht:gate=1e300", "mht:jump=0.1,jump_z=1e300", "lmht:gate=1e300",
                                  "pri-transform:pri_max=1e300", "pri-transform:pri_min=1,pri_max=1e300"])
def test_a_huge_legal_width_labels(pulses, capsys, spec):
    if spec.startswith("lmht"):
        pytest.importorskip("torch")
    priors = [] if spec.startswith("pri-transform") else ["--priors", "pr.json"]
    code = main(["label", "p.csv", *priors, "-o", "out.csv", "--policy", spec])  # was OverflowError (x ** 2)
    err = capsys.readouterr().err
    assert code == 0 and "labelled 500 pulses" in err, err


def test_fdp_start_look_is_bounded_as_mhts_look_start(pulses, capsys):
    one_line(capsys, "label", "p.csv", "--priors", "pr.json", "-o", "out.csv", "--policy",
             "fdp:start=lookahead,start_look=21",  # 50 and 10^5 searched for over 60 s
             says="start_look=21 is invalid: an integer in [1, 20]")
    assert main(["label", "p.csv", "--priors", "pr.json", "-o", "out.csv", "--policy",
                 "fdp:start=lookahead,start_look=20"]) == 0


def test_agent_beam_bounds_its_undecided_labels():
    from agents.beam import BeamDecoder

    with pytest.raises(DeintError, match=r"beam=4096 with decision_lag=1000 is invalid: beam \* \(decision_lag \+ 1\) "
                                         r"at most 2\^20"):
        BeamDecoder(None, None, beam=4096, decision_lag=1000)  # was 32 MB copied a pulse: 500 pulses over 60 s


# ---- odd options ------------------------------------------------------------------------------------
def test_tune_with_an_empty_scenarios_option_is_one_line(capsys):
    one_line(capsys, "tune", "fdp", "--suite", "core-v0", "--scenarios", "", "--budget", "1", "--configs", "1",
             "--work", "w", "--out", "t.json", "--no-progress",  # was a tune over the whole suite
             says="--scenarios='' is invalid: scenario names separated by commas")


def test_tune_refuses_a_preset_path_that_is_its_work_folder(capsys):
    one_line(capsys, "tune", "fdp", "--suite", "core-v0", "--budget", "45", "--out", "w", "--work", "./w",
             "--no-progress",  # was refused only after every play, writing the preset over the folder the plays made
             says="--out w is the work folder --work w")
    assert not os.path.exists("w")


def test_a_blind_expert_is_refused_before_training():
    pytest.importorskip("torch")
    from agents.experts import make_expert

    with pytest.raises(DeintError, match="--expert 'cdif' plays blind scenarios only"):
        make_expert("cdif")  # was refused at the first episode, on the line of a running progress bar


# ---- results records ----------------------------------------------------------------------------------
def record(**changes) -> dict:
    base = {"accuracy": 0.5, "pe": [0.1, 0.2], "policy": "random", "scenario": "mk94-two-var1",
            "scenario_hash": "0c829c6f5a15e89d", "seed": 1000000, "split": "test", "suite": "paper-v0",
            "suite_hash": "654cf82820d16e7a", "tags": ["paper"], "settings": {}, "oracle": False, "lag": 0,
            "n_sources": 2, "version": "0.1.0", "applicable": True}
    return {**base, **changes}


@pytest.mark.parametrize("changes, says", [
    ({"accuracy": [1]}, "metric 'accuracy' is [1], not a number or null"),
    ({"pe": [0.1] * 1000}, "metric 'pe' is [0.1, 0.1,"),
    ({"pe": [0.1]}, "metric 'pe' is [0.1], not a list of 2 numbers or nulls (one per source)"),
    ({"split": "nope"}, "field 'split' is \"nope\", not one of train, validation, test"),
])
def test_a_results_record_is_checked_field_by_field(changes, says):
    assert EpisodeRecord.from_json(record(), "r.jsonl: line 1").split == "test"
    with pytest.raises(DeintError, match="r.jsonl: line 1: ") as e:
        EpisodeRecord.from_json(record(**changes), "r.jsonl: line 1")  # accepted (a list accuracy: TypeError later)
    assert says in str(e.value)


def test_a_list_accuracy_in_a_results_file_is_one_line(capsys):
    with open("x.jsonl", "w") as f:
        f.write(json.dumps(record(accuracy=[1])) + "\n")
    one_line(capsys, "run", "--policy", "random", "--scenario", "paper-v0/mk94-two-var1", "--max-seeds", "2",
             "--out", "x.jsonl", "--no-progress",  # was TypeError: must be real number, not list
             says="x.jsonl: line 1: metric 'accuracy' is [1], not a number or null")


# ---- the Python API ------------------------------------------------------------------------------------
def test_evaluate_refuses_a_scenario_that_is_no_name():
    spec = deint_env.resolve_scenario("paper-v0/mk94-two-var1")
    with pytest.raises(DeintError, match=r"scenarios holds ScenarioSpec\(.*: a list of SUITE/SCENARIO names"):
        deint_env.evaluate("random", scenarios=[spec], max_seeds=1, progress=False)  # was TypeError: not iterable


@pytest.mark.parametrize("make", [
    lambda: deint_env.Priors.from_json_dict({"period": np.ones((2, 2))}),
    lambda: deint_env.Modulation(kind="random_stagger", pattern=(1.0, 1.5), transition=np.full((2, 2), 0.5)),
])
def test_an_array_in_an_error_is_shown_on_one_line(make):
    with pytest.raises(DeintError) as e:
        make()  # the array's repr broke the error over two lines
    assert "\n" not in str(e.value), str(e.value)
    assert shown(np.ones((2, 2))) == "array([[1., 1.], [1., 1.]])"

"""Hostile inputs, round seven (docs/hostile-round7.md): Ctrl-C while Python imports the package (a
KeyboardInterrupt traceback), a policy's `act` before its `reset`, observations built by hand that no policy
checks, `simulate_many` over a range of 10^12 seeds, huge tune budgets, train step counts and export worker
counts, help on an ASCII stdout, error lines of 60 KB, reset options the envs ignored, and a scenario that
`evaluate` counted twice."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import deint_env
from deint_env.cli import main
from deint_env.errors import DeintError
from deint_env.play import play
from hostile_cli import deint_script, one_line

BIG = "100000000000000000000"


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


# ---- Ctrl-C while Python imports the package ---------------------------------------------------------
def interrupted_at(marker: str, *, ignored: bool = False) -> tuple[int, str]:
    """Run `deint --help`, sending SIGINT as soon as Python has imported a module named like `marker`
    (PYTHONPROFILEIMPORTTIME reports each import on stderr as it ends): mid-import, whatever the load."""
    env = {**os.environ, "PYTHONPROFILEIMPORTTIME": "1"}
    pre = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignored else None
    proc = subprocess.Popen([deint_script(), "--help"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=env, preexec_fn=pre)
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if marker in line:
            proc.send_signal(signal.SIGINT)
            break
    seen.append(proc.stderr.read())
    proc.wait(timeout=60)
    return proc.returncode, "".join(seen)


@pytest.mark.parametrize("marker", ["numpy", "gymnasium", "deint_env.episode"])
def test_ctrl_c_while_the_package_imports_is_one_line(marker):
    code, err = interrupted_at(marker)  # was a KeyboardInterrupt traceback, exit -2
    assert "Traceback" not in err and code in (130, 0), err[-2000:]
    if code == 130:
        said = [line for line in err.splitlines() if not line.startswith("import time:")]
        assert said == ["deint: interrupted"], err[-2000:]


def test_ctrl_c_that_an_import_turns_into_an_import_error_is_still_one_line(monkeypatch, capsys):
    """numpy's loader re-raises what interrupts the loading of a compiled module as an ImportError (a
    traceback 1 time in ~10 under load); once the handler has fired, any failed import means Ctrl-C.
    Simulated: the handler has fired and the import fails."""
    import deint_entry

    monkeypatch.setitem(sys.modules, "deint_env.cli", None)  # `from deint_env.cli import main`: ImportError
    monkeypatch.setattr(deint_entry, "_fired", [signal.SIGINT])
    before = signal.getsignal(signal.SIGINT)
    assert deint_entry.main() == 130
    assert signal.getsignal(signal.SIGINT) is before
    monkeypatch.setattr(deint_entry, "_fired", [])  # not interrupted: the import error is a real one
    with pytest.raises(ImportError):
        deint_entry.main()


def test_an_inherited_ignored_sigint_stays_ignored():
    code, err = interrupted_at("gymnasium", ignored=True)  # nohup, `deint ... &`: Ctrl-C is not for it
    assert code == 0 and "Traceback" not in err and "interrupted" not in err, err[-2000:]


# ---- a policy's act before its reset -----------------------------------------------------------------
OBS = {"toa": np.array([1.0]), "valid": np.int64(1)}


def episode():
    return deint_env.simulate(deint_env.resolve_scenario("paper-v0/mk94-two-var1"), 5)


@pytest.mark.parametrize("spec", ["fdp", "random", "mht", "cdif", "genie", "mht-tuned:suite=core-v0"])
def test_act_before_any_reset_says_to_reset_first(spec):
    policy = deint_env.make_policy(spec)
    with pytest.raises(DeintError, match=r"act\(obs\) before any reset: call reset\(priors, info\) first"):
        policy.act(OBS)  # was the policy's own AttributeError ('FDP' object has no attribute ...)


@pytest.mark.parametrize("spec", ["fdp", "random", "mht-tuned:suite=core-v0"])
def test_after_a_reset_act_is_the_policys_own(spec):
    policy = deint_env.make_policy(spec)
    first = play(policy, episode()).labels
    assert "act" not in vars(policy)  # the per-pulse path is the class's method, as before
    again = deint_env.make_policy(spec)
    assert play(again, episode()).labels.tolist() == first.tolist()


# ---- observations built by hand: make_policy(checked=True) -------------------------------------------
def checked(spec: str = "fdp"):
    policy = deint_env.make_policy(spec, checked=True)
    policy.reset(deint_env.Priors.from_json_dict({"period": [10.0, 22.0]}), {})
    return policy


@pytest.mark.parametrize("obs, says", [
    ({"valid": 1}, "obs has no 'toa'"),  # was KeyError: 'toa'
    ({"toa": np.array([1.0])}, "obs has no 'valid'"),  # was KeyError: 'valid'
    ({"toa": np.array([np.nan]), "valid": 1}, "obs['toa']=nan is invalid: a finite TOA"),  # was labelled silently
    ({"toa": np.array([np.inf]), "valid": 1}, "obs['toa']=inf is invalid: a finite TOA"),
    ({"toa": np.array(["x"]), "valid": 1}, "obs['toa']=array(['x']"),
    ({"toa": np.array([1.0, 2.0]), "valid": 1}, "an array of one TOA"),
    ({"toa": np.array([1.0]), "valid": 2}, "obs['valid']=2 is invalid: 0 or 1"),
    (None, "obs=None is invalid: a dict with 'toa' and 'valid'"),
])
def test_a_checked_policy_refuses_a_bad_observation(obs, says):
    with pytest.raises(DeintError, match="policy 'fdp': act\\(obs\\): ") as e:
        checked().act(obs)
    assert says in str(e.value)


def test_a_checked_policy_refuses_a_toa_before_the_last_one():
    policy = checked()
    policy.act({"toa": np.array([5.0]), "valid": 1})
    with pytest.raises(DeintError, match=r"obs\['toa'\]=1.0 is invalid: TOAs do not decrease \(the last one: 5.0\)"):
        policy.act({"toa": np.array([1.0]), "valid": 1})  # was labelled silently
    policy.reset(deint_env.Priors.from_json_dict({"period": [10.0, 22.0]}), {})
    policy.act({"toa": np.array([1.0]), "valid": 1})  # a new episode starts again


@pytest.mark.parametrize("spec", ["fdp", "mht-tuned:suite=core-v0"])
def test_a_checked_policy_labels_as_the_unchecked_one(spec):
    plain = play(deint_env.make_policy(spec), episode()).labels
    assert play(deint_env.make_policy(spec, checked=True), episode()).labels.tolist() == plain.tolist()


def test_checked_is_a_bool():
    with pytest.raises(DeintError, match="checked='yes' is invalid: True or False"):
        deint_env.make_policy("fdp", checked="yes")


# ---- simulate_many: a bound on the seeds of one call -------------------------------------------------
@pytest.mark.parametrize("seeds", [range(10**12), iter(range(10**12)), range(10**20)])
def test_simulate_many_refuses_more_than_a_million_seeds_up_front(seeds):
    spec = deint_env.resolve_scenario("paper-v0/mk94-two-var1")
    t0 = time.perf_counter()
    with pytest.raises(DeintError, match=r"at most 1000000 seeds a call"):
        deint_env.simulate_many(spec, seeds)  # was working through the 10^12 seeds, then memory
    assert time.perf_counter() - t0 < 10


@pytest.mark.parametrize("seeds", [5, None, b"ab", {1: 2}])
def test_simulate_many_refuses_seeds_that_are_no_sequence(seeds):
    spec = deint_env.resolve_scenario("paper-v0/mk94-two-var1")
    with pytest.raises(DeintError, match=r"seeds=.* is invalid: a sequence of integers"):
        deint_env.simulate_many(spec, seeds)  # TypeError: 'int' object is not iterable; b"ab" played seeds 97, 98


# ---- huge numbers on the command line ----------------------------------------------------------------
def test_a_huge_tune_budget_is_one_line(capsys):
    one_line(capsys, "tune", "fdp", "--suite", "core-v0", "--budget", BIG,  # was a search of every validation seed
             says=f"budget={BIG} is invalid: an integer in [1, 10^9] (episode plays)")


def test_a_huge_tune_eta_is_one_line(capsys):
    one_line(capsys, "tune", "fdp", "--suite", "core-v0", "--eta", BIG, "--budget", "50",
             says=f"eta={BIG} is invalid: an integer in [2, 1000]")


def test_a_huge_leaderboard_export_worker_count_is_one_line(capsys):
    one_line(capsys, "leaderboard", "export", "--suite", "core-v0", "--policy", "random", "-o", "x.csv",
             "--workers", BIG, says=f"workers={BIG} is invalid: an integer in [1, 1024]")  # was OverflowError (pool)
    assert not os.path.exists("x.csv")


@pytest.mark.parametrize("option", ["--timesteps", "--eval-every"])
def test_a_huge_train_step_count_is_one_line(capsys, option):
    pytest.importorskip("stable_baselines3")
    one_line(capsys, "train", "--suite", "core-v0", option, BIG, "--out", "t",  # was a run that trained on and on
             says=f"{option}={BIG} is invalid: at most 10^12 steps")
    assert not os.path.exists("t")


# ---- the terminal --------------------------------------------------------------------------------------
def test_help_on_an_ascii_stdout_is_printed(capsys, monkeypatch):
    raw = io.BytesIO()
    monkeypatch.setattr(sys, "stdout", io.TextIOWrapper(raw, encoding="ascii"))
    assert main(["plot", "--help"]) == 0  # was UnicodeEncodeError on the help's 'Δ' (PYTHONIOENCODING=ascii)
    sys.stdout.flush()
    assert b"\\u0394TOA" in raw.getvalue()


def test_a_usage_error_naming_10000_arguments_is_cut(capsys):
    code = main(["score", *["l.csv"] * 10_000, "--truth", "p.csv"])
    err = capsys.readouterr().err  # was one 60 KB line repeating every argument
    assert code == 2 and err.startswith("deint: error: unrecognized arguments: l.csv l.csv") and len(err) < 600, err


# ---- the Gymnasium API -------------------------------------------------------------------------------
@pytest.mark.parametrize("make", ["make", "make_vec"])
@pytest.mark.parametrize("options", [{"scenario": "paper-v0/mk94-three"}, [1]])
def test_reset_options_the_envs_do_not_take_are_refused(make, options):
    import gymnasium as gym

    env = gym.make("deint_env/Deinterleave-v0") if make == "make" else gym.make_vec("deint_env/Deinterleave-v0",
                                                                                     num_envs=2)
    with pytest.raises(DeintError, match=r"is invalid: these envs take no reset options \(None or \{\}\)"):
        env.reset(seed=1, options=options)  # was ignored: the default scenario played as if asked for
    a, _ = env.reset(seed=1, options={})
    b, _ = env.reset(seed=1)
    assert a["toa"].tolist() == b["toa"].tolist()


def test_a_dataset_tag_list_of_30000_is_cut_in_the_error_line(capsys, monkeypatch):
    pytest.importorskip("minari")
    monkeypatch.setenv("MINARI_DATASETS_PATH", "ds")
    err = one_line(capsys, "dataset", "deint/x-v0", "--suite", "core-v0", "--tags", ",".join(["x"] * 30_000),
                   says="no scenario of core-v0 has the tags ['x', 'x',")
    assert len(err) < 400, len(err)  # was one 150 KB line


def test_evaluate_refuses_a_scenario_named_twice():
    with pytest.raises(DeintError, match="scenarios names 'paper-v0/mk94-two-var1' twice; name each scenario once"):
        deint_env.evaluate("random", scenarios=["paper-v0/mk94-two-var1"] * 2, max_seeds=1, progress=False)

"""Hostile inputs, round five (docs/hostile-round5.md): `deint train` seeds and hyper-parameter files read
without checks, float options that float() alone read, empty folder options taken as the current
directory, PDWs whose squared distances overflow, coincident pulses in the PDW pipeline, ΔTOAs too spread
for a log axis, scenario descriptors drawn as inf, a leaderboard file whose spaced adapter spec was run,
outputs ending in '/.', token actions outside the action space, and API calls that took wrong values."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from deint_env.cli import main

TRAIN = ["train", "--scenario", "paper-v0/mk94-two-var1", "--timesteps", "64", "--n-envs", "1", "--eval-every", "64",
         "--eval-episodes", "1", "--no-progress", "-o", "run"]


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def one_line(capsys, *argv, says: str, out: str = "run") -> str:
    """`deint ARGV` exits 2 with one error line (its last) holding `says`, and writes no `out`."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and err.count("deint: error: ") == 1 and err.endswith("\n") and says in err, err
    assert err.splitlines()[-1].startswith("deint: error: "), err
    assert not os.path.exists(out)
    return err


# ---- deint train -------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, says", [
    (["--seed", "-1"], "--seed=-1 is invalid: an integer in [0, 2^32)"),  # numpy's ValueError, a traceback
    (["--seed", str(2**32)], "--seed=4294967296 is invalid"),
    (["--eval-episodes", str(10**12)], "--eval-episodes=1000000000000 is invalid: an integer in [1, 10000]"),
    (["--time-budget", "1_0"], "argument --time-budget: invalid float value: '1_0'"),  # was 10 s
    (["--time-budget", "\u0661"], "invalid float value"),
])
def test_train_options_are_checked(capsys, argv, says):
    pytest.importorskip("stable_baselines3")
    one_line(capsys, *TRAIN, *argv, says=says)


@pytest.mark.parametrize("yaml, says", [
    ("default:\n  n_timesteps: lots\n", "n_timesteps='lots' is invalid: an integer in [1, 1e+15]"),  # traceback
    ("default:\n  max_tracks: -3\n", "max_tracks=-3 is invalid: an integer in [1, 256]"),  # was silently 2
    ("default:\n  max_tracks: eight\n", "max_tracks='eight' is invalid"),
    ("default:\n  policy_kwargs: [1, 2]\n", "policy_kwargs=[1, 2] is invalid: a mapping"),
    ("default:\n  policy_kwargs:\n    d_model: 1000000000\n", "policy_kwargs.d_model=1000000000 is invalid"),  # 88 GB
    ("default:\n  policy_kwargs:\n    net_arch: [100000000]\n", "policy_kwargs.net_arch=[100000000] is invalid"),
    ("default:\n  policy_kwargs:\n    heads: 3\n", "policy_kwargs.heads=3 is invalid: a divisor of d_model=64"),
    (b"default:\n  n\xff: 1\n", "h.yml: is not UTF-8 text"),
])
def test_a_hyperparameter_file_is_checked_before_training(capsys, yaml, says):
    pytest.importorskip("stable_baselines3")
    with open("h.yml", "wb") as f:  # short runs where the code before the fixes trained on
        f.write(yaml if isinstance(yaml, bytes) else (yaml + ("" if "n_timesteps" in yaml else
                                                              "  n_timesteps: 64\n  n_envs: 1\n")).encode())
    one_line(capsys, *TRAIN[:3], *TRAIN[5:], "--hyperparams", "h.yml", says=says)  # no --timesteps: the file's


@pytest.mark.parametrize("entry, says", [
    ("batch_size: 0", "batch_size=0 is invalid: an integer in [1, 1e+06]"),  # range() arg 3 must not be zero
    ("rollout_steps: many", "rollout_steps='many' is invalid"),
    ("buffer: many", "buffer='many' is invalid"),
    ("learning_rate: -1", "learning_rate=-1 is invalid: a number in (0, 1]"),
])
def test_dagger_hyperparameters_are_checked(capsys, entry, says):
    pytest.importorskip("stable_baselines3")
    with open("h.yml", "w") as f:
        f.write(f"default:\n  {entry}\n  n_envs: 1\n")
    one_line(capsys, *TRAIN, "--algo", "dagger", "--hyperparams", "h.yml", says=f"dagger hyper-parameters: {says}")


def test_a_learning_rate_torch_refuses_is_one_line(capsys):
    pytest.importorskip("stable_baselines3")
    with open("h.yml", "w") as f:
        f.write("default:\n  learning_rate: .nan\n")
    one_line(capsys, *TRAIN, "--hyperparams", "h.yml", says="hyper-parameters 'default' for maskable-ppo: ",
             out="run/last.safetensors")


# ---- empty folder options ----------------------------------------------------------------------------
@pytest.mark.parametrize("argv, opt", [
    (["tune", "fdp", "--suite", "paper-v0", "--out", "t.json", "--work", ""], "--work"),  # played into ./
    (["reproduce", "mk94-fig3", "--quick", "--out", ""], "--out"),
    (["leaderboard", "--suite", "blind-v0", "--policy", "random", "--root", ""], "--root"),
    (["leaderboard", "submit", "--suite", "blind-v0", "--root", "", "s.jsonl"], "--root"),
    (["dataset", "deint/x-v0", "--scenario", "paper-v0/mk94-two-var1", "--root", ""], "--root"),
    (["train", "--scenario", "paper-v0/mk94-two-var1", "-o", ""], "-o"),
])
def test_an_empty_folder_is_refused(capsys, argv, opt):
    if argv[0] in ("dataset", "train"):
        pytest.importorskip("minari" if argv[0] == "dataset" else "stable_baselines3")
    one_line(capsys, *argv, says=f"{opt} '': the path is empty; give a folder name")
    assert os.listdir(".") == []


# ---- PDWs and ΔTOAs beyond what the policies and the plot can hold -----------------------------------
def _pdw_file(path, **columns):
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    n = 200
    cols = {"toa": np.cumsum(rng.uniform(1, 10, n)), "frequency": rng.uniform(9000, 9100, n),
            "pulse_width": rng.uniform(1, 2, n), "angle_of_arrival": rng.uniform(0, 360, n),
            "amplitude": rng.uniform(1, 2, n)}
    cols.update(columns)
    with h5py.File(path, "w") as f:
        f.create_dataset("data", data=np.stack([np.broadcast_to(v, n) for v in cols.values()], axis=1))
        f.create_dataset("labels", data=rng.integers(0, 3, n))
        f.create_group("metadata").create_dataset("feature_names", data=np.array([k.encode() for k in cols]))


@pytest.mark.parametrize("policy, column, value", [
    ("pdw-hdbscan", "frequency", 1e300),  # 46 s, then killed at 4 GB: HDBSCAN on inf distances
    ("pdw-pipeline", "pulse_width", 1e308),  # > 60 s
    ("pdw-hdbscan:scale=robust", "amplitude", 1e307),
])
def test_pdws_whose_squares_overflow_are_one_line(capsys, policy, column, value):
    _pdw_file("x.h5", **{column: value})
    one_line(capsys, "label", "x.h5", "--policy", policy, "--n-sources", "3", "-o", "l.csv", out="l.csv",
             says=f"has {column.replace('angle_of_arrival', 'aoa')}={value!r}; the pdw-* policies cluster TOAs and "
                  f"descriptors of magnitude up to 1e+150")


def test_the_pdw_pipeline_takes_coincident_pulses(capsys):
    _pdw_file("x.h5", toa=5.0)  # was math.log(0): a ValueError traceback
    assert main(["label", "x.h5", "--policy", "pdw-pipeline", "--n-sources", "3", "-o", "l.csv"]) == 0


def test_dtoas_too_spread_for_a_log_axis_are_one_line(capsys):
    pytest.importorskip("matplotlib")
    with open("x.csv", "w") as f:
        f.write("toa\n0\n1\n2\n1e290\n")  # ΔTOAs over 290 decades: matplotlib's OverflowError
    err = one_line(capsys, "plot", "x.csv", "-o", "o.png", out="o.png",
                   says="x.csv: its ΔTOAs run from 1 to 1e+290, too wide a range for a log axis")
    assert "Warning" not in err


def test_leaderboard_all_with_no_board_under_root_says_so(capsys):
    os.makedirs("lb/zzz-v0")  # a folder, but no known suite's leaderboard.json: --all did nothing, silently
    with open("lb/zzz-v0/leaderboard.json", "w") as f:
        f.write("{}")
    one_line(capsys, "leaderboard", "--all", "--root", "lb", "--no-progress", out="lb/blind-v0",
             says="--root lb: holds no published leaderboard")


def test_a_pareto_plot_with_nothing_to_draw_warns_nothing():
    """A board of submitted entries only (no lag, no timing) printed matplotlib's "No artists with labels
    found to put in legend" on a successful `deint leaderboard submit`."""
    import warnings

    pytest.importorskip("matplotlib")
    from deint_env.leaderboard.plots import pareto

    row = {"division": "offline", "oracle": False, "coverage": 1.0, "lag": None, "us_per_pulse": None,
           "score_mean": 0.5, "policy": "x (submitted)"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pareto("blind-v0", [row]).startswith(b"\x89PNG")


# ---- scenario files: descriptors drawn beyond float64, a drift that overflowed the check -------------
PDW_SOURCE = {"period": 100.0, "descriptors": {"frequency": 9000.0, "pulse_width": 1.0}}


@pytest.mark.parametrize("descriptors, receiver, says", [
    ({"frequency_std": 1e308}, None, "descriptors.frequency_std=1e+308 is invalid: a number in [0, 1e+30]"),
    ({"frequency_hops": [0.0, -20000.0]}, None,
     "descriptors.frequency_hops=[0.0, -20000.0] is invalid: offsets that keep every frequency positive"),  # accepted
    ({"pulse_width_levels": [1.0, 1e308]}, None, "at least two positive numbers of magnitude at most 1e+30"),
    ({"scan": "circular", "scan_period": 1e-300}, None,
     "descriptors.scan_period=1e-300 is invalid: circular scan needs a period >= 1e-09"),  # NaN amplitudes
    ({}, {"frequency_noise_std": 1e308}, "receiver.frequency_noise_std=1e+308 is invalid: a number in [0, 1e+30]"),
])
def test_descriptors_that_would_be_drawn_as_inf_are_refused(capsys, descriptors, receiver, says):
    source = {**PDW_SOURCE, "descriptors": {**PDW_SOURCE["descriptors"], **descriptors}}
    spec = {"name": "x", "n_pulses": 100, "amplitudes": True, "sources": [source],
            **({"receiver": receiver} if receiver else {})}
    with open("s.json", "w") as f:
        json.dump(spec, f)  # was written, then refused by the TDC writer ("data[65, 1] = -inf"), or not at all
    err = one_line(capsys, "simulate", "s.json", "--seed", "1", "-o", "o.h5", out="o.h5", says=says)
    assert err.startswith("deint: error: s.json: descriptors.") or err.startswith("deint: error: s.json: receiver.")


def test_a_drift_whose_power_overflows_is_one_line(capsys):
    with open("s.json", "w") as f:  # 1.1 ** 100000 was an OverflowError traceback before the 100-fold check
        json.dump({"name": "x", "n_pulses": 100000, "sources": [
            {"period": 10.0, "modulation": {"kind": "drifting", "alpha": 1.1}}]}, f)
    one_line(capsys, "simulate", "s.json", "--seed", "1", "-o", "o.csv", out="o.csv",
             says="modulation.alpha=1.1 is invalid: the period may change at most 100-fold")


@pytest.mark.parametrize("scenarios", [",,,", "mk94-two-var1,,mk94-three", " "])
def test_tune_scenarios_naming_nothing_are_refused(capsys, scenarios):
    one_line(capsys, "tune", "fdp", "--suite", "paper-v0", "--scenarios", scenarios, "--out", "t.json",
             out="t.json", says=f"--scenarios={scenarios!r} is invalid: scenario names separated by commas")  # all


def test_a_numpy_integer_cycle_is_taken_as_an_int():
    from deint_env.scenario import Modulation

    m = Modulation(kind="sliding", depth=0.2, cycle=np.int64(10))  # was refused: not an int
    assert m.cycle == 10 and type(m.cycle) is int and m == Modulation(kind="sliding", depth=0.2, cycle=10)


# ---- a leaderboard file that names code to run -------------------------------------------------------
@pytest.mark.parametrize("spec", [" tdc:model=this:s", "tdc :model=this:s"])
def test_a_leaderboard_file_names_no_adapter_however_spaced(capsys, spec):
    import sys

    assert main(["leaderboard", "--suite", "blind-v0", "--policy", "random", "--max-seeds", "1", "--root", "lb",
                 "--reps", "100", "--no-progress"]) == 0
    with open("lb/blind-v0/leaderboard.json") as f:
        board = json.load(f)
    board["rows"][0]["policy"] = spec  # ' tdc' passed the adapter check, then played as tdc: `import this` ran
    with open("lb/blind-v0/leaderboard.json", "w") as f:
        json.dump(board, f)
    capsys.readouterr()
    sys.modules.pop("this", None)
    one_line(capsys, "leaderboard", "--all", "--root", "lb", "--reps", "100", "--no-progress", out="nothing",
             says=f"records {spec!r}, whose parameters name code to import")
    assert "this" not in sys.modules


# ---- outputs and the Python API ----------------------------------------------------------------------
@pytest.mark.parametrize("out", ["l.csv/.", "sub/.."])
def test_an_output_whose_last_part_is_a_dot_is_refused(capsys, out):
    with open("p.csv", "w") as f:
        f.write("toa\n" + "".join(f"{1.0 + 10 * i}\n" for i in range(30)))
    os.makedirs("sub")
    one_line(capsys, "label", "p.csv", "--policy", "random", "--n-sources", "2", "-o", out, out="l.csv",
             says=f"cannot write {out}: it names a directory")  # `l.csv/.` wrote l.csv


@pytest.mark.parametrize("action", [9, -1, 1.0, True, np.array([10**6])])
def test_a_token_action_outside_the_space_is_refused(action):
    import gymnasium as gym

    from deint_env.errors import DeintError

    env = gym.make("deint_env/DeinterleaveTokens-v0")
    env.reset(seed=0)
    with pytest.raises(DeintError, match=r"action=.* is invalid: a track in \[0, 8\] \(8 = spurious\)"):
        env.step(action)  # was taken as spurious


def test_token_vector_actions_are_checked():
    import gymnasium as gym

    from deint_env.errors import DeintError

    env = gym.make_vec("deint_env/DeinterleaveTokens-v0", num_envs=2)
    env.reset(seed=0)
    for actions in (np.array([0, 9]), np.zeros(3, int), np.array([0.5, 1.0])):
        with pytest.raises(DeintError, match=r"is invalid: 2 tracks in \[0, 8\]"):
            env.step(actions)


def _api_calls():
    import deint_env
    from deint_env import formats
    from deint_env.policies import register_policy

    with open("p.csv", "w") as f:
        f.write("toa\n1.0\n2.0\n")
    with open("l.csv", "w") as f:
        f.write("toa,label\n1.0,0\n2.0,-1\n")
    toa = np.array([1.0, 2.0])
    return [
        (lambda: deint_env.simulate(None, 1), "spec=None is invalid: a ScenarioSpec"),  # AttributeError
        (lambda: formats.write_pulses("o.csv", None), "episode=None is invalid: an Episode"),  # AttributeError
        (lambda: formats.write_labels("o.csv", np.array([np.nan, 1.0]), np.zeros(2, int), 2),
         "toa=nan is not finite"),  # written, then refused by the reader
        (lambda: formats.read_labels("l.csv", toa, 2.5), "n_labels=2.5 is invalid"),  # accepted
        (lambda: formats.read_pulses("p.csv", None), "priors=None is invalid: a Priors"),  # accepted
        (lambda: formats.read_pulses("p.csv", {"period": [1.0]}), "priors={'period': [1.0]} is invalid"),
        (lambda: deint_env.evaluate("random", scenarios=["paper-v0/mk94-two-var1"], max_seeds=1, progress="no"),
         "progress='no' is invalid: True or False"),  # accepted
        (lambda: deint_env.evaluate(type(deint_env.make_policy("random")), scenarios=["paper-v0/mk94-two-var1"],
                                    max_seeds=1, progress=False), "is a class; pass a policy object"),  # played
        (lambda: register_policy("bad name", "os:system"), "the name is invalid"),  # accepted
        (lambda: register_policy("fdp", "os:system"), "policy name 'fdp' is registered twice"),  # until first use
    ]


@pytest.mark.parametrize("i", range(10))
def test_api_calls_with_wrong_values_raise_one_clear_error(i):
    from deint_env import policies
    from deint_env.errors import DeintError

    call, says = _api_calls()[i]
    saved, loaded = dict(policies._REGISTRY), policies._builtins_loaded
    if i == 9:  # a fresh process: nothing registered yet, as in a notebook's first cell
        policies._REGISTRY.clear()
        policies._builtins_loaded = False
    try:
        with pytest.raises((DeintError, ValueError, TypeError)) as e:
            call()
    finally:
        policies._REGISTRY.clear()
        policies._REGISTRY.update(saved)
        policies._builtins_loaded = loaded
    assert says in str(e.value) and "\n" not in str(e.value)
    assert not os.path.exists("o.csv")

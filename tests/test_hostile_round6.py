"""Hostile inputs, round six (docs/hostile-round6.md): a results file whose records are separated by CRs
alone cut off as a torn line, results records with values no run writes (a negative seed, an accuracy of
2.5) averaged into summaries, TDC emitter ids that wrap round as int64, outputs that replace read-only
files, policies reset with priors that are no `Priors`, and Gymnasium seeds (numpy integers, negative,
fractional) that reached gymnasium's own seeding error."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from deint_env.cli import main
from hostile_cli import one_line

RUN = ["run", "--scenario", "paper-v0/mk94-two-var1", "--policy", "random", "--max-seeds", "2", "--no-progress",
       "--out", "r.jsonl"]


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def two_records(capsys):
    """r.jsonl with the two records of RUN, and their text."""
    assert main(RUN) == 0
    capsys.readouterr()
    with open("r.jsonl", "rb") as f:
        return f.read()


# ---- results files -----------------------------------------------------------------------------------
def test_records_separated_by_crs_alone_are_not_cut_off(capsys, two_records):
    with open("r.jsonl", "wb") as f:
        f.write(two_records.replace(b"\n", b"\r"))  # was read as one torn line and truncated to nothing
    one_line(capsys, *RUN, says="r.jsonl: is not a results file (its last line is not a record)")
    with open("r.jsonl", "rb") as f:
        assert f.read() == two_records.replace(b"\n", b"\r")


def test_a_torn_last_record_is_still_repaired(capsys, two_records):
    with open("r.jsonl", "wb") as f:
        f.write(two_records[:-40])  # a run killed mid-write: the torn line goes, the episode is played again
    assert main(RUN) == 0
    with open("r.jsonl", "rb") as f:
        text = f.read()
    assert text.startswith(two_records.splitlines(keepends=True)[0])
    assert [json.loads(line)["seed"] for line in text.splitlines()] == [1000000, 1000001]


@pytest.mark.parametrize("field, value, says", [
    ("seed", -5, "field 'seed' is -5; a run writes values in [0, 2^63)"),  # was kept, and its seed played again
    ("accuracy", 2.5, "field 'accuracy' is 2.5; a run writes values in [0, 1]"),  # was averaged into the summary
    ("accuracy", -1, "field 'accuracy' is -1; a run writes values in [0, 1]"),
    ("ari", -3.0, "field 'ari' is -3.0; a run writes values in [-1, 1]"),
    ("n_pulses", -500, "field 'n_pulses' is -500; a run writes values >= 0"),
    ("pe", [0.1, 7.0], "field 'pe' is [0.1, 7.0]; a run writes values in [0, 1]"),
    ("us_per_pulse", -2.0, "field 'us_per_pulse' is -2.0; a run writes values >= 0"),
])
def test_a_record_value_no_run_writes_is_refused(capsys, two_records, field, value, says):
    lines = two_records.decode().splitlines()
    record = json.loads(lines[1])
    record[field] = value
    with open("r.jsonl", "w") as f:
        f.write(lines[0] + "\n" + json.dumps(record) + "\n")
    one_line(capsys, *RUN, says=f"r.jsonl: line 2: {says}")


# ---- TDC emitter ids ---------------------------------------------------------------------------------
@pytest.mark.parametrize("dtype, value", [("u8", 2**63 + 5), ("f8", 1e30), ("f8", -1e19)])
def test_tdc_emitter_ids_beyond_int64_are_refused(capsys, dtype, value):
    h5py = pytest.importorskip("h5py")
    toa = np.arange(1.0, 51.0)
    labels = (np.arange(50) % 2).astype(dtype)
    labels[3] = value  # astype(int64) wrapped it round: a real emitter read as noise (a negative id)
    with h5py.File("x.h5", "w") as f:
        f.create_dataset("data", data=toa[:, None])
        f.create_dataset("labels", data=labels)
        f.create_group("metadata").create_dataset("feature_names", data=np.array([b"time_of_arrival"]))
    with open("l.csv", "w") as f:
        f.write("toa,label\n" + "".join(f"{t!r},0\n" for t in toa))
    one_line(capsys, "score", "--truth", "x.h5", "l.csv", says="x.h5: labels[3] = ")
    err = one_line(capsys, "tdc", "convert", "x.h5", "o.csv", says="emitter ids are integers in [-2^63, 2^63)")
    assert not os.path.exists("o.csv"), err


# ---- read-only outputs -------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, out", [
    (["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o", "o.csv"], "o.csv"),
    (["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o", "o.h5"], "o.h5"),
    (["tdc", "convert", "o.csv", "o.h5"], "o.h5"),
])
def test_an_output_over_a_read_only_file_is_refused(capsys, argv, out):
    if out.endswith(".h5"):
        pytest.importorskip("h5py")
    if argv[0] == "tdc":
        assert main(["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o", "o.csv"]) == 0
    with open(out, "w") as f:
        f.write("keep\n")
    os.chmod(out, 0o444)  # renamed over (or appended to, as root) all the same
    one_line(capsys, *argv, says=f"cannot write {out}: it is read-only (mode 0444); make it writable or write "
                                 f"elsewhere")
    with open(out) as f:
        assert f.read() == "keep\n"
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o444


def test_a_read_only_results_file_is_not_appended_to(capsys, two_records):
    os.chmod("r.jsonl", 0o444)  # as root, appending worked
    one_line(capsys, *RUN, "--max-seeds", "3", says="cannot write r.jsonl: it is read-only (mode 0444)")
    with open("r.jsonl", "rb") as f:
        assert f.read() == two_records


# ---- the Python API ----------------------------------------------------------------------------------
@pytest.mark.parametrize("policy", ["fdp", "random", "renewal-ml"])
@pytest.mark.parametrize("priors", [None, "info"])
def test_a_policy_reset_with_priors_that_are_no_priors_is_a_type_error(policy, priors):
    import gymnasium as gym

    import deint_env

    env = gym.make("deint_env/MK94-TwoSources-v0")
    obs, info = env.reset(seed=1)
    pol = deint_env.make_policy(policy)
    with pytest.raises(TypeError, match=r"priors=(NoneType|dict) is invalid: a deint_env.Priors"):
        pol.reset(info["priors"] if priors == "info" else None, info)  # an AttributeError deep inside
    pol.reset(deint_env.Priors.from_info(info["priors"]), info)  # still plays
    assert isinstance(pol.act(obs), (int, np.integer))


def test_a_numpy_integer_seed_resets_as_the_same_int():
    import gymnasium as gym

    import deint_env  # noqa: F401

    env = gym.make("deint_env/MK94-TwoSources-v0")
    a, _ = env.reset(seed=np.int64(3))  # was gymnasium's "Seed must be a python integer"
    b, _ = env.reset(seed=3)
    assert a["toa"].tolist() == b["toa"].tolist()


@pytest.mark.parametrize("seed", [-1, 1.5, np.int8(-3), "3"])
def test_an_invalid_env_seed_is_one_deint_error(seed):
    import gymnasium as gym

    from deint_env.errors import DeintError

    env = gym.make("deint_env/MK94-TwoSources-v0")
    with pytest.raises(DeintError, match=r"is invalid: an integer in \[0, 2\^63\)"):
        env.reset(seed=seed)  # was gymnasium.error.Error, neither a DeintError nor a ValueError


# ---- long file names ---------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, name", [
    (["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o"], "b" * 250 + ".csv"),  # its temporary: 264 bytes
    (["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o"], "é" * 125 + ".h5"),
    (RUN[:-1], "c" * 248 + ".jsonl"),  # its lock file .NAME.lock: 260 bytes
])
def test_an_output_name_of_up_to_255_bytes_is_written(capsys, argv, name):
    if name.endswith(".h5"):
        pytest.importorskip("h5py")
    assert len(os.fsencode(name)) <= 255
    assert main([*argv, name]) == 0, capsys.readouterr().err  # was 'cannot write ...: File name too long'
    assert sorted(os.listdir(".")) == [name]


def test_a_policy_reset_straight_from_make_policy_is_no_error():
    import deint_env

    priors = deint_env.Priors.from_json_dict({"period": [10.0, 22.0]})
    deint_env.make_policy("fdp").reset(priors, {})  # was "TypeError: 'NoneType' object is not callable"
    deint_env.make_policy("random").reset(priors, {"policy_seed": 0})


@pytest.mark.parametrize("policy", ["dokf", "pt-post", "pt-prior"])
def test_a_prior_period_deviation_beyond_the_filter_is_one_line(capsys, policy):
    """period_std 1e30 (or 1e12) of a period of 10: the filter's variances cancelled to negative ones and dokf's
    start beam took the log of one (`ValueError: math domain error`); the others labelled from that filter."""
    with open("p.csv", "w") as f:
        f.write("toa\n" + "".join(f"{t}\n" for t in sorted([1.0 + 10 * i for i in range(30)]
                                                             + [2.5 + 22 * i for i in range(14)])))
    with open("x.json", "w") as f:
        json.dump({"period": [10.0, 22.0], "phase": [1.0, 2.0], "period_std": [1e12, 1.0], "jitter_std": 1.0}, f)
    one_line(capsys, "label", "p.csv", "--policy", policy, "--priors", "x.json", "-o", "o.csv",
             says="prior period_std[0]=1e+12 is beyond what the PT's filter holds: at most 1e+06 times the period (10)")
    assert not os.path.exists("o.csv")

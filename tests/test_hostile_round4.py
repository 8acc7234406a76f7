"""Hostile inputs, round four (docs/hostile-round4.md): numbers only int()/float() read on the command line,
priors keys that were silently dropped, modulations and channels too large to build, quoted CSV cells that
ran over lines, error lines that echoed megabytes, TOAs and phases beyond what a policy can count or square,
and outputs refused only after the work was done."""

from __future__ import annotations

import json
import os

import pytest

from deint_env.cli import main
from deint_env.episode import Priors
from deint_env.errors import DeintError, check
from deint_env.formats import read_pulse_table
from deint_env.policies import make_policy
from deint_env.scenario import ScenarioSpec

PRIORS = {"period": [10.0, 22.0], "phase": [1.0, 2.0], "jitter_std": 1.0}
TOAS = sorted([1.0 + 10 * i for i in range(30)] + [2.5 + 22 * i for i in range(14)])
PULSES = "toa\n" + "".join(f"{t}\n" for t in TOAS)


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with open("p.csv", "w") as f:
        f.write(PULSES)
    with open("pr.json", "w") as f:
        json.dump(PRIORS, f)


def one_line(capsys, *argv, says: str, out: str = "l.csv") -> str:
    """`deint ARGV` exits 2 with one error line holding `says`, and writes no `out`."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("deint: error: ") and says in err, err
    assert not os.path.exists(out)
    return err


# ---- numbers on the command line -------------------------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "l.csv", "--seed", "1_000"],
    ["label", "p.csv", "--policy", "random", "--n-sources", "\u0663", "-o", "l.csv"],  # ARABIC-INDIC THREE
    ["run", "--scenario", "paper-v0/mk94-two-var1", "--policy", "random", "--max-seeds", "1_0"],
])
def test_int_options_take_decimal_digits_only(capsys, argv):
    one_line(capsys, *argv, says="invalid int value")


@pytest.mark.parametrize("periods", ["1_0,22", "\u0661\u0660,22"])
def test_prior_periods_take_decimal_numbers_only(capsys, periods):
    one_line(capsys, "label", "p.csv", "--policy", "fdp", "--prior-periods", periods, "-o", "l.csv",
             says=f"--prior-periods={periods!r} is invalid: comma-separated positive numbers")


def test_the_largest_seed_a_range_allows_is_allowed():
    assert make_policy("random:seed=9223372036854775807").seed == 2**63 - 1  # float(2^63 - 1) is 2^63
    with pytest.raises(DeintError, match=r"seed=9223372036854775808' .* is out of range"):
        make_policy("random:seed=9223372036854775808")


# ---- priors keys that were dropped ---------------------------------------------------------------------
@pytest.mark.parametrize("d, says", [
    ({"blind": True, "label_budget": 3, "period": [10.0]}, "period is for anchored priors"),
    ({"blind": True, "label_budget": 3, "phase": [1.0]}, "phase is for anchored priors"),
    ({"period": [10.0, 22.0], "phase_std": [1.0, 1.0]}, "phase_std needs phase"),
    ({**PRIORS, "amplitude_std": [1.0, 1.0]}, "amplitude_std needs amplitude"),
])
def test_priors_keys_are_never_dropped_silently(d, says):
    with pytest.raises(DeintError, match=f"f.json: {says}"):
        Priors.from_json_dict(d, where="f.json")


# ---- sizes declared in a modulation or a channel -------------------------------------------------------
@pytest.mark.parametrize("mod, says", [
    ({"kind": "stagger", "pattern": [1.0 + i / 100 for i in range(65)]},
     "needs at least two (at most 64) positive PRI multipliers"),
    ({"kind": "random_stagger", "pattern": [1.0 + i / 2000 for i in range(2000)],
      "transition": [[1 / 2000] * 2000] * 2000}, "(at most 64)"),  # was minutes of matrix powers
    ({"kind": "sliding", "depth": 0.5, "cycle": 10**18}, "an integer >= 2 and <= 1e+06"),
    ({"kind": "dwell_switch", "pattern": [1.0, 1.5], "cycle": 10**18}, "an integer >= 2 and <= 1e+06"),
    ({"kind": "sinusoidal", "depth": 0.5, "cycle": 1e300}, "a number >= 2 and <= 1e+06"),
    ({"kind": "dwell_switch", "pattern": [1.0, 1.5], "dwells": [10**6, 10**6]}, "1e+06 in all at most"),
    ({"kind": "drifting", "drift_std": 1e300}, "drift_std=1e+300 is invalid: a number in [0, 1e+30]"),
])
def test_a_modulation_too_large_to_build_is_one_line(capsys, mod, says):
    with open("m.json", "w") as f:
        json.dump({**PRIORS, "modulation": [mod, None]}, f)
    err = one_line(capsys, "label", "p.csv", "--policy", "agile-kf", "--priors", "m.json", "-o", "l.csv", says=says)
    assert len(err) < 500  # the 2000-level pattern is not repeated in full


def test_a_waveform_channel_is_bounded():
    spec = {"name": "x", "sources": [{"period": 10.0}], "n_pulses": 10,
            "waveform": {"sample_period": 0.1, "numerator": [1.0] * 10**5, "denominator": [1.0]}}
    with pytest.raises(DeintError, match=r"waveform.numerator=.* is invalid: 1 to 16 coefficients"):
        ScenarioSpec.from_dict(spec)


def test_a_missing_scenario_field_is_named():
    with pytest.raises(DeintError, match="scenario: field 'sources' is required; required: sources, n_pulses"):
        ScenarioSpec.from_dict({"name": "x"})


def test_error_lines_cut_long_values():
    with pytest.raises(DeintError) as e:
        check(False, "x", list(range(10**5)), "short")
    assert len(str(e.value)) < 250 and str(e.value).endswith("... is invalid: short")


# ---- pulse CSV -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, says", [
    ('toa\n"1\n5"\n7\n', "line 2: a quoted cell spans several lines"),  # was read as 15
    ('toa\n"1.0\n3.0\n', "unexpected end of data"),  # an open quote swallowed the rest of the file
    ("toa\n" + "1" * 10**6 + "\n", "toa=" + "1" * 200 + " is not finite"),
    ("\x1b[2J\n1\n", r"columns found: ['\x1b[2J']"),  # a terminal escape is shown, not sent
])
def test_csv_cells_are_read_and_shown_as_written(text, says):
    with open("x.csv", "w") as f:
        f.write(text)
    with pytest.raises(DeintError) as e:
        read_pulse_table("x.csv")
    assert says in str(e.value) and len(str(e.value)) < 400 and "\x1b" not in str(e.value)


# ---- paths ---------------------------------------------------------------------------------------------
def test_an_empty_output_path_is_refused(capsys):
    one_line(capsys, "simulate", "paper-v0/mk94-two-var1", "--seed", 1, "-o", "", says="the path is empty")


@pytest.mark.parametrize("path, says", [("f.json", "f.json: is not a regular file"),
                                        ("/dev/zero", "/dev/zero: is not a regular file")])
def test_a_scenario_that_is_no_regular_file_says_so(capsys, path, says):
    if path == "f.json":
        os.mkfifo(path)
    one_line(capsys, "simulate", path, "--seed", 1, "-o", "out.csv", says=says, out="out.csv")


def test_an_output_that_cannot_be_written_is_refused_before_playing(capsys, monkeypatch):
    import deint_env.leaderboard as board

    monkeypatch.setattr(board, "export", lambda *a, **k: pytest.fail("played before checking -o"))
    one_line(capsys, "leaderboard", "export", "--suite", "core-v0", "--policy", "random", "-o", ".",
             says="cannot write .: it is a directory")


# ---- what a policy cannot count or square --------------------------------------------------------------
@pytest.mark.parametrize("policy, pulses, priors, says", [
    ("dokf", "toa\n1.0\n2.0\n1e300\n", PRIORS, "lies 1e+299 periods (10) past track 0's last arrival"),
    ("pt-post", PULSES, {**PRIORS, "period": [1e-30, 22.0]}, "at most 2^53 can be counted"),
    ("genie", PULSES, {**PRIORS, "phase": [1e30, 2.0]}, "genie: phases up to 1e+30 are stored in float64 steps"),
    ("sdif", "toa\n" + "".join(f"{i * 1e298!r}\n" for i in range(100)), None,
     "the blind PRI analysis handles TOAs up to 1e+30"),
    ("pri-transform", "toa\n" + "".join(f"{i * 1e298!r}\n" for i in range(100)), None,
     "the blind PRI analysis handles TOAs up to 1e+30"),
    ("renewal-ml", "toa\n" + "".join(f"{i * 1e298!r}\n" for i in range(100)), None,
     "blind RenewalML measures the TOA noise on TOAs up to 1e+30"),
    ("pri-transform:pri_min=1e-9", PULSES, None, "need more than 1000000 PRI bins; raise pri_min"),
])
def test_a_scene_beyond_the_policy_is_one_line(capsys, policy, pulses, priors, says):
    with open("x.csv", "w") as f:
        f.write(pulses)
    with open("x.json", "w") as f:
        json.dump(priors, f)
    one_line(capsys, "label", "x.csv", "--policy", policy, *(["--priors", "x.json"] if priors else []), "-o", "l.csv",
             says=says)


def test_genie_labels_coincident_emissions_without_noise(capsys):
    with open("g.json", "w") as f:  # 300 sources all at phase 0: the schedule's median spacing is 0
        json.dump({"period": [10.0 + i for i in range(300)], "phase": [0.0] * 300}, f)
    assert main(["label", "p.csv", "--policy", "genie", "--priors", "g.json", "-o", "l.csv"]) == 0


@pytest.mark.parametrize("spec, says", [
    ("mht:look_start=100", "look_start=100 is invalid: an integer in [0, 20]"),  # did not end in 200 s
    ("lmht:look=100000", "look=100000 is invalid: an integer in [0, 20]"),
    ("tree:max_pulses=200,max_nodes=9223372036854775807", "an integer in [1, 2000000]"),  # GBs a million nodes
])
def test_search_sizes_are_bounded_before_the_search(spec, says):
    with pytest.raises(DeintError) as e:
        make_policy(spec)
    assert str(e.value).startswith(f"policy '{spec}': ") and says in str(e.value)


def test_evaluate_names_an_unknown_suite_as_a_suite():
    import deint_env

    with pytest.raises(DeintError, match="suite 'nope' is unknown; known suites: "):  # was "scenario 'nope'"
        deint_env.evaluate("random", suite="nope", max_seeds=1, progress=False)


@pytest.mark.parametrize("info, says", [
    ({"n_labels": 2, "period": "abc"}, "period='abc' must be an array of numbers"),  # was numpy's ValueError
    ({"n_labels": 2, "period": [float("nan"), 1.0]}, r"period=\[nan, 1.0\] must be positive"),  # was accepted
])
def test_priors_from_info_check_their_arrays(info, says):
    with pytest.raises(DeintError, match=f"priors: {says}"):
        Priors.from_info(info)


def test_a_dataset_root_may_be_relative(capsys):
    pytest.importorskip("minari")
    assert main(["dataset", "ds/rel-v0", "--scenario", "paper-v0/mk94-two-var1", "--seeds", "2", "--root", "r"]) == 0
    assert os.path.isdir("r/ds/rel-v0") and "wrote 2 episodes" in capsys.readouterr().err  # was a doubled path

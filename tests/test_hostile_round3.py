"""Hostile inputs, round three (issue 26): repeated JSON keys, numbers only float() reads, doubled merged
sources, TOAs too large to draw, `deint tune` options checked before any play, and bounded worker counts."""

from __future__ import annotations

import json
import os

import pytest

from deint_env.cli import main
from deint_env.errors import DeintError
from deint_env.formats import read_pulse_table
from deint_env.formats.json_files import loads
from deint_env.policies import parse_policy_spec

PRIORS = {"period": [20.0, 37.0], "phase": [4.0, 35.0], "jitter_std": 0.05}
_TOAS = sorted([4.0 + 20 * i for i in range(20)] + [35.5 + 37 * i for i in range(11)])
PULSES = "toa\n" + "".join(f"{t}\n" for t in _TOAS)


def deint(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("text,key", [
    ('{"period": [20.0], "period": [30.0]}', "period"),
    ('{"a": {"b": 1, "b": 2}}', "b"),  # nested objects too
])
def test_a_repeated_json_key_is_refused(text, key):
    with pytest.raises(DeintError, match=f"f.json: key '{key}' appears twice in an object; give each key once"):
        loads(text, "f.json")


def test_a_priors_file_with_a_repeated_key_is_one_line(capsys, tmp_path):
    (tmp_path / "p.csv").write_text(PULSES)
    (tmp_path / "pr.json").write_text(json.dumps(PRIORS)[:-1] + ', "jitter_std": 7.0}')
    code, _, err = deint(capsys, "label", "--policy", "fdp", "--priors", tmp_path / "pr.json",
                         "-o", tmp_path / "l.csv", tmp_path / "p.csv")
    assert code == 2 and err.count("\n") == 1 and "key 'jitter_std' appears twice" in err
    assert not (tmp_path / "l.csv").exists()


@pytest.mark.parametrize("column,cell", [
    ("toa", "1_0"),  # float() and numpy read it as 10
    ("toa", "\u0661"),  # ARABIC-INDIC DIGIT ONE, read as 1
    ("source", "1_0"),
])
def test_pulse_cells_only_float_reads_are_not_numbers(tmp_path, column, cell):
    rows = {"toa": ["0.5", cell], "source": ["0", "0"]}
    if column == "source":
        rows = {"toa": ["0.5", "2.5"], "source": ["0", cell]}
    path = tmp_path / "p.csv"
    path.write_text("toa,source\n" + "".join(f"{t},{s}\n" for t, s in zip(rows["toa"], rows["source"])))
    with pytest.raises(DeintError, match=f"line 3: {column}='{cell}' is not a decimal number"):
        read_pulse_table(path)


@pytest.mark.parametrize("cell,says", [
    ("0|0", "names a source twice"),
    ("0|1_0", "is invalid; allowed: source numbers"),
])
def test_a_merged_pulse_names_each_source_once(tmp_path, cell, says):
    path = tmp_path / "p.csv"
    path.write_text(f"toa,source,sources\n1.0,0,{cell}\n2.0,1,\n")
    with pytest.raises(DeintError, match=says):
        read_pulse_table(path)


@pytest.mark.parametrize("value", ["1_0", "\u0663"])
def test_policy_values_only_float_reads_stay_text(capsys, tmp_path, value):
    assert parse_policy_spec(f"fdp:gate={value}")[1] == {"gate": value}
    (tmp_path / "p.csv").write_text(PULSES)
    (tmp_path / "pr.json").write_text(json.dumps(PRIORS))
    code, _, err = deint(capsys, "label", "--policy", f"fdp:gate={value}", "--priors", tmp_path / "pr.json",
                         "-o", tmp_path / "l.csv", tmp_path / "p.csv")
    assert code == 2 and err.count("\n") == 1 and f"gate='{value}' is invalid" in err


@pytest.mark.parametrize("toa", ["1e308,1.7e308", "-1.7e308,1.7e308", "0,1e308"])
def test_toas_too_large_to_draw_are_one_line(capsys, tmp_path, toa):
    pytest.importorskip("matplotlib")
    (tmp_path / "p.csv").write_text("toa\n" + toa.replace(",", "\n") + "\n")
    code, _, err = deint(capsys, "plot", "-o", tmp_path / "p.png", tmp_path / "p.csv")
    assert code == 2 and err.count("\n") == 1 and "too large to draw" in err, err
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("option,value,says", [
    ("--configs", 10**12, "configs=1000000000000 is invalid: an integer in [1, 1000]"),  # drew candidates for hours
    ("--seed", -1, "seed=-1 is invalid: an integer in [0, 2^63)"),  # numpy's ValueError, a traceback
    ("--seed", 2**64, "seed=18446744073709551616 is invalid"),
    ("--workers", 0, "workers=0 is invalid"),  # after the schedule was printed
])
def test_tune_options_are_checked_before_anything(capsys, tmp_path, option, value, says):
    code, out, err = deint(capsys, "tune", "fdp", "--suite", "core-v0", option, value, "--budget", 1,
                           "--out", tmp_path / "t.json", "--work", tmp_path / "work", "--no-progress")
    assert code == 2 and err == f"deint: error: {says}" + err[len(f"deint: error: {says}"):] and err.count("\n") == 1
    assert not (tmp_path / "work").exists() and not (tmp_path / "t.json").exists()


@pytest.mark.parametrize("kind", ["dir", "fifo", "symlink", "results"])
def test_tune_refuses_a_preset_path_it_cannot_write_before_playing(capsys, tmp_path, kind):
    out = tmp_path / "t.json"
    if kind == "dir":
        out.mkdir()
    elif kind == "fifo":
        os.mkfifo(out)
    elif kind == "symlink":
        out.symlink_to(tmp_path / "elsewhere.json")
    else:
        out = tmp_path / "work" / "results.jsonl"
    code, _, err = deint(capsys, "tune", "fdp", "--suite", "core-v0", "--scenarios", "core-n2-spread4-jitter0.05",
                         "--budget", 1, "--out", out, "--work", tmp_path / "work", "--no-progress")
    assert code == 2 and err.count("\n") == 1, err
    assert ("results file" if kind == "results" else "outputs are written only to regular files") in err
    assert not (tmp_path / "work" / "results.jsonl").exists()  # no play ran


@pytest.mark.parametrize("policy", ["dbscan", "hdbscan"])
@pytest.mark.parametrize("toa", ["0,1e308", "-1.7e308,1.7e308"])
def test_density_clustering_of_overflowing_toas_is_one_line(capsys, tmp_path, policy, toa):
    (tmp_path / "p.csv").write_text("toa\n" + toa.replace(",", "\n") + "\n")
    code, _, err = deint(capsys, "label", "--policy", policy, "-o", tmp_path / "l.csv", tmp_path / "p.csv")
    assert code == 2 and err.count("\n") == 1, err  # was sklearn's ValueError, after numpy's overflow warnings
    assert err.startswith(f"deint: error: {policy}: the descriptors of pulse 0") and "overflow float64" in err
    assert not (tmp_path / "l.csv").exists()


@pytest.mark.parametrize("workers", [0, 1025, 100_000, True])
def test_a_worker_count_is_bounded_before_any_process_starts(capsys, workers):
    """A local pool forks every worker at once: 10^5 workers asked for is refused, not forked; a boolean is
    not a count (evaluate's Python callers too)."""
    from deint_env.runner import evaluate

    with pytest.raises(DeintError, match=r"workers=.* is invalid: an integer in \[1, 1024\]"):
        evaluate(["fdp"], "core-v0/core-n2-spread4-jitter0.05", max_seeds=2, workers=workers, progress=False)
    if not isinstance(workers, bool):
        assert main(["run", "--scenario", "core-n2-spread4-jitter0.05", "--policy", "fdp", "--max-seeds", "2",
                     "--workers", str(workers)]) == 2
        assert "is invalid: an integer in [1, 1024]" in capsys.readouterr().err

"""Hostile results and leaderboard files (issue 26): every field is checked by type before it is used,
one line names the file and the field, and a leaderboard file never chooses code to import."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from deint_env.cli import main

TARGET = "paper-v0/mk94-two-var1"
BOARD = {"suite": "core-v0", "scope": {"scenarios": ["core-n2-spread1.5-jitter0.05"], "max_seeds": 1},
         "rows": [{"policy": "random", "submitted": False}], "incomplete": {}, "stale": {}}


def deint(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def record_line(tmp_path_factory) -> str:
    """One genuine results line, for the tests to tamper with."""
    out = tmp_path_factory.mktemp("run") / "res.jsonl"
    assert main(["run", "--policies", "random", "--scenario", TARGET, "--max-seeds", "1", "--out", str(out),
                 "--no-progress"]) == 0
    return out.read_text()


def _run(capsys, out: Path):
    return deint(capsys, "run", "--policies", "random", "--scenario", TARGET, "--max-seeds", 2, "--out", out,
                 "--no-progress")


@pytest.mark.parametrize("field,value,says", [
    ("accuracy", "abc", "metric 'accuracy' is \"abc\", not a number or null"),
    ("pe", [0.1, "x"], "metric 'pe' is [0.1, \"x\"], not a list of 2 numbers or nulls (one per source)"),
    ("score", True, "metric 'score' is true, not a number"),
    ("tags", [{}], "field 'tags' is [{}], not a list of strings"),
])
def test_a_record_field_of_the_wrong_type_is_one_line(capsys, tmp_path, record_line, field, value, says):
    out = tmp_path / "res.jsonl"
    out.write_text(json.dumps({**json.loads(record_line), field: value}) + "\n")
    before = out.read_bytes()
    code, _, err = _run(capsys, out)
    assert code == 2 and err.startswith(f"deint: error: {out}: line 1: ") and says in err
    assert err.count("\n") == 1 and out.read_bytes() == before  # nothing written


def test_a_deep_torn_last_line_is_cut_not_a_traceback(capsys, tmp_path, record_line):
    out = tmp_path / "res.jsonl"
    out.write_text(record_line + '{"pe": ' + "[" * 200_000)  # a torn record deeper than the parser's recursion limit
    code, _, err = _run(capsys, out)
    assert code == 0, err
    lines = out.read_text().splitlines()
    assert len(lines) == 2 and lines[0] == record_line.strip()  # the record kept, the torn line cut, one played
    out.write_text(record_line + "[" * 200_000)  # deep, and no record at all
    code, _, err = _run(capsys, out)
    assert code == 2 and err == (f"deint: error: {out}: line 2 is not a JSON record; fix or remove it\n")


def _board(root: Path, board) -> Path:
    folder = root / "core-v0"
    folder.mkdir(parents=True)
    (folder / "leaderboard.json").write_text(board if isinstance(board, str) else json.dumps(board))
    return folder


@pytest.mark.parametrize("change,says", [
    ({"rows": [{"policy": 5, "submitted": False}]}, "field rows[0].policy is 5, not a policy spec"),
    ({"rows": [{"policy": "random"}]}, "field rows[0].submitted is null, not true or false"),
    ({"rows": 5}, "field rows is 5, not a list"),
    ({"stale": [5]}, "field stale is [5], not an object of episode counts"),
    ({"incomplete": {"random": "x"}}, "field incomplete is {\"random\": \"x\"}, not an object of episode counts"),
    ({"scope": {"scenarios": 5, "max_seeds": 1}}, "field scope.scenarios is 5, not a list of strings"),
    ({"scope": {"scenarios": None, "max_seeds": True}}, "field scope.max_seeds is true, not null or an integer >= 1"),
    ({"scope": {"scenarios": None, "max_seeds": 0}}, "field scope.max_seeds is 0, not null or an integer >= 1"),
    ({"suite": ["core-v0"]}, "field suite is [\"core-v0\"], not a suite name"),
])
def test_a_tampered_leaderboard_file_is_one_line(capsys, tmp_path, change, says):
    folder = _board(tmp_path, {**BOARD, **change})
    code, _, err = deint(capsys, "leaderboard", "--all", "--root", tmp_path, "--no-progress")
    assert code == 2 and err == (f"deint: error: {folder / 'leaderboard.json'}: {says}; remove the file or "
                                 f"regenerate the folder\n")
    assert sorted(p.name for p in folder.iterdir()) == ["leaderboard.json"]  # nothing run, nothing written


def test_a_deeply_nested_leaderboard_file_is_one_line(capsys, tmp_path):
    folder = _board(tmp_path, "[" * 200_000 + "]" * 200_000)
    code, _, err = deint(capsys, "leaderboard", "--all", "--root", tmp_path, "--no-progress")
    assert code == 2 and err == (f"deint: error: {folder / 'leaderboard.json'}: is not a leaderboard file (not "
                                 f"readable JSON); remove it or regenerate the folder\n")


def test_a_leaderboard_file_does_not_choose_what_is_imported(capsys, tmp_path, monkeypatch):
    marker = tmp_path / "imported"
    (tmp_path / "chosen_by_the_file.py").write_text(f"open({str(marker)!r}, 'w').close()\nclass M: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = "tdc:model=chosen_by_the_file:M"
    folder = _board(tmp_path / "boards", {**BOARD, "rows": [{"policy": spec, "submitted": False}]})
    code, _, err = deint(capsys, "leaderboard", "--all", "--root", tmp_path / "boards", "--no-progress")
    assert code == 2 and err == (f"deint: error: {folder / 'leaderboard.json'}: records {spec!r}, whose parameters "
                                 f"name code to import; a leaderboard file does not choose what runs: name it with "
                                 f"--policies to rebuild it\n")
    assert not marker.exists()


# ---------------------------------------------------------------------------------------------------
# outputs damage nothing that is not theirs
# ---------------------------------------------------------------------------------------------------
def test_a_text_file_as_results_file_is_refused_not_cut(capsys, tmp_path):
    from deint_env.errors import DeintError
    from deint_env.results import ResultsWriter

    notes = tmp_path / "notes.txt"
    notes.write_text("my notes, one line without its newline")
    code, _, err = _run(capsys, notes)
    assert code == 2 and err == f"deint: error: {notes}: line 1 is not a JSON record; fix or remove it\n"
    with pytest.raises(DeintError, match="is not a results file"):  # the writer alone does not cut it either
        ResultsWriter(notes)
    assert notes.read_text() == "my notes, one line without its newline"


@pytest.mark.parametrize("kind", ["fifo", "symlink"])
def test_outputs_that_are_not_regular_files_are_refused(capsys, tmp_path, kind):
    import os

    target, out = tmp_path / "precious.csv", tmp_path / "out.csv"
    target.write_text("keep me\n")
    if kind == "fifo":
        os.mkfifo(out)
        says = "a FIFO"
    else:
        out.symlink_to(target)
        says = "a symbolic link"
    code, _, err = deint(capsys, "simulate", TARGET, "--seed", 1, "-o", out)
    assert code == 2 and err == (f"deint: error: cannot write {out}: it is {says}; outputs are written only to "
                                 f"regular files (new or existing)\n")
    assert target.read_text() == "keep me\n" and (out.is_fifo() if kind == "fifo" else out.is_symlink())
    results = tmp_path / "res.jsonl"  # a results file appended to is an output (and an input) too
    if kind == "fifo":
        os.mkfifo(results)
    else:
        (tmp_path / "empty.jsonl").touch()
        results.symlink_to(tmp_path / "empty.jsonl")
    code, _, err = _run(capsys, results)
    assert code == 2 and err == (f"deint: error: {results}: is not a regular file; a results file is read only from a "
                                 f"regular file\n" if kind == "fifo" else
                                 f"deint: error: cannot write {results}: it is a symbolic link; outputs are written "
                                 f"only to regular files (new or existing)\n")
    assert kind == "fifo" or (tmp_path / "empty.jsonl").read_text() == ""


@pytest.mark.parametrize("name", ["results.jsonl", "leaderboard.json"])
def test_export_cannot_replace_a_leaderboards_own_files(capsys, tmp_path, name):
    folder = _board(tmp_path, BOARD)
    (folder / "results.jsonl").write_text("")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    code, _, err = deint(capsys, "leaderboard", "export", "--suite", "core-v0", "--policy", "random",
                         "--scenarios", "core-n2-spread1.5-jitter0.05", "--max-seeds", 1, "-o", folder / name)
    assert code == 2 and err == (f"deint: error: {folder / name}: lies in a leaderboard folder, whose files `deint "
                                 f"leaderboard` writes; write the labels elsewhere\n")
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


@pytest.mark.parametrize("flag", ["pulses", "--priors"])
def test_inputs_that_are_not_regular_files_are_refused(capsys, tmp_path, flag):
    import os

    good, fifo = tmp_path / "p.csv", tmp_path / "fifo"
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(good), "--priors-out", str(tmp_path / "p.json")]) == 0
    capsys.readouterr()
    os.mkfifo(fifo)  # reading it would wait for a writer that never comes
    pulses, priors = (fifo, tmp_path / "p.json") if flag == "pulses" else (good, fifo)
    code, _, err = deint(capsys, "label", pulses, "--priors", priors, "--policy", "random", "-o", tmp_path / "l.csv")
    kind = "CSV" if flag == "pulses" else "JSON"
    assert code == 2 and err == f"deint: error: {fifo}: is not a regular file; a {kind} file is read only from a " \
                                f"regular file\n"
    code, _, err = deint(capsys, "label", "/dev/zero", "--priors", tmp_path / "p.json", "--policy", "random",
                         "-o", tmp_path / "l.csv")
    assert code == 2 and err == "deint: error: /dev/zero: is not a regular file; a CSV file is read only from a " \
                                "regular file\n"


# ---------------------------------------------------------------------------------------------------
# submissions and challenge files
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", ["true", "1.0001", "\"1\""])
def test_a_submission_header_version_must_be_the_integer(tmp_path, version):
    from deint_env.errors import DeintError
    from deint_env.leaderboard.submit import read_submission

    path = tmp_path / "sub.jsonl"
    path.write_text('{"format": "deint-submission", "version": ' + version + ', "suite": "core-v0", "name": "x"}\n'
                    '{"scenario": "a", "seed": 1, "labels": [0]}\n')
    with pytest.raises(DeintError, match=r"version=.* is not supported: 1"):
        read_submission(path)


def test_challenge_feature_names_lose_their_unit_in_linear_time():
    import random
    import re

    from deint_env.formats.tdc import _without_unit, canonical_feature

    def reference(name: str) -> str:  # the regex it replaced (quadratic on many opening brackets)
        return re.sub(r"\s*[(\[][^)\]]*[)\]]\s*$", "", name)

    rng = random.Random(0)
    for _ in range(5000):
        name = "".join(rng.choice("ab (])[ \t-") for _ in range(rng.randint(0, 12)))
        assert _without_unit(name).strip() == reference(name).strip(), name
    assert canonical_feature("Time of Arrival (us)") == "toa"
    assert canonical_feature("(" * 100_000 + "toa") is None and canonical_feature("[" * 100_000 + ")") is None


# ---------------------------------------------------------------------------------------------------
# policy parameter values
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["²", "+-3", "--3", "-+3", "٣"])
def test_policy_values_that_int_refuses_are_not_integers(text):
    from deint_env.policies import _parse_value

    value = _parse_value(text, "x")  # was int(text) on anything str.isdigit() passed: a traceback
    assert not isinstance(value, int) or isinstance(value, bool)


@pytest.mark.parametrize("spec", ["fdp:lookahead=²", "mht:beam=+-3", "random:seed=--3"])
def test_such_values_through_label_are_one_line(capsys, tmp_path, spec):
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(tmp_path / "p.csv"), "--priors-out",
                 str(tmp_path / "p.json")]) == 0
    capsys.readouterr()
    code, _, err = deint(capsys, "label", tmp_path / "p.csv", "--priors", tmp_path / "p.json", "--policy", spec, "-o",
                         tmp_path / "l.csv")
    assert code == 2 and err.startswith(f"deint: error: policy {spec!r}: ") and err.count("\n") == 1
    assert not (tmp_path / "l.csv").exists()


# ---------------------------------------------------------------------------------------------------
# priors: strict booleans, magnitudes a tracker can represent
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("priors,says", [
    ({"blind": "false", "label_budget": 3}, "blind='false' must be true or false"),
    ({"blind": "yes", "label_budget": 3}, "blind='yes' must be true or false"),
    ({"blind": 1, "label_budget": 3}, "blind=1 must be true or false"),
    ({"blind": True, "label_budget": True}, "label_budget=True must be an integer in [1, 256]"),
    ({"period": [10.0], "label_budget": 3}, "label_budget is for blind priors"),
    ({"period": [10.0, 17.0], "jitter_std": 1e200}, "jitter_std=1e+200 must be a number in [0.0, 1e+30]"),
    ({"period": [5e-324, 17.0]}, "period must be a list of positive numbers of size in [1e-30, 1e+30]"),
    ({"period": [10.0, 17.0], "phase": [1e300, 0.0]}, "phase must be a list of 2 numbers of size in [0, 1e+30]"),
])
def test_priors_fields_are_strict(tmp_path, priors, says):
    from deint_env.errors import DeintError
    from deint_env.formats import read_priors

    path = tmp_path / "p.json"
    path.write_text(json.dumps(priors))
    with pytest.raises(DeintError) as err:
        read_priors(path)
    assert str(err.value).startswith(f"{path}: {says}")


@pytest.mark.parametrize("info,says", [({"n_labels": -3}, "n_labels=-3 must be an integer >= 1"),
                                       ({"n_labels": 2, "blind": "no"}, "blind='no' must be true or false")])
def test_priors_from_info_are_checked(info, says):
    from deint_env.episode import Priors
    from deint_env.errors import DeintError

    with pytest.raises(DeintError, match=says):
        Priors.from_info(info)


@pytest.mark.parametrize("policy", ["fdp", "mht", "dokf", "pt-post", "agile-kf", "renewal-ml", "genie"])
def test_the_largest_representable_jitter_is_no_traceback(capsys, tmp_path, policy):
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(tmp_path / "p.csv"), "--true-priors-out",
                 str(tmp_path / "p.json")]) == 0
    capsys.readouterr()
    priors = json.loads((tmp_path / "p.json").read_text())
    (tmp_path / "p.json").write_text(json.dumps({**priors, "jitter_std": 1e30}))
    code, _, err = deint(capsys, "label", tmp_path / "p.csv", "--priors", tmp_path / "p.json", "--policy", policy,
                         "-o", tmp_path / "l.csv")
    assert (code == 0 and (tmp_path / "l.csv").exists()) or (code == 2 and err.count("\n") == 1), err
    assert "Traceback" not in err


def test_a_compressed_hdf5_bomb_within_the_array_limit_is_refused(capsys, tmp_path):
    h5py = pytest.importorskip("h5py")
    import numpy as np

    bomb = tmp_path / "bomb.h5"
    with h5py.File(bomb, "w") as f:  # 1 GiB declared (the per-array limit), nothing stored: a few KB
        f.create_group("metadata").create_dataset("feature_names", data=np.array([b"toa", b"amplitude"]))
        f.create_dataset("data", shape=(2**26, 2), dtype="float64", chunks=(2**16, 2), compression="gzip")
    size = bomb.stat().st_size
    assert size < 20_000
    code, _, err = deint(capsys, "label", bomb, "--policy", "random", "--n-sources", 2, "-o", tmp_path / "l.csv")
    assert code == 2 and err == (f"deint: error: {bomb}: 'data' declares {2**30} bytes from a {size}-byte file; a "
                                 f"dataset unpacks to at most 64 times its file's size (beyond 64 MiB)\n")


def test_a_variable_length_tdc_attribute_is_refused_before_labelling(capsys, tmp_path):
    h5py = pytest.importorskip("h5py")
    import numpy as np

    path = tmp_path / "vlen.h5"
    with h5py.File(path, "w") as f:
        f.create_group("metadata").create_dataset("feature_names", data=np.array([b"toa"]))
        f.create_dataset("data", data=np.arange(20, dtype=np.float64).reshape(20, 1))
        ragged = np.empty(2, dtype=h5py.vlen_dtype(np.dtype("int32")))
        ragged[0], ragged[1] = np.array([1, 2], dtype="int32"), np.array([3], dtype="int32")
        f["metadata"].attrs.create("ragged", ragged, dtype=h5py.vlen_dtype(np.dtype("int32")))
    code, _, err = deint(capsys, "label", path, "--policy", "random", "--n-sources", 2, "-o", tmp_path / "out.h5")
    assert code == 2 and err == (f"deint: error: {path}: metadata attribute 'ragged' holds variable-length or object "
                                 f"values; TDC metadata attributes are strings, numbers or arrays of them\n")
    assert not (tmp_path / "out.h5").exists()


def test_a_multi_output_command_checks_every_output_first(capsys, tmp_path):
    good, folder = tmp_path / "good.csv", tmp_path / "DIR"
    good.write_text("keep me\n")
    folder.mkdir()
    code, _, err = deint(capsys, "simulate", TARGET, "--seed", 1, "-o", good, "--priors-out", folder)
    assert code == 2 and err == (f"deint: error: cannot write {folder}: it is a directory; outputs are written only "
                                 f"to regular files (new or existing)\n")
    assert good.read_text() == "keep me\n"  # not replaced before the directory was found


def test_an_output_with_a_trailing_slash_is_refused(capsys, tmp_path):
    out = f"{tmp_path / 'out.csv'}/"
    code, _, err = deint(capsys, "simulate", TARGET, "--seed", 1, "-o", out)
    assert code == 2 and err == f"deint: error: cannot write {out}: it names a directory (a trailing /); give a file " \
                                f"name\n"
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("dataset_id", ["../../evil/x-v0", "a/../b-v0", "deint/.hidden-v0"])
def test_a_dataset_id_cannot_leave_the_datasets_root(capsys, tmp_path, dataset_id):
    pytest.importorskip("minari")
    code, _, err = deint(capsys, "dataset", dataset_id, "--suite", "core-v0", "--policy", "random", "--seeds", 1,
                         "--root", tmp_path / "datasets")
    assert code == 2 and err == (f"deint: error: dataset id {dataset_id!r} is invalid: write NAMESPACE/NAME-vN, e.g. "
                                 f"deint/core-fdp-v0\n")
    assert not any(tmp_path.rglob("*-v0"))


@pytest.mark.parametrize("value", ["maybe", "1", "0.5"])
def test_an_agents_deterministic_flag_is_a_boolean(capsys, tmp_path, value):
    pytest.importorskip("torch")
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(tmp_path / "p.csv"), "--priors-out",
                 str(tmp_path / "p.json")]) == 0
    capsys.readouterr()
    spec = f"dagger:deterministic={value}"
    code, _, err = deint(capsys, "label", tmp_path / "p.csv", "--priors", tmp_path / "p.json", "--policy", spec,
                         "-o", tmp_path / "l.csv")
    assert code == 2 and "is invalid: true or false" in err and err.count("\n") == 1


@pytest.mark.parametrize("reps", ["100000000", "99"])
def test_bootstrap_replicates_are_bounded(capsys, tmp_path, reps):
    code, _, err = deint(capsys, "leaderboard", "--suite", "core-v0", "--root", tmp_path, "--reps", reps,
                         "--policies", "random", "--max-seeds", 1, "--scenarios", "core-n2-spread1.5-jitter0.05")
    assert code == 2 and err == f"deint: error: --reps={reps} is invalid: an integer in [100, 100000]\n"
    assert not any(tmp_path.iterdir())


def test_the_statistics_refuse_unbounded_replicates():
    import numpy as np

    from deint_env import stats
    from deint_env.errors import DeintError

    with pytest.raises(DeintError, match=r"reps=100000000 is invalid: an integer in \[100, 100000\]"):
        stats.probability_of_improvement({"a": np.ones(3)}, {"a": np.zeros(3)}, reps=10**8)


def test_fdp_refuses_a_tree_it_cannot_walk_in_one_line(capsys, tmp_path):
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(tmp_path / "p.csv")]) == 0
    capsys.readouterr()
    n = 5000
    (tmp_path / "p.json").write_text(json.dumps({"period": [100 + i / 50 for i in range(n)],
                                                 "phase": [i / 50 for i in range(n)], "jitter_std": 0.1}))
    code, _, err = deint(capsys, "label", tmp_path / "p.csv", "--priors", tmp_path / "p.json", "--policy", "fdp",
                         "-o", tmp_path / "l.csv")
    assert code == 2 and err == ("deint: error: lookahead=3 with 5000 sources means 5000^4 continuations a pulse; at "
                                 "most 4e6 (tree_gate keeps only the gated ones)\n")


def test_a_policys_own_checkpoint_is_an_input_not_an_output(capsys, tmp_path):
    import shutil

    pytest.importorskip("torch")
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(tmp_path / "p.csv"), "--priors-out",
                 str(tmp_path / "p.json")]) == 0
    capsys.readouterr()
    ck = tmp_path / "ck.safetensors"
    shutil.copy("agents/checkpoints/dagger-all-lag3.safetensors", ck)
    before = ck.read_bytes()
    code, _, err = deint(capsys, "label", tmp_path / "p.csv", "--priors", tmp_path / "p.json", "--policy",
                         f"agent:checkpoint={ck}", "-o", ck)
    assert code == 2 and err == (f"deint: error: -o {ck} is the same file as the input --policy checkpoint= {ck}; "
                                 f"name a different file for each input and output\n")
    code, _, err = deint(capsys, "leaderboard", "export", "--suite", "core-v0", "--policy", f"agent:checkpoint={ck}",
                         "-o", ck)
    assert code == 2 and "is the same file as the input --policy checkpoint=" in err
    assert ck.read_bytes() == before


def test_a_model_module_a_policy_names_is_an_input(capsys, tmp_path, monkeypatch):
    module = tmp_path / "my_tdc_model.py"
    module.write_text("class M:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["simulate", TARGET, "--seed", "1", "-o", str(tmp_path / "p.csv")]) == 0
    capsys.readouterr()
    code, _, err = deint(capsys, "label", tmp_path / "p.csv", "--n-sources", 2, "--policy", "tdc:model=my_tdc_model:M",
                         "-o", module)
    assert code == 2 and err == (f"deint: error: -o {module} is the same file as the input --policy model= {module}; "
                                 f"name a different file for each input and output\n")
    assert module.read_text() == "class M:\n    pass\n"

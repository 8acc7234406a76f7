"""Hostile inputs and faults (issue 7): every case gives one line `deint: error: ...`, exit 2, and
leaves every file as it was (nothing lost, nothing half-written, no temporary file left)."""

from __future__ import annotations

import errno
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from deint_env.cli import main
from deint_env.errors import DeintError
from deint_env.formats import files
from deint_env.leaderboard.submit import read_submission

SCENARIO = "paper-v0/mk94-two-var1"
DEEP = "[" * 100_000 + "]" * 100_000


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def refused(capsys, tmp_path, *argv, expected: str) -> str:
    """Run `deint ARGV`: exit 2, one error line holding `expected`, and no file created or changed."""
    before = snapshot(tmp_path)
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert code == 2 and out == "" and len(lines) == 1 and lines[0].startswith("deint: error: "), err
    assert expected in lines[0], lines[0]
    assert snapshot(tmp_path) == before
    return lines[0]


@pytest.fixture
def pulses(capsys):
    assert main(["simulate", SCENARIO, "--seed", "1", "-o", "p.csv", "--priors-out", "pr.json",
                 "--true-priors-out", "true.json"]) == 0
    capsys.readouterr()


# ---- outputs against inputs and other outputs --------------------------------------------------------
def test_simulate_outputs_must_differ(capsys, tmp_path):
    refused(capsys, tmp_path, "simulate", SCENARIO, "--seed", 1, "-o", "x", "--priors-out", "x",
            expected="--priors-out x is the same file as the output -o x")
    Path("f.json").write_text("{}")  # the true parameters must never land in the public file
    refused(capsys, tmp_path, "simulate", SCENARIO, "--seed", 1, "-o", "p2.csv", "--priors-out", "f.json",
            "--true-priors-out", "f.json", expected="--true-priors-out f.json is the same file as the output "
                                                    "--priors-out f.json")


def test_same_file_under_other_spellings(capsys, tmp_path, pulses):
    os.mkdir("d")
    refused(capsys, tmp_path, "simulate", SCENARIO, "--seed", 1, "-o", "x.csv", "--priors-out", "d/../x.csv",
            expected="is the same file as the output -o x.csv")
    refused(capsys, tmp_path, "simulate", SCENARIO, "--seed", 1, "-o", "x.csv", "--priors-out",
            str(tmp_path / "x.csv"), expected="is the same file as the output -o x.csv")
    os.link("p.csv", "hard.csv")
    refused(capsys, tmp_path, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "hard.csv",
            expected="-o hard.csv is the same file as the input PULSES p.csv")
    os.symlink("pr.json", "soft.json")
    refused(capsys, tmp_path, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "soft.json",
            expected="-o soft.json is the same file as the input --priors pr.json")


def test_label_cannot_overwrite_its_priors(capsys, tmp_path, pulses):
    refused(capsys, tmp_path, "label", "p.csv", "--policy", "random", "--priors", "pr.json", "-o", "pr.json",
            expected="-o pr.json is the same file as the input --priors pr.json")


def test_tdc_convert_cannot_overwrite_its_input(capsys, tmp_path, pulses):
    os.link("p.csv", "same.h5")
    refused(capsys, tmp_path, "tdc", "convert", "p.csv", "same.h5", expected="OUTPUT same.h5 is the same file")


def test_a_submission_cannot_live_in_the_board_it_rewrites(capsys, tmp_path):
    os.makedirs("board/core-v0")
    Path("board/core-v0/results.jsonl").write_text("")
    refused(capsys, tmp_path, "leaderboard", "submit", "board/core-v0/results.jsonl", "--suite", "core-v0",
            "--root", "board", expected="lies in the leaderboard directory board/core-v0")


# ---- JSON: magnitude and depth ---------------------------------------------------------------------------
@pytest.mark.parametrize("text, expected", [
    ('{"period": [1' + "0" * 400 + "]}", "has 401 digits; the limit is 19 digits"),
    ('{"period": [1e400]}', "1e400 is out of range"),
    (DEEP, "nested more than 64 deep; the limit is 64 levels"),
    ('{"period": [10.0], "x": "' + "[" * 1000 + '"}', "unknown"),  # brackets inside a string do not count
])
def test_priors_limits(capsys, tmp_path, pulses, text, expected):
    Path("bad.json").write_text(text)
    refused(capsys, tmp_path, "label", "p.csv", "--policy", "random", "--priors", "bad.json", "-o", "l.csv",
            expected=expected)


def test_scenario_file_depth(capsys, tmp_path):
    Path("s.json").write_text(DEEP)
    refused(capsys, tmp_path, "simulate", "s.json", "--seed", 1, "-o", "p.csv", expected="the limit is 64 levels")


def test_submission_depth_and_digits(tmp_path):
    Path("deep.jsonl").write_text('{"scenario": "a", "seed": 1, "labels": ' + DEEP + "}\n")
    with pytest.raises(DeintError, match="deep.jsonl: line 1: JSON nested more than 64 deep"):
        read_submission("deep.jsonl")
    Path("digits.jsonl").write_text('{"scenario": "a", "seed": 1, "labels": [' + "1" * 5000 + "]}\n")
    with pytest.raises(DeintError, match="digits.jsonl: line 1"):
        read_submission("digits.jsonl")


# ---- policy specs and seeds ----------------------------------------------------------------------------
@pytest.mark.parametrize("argv, expected", [
    (["--policy", "random", "--seed", "-1"], "--seed=-1 is invalid: an integer in [0, 2^63)"),
    (["--policy", "random", "--seed", "1e400"], "invalid int value"),
    (["--policy", "random:seed=-1"], "seed=-1 is invalid"),
    (["--policy", "random:seed=1e400"], "numbers in policy parameters are finite"),
    (["--policy", "fdp:lookahead=3,lookahead=4"], "'lookahead' is given twice"),
])
def test_policy_seeds_and_specs(capsys, tmp_path, pulses, argv, expected):
    refused(capsys, tmp_path, "label", "p.csv", "--priors", "pr.json", "-o", "l.csv", *argv, expected=expected)


# ---- HDF5 (TDC) files ------------------------------------------------------------------------------------
h5py = pytest.importorskip("h5py")


def tdc_file(path: str, data=None, **links) -> None:
    with h5py.File(path, "w") as f:
        meta = f.create_group("metadata")
        meta.create_dataset("feature_names", data=np.array([b"time_of_arrival"]))
        if data is not None:
            f.create_dataset("data", data=data)
        for name, link in links.items():
            f[name] = link


def test_hdf5_external_and_soft_links(capsys, tmp_path):
    tdc_file("other.h5", np.arange(5.0)[:, None])
    tdc_file("ext.h5", data=None, data_link=h5py.ExternalLink("other.h5", "/data"))
    with h5py.File("ext.h5", "a") as f:
        f.move("data_link", "data")
    refused(capsys, tmp_path, "label", "ext.h5", "--policy", "random", "--n-sources", 2, "-o", "l.csv",
            expected="'data' is an external link (to other.h5:/data)")
    with h5py.File("loop.h5", "w") as f:
        f["a"] = h5py.SoftLink("/b")
        f["b"] = h5py.SoftLink("/a")
        f["data"] = h5py.SoftLink("/a")
    refused(capsys, tmp_path, "label", "loop.h5", "--policy", "random", "--n-sources", 2, "-o", "l.csv",
            expected="'data' is a soft link (to /a)")


def test_hdf5_declared_size_is_checked_before_reading(capsys, tmp_path):
    with h5py.File("huge.h5", "w") as f:
        f.create_group("metadata").create_dataset("feature_names", data=np.array([b"toa", b"amplitude"]))
        f.create_dataset("data", shape=(4 * 10**9, 2), dtype="float32", chunks=(1024, 2), compression="gzip")
    assert Path("huge.h5").stat().st_size < 10_000
    line = refused(capsys, tmp_path, "label", "huge.h5", "--policy", "random", "--n-sources", 2, "-o", "l.csv",
                   expected="'data' declares shape (4000000000, 2) (29.8 GiB); the limit is 1 GiB per array")
    assert "huge.h5" in line


# ---- NPZ submissions ---------------------------------------------------------------------------------
def npz(path: str, members: list[tuple[str, bytes]]) -> None:
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members:
            z.writestr(name, data)


def npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def test_npz_declared_size_is_checked_before_reading(tmp_path):
    raw = io.BytesIO()  # a .npy header declaring 10^10 int64 (74.5 GiB), and no data
    np.lib.format.write_array_header_1_0(raw, {"descr": "<i8", "fortran_order": False, "shape": (10**10,)})
    npz("huge.npz", [("core/1.npy", raw.getvalue())])
    assert Path("huge.npz").stat().st_size < 300
    with pytest.raises(DeintError, match=r"array 'core/1' declares shape \(10000000000,\) \(74.5 GiB\); "
                                         r"the limit is 1 GiB per array"):
        read_submission("huge.npz")


def test_npz_members_must_be_npy_and_unique(tmp_path):
    npz("txt.npz", [("core/1.npy", npy(np.zeros(3, np.int64))), ("notes.txt", b"hello")])
    with pytest.raises(DeintError, match="member 'notes.txt' is not a .npy array"):
        read_submission("txt.npz")
    with pytest.warns(UserWarning, match="Duplicate name"):
        npz("dup.npz", [("core/1.npy", npy(np.zeros(3, np.int64))), ("core/1.npy", npy(np.ones(3, np.int64)))])
    with pytest.raises(DeintError, match="member 'core/1.npy' appears twice in the archive"):
        read_submission("dup.npz")
    npz("obj.npz", [("core/1.npy", npy(np.array([{"a": 1}], dtype=object)))])
    header, items = read_submission("obj.npz")
    assert items[0].labels == "the array holds Python objects, which only pickle could load"
    npz("good.npz", [("core/1.npy", npy(np.arange(3)))])
    assert read_submission("good.npz")[1][0].labels.tolist() == [0, 1, 2]


# ---- a full disk ---------------------------------------------------------------------------------------
def disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_full_disk_names_the_file_and_keeps_the_old_one(capsys, tmp_path, monkeypatch):
    Path("out.csv").write_text("old pulses\n")
    monkeypatch.setattr(files.os, "fsync", disk_full)
    refused(capsys, tmp_path, "simulate", SCENARIO, "--seed", 1, "-o", "out.csv",
            expected="deint: error: cannot write out.csv: No space left on device")


def test_full_disk_on_a_later_output_changes_no_output(capsys, tmp_path, monkeypatch):
    Path("out.csv").write_text("old pulses\n")
    Path("pr.json").write_text("{}\n")
    real = files.os.fsync
    calls = []

    def second_fails(fd):
        calls.append(fd)
        return real(fd) if len(calls) == 1 else disk_full()

    monkeypatch.setattr(files.os, "fsync", second_fails)
    refused(capsys, tmp_path, "simulate", SCENARIO, "--seed", 1, "-o", "out.csv", "--priors-out", "pr.json",
            expected="cannot write pr.json: No space left on device")
    assert len(calls) == 2


def test_write_all_publishes_together(tmp_path):
    files.write_all([("a.txt", "A"), ("b.bin", b"B")])
    assert Path("a.txt").read_text() == "A" and Path("b.bin").read_bytes() == b"B"
    with pytest.raises(DeintError, match="cannot write missing/c.txt"):
        files.write_all([("a.txt", "A2"), ("missing/c.txt", "C")])
    assert Path("a.txt").read_text() == "A" and sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.bin"]

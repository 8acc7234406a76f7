"""benchmarks/paired.py: the paired comparison the README's robust-v0 analysis was measured with."""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from deint_env.runner import evaluate

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "paired.py"


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("paired") / "r.jsonl"
    evaluate(["nearest-prior", "random"], "robust-v0/robust-missing0.1", split="train", max_seeds=18, out=out,
             progress=False)
    return out


def _run(args: list[str], capsys) -> tuple[int, str, str]:
    argv = sys.argv
    sys.argv = [str(SCRIPT), *args]
    try:
        with pytest.raises(SystemExit) as e:
            runpy.run_path(str(SCRIPT), run_name="__main__")
    finally:
        sys.argv = argv
    cap = capsys.readouterr()
    return e.value.code, cap.out, cap.err


def test_pairs_split_and_skip(results, capsys):
    scores = {}
    for line in results.read_text().splitlines():
        r = json.loads(line)
        scores.setdefault(r["seed"], {})[r["policy"]] = r["score"]
    d = np.array([v["nearest-prior"] - v["random"] for _, v in sorted(scores.items())])
    code, out, _ = _run([str(results), "nearest-prior", "random", "--rare", "0.5"], capsys)
    assert code == 0
    assert "all: 18 episodes" in out and f"difference {d.mean():+.5f}" in out
    big = np.abs(d) > 0.5
    assert f"rare: {big.sum()} episodes" in out and f"typical: {(~big).sum()} episodes" in out
    # offsets 10-15 of the train range are left out: 12 episodes remain, the mean of the others
    code, out, _ = _run([str(results), "nearest-prior", "random", "--skip-offsets", "10-15"], capsys)
    keep = np.r_[d[:10], d[16:]]
    assert code == 0 and "all: 12 episodes" in out and f"difference {keep.mean():+.5f}" in out


@pytest.mark.parametrize("args, message", [
    (["nearest-prior", "mht"], "policy 'mht' has no records"),
    (["nearest-prior", "random", "--skip-offsets", "5-2"], "must have 0 <= A <= B"),
    (["nearest-prior", "random", "--skip-offsets", "x"], "must be A-B or A"),
    (["nearest-prior", "random", "--rare", "-1"], "must be a finite number > 0"),
])
def test_bad_input_one_line(results, capsys, args, message):
    code, out, err = _run([str(results), *args], capsys)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and message in err


def test_missing_file(tmp_path, capsys):
    code, _, err = _run([str(tmp_path / "none.jsonl"), "a", "b"], capsys)
    assert code == 2 and "does not exist" in err

"""benchmarks/replay_board.py: a board's records played again and compared, and `--adopt` writing a
policy's replayed records in place of checked-in ones that differ."""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path

import pytest

from deint_env.cli import main

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "replay_board.py"


def _replay(capsys, *args: str) -> str:
    argv = sys.argv
    sys.argv = [str(SCRIPT), *args]
    try:
        runpy.run_path(str(SCRIPT), run_name="__main__")
    finally:
        sys.argv = argv
    return capsys.readouterr().out


@pytest.fixture()
def board(tmp_path, capsys) -> Path:
    code = main(["leaderboard", "--suite", "core-v0", "--scenarios", "core-n2-spread1.5-jitter0.05", "--max-seeds", "2",
                 "--policies", "nearest-prior,fdp", "--root", str(tmp_path / "lb"), "--workers", "1", "--reps", "100",
                 "--no-progress"])
    capsys.readouterr()
    assert code == 0
    return tmp_path / "lb"


def test_a_board_replays_equal_and_a_tampered_record_is_found_then_adopted(board, tmp_path, capsys):
    results = board / "core-v0" / "results.jsonl"
    common = ["core-v0", "--root", str(board), "--no-progress"]
    out = _replay(capsys, *common, "--work", str(tmp_path / "w1"))
    assert "4 episodes replayed and compared: 4 equal bit for bit" in out, out

    lines = results.read_text().splitlines(keepends=True)
    first = next(i for i, line in enumerate(lines) if json.loads(line)["policy"] == "fdp")
    tampered = json.loads(lines[first]) | {"accuracy": 0.123}
    lines[first] = json.dumps(tampered, sort_keys=True) + "\n"
    results.write_text("".join(lines))
    out = _replay(capsys, *common, "--work", str(tmp_path / "w2"))
    assert "fdp: 2 compared, 1 equal bit for bit, 0 within 1e-12, 1 differ" in out and "accuracy: 0.123 ->" in out, out

    # --adopt fdp puts the replayed record back in the tampered one's place; nothing else moves
    out = _replay(capsys, *common, "--work", str(tmp_path / "w2"), "--policies", "fdp", "--adopt", "fdp")
    assert "adopted 1 replayed records of fdp" in out, out
    after = results.read_text().splitlines(keepends=True)
    assert len(after) == len(lines) and [a for i, a in enumerate(after) if i != first] == [
        a for i, a in enumerate(lines) if i != first]
    assert json.loads(after[first])["accuracy"] != 0.123
    out = _replay(capsys, *common, "--work", str(tmp_path / "w3"))
    assert "4 episodes replayed and compared: 4 equal bit for bit" in out, out

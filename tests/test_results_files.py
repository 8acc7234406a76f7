"""Results files: typed, validated records; one writer at a time; repaired ends; no duplicates; stale
records replayed; leaderboards published all together or not at all."""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from deint_env import policies, results, runner
from deint_env.cli import main
from deint_env.errors import DeintError
from deint_env.leaderboard import Scope, build, render, write
from deint_env.results import EpisodeRecord, read_records, results_lock

ROOT = Path(__file__).resolve().parents[1]
TARGET = "paper-v0/mk94-two-var1"
SCOPE = Scope("core-v0", ("core-n2-spread1.5-jitter0.05",), max_seeds=2)


def deint(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def keys(path) -> list:
    return [EpisodeRecord.from_json(json.loads(line)).key for line in Path(path).read_text().splitlines()]


# ---------------------------------------------------------------------------------------------------
# records
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("suite", ["paper-v0", "core-v0", "robust-v0", "agile-v0"])
def test_checked_in_results_read_and_round_trip(suite):
    """The checked-in results read; writing them back changes nothing but, in records written before
    records were typed, the added policy_version (1)."""
    path = ROOT / "leaderboards" / suite / "results.jsonl"
    lines = path.read_text().splitlines()
    recs = read_records(path)
    assert len(recs) == len(lines)
    for line in lines[:: max(1, len(lines) // 300)]:
        data = json.loads(line)
        assert EpisodeRecord.from_json(data).to_json() == {"policy_version": 1, **data}


def test_a_played_record_is_the_record_its_file_line_reads_back(tmp_path):
    """What evaluate returns equals what the results file holds, field for field and metric for metric
    (the env's `lag` metric is the record's `lag` field, once): a replay compares them as they are."""
    out = tmp_path / "r.jsonl"
    played = runner.evaluate(["fdp", "mht:lag=3,nscan=3"], TARGET, max_seeds=1, out=out, progress=False)
    assert [dataclasses.replace(r, metrics={**r.metrics, "us_per_pulse": 0.0}) for r in played] == [
        dataclasses.replace(r, metrics={**r.metrics, "us_per_pulse": 0.0}) for r in read_records(out)]
    assert all("lag" not in r.metrics and r.lag == (3 if r.policy != "genie" else 0) for r in played)


@pytest.mark.parametrize("line,problem", [
    ("{}", "is not a results record: it has no policy"), ("5", "is not a results record (a JSON object), but 5"),
    ("null", "but null"), ("[1, 2]", "but [1, 2]"), ('"x"', 'but "x"'),
])
def test_json_that_is_not_a_record_is_one_line(tmp_path, capsys, line, problem):
    out = tmp_path / "res.jsonl"
    runner.evaluate(["random"], TARGET, max_seeds=1, progress=False, out=out)
    good = out.read_text()
    out.write_text(good + line + "\n")
    code, stdout, err = deint(capsys, "run", "--policies", "random", "--scenario", TARGET, "--max-seeds", 2,
                              "--out", out, "--no-progress")
    assert code == 2 and stdout == ""
    assert err == f"deint: error: {out}: line 2 {problem}\n" or err.startswith(f"deint: error: {out}: line 2: ")
    assert problem in err and err.count("\n") == 1
    assert out.read_text() == good + line + "\n"  # nothing written


def test_a_field_of_the_wrong_type_is_named(tmp_path):
    out = tmp_path / "res.jsonl"
    runner.evaluate(["random"], TARGET, max_seeds=1, progress=False, out=out)
    data = json.loads(out.read_text())
    out.write_text(json.dumps({**data, "seed": "7"}) + "\n")
    with pytest.raises(DeintError, match=r"res.jsonl: line 1: field 'seed' is \"7\", not a int"):
        read_records(out)
    out.write_text(json.dumps({**data, "seed": True}) + "\n")
    with pytest.raises(DeintError, match="field 'seed' is true"):
        read_records(out)


def test_duplicates_are_dropped_first_wins(tmp_path):
    out = tmp_path / "res.jsonl"
    runner.evaluate(["random"], TARGET, max_seeds=2, progress=False, out=out)
    a, b = out.read_text().splitlines()
    changed = json.dumps({**json.loads(a), "accuracy": 0.999}, sort_keys=True)
    out.write_text("\n".join([a, b, changed, a]) + "\n")
    recs = read_records(out)
    assert len(recs) == 2 and recs[0].get("accuracy") == json.loads(a)["accuracy"]


def test_missing_final_newline_is_repaired_before_appending(tmp_path):
    out = tmp_path / "res.jsonl"
    runner.evaluate(["random"], TARGET, max_seeds=1, progress=False, out=out)
    out.write_text(out.read_text().rstrip("\n"))  # a last record without its newline
    runner.evaluate(["random"], TARGET, max_seeds=3, progress=False, out=out)
    lines = out.read_text().splitlines()
    assert len(lines) == 3 and len(set(keys(out))) == 3
    runner.evaluate(["random"], TARGET, max_seeds=4, progress=False, out=out)  # and later runs go on
    assert len(read_records(out)) == 4


def test_two_runs_on_one_file_store_each_episode_once(tmp_path, capsys):
    out = tmp_path / "res.jsonl"
    argv = ["run", "--policies", "random,genie", "--scenario", TARGET, "--max-seeds", 2, "--out", out,
            "--no-progress", "--json"]
    assert deint(capsys, *argv)[0] == 0
    code, stdout, _ = deint(capsys, *argv)
    assert code == 0 and len(out.read_text().splitlines()) == 4
    assert all(r["episodes"] == 2 for r in json.loads(stdout))


# ---------------------------------------------------------------------------------------------------
# one writer
# ---------------------------------------------------------------------------------------------------
def test_a_second_writer_is_refused_in_process(tmp_path):
    out = tmp_path / "res.jsonl"
    script = textwrap.dedent(f"""
        import sys
        from deint_env.runner import evaluate
        from deint_env.errors import DeintError
        try:
            evaluate(["random"], {TARGET!r}, max_seeds=1, progress=False, out={str(out)!r})
        except DeintError as e:
            print(e)
            sys.exit(2)
    """)
    with results_lock(out):
        with results_lock(out):  # re-entrant in one process
            pass
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stdout.strip() == (f"{out}: another process is writing this results file (it holds "
                                   f".res.jsonl.lock); wait for it to finish or write elsewhere")
    assert not out.exists() and not results.lock_path(out).exists()  # released and removed


# A run whose policy holds its first episode until the test lets it go: `reset` runs inside the run's
# results lock, so while the hold file exists the run provably holds the lock (timing-free: under load a
# second process's start-up can outlast any fixed number of slow episodes, and the first run then
# releases the lock and ends before the second tries).
HELD_RUN = """
import os, sys, time
from deint_env import policies
from deint_env.cli import main
import baselines.floors as floors

hold, started = os.environ["DEINT_TEST_HOLD"], os.environ["DEINT_TEST_STARTED"]

class Held(floors.RandomPolicy):
    def reset(self, priors, info):
        open(started, "w").close()
        deadline = time.monotonic() + 300
        while os.path.exists(hold) and time.monotonic() < deadline:
            time.sleep(0.02)
        super().reset(priors, info)

policies.list_policies()
policies.register_policy("held-random", Held)
sys.exit(main(sys.argv[1:]))
"""


def _deint_process(*argv, hold: Path, script: str = HELD_RUN) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DEINT_TEST_HOLD": str(hold),
           "DEINT_TEST_STARTED": str(hold.with_suffix(".started"))}
    return subprocess.Popen([sys.executable, "-c", script, *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)


def test_two_concurrent_writers_lose_nothing_and_the_second_is_told(tmp_path):
    out, hold = tmp_path / "res.jsonl", tmp_path / "hold"
    started = hold.with_suffix(".started")
    argv = ["run", "--policies", "held-random", "--scenario", TARGET, "--max-seeds", 10, "--out", out, "--no-progress"]
    hold.touch()
    first = _deint_process(*argv, hold=hold)
    try:
        deadline = time.monotonic() + 120
        while not started.exists():  # the first is inside its run, so it holds the lock
            assert time.monotonic() < deadline and first.poll() is None, first.stderr.read() if first.poll() else ""
            time.sleep(0.05)
        second = _deint_process(*argv, hold=tmp_path / "no-hold")
        _, err2 = second.communicate(timeout=300)
        assert first.poll() is None  # still held: the refusal below was the lock's doing
    finally:
        hold.unlink()
    _, err1 = first.communicate(timeout=300)
    assert first.returncode == 0, err1
    assert second.returncode == 2, err2
    assert err2 == (f"deint: error: {out}: another process is writing this results file (it holds "
                    f".res.jsonl.lock); wait for it to finish or write elsewhere\n")
    got = keys(out)
    assert len(got) == 10 and len(set(got)) == 10  # none lost, none twice
    again = _deint_process(*argv, hold=tmp_path / "no-hold")
    assert again.wait(timeout=300) == 0 and keys(out) == got  # a later run finds everything done


def test_a_second_leaderboard_keeps_the_first_runs_records(tmp_path):
    build(SCOPE, ["random"], workers=1, root=tmp_path, progress=False, reps=100)
    path = tmp_path / "core-v0" / "results.jsonl"
    first = set(path.read_text().splitlines())
    lock = os.open(results.lock_path(path), os.O_CREAT | os.O_RDWR)
    fcntl.flock(lock, fcntl.LOCK_EX)  # another build in progress (another open file: as another process)
    try:
        with pytest.raises(DeintError, match="another process is writing this results file"):
            build(SCOPE, ["genie"], workers=1, root=tmp_path, progress=False, reps=100)
    finally:
        os.close(lock)
    assert set(path.read_text().splitlines()) == first
    _, board = build(SCOPE, ["genie"], workers=1, root=tmp_path, progress=False, reps=100)
    assert first <= set(path.read_text().splitlines()) and len(path.read_text().splitlines()) == 4
    assert {r["policy"] for r in board["rows"]} == {"genie", "random"}


# ---------------------------------------------------------------------------------------------------
# stale records
# ---------------------------------------------------------------------------------------------------
def test_records_of_another_policy_version_are_replayed(tmp_path, monkeypatch):
    root = tmp_path
    build(SCOPE, ["random"], workers=1, root=root, progress=False, reps=100)
    path = root / "core-v0" / "results.jsonl"
    v1 = path.read_text()
    played = []
    real = runner.run_job
    monkeypatch.setattr(runner, "run_job", lambda job: played.append(job) or real(job))
    policies.list_policies()
    monkeypatch.setitem(policies._REGISTRY, "random", dataclasses.replace(policies.policy_info("random"), version=2))
    # Only aggregating: the version-1 records are stale, never mixed in.
    board = write(root / "core-v0", SCOPE, reps=100)
    assert board["rows"] == [] and board["stale"] == {"random": 2}
    assert "stale" in (root / "core-v0" / "README.md").read_text()
    # Building replays them under version 2; the published file then drops the superseded ones.
    _, board = build(SCOPE, ["random"], workers=1, root=root, progress=False, reps=100)
    assert len(played) == 2 and all(j.policy_version == 2 for j in played)
    assert [r["policy_version"] for r in board["rows"]] == [2] and board["stale"] == {}
    recs = read_records(path)
    assert sorted(r.policy_version for r in recs) == [2, 2] and not set(v1.splitlines()) & set(
        path.read_text().splitlines())
    played.clear()
    build(SCOPE, ["random"], workers=1, root=root, progress=False, reps=100)
    assert played == []


# ---------------------------------------------------------------------------------------------------
# all files or none
# ---------------------------------------------------------------------------------------------------
def test_a_failed_publish_leaves_the_old_leaderboard(tmp_path, monkeypatch):
    folder, _ = build(SCOPE, ["random"], workers=1, root=tmp_path, progress=False, reps=100)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    real = Path.write_bytes

    def full_disk(self, data):
        if data.startswith(b"\x89PNG"):  # the PNGs come after JSON, CSV, README, HTML and results
            raise OSError(28, "No space left on device")
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(DeintError, match=r"cannot write .*core-v0/[^/]+\.png: No space left on device; "
                                         r"nothing was published"):
        build(SCOPE, ["random", "genie"], workers=1, root=tmp_path, progress=False, reps=100)
    after = {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "results.jsonl"}
    assert after == {k: v for k, v in before.items() if k != "results.jsonl"}  # untouched, no staging left
    # results.jsonl is the run's log: the played episodes were appended (and are not played again).
    now = set((folder / "results.jsonl").read_text().splitlines())
    assert set(before["results.jsonl"].decode().splitlines()) <= now


def test_run_on_a_full_disk_names_the_file(tmp_path, capsys, monkeypatch):
    out = tmp_path / "res.jsonl"
    def full_disk(fd, data):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(results, "_write", full_disk)
    code, stdout, err = deint(capsys, "run", "--policies", "random", "--scenario", TARGET, "--max-seeds", 2,
                              "--out", out, "--no-progress")
    assert code == 2 and err == f"deint: error: {out}: cannot write (No space left on device)\n"

"""Policy faults are recorded per episode and the run goes on; labels must be exact integers; Ctrl-C
ends quietly with the resume line; pool workers die with their parent."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from baselines.floors import RandomPolicy
from deint_env import policies, runner
from deint_env.cli import main
from deint_env.leaderboard import Scope, build
from deint_env.policies import PolicyInfo
from deint_env.results import read_records

ROOT = Path(__file__).resolve().parents[1]
TARGET = "paper-v0/mk94-two-var1"
BAD_SEED = 1000001  # the second test seed


class Labels(RandomPolicy):
    """Random labels, but on BAD_SEED every label is `label` (or `act` raises / the process dies)."""

    label: object = None

    def reset(self, priors, info):
        super().reset(priors, info)
        self.bad = info["policy_seed"] == BAD_SEED

    def act(self, obs):
        if not self.bad:
            return super().act(obs)
        if self.label == "raise":
            raise ZeroDivisionError("the policy divided by zero\nsecond line")
        if self.label == "die":
            os.kill(os.getpid(), signal.SIGKILL)
        return self.label


def register(monkeypatch, label) -> str:
    policies.list_policies()
    cls = type("Bad", (Labels,), {"label": label})
    monkeypatch.setitem(policies._REGISTRY, "bad", PolicyInfo("bad", cls))
    return "bad"


@pytest.mark.parametrize("label,error", [
    ("raise", "ZeroDivisionError: the policy divided by zero"),
    (None, "DeintError: action=None is invalid: a label is an integer (int or numpy integer) in [0, 2] "
           "(2 = spurious), not a NoneType"),
    (float("nan"), "DeintError: action=nan is invalid: a label is an integer"),
    (1.7, "DeintError: action=1.7 is invalid: a label is an integer"),
    ("1", "DeintError: action='1' is invalid: a label is an integer"),
    (np.float64(1.0), "not a float64"),
    (True, "DeintError: action=True is invalid: a label is an integer (int or numpy integer) in [0, 2] "
           "(2 = spurious), not a bool"),
    (7, "DeintError: action=7 is invalid: a label in [0, 2] (2 = spurious)"),
])
def test_a_policy_fault_is_recorded_and_the_run_goes_on(tmp_path, monkeypatch, capsys, label, error):
    register(monkeypatch, label)
    out = tmp_path / "res.jsonl"
    recs = runner.evaluate(["bad", "random"], TARGET, max_seeds=3, progress=False, out=out)
    assert len(recs) == 6
    faults = [r for r in recs if r.fault is not None]
    assert len(faults) == 1
    f = faults[0]
    assert (f.policy, f.scenario, f.seed) == ("bad", "mk94-two-var1", BAD_SEED)
    assert error in f.fault and "\n" not in f.fault
    # The summary says so: a faults column and a line naming policy, scenario, seed and the error.
    rows = {r["policy"]: r for r in runner.summarise(recs, reps=100)}
    assert rows["bad"]["faults"] == [{"scenario": "mk94-two-var1", "seed": BAD_SEED, "error": f.fault}]
    assert rows["bad"]["played"] == 2 and rows["bad"]["coverage"] == 2 / 3 and rows["random"]["faults"] == []
    table = runner.format_table(list(rows.values()))
    assert "faults" in table.splitlines()[0]
    assert f"bad, scenario mk94-two-var1, seed {BAD_SEED}: {f.fault}" in table
    assert "incomplete: 1 faulted episode(s)" in table


def test_numpy_integers_are_labels(monkeypatch):
    for label in (np.int64(1), np.int32(2), np.uint8(0)):
        register(monkeypatch, label)
        recs = runner.evaluate(["bad"], TARGET, max_seeds=2, progress=False)
        assert all(r.fault is None for r in recs)


class FailsOnce(RandomPolicy):
    """Random labels, but its first reset in a process raises (a warm-up's, in the test below)."""

    failed = False

    def reset(self, priors, info):
        if not FailsOnce.failed:
            FailsOnce.failed = True
            raise ZeroDivisionError("the first reset")
        super().reset(priors, info)


def test_a_policy_warms_up_untimed_once_per_process_and_scenario(monkeypatch):
    """A policy's first job on a scenario in a process plays the job's episode untimed before its timed
    play (a compiled policy's kernels load then, not on the clock), once per spec and scenario; an
    episode of more than _WARM_FULL pulses warms up on a short one; a failed warm-up is not the job's
    fault."""
    lengths = []

    def spy(policy, episode, **kw):
        lengths.append(len(episode))
        return play(policy, episode, **kw)

    play = runner.play
    monkeypatch.setattr(runner, "play", spy)
    monkeypatch.setattr(runner, "_WARMED", set())
    monkeypatch.setattr(FailsOnce, "failed", False)
    policies.list_policies()
    monkeypatch.setitem(policies._REGISTRY, "fails-once", PolicyInfo("fails-once", FailsOnce))
    for name in ("random", "fails-once"):
        lengths.clear()
        recs = runner.evaluate([name], TARGET, max_seeds=2, progress=False)
        assert lengths == [500, 500, 500]
        assert all(r.fault is None for r in recs)
    runner.evaluate(["random"], TARGET, max_seeds=1, progress=False)
    assert lengths == [500, 500, 500, 500]
    runner.evaluate(["random"], "paper-v0/mk94-two-var0.1", max_seeds=1, progress=False)  # another scenario
    assert lengths == [500, 500, 500, 500, 500, 500]
    monkeypatch.setattr(runner, "_WARM_FULL", 400)
    runner.evaluate(["random"], "paper-v0/mk94-two-var0.25", max_seeds=1, progress=False)
    assert lengths[-2:] == [runner._WARM_PULSES, 500]


def test_a_second_worker_does_not_start_a_policy_still_compiling():
    """`_next_task`: while a policy's first task runs (its kernels compiling), other policies' tasks go
    first; once it has finished a task, its tasks run on every worker; queue order is kept otherwise."""
    from collections import deque

    tasks = [(runner.Job(p, {}, s, "test", None, None, (), {}, 0),) for s in (1, 2) for p in ("mht", "fdp")]
    queue = deque(tasks)
    first = runner._next_task(queue, [], set())
    assert (first[0].policy, first[0].seed) == ("mht", 1)
    second = runner._next_task(queue, [first], set())
    assert (second[0].policy, second[0].seed) == ("fdp", 1)
    assert runner._next_task(queue, [first, second], set()) is None  # both still on their first task
    third = runner._next_task(queue, [first, second], {"mht"})
    assert (third[0].policy, third[0].seed) == ("mht", 2)
    assert runner._next_task(queue, [third], {"mht"})[0].policy == "fdp" and not queue


def test_a_rerun_retries_faults(tmp_path, monkeypatch, capsys):
    register(monkeypatch, "raise")
    out = tmp_path / "res.jsonl"
    argv = ["run", "--policies", "bad", "--scenario", TARGET, "--max-seeds", "2", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    stdout = capsys.readouterr().out
    assert f"bad, scenario mk94-two-var1, seed {BAD_SEED}: ZeroDivisionError" in stdout
    register(monkeypatch, 1)  # fixed
    assert main(argv) == 0
    assert "incomplete" not in capsys.readouterr().out
    recs = read_records(out)
    assert len(recs) == 2 and all(r.fault is None for r in recs)  # the played record supersedes the fault
    assert len(out.read_text().splitlines()) == 3


def test_leaderboard_lists_faults_and_does_not_rank_the_entry(tmp_path, monkeypatch):
    register(monkeypatch, 7)
    scope = Scope("paper-v0", ("mk94-two-var1",), max_seeds=2)
    folder, board = build(scope, ["bad", "random"], workers=1, root=tmp_path, progress=False, reps=100)
    rows = {r["policy"]: r for r in board["rows"]}
    assert rows["bad"]["rank"] is None and rows["random"]["rank"] == 1
    assert len(rows["bad"]["faults"]) == 1
    readme = (folder / "README.md").read_text()
    assert f"Faults: 1 episode(s) where a policy failed" in readme
    assert f"bad, scenario mk94-two-var1, seed {BAD_SEED}: DeintError: action=7 is invalid" in readme
    assert "faults" in (folder / "leaderboard.csv").read_text().splitlines()[0]


def test_a_killed_worker_is_that_episodes_fault(tmp_path, monkeypatch):
    register(monkeypatch, "die")
    out = tmp_path / "res.jsonl"
    recs = runner.evaluate(["bad", "random"], TARGET, max_seeds=4, workers=2, progress=False, out=out)
    assert len(recs) == 8
    faults = [r for r in recs if r.fault is not None]
    assert [(f.policy, f.seed) for f in faults] == [("bad", BAD_SEED)]
    assert faults[0].fault.startswith("the worker process died (BrokenProcessPool")
    assert len(read_records(out)) == 8


# ---------------------------------------------------------------------------------------------------
# interrupts and killed parents (real processes and signals)
# ---------------------------------------------------------------------------------------------------
SLOW = """
import signal, sys, time
# A test run started in the background (`cmd &` in a non-interactive shell) inherits SIGINT ignored,
# and Python then leaves it ignored: restore Ctrl-C's default so the signal this test sends is seen.
signal.signal(signal.SIGINT, signal.default_int_handler)
from deint_env import policies
from deint_env.cli import main
import baselines.floors as floors

class Slow(floors.RandomPolicy):
    def reset(self, priors, info):
        time.sleep(1.0)  # long enough that a loaded machine still has episodes left when SIGINT lands
        super().reset(priors, info)

policies.list_policies()
policies.register_policy("slow-random", Slow)
sys.exit(main(sys.argv[1:]))
"""


def _start(out: Path, workers: int) -> subprocess.Popen:
    argv = ["run", "--policies", "slow-random", "--scenario", TARGET, "--out", str(out), "--no-progress",
            "--workers", str(workers)]
    return subprocess.Popen([sys.executable, "-c", SLOW, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=ROOT)


def _wait_for_records(proc: subprocess.Popen, out: Path, n: int) -> None:
    deadline = time.monotonic() + 90
    while not (out.exists() and len(out.read_text().splitlines()) >= n):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _interrupt_once(tmp_path: Path, k: int) -> None:
    out = tmp_path / f"res{k}.jsonl"
    proc = _start(out, workers=2)
    _wait_for_records(proc, out, 1)
    proc.send_signal(signal.SIGINT)
    stdout, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert stdout == ""
    saved = len(out.read_text().splitlines())
    assert err == f"deint: interrupted; {saved} of 10 episodes are saved in {out}, rerun to resume\n"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals and /proc as on Linux")
def test_ctrl_c_ends_quietly_with_the_resume_line(tmp_path):
    _interrupt_once(tmp_path, 0)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals and /proc as on Linux")
def test_ctrl_c_ends_quietly_every_time(tmp_path):
    for k in range(12):
        _interrupt_once(tmp_path, k)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_workers_die_with_their_parent(tmp_path):
    out = tmp_path / "res.jsonl"
    proc = _start(out, workers=2)
    _wait_for_records(proc, out, 1)
    workers = _children(proc.pid)
    assert len(workers) >= 2
    proc.kill()
    proc.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(Path(f"/proc/{w}").exists() and "Z" not in Path(f"/proc/{w}/stat").read_text().rsplit(")", 1)[1][:3]
              for w in workers):
        assert time.monotonic() < deadline, "pool workers outlived their parent"
        time.sleep(0.1)

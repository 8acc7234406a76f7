"""The runner on Ray (`executor="ray"`): the same jobs give the same records as the process pool.

Ray 2.x no longer has `local_mode` (ray.init(local_mode=True) raises "no longer supported"), so the
tests start a minimal local Ray instance once (two CPUs, no dashboard) and the runner joins it, as it
joins any instance already initialised in the process.  Starting it takes a few seconds.
"""

from __future__ import annotations

import json

import pytest
import ray
from tqdm import tqdm

from deint_env.cli import main
from deint_env.errors import DeintError
from deint_env.runner import evaluate, read_records

TARGET = "paper-v0/mk94-two-var1"
POLICIES = ["genie", "random", "nearest-prior"]
WALL_CLOCK = {"us_per_pulse"}


@pytest.fixture(scope="module")
def local_ray():
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield
    if started:
        ray.shutdown()


def comparable(records: list) -> dict:
    return {r.key: {k: v for k, v in r.to_json().items() if k not in WALL_CLOCK} for r in records}


def test_own_ray_instance_interrupted_then_resumed(tmp_path, monkeypatch):
    """Without a running instance the runner starts one and always shuts it down; an interrupt keeps
    the finished episodes, and a rerun (here on the process pool) plays only the rest."""

    assert not ray.is_initialized()
    real, seen = tqdm.update, []

    def interrupt_after_three(self, *args, **kwargs):
        seen.append(1)
        if len(seen) == 3:
            raise KeyboardInterrupt
        return real(self, *args, **kwargs)

    monkeypatch.setattr(tqdm, "update", interrupt_after_three)
    out = tmp_path / "res.jsonl"
    with pytest.raises(KeyboardInterrupt, match="interrupted; 3 of 6 episodes are saved"):
        evaluate(["genie", "random"], TARGET, max_seeds=3, workers=2, progress=False, out=out, executor="ray")
    assert not ray.is_initialized() and len(out.read_text().splitlines()) == 3
    monkeypatch.setattr(tqdm, "update", real)
    records = evaluate(["genie", "random"], TARGET, max_seeds=3, workers=2, progress=False, out=out)
    assert len(records) == 6 and len(out.read_text().splitlines()) == 6


def test_ray_records_equal_the_process_pool(local_ray, tmp_path):
    pool = evaluate(POLICIES, TARGET, max_seeds=3, workers=2, progress=False, out=tmp_path / "pool.jsonl")
    on_ray = evaluate(POLICIES, TARGET, max_seeds=3, workers=2, progress=False, out=tmp_path / "ray.jsonl",
                      executor="ray")
    assert len(on_ray) == len(pool) == 9
    assert comparable(on_ray) == comparable(pool)
    assert comparable(read_records(tmp_path / "ray.jsonl")) == comparable(pool)  # streamed to the file
    assert ray.is_initialized()  # an instance the runner did not start is left running


def test_ray_resumes_a_file_the_pool_started(local_ray, tmp_path):
    out = tmp_path / "res.jsonl"
    first = evaluate(["random"], TARGET, max_seeds=2, workers=2, progress=False, out=out)
    both = evaluate(["random", "genie"], TARGET, max_seeds=2, progress=False, out=out, executor="ray")
    lines = out.read_text().splitlines()
    assert len(lines) == 4 and lines[:2] == [r.line().rstrip("\n") for r in first]
    assert {r.policy for r in both} == {"random", "genie"}
    again = evaluate(["random", "genie"], TARGET, max_seeds=2, progress=False, out=out, executor="ray")
    assert len(out.read_text().splitlines()) == 4 and comparable(again) == comparable(both)


def test_cli_run_on_ray(local_ray, tmp_path, capsys):
    code = main(["run", "--policies", "genie,random", "--scenario", TARGET, "--max-seeds", "2", "--out",
                 str(tmp_path / "r.jsonl"), "--executor", "ray", "--no-progress", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    rows = {r["policy"]: r for r in json.loads(out)}
    assert rows["genie"]["episodes"] == 2 and rows["genie"]["score_mean"] == 1.0


def test_bad_executor_arguments(capsys):
    with pytest.raises(DeintError, match="executor='spark' is invalid: one of local, ray"):
        evaluate(["random"], TARGET, max_seeds=1, progress=False, executor="spark")
    with pytest.raises(DeintError, match="needs executor='ray'"):
        evaluate(["random"], TARGET, max_seeds=1, progress=False, address="auto")
    code = main(["run", "--policies", "random", "--scenario", TARGET, "--executor", "dask"])
    assert code == 2 and "invalid choice: 'dask'" in capsys.readouterr().err

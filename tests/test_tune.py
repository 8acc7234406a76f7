"""`deint tune` (deint_env/tune.py) and the tuned entries (baselines/tuned.py): a tiny tune writes its
preset, the preset plays, reruns replay nothing, and neither tuning nor training ever simulates a
test seed."""

from __future__ import annotations

import json
import sys

import pytest

import baselines.tuned
from deint_env import cli, runner
from deint_env.results import read_records
from deint_env.suites import load_suite
from deint_env.tune import LMHT_SEARCH, SPACES, Choice, Rung, check_not_test_seeds, plays, schedule, tune

SUITE = "core-v0"
SCENARIOS = ("core-n2-spread1.5-jitter0.05", "core-n3-spread4-jitter0.05")
PRESET_KEYS = {"policy", "base_version", "suite", "suite_hash", "division", "scenarios", "params", "spec",
               "validation", "search", "command", "package_version"}


def tiny_tune(tmp_path, **kw):
    """fdp on two scenarios, 4 candidates: rung 0 on 1 seed, the survivor on 3 (14 plays)."""
    args = dict(division="online", budget=14, configs=4, workers=1, out=tmp_path / "presets" / "fdp" /
                f"{SUITE}.online.json", work=tmp_path / "work", scenarios=SCENARIOS, progress=False,
                log=lambda *_: None)
    return tune("fdp", SUITE, **{**args, **kw})


def run_cli(argv, capsys):
    status = cli.main(argv)
    return status, capsys.readouterr()


def test_a_tiny_tune_writes_its_preset_and_the_tuned_entry_plays(tmp_path, monkeypatch, capsys):
    result = tiny_tune(tmp_path)
    preset = json.loads(result.path.read_text())
    assert set(preset) == PRESET_KEYS and preset["policy"] == "fdp" and preset["base_version"] == 2
    assert preset["suite_hash"] == load_suite(SUITE).content_hash and preset["division"] == "online"
    assert preset["search"]["method"] == "successive halving" and preset["search"]["plays"] <= 14
    assert [r["configs"] for r in preset["search"]["rungs"]] == [4, 1]
    assert preset["validation"]["episodes"] == 2 * preset["validation"]["seeds_per_scenario"]
    assert preset["command"].startswith("deint tune fdp --suite core-v0 --division online --budget 14")
    monkeypatch.setattr(baselines.tuned, "PRESET_DIR", tmp_path / "presets")
    spec = f"fdp-tuned:suite={SUITE},division=online"
    assert baselines.tuned.variants(SUITE) == ["fdp-tuned:division=online,suite=core-v0"]  # its board's rows
    assert baselines.tuned.variants("robust-v0") == []
    version = runner.make_jobs([spec], f"{SUITE}/{SCENARIOS[0]}", split="validation", max_seeds=1)[0].policy_version
    assert version.startswith("2:") and len(version) == 2 + 12  # keyed on the preset
    status, out = run_cli(["run", "--policy", spec, "--scenario", f"{SUITE}/{SCENARIOS[0]}", "--split", "validation",
                           "--max-seeds", "1", "--out", str(tmp_path / "r.jsonl"), "--no-progress", "--json"], capsys)
    assert status == 0, out.err
    assert json.loads(out.out)[0]["played"] == 1


def test_a_rerun_replays_nothing_and_writes_the_same_bytes(tmp_path):
    first = tiny_tune(tmp_path)
    data, n = first.path.read_bytes(), len(read_records(tmp_path / "work" / "results.jsonl"))
    again = tiny_tune(tmp_path)
    assert again.path.read_bytes() == data and len(read_records(tmp_path / "work" / "results.jsonl")) == n


def _in(seed, r):
    return r.start <= seed < r.stop


def test_tuning_never_simulates_a_test_seed(tmp_path, monkeypatch):
    seen = []
    real = runner.simulate  # evaluate with workers=1 plays in this process, through runner's name

    def recording(spec, seed):
        seen.append((spec.name, seed))
        return real(spec, seed)

    monkeypatch.setattr(runner, "simulate", recording)
    tiny_tune(tmp_path, budget=30, configs=5)
    entries = {e.name: e for e in load_suite(SUITE)}
    assert {name for name, _ in seen} == set(SCENARIOS)
    for name, seed in seen:
        assert _in(seed, entries[name].seeds("validation")) and not _in(seed, entries[name].seeds("test"))
    with pytest.raises(Exception, match="not a validation seed"):
        check_not_test_seeds(SUITE, [(SCENARIOS[0], entries[SCENARIOS[0]].test.start)])


def test_training_never_simulates_a_test_seed(tmp_path, monkeypatch):
    pytest.importorskip("sb3_contrib")  # the [rl] extra
    import importlib

    from agents.train import TrainConfig, train

    simulate_module = importlib.import_module("deint_env.simulate")  # deint_env.simulate is also the function
    seen = []
    real_many = simulate_module.simulate_many

    def recording_many(spec, seeds):
        seen.extend((spec.name, int(s)) for s in seeds)
        return real_many(spec, seeds)

    def recording_one(spec, seed):
        return recording_many(spec, [seed])[0]

    # every module's own name for the simulator (the vector envs import simulate_many by name)
    for module in list(sys.modules.values()):
        for attr, fake in (("simulate_many", recording_many), ("simulate", recording_one)):
            if getattr(module, attr, None) in (real_many, simulate_module.simulate):
                monkeypatch.setattr(module, attr, fake)
    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  rollout_steps: 64\n  epochs: 1\n  policy_kwargs: {d_model: 8, heads: 2}\n")
    scenario = f"{SUITE}/{SCENARIOS[1]}"
    train(TrainConfig(out=tmp_path / "bc", algo="bc", expert="nearest-prior", scenarios=(scenario,), n_envs=2,
                      timesteps=128, eval_every=64, eval_episodes=2, hyperparams_file=hp, progress=False))
    entry = load_suite(SUITE).entry(SCENARIOS[1])
    assert seen and {name for name, _ in seen} == {SCENARIOS[1]}
    assert not [s for _, s in seen if _in(s, entry.seeds("test"))]
    assert any(_in(s, entry.seeds("validation")) for _, s in seen)  # the evaluations are validation episodes


@pytest.mark.parametrize("argv, match", [
    (["tune", "nosuch", "--suite", SUITE], "policy 'nosuch' is unknown"),
    (["tune", "genie", "--suite", SUITE], "has no search space"),
    (["tune", "fdp", "--suite", "nosuch-v0"], "suite 'nosuch-v0' is unknown"),
    (["tune", "fdp", "--suite", SUITE, "--budget", "0"], "budget=0 is invalid"),
    (["tune", "cdif", "--suite", "blind-v0", "--division", "online"], "cannot be tuned for division 'online'"),
    (["run", "--policy", "mht-tuned:suite=scale-v0", "--suite", "scale-v0", "--split", "validation"],
     "no preset for suite scale-v0"),
])
def test_bad_input_is_one_line(tmp_path, monkeypatch, capsys, argv, match):
    monkeypatch.chdir(tmp_path)  # a default work directory would land here
    status, out = run_cli(argv, capsys)
    assert status == cli.EXIT_ERROR and match in out.err and len(out.err.strip().splitlines()) == 1


def test_a_preset_of_another_base_version_is_refused(tmp_path, monkeypatch):
    result = tiny_tune(tmp_path)
    preset = json.loads(result.path.read_text())
    result.path.write_text(json.dumps({**preset, "base_version": 1}))
    monkeypatch.setattr(baselines.tuned, "PRESET_DIR", tmp_path / "presets")
    with pytest.raises(Exception, match="tuned for fdp version 1, not the current 2: re-tune"):
        baselines.tuned.fdp_tuned(SUITE, "online")


def test_the_schedule_fits_its_budget():
    rungs = schedule(27, 3, 4000, 45, 1000)
    assert [r.configs for r in rungs] == [27, 9, 3, 1] and [r.seeds for r in rungs] == [1, 3, 9, 27]
    assert plays(rungs, 45) <= 4000 < plays(schedule(27, 3, 10**6, 45, 1000), 45)
    assert schedule(27, 3, 200, 45, 1000) == [Rung(2, 1), Rung(1, 3)]  # too small for 27: fewer candidates


def test_mht_space_covers_lmht_search():
    from agents.lmht import SEARCH

    assert LMHT_SEARCH == SEARCH and SPACES["mht"].known == (SEARCH,)
    for key, value in SEARCH.items():
        param = SPACES["mht"].params[key]
        assert isinstance(param, Choice) and value in param.values

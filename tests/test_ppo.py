"""The learned `ppo` agent: registry, the committed checkpoint's accuracy, refusals, a smoke training."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")  # the [rl] extra

from agents.ppo import CHECKPOINT, PPOPolicy, main, sidecar_path, train  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.policies import list_policies, make_policy  # noqa: E402
from deint_env.runner import evaluate, play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

META = json.loads(sidecar_path(CHECKPOINT).read_text())


def test_registering_agents_imports_no_torch():
    code = ("import sys, deint_env; from deint_env.policies import policy_info; policy_info('ppo'); "
            "assert not {'torch', 'stable_baselines3'} & set(sys.modules)")
    subprocess.run([sys.executable, "-c", code], check=True)
    assert "ppo" in {p.name for p in list_policies()}


def test_checkpoint_matches_its_scenario():
    entry = find_entry(META["scenario"])
    assert META["scenario_hash"] == entry.spec.content_hash  # retrain when the scenario changes
    assert META["n_labels"] == entry.spec.n_labels == 2
    assert CHECKPOINT.stat().st_size < 1_000_000


def test_ppo_beats_random_and_nearest_prior_on_test_seeds():
    records = evaluate(["ppo", "nearest-prior"], META["scenario"], split="test", max_seeds=3, progress=False)
    acc = {p: np.mean([r.get("accuracy") for r in records if r.policy == p]) for p in ("ppo", "nearest-prior")}
    random_acc = np.mean([r.get("random_accuracy") for r in records])
    genie_acc = np.mean([r.get("genie_accuracy") for r in records])
    # Measured over all 10 test seeds: ppo 0.996, genie 0.998, nearest-prior 0.57, random 0.33.
    assert acc["ppo"] > random_acc + 0.5
    assert acc["ppo"] > acc["nearest-prior"] + 0.2
    assert acc["ppo"] > genie_acc - 0.05


def test_ppo_refuses_other_track_counts_and_blind_scenarios():
    policy = make_policy("ppo")
    three = simulate(find_entry("core-v0/core-n3-spread4-jitter0.05").spec, 0)
    with pytest.raises(DeintError, match="trained for 2 tracks"):
        policy.reset(three.priors, {})
    blind = simulate(find_entry("blind-v0/blind-n2to2-jitter0.1").spec, 0)
    with pytest.raises(DeintError, match="blind"):
        policy.reset(blind.priors, {})


def test_missing_checkpoint_is_one_clear_error(tmp_path):
    with pytest.raises(DeintError, match="does not exist"):
        PPOPolicy(checkpoint=str(tmp_path / "nothing.zip"))


def test_stochastic_ppo_is_reproducible_per_seed():
    episode = simulate(find_entry(META["scenario"]).spec, 1_000_000)
    a = play(PPOPolicy(deterministic=False), episode, policy_seed=4, clustering=False).labels
    b = play(PPOPolicy(deterministic=False), episode, policy_seed=4, clustering=False).labels
    assert np.array_equal(a, b)


def test_evaluate_command_prints_the_table(capsys):
    assert main(["evaluate", "--max-seeds", "1"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ("ppo", "random", "genie", "nearest-prior"))


@pytest.mark.slow
def test_smoke_training_writes_a_usable_checkpoint(tmp_path):
    out = train(META["scenario"], total_timesteps=2048, seed=1, out=tmp_path / "smoke.zip")
    meta = json.loads(sidecar_path(out).read_text())
    assert meta["timesteps"] >= 2048 and meta["scenario"] == META["scenario"] and meta["seed"] == 1
    episode = simulate(find_entry(META["scenario"]).spec, 5)
    labels = play(PPOPolicy(checkpoint=str(out)), episode, clustering=False).labels
    assert labels.shape == (len(episode),) and labels.min() >= 0 and labels.max() <= 2

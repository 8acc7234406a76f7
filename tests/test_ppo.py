"""The checked-in `ppo` agent: registry, its accuracy on test seeds, refusals, reproducible sampling."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")  # the [rl] extra

from agents.checkpoint import read_meta  # noqa: E402
from agents.policy import PPO_CHECKPOINT, AgentPolicy, ppo  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.policies import list_policies, make_policy  # noqa: E402
from deint_env.runner import evaluate, play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry, load_suite  # noqa: E402

META = read_meta(PPO_CHECKPOINT)
SCENARIO = META.scenarios[0]


def test_registering_agents_imports_no_torch():
    code = ("import sys, deint_env; from deint_env.policies import policy_info; policy_info('ppo'); "
            "policy_info('agent'); assert not {'torch', 'stable_baselines3'} & set(sys.modules)")
    subprocess.run([sys.executable, "-c", code], check=True)
    assert {"ppo", "agent"} <= {p.name for p in list_policies()}


def test_checkpoint_matches_its_scenario():
    entry = find_entry(SCENARIO)
    assert META.notes["scenario_hash"] == entry.spec.content_hash  # retrain when the scenario changes
    assert META.suite_hashes == {"core-v0": load_suite("core-v0").content_hash}
    assert META.features == {"layout": "pulse", "n_labels": 2, "version": 1}
    assert PPO_CHECKPOINT.suffix == ".safetensors" and PPO_CHECKPOINT.stat().st_size < 1_000_000


def test_ppo_beats_random_and_nearest_prior_on_test_seeds():
    records = evaluate(["ppo", "nearest-prior"], SCENARIO, split="test", max_seeds=3, progress=False)
    acc = {p: np.mean([r.get("accuracy") for r in records if r.policy == p]) for p in ("ppo", "nearest-prior")}
    random_acc = np.mean([r.get("random_accuracy") for r in records])
    genie_acc = np.mean([r.get("genie_accuracy") for r in records])
    # Measured over all 10 test seeds: ppo 0.996, genie 0.998, nearest-prior 0.57, random 0.33.
    assert acc["ppo"] > random_acc + 0.5
    assert acc["ppo"] > acc["nearest-prior"] + 0.2
    assert acc["ppo"] > genie_acc - 0.05


def test_ppo_is_the_agent_policy_on_the_shipped_checkpoint():
    episode = simulate(find_entry(SCENARIO).spec, 1_000_001)
    a = play(make_policy("ppo"), episode, clustering=False).labels
    b = play(make_policy(f"agent:checkpoint={PPO_CHECKPOINT}"), episode, clustering=False).labels
    assert np.array_equal(a, b)


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
        AgentPolicy(checkpoint=str(tmp_path / "nothing.safetensors"))


def test_stochastic_ppo_is_reproducible_per_seed():
    episode = simulate(find_entry(SCENARIO).spec, 1_000_000)
    a = play(ppo(deterministic=False), episode, policy_seed=4, clustering=False).labels
    b = play(ppo(deterministic=False), episode, policy_seed=4, clustering=False).labels
    assert np.array_equal(a, b)

"""Checkpoints: one safetensors file, rebuilt from its JSON, never unpickled; identified by content."""

from __future__ import annotations

import json
import pickle
import struct
import subprocess
import sys
import zipfile

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # the [rl] extra

from agents.checkpoint import CheckpointMeta, load_checkpoint, save_checkpoint  # noqa: E402
from agents.networks import (TrackPolicy, action_scores, architecture_of, build_policy,  # noqa: E402
                             load_weights, weights_of)
from agents.policy import PPO_CHECKPOINT, AgentPolicy  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.features import TrackLayout  # noqa: E402
from deint_env.runner import play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

LAYOUT = TrackLayout(max_tracks=6, lookahead=0)


class _Boom:
    """Unpickling this creates a file: the proof that something was unpickled."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _meta(arch, **changes) -> CheckpointMeta:
    base = dict(architecture=arch, features=LAYOUT.to_dict(), algorithm="ppo", scenarios=["core-v0/x"],
                suite_hashes={"core-v0": "0"}, train_seeds=[0, 99000], timesteps=0, hyperparameters={},
                versions={}, seed=0)
    return CheckpointMeta(**{**base, **changes})


def _random_agent(path, seed=0):
    torch.manual_seed(seed)
    net = TrackPolicy(LAYOUT.observation_space(), __import__("gymnasium").spaces.Discrete(LAYOUT.n_actions),
                      lambda _: 1e-3, d_model=16, heads=2)
    key = save_checkpoint(path, weights_of(net), _meta(architecture_of(net)))
    return net, key


def test_roundtrip_rebuilds_the_same_network(tmp_path):
    net, key = _random_agent(tmp_path / "a.safetensors")
    ck = load_checkpoint(tmp_path / "a.safetensors")
    assert ck.key == key and key.startswith("sha256:") and ck.meta.architecture["name"] == "track-net"
    again = build_policy(ck.meta.architecture, ck.meta.features)
    load_weights(again, ck.tensors, "x")
    obs = {k: np.random.default_rng(1).uniform(0, 1, (5, *s.shape)).astype(np.float32)
           for k, s in LAYOUT.observation_space().spaces.items()}
    net.eval()
    assert torch.allclose(action_scores(net, obs), action_scores(again, obs), rtol=1e-5, atol=1e-6)


def test_key_follows_content_and_a_rewritten_path_is_reloaded(tmp_path):
    path = tmp_path / "agent.safetensors"
    _, k1 = _random_agent(path, seed=1)
    first = AgentPolicy(str(path))
    _, k2 = _random_agent(path, seed=2)  # retrained to the same path
    second = AgentPolicy(str(path))
    assert k1 != k2 and (first.version, second.version) == (k1, k2)


def test_pickles_and_zips_are_refused_without_running_them(tmp_path):
    marker = tmp_path / "pwned"
    payload = pickle.dumps(_Boom(str(marker)))
    (tmp_path / "p.safetensors").write_bytes(payload)
    with zipfile.ZipFile(tmp_path / "sb3.zip", "w") as z:  # the layout of an SB3 checkpoint
        z.writestr("data", json.dumps({"policy_class": {":serialized:": payload.hex()}}))
        z.writestr("policy.pth", payload)
    torch.save({"w": torch.zeros(2)}, tmp_path / "torch.pt")
    for name, what in (("p.safetensors", "pickle"), ("sb3.zip", "zip"), ("torch.pt", "zip")):
        with pytest.raises(DeintError, match=what) as err:
            AgentPolicy(str(tmp_path / name))
        assert "\n" not in str(err.value)
    assert not marker.exists()


def test_a_header_length_ending_in_0x80_is_not_taken_for_a_pickle(tmp_path):
    """A safetensors file starts with its header length: low byte 0x80 is a pickle's first byte."""
    net, _ = _random_agent(tmp_path / "a.safetensors")
    path = tmp_path / "b.safetensors"
    for pad in range(256):
        save_checkpoint(path, weights_of(net), _meta(architecture_of(net), notes={"pad": "x" * pad}))
        if path.read_bytes()[0] == 0x80:
            break
    assert path.read_bytes()[0] == 0x80
    assert load_checkpoint(path).meta.notes["pad"] == "x" * pad


def test_malformed_and_foreign_safetensors_are_refused(tmp_path):
    from safetensors.torch import save_file

    save_file({"w": torch.zeros(2)}, tmp_path / "plain.safetensors")
    cases = {
        "plain.safetensors": "not a deint checkpoint",
        "huge.safetensors": "impossible",
        "text.safetensors": "not JSON",
        "short.safetensors": "too short",
    }
    (tmp_path / "huge.safetensors").write_bytes(struct.pack("<Q", 10**12) + b"{}")
    (tmp_path / "text.safetensors").write_bytes(struct.pack("<Q", 4) + b"nope")
    (tmp_path / "short.safetensors").write_bytes(b"{}")
    for name, match in cases.items():
        with pytest.raises(DeintError, match=match):
            load_checkpoint(tmp_path / name)


def test_tampered_metadata_and_mismatched_tensors_are_refused(tmp_path):
    from safetensors.torch import save

    net, _ = _random_agent(tmp_path / "a.safetensors")
    w = weights_of(net)
    bad_arch = _meta({"name": "exec", "code": "import os"})
    (tmp_path / "arch.safetensors").write_bytes(save(dict(w), metadata={"format": "deint-checkpoint/1",
                                                                        "meta": bad_arch.to_json()}))
    with pytest.raises(DeintError, match="architecture 'exec' is unknown"):
        AgentPolicy(str(tmp_path / "arch.safetensors"))
    w.pop(next(iter(w)))
    save_checkpoint(tmp_path / "missing.safetensors", w, _meta(architecture_of(net)))
    with pytest.raises(DeintError, match="do not match its architecture"):
        AgentPolicy(str(tmp_path / "missing.safetensors"))
    deep = "[" * 100_000 + "]" * 100_000
    (tmp_path / "deep.safetensors").write_bytes(save({"w": torch.zeros(1)}, metadata={
        "format": "deint-checkpoint/1", "meta": deep}))
    with pytest.raises(DeintError, match="not valid JSON"):
        load_checkpoint(tmp_path / "deep.safetensors")


def test_cli_refuses_a_pickle_checkpoint_with_one_line(tmp_path):
    marker = tmp_path / "pwned"
    (tmp_path / "evil.zip").write_bytes(b"PK\x03\x04" + pickle.dumps(_Boom(str(marker))))
    run = subprocess.run([sys.executable, "-c", "from deint_env.cli import main; raise SystemExit(main())", "run",
                          "--suite", "core-v0",
                          "--policies", f"agent:checkpoint={tmp_path / 'evil.zip'}", "--max-seeds", "1",
                          "--out", str(tmp_path / "r.jsonl")], capture_output=True, text=True)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1 and "zip" in run.stderr
    assert not marker.exists() and not (tmp_path / "r.jsonl").exists()


def test_token_agent_plays_two_to_eight_sources_and_blind(tmp_path):
    path = tmp_path / "a.safetensors"
    layout = TrackLayout(max_tracks=8, lookahead=2)
    torch.manual_seed(0)
    import gymnasium as gym

    net = TrackPolicy(layout.observation_space(), gym.spaces.Discrete(layout.n_actions), lambda _: 1e-3, d_model=16)
    save_checkpoint(path, weights_of(net), _meta(architecture_of(net), features=layout.to_dict()))
    for name in ("core-v0/core-n2-spread4-jitter0.05", "core-v0/core-n8-spread4-jitter0.05",
                 "blind-v0/blind-n2to2-jitter0.1"):
        episode = simulate(find_entry(name).spec.replace(n_pulses=80), 3)
        labels = play(AgentPolicy(str(path)), episode, clustering=False).labels
        assert labels.shape == (80,) and labels.min() >= 0 and labels.max() <= episode.n_labels
    agent = AgentPolicy(str(path))
    assert agent.lag == 2
    with pytest.raises(DeintError, match="at most 8 tracks"):
        agent.reset(simulate(find_entry("scale-v0/scale-10000p-16s").spec.replace(n_pulses=50), 0).priors, {})


def test_shipped_ppo_checkpoint_is_safetensors():
    assert PPO_CHECKPOINT.read_bytes()[:1] != b"P" and load_checkpoint(PPO_CHECKPOINT).meta.algorithm == "PPO"


@pytest.mark.parametrize("path", sorted(PPO_CHECKPOINT.parent.glob("*.safetensors")), ids=lambda p: p.name)
def test_every_shipped_checkpoint_loads_and_matches_its_suites(path):
    from deint_env.suites import load_suite

    from deint_env.policies import make_policy

    agent = make_policy(f"agent:checkpoint={path}")  # the generic spec rebuilds any architecture
    assert agent.meta.suite_hashes == {s: load_suite(s).content_hash for s in agent.meta.suite_hashes}
    assert all(s.split("/")[0] in agent.meta.suite_hashes for s in agent.meta.scenarios)
    assert agent.meta.train_seeds[1] <= 100_000  # train seeds only; test seeds start at 1,000,000


def test_shipped_dagger_agent_beats_the_floors_on_a_core_test_episode():
    path = PPO_CHECKPOINT.parent / "dagger-core-v0-lag3.safetensors"
    episode = simulate(find_entry("core-v0/core-n4-spread4-jitter0.05").spec, 1_000_000)
    result = play(AgentPolicy(str(path)), episode, clustering=False)
    # Measured on the first test seed of all 45 core-v0 scenarios: mean accuracy 0.888 (fdp 0.890).
    assert result.metrics["accuracy"] > 0.9


@pytest.mark.parametrize("n", [2, 3, 8])
def test_one_checkpoint_labels_pulse_files_of_any_source_count(tmp_path, n):
    from deint_env.cli import main
    from deint_env.formats import write_priors, write_pulses

    episode = simulate(find_entry(f"core-v0/core-n{n}-spread4-jitter0.05").spec.replace(n_pulses=300), 1_000_000)
    write_pulses(tmp_path / "p.csv", episode, truth=False)
    write_priors(tmp_path / "pr.json", episode.priors)
    ck = PPO_CHECKPOINT.parent / "dagger-core-v0-lag3.safetensors"
    assert main(["label", str(tmp_path / "p.csv"), "--policy", f"agent:checkpoint={ck}", "--priors",
                 str(tmp_path / "pr.json"), "-o", str(tmp_path / "l.csv")]) == 0
    labels = np.loadtxt(tmp_path / "l.csv", delimiter=",", skiprows=1, usecols=1).astype(int)
    truth = np.where(episode.source >= 0, episode.source, -1)
    # Measured with the checked-in agent on these 300 pulses: accuracy 0.993, 0.987, 0.957 (2, 3, 8 sources).
    assert labels.shape == (300,) and np.mean(labels == truth) > 0.85


def test_retraining_to_the_same_path_replays_its_episodes(tmp_path):
    """Results of `agent:checkpoint=PATH` are keyed on the checkpoint's content, not its path."""
    import shutil

    from deint_env.policies import spec_version
    from deint_env.runner import evaluate

    from agents.policy import checkpoint_version

    path, out = tmp_path / "agent.safetensors", tmp_path / "results.jsonl"
    spec, target = f"agent:checkpoint={path}", "core-v0/core-n2-spread4-jitter0.05"
    shutil.copyfile(PPO_CHECKPOINT, path)
    first = evaluate([spec], target, max_seeds=1, out=out, progress=False)
    assert [r.policy_version for r in first] == [checkpoint_version(PPO_CHECKPOINT)] == [spec_version(spec)]
    again = evaluate([spec], target, max_seeds=1, out=out, progress=False)  # unchanged: resumed, not replayed
    assert [r.key for r in again] == [r.key for r in first] and len(out.read_text().splitlines()) == 1
    shutil.copyfile(PPO_CHECKPOINT.parent / "dagger-core-v0-lag3.safetensors", path)  # "retrained"
    second = evaluate([spec], target, max_seeds=1, out=out, progress=False)
    assert [r.policy_version for r in second] == [spec_version(spec)] != [r.policy_version for r in first]
    assert second[0].lag == 3 and len(out.read_text().splitlines()) == 2  # played again, not reused

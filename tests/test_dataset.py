"""`deint dataset` / agents.dataset: demonstrations as Minari datasets, read back with minari."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

minari = pytest.importorskip("minari")

from agents.dataset import DatasetConfig, write_dataset  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.policies import make_policy  # noqa: E402
from deint_env.runner import accuracy_of, play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

N2, N3 = "core-v0/core-n2-spread4-jitter0.2", "core-v0/core-n3-spread4-jitter0.05"


def load(root, dataset_id, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return minari.load_dataset(dataset_id)


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "from deint_env.cli import main; raise SystemExit(main())", "dataset",
                           *args], capture_output=True, text=True)


def test_raw_dataset_holds_the_policys_labels_and_the_truth(tmp_path, monkeypatch):
    dest, n = write_dataset(DatasetConfig("deint/fdp-v0", policy="fdp", scenarios=(N3,), seeds=2, root=tmp_path))
    assert n == 2 and dest == tmp_path / "deint" / "fdp-v0"
    dataset = load(tmp_path, "deint/fdp-v0", monkeypatch)
    assert dataset.total_episodes == 2
    lag = make_policy("fdp").lag
    for seed, ep in zip(find_entry(N3).train, dataset.iterate_episodes()):
        assert ep.id in (0, 1)
        episode = simulate(find_entry(N3).spec, seed)
        labels = play(make_policy("fdp"), episode, clustering=False).labels
        steps = len(episode) + lag
        assert len(ep.actions) == steps and len(ep.infos["pulse"]) == steps + 1  # infos[k + 1]: step k
        np.testing.assert_array_equal(ep.actions[lag:], labels)  # actions are the policy's labels
        np.testing.assert_array_equal(ep.infos["reference_label"][lag + 1:], labels)
        truth = np.where(episode.source >= 0, episode.source, episode.n_labels)
        np.testing.assert_array_equal(ep.infos["true_label"][lag + 1:], truth)  # the simulator's truth
        np.testing.assert_array_equal(ep.infos["pulse"][lag + 1:], np.arange(len(episode)))
        assert np.all(ep.infos["pulse"][:lag + 1] == -1) and np.all(ep.infos["true_label"][:lag + 1] == -1)
        assert ep.rewards.sum() == pytest.approx(accuracy_of(labels, episode) * len(episode))
        assert ep.terminations[-1] and not ep.terminations[:-1].any()


def test_tokens_dataset_mixes_source_counts_with_track_actions(tmp_path, monkeypatch):
    write_dataset(DatasetConfig("deint/tok-v0", policy="nearest-prior", scenarios=(N2, N3), seeds=1, env="tokens",
                                max_tracks=4, root=tmp_path))
    dataset = load(tmp_path, "deint/tok-v0", monkeypatch)
    assert dataset.total_episodes == 2 and dataset.action_space.n == 5
    for name, ep in zip((N2, N3), dataset.iterate_episodes()):
        episode = simulate(find_entry(name).spec, find_entry(name).train.start)
        labels = play(make_policy("nearest-prior"), episode, clustering=False).labels
        # the token env's spurious action is max_tracks, whatever the scenario's own label count
        np.testing.assert_array_equal(ep.actions, np.where(labels == episode.n_labels, 4, labels))
        assert ep.observations["tracks"].shape[:2] == (len(episode) + 1, 4)
        assert ep.observations["mask"][0].sum() == episode.n_labels


def test_existing_dataset_is_refused_and_kept(tmp_path, monkeypatch):
    args = ["deint/x-v0", "--scenario", N2, "--seeds", "1", "--root", str(tmp_path)]
    write_dataset(DatasetConfig("deint/x-v0", scenarios=(N2,), seeds=1, root=tmp_path))
    before = sorted((p.relative_to(tmp_path), p.stat().st_size) for p in tmp_path.rglob("*") if p.is_file())
    again = cli(*args, "--policy", "random")
    assert again.returncode == 2 and "already exists" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    assert sorted((p.relative_to(tmp_path), p.stat().st_size) for p in tmp_path.rglob("*") if p.is_file()) == before
    assert load(tmp_path, "deint/x-v0", monkeypatch).total_episodes == 1


@pytest.mark.parametrize("args,match", [
    (["bad id", "--scenario", N2], "dataset id 'bad id' is invalid"),
    (["deint/x", "--scenario", N2], "dataset id 'deint/x' is invalid"),
    (["deint/x-v0", "--scenario", N2, "--seeds", "0"], "--seeds=0"),
    (["deint/x-v0", "--scenario", N2, "--seeds", "11", "--split", "test"], "has 10 test seeds"),
    (["deint/x-v0", "--scenario", N2, "--scenario", N3], "another number of labels"),
    (["deint/x-v0", "--scenario", N3, "--env", "tokens", "--max-tracks", "2"], "has 3 labels"),
    (["deint/x-v0", "--scenario", N2, "--policy", "nosuch"], "nosuch"),
    (["deint/x-v0", "--suite", "nosuch-v0"], "nosuch-v0"),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, args, match):
    from deint_env.cli import main

    assert main(["dataset", *args, "--root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1, err
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]


def test_a_failure_midway_leaves_no_dataset(tmp_path, monkeypatch):
    import agents.dataset as ds

    calls = []

    def failing_play(*a, **k):
        if calls:
            raise DeintError("interrupted")
        calls.append(1)
        return play(*a, **k)

    monkeypatch.setattr(ds, "play", failing_play)
    with pytest.raises(DeintError, match="interrupted"):
        write_dataset(DatasetConfig("deint/half-v0", policy="nearest-prior", scenarios=(N2,), seeds=2, root=tmp_path))
    assert list(tmp_path.iterdir()) == []  # no dataset, no temporary directory


@pytest.mark.parametrize("env,scenarios", [("raw", (N3,)), ("raw", (N2, "core-v0/core-n2-spread16-jitter0.05")),
                                           ("tokens", (N2, N3))])
def test_the_dataset_recovers_its_env(tmp_path, monkeypatch, env, scenarios):
    """`env_spec` names the flavour's env on the dataset's scenarios and split at the policy's lag, so
    Minari's recover_environment() plays the dataset's kind of episodes in its spaces."""
    write_dataset(DatasetConfig("deint/rec-v0", policy="nearest-prior", scenarios=scenarios, seeds=1, env=env,
                                max_tracks=4, root=tmp_path))
    dataset = load(tmp_path, "deint/rec-v0", monkeypatch)
    assert dataset.env_spec is not None
    recovered = dataset.recover_environment()
    assert recovered.observation_space == dataset.observation_space
    assert recovered.action_space == dataset.action_space
    first = find_entry(scenarios[0]).train.start
    obs, info = recovered.reset(seed=first if len(scenarios) == 1 else 0)
    assert f"core-v0/{info['scenario']}" in scenarios
    if len(scenarios) == 1:  # the dataset's first episode, from its first observation on
        ep = next(iter(dataset.iterate_episodes()))
        np.testing.assert_array_equal(obs["toa"], ep.observations["toa"][0])
        with pytest.raises(DeintError, match="test seed"):  # the dataset's split only
            recovered.reset(seed=find_entry(scenarios[0]).test.start)
    recovered.close()

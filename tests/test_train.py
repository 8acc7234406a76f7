"""`deint train` / agents.train: a tiny run writes usable checkpoints, resumes, and respects its limits."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("sb3_contrib")  # the [rl] extra

from agents.checkpoint import read_meta, save_checkpoint  # noqa: E402
from agents.policy import AgentPolicy  # noqa: E402
from agents.train import PACKAGE_DIRS, TrainConfig, load_hyperparams, train  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.runner import play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

SCENARIO = "core-v0/core-n3-spread4-jitter0.05"


def tiny(out, **kw) -> TrainConfig:
    base = dict(out=out, scenarios=(SCENARIO,), n_envs=2, timesteps=512, eval_every=256, eval_episodes=2,
                progress=False)
    return TrainConfig(**{**base, **kw})


@pytest.mark.parametrize("algo", ["maskable-ppo", pytest.param("dqn", marks=pytest.mark.slow)])
def test_tiny_training_writes_checkpoints_and_resumes(tmp_path, algo):
    hp = tmp_path / "hp.yml"
    hp.write_text(f"{SCENARIO}:\n  n_steps: 64\n  batch_size: 64\n  n_epochs: 1\n  policy_kwargs: {{d_model: 8, heads: 2}}\n"
                  if algo != "dqn" else "default:\n  learning_starts: 64\n  buffer_size: 1000\n"
                  "  policy_kwargs: {d_model: 8, heads: 2}\n")
    out = tmp_path / "run"
    first = train(tiny(out, algo=algo, hyperparams_file=hp))
    meta = read_meta(first.last)
    assert meta.algorithm == algo and meta.timesteps == first.timesteps >= 512 and meta.scenarios == [SCENARIO]
    assert meta.features["layout"] == "tracks" and meta.train_seeds[1] <= find_entry(SCENARIO).train.stop
    assert len(first.evaluations) >= 2 and first.best is not None
    episode = simulate(find_entry(SCENARIO).spec.replace(n_pulses=50), 1_000_000)
    assert play(AgentPolicy(str(first.best)), episode, clustering=False).labels.shape == (50,)
    again = train(tiny(out, algo=algo, hyperparams_file=hp, timesteps=1024))  # resumes from last.safetensors
    assert read_meta(again.last).timesteps >= 1024 > first.timesteps
    lines = [json.loads(x) for x in (out / "eval.jsonl").read_text().splitlines()]
    assert lines[-1]["timesteps"] == again.timesteps and len(lines) > len(first.evaluations)


def sb3_labels(model, scenario, seed: int, n: int, lag: int, state=None) -> list[np.ndarray]:
    """The env labels SB3's own `predict` gives the pulses of episodes seed..seed+n-1 (one env each),
    carrying the LSTM state as RecurrentPPO's rollouts do, from zeros or from `state`."""
    from agents.vec_env import TokenVecEnv

    venv = TokenVecEnv.make(n, scenario=scenario, lag=lag, max_tracks=8)
    venv.seed(seed)
    obs, starts = venv.reset(), np.full(n, state is None)
    labels: list[list[int]] = [[] for _ in range(n)]
    finished = np.zeros(n, bool)
    while not finished.all():
        actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
        tokens = venv.env.features
        ready, env_labels = tokens.ready.copy(), tokens.env_actions(actions, venv.env._spurious)
        for i in np.flatnonzero(ready & ~finished).tolist():
            labels[i].append(int(env_labels[i]))
        venv.step_async(actions)
        obs, _, starts, _ = venv.step_wait()
        finished |= starts
    return [np.array(x) for x in labels]


def test_recurrent_ppo_round_trip_carries_the_lstm_state(tmp_path):
    """train -> safetensors -> `agent:checkpoint=` plays each episode with the labels SB3's own
    RecurrentPPO.predict gives it (LSTM state carried per step, reset per episode)."""
    import torch
    from sb3_contrib import RecurrentPPO

    from agents.checkpoint import load_checkpoint
    from agents.networks import RecurrentTrackPolicy, load_weights
    from agents.vec_env import TokenVecEnv
    from deint_env.policies import make_policy

    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  n_steps: 64\n  batch_size: 64\n  n_epochs: 1\n"
                  "  policy_kwargs: {d_model: 8, heads: 2, lstm_hidden_size: 8}\n")
    out = tmp_path / "run"
    first = train(tiny(out, algo="recurrent-ppo", hyperparams_file=hp, lag=3))
    ck = load_checkpoint(first.last)
    assert ck.meta.algorithm == "recurrent-ppo" and ck.meta.timesteps == first.timesteps >= 512
    assert ck.meta.architecture == {"name": "recurrent-track-net", "d_model": 8, "attention": True, "heads": 2,
                                    "lstm_hidden_size": 8, "n_lstm_layers": 1}
    assert len(first.evaluations) >= 2 and first.best is not None
    again = train(tiny(out, algo="recurrent-ppo", hyperparams_file=hp, lag=3, timesteps=1024))  # resumes
    assert read_meta(again.last).timesteps >= 1024 > first.timesteps

    # Make the memory long (forget gates near 1: PyTorch's gate order is i, f, g, o) and weigh in each
    # track's score, so a state not carried, not reset or not stepped on look-ahead steps changes labels.
    ck = load_checkpoint(again.last)
    ck.tensors["lstm_actor.lstm.bias_ih_l0"][8:16] += 2.0
    ck.tensors["mlp_extractor.score.0.weight"][:, 8:] *= 3.0
    boosted = tmp_path / "boosted.safetensors"
    save_checkpoint(boosted, ck.tensors, ck.meta)
    model = RecurrentPPO(RecurrentTrackPolicy, TokenVecEnv.make(1, scenario=SCENARIO, lag=3), device="cpu",
                         policy_kwargs=dict(d_model=8, heads=2, lstm_hidden_size=8))
    load_weights(model.policy, ck.tensors, "test")
    seed, spec = find_entry(SCENARIO).test.start, find_entry(SCENARIO).spec.replace(n_pulses=120)
    expected = sb3_labels(model, spec, seed, 2, lag=3)
    state = tuple(np.random.default_rng(0).normal(0, 3, (2, 1, 2, 8)))  # (h, c), 1 layer, 2 envs
    assert any((a != b).any() for a, b in zip(sb3_labels(model, spec, seed, 2, lag=3, state=state), expected))
    policy = make_policy(f"agent:checkpoint={boosted}")  # one policy object for both episodes
    assert policy.lag == 3
    for i in range(2):
        episode = simulate(spec, seed + i)
        policy._state = tuple(torch.as_tensor(x[:, :1], dtype=torch.float32) for x in state)  # reset drops it
        labels = play(policy, episode, clustering=False).labels
        assert len(np.unique(expected[i])) > 1  # the network does label, not a constant
        np.testing.assert_array_equal(labels, expected[i])


@pytest.mark.slow
def test_resume_refuses_another_algorithm(tmp_path):
    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  n_steps: 64\n  batch_size: 64\n  n_epochs: 1\n  policy_kwargs: {d_model: 8, heads: 2}\n")
    train(tiny(tmp_path, algo="ppo", hyperparams_file=hp, timesteps=128, eval_every=10_000))
    with pytest.raises(DeintError, match="this run trains another"):
        train(tiny(tmp_path, algo="a2c", timesteps=128))


def test_never_writes_into_the_package_unless_asked():
    with pytest.raises(DeintError, match="inside the installed package"):
        train(tiny(PACKAGE_DIRS[0] / "checkpoints" / "x"))


def test_hyperparameters_are_looked_up_by_scenario_then_suite_then_default(tmp_path):
    f = tmp_path / "h.yml"
    f.write_text("default: {gamma: 0.1}\ncore-v0: {gamma: 0.2}\ncore-v0/a: {gamma: 0.3}\n")
    assert load_hyperparams("ppo", ["core-v0/a", "core-v0"], f) == ("core-v0/a", {"gamma": 0.3})
    assert load_hyperparams("ppo", ["core-v0/b", "core-v0"], f) == ("core-v0", {"gamma": 0.2})
    assert load_hyperparams("ppo", ["robust-v0"], f) == ("default", {"gamma": 0.1})
    f.write_text("default: [1, 2]\n")
    with pytest.raises(DeintError, match="must be a mapping"):
        load_hyperparams("ppo", [], f)
    for algo in ("ppo", "maskable-ppo", "recurrent-ppo", "a2c", "dqn"):  # the shipped files parse
        assert load_hyperparams(algo, ["core-v0"])[1]["policy_kwargs"]["d_model"] > 0


@pytest.mark.parametrize("args,match", [(["--time-budget", "0"], "time-budget"), (["--algo", "sac"], "sac"),
                                         (["--n-envs", "0"], "n-envs")])
def test_cli_train_refuses_bad_arguments_with_one_line(tmp_path, args, match):
    run = subprocess.run([sys.executable, "-c", "from deint_env.cli import main; raise SystemExit(main())", "train",
                          "--scenario", SCENARIO, "-o", str(tmp_path / "o"), *args], capture_output=True, text=True)
    assert run.returncode == 2 and match in run.stderr and len(run.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("suite", ["robust-v0", "blind-v0"])
def test_dagger_expert_is_the_truth(suite):
    from agents.imitation import expert_actions
    from deint_env.envs.tokens import make_tokens_vector_env

    env = make_tokens_vector_env(3, suite=suite, lag=1, max_tracks=8)
    env.reset(seed=0)
    rewards, labelled = 0.0, 0
    for _ in range(600):
        ready = env.features.ready
        _, r, *_ = env.step(expert_actions(env, 8))
        rewards, labelled = rewards + r[ready].sum(), labelled + ready.sum()
    # robust-v0 merges pulses: the expert names the primary source, right under any merged source;
    # blind-v0 rewards links: the expert continues the learner's track of the true predecessor.
    assert labelled > 1500 and rewards == labelled


@pytest.mark.slow
def test_a_tiny_dagger_run_learns_something(tmp_path):
    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  rollout_steps: 100\n  epochs: 2\n  policy_kwargs: {d_model: 16, heads: 2}\n")
    result = train(tiny(tmp_path / "d", algo="dagger", hyperparams_file=hp, n_envs=8, timesteps=3200,
                        eval_every=1600, eval_episodes=4, scenarios=("core-v0/core-n2-spread4-jitter0.05",)))
    assert read_meta(result.last).algorithm == "dagger" and result.timesteps == 3200
    # Measured: ~0.9 validation accuracy after 3200 steps (random labels: 0.33).
    assert result.evaluations[-1]["validation_accuracy"] > 0.5


def test_dagger_stops_within_a_round_at_its_steps_and_its_time_budget(tmp_path):
    """A DAgger round (rollout_steps x n_envs) can outlast the budget with a slow expert: both limits are
    checked every env step, as SB3's callbacks check them."""
    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  rollout_steps: 100000\n  epochs: 1\n  policy_kwargs: {d_model: 8, heads: 2}\n")
    result = train(tiny(tmp_path / "steps", algo="dagger", hyperparams_file=hp, timesteps=1, eval_every=10**6))
    assert result.timesteps == 2  # one step of 2 envs, not the round's 200,000
    result = train(tiny(tmp_path / "time", algo="dagger", hyperparams_file=hp, timesteps=10**9, eval_every=10**9,
                        time_budget=1.0))
    assert 0 < result.timesteps < 200_000


def scalars(run_dir) -> dict[str, list[float]]:
    """Every scalar tag TensorBoard would show for the event files under `run_dir`."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[float]] = {}
    for events in run_dir.rglob("events.out.tfevents.*"):
        acc = EventAccumulator(str(events.parent))
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            out.setdefault(tag, []).extend(e.value for e in acc.Scalars(tag))
    return out


def test_sb3_runs_log_to_tensorboard_with_the_validation_accuracy(tmp_path):
    pytest.importorskip("tensorboard")
    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  n_steps: 64\n  batch_size: 64\n  n_epochs: 1\n  policy_kwargs: {d_model: 8, heads: 2}\n")
    result = train(tiny(tmp_path / "p", algo="ppo", hyperparams_file=hp))
    logged = scalars(tmp_path / "p" / "tensorboard")
    assert "train/loss" in logged and "time/fps" in logged  # SB3's own scalars
    assert logged["eval/validation_accuracy"] == pytest.approx([e["validation_accuracy"] for e in result.evaluations],
                                                               abs=1e-4)


def test_bc_from_a_reference_policy_logs_resumes_and_keeps_its_expert(tmp_path):
    pytest.importorskip("tensorboard")
    hp = tmp_path / "hp.yml"
    hp.write_text("default:\n  rollout_steps: 64\n  epochs: 1\n  policy_kwargs: {d_model: 8, heads: 2}\n")
    out = tmp_path / "bc"
    first = train(tiny(out, algo="bc", expert="nearest-prior", hyperparams_file=hp, n_envs=4, timesteps=256))
    meta = read_meta(first.last)
    assert meta.algorithm == "bc" and meta.hyperparameters["expert"] == "nearest-prior" and first.timesteps == 256
    logged = scalars(out / "tensorboard")
    assert logged["train/beta"] == [1.0] * len(logged["train/beta"])  # plain behaviour cloning: the expert drives
    assert len(logged["train/loss"]) == 1 and np.isfinite(logged["train/loss"]).all()
    assert len(logged["eval/validation_accuracy"]) == len(first.evaluations)
    again = train(tiny(out, algo="bc", expert="nearest-prior", hyperparams_file=hp, n_envs=4, timesteps=512))
    assert again.timesteps == 512 and len(list((out / "tensorboard").iterdir())) == 2  # bc_1, bc_2
    with pytest.raises(DeintError, match="this run trains another"):
        train(tiny(out, algo="bc", expert="truth", hyperparams_file=hp, n_envs=4, timesteps=1024))


@pytest.mark.parametrize("kw,match", [
    (dict(algo="ppo", expert="mht"), "--expert applies to dagger and bc"),
    (dict(algo="bc", expert="nosuch"), "nosuch"),
    (dict(algo="dagger", expert="agent:checkpoint=x.safetensors"), "learned agent"),
    (dict(algo="bc", expert="fdp", scenarios=("blind-v0/blind-n2to2-jitter0.1",)), "blind scenarios need"),
])
def test_bad_experts_are_refused_before_anything_is_written(tmp_path, kw, match):
    with pytest.raises(DeintError, match=match):
        train(tiny(tmp_path / "o", **kw))
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("spec", ["fdp", "genie"])
def test_a_reference_expert_replays_the_policys_own_labels(spec):
    """Driving the token env with the expert's actions reproduces the policy's episode accuracy."""
    from agents.experts import make_expert
    from deint_env.envs.tokens import make_tokens_vector_env
    from deint_env.policies import is_oracle, make_policy
    from deint_env.runner import accuracy_of

    expert = make_expert(spec)
    env = make_tokens_vector_env(2, scenario=SCENARIO, lag=0, max_tracks=8)
    env.reset(seed=find_entry(SCENARIO).test.start)
    while True:
        _, _, terminated, _, info = env.step(expert.actions(env, 8))
        if terminated.any():
            break
    for i in range(2):
        episode = simulate(find_entry(SCENARIO).spec, find_entry(SCENARIO).test.start + i)
        own = play(make_policy(spec), episode, oracle=is_oracle(spec), clustering=False).labels
        assert info["episode_accuracy"][i] == pytest.approx(accuracy_of(own, episode))


def test_a_reference_expert_refuses_blind_scenarios():
    from agents.experts import make_expert

    episode = simulate(find_entry("blind-v0/blind-n2to2-jitter0.1").spec, 0)
    with pytest.raises(DeintError, match="anchored scenarios only"):
        make_expert("fdp").labels(episode)

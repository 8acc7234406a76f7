"""The native vector env against N single envs, step for step, and its Gymnasium plumbing."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import deint_env
from deint_env import PriorSpec, Range, ScenarioSpec, SourceSpec
from deint_env.envs import deinterleave as single_module
from deint_env.envs import vector as vector_module
from deint_env.envs.deinterleave import DeinterleaveEnv
from deint_env.envs.vector import DeinterleaveVectorEnv
from deint_env.errors import DeintError
from deint_env.labels import label_predecessors, true_predecessors
from deint_env.simulate import simulate

N_ENVS = 4


def _small(name: str) -> ScenarioSpec:
    return deint_env.resolve_scenario(name).replace(n_pulses=50)


def _amplitude_spec() -> ScenarioSpec:
    src = SourceSpec(period=Range(10.0, 40.0, log=True), amplitude=Range(0.5, 2.0), amplitude_std=0.05)
    return ScenarioSpec(name="vec-amplitudes", sources=(src, src), n_pulses=50, toa_jitter_std=0.2,
                        amplitudes=True, amplitude_noise_std=0.1,
                        priors=PriorSpec(kind="perturbed", period_error=0.01, phase_error=0.05))


def _blind_merged_spec() -> ScenarioSpec:
    # Dense, merging and spurious: merged pulses with alternative true predecessors are common.
    return _small("blind-v0/blind-n2to5-jitter0.5").replace(coincidence_resolution=3.0, spurious_rate=0.1,
                                                            n_pulses=80)


def _same_json(a, b) -> bool:
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _compare(spec: ScenarioSpec, lag: int, n_steps: int, seed: int = 100, min_boundaries: int = 2) -> int:
    """Step the vector env and N single envs with the same seeds and actions; return how many merged
    pulses were rewarded through an alternative predecessor only (blind mode)."""
    vec = DeinterleaveVectorEnv(num_envs=N_ENVS, scenario=spec, lag=lag, clustering_metrics=False)
    singles = [DeinterleaveEnv(scenario=spec, lag=lag, clustering_metrics=False) for _ in range(N_ENVS)]
    obs, info = vec.reset(seed=seed)
    assert vec.observation_space.contains(obs)
    for i, env in enumerate(singles):
        o, inf = env.reset(seed=seed + i)
        _check_obs(obs, i, o)
        _check_reset_info(info, i, inf)
    spur = vec.n_labels
    rng = np.random.default_rng(seed)
    steps = [0] * N_ENVS  # the single envs' step counts, to pick oracle labels
    score = [0.0] * N_ENVS  # the single envs' episode rewards
    done = [False] * N_ENVS
    boundaries = np.zeros(N_ENVS, int)
    alt_hits = 0
    for _ in range(n_steps):
        actions = rng.integers(0, spur + 1, N_ENVS)
        for i, env in enumerate(singles):  # half the labels right-ish, so both rewards occur
            j = steps[i] - lag
            if not done[i] and 0 <= j < len(env.episode) and rng.random() < 0.5:
                src = int(env.episode.source[j])
                actions[i] = src if src >= 0 else spur
        obs, rew, term, trunc, info = vec.step(actions)
        assert vec.observation_space.contains(obs)
        assert rew.dtype == np.float64 and term.dtype == bool and not trunc.any()
        for i, env in enumerate(singles):
            if done[i]:  # NEXT_STEP autoreset: the action is ignored, a new episode starts
                o, inf = env.reset()
                r, te = 0.0, False
                steps[i], score[i] = 0, 0.0
                _check_reset_info(info, i, inf)
            else:
                o, r, te, tr, inf = env.step(int(actions[i]))
                steps[i] += 1
                score[i] += r
                if te:
                    assert info["_episode_accuracy"][i]
                    assert info["episode_accuracy"][i] == score[i] / len(env.episode)
                    assert _same_json(vec.metrics(i), env.metrics())
                    alt_hits += _alt_only_hits(env)
            _check_obs(obs, i, o)
            assert rew[i] == r and term[i] == te
            if "_episode_accuracy" in info and not te:
                assert not info["_episode_accuracy"][i] and np.isnan(info["episode_accuracy"][i])
            done[i] = te
        boundaries += term
    assert boundaries.min() >= min_boundaries
    return alt_hits


def _check_obs(batch: dict, i: int, single: dict) -> None:
    assert batch["toa"].shape == (N_ENVS, 1) and batch["toa"].dtype == np.float64
    assert batch["amplitude"].shape == (N_ENVS, 1) and batch["valid"].dtype == np.int64
    assert batch["toa"][i, 0] == single["toa"][0]
    assert batch["amplitude"][i, 0] == single["amplitude"][0]
    assert batch["valid"][i] == single["valid"]


def _check_reset_info(batch: dict, i: int, single: dict) -> None:
    assert batch["_priors"][i] and batch["_n_pulses"][i]
    assert batch["n_pulses"][i] == single["n_pulses"] and batch["scenario"][i] == single["scenario"]
    for key, value in single["priors"].items():
        np.testing.assert_array_equal(batch["priors"][key][i], value)


def test_episode_accuracy_equals_metrics_accuracy():
    spec = _blind_merged_spec()
    env = DeinterleaveVectorEnv(N_ENVS, scenario=spec, clustering_metrics=False)
    env.reset(seed=0)
    for k in range(spec.n_pulses):  # label every pulse by its primary source: many merged links
        actions = np.array([max(int(ep.source[k]), 0) for ep in env.episodes])
        _, _, term, _, info = env.step(actions)
    assert term.all()
    for i in range(N_ENVS):
        assert info["episode_accuracy"][i] == env.metrics(i)["accuracy"]


def _alt_only_hits(env: DeinterleaveEnv) -> int:
    ep = env.episode
    truth = true_predecessors(ep.source, ep.mask)
    named = label_predecessors(env.labels, env.n_labels)
    hit = (named[truth.alt_pulse] == truth.alt_pred) & (named[truth.alt_pulse] != truth.pred[truth.alt_pulse])
    return int(hit.sum())


@pytest.mark.parametrize("spec, lag", [
    (_small("core-v0/core-n3-spread4-jitter0.2"), 0),
    (_small("core-v0/core-n3-spread4-jitter0.2"), 3),
    (_small("blind-v0/blind-n2to5-jitter0.5"), 0),
    (_small("blind-v0/blind-n2to5-jitter0.5"), 2),
    (_small("robust-v0/robust-combined"), 0),
    (_amplitude_spec(), 1),
], ids=["anchored-lag0", "anchored-lag3", "blind-lag0", "blind-lag2", "robust-combined", "amplitudes"])
def test_matches_single_envs(spec, lag):
    _compare(spec, lag, n_steps=3 * (spec.n_pulses + lag + 1))


def test_blind_merged_alternatives_match_single_envs():
    spec = _blind_merged_spec()
    hits = _compare(spec, lag=1, n_steps=3 * (spec.n_pulses + 2))
    assert hits > 0  # the alternative-predecessor path was exercised


def test_anchored_more_than_64_tracks_matches_single_envs():
    # Labels past bit 63 can never be right (the single env's `a < 64` rule).
    spec = _small("core-v0/core-n3-spread4-jitter0.2").replace(
        priors=PriorSpec(kind="explicit", period=tuple(10.0 + i for i in range(70)), period_std=(1.0,), phase_std=(1.0,)))
    _compare(spec, lag=0, n_steps=3 * (spec.n_pulses + 1))


@pytest.mark.parametrize("name", ["robust-v0/robust-combined", "blind-v0/blind-n2to5-jitter0.5"])
def test_episodes_of_varying_length(monkeypatch, name):
    """Shorter and longer episodes than n_pulses: sub-envs fall out of step and rows must grow."""
    real = simulate

    def varying(spec, seed):
        return real(spec.replace(n_pulses=20 + seed % 60), seed)

    monkeypatch.setattr(vector_module, "simulate_many", lambda spec, seeds: [varying(spec, s) for s in seeds])
    monkeypatch.setattr(single_module, "simulate", varying)
    spec = _small(name).replace(coincidence_resolution=2.0, spurious_rate=0.1)
    _compare(spec, lag=2, n_steps=260, seed=37, min_boundaries=2)


def test_episodes_starting_together_are_simulated_together(monkeypatch):
    calls = []
    real = vector_module.simulate_many

    def counting(spec, seeds):
        calls.append(list(seeds))
        return real(spec, seeds)

    monkeypatch.setattr(vector_module, "simulate_many", counting)
    spec = _small("core-v0/core-n3-spread4-jitter0.2")
    env = DeinterleaveVectorEnv(N_ENVS, scenario=spec)
    env.reset(seed=3)
    assert calls == [[3, 4, 5, 6]]
    for _ in range(spec.n_pulses + 1):  # all sub-envs end on the same step and restart on the next
        env.step(np.zeros(N_ENVS, np.int64))
    assert len(calls) == 2 and len(calls[1]) == N_ENVS
    assert [ep.seed for ep in env.episodes] == calls[1]


def test_batched_infos_match_gymnasium_add_info():
    """`_add_infos` (many sub-envs at once) builds what Gymnasium's `_add_info` builds env by env."""
    env = DeinterleaveVectorEnv(5, scenario=_amplitude_spec())
    rows = [1, 3, 4]
    episodes = [simulate(env.spec_scenario, s) for s in (7, 8, 9)]
    infos = [{"priors": ep.priors.as_info(), "n_pulses": len(ep), "lag": 0, "has_amplitude": True,
              "scenario": ep.scenario} for ep in episodes]
    expected: dict = {"episode_accuracy": np.zeros(5)}  # an info key already present is kept
    actual: dict = {"episode_accuracy": np.zeros(5)}
    for i, info in zip(rows, infos):
        env._add_info(expected, info, i)

    def columns(dicts: list[dict]) -> dict:  # {key: [each sub-env's value]}, nested dicts alike
        return {k: columns([d[k] for d in dicts]) if isinstance(v, dict) else [d[k] for d in dicts]
                for k, v in dicts[0].items()}

    env._add_infos(actual, columns(infos), rows)

    def check(a: dict, b: dict) -> None:
        assert list(a) == list(b)
        for k in a:
            if isinstance(a[k], dict):
                check(a[k], b[k])
            else:
                assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
                assert all(np.array_equal(x, y) for x, y in zip(a[k], b[k])), k

    check(actual, expected)


def test_make_vec():
    envs = gym.make_vec("deint_env/Deinterleave-v0", num_envs=3)
    assert isinstance(envs, DeinterleaveVectorEnv) and envs.num_envs == 3
    obs, info = envs.reset(seed=0)
    assert obs["toa"].shape == (3, 1) and info["priors"]["period"].shape[0] == 3
    envs.action_space.seed(0)
    for _ in range(5):
        obs, rew, term, trunc, info = envs.step(envs.action_space.sample())
        assert envs.observation_space.contains(obs) and rew.shape == (3,)
    envs.close()
    paper = gym.make_vec("deint_env/MK94-ThreeSources-v0", num_envs=2, lag=2)
    assert isinstance(paper, DeinterleaveVectorEnv) and paper.lag == 2
    assert paper.spec_scenario.name == "mk94-three"


def _rollout(env: DeinterleaveVectorEnv, reset_seed, n_steps: int):
    obs, _ = env.reset(seed=reset_seed)
    actions = np.random.default_rng(5).integers(0, env.n_labels + 1, (n_steps, env.num_envs))
    out = [obs["toa"].copy()]
    for a in actions:
        obs, rew, term, _, _ = env.step(a)
        out += [obs["toa"].copy(), obs["amplitude"].copy(), rew, term]
    return out


def test_same_seed_same_rollout():
    spec = _small("robust-v0/robust-combined")
    n_steps = 2 * (spec.n_pulses + 1) + 5
    a = _rollout(DeinterleaveVectorEnv(3, scenario=spec), 7, n_steps)
    b = _rollout(DeinterleaveVectorEnv(3, scenario=spec), 7, n_steps)
    c = _rollout(DeinterleaveVectorEnv(3, scenario=spec), [7, 8, 9], n_steps)
    for x, y, z in zip(a, b, c):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)
    d = _rollout(DeinterleaveVectorEnv(3, scenario=spec), 8, n_steps)
    assert not np.array_equal(a[0], d[0])


def test_bad_actions_and_seeds_raise():
    env = DeinterleaveVectorEnv(2, scenario=_small("core-v0/core-n3-spread4-jitter0.2"), lag=1)
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(2, np.int64))
    env.reset(seed=0)
    env.step(np.array([-1, 99]))  # the first step labels nothing (lag 1): ignored, as in the single env
    with pytest.raises(DeintError):
        env.step(np.array([0, env.n_labels + 1]))
    with pytest.raises(DeintError):
        env.step(np.array([0, -1]))
    with pytest.raises(DeintError):
        env.step(np.zeros(3, np.int64))
    with pytest.raises(DeintError):
        env.step(np.zeros(2))
    for bad in (-1, 2**63 - 1, [0], [0, "x"], 1.5):
        with pytest.raises(DeintError):
            env.reset(seed=bad)
    with pytest.raises(DeintError):
        DeinterleaveVectorEnv(0)
    with pytest.raises(DeintError):
        DeinterleaveVectorEnv(2, render_mode="human")


@pytest.mark.parametrize("mode", ["rgb_array", "ansi"])
def test_render(mode):
    env = DeinterleaveVectorEnv(2, scenario=_small("core-v0/core-n2-spread4-jitter0.2"), render_mode=mode)
    assert len(env.render()) == 2  # before reset: empty frames
    env.reset(seed=1)
    for _ in range(10):
        env.step(np.zeros(2, np.int64))
    frames = env.render()
    assert len(frames) == 2
    if mode == "rgb_array":
        assert all(f.shape == (480, 720, 3) and f.dtype == np.uint8 for f in frames)
    else:
        assert all(f.startswith("  pulse") and "10 pulses labelled" in f for f in frames)


def test_split_refuses_the_other_splits_seeds():
    name = "core-v0/core-n2-spread1.5-jitter0.05"
    vec = DeinterleaveVectorEnv(3, scenario=name, split="test")
    vec.reset(seed=1_000_007)  # sub-envs play 1000007, 1000008, 1000009
    assert [ep.seed for ep in vec.episodes] == [1_000_007, 1_000_008, 1_000_009]
    with pytest.raises(DeintError, match=r"^seed=1000010 is not a seed of any split of core-v0/core-n2-spread1.5"
                                         r"-jitter0.05: this env \(split='test'\) plays test seeds"):
        vec.reset(seed=1_000_008)  # the third sub-env would play 1000010
    with pytest.raises(DeintError, match="seed=7 is a train seed"):
        vec.reset(seed=[1_000_000, 7, None])
    train = DeinterleaveVectorEnv(2, scenario=name, split="train")
    with pytest.raises(DeintError, match="seed=1000000 is a test seed"):
        train.reset(seed=[3, 1_000_000])
    train.reset(seed=[3, None])
    assert train.episodes[0].seed == 3 and 0 <= train.episodes[1].seed < 99_000
    # autoresets draw their episodes from the split, as the single env's unseeded resets do
    single = gym.make("deint_env/Deinterleave-v0", scenario=name, split="train").unwrapped
    single.reset(seed=4)
    train.reset(seed=[4, 5])
    n = len(train.episodes[0])
    for _ in range(n + 1):
        train.step(np.zeros(2, np.int64))
    single.reset()
    assert train.episodes[0].seed == single.episode.seed and 0 <= train.episodes[0].seed < 100_000
    with pytest.raises(DeintError, match="split="):
        gym.make_vec("deint_env/Deinterleave-v0", num_envs=2, scenario=name, split="dev")

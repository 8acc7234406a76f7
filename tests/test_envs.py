"""The Gymnasium env: API checkers (no warnings), determinism, rendering, pickling, spec JSON, lag
semantics, the reset info, and the reward rules (anchored and blind)."""

from __future__ import annotations

import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.registration import EnvSpec

import deint_env
from deint_env import simulate
from deint_env.errors import DeintError
from deint_env.labels import correct_link
from deint_env.scenario import PriorSpec, ScenarioSpec, SourceSpec
from deint_env.suites import resolve_scenario

IDS = deint_env.env_ids()
MAIN = "deint_env/Deinterleave-v0"


def make(env_id=MAIN, **kw):
    return gym.make(env_id, **kw)


def short(name: str, n: int = 300, **changes) -> ScenarioSpec:
    return resolve_scenario(name).replace(n_pulses=n, **changes)


def perfect_actions(ep) -> np.ndarray:
    return np.where(ep.source >= 0, ep.source, ep.n_labels).astype(np.int64)


def play(env, seed, actions=None, action_seed=0):
    """Run one whole episode; returns (reset obs, reset info, [obs], [reward], [info], terminated flags)."""
    obs0, info0 = env.reset(seed=seed)
    rng = np.random.default_rng(action_seed)
    obs, rew, infos, terms = [], [], [], []
    k = 0
    while True:
        a = int(actions[k]) if actions is not None else int(rng.integers(env.action_space.n))
        o, r, term, trunc, info = env.step(a)
        assert trunc is False
        obs.append(o), rew.append(r), infos.append(info), terms.append(term)
        k += 1
        if term:
            return obs0, info0, obs, rew, infos, terms


def same_obs(a, b) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def same_metrics(a, b) -> bool:
    if a.keys() != b.keys():
        return False
    for k in a:
        x, y = a[k], b[k]
        if isinstance(x, np.ndarray):
            if not (isinstance(y, np.ndarray) and np.array_equal(x, y, equal_nan=True)):
                return False
        elif isinstance(x, float) and np.isnan(x):
            if not (isinstance(y, float) and np.isnan(y)):
                return False
        elif x != y:
            return False
    return True


# ---- the API checkers -------------------------------------------------------------------------------
def test_env_ids_registered():
    assert MAIN in IDS and len(IDS) == len(set(IDS))
    for env_id in IDS:
        assert env_id in gym.registry
        assert gym.spec(env_id).entry_point == "deint_env.envs.deinterleave:DeinterleaveEnv"
    deint_env.register_envs()  # idempotent
    assert gym.make("deint_env:deint_env/Deinterleave-v0").unwrapped.spec_scenario.name == "mk94-two-var1"


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_gymnasium_check_env_no_warnings(env_id, render_mode):
    from gymnasium.utils.env_checker import check_env

    env = make(env_id, render_mode=render_mode)
    assert env.spec is not None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("kwargs", [{"scenario": "blind-v0/blind-n2to5-jitter0.1", "lag": 2},
                                    {"scenario": "robust-v0/robust-combined", "lag": 1, "render_mode": "ansi"},
                                    {"scenario": "paper-v0/mk94-pt-post"}])
def test_gymnasium_check_env_other_scenarios(kwargs):
    from gymnasium.utils.env_checker import check_env

    env = make(MAIN, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env_no_warnings(env_id):
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(make(env_id), warn=True)
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("env_id", IDS)
def test_step_types(env_id):
    env = make(env_id)
    obs, info = env.reset(seed=0)
    assert obs in env.observation_space
    o, r, term, trunc, info = env.step(0)
    assert type(r) is float and type(term) is bool and type(trunc) is bool
    assert o in env.observation_space


# ---- determinism, pickling, spec JSON -----------------------------------------------------------------
@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_rollouts_identical(env_id):
    a = play(make(env_id), seed=17, action_seed=5)
    b = play(make(env_id), seed=17, action_seed=5)
    assert same_obs(a[0], b[0])
    assert all(same_obs(x, y) for x, y in zip(a[2], b[2]))
    assert a[3] == b[3]
    assert same_metrics(a[4][-1]["metrics"], b[4][-1]["metrics"])
    env = make(env_id)
    env.reset(seed=18)  # another seed plays its own episode (the noise-free CM00 ones are the same for all)
    assert np.array_equal(env.unwrapped.episode.toa, simulate(env.unwrapped.spec_scenario, 18).toa)
    if env_id == MAIN:
        assert not np.array_equal(env.unwrapped.episode.toa, simulate(env.unwrapped.spec_scenario, 17).toa)


def test_unseeded_reset_follows_the_env_generator():
    e1, e2 = make(), make()
    e1.reset(seed=3), e2.reset(seed=3)
    o1, _ = e1.reset()
    o2, _ = e2.reset()
    assert same_obs(o1, o2)
    assert np.array_equal(e1.unwrapped.episode.toa, e2.unwrapped.episode.toa)
    assert not np.array_equal(e1.unwrapped.episode.toa, simulate(e1.unwrapped.spec_scenario, 3).toa)


def test_reset_seed_plays_simulate_seed():
    env = make(MAIN, scenario="robust-v0/robust-combined")
    env.reset(seed=42)
    ref = simulate(resolve_scenario("robust-v0/robust-combined"), 42)
    assert np.array_equal(env.unwrapped.episode.toa, ref.toa)


@pytest.mark.parametrize("env_id", IDS)
def test_pickle_mid_episode(env_id):
    env = make(env_id)
    env.reset(seed=9)
    rng = np.random.default_rng(1)
    for _ in range(10):
        env.step(int(rng.integers(env.action_space.n)))
    clone = pickle.loads(pickle.dumps(env))
    acts = rng.integers(env.action_space.n, size=25)
    for a in acts:
        x, y = env.step(int(a)), clone.step(int(a))
        assert same_obs(x[0], y[0]) and x[1:4] == y[1:4]
    # the clone carries the generator too: the next unseeded episode is the same
    assert same_obs(env.reset()[0], clone.reset()[0])


@pytest.mark.parametrize("env_id", IDS)
def test_env_spec_json_round_trip(env_id):
    env = make(env_id)
    spec2 = EnvSpec.from_json(env.spec.to_json())
    assert spec2 == env.spec
    env2 = gym.make(spec2)
    assert same_obs(env.reset(seed=4)[0], env2.reset(seed=4)[0])
    assert np.array_equal(env.unwrapped.episode.toa, env2.unwrapped.episode.toa)


def test_env_spec_json_with_dict_scenario():
    d = short("paper-v0/mk94-three", 50).to_dict()
    env = make(MAIN, scenario=d, lag=2)
    env2 = gym.make(EnvSpec.from_json(env.spec.to_json()))
    assert env2.unwrapped.spec_scenario == env.unwrapped.spec_scenario and env2.unwrapped.lag == 2


def test_env_spec_json_with_spec_object():
    spec = short("robust-v0/robust-combined", 80)
    env = make(MAIN, scenario=spec)
    env2 = gym.make(EnvSpec.from_json(env.spec.to_json()))
    assert env2.unwrapped.spec_scenario == spec
    env.reset(seed=1), env2.reset(seed=1)
    assert np.array_equal(env.unwrapped.episode.toa, env2.unwrapped.episode.toa)


# ---- rendering -----------------------------------------------------------------------------------------
def test_render_modes():
    env = make(MAIN, render_mode="ansi")
    env.reset(seed=0)
    assert isinstance(env.render(), str)
    for _ in range(5):
        env.step(0)
    text = env.render()
    assert isinstance(text, str) and text.strip()
    env = make(MAIN, render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(5):
        env.step(1)
    img = env.render()
    assert isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.shape[0] > 0 and img.shape[1] > 0 and np.ptp(img) > 0
    from deint_env.envs import DeinterleaveEnv

    with pytest.raises(DeintError, match="render_mode"):
        DeinterleaveEnv(render_mode="rgb")


# ---- lag semantics -----------------------------------------------------------------------------------
@pytest.mark.parametrize("lag", [0, 1, 3])
def test_lag_semantics(lag):
    spec = short("paper-v0/mk94-two-var1", 60)
    env = make(MAIN, scenario=spec, lag=lag)
    n = spec.n_pulses
    obs0, info0, obs, rew, infos, terms = play(env, seed=2, action_seed=lag)
    ep = env.unwrapped.episode
    assert info0["lag"] == lag and info0["n_pulses"] == n
    assert len(rew) == n + lag
    assert rew[:lag] == [0.0] * lag
    assert terms == [False] * (n + lag - 1) + [True]
    seen = [obs0] + obs  # the observation in hand before step k is seen[k]
    for k in range(n):
        assert seen[k]["valid"] == 1 and seen[k]["toa"][0] == ep.toa[k]
    for k in range(n, n + lag + 1):  # the D padding steps and the terminal observation
        assert seen[k]["valid"] == 0
    assert all(i["metrics"]["n_pulses"] == 0 for i in infos[:-1])  # placeholders until the end
    m = infos[-1]["metrics"]
    assert m["lag"] == lag and m["n_pulses"] == n
    assert m["accuracy"] == pytest.approx(sum(rew) / n)
    # the reward of step k is for pulse k - lag
    labels = env.unwrapped.labels
    from deint_env.labels import correct_anchored

    ok = correct_anchored(labels, ep.source, ep.mask, ep.n_labels)
    assert rew[lag:] == ok.astype(float).tolist()
    with pytest.raises(gym.error.ResetNeeded):
        env.step(0)


def test_lag_labels_the_delayed_pulse():
    spec = short("paper-v0/mk94-two-var1", 40)
    env = make(MAIN, scenario=spec, lag=2)
    env.reset(seed=0)
    env.step(0), env.step(0)
    env.step(1)  # labels pulse 0
    assert env.unwrapped.labels[0] == 1 and np.all(env.unwrapped.labels[1:] == -1)


def test_bad_lag_and_scenario():
    with pytest.raises(DeintError, match="lag"):
        make(MAIN, lag=-1)
    with pytest.raises(DeintError, match="no-such-scenario"):
        make(MAIN, scenario="no-such-scenario")


# ---- reset info ------------------------------------------------------------------------------------------
def test_reset_info_priors_without_truth():
    env = make(MAIN, scenario="core-v0/core-n3-spread4-jitter0.2")
    _, info = env.reset(seed=5)
    ep = env.unwrapped.episode
    assert set(info["priors"]) == set(ep.priors.as_info())
    # docs/design.md section 4: periods, phases, their spreads, source probabilities, jitter
    assert {"period", "phase", "period_std", "phase_std", "source_prob", "jitter_std"} <= set(info["priors"])
    assert not {"source", "mask", "truth", "schedule_toa", "toa"} & (set(info) | set(info["priors"]))
    np.testing.assert_array_equal(info["priors"]["period"], ep.priors.period)
    # perturbed priors (1 % period error): the truth is not what the policy is told
    assert not np.array_equal(info["priors"]["period"], ep.truth.period)
    assert np.allclose(info["priors"]["period"], ep.truth.period, rtol=0.06)
    assert info["scenario"] == "core-n3-spread4-jitter0.2" and info["has_amplitude"] is False


def test_reset_info_arrays_are_fresh():
    env = make()
    _, a = env.reset(seed=1)
    _, b = env.reset(seed=1)
    for k, v in a["priors"].items():
        if isinstance(v, np.ndarray):
            assert v is not b["priors"][k] and not np.shares_memory(v, b["priors"][k])
    a["priors"]["period"][:] = -1.0  # a policy scribbling on its info leaves the env intact
    _, c = env.reset(seed=1)
    np.testing.assert_array_equal(c["priors"]["period"], b["priors"]["period"])
    assert np.all(env.unwrapped.episode.priors.period > 0)


def test_step_infos_leak_nothing():
    env = make(MAIN, scenario=short("robust-v0/robust-combined", 100))
    *_, infos, _ = play(env, seed=0)
    for info in infos[:-1]:
        assert not {"source", "mask", "truth"} & set(info)
        # the metrics are placeholders until the last step
        m = info["metrics"]
        assert m["n_pulses"] == 0 and np.all(m["pe"] == -np.inf)
        assert all(v == -np.inf for k, v in m.items() if isinstance(v, float))
    assert infos[-1]["metrics"]["n_pulses"] == 100 and 0 <= infos[-1]["metrics"]["accuracy"] <= 1


# ---- actions and rewards -----------------------------------------------------------------------------------
def test_out_of_range_action_raises():
    env = make()
    env.reset(seed=0)
    n = env.action_space.n
    with pytest.raises(DeintError, match="action"):
        env.step(n)
    with pytest.raises(DeintError, match="action"):
        env.step(-1)
    env.step(np.int64(n - 1))  # numpy integers are fine


@pytest.mark.parametrize("name", ["robust-v0/robust-combined", "paper-v0/mk94-missing-two", "paper-v0/mk94-pt-post",
                                  "agile-v0/agile-all-stagger", "robust-v0/robust-spurious0.2"])
@pytest.mark.parametrize("lag", [0, 2])
def test_perfect_labelling_scores_one(name, lag):
    spec = short(name, 400)
    env = make(MAIN, scenario=spec, lag=lag)
    env.reset(seed=8)
    ep = env.unwrapped.episode
    acts = np.concatenate([np.zeros(lag, np.int64), perfect_actions(ep)])
    _, _, _, rew, infos, _ = play(env, seed=8, actions=acts)
    assert rew[lag:] == [1.0] * spec.n_pulses
    m = infos[-1]["metrics"]
    assert m["accuracy"] == 1.0 and m["matched_accuracy"] == 1.0 and m["mean_pe"] == 0.0


def test_merged_pulse_right_under_either_source():
    spec = short("paper-v0/mk94-missing-two", 400)
    ep = simulate(spec, 3)
    merged = np.flatnonzero(ep.mask == 3)
    assert merged.size > 0
    acts = perfect_actions(ep)
    acts[merged] = 1 - ep.source[merged]  # the other member source
    env = make(MAIN, scenario=spec)
    _, _, _, rew, _, _ = play(env, seed=3, actions=acts)
    assert rew == [1.0] * spec.n_pulses
    acts[merged] = ep.n_labels  # "spurious" is wrong for a merged pulse
    _, _, _, rew, _, _ = play(env, seed=3, actions=acts)
    assert sum(rew) == spec.n_pulses - merged.size


BLIND = ScenarioSpec(name="blind-test", sources=tuple(SourceSpec(period=10.0 * 1.3**i) for i in range(4)),
                     n_pulses=500, toa_jitter_std=0.1, coincidence_resolution=0.5, spurious_rate=0.1, blind=True,
                     label_budget=6, n_active=(2, 4), priors=PriorSpec(kind="none"))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_blind_reward_equals_correct_link(seed):
    env = make(MAIN, scenario=BLIND, lag=1)
    env.reset(seed=seed)
    ep = env.unwrapped.episode
    rng = np.random.default_rng(seed)
    # mostly the true sources (labels 0..k-1, spurious -> budget), sometimes a random label
    acts = np.where(rng.random(len(ep)) < 0.8, perfect_actions(ep), rng.integers(0, BLIND.label_budget + 1, len(ep)))
    acts = np.concatenate([[0], acts])
    _, info0, _, rew, infos, _ = play(env, seed=seed, actions=acts)
    assert info0["priors"]["blind"] is True and info0["priors"]["n_labels"] == BLIND.label_budget
    labels = env.unwrapped.labels
    assert np.array_equal(labels, acts[1:])
    want = correct_link(labels, ep.source, ep.mask, BLIND.label_budget)
    assert rew[1:] == want.astype(float).tolist()
    assert 0 < sum(rew) < len(ep)
    assert infos[-1]["metrics"]["accuracy"] == pytest.approx(want.mean())
    assert np.any(np.bitwise_and(ep.mask, ep.mask - np.uint64(1)) != 0) and np.any(ep.source < 0)


def test_blind_perfect_links_without_merges():
    spec = short("blind-v0/blind-n3to3-jitter0.1", 400)
    env = make(MAIN, scenario=spec)
    env.reset(seed=4)
    ep = env.unwrapped.episode
    # any permutation of the labels is as good: the reward is for links
    perm = np.array([5, 2, 7])
    acts = perm[ep.source]
    _, _, _, rew, infos, _ = play(env, seed=4, actions=acts)
    assert rew == [1.0] * len(ep)
    assert infos[-1]["metrics"]["accuracy"] == 1.0 and infos[-1]["metrics"]["matched_accuracy"] == 1.0


def test_step_before_reset():
    env = make().unwrapped
    with pytest.raises(gym.error.ResetNeeded):
        env.step(0)


# ---- the same info structure at every step (Minari records infos) -------------------------------------------
def _structure(info):
    """Keys, and for each leaf its type (and dtype and shape for arrays)."""
    if isinstance(info, dict):
        return {k: _structure(v) for k, v in info.items()}
    if isinstance(info, np.ndarray):
        return ("array", info.dtype.str, info.shape)
    return type(info).__name__


@pytest.mark.parametrize("scenario,lag", [("paper-v0/mk94-two-var1", 0), ("blind-v0/blind-n2to5-jitter0.1", 2),
                                          ("paper-v0/cm00-five-jitter0", 1), ("robust-v0/robust-combined", 0)])
def test_every_info_has_the_reset_structure(scenario, lag):
    env = make(MAIN, scenario=short(scenario, 120), lag=lag)
    _, info0, _, _, infos, _ = play(env, seed=3)
    want = _structure(info0)
    assert all(_structure(i) == want for i in infos)
    ep = env.unwrapped.episode
    m = infos[-1]["metrics"]
    assert m["n_pulses"] == len(ep) and m["lag"] == lag and 0 <= m["accuracy"] <= 1
    json_form = env.unwrapped.metrics()  # the JSON form: pe a list, None for a source without pulses
    assert [math.nan if v is None else v for v in json_form["pe"]] == pytest.approx(m["pe"].tolist(), nan_ok=True)
    assert {k: v for k, v in json_form.items() if k != "pe"} == pytest.approx(
        {k: v for k, v in m.items() if k != "pe"}, nan_ok=True)
    # priors in full at reset only; placeholders after it
    np.testing.assert_array_equal(info0["priors"]["period"], ep.priors.period)
    assert np.all(infos[0]["priors"]["period"] == -np.inf) and infos[0]["priors"]["n_labels"] == ep.n_labels


def test_minari_records_infos(tmp_path, monkeypatch):
    from minari import DataCollector

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    env = DataCollector(make(MAIN, scenario=short("paper-v0/cm00-five-jitter23", 60), lag=1), record_infos=True)
    rng = np.random.default_rng(0)
    for seed in (1, 2, 3):
        env.reset(seed=seed)
        while not env.step(int(rng.integers(env.action_space.n)))[2]:
            pass
    dataset = env.create_dataset("deint/test-v0", eval_env=env.spec, algorithm_name="random",
                                 author="deint-bench tests", author_email="tests@example.invalid",
                                 code_permalink="none", description="three random-label episodes")
    assert dataset.total_episodes == 3
    for episode in dataset.iterate_episodes():
        infos = episode.infos
        steps = len(episode.rewards)
        assert steps == 61
        assert infos["priors"]["period"].shape == (steps + 1, 5)
        assert np.all(np.isfinite(infos["priors"]["period"][0])) and np.all(infos["priors"]["period"][1:] == -np.inf)
        acc = infos["metrics"]["accuracy"]
        assert acc.shape == (steps + 1,) and np.all(acc[:-1] == -np.inf) and 0 <= acc[-1] <= 1
        assert infos["metrics"]["pe"].shape == (steps + 1, 5)
    env.close()


# ---- split= ------------------------------------------------------------------------------------------------
def test_split_refuses_the_other_splits_seeds():
    name = "core-v0/core-n2-spread1.5-jitter0.05"
    train = make(MAIN, scenario=name, split="train")
    train.reset(seed=98_999)
    with pytest.raises(DeintError, match=r"^seed=1000000 is a test seed of core-v0/core-n2-spread1.5-jitter0.05: "
                                         r"this env \(split='train'\) plays train seeds \[0, 99000\) only$"):
        train.reset(seed=1_000_000)
    with pytest.raises(DeintError, match=r"^seed=99000 is a validation seed .* plays train seeds"):
        train.reset(seed=99_000)
    with pytest.raises(DeintError, match="not a seed of any split"):
        train.reset(seed=500_000)
    validation = make(MAIN, scenario=name, split="validation")
    validation.reset(seed=99_999)
    with pytest.raises(DeintError, match=r"seed=1000000 is a test seed .* plays validation seeds \[99000, 100000\)"):
        validation.reset(seed=1_000_000)
    test = make(MAIN, scenario=name, split="test")
    test.reset(seed=1_000_009)
    with pytest.raises(DeintError, match=r"seed=5 is a train seed .* plays test seeds \[1000000, 1000010\) only"):
        test.reset(seed=5)
    # unseeded resets draw from the split
    for env, lo, hi in ((train, 0, 99_000), (validation, 99_000, 100_000), (test, 1_000_000, 1_000_010)):
        env.reset(seed=None)
        for _ in range(5):
            env.reset()
            assert lo <= env.unwrapped.episode.seed < hi
    # split=None plays any seed, as before
    make(MAIN, scenario=name).reset(seed=1_000_000)


def test_split_needs_a_suite_scenario():
    spec = short("core-v0/core-n2-spread1.5-jitter0.05", 100)  # changed: in no suite
    with pytest.raises(DeintError, match="needs a suite scenario"):
        make(MAIN, scenario=spec, split="train")
    with pytest.raises(DeintError, match=r"split='dev' is invalid: None, 'train', 'validation' or 'test'"):
        make(MAIN, split="dev")
    # a spec equal to a suite's, and a bare scenario name, find their seed ranges
    same = resolve_scenario("core-v0/core-n2-spread1.5-jitter0.05")
    assert make(MAIN, scenario=same.to_dict(), split="test").unwrapped.split.scenario == \
        "core-v0/core-n2-spread1.5-jitter0.05"
    assert make(MAIN, scenario="mk94-three", split="train").unwrapped.split.scenario == "paper-v0/mk94-three"

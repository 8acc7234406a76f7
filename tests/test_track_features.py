"""Token features (layout 2): conformance, meaning, batched = single step for step, multi-scenario env."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import deint_env  # noqa: F401  (registers the ids)
from deint_env.envs.deinterleave import DeinterleaveEnv
from deint_env.envs.mixed import MixedScenarioVectorEnv, split_seeds
from deint_env.envs.tokens import make_tokens_env, make_tokens_vector_env
from deint_env.errors import DeintError
from deint_env.features import CLIP, TrackLayout
from deint_env.registration import TOKENS_ID
from deint_env.scenario import PriorSpec, ScenarioSpec, SourceSpec
from deint_env.suites import find_entry, resolve_scenario
from deint_env.wrappers import TrackTokens

PERIODIC = ScenarioSpec(name="periodic", n_pulses=200,
                        sources=(SourceSpec(period=10.0, phase=3.0), SourceSpec(period=14.142, phase=5.5),
                                 SourceSpec(period=23.3, phase=1.0)),
                        priors=PriorSpec(period_error=0.0, phase_error=0.0))
NAMES = TrackLayout(lookahead=3).token_names


def short(name: str, n: int = 60) -> ScenarioSpec:
    return resolve_scenario(name).replace(n_pulses=n)


@pytest.mark.parametrize("scenario,lag", [("core-v0/core-n3-spread4-jitter0.05", 0),
                                          ("core-v0/core-n3-spread4-jitter0.05", 2),
                                          ("blind-v0/blind-n2to2-jitter0.1", 1)])
def test_gymnasium_and_sb3_checkers_pass(scenario, lag):
    env = gym.make(TOKENS_ID, scenario=short(scenario), lag=lag, max_tracks=8)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    assert [str(w.message) for w in caught if "different from the unwrapped" not in str(w.message)] == []
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_checker.check_env(TrackTokens(DeinterleaveEnv(short(scenario), lag=lag), max_tracks=8, flat=True))


def _labels_truly(env, seed):
    """Play one episode labelling every pulse with its source; yields (obs, true label) per labelling step."""
    obs, _ = env.reset(seed=seed)
    ep, lag = env.unwrapped.episode, env.unwrapped.lag
    m = env.layout.max_tracks
    truth = np.where(ep.source >= 0, ep.source, m)
    k, out = 0, []
    while True:
        j = k - lag
        a = int(truth[j]) if 0 <= j < len(ep) else 0
        if 0 <= j < len(ep):
            out.append((obs, a, j))
        obs, _, term, _, _ = env.step(a)
        k += 1
        if term:
            return out, ep


def test_on_schedule_pulses_have_zero_residual_and_lookahead_finds_the_next_one():
    env = TrackTokens(DeinterleaveEnv(PERIODIC, lag=3, clustering_metrics=False), max_tracks=5)
    steps, ep = _labels_truly(env, 0)
    resid, z = NAMES.index("resid"), NAMES.index("z")
    hits = 0
    for obs, s, j in steps:
        tracks = obs["tracks"]
        assert abs(tracks[s, resid]) < 1e-6 and abs(tracks[s, z]) < 1e-3
        assert np.all(tracks[3:] == 0) and obs["mask"].tolist() == [1, 1, 1, 0, 0]
        nxt = np.flatnonzero(ep.source[j + 1:j + 4] == s)  # the source's next pulse within the look-ahead
        if nxt.size:
            hits += 1
            ahead = int(nxt[0]) + 1
            assert abs(tracks[s, NAMES.index(f"ahead_self_{ahead}")]) < 1e-6
            assert abs(tracks[s, NAMES.index(f"ahead_self_z_{ahead}")]) < 1e-3
    assert hits > 20


def test_features_are_bounded_and_masks_name_the_scenarios_labels():
    env = make_tokens_env(short("core-v0/core-n3-spread4-jitter0.05", 100), lag=1, max_tracks=6)
    obs, _ = env.reset(seed=4)
    assert env.action_masks().tolist() == [True, True, True, False, False, False, True]
    rng = np.random.default_rng(0)
    for _ in range(101):
        assert env.observation_space.contains(obs) and np.all(np.abs(obs["tracks"]) <= CLIP)
        obs, *_ = env.step(int(rng.choice(np.flatnonzero(env.action_masks()))))


def _match(scenario, lag, n_envs=3, steps=260):
    venv = make_tokens_vector_env(n_envs, scenario=scenario, lag=lag, max_tracks=9)
    envs = [make_tokens_env(scenario, lag=lag, max_tracks=9, clustering_metrics=False) for _ in range(n_envs)]
    vo, _ = venv.reset(seed=10)
    so = [e.reset(seed=10 + i)[0] for i, e in enumerate(envs)]
    rng, done, ends = np.random.default_rng(0), [False] * n_envs, 0
    for _ in range(steps):
        for i in range(n_envs):
            assert all(np.array_equal(vo[k][i], so[i][k]) for k in vo)
        masks = venv.action_masks()
        a = np.array([rng.choice(np.flatnonzero(masks[i])) for i in range(n_envs)])
        vo, vr, vt, _, _ = venv.step(a)
        for i, e in enumerate(envs):
            if done[i]:  # NEXT_STEP autoreset: the single env is reset where the vector env restarts
                so[i], r, t = e.reset()[0], 0.0, False
            else:
                so[i], r, t, _, _ = e.step(int(a[i]))
            assert r == vr[i] and t == vt[i]
            done[i] = t
            ends += t
    assert ends >= n_envs  # every sub-env crossed an episode boundary


@pytest.mark.parametrize("lag", [0, 2])
def test_batched_features_match_single_envs_step_for_step(lag):
    _match(short("core-v0/core-n3-spread4-jitter0.05"), lag)


def test_batched_blind_features_match_single_envs():
    _match(short("blind-v0/blind-n2to2-jitter0.1"), 1)


def test_make_vec_gives_the_batched_env_and_make_the_single_one():
    envs = gym.make_vec(TOKENS_ID, num_envs=4, scenario="core-v0/core-n8-spread4-jitter0.05")
    obs, _ = envs.reset(seed=0)
    assert obs["tracks"].shape == (4, 8, len(TrackLayout().token_names)) and envs.action_masks().shape == (4, 9)
    env = gym.make(TOKENS_ID, scenario="core-v0/core-n2-spread4-jitter0.05", max_tracks=4)
    assert env.reset(seed=0)[0]["mask"].tolist() == [1, 1, 0, 0]


@pytest.mark.parametrize("kwargs", [dict(suite="core-v0", tags=("jitter",), split="validation", lag=2),
                                    dict(scenarios=["core-v0/core-n2-spread4-jitter0.05",
                                                    "core-v0/core-n3-spread4-jitter0.05"], max_tracks=4)])
def test_make_and_make_vec_take_the_same_keywords_and_play_the_same_episodes(kwargs):
    """gym.make takes suite=, scenarios=, tags=, split= as gym.make_vec does; reset(seed=s) plays the
    episode of the vector env's sub-env 0, step for step (a narrower scenario's spurious label is the
    widest one's, as in the vector env)."""
    env = gym.make(TOKENS_ID, **kwargs)
    envs = gym.make_vec(TOKENS_ID, num_envs=2, **kwargs)
    obs, info = env.reset(seed=4)
    vobs, vinfo = envs.reset(seed=4)
    assert f"core-v0/{info['scenario']}" == vinfo["scenario"][0]
    rng = np.random.default_rng(0)
    for _ in range(1000 + kwargs.get("lag", 0)):
        assert all(np.array_equal(obs[k], vobs[k][0]) for k in obs)
        mask = env.get_wrapper_attr("action_masks")()
        assert np.array_equal(mask, envs.action_masks()[0])
        a = int(rng.choice(np.flatnonzero(mask)))
        obs, r, done, _, _ = env.step(a)
        vobs, vr, vdone, _, _ = envs.step(np.array([a, 0]))
        assert (r, done) == (vr[0], vdone[0])
        if done:
            break
    assert done
    split = kwargs.get("split", "train")
    entry = find_entry(vinfo["scenario"][0])
    assert vinfo["episode_seed"][0] in split_seeds(entry, split)
    with pytest.raises(DeintError, match="not both"):
        gym.make(TOKENS_ID, scenario="core-v0/core-n2-spread4-jitter0.05", **kwargs)
    single = dict(scenario="core-v0/core-n2-spread4-jitter0.05", split="validation")  # one scenario: its split only
    for made in (gym.make(TOKENS_ID, **single), gym.make_vec(TOKENS_ID, num_envs=1, **single)):
        with pytest.raises(DeintError, match="validation"):
            made.reset(seed=0)


def test_mixed_env_samples_scenarios_and_only_its_split_seeds():
    env = MixedScenarioVectorEnv(8, suite="core-v0", tags=("jitter",), split="train")
    _, info = env.reset(seed=3)
    names, seeds = list(info["scenario"]), list(info["episode_seed"])
    assert len(set(names)) > 2 and all(n.startswith("core-v0/") for n in names)
    for n, s in zip(names, seeds):
        entry = find_entry(n)
        assert s in split_seeds(entry, "train") and s not in split_seeds(entry, "validation")
        assert s < entry.train.stop and not entry.test.start <= s < entry.test.stop
    again = MixedScenarioVectorEnv(8, suite="core-v0", tags=("jitter",), split="train")
    assert list(again.reset(seed=3)[1]["episode_seed"]) == seeds  # reproducible
    val = MixedScenarioVectorEnv(4, suite="core-v0", split="validation").reset(seed=0)[1]
    assert all(s in split_seeds(find_entry(n), "validation") for n, s in zip(val["scenario"], val["episode_seed"]))
    assert env.n_labels == 8  # the widest scenario's labels; label 8 is spurious for all


def test_mixed_env_refusals():
    with pytest.raises(DeintError, match="split"):
        MixedScenarioVectorEnv(2, suite="core-v0", split="dev")
    with pytest.raises(DeintError, match="mix anchored and blind"):
        MixedScenarioVectorEnv(2, scenarios=["core-v0/core-n2-spread4-jitter0.05", "blind-v0/blind-n2to2-jitter0.1"])
    with pytest.raises(DeintError, match="tags"):
        MixedScenarioVectorEnv(2, suite="core-v0", tags=("blind",))
    with pytest.raises(DeintError, match="at most 4"):
        make_tokens_vector_env(2, suite="core-v0", max_tracks=4)


def test_mixed_env_plays_whole_episodes_with_right_rewards():
    venv = make_tokens_vector_env(4, suite="core-v0", tags=("jitter",), max_tracks=8)
    venv.reset(seed=1)
    base = venv.env.unwrapped
    total = np.zeros(4)
    for _ in range(1000):  # core-v0 episodes have 1000 pulses: label every pulse truly
        ep_truth = [ep.source[base._k[i]] for i, ep in enumerate(base.episodes)]
        a = np.array([s if s >= 0 else 8 for s in ep_truth])
        _, r, term, _, info = venv.step(a)
        total += r
    assert term.all() and np.array_equal(total, np.full(4, 1000.0))


def test_same_step_autoreset_is_next_step_without_the_reset_steps():
    from gymnasium.vector import AutoresetMode

    from deint_env.envs.vector import DeinterleaveVectorEnv

    spec = short("core-v0/core-n2-spread4-jitter0.05", 30)
    nxt = DeinterleaveVectorEnv(2, spec, lag=1)
    same = DeinterleaveVectorEnv(2, spec, lag=1, autoreset_mode=AutoresetMode.SAME_STEP)
    o1, _ = nxt.reset(seed=5)
    o2, _ = same.reset(seed=5)
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(100):
        a = rng.integers(0, 3, 2)
        o1, r1, t1, _, _ = nxt.step(a)
        o2, r2, t2, _, info = same.step(a)
        assert np.array_equal(r1, r2) and np.array_equal(t1, t2)
        if t1.any():  # NEXT_STEP needs one more step to show the new episode; SAME_STEP already does
            ends += 1
            assert info["_final_obs"].tolist() == t1.tolist()
            o1, *_ = nxt.step(a)
        assert all(np.array_equal(o1[k], o2[k]) for k in o1)
    assert ends >= 3
    with pytest.raises(DeintError, match="autoreset_mode"):
        DeinterleaveVectorEnv(2, spec, autoreset_mode="Disabled")

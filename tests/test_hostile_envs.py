"""Hostile env and runner arguments (issue 26): what int() or a default would silently accept is refused."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import deint_env  # noqa: F401  (registers the ids)
from deint_env.errors import DeintError
from deint_env.runner import evaluate

ID = "deint_env/Deinterleave-v0"
SCENARIO = "paper-v0/mk94-two-var1"


@pytest.fixture
def env():
    e = gym.make(ID, scenario=SCENARIO).unwrapped
    e.reset(seed=1_000_000)
    return e


@pytest.mark.parametrize("action", [1.7, 2.0, np.float64(1.0), "1", True, np.bool_(False), np.array([0, 1]),
                                    np.array([1.0]), None])
def test_a_non_integer_action_is_refused(env, action):
    with pytest.raises(DeintError, match=r"action=.* is invalid: a label in \[0, 2\]"):
        env.step(action)


@pytest.mark.parametrize("action", [1, np.int64(1), np.uint8(1), np.array(1), np.array([1])])
def test_integer_actions_of_every_kind_play(env, action):
    _, reward, *_ = env.step(action)
    assert reward in (0.0, 1.0) and env.labels[0] == 1


@pytest.mark.parametrize("kwargs,says", [
    ({"n_labels": 5}, "these are for scenario=None"),
    ({"blind": True}, "these are for scenario=None"),
    ({"clustering_metrics": "no"}, "clustering_metrics='no' is invalid: True or False"),
])
def test_make_refuses_keywords_it_would_ignore(kwargs, says):
    with pytest.raises(DeintError, match=says):
        gym.make(ID, scenario=SCENARIO, **kwargs)


@pytest.mark.parametrize("kwargs", [{"n_labels": -3}, {"n_labels": 2.5}, {"n_labels": 2, "blind": "yes"}])
def test_an_episode_env_needs_a_real_label_count(kwargs):
    from deint_env.envs.deinterleave import DeinterleaveEnv

    with pytest.raises(DeintError, match="scenario=None needs an integer n_labels >= 1"):
        DeinterleaveEnv(None, **kwargs)


@pytest.mark.parametrize("num_envs", [0, 10**9, True, 2.0])
def test_make_vec_bounds_num_envs(num_envs):
    with pytest.raises(DeintError, match=r"num_envs=.* is invalid: an integer in \[1, 4096\]"):
        gym.make_vec(ID, num_envs=num_envs, scenario=SCENARIO)


def test_make_vec_refuses_a_non_boolean_clustering_flag():
    with pytest.raises(DeintError, match="clustering_metrics='no' is invalid"):
        gym.make_vec(ID, num_envs=2, scenario=SCENARIO, clustering_metrics="no")


@pytest.mark.parametrize("max_seeds", [0, -1, True, 1.5])
def test_evaluate_refuses_a_non_positive_seed_count(max_seeds):
    with pytest.raises(DeintError, match=r"max_seeds=.* is invalid: an integer >= 1 \(or None: every seed\)"):
        evaluate(["random"], SCENARIO, max_seeds=max_seeds, progress=False)


def test_a_ray_address_that_answers_nothing_fails_within_seconds():
    import socket
    import subprocess
    import sys

    with socket.socket() as silent:  # accepts connections, never says a word
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        code = ("from deint_env.runner import evaluate\n"
                f"evaluate(['random'], {SCENARIO!r}, max_seeds=1, progress=False, executor='ray', address={address!r})")
        # A process of its own: a Ray instance this test session already joined would be used instead.
        # ray.init alone did not return in 200 s; "timed out" is the probe's own deadline.
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and run.stderr.strip().splitlines()[-1] == (
        f"deint_env.errors.DeintError: cannot reach a Ray cluster at {address!r} (timed out)")


@pytest.mark.parametrize("address", ["nowhere", "host:port", ":6379"])
def test_a_malformed_ray_address_is_one_line(address):
    pytest.importorskip("ray")
    from deint_env.runner import _probe_ray

    with pytest.raises(DeintError, match=r"is invalid: 'auto', HOST:PORT or ray://HOST:PORT"):
        _probe_ray(address)

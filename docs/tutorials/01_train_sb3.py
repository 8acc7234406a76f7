"""Tutorial 1: train MaskablePPO on the token env, then measure it on validation seeds."""

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import MaskablePPO

import deint_env  # noqa: F401  (importing it registers the env ids)
from agents.networks import MaskableTrackPolicy
from agents.vec_env import TokenVecEnv
from deint_env.suites import load_suite

torch.set_num_threads(1)  # a small network: one thread is fastest, and leaves the other cores free

SCENARIO = "core-v0/core-n3-spread4-jitter0.05"  # three constant-PRI sources
LAG = 2  # label each pulse after seeing the next two

# 4 copies of the scenario, stepped together in numpy; they play train seeds only
venv = TokenVecEnv.make(4, scenarios=[SCENARIO], split="train", lag=LAG)
model = MaskablePPO(MaskableTrackPolicy, venv, n_steps=256, batch_size=256, seed=0, verbose=0)


def validation_accuracy(model: MaskablePPO, n_episodes: int = 3) -> float:
    """Mean label accuracy of the greedy policy on the scenario's first validation seeds."""
    entry = load_suite("core-v0").entry(SCENARIO.split("/")[1])
    env = gym.make("deint_env/DeinterleaveTokens-v0", scenario=SCENARIO, lag=LAG)
    accuracies = []
    for seed in entry.seeds("validation")[:n_episodes]:
        obs, info = env.reset(seed=seed)
        done = False
        while not done:
            masks = env.get_wrapper_attr("action_masks")()  # which actions are tracks of this scenario
            action, _ = model.predict(obs, action_masks=masks, deterministic=True)
            obs, reward, done, truncated, info = env.step(action)
        accuracies.append(info["metrics"]["accuracy"])  # the last step's info holds the episode's metrics
    return float(np.mean(accuracies))


print(f"validation accuracy before training: {validation_accuracy(model):.3f}")
model.learn(total_timesteps=24_576)
print(f"validation accuracy after training: {validation_accuracy(model):.3f}")

"""SB3 PPO training throughput on the batched token features against SB3 PPO on CartPole-v1.

Same PPO settings for both (MlpPolicy 64x64, n_envs, n_steps, batch, epochs; one torch thread), run
alternately in this process; CartPole runs through SB3's DummyVecEnv as usual.  Ours: the native
vector env with the token features computed in numpy for all sub-envs (`agents.vec_env.TokenVecEnv`),
flat layout for MlpPolicy; also MaskablePPO with the track network (its own, larger, network) for
reference.  Target (issue 9): ours >= 0.8x CartPole's steps/s.
`python benchmarks/bench_training.py [--timesteps 20480] [--repeats 3]`
"""

from __future__ import annotations

import argparse
import time

import torch

SETTINGS = dict(n_steps=128, batch_size=512, n_epochs=4, learning_rate=3e-4, gamma=0.5, device="cpu",
                policy_kwargs=dict(net_arch=[64, 64]))


def steps_per_second(make, timesteps: int, repeats: int) -> float:
    best = 0.0
    for _ in range(repeats):
        model = make()
        t0 = time.perf_counter()
        model.learn(total_timesteps=timesteps)
        best = max(best, model.num_timesteps / (time.perf_counter() - t0))
        model.env.close()
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=20_480)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--n-envs", type=int, default=16)
    parser.add_argument("--scenario", default="core-v0/core-n6-spread4-jitter0.05")
    args = parser.parse_args()
    torch.set_num_threads(1)
    from sb3_contrib import MaskablePPO
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    from agents.networks import MaskableTrackPolicy
    from agents.vec_env import TokenVecEnv

    n = args.n_envs
    runs = {
        "CartPole-v1, PPO MlpPolicy (DummyVecEnv)": lambda: PPO("MlpPolicy", make_vec_env("CartPole-v1", n_envs=n),
                                                                 seed=0, **SETTINGS),
        f"{args.scenario}, PPO MlpPolicy (flat tokens)": lambda: PPO(
            "MlpPolicy", TokenVecEnv.make(n, scenario=args.scenario, flat=True), seed=0, **SETTINGS),
        f"{args.scenario}, MaskablePPO track network": lambda: MaskablePPO(
            MaskableTrackPolicy, TokenVecEnv.make(n, scenario=args.scenario), seed=0,
            **{**SETTINGS, "policy_kwargs": dict(d_model=64)}),
        "core-v0 (all scenarios), PPO MlpPolicy (flat tokens)": lambda: PPO(
            "MlpPolicy", TokenVecEnv.make(n, suite="core-v0", flat=True), seed=0, **SETTINGS),
    }
    figures = {name: steps_per_second(make, args.timesteps, args.repeats) for name, make in runs.items()}
    cart = next(iter(figures.values()))
    print(f"PPO training steps/s, {n} envs, n_steps {SETTINGS['n_steps']}, batch {SETTINGS['batch_size']}, "
          f"{SETTINGS['n_epochs']} epochs, {args.timesteps} steps, best of {args.repeats}")
    for name, sps in figures.items():
        print(f"  {name:58s} {sps:8.0f} steps/s  {sps / cart:5.2f}x CartPole")


if __name__ == "__main__":
    main()

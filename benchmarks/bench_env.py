"""Single-env step time against CartPole-v1's, measured in the same run.

Both envs are stepped unwrapped (the env's own cost) and through `gym.make` (what users get).
Target (issue 2): our step <= 2x CartPole's.  `python benchmarks/bench_env.py [--steps 200000]`
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import deint_env  # noqa: E402,F401  (registers the ids)


def us_per_step(env: gym.Env, steps: int) -> float:
    actions = np.random.default_rng(0).integers(0, env.action_space.n, steps).tolist()
    env.reset(seed=0)
    step, reset = env.step, env.reset
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = step(a)
        if terminated or truncated:
            reset()
    return 1e6 * (time.perf_counter() - t0) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--steps", type=int, default=200_000)
    args = ap.parse_args()
    rows = []
    for label, make in (("unwrapped", lambda i, **kw: gym.make(i, **kw).unwrapped), ("gym.make", gym.make)):
        cart = min(us_per_step(make("CartPole-v1"), args.steps) for _ in range(3))
        for scenario in ("paper-v0/mk94-two-var1", "core-v0/core-n8-spread4-jitter0.2", "blind-v0/blind-n2to5-jitter0.5"):
            ours = min(us_per_step(make("deint_env/Deinterleave-v0", scenario=scenario,
                                        clustering_metrics=False), args.steps) for _ in range(3))
            rows.append((label, scenario, ours, cart))
    print(f"{'how':<10} {'scenario':<36} {'us/step':>8} {'CartPole':>9} {'ratio':>6}")
    for label, scenario, ours, cart in rows:
        print(f"{label:<10} {scenario:<36} {ours:>8.2f} {cart:>9.2f} {ours / cart:>6.2f}")
    print("target: ratio <= 2 (episode resets, i.e. simulation, included in our time)")


if __name__ == "__main__":
    main()

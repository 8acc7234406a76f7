"""Single-env step time against CartPole-v1's, measured side by side in the same run.

What users get: both envs through `gym.make` (so both carry Gymnasium's PassiveEnvChecker and
OrderEnforcing wrappers), default arguments, stepped with random actions in the same loop, episode
resets included, and for ours the final step's metrics (label and clustering metrics) and the per-step
info included.  The rounds alternate between the two envs so that load from other processes falls on
both alike; the best round of each is kept.  `unwrapped` rows show the envs' own cost.
Target (issue 7): the default `gym.make("deint_env/Deinterleave-v0")` <= 1.5x CartPole-v1.

    python benchmarks/bench_env.py [--steps 100000] [--rounds 5]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import deint_env  # noqa: F401  (registers the ids)

MAIN = "deint_env/Deinterleave-v0"
SCENARIOS = (None, "core-v0/core-n8-spread4-jitter0.2", "blind-v0/blind-n2to5-jitter0.5")


def us_per_step(env: gym.Env, steps: int) -> tuple[float, int]:
    """Microseconds per step over `steps` random actions (resets included), and the episodes ended."""
    actions = np.random.default_rng(0).integers(0, env.action_space.n, steps).tolist()
    env.reset(seed=0)
    step, reset = env.step, env.reset
    episodes = 0
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = step(a)
        if terminated or truncated:
            reset()
            episodes += 1
    return 1e6 * (time.perf_counter() - t0) / steps, episodes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print(f"{'how':<10} {'env':<52} {'us/step':>8} {'episodes':>9} {'CartPole':>9} {'ratio':>6}")
    for how, wrap in (("gym.make", lambda env: env), ("unwrapped", lambda env: env.unwrapped)):
        for scenario in SCENARIOS:
            kwargs = {} if scenario is None else {"scenario": scenario}
            ours, cart = [], []
            for _ in range(args.rounds):  # alternate, so that both see the same background load
                cart.append(us_per_step(wrap(gym.make("CartPole-v1")), args.steps))
                ours.append(us_per_step(wrap(gym.make(MAIN, **kwargs)), args.steps))
            (o, o_eps), (c, _) = min(ours), min(cart)
            name = MAIN + ("" if scenario is None else f" {scenario.split('/')[1]}")
            print(f"{how:<10} {name:<52} {o:>8.2f} {o_eps:>9} {c:>9.2f} {o / c:>6.2f}")
    print("target: gym.make default env <= 1.5x CartPole-v1 (first row)")


if __name__ == "__main__":
    main()

"""Throughput of the native vector env against Gymnasium's CartPoleVectorEnv, measured in one run.

    python benchmarks/bench_vector_env.py [--steps S] [--num-envs 1024] [--scenario NAME] [--n-pulses 1000]

Both envs take random actions from a pregenerated array.  Each step is timed on its own so the steps
on which sub-envs autoreset (NEXT_STEP: the step after an episode ends, when `simulate()` makes the
new episodes) can be shown apart from plain stepping.  The default run is three whole episode
cycles, so "with autoresets" is the steady-state rate.  The target is a ratio >= 0.5 to CartPole;
it is reported, never asserted.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

import deint_env
from deint_env.envs.vector import DeinterleaveVectorEnv

TARGET = 0.5


def timed_steps(env, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seconds per step, and whether the step autoreset some sub-env (one ended on the step before)."""
    times = np.empty(len(actions))
    autoreset = np.zeros(len(actions), bool)
    ended = False
    clock = time.perf_counter
    for t, a in enumerate(actions):
        t0 = clock()
        _, _, terminated, truncated, _ = env.step(a)
        times[t] = clock() - t0
        autoreset[t] = ended
        ended = bool(terminated.any() or truncated.any())
    return times, autoreset


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=None,
                   help="vector steps per env (default: three episode cycles, n_pulses + lag + 1 each)")
    p.add_argument("--num-envs", type=int, default=1024)
    p.add_argument("--scenario", default="core-v0/core-n3-spread4-jitter0.2")
    p.add_argument("--n-pulses", type=int, default=1000)
    p.add_argument("--lag", type=int, default=0)
    args = p.parse_args(argv)
    n = args.num_envs
    spec = deint_env.resolve_scenario(args.scenario).replace(n_pulses=args.n_pulses)
    steps = args.steps if args.steps is not None else 3 * (args.n_pulses + args.lag + 1)
    rng = np.random.default_rng(0)

    cart = CartPoleVectorEnv(num_envs=n)
    cart.reset(seed=0)
    cart_t, _ = timed_steps(cart, rng.integers(0, 2, (steps, n)))
    cart.close()

    deint = DeinterleaveVectorEnv(num_envs=n, scenario=spec, lag=args.lag, clustering_metrics=False)
    deint.reset(seed=0)
    deint_t, autoreset = timed_steps(deint, rng.integers(0, deint.n_labels + 1, (steps, n)))
    deint.close()

    cart_rate = steps * n / cart_t.sum()
    plain = ~autoreset
    rows = [("CartPoleVectorEnv", cart_rate, cart_t.mean())]
    if plain.any():
        rows.append(("DeinterleaveVectorEnv, stepping only", plain.sum() * n / deint_t[plain].sum(),
                     deint_t[plain].mean()))
    if autoreset.any():
        rows.append(("DeinterleaveVectorEnv, with autoresets", steps * n / deint_t.sum(), deint_t.mean()))

    print(f"{n} envs, {steps} steps each; scenario {spec.name} (n_pulses={spec.n_pulses}, lag={args.lag})")
    print(f"{'':40} {'env-steps/s':>12} {'us/step':>9} {'ratio':>7}")
    for name, rate, per_step in rows:
        print(f"{name:40} {rate / 1e6:>11.2f}M {per_step * 1e6:>9.1f} {rate / cart_rate:>7.2f}")
    if autoreset.any():
        burst = deint_t[autoreset].mean()
        print(f"autoreset steps: {int(autoreset.sum())}, {burst * 1e3:.0f} ms each "
              f"({burst / n * 1e6:.0f} us per new episode, mostly simulate())")
    else:
        print("no autoreset in this run: use --steps > n_pulses + lag to include episode starts")
    for name, rate, _ in rows[1:]:
        verdict = "met" if rate / cart_rate >= TARGET else "not met"
        print(f"target ratio >= {TARGET} ({name.split(', ')[1]}): {verdict}")


if __name__ == "__main__":
    main()

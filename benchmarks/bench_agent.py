"""Policy time per pulse of learned agents beside fdp (the issue-9 target: the agent's time per pulse
<= fdp's), the runner's own compute-time measure (act + reset, not the env).

Default: core-v0 episodes of 2, 4 and 8 sources (test seed 1,000,000), each figure the best of
`--repeats` plays, so other load on the machine disturbs it least; the ratio column is agent / fdp
measured in the same run.  `--suite S`: every scenario of S on its first `--seeds` test seeds (what
the leaderboard times), the policies played in turn on each repeat and each episode's best time kept.

`python benchmarks/bench_agent.py [--policies lmht,dagger-beam,fdp,dagger] [--repeats 3]`
`python benchmarks/bench_agent.py --suite robust-v0 --policy lmht --policy mht:beam=16,margin=15 --policy fdp`
"""

from __future__ import annotations

import argparse

import numpy as np

from deint_env import make_policy, simulate
from deint_env.runner import play
from deint_env.suites import find_entry, load_suite

SCENARIOS = ("core-v0/core-n2-spread4-jitter0.2", "core-v0/core-n4-spread4-jitter0.2", "core-v0/core-n8-spread4-jitter0.2")


def us_per_pulse(spec: str, scenario: str, repeats: int) -> float:
    episode = simulate(find_entry(scenario).spec, 1_000_000)
    best = min(play(make_policy(spec), episode, clustering=False).seconds for _ in range(repeats))
    return 1e6 * best / len(episode)


def suite_us_per_pulse(specs: list[str], suite: str, seeds: int, repeats: int) -> dict[str, float]:
    episodes = [simulate(e.spec, seed) for e in load_suite(suite) for seed in list(e.test)[:seeds]]
    for s in specs:  # first plays load (or compile) the numba kernels
        play(make_policy(s), episodes[0], clustering=False)
    best = {s: np.full(len(episodes), np.inf) for s in specs}
    for _ in range(repeats):
        for s in specs:
            for i, ep in enumerate(episodes):
                best[s][i] = min(best[s][i], play(make_policy(s), ep, clustering=False).seconds)
    n = sum(len(ep) for ep in episodes)
    return {s: 1e6 * float(best[s].sum()) / n for s in specs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--policies", default="lmht,dagger-beam,dagger-beam:beam=4,fdp,dagger",
                    help="plain specs, comma-separated")
    ap.add_argument("--policy", action="append", default=[], help="one spec NAME:k=v,k=v (repeatable; replaces "
                    "--policies)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--suite", help="time every scenario of this suite instead")
    ap.add_argument("--seeds", type=int, default=2, help="with --suite: test seeds per scenario")
    args = ap.parse_args()
    specs = args.policy or args.policies.split(",")
    if args.suite:
        got = suite_us_per_pulse(specs, args.suite, args.seeds, args.repeats)
        print(f"us per pulse (policy compute time, each episode's best of {args.repeats}), {args.suite}, "
              f"{args.seeds} test seeds per scenario")
        for s, v in got.items():
            ratio = f"{v / got['fdp']:>10.2f} x fdp" if "fdp" in got else ""
            print(f"{s:<40}{v:>8.2f}{ratio}")
        return
    table = {s: [us_per_pulse(s, sc, args.repeats) for sc in SCENARIOS] for s in specs}
    print("us per pulse (policy compute time, best of %d), core-v0 test seed 1000000" % args.repeats)
    print(f"{'policy':<28}" + "".join(f"{sc.split('/')[1][5:]:>22}" for sc in SCENARIOS) + f"{'/ fdp (mean)':>14}")
    fdp = table.get("fdp")
    for s, row in table.items():
        ratio = f"{sum(a / b for a, b in zip(row, fdp)) / len(row):>14.2f}" if fdp else ""
        print(f"{s:<28}" + "".join(f"{v:>22.1f}" for v in row) + ratio)


if __name__ == "__main__":
    main()

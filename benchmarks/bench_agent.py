"""Policy time per pulse of the zoo's learned agent (`dagger-beam`, beam decoding with numba kernels
and a numpy network) beside fdp (the issue-9 target: the agent's time per pulse <= fdp's) and the
greedy torch agent `dagger`, on core-v0 episodes of 2, 4 and 8 sources (test seed 1,000,000).
Each figure is the best of `--repeats` plays (the runner's own compute-time measure), so other load
on the machine disturbs it least; the ratio column is agent / fdp measured in the same run.

`python benchmarks/bench_agent.py [--policies dagger-beam,dagger-beam:beam=4,fdp,dagger] [--repeats 3]`
"""

from __future__ import annotations

import argparse

from deint_env import make_policy, simulate
from deint_env.runner import play
from deint_env.suites import find_entry

SCENARIOS = ("core-v0/core-n2-spread4-jitter0.2", "core-v0/core-n4-spread4-jitter0.2", "core-v0/core-n8-spread4-jitter0.2")


def us_per_pulse(spec: str, scenario: str, repeats: int) -> float:
    episode = simulate(find_entry(scenario).spec, 1_000_000)
    best = min(play(make_policy(spec), episode, clustering=False).seconds for _ in range(repeats))
    return 1e6 * best / len(episode)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--policies", default="dagger-beam,dagger-beam:beam=4,fdp,dagger")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    specs = args.policies.split(",")
    table = {s: [us_per_pulse(s, sc, args.repeats) for sc in SCENARIOS] for s in specs}
    print("us per pulse (policy compute time, best of %d), core-v0 test seed 1000000" % args.repeats)
    print(f"{'policy':<28}" + "".join(f"{sc.split('/')[1][5:]:>22}" for sc in SCENARIOS) + f"{'/ fdp (mean)':>14}")
    fdp = table.get("fdp")
    for s, row in table.items():
        ratio = f"{sum(a / b for a, b in zip(row, fdp)) / len(row):>14.2f}" if fdp else ""
        print(f"{s:<28}" + "".join(f"{v:>22.1f}" for v in row) + ratio)


if __name__ == "__main__":
    main()

"""Speed of the agile-PRI trackers: pulses/s of their own compute time (reset + act, as the runner
measures it) on agile-v1 scenarios (modulations named: one model per source) and agile-v0 ones (the
default bank of five models per source), against `dokf` (the constant-PRI DLM tracker, the same
MAP-and-coast loop on 2x2 blocks) measured in the same run; and renewal-ml's cost against its beam.

`python benchmarks/bench_agile.py [--episodes 2]`
"""

from __future__ import annotations

import argparse

from deint_env import make_policy, simulate
from deint_env.runner import play
from deint_env.suites import find_entry

SCENARIOS = ("agile-stagger3", "agile-wobulated", "agile-dwell-switch")
POLICIES = ("dokf", "agile-kf", "renewal-ml:beam=16,lag=8", "renewal-ml")


def rate(policy: str, scenario: str, episodes: int) -> float:
    spec = find_entry(scenario).spec
    pulses = seconds = 0.0
    for seed in range(episodes):
        episode = simulate(spec, 1_000_000 + seed)
        res = play(make_policy(policy), episode, policy_seed=seed, clustering=False)
        pulses += len(episode)
        seconds += res.seconds
    return pulses / seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--episodes", type=int, default=2, help="test episodes (1000 pulses, 3 sources) per cell")
    args = ap.parse_args()
    print(f"pulses/s (policy compute time), {args.episodes} x 1000 pulses, 3 sources")
    header = f"{'policy':<26}" + "".join(f"{s.removeprefix('agile-') + ' ' + v:>22}" for v in ("v1", "v0")
                                         for s in SCENARIOS)
    print(header)
    base = {}
    for policy in POLICIES:
        cells = []
        for suite in ("agile-v1", "agile-v0"):
            for s in SCENARIOS:
                r = rate(policy, f"{suite}/{s}", args.episodes)
                base.setdefault((suite, s), r)  # dokf: the first row
                cells.append(f"{r:>12.0f} ({r / base[(suite, s)]:4.2f}x)")
        print(f"{policy:<26}" + "".join(f"{c:>22}" for c in cells))
    print("(ratios: against dokf on the same episodes, same run)")


if __name__ == "__main__":
    main()

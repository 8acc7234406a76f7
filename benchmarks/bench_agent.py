"""Policy time per pulse of learned agents beside fdp (the issue-9 target: the agent's time per pulse
<= fdp's), the runner's own compute-time measure (act + reset, not the env).

Default: core-v0 episodes of 2, 4 and 8 sources (test seed 1,000,000), each figure the best of
`--repeats` plays, so other load on the machine disturbs it least; the ratio column is agent / fdp
measured in the same run.  `--suite S`: every scenario of S on its first `--seeds` test seeds (what
the leaderboard times), the policies played in turn on each repeat and each episode's best time kept.

`--board`: what the core-v0 board's timing run measures (issue 25: learned entries at most fdp's
µs/pulse), the first test seed of every core-v0 scenario, each policy's median over its episodes played
alone and, for a policy the runner batches (`deint_env.policies.BatchPolicy`), in lock-step (batches
of at most `runner.BATCH`, each episode at its batch's time per pulse), the policies in turn on each
repeat and each episode's best of `--repeats` kept, and the ratio of each median to fdp's (alone).

`python benchmarks/bench_agent.py [--policies lmht,dagger-beam,fdp,dagger] [--repeats 3]`
`python benchmarks/bench_agent.py --suite robust-v0 --policy lmht --policy mht:beam=16,margin=15 --policy fdp`
`python benchmarks/bench_agent.py --board [--policies dagger,dagger-beam,ppo,lmht,fdp]`
"""

from __future__ import annotations

import argparse

import numpy as np

from deint_env import make_policy, simulate
from deint_env.errors import NotApplicable
from deint_env.runner import BATCH, batch_size, play, play_batch
from deint_env.suites import find_entry, load_suite

DEFAULT = "lmht,dagger-beam,dagger-beam:beam=4,fdp,dagger"
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


def board(specs: list[str], repeats: int) -> None:
    """The policies played in turn on each repeat (alone, then batched), so that load on the machine
    falls on all of them alike; each episode's best time is kept."""
    episodes = [simulate(e.spec, e.test.start) for e in load_suite("core-v0")]
    mine: dict[str, list] = {}
    for s in specs:  # the first plays load (or compile) the kernels and tell the episodes each plays
        mine[s] = []
        for ep in episodes:
            try:
                play(make_policy(s), ep, clustering=False, scored=False)
                mine[s].append(ep)
            except NotApplicable:
                pass
    alone = {s: np.full(len(mine[s]), np.inf) for s in specs}
    together = {s: np.full(len(mine[s]), np.inf) for s in specs if batch_size(s) > 1}
    for _ in range(repeats):
        for s in specs:
            times = [play(make_policy(s), ep, scored=False).seconds / len(ep) for ep in mine[s]]
            alone[s] = np.minimum(alone[s], times)
            if s in together:
                size = -(-len(mine[s]) // -(-len(mine[s]) // BATCH))
                got = [r.seconds / len(ep) for i in range(0, len(mine[s]), size)
                       for r, ep in zip(play_batch(make_policy(s), mine[s][i:i + size], scored=False), mine[s][i:])]
                together[s] = np.minimum(together[s], got)
    median = {s: (1e6 * float(np.median(alone[s])) if len(alone[s]) else None,
                  1e6 * float(np.median(together[s])) if s in together and len(together[s]) else None) for s in specs}
    fdp = median["fdp"][0] if "fdp" in median else None
    print(f"us per pulse (policy compute time, median over the first test seed of each core-v0 scenario it plays, "
          f"each episode's best of {repeats}); x fdp = / fdp's median alone, this run")
    print(f"{'policy':<16}{'episodes':>9}{'alone':>10}{'x fdp':>8}{'batched':>10}{'x fdp':>8}")
    for s, values in median.items():
        cells = [f"{v:>10.1f}{v / fdp if fdp else float('nan'):>8.2f}" if v is not None else f"{'-':>10}{'':>8}"
                 for v in values]
        print(f"{s:<16}{len(mine[s]):>9}" + "".join(cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--policies", default=DEFAULT,
                    help="plain specs, comma-separated")
    ap.add_argument("--policy", action="append", default=[], help="one spec NAME:k=v,k=v (repeatable; replaces "
                    "--policies)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--suite", help="time every scenario of this suite instead")
    ap.add_argument("--seeds", type=int, default=2, help="with --suite: test seeds per scenario")
    ap.add_argument("--board", action="store_true", help="the core-v0 board's episodes, alone and batched")
    args = ap.parse_args()
    if args.board:
        board(args.policy or (["dagger", "dagger-beam", "ppo", "lmht", "fdp"] if args.policies == DEFAULT else
                              args.policies.split(",")), args.repeats)
        return
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

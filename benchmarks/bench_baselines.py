"""Speed of every registered policy: pulses/s of its own compute time (reset + act, as the runner
measures it) on 2, 3, 5 and 8 constant-PRI sources, and the cost of 10^4 against 10^5 pulses (a
ratio near 10 means cost linear in the number of pulses).

Targets (issue 3): fdp (lookahead 3) >= 20,000 pulses/s at 3 sources and >= 2,000 at 8; pt-prior
>= 20,000 at 3; ekf-bank >= 5,000 at 5 trains (on the CM00 five-train scenario, 10x the highest PRF).
`python benchmarks/bench_baselines.py [--pulses 4000] [--policies fdp,pt-prior]`
"""

from __future__ import annotations

import argparse

from deint_env import PriorSpec, Range, ScenarioSpec, SourceSpec, make_policy, simulate
from deint_env.errors import NotApplicable
from deint_env.policies import default_policies, is_oracle
from deint_env.runner import play
from deint_env.suites import find_entry

def scenario(n_sources: int, n_pulses: int) -> ScenarioSpec:
    return ScenarioSpec(name=f"bench-{n_sources}", n_pulses=n_pulses, toa_jitter_std=0.2,
                        sources=tuple(SourceSpec(period=Range(10.0, 40.0, log=True)) for _ in range(n_sources)),
                        priors=PriorSpec(kind="perturbed", period_error=0.01, phase_error=0.05))


def rate(policy: str, spec: ScenarioSpec, seed: int = 0) -> float | None:
    episode = simulate(spec, seed)
    try:
        res = play(make_policy(policy), episode, policy_seed=seed, oracle=is_oracle(policy), clustering=False)
    except NotApplicable:
        return None
    return len(episode) / res.seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--pulses", type=int, default=4000)
    ap.add_argument("--policies", default=None,
                    help="comma-separated (default: the registry's default set, as leaderboards run)")
    args = ap.parse_args()
    names = args.policies.split(",") if args.policies else default_policies()
    print(f"pulses/s (policy compute time), {args.pulses} pulses, sigma_w = 0.2, periods log-uniform in [10, 40]")
    print(f"{'policy':<14}" + "".join(f"{n:>10}" for n in ("2 src", "3 src", "5 src", "8 src")) +
          f"{'1e5/1e4 cost':>14}")
    for name in names:
        cells = []
        for n in (2, 3, 5, 8):
            r = rate(name, scenario(n, args.pulses))
            cells.append(f"{r:>10.0f}" if r else f"{'n/a':>10}")
        small, big = rate(name, scenario(3, 10_000)), rate(name, scenario(3, 100_000))
        ratio = f"{10 * small / big:>14.2f}" if small and big else f"{'n/a':>14}"
        print(f"{name:<14}" + "".join(cells) + ratio)
    cm00 = find_entry("paper-v0/cm00-five-jitter0").spec
    for name in names:
        if name.startswith("ekf"):
            r = rate(name, cm00)
            print(f"{name} on CM00's five trains (2000 pulses): {r:.0f} pulses/s" if r else f"{name}: n/a")
    print("targets: fdp >= 20000 (3 src), >= 2000 (8 src); pt-prior >= 20000 (3 src); ekf-bank >= 5000 (CM00 five "
          "trains); cost ratio 1e5/1e4 ~ 10 (linear)")


if __name__ == "__main__":
    main()

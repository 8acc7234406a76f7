"""fdp's speed against the number of sources (3, 8, 16, 32), against a straightforward batched-numpy FDP
measured in the same run, and fdp's accuracy on scale-v0's scale-10000p-16s.

Rows (pulses/s of policy time, as `deint_env.runner.play` measures it: the fastest of `--repeats` runs
after a warm-up that compiles): `numpy` is the batched-numpy form rebuilding the N^(Delta+1) tree at
every pulse (`fdp:engine=numpy,reuse=false`), `numpy-reuse` keeps the chosen subtrees (the published
fdp before the compiled core), `compiled` is the default fdp (the same labels), `gated` adds
`tree_gate=4,start=lookahead` (what makes 16-32 sources playable).  Episodes: N constant-PRI sources
with periods log-uniform in [10, max(40, 5 N)], sigma_w = 0.1, priors 1 % / 5 % off (scale-v0's
channel); a full tree of N^4 continuations a pulse is timed on few pulses.

Targets (issue 10): fdp (Delta = 3) on three sources >= 60,000 pulses/s, 10x the batched-numpy FDP;
on scale-10000p-16s (test seeds 1000000, 1000001) >= 2,000 pulses/s and accuracy >= 0.9.

    nice python benchmarks/bench_fdp.py [--sources 3,8,16,32] [--repeats 3] [--no-scale]
"""

from __future__ import annotations

import argparse

import numpy as np

import baselines  # noqa: F401  (registers the policies)
from deint_env import PriorSpec, Range, ScenarioSpec, SourceSpec, make_policy, simulate
from deint_env.runner import play
from deint_env.suites import find_entry

ROWS = {"numpy": "fdp:engine=numpy,reuse=false", "numpy-reuse": "fdp:engine=numpy", "compiled": "fdp",
        "gated": "fdp:tree_gate=4,start=lookahead"}
FULL_TREE_WORK = 4e6  # continuations (pulses x N^4) a full-tree row is given; the numpy form stops at 16 sources


def scenario(n_sources: int, n_pulses: int) -> ScenarioSpec:
    return ScenarioSpec(name=f"bench-fdp-{n_sources}", n_pulses=n_pulses, toa_jitter_std=0.1,
                        sources=tuple(SourceSpec(period=Range(10.0, max(40.0, 5.0 * n_sources), log=True))
                                      for _ in range(n_sources)),
                        priors=PriorSpec(period_error=0.01, phase_error=0.05))


def rate(policy: str, spec: ScenarioSpec, repeats: int) -> tuple[float, float]:
    """(pulses/s, accuracy): the fastest of `repeats` plays of seed 1 after one warm-up play."""
    ep = simulate(spec, 1)
    play(make_policy(policy), simulate(spec.replace(n_pulses=min(spec.n_pulses, 500)), 2), clustering=False)
    best, acc = np.inf, 0.0
    for _ in range(repeats):
        res = play(make_policy(policy), ep, clustering=False)
        best, acc = min(best, res.seconds), res.metrics["accuracy"]
    return len(ep) / best, acc


def pulses_for(row: str, n: int) -> int | None:
    if row == "gated":
        return 20_000
    work = float(n) ** 4
    if row.startswith("numpy"):
        if n > 16:
            return None  # N^4 nodes of N blocks each: over a gigabyte a pulse at 32 sources
        work *= 20.0  # the numpy form is the slower one: give it fewer pulses
    return int(min(20_000, max(50, FULL_TREE_WORK / work)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sources", default="3,8,16,32")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-scale", action="store_true", help="skip the scale-10000p-16s accuracy run")
    args = ap.parse_args()
    sources = [int(s) for s in args.sources.split(",")]
    print("fdp (Delta = 3) pulses/s of policy time (best of %d; accuracy in brackets; pulses timed)" % args.repeats)
    print(f"{'row':<12}" + "".join(f"{f'{n} src':>26}" for n in sources))
    rates: dict[str, list[float | None]] = {}
    for row, policy in ROWS.items():
        cells, rates[row] = [], []
        for n in sources:
            pulses = pulses_for(row, n)
            if pulses is None:
                cells.append(f"{'n/a':>26}")
                rates[row].append(None)
                continue
            r, acc = rate(policy, scenario(n, pulses), args.repeats)
            rates[row].append(r)
            cells.append(f"{r:>12,.0f} ({acc:.3f}) {pulses:>6}")
        print(f"{row:<12}" + "".join(cells), flush=True)
    for row in ("compiled", "gated"):
        ratio = [f"{a / b:>26.1f}" if a and b else f"{'n/a':>26}" for a, b in zip(rates[row], rates["numpy"])]
        print(f"{row + '/numpy':<12}" + "".join(ratio))
    if not args.no_scale:
        entry = find_entry("scale-v0/scale-10000p-16s")
        for seed in (1000000, 1000001):
            ep = simulate(entry.spec, seed)
            res = play(make_policy(ROWS["gated"]), ep)
            print(f"scale-10000p-16s seed {seed}: {ROWS['gated']}: accuracy {res.metrics['accuracy']:.3f}, "
                  f"{len(ep) / res.seconds:,.0f} pulses/s")
    print("targets: compiled >= 60,000 pulses/s at 3 sources and 10x numpy; gated on scale-10000p-16s >= 2,000 "
          "pulses/s, accuracy >= 0.9 (genie ~0.944)")


if __name__ == "__main__":
    main()

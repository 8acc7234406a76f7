"""Simulation time of pdw-v0's largest scenes (issue 28, item 2; target: a 10^5-pulse, 90-emitter
episode in under 2 s).

For each of pdw-v0's 10^5-pulse scenarios (90 emitters; a staring and a scanning receiver), and for
a 10^4-pulse 90-emitter one beside them: the median wall time of `simulate(spec, seed)` over
--repeats test seeds, after one untimed episode (imports, first-call allocations).  Prints figures
and whether each meets the target; asserts nothing.

    python benchmarks/bench_pdw.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

from deint_env.simulate import simulate
from deint_env.suites import load_suite

SCENARIOS = ("pdw-staring-n90-blind-100k", "pdw-scanning-n90-blind-100k", "pdw-scanning-n90")
TARGET = 2.0  # seconds per 10^5-pulse episode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5, help="episodes timed per scenario (default 5)")
    args = ap.parse_args()
    suite = load_suite("pdw-v0")
    print(f"{'scenario':34s} {'pulses':>7s} {'emitters':>8s} {'median s':>9s} {'max s':>7s}  target")
    for name in SCENARIOS:
        entry = suite.entry(name)
        spec = entry.spec
        simulate(spec, entry.train.start)  # untimed
        times = []
        for seed in range(entry.test.start, entry.test.start + args.repeats):
            t0 = time.perf_counter()
            simulate(spec, seed)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        verdict = f"{'met' if max(times) < TARGET else 'MISSED'} (< {TARGET:g} s)" if spec.n_pulses >= 100_000 else ""
        print(f"{name:34s} {spec.n_pulses:7d} {len(spec.sources):8d} {med:9.3f} {max(times):7.3f}  {verdict}")


if __name__ == "__main__":
    main()

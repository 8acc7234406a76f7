"""Simulator throughput: pulses/s of `simulate`, against numpy's normal-variate rate in the same run.

Target (issue 2): >= 1e7 pulses/s.  `python benchmarks/bench_simulator.py [--pulses 1000000]`
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import best_of  # noqa: E402

from deint_env import Range, ScenarioSpec, SourceSpec, simulate  # noqa: E402


def scenario(n_sources: int, n_pulses: int, impaired: bool) -> ScenarioSpec:
    extra = dict(missing_prob=0.05, spurious_rate=0.05, coincidence_resolution=0.1, amplitudes=True,
                 amplitude_noise_std=0.1) if impaired else {}
    return ScenarioSpec(name=f"bench-{n_sources}s", n_pulses=n_pulses, toa_jitter_std=0.3,
                        sources=tuple(SourceSpec(period=Range(10, 10 * n_sources, log=True))
                                      for _ in range(n_sources)), **extra)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--pulses", type=int, default=1_000_000)
    args = ap.parse_args()
    n = args.pulses
    rng = np.random.default_rng(0)
    normal_rate = n / best_of(lambda: rng.standard_normal(n))
    print(f"numpy standard_normal: {normal_rate:.3g} variates/s (reference)")
    print(f"{'sources':>7} {'impairments':>12} {'pulses':>9} {'pulses/s':>10} {'vs normals':>10}")
    for n_sources in (2, 8, 32):
        for impaired in (False, True):
            spec = scenario(n_sources, n, impaired)
            seeds = iter(range(10**6))
            simulate(spec, 0)  # warm-up
            rate = n / best_of(lambda: simulate(spec, next(seeds)))
            print(f"{n_sources:>7} {'all' if impaired else 'jitter':>12} {n:>9} {rate:>10.3g} "
                  f"{rate / normal_rate:>10.3f}")
    print("target: >= 1e7 pulses/s")


if __name__ == "__main__":
    main()

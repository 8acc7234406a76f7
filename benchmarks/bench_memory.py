"""Peak memory of simulating a 10^6-pulse episode (and of playing it through the env's reset).

Each case runs in a fresh subprocess; we report the peak resident set size over the interpreter
with numpy and deint_env imported (the baseline), and numpy's own peak allocation via tracemalloc.
Target (issue 2): under 300 MB.  `python benchmarks/bench_memory.py`
"""

from __future__ import annotations

import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, tracemalloc
import numpy as np
import deint_env
from deint_env import Range, ScenarioSpec, SourceSpec, simulate
from deint_env.envs.deinterleave import DeinterleaveEnv
n_sources, n_pulses, what = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
spec = ScenarioSpec(name="mem", n_pulses=n_pulses, toa_jitter_std=0.3, missing_prob=0.05, spurious_rate=0.05,
                    coincidence_resolution=0.1, sources=tuple(SourceSpec(period=Range(10, 10 * n_sources, log=True))
                                                              for _ in range(n_sources)))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
tracemalloc.start()
if what == "simulate":
    ep = simulate(spec, 0)
else:
    env = DeinterleaveEnv(spec)
    env.reset(seed=0)
_, peak = tracemalloc.get_traced_memory()
top = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"baseline_mb": base / 1024, "peak_rss_mb": top / 1024, "traced_peak_mb": peak / 2**20}))
"""


def main() -> None:
    print(f"{'case':<22} {'baseline RSS':>13} {'peak RSS':>9} {'RSS growth':>11} {'numpy peak':>11}")
    for n_sources in (8, 32):
        for what in ("simulate", "env.reset"):
            out = subprocess.run([sys.executable, "-c", CHILD, str(n_sources), "1000000", what], check=True,
                                 capture_output=True, text=True).stdout
            r = json.loads(out)
            print(f"{what + f' ({n_sources} src)':<22} {r['baseline_mb']:>11.0f}MB {r['peak_rss_mb']:>7.0f}MB "
                  f"{r['peak_rss_mb'] - r['baseline_mb']:>9.0f}MB {r['traced_peak_mb']:>9.0f}MB")
    print("target: a 10^6-pulse episode under 300 MB peak")


if __name__ == "__main__":
    main()

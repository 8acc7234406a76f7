"""Per-pulse policy cost against the number of sources (2-32) and of pulses (10^4-10^6), and peak memory.

Each case runs in a fresh subprocess: simulate a scale-v0-like episode (N constant-PRI sources with
periods log-uniform in [10, 5 N], sigma_w = 0.1, priors 1 % / 5 % off), play the policy through the env
(`deint_env.runner.play`), and report the policy's own time per pulse, pulses per second, label accuracy
and the subprocess's peak RSS.  The policy's time is reported twice: as the runner measures it (wall
clock around every `act`, what leaderboards show) and as CPU time of the same calls (process time),
which stays meaningful on a shared machine where the wall clock also counts other jobs.  Targets
(issue 10, `mht`): 10^6 pulses of 16 sources in < 60 s of policy time, of 32 sources in < 120 s,
peak RSS < 1 GB.  With `--reference POLICY` every case is also run with that policy and the ratio of
the two CPU times is printed.

    python benchmarks/bench_scaling.py [--policy mht] [--sources 2,4,8,16,32] [--pulses 10000,100000,1000000]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
import numpy as np
import baselines  # registers the policies
from deint_env import PriorSpec, Range, ScenarioSpec, SourceSpec, make_policy, simulate
from deint_env.runner import play
policy, n_sources, n_pulses = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
spec = ScenarioSpec(name="bench-scaling", n_pulses=n_pulses, toa_jitter_std=0.1,
                    sources=tuple(SourceSpec(period=Range(10.0, 5.0 * n_sources, log=True)) for _ in range(n_sources)),
                    priors=PriorSpec(period_error=0.01, phase_error=0.05))
ep = simulate(spec, 1)


class CpuTimed:
    # the policy, with the process time of its reset and act calls added up

    def __init__(self, policy):
        self.policy, self.cpu = policy, 0.0

    def __getattr__(self, name):
        return getattr(self.policy, name)

    def reset(self, priors, info):
        t0 = time.process_time()
        self.policy.reset(priors, info)
        self.cpu += time.process_time() - t0

    def act(self, obs):
        t0 = time.process_time()
        a = self.policy.act(obs)
        self.cpu += time.process_time() - t0
        return a


play(make_policy(policy), simulate(spec.replace(n_pulses=min(n_pulses, 2000)), 2))  # warm-up (JIT compile)
timed = CpuTimed(make_policy(policy))
res = play(timed, ep, clustering=False)
n = ep.priors.n_labels
acc = float(np.mean(res.labels == np.where(ep.source < 0, n, ep.source)))
print(json.dumps({"seconds": res.seconds, "cpu": timed.cpu, "accuracy": acc,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(policy: str, n_sources: int, n_pulses: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, policy, str(n_sources), str(n_pulses)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policy", default="mht")
    ap.add_argument("--reference", default=None, help="a second policy timed on the same cases (ratio: of CPU times)")
    ap.add_argument("--sources", default="2,4,8,16,32")
    ap.add_argument("--pulses", default="10000,100000,1000000")
    args = ap.parse_args()
    print(f"{'policy':>24} {'N':>3} {'pulses':>8} {'s':>8} {'us/pulse':>9} {'pulses/s':>9} {'cpu s':>8} "
          f"{'cpu us/p':>9} {'acc':>6} {'peak RSS MB':>11} {'ratio':>6}")
    for n_pulses in (int(x) for x in args.pulses.split(",")):
        for n_sources in (int(x) for x in args.sources.split(",")):
            r = run(args.policy, n_sources, n_pulses)
            ratio = ""
            rows = [(args.policy, r)]
            if args.reference:
                ref = run(args.reference, n_sources, n_pulses)
                rows.append((args.reference, ref))
                ratio = f"{r['cpu'] / ref['cpu']:.2f}"
            for name, x in rows:
                print(f"{name:>24} {n_sources:>3} {n_pulses:>8} {x['seconds']:>8.2f} "
                      f"{1e6 * x['seconds'] / n_pulses:>9.2f} {n_pulses / x['seconds']:>9.0f} {x['cpu']:>8.2f} "
                      f"{1e6 * x['cpu'] / n_pulses:>9.2f} {x['accuracy']:>6.3f} "
                      f"{x['rss_mb']:>11.0f} {ratio if name == args.policy else '':>6}", flush=True)


if __name__ == "__main__":
    main()

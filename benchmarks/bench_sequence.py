"""The learned sequence labeller `seq` (agents/sequence.py) on blind-v0: its own time per pulse at
batch 1 (lag 32) and batch 32 (lag 63) against `cdif` on the same episodes, and per scenario the
trains it finds (chains of >= 10 pulses) against the true number of sources, on the test seeds.
Prints figures; asserts nothing.  Link accuracy and V-measure per scenario come from
`deint run --suite blind-v0 --policies seq,cdif,genie`.

    nice python benchmarks/bench_sequence.py [--seeds 10]
"""

from __future__ import annotations

import argparse

import numpy as np

from deint_env.policies import make_policy
from deint_env.runner import play
from deint_env.simulate import simulate
from deint_env.suites import load_suite


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="test seeds per scenario")
    args = ap.parse_args()
    print("## speed (policy's own time, us/pulse)")
    for name in ("blind-n3to3-jitter0.1", "blind-n4to6-jitter0.1"):
        entry = next(e for e in load_suite("blind-v0") if e.name == name)
        ep = simulate(entry.spec, next(iter(entry.test)))
        row = []
        for spec in ("seq", "seq:batch=32", "cdif"):
            play(make_policy(spec), ep, clustering=False)  # warm-up
            res = play(make_policy(spec), ep, clustering=False)
            row.append(f"{spec} {1e6 * res.seconds / len(ep):,.0f}")
        print(f"{name} ({ep.truth.n_sources} sources): " + "; ".join(row))
    print("\n## trains found on the test seeds (seq:batch=32, the same labels as seq)")
    print("| scenario | true sources | trains found (>= 10 pulses) | right count | chains opened |")
    print("|---|---|---|---|---|")
    for entry in load_suite("blind-v0"):
        rows = []
        for seed in list(entry.test)[:args.seeds]:
            ep = simulate(entry.spec, seed)
            pol = make_policy("seq:batch=32")
            play(pol, ep, clustering=False)
            true = int(np.sum(ep.truth.n_received > 0))
            rows.append((true, pol.trains_found, pol.trains_found == true, pol.decoder.chains))
        a = np.array(rows, dtype=np.float64)
        print(f"| {entry.name} | {a[:, 0].mean():.1f} | {a[:, 1].mean():.1f} | {a[:, 2].mean():.0%} | "
              f"{a[:, 3].mean():.1f} |")


if __name__ == "__main__":
    main()

"""Seconds the pulse-descriptor policies take on 10^4 and 10^5 pulses of 90 emitters (issue #28).

The files come from tests/test_pdw_policies.py's generator (plain numpy: 90 emitters with PRIs in
[200, 1500] us, frequencies every 180 MHz over 2-18 GHz, per-pulse descriptor noise, 2 % spurious
pulses); each policy is fed pulse by pulse through the protocol, as the env feeds it, and timed end to
end once (its `reset` and every `act`, windows included).  The V-measure is printed beside the time.

    nice python benchmarks/bench_pdw_policies.py [--pulses 10000,100000] [--policies pdw-hdbscan,...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_pdw_policies import generate, play, random_emitters, v_measure  # noqa: E402

EMITTERS = 90
SPURIOUS = 0.02


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pulses", default="10000,100000")
    ap.add_argument("--policies", default="pdw-hdbscan,pdw-hdbscan:scale=robust,pdw-pipeline")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    emitters = random_emitters(EMITTERS, np.random.default_rng(args.seed))
    rate = (1 + SPURIOUS) * sum(1.0 / e.pri for e in emitters)  # pulses per us
    print("| pulses | policy | seconds | us/pulse | V-measure |\n|---|---|---|---|---|")
    for n in (int(x) for x in args.pulses.split(",")):
        p = generate(emitters, n / rate, args.seed, spurious=SPURIOUS)
        for spec in args.policies.split(","):
            t0 = time.perf_counter()
            labels = play(spec, p, n_labels=EMITTERS + 38)
            spent = time.perf_counter() - t0
            print(f"| {p.toa.size} | {spec} | {spent:.1f} | {1e6 * spent / p.toa.size:.0f} | "
                  f"{v_measure(p, labels):.3f} |", flush=True)


if __name__ == "__main__":
    main()

"""The results-file lock under load (issue 27, item 6): run the two-concurrent-writers test N times while
CPU-burning processes keep every core busy, and print how many runs passed (target: all of them).

    python benchmarks/lock_under_load.py [--runs 20] [--burners 2]

Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEST = "tests/test_results_files.py::test_two_concurrent_writers_lose_nothing_and_the_second_is_told"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--burners", type=int, default=os.cpu_count() or 2, help="busy-loop processes (default: one per core)")
    args = ap.parse_args()

    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.burners)]
    passed, failures = 0, []
    t0 = time.perf_counter()
    try:
        for i in range(args.runs):
            run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", TEST], cwd=ROOT,
                                 capture_output=True, text=True)
            if run.returncode == 0:
                passed += 1
            else:
                failures.append((i, run.stdout.strip().splitlines()[-1:] or ["?"]))
    finally:
        for b in burners:
            b.kill()
    print(f"{passed} of {args.runs} runs passed beside {args.burners} CPU-burning processes "
          f"({time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.1f} at the end)")
    for i, tail in failures:
        print(f"  run {i}: {tail[0]}")


if __name__ == "__main__":
    main()

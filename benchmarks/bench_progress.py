"""What the runner's tqdm progress bar costs: one `update` against one episode of the cheapest policy.

    PYTHONPATH=. python benchmarks/bench_progress.py

Prints the cost of a tqdm update (drawing to a pipe, as in a log, and to a pseudo-terminal, where it
redraws in place), the runner's time per episode for `random` (the cheapest policy) with and without
the bar, and their ratio.  Figures only; nothing is asserted.
"""

from __future__ import annotations

import io
import os
import sys
import time

from _common import best_of
from tqdm import tqdm

from deint_env.runner import evaluate

TARGET = "paper-v0/mk94-two-var1"
UPDATES = 100_000


def update_cost(stream, mininterval: float) -> float:
    """Seconds per `update(1)` over UPDATES updates."""
    def run():
        bar = tqdm(total=UPDATES, file=stream, mininterval=mininterval)
        for _ in range(UPDATES):
            bar.update(1)
        bar.close()
    return best_of(run, 3) / UPDATES


def main() -> None:
    log = update_cost(io.StringIO(), 10.0)
    master, slave = os.openpty()
    with os.fdopen(slave, "w") as tty:  # a terminal: redrawn every 0.1 s
        term = update_cost(tty, 0.1)
    os.close(master)
    print(f"tqdm update: {1e6 * log:.3f} us (log), {1e6 * term:.3f} us (terminal)")

    evaluate(["random"], TARGET, max_seeds=10, progress=False)  # imports and caches warm
    stderr = sys.stderr
    sys.stderr = io.StringIO()  # the bar draws here, as into a log
    try:
        with_bar = best_of(lambda: evaluate(["random"], TARGET, max_seeds=10, progress=True), 5) / 10
    finally:
        sys.stderr = stderr
    without = best_of(lambda: evaluate(["random"], TARGET, max_seeds=10, progress=False), 5) / 10
    print(f"runner, random on {TARGET}: {1e3 * without:.2f} ms/episode without the bar, "
          f"{1e3 * with_bar:.2f} ms with it (ratio {with_bar / without:.3f})")
    print(f"one update is {log / without:.2e} of an episode")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)")

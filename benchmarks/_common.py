"""Shared helpers for the benchmark scripts (figures are printed, never asserted)."""

from __future__ import annotations

import time
from typing import Callable


def best_of(fn: Callable[[], object], repeats: int = 5) -> float:
    """The fastest of `repeats` wall-clock runs, in seconds (the least disturbed by other load)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def files_summary(values: list[float]) -> str:
    """A per-file accuracy list in one line: its worst file, its mean and how many files reach 0.90."""
    return (f"worst file {min(values):.3f}, mean {sum(values) / len(values):.4f}, "
            f"files >= 0.90: {sum(v >= 0.9 for v in values)}/{len(values)}")

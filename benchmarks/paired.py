"""Paired comparison of two policies on the episodes both played (same scenario and seed): the mean
difference of their normalised scores with its standard error, split into rare episodes (the two
differ by more than `--rare`) and typical ones, per scenario.

Near the ceiling a suite's mean difference can be decided by a handful of episodes in which one
policy loses a whole track; the split shows whether a lead is a small gain on most episodes or a few
large ones, and so what a small sample (a suite's 10 test seeds per scenario) can be expected to show.
How lmht against mht on robust-v0 was measured (README, lmht's section):

    deint run --suite robust-v0 --split train --max-seeds 240 --policies lmht,mht --out runs/rob240.jsonl
    python benchmarks/paired.py runs/rob240.jsonl lmht mht --skip-offsets 10-15

`--skip-offsets A-B` leaves out the train seeds at offsets A..B of each scenario's train range (those a
checkpoint was trained on: lmht-v1's, in its `train_seeds`, are 10-15).  Figures are printed, never asserted.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from deint_env.envs.mixed import split_seeds
from deint_env.errors import DeintError
from deint_env.results import read_records
from deint_env.suites import find_entry


def _offsets(text: str) -> range:
    lo, sep, hi = text.partition("-")
    try:
        a, b = int(lo), int(hi if sep else lo)
    except ValueError:
        raise DeintError(f"--skip-offsets {text!r} must be A-B or A (integers)") from None
    if not 0 <= a <= b:
        raise DeintError(f"--skip-offsets {text!r} must have 0 <= A <= B")
    return range(a, b + 1)


def paired_scores(paths: list[str], a: str, b: str, skip: range) -> dict[str, np.ndarray]:
    """Per scenario, an (episodes, 2) array of a's and b's scores on the episodes both played with a score
    (in seed order)."""
    scores: dict[tuple[str, str, int], dict[str, float]] = defaultdict(dict)
    seen: set[str] = set()
    train_start: dict[str, int] = {}
    for path in paths:
        if not Path(path).exists():
            raise DeintError(f"results file {path} does not exist")
        for rec in read_records(path):
            seen.add(rec.policy)
            score = rec.get("score")
            if rec.policy not in (a, b) or not rec.played or score is None or not math.isfinite(score):
                continue
            name = f"{rec.suite}/{rec.scenario}" if rec.suite else rec.scenario
            if skip and rec.split == "train":
                if name not in train_start:
                    train_start[name] = split_seeds(find_entry(name), "train").start
                if rec.seed - train_start[name] in skip:
                    continue
            scores[(name, rec.split, rec.seed)][rec.policy] = float(score)
    for p in (a, b):
        if p not in seen:
            raise DeintError(f"policy {p!r} has no records in {', '.join(paths)}; they hold: "
                             f"{', '.join(sorted(seen)) or 'none'}")
    rows: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for (name, _, _), v in sorted(scores.items()):
        if a in v and b in v:
            rows[name].append((v[a], v[b]))
    if not rows:
        raise DeintError(f"{a} and {b} share no scored episode in {', '.join(paths)}")
    return {name: np.array(r) for name, r in rows.items()}


def _mean(x: np.ndarray) -> float:
    return float(x.mean()) if x.size else math.nan


def _se(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else math.nan


def report(pairs: dict[str, np.ndarray], a: str, b: str, rare: float) -> str:
    lines = [f"{a} - {b}, normalised score; rare: |difference| > {rare}",
             f"{'scenario':32s} {'n':>5s} {'typical sum':>12s} {'+-':>7s} {'wins/losses':>12s} {'rare':>5s} "
             f"{'rare sum':>9s}"]
    for name, ab in pairs.items():
        d = ab[:, 0] - ab[:, 1]
        big = np.abs(d) > rare
        t = d[~big]
        sd = t.std(ddof=1) * math.sqrt(t.size) if t.size > 1 else math.nan
        lines.append(f"{name:32s} {d.size:5d} {t.sum():+12.4f} {sd:7.4f} {f'{(t > 0).sum()}/{(t < 0).sum()}':>12s} "
                     f"{int(big.sum()):5d} {d[big].sum():+9.4f}")
    ma, mb = np.concatenate(list(pairs.values())).mean(axis=0)
    d = np.concatenate([ab[:, 0] - ab[:, 1] for ab in pairs.values()])
    big = np.abs(d) > rare
    lines += [f"all: {d.size} episodes; {a} {ma:.5f}, {b} {mb:.5f}; difference {_mean(d):+.5f} +- {_se(d):.5f}",
              f"typical: {int((~big).sum())} episodes, {_mean(d[~big]):+.5f} +- {_se(d[~big]):.5f} per episode "
              f"({int((d[~big] > 0).sum())} wins, {int((d[~big] < 0).sum())} losses)",
              f"rare: {int(big.sum())} episodes ({big.mean():.2%}), {d[big].sum():+.3f} summed, {a} wins "
              f"{int((d[big] > 0).sum())}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", help="results files (jsonl) holding both policies' episodes")
    ap.add_argument("a", help="policy A (as recorded, e.g. lmht)")
    ap.add_argument("b", help="policy B")
    ap.add_argument("--rare", type=float, default=0.05, help="an episode is rare when |A - B| exceeds this")
    ap.add_argument("--skip-offsets", default=None, metavar="A-B",
                    help="leave out train seeds at these offsets of each scenario's train range")
    args = ap.parse_args(argv)
    try:
        if not (math.isfinite(args.rare) and args.rare > 0):
            raise DeintError(f"--rare {args.rare} must be a finite number > 0")
        skip = _offsets(args.skip_offsets) if args.skip_offsets else range(0)
        print(report(paired_scores(args.results, args.a, args.b, skip), args.a, args.b, args.rare))
    except DeintError as e:
        print(f"paired.py: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Blind policies on agile trains: files of tests/independent_agile.py's generator (3 radars, about
1000 pulses; jittered, random-level staggered, deeply sliding and wobulated PRIs; clean, missing,
spurious), labelled through `deint label` with --n-sources 3 and with nothing (no priors: the TOA
noise is measured).  Prints one row per file and setting: each policy's Hungarian-matched accuracy
and its wall time (the CLI's, reading and writing included).  Asserts nothing.

    nice python benchmarks/bench_blind_agile.py [--seeds 1,2] [--policies cdif,sdif,...] [--scenes stagger,...]

Seed 0 is the tests'; choices are made on other seeds.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _common import files_summary  # noqa: E402
from independent_agile import agile_file, grid, matched_accuracy, read_labels, write_pulses  # noqa: E402

from deint_env.cli import main  # noqa: E402

POLICIES = "cdif,cdif-renewal,sdif,pri-transform,dbscan,hdbscan,renewal-ml,seq"


def label(folder: Path, policy: str, args: list[str]) -> tuple[object, float]:
    t0 = time.perf_counter()
    with contextlib.redirect_stderr(io.StringIO()):
        code = main(["label", str(folder / "p.csv"), "--policy", policy, *args, "-o", str(folder / "l.csv")])
    seconds = time.perf_counter() - t0
    return (read_labels(folder / "l.csv") if code == 0 else None), seconds


def run(seeds: list[int], policies: list[str], scenes: list[str] | None) -> None:
    settings = {"K=3": ["--n-sources", "3"], "none": []}
    print("file".ljust(30) + "setting " + "".join(p.rjust(18) for p in policies) + "      best")
    best_of: dict[str, list[float]] = {s: [] for s in settings}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, kinds, miss, spur, seed in grid(seeds):
            if scenes and not any(name.startswith(s) for s in scenes):
                continue
            f = agile_file(kinds, seed, missing=miss, spurious=spur)
            write_pulses(folder / "p.csv", f)
            for setting, args in settings.items():
                cells, accs = [], []
                for p in policies:
                    labels, seconds = label(folder, p, args)
                    acc = matched_accuracy(labels, f.source) if labels is not None else float("nan")
                    accs.append(acc)
                    cells.append(f"{acc:.3f} {seconds:5.1f}s".rjust(18))
                best = max((a for a in accs if a == a), default=float("nan"))
                best_of[setting].append(best)
                print(f"{name:30s}{setting:8s}" + "".join(cells) + f"{best:10.3f}", flush=True)
    for setting, values in best_of.items():
        if values:
            print(f"best blind policy, {setting}: {files_summary(values)}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0", help="comma-separated generator seeds (0: the tests' files)")
    ap.add_argument("--policies", default=POLICIES)
    ap.add_argument("--scenes", default=None, help="comma-separated file-name prefixes (default: all)")
    a = ap.parse_args()
    run([int(x) for x in a.seeds.split(",")], a.policies.split(","), a.scenes.split(",") if a.scenes else None)

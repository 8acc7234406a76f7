"""Anchored agile trackers on files of tests/independent_agile.py's generator (3 radars, about 1000 pulses;
jittered, staggered, deeply sliding and wobulated PRIs; clean, missing, spurious), labelled through
`deint label` with an emitter library's priors (`independent_agile.library_priors`: each radar's mean PRI
and modulation, the channel's rates; phases only with --phases).  Prints one row per file: each policy's
Hungarian-matched accuracy and wall time (the CLI's, reading and writing included), then each policy's
worst file and mean.  Asserts nothing.  Seed 0 is the tests' (tests/test_agile_independent.py); choices
are made on other seeds.

    nice python benchmarks/bench_agile_independent.py [--seeds 1,2] [--policies renewal-ml,agile-kf] [--phases]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _common import files_summary  # noqa: E402
from bench_blind_agile import label  # noqa: E402
from independent_agile import agile_file, grid, library_priors, matched_accuracy, write_pulses  # noqa: E402


def run(seeds: list[int], policies: list[str], scenes: list[str] | None, phases: bool) -> None:
    print("file".ljust(30) + "".join(p.rjust(20) for p in policies))
    accs: dict[str, list[float]] = {p: [] for p in policies}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, kinds, miss, spur, seed in grid(seeds):
            if scenes and not any(name.startswith(s) for s in scenes):
                continue
            f = agile_file(kinds, seed, missing=miss, spurious=spur)
            write_pulses(folder / "p.csv", f)
            (folder / "pr.json").write_text(json.dumps(library_priors(f, miss, spur, phases=phases)))
            cells = []
            for p in policies:
                labels, seconds = label(folder, p, ["--priors", str(folder / "pr.json")])
                acc = matched_accuracy(labels, f.source) if labels is not None else float("nan")
                accs[p].append(acc)
                cells.append(f"{acc:.3f} {seconds:5.1f}s".rjust(20))
            print(f"{name:30s}" + "".join(cells), flush=True)
    for p, values in accs.items():
        if values:
            print(f"{p}: {files_summary(values)}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0", help="comma-separated generator seeds (0: the tests' files)")
    ap.add_argument("--policies", default="renewal-ml,agile-kf")
    ap.add_argument("--scenes", default=None, help="comma-separated file-name prefixes (default: all)")
    ap.add_argument("--phases", action="store_true", help="state each radar's first pulse (default: unknown)")
    a = ap.parse_args()
    run([int(s) for s in a.seeds.split(",")], a.policies.split(","), a.scenes.split(",") if a.scenes else None,
        a.phases)

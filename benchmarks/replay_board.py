"""Replay a leaderboard's checked-in episodes and compare every metric (issue 24: "labels of every policy
bit-identical ... on the core-v0, robust-v0 and agile-v0 boards, replayed, not cached").

Each current (not superseded) record of `leaderboards/SUITE/results.jsonl` whose policy is a registry
spec is played again by the runner at the board's scope, into a work results file (resumable: rerun
it and it goes on), and its metrics compared with the checked-in record's: every metric but the
timing (`us_per_pulse`) must be equal, float for float, or (reported apart) within 1e-12: the AMI's
expected-mutual-information sum runs through numpy's and scipy's log, exp and gammaln, whose last bits
moved between the library versions that played old records and today's (measured: agile-v0's random
and nearest-prior records, AMI off by up to 3e-15, every other metric equal).  A record's metrics are functions of its
labels (accuracy, P_e per source, V-measure, ARI, AMI, cluster MCC/F1, spurious precision/recall,
period and phase errors): equal metrics across them are the check a results file allows, since it
does not store the labels.  Submissions are not replayed (their labels came from outside).

    python benchmarks/replay_board.py robust-v0 [--policies mht,fdp] [--policy mht:lag=3,nscan=3] [--workers 2]
        [--work runs/replay]

Prints, per policy, how many episodes were compared and how many differ (with the first difference);
asserts nothing.  `--adopt POLICY` writes that policy's replayed records into the board in place of those
that differ (ekf-bank's period estimates and, on 3 robust-v0 episodes, its labels moved with numpy's last
bits since they were recorded: docs/leaderboards.md).
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path

from deint_env.formats.files import write_text
from deint_env.leaderboard.build import DEFAULT_ROOT, RESULTS, Scope, current_versions
from deint_env.results import EpisodeRecord, read_records, results_lock
from deint_env.runner import evaluate

TIMING = {"us_per_pulse"}


TOLERANCE = 1e-12


def same(a: object, b: object, tol: float = 0.0) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= tol * max(1.0, abs(a))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y, tol) for x, y in zip(a, b))
    return a == b


def differences(old: EpisodeRecord, new: EpisodeRecord, tol: float = 0.0) -> list[str]:
    out = [f"{k}: {old.metrics.get(k)!r} -> {new.metrics.get(k)!r}"
           for k in sorted(set(old.metrics) | set(new.metrics)) if k not in TIMING
           and not same(old.metrics.get(k), new.metrics.get(k), tol)]
    for name in ("applicable", "fault", "lag", "n_sources"):
        if getattr(old, name) != getattr(new, name):
            out.append(f"{name}: {getattr(old, name)!r} -> {getattr(new, name)!r}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("suite")
    ap.add_argument("--policies", default=None, help="only these board policies (comma-separated plain names)")
    ap.add_argument("--policy", action="append", default=[],
                    help="only this board policy spec (repeatable; a spec may hold commas: mht:lag=3,nscan=3)")
    ap.add_argument("--root", type=Path, default=DEFAULT_ROOT)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--work", type=Path, default=Path("runs/replay"))
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--adopt", action="append", default=[], metavar="SPEC",
                    help="write this policy's replayed records into the board's results.jsonl in place of the "
                         "checked-in ones (a policy whose last bits moved with the libraries); then rebuild the "
                         "board with `deint leaderboard --suite SUITE`")
    args = ap.parse_args()

    folder = args.root / args.suite
    scope = Scope.of_folder(folder, args.suite)
    records = [r for r in read_records(folder / RESULTS) if not r.submitted]
    current = current_versions(records)  # None: not a registry spec here (nothing to replay it with)
    stale = sum(1 for r in records if current[r.policy] is not None and r.policy_version != current[r.policy])
    records = [r for r in records if current[r.policy] is not None and r.policy_version == current[r.policy]]
    if stale:
        print(f"{stale} records of an older policy version are not compared (the board lists them as stale)")
    wanted = set(args.policies.split(",") if args.policies else ()) | set(args.policy) or None
    by_policy: dict[str, dict] = defaultdict(dict)
    for r in records:
        if wanted is None or r.policy in wanted:
            by_policy[r.policy][(r.scenario, r.seed)] = r

    args.work.mkdir(parents=True, exist_ok=True)
    out = args.work / f"{args.suite}.jsonl"
    rows, adopted = [], {}
    for policy, old in sorted(by_policy.items()):
        targets = [args.suite] if scope.scenarios is None else [f"{args.suite}/{s}" for s in scope.scenarios]
        new: dict = {}
        for target in targets:
            for r in evaluate([policy], target, split="test", max_seeds=scope.max_seeds, workers=args.workers,
                              out=out, progress=not args.no_progress):
                new[(r.scenario, r.seed)] = r
        keys = [k for k in sorted(old) if k in new]
        inexact = [k for k in keys if differences(old[k], new[k])]
        bad = [(k, d) for k in inexact if (d := differences(old[k], new[k], TOLERANCE))]
        version = {r.policy_version for r in new.values()} - {current[policy]}
        rows.append((len(keys), len(inexact), len(bad)))
        if policy in args.adopt:
            adopted.update({(policy, *k): new[k] for k in inexact})
        first = f"  first: {bad[0][0]} {bad[0][1][0]}" if bad else ""
        print(f"{policy}: {len(keys)} compared, {len(keys) - len(inexact)} equal bit for bit, "
              f"{len(inexact) - len(bad)} within {TOLERANCE:g}, {len(bad)} differ"
              + (f", replayed at another version {sorted(version)}" if version else "") + first, flush=True)

    compared, inexact, differ = (sum(r[i] for r in rows) for i in range(3))
    print(f"\n{args.suite}: {len(rows)} policies, {compared} episodes replayed and compared: "
          f"{compared - inexact} equal bit for bit, {inexact - differ} within {TOLERANCE:g}, {differ} differ")
    if adopted:
        adopt(folder / RESULTS, adopted, current)
        print(f"adopted {len(adopted)} replayed records of {', '.join(sorted(args.adopt))} into {folder / RESULTS}; "
              f"rebuild the board: deint leaderboard --suite {args.suite}")


def adopt(path: Path, replayed: dict, current: dict) -> None:
    """The board's results file with each current record that has a replayed one (policy, scenario, seed)
    replaced by it, line for line (other lines as they were), written atomically under the file's lock."""
    with results_lock(path):
        lines = path.read_text().splitlines(keepends=True)
        out = []
        for line in lines:
            data = json.loads(line)
            key = (data["policy"], data["scenario"], data["seed"])
            fresh = replayed.get(key)
            keep = fresh is None or data.get("submitted") or data.get("policy_version", 1) != current[data["policy"]]
            out.append(line if keep else fresh.line())
        write_text(path, "".join(out))


if __name__ == "__main__":
    main()

"""Speed and labels of policies at two commits, measured side by side (issue 24: a refactor keeps every
policy's labels bit-identical and its speed within 5 %).

Each commit is checked out as a detached git worktree in a temporary folder and imported from there
(PYTHONPATH first: this venv's editable install is shadowed), with its own numba cache.  Each
(commit, suite) is played by a fresh process: the first test seed of every scenario of the suite, per
policy, through that commit's `deint_env.runner.evaluate` (one worker: the runner's untimed warm-up
episode per scenario, then the timed one).  The commits alternate, the order swapped every repeat, so
that the machine's drift (±40 % over minutes here) falls on both alike.  Per policy and suite: the
median over scenarios of each episode's fastest us/pulse over the repeats, the ratio after/before,
and how many episodes' metrics (accuracy, P_e, V-measure, ARI, AMI, period errors, ...: functions of
the labels; those both commits compute) differ; and a row "all" per policy over every suite's episodes,
its ratio the median of the episodes' own after/before ratios.  Prints figures; asserts nothing.

    python benchmarks/compare_commits.py --before 796bd93^ --after 796bd93 \\
        --suites core-v0,robust-v0,agile-v0 --policies mht,fdp,dokf [--policy mht:lag=3,nscan=3] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SKIP = {"us_per_pulse", "policy_version", "seed"}  # timing, and what names the episode

# run in the worktree: every policy on the first test seed of every scenario, as JSON lines
CHILD = """
import json, sys
from deint_env.runner import evaluate
suite, policies = sys.argv[1], json.loads(sys.argv[2])
for r in evaluate(policies, suite, split="test", max_seeds=1, workers=1, progress=False):
    m = {k: v for k, v in r.to_json().items() if isinstance(v, (int, float, list)) and not isinstance(v, bool)}
    print(json.dumps({"policy": r.policy, "scenario": r.scenario, "fault": r.fault, "metrics": m}))
"""


def same(a: dict, b: dict) -> bool:
    """Equal on the metrics both commits compute (a metric one of them added is not a label change)."""
    return all(a[k] == b[k] for k in a.keys() & b.keys())


def worktree(rev: str, folder: Path) -> Path:
    path = folder / rev.replace("/", "_").replace("^", "-parent").replace("~", "-back")
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "--quiet", str(path), rev], check=True)
    return path


def play(tree: Path, suite: str, policies: list[str]) -> list[dict]:
    env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(tree / ".numba-cache"))
    out = subprocess.run([sys.executable, "-c", CHILD, suite, json.dumps(policies)], cwd=tree, env=env,
                         capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"{tree.name} {suite}: the child failed:\n{out.stderr[-2000:]}")
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True)
    ap.add_argument("--after", default="HEAD")
    ap.add_argument("--suites", default="core-v0,robust-v0,agile-v0")
    ap.add_argument("--policies", default="mht,fdp", help="plain policy names, comma-separated")
    ap.add_argument("--policy", action="append", default=[],
                    help="a policy spec (repeatable; a spec may hold commas: mht:lag=3,nscan=3)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    # SIGTERM as Ctrl-C: the child is killed (subprocess.run) and the worktrees removed (finally)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    # (dict.fromkeys: a policy named by both --policies and --policy is played once)
    policies = list(dict.fromkeys([p for p in args.policies.split(",") if p] + args.policy))
    suites = args.suites.split(",")

    with tempfile.TemporaryDirectory(prefix="deint-commits-") as tmp:
        trees = {"before": worktree(args.before, Path(tmp)), "after": worktree(args.after, Path(tmp))}
        try:
            for side in ("before", "after"):  # untimed: fills each tree's numba cache
                for suite in suites:
                    play(trees[side], suite, policies)
            # (side, suite, policy, scenario) -> [us/pulse per repeat]; and the metrics of the last repeat
            times: dict[tuple, list[float]] = defaultdict(list)
            metrics: dict[tuple, dict] = {}
            for r in range(args.repeats):
                for side in (("before", "after") if r % 2 == 0 else ("after", "before")):
                    for suite in suites:
                        for rec in play(trees[side], suite, policies):
                            key = (side, suite, rec["policy"], rec["scenario"])
                            times[key].append(rec["metrics"].get("us_per_pulse", float("nan")))
                            metrics[key] = {k: v for k, v in rec["metrics"].items() if k not in SKIP} | {
                                "fault": rec["fault"]}
                print(f"repeat {r + 1}/{args.repeats} done", file=sys.stderr, flush=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)

    print(f"# {args.before} -> {args.after}: us/pulse, the median over scenarios (first test seed each) of "
          f"each episode's fastest of {args.repeats} repeats, commits alternating")
    width = max(12, *(len(p) for p in policies))
    print(f"{'suite':<10} {'policy':<{width}} {'episodes':>8} {'before':>9} {'after':>9} {'after/before':>12} "
          f"{'within 5%':>9} {'metrics differ':>14}")
    for suite in (*suites, "all"):
        for policy in policies:
            # "all": every suite's episodes, and the median of the episodes' own ratios (each episode its own
            # control: steadier than a ratio of medians over scenarios of unlike speeds)
            keys = sorted(k[1::2] for k in times if k[0] == "before" and k[2] == policy and suite in ("all", k[1]))
            both = [(u, s) for u, s in keys if ("after", u, policy, s) in times]
            if not both:
                continue
            fastest = {side: [min(times[(side, u, policy, s)]) for u, s in both] for side in ("before", "after")}
            before, after = (statistics.median(fastest[side]) for side in ("before", "after"))
            differ = sum(not same(metrics[("before", u, policy, s)], metrics[("after", u, policy, s)]) for u, s in both)
            ratio = after / before if suite != "all" else statistics.median(
                a / b for a, b in zip(fastest["after"], fastest["before"]))
            print(f"{suite:<10} {policy:<{width}} {len(both):>8} {before:>9.2f} {after:>9.2f} {ratio:>12.3f} "
                  f"{'yes' if abs(ratio - 1.0) <= 0.05 else 'no':>9} {differ:>14}")


if __name__ == "__main__":
    main()

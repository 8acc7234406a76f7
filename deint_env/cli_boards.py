"""`deint tune` and `deint leaderboard` (submit, export): the commands that choose presets on validation
seeds and score policies on test seeds (docs/design.md, 7a)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from deint_env.errors import DeintError

from deint_env.cli_util import _check_folders, _check_paths, _policy_inputs, _run_policies, _status


# ---------------------------------------------------------------------------------------------------
# deint tune
# ---------------------------------------------------------------------------------------------------
def _add_tune(sub) -> None:
    p = sub.add_parser("tune", help="tune a reference policy's parameters on validation seeds",
                       description="Choose a reference policy's parameters by successive halving on the validation "
                                   "seeds of a suite (never a test seed) within a budget of episode plays, and write "
                                   "the preset that POLICY-tuned:suite=SUITE plays (deint_env/tune.py).  Plays are "
                                   "kept in the work directory: rerun to resume.")
    p.add_argument("policy", help="the policy to tune (one with a search space: mht, fdp, dokf, renewal-ml, cdif)")
    p.add_argument("--suite", required=True, help="the suite whose validation seeds choose")
    p.add_argument("--division", default="offline", help="online, low-latency or offline (default): the lag bound")
    p.add_argument("--budget", type=int, default=2000, help="episode plays the search may spend (default 2000)")
    p.add_argument("--configs", type=int, default=27, help="candidate configurations (default 27)")
    p.add_argument("--eta", type=int, default=3, help="keep 1/eta per rung, eta times the seeds (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the candidates drawn from the space")
    p.add_argument("--scenarios", default=None, metavar="A,B,...", help="only these scenarios of the suite")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--out", metavar="PRESET.json",
                   help="the preset file (default baselines/presets/POLICY/SUITE.DIVISION.json)")
    p.add_argument("--work", metavar="DIR", help="the plays' results (default runs/tune/POLICY-SUITE-DIVISION)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_tune)


def cmd_tune(args: argparse.Namespace) -> int:
    from deint_env.tune import tune

    _check_folders({"--work": args.work})
    # ",,," and "" name none: not the whole suite
    scenarios = _scenario_names(args.scenarios) if args.scenarios is not None else ()
    result = tune(args.policy, args.suite, division=args.division, budget=args.budget, configs=args.configs,
                  eta=args.eta, seed=args.seed, workers=args.workers, out=args.out, work=args.work,
                  scenarios=scenarios, progress=not args.no_progress,
                  log=_status)
    preset = result.preset
    print(json.dumps({"params": preset["params"], "validation": preset["validation"]}))
    _status(f"deint: chose {preset['spec']} (validation mean {preset['validation']['mean_score']:.4f} over "
            f"{preset['validation']['episodes']} episodes) -> {result.path}")
    return 0


# ---------------------------------------------------------------------------------------------------
# deint leaderboard
# ---------------------------------------------------------------------------------------------------
def _add_leaderboard(sub) -> None:
    p = sub.add_parser(
        "leaderboard", help="score policies on a suite's test seeds: tables, plots, a web page; submissions",
        description="Play every policy on every test episode of a suite and write ROOT/SUITE/: results.jsonl "
                    "(per episode; an interrupted run resumes from it), leaderboard.json and .csv (normalised "
                    "score IQM and mean with 95% stratified-bootstrap intervals, accuracy, P_e, V-measure, ARI, "
                    "per-tag scores, period error vs CRLB, us/pulse, lag, coverage), README.md, index.html and "
                    "PNG plots; rows ranked within latency divisions (online lag <= 3, low-latency <= 64, offline).  "
                    "Default policies: every shipped policy in every division it reaches, the suite's tuned presets "
                    "and each learned entry's ablation (with --all, the ones each leaderboard records).  "
                    "--time: one timing run (timings.json) for the speed columns.  `deint leaderboard submit` scores "
                    "labels made elsewhere; `deint leaderboard export` writes a policy's labels in that format.")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--suite", help="a suite name (see `deint suites`)")
    which.add_argument("--all", action="store_true",
                       help="regenerate every published leaderboard (each suite with a folder under --root holding "
                            "leaderboard.json), each with the policy specs and scope it records (--policy/--policies: "
                            "those instead)")
    p.add_argument("--policy", action="append", default=[], metavar="SPEC",
                   help="a policy, NAME or NAME:key=value,... (repeatable; default: every reference policy)")
    p.add_argument("--policies", metavar="A,B,...", help="policies by plain name, comma-separated")
    p.add_argument("--workers", type=int, metavar="N", help="worker processes (default: every core)")
    p.add_argument("--root", default="leaderboards", metavar="DIR",
                   help="the leaderboards folder (default ./leaderboards)")
    p.add_argument("--scenarios", metavar="A,B,...", help="only these scenarios: a smoke run, not a full leaderboard")
    p.add_argument("--max-seeds", type=int, metavar="K", help="only the first K test seeds: a smoke run")
    p.add_argument("--reps", type=int, default=2000, metavar="R", help="bootstrap replicates (default 2000)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where episodes run: the local process pool (default) or a Ray cluster")
    p.add_argument("--address", help="the Ray cluster to join (with --executor ray; default: a private one)")
    p.add_argument("--time", action="store_true",
                   help="then time every entry in one process, one after another (timings.json: median us/pulse "
                        "and the ratio to fdp; the board's only speed columns); run it on an idle machine")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_leaderboard)
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    s = actions.add_parser(
        "submit", help="score a submission file into a suite's leaderboard",
        description="Validate FILE (JSON lines or NPZ: the labels of every test episode; format in the README) "
                    "without executing anything, score it like the reference policies, and add it to ROOT/SUITE "
                    "as 'NAME (submitted)' (replacing an earlier submission of that name).  A bad file is "
                    "refused with one line naming the episode and the problem; the leaderboard is unchanged.")
    s.add_argument("file", metavar="FILE")
    s.add_argument("--suite", required=True, help="the suite the file labels")
    s.add_argument("--name", help="the entry's name (default: the file header's name)")
    s.add_argument("--root", default="leaderboards", metavar="DIR",
                   help="the leaderboards folder (default ./leaderboards)")
    s.add_argument("--reps", type=int, default=2000, metavar="R", help="bootstrap replicates (default 2000)")
    s.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    s.set_defaults(func=cmd_leaderboard_submit)
    e = actions.add_parser(
        "export", help="write a policy's labels of a suite's test episodes as a submission file",
        description="Play the policy on every test episode of SUITE and write its labels in the submission "
                    "format: JSON lines, or NPZ when FILE ends in .npz.")
    e.add_argument("--suite", required=True)
    e.add_argument("--policy", required=True, metavar="SPEC", help="NAME or NAME:key=value,...")
    e.add_argument("-o", "--output", required=True, metavar="FILE")
    e.add_argument("--workers", type=int, default=1, metavar="N", help="worker processes (default 1)")
    e.add_argument("--scenarios", metavar="A,B,...", help="only these scenarios (matching a smoke-run leaderboard)")
    e.add_argument("--max-seeds", type=int, metavar="K", help="only the first K test seeds")
    e.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    e.set_defaults(func=cmd_leaderboard_export)


def _scenario_names(text: str) -> tuple[str, ...]:
    """The names of a --scenarios option; an empty one (",,", a trailing comma) is refused."""
    names = tuple(n.strip() for n in text.split(","))
    if not all(names):
        raise DeintError(f"--scenarios={text!r} is invalid: scenario names separated by commas")
    return names


def _scope(suite: str, args: argparse.Namespace):
    from deint_env.leaderboard import Scope

    names = None if args.scenarios is None else _scenario_names(args.scenarios)
    if args.max_seeds is not None and args.max_seeds < 1:
        raise DeintError(f"--max-seeds={args.max_seeds} is invalid: an integer >= 1")
    return Scope(suite, names, args.max_seeds)


def _leaderboard_report(board: dict[str, Any], folder: Path) -> None:
    from deint_env.leaderboard.render import tidy
    from deint_env.tables import entry_table

    b = tidy(board)
    print(f"{b['suite']} (version {b['suite_version']}, hash {b['suite_hash']}), {b['episodes']} test episodes")
    print(entry_table(b["rows"]))
    for policy, n in sorted(b["incomplete"].items()):
        _status(f"deint: warning: {policy} has {n} of {b['episodes']} episodes; it is left out until complete")
    _status(f"deint: leaderboard of {b['suite']} -> {folder}/ (README.md, index.html, leaderboard.json, .csv, plots)")


def _check_reps(reps: int) -> None:
    from deint_env.stats import MAX_REPS, MIN_REPS

    if not MIN_REPS <= reps <= MAX_REPS:
        raise DeintError(f"--reps={reps} is invalid: an integer in [{MIN_REPS}, {MAX_REPS}]")


def cmd_leaderboard(args: argparse.Namespace) -> int:
    from deint_env.leaderboard import Scope, board_entries, board_policies, build, published_suites, timing, write

    if not args.all and args.suite is None:
        raise DeintError("name a suite: --suite SUITE, or --all for the published leaderboards")
    if args.all and (args.scenarios is not None or args.max_seeds is not None):
        raise DeintError("--all rebuilds each leaderboard at the scope it records; --scenarios and --max-seeds are "
                         "for one --suite")
    if args.workers is not None and args.workers < 1:
        raise DeintError(f"--workers={args.workers} is invalid: an integer >= 1")
    _check_reps(args.reps)
    _check_folders({"--root": args.root})
    named = _run_policies(args) if args.policy or args.policies else None
    if args.all:  # each board as it was built: its own policy specs (parameters included) and scope
        runs = []
        if not published_suites(args.root):  # else --all would do nothing and say nothing
            raise DeintError(f"--root {args.root}: holds no published leaderboard (a SUITE/leaderboard.json of a "
                             f"known suite); name the leaderboards folder, or build one with --suite SUITE")
        for suite in published_suites(args.root):
            folder = Path(args.root) / suite
            runs.append((Scope.of_folder(folder, suite), named or board_policies(folder)))
    else:
        runs = [(_scope(args.suite, args), named or board_entries(args.suite))]
    for scope, policies in runs:
        if args.all:
            _status(f"deint: {scope.suite}: {len(policies)} policies: {' '.join(policies)}")
        folder, board = build(scope, policies, workers=args.workers, root=args.root, progress=not args.no_progress,
                              reps=args.reps, executor=args.executor, address=args.address)
        if args.time:
            timing.run(folder, scope.suite, [r["policy"] for r in board["rows"] if not r["submitted"] and r["played"]],
                       scope.scenarios, progress=not args.no_progress)
            board = write(folder, scope, reps=args.reps)
        _leaderboard_report(board, folder)
    return 0


def cmd_leaderboard_submit(args: argparse.Namespace) -> int:
    from deint_env.leaderboard import submit

    _check_reps(args.reps)
    _check_folders({"--root": args.root})
    board_dir = Path(args.root) / args.suite
    if Path(args.file).resolve().parent == board_dir.resolve():
        raise DeintError(f"FILE {args.file} lies in the leaderboard directory {board_dir}, whose files submit "
                         f"rewrites; keep submissions elsewhere")
    policy, board = submit(args.file, args.suite, args.name, root=args.root, reps=args.reps,
                           progress=not args.no_progress)
    _leaderboard_report(board, Path(args.root) / args.suite)
    _status(f"deint: {args.file} accepted as {policy!r}")
    return 0


def cmd_leaderboard_export(args: argparse.Namespace) -> int:
    from deint_env.leaderboard import export

    if args.workers < 1:
        raise DeintError(f"--workers={args.workers} is invalid: an integer >= 1")
    _check_paths(_policy_inputs([args.policy]), {"-o": args.output})
    n = export(_scope(args.suite, args), args.policy, args.output, workers=args.workers, progress=not args.no_progress)
    _status(f"deint: labels of {n} test episodes of {args.suite} by {args.policy} -> {args.output}")
    return 0

"""The `deint` command (docs/design.md section 7).

    deint simulate SCENARIO --seed S -o PULSES.csv [--priors-out PRIORS.json] [--true-priors-out TRUE.json]
    deint label PULSES.csv --policy SPEC [--priors PRIORS.json | --n-sources N --prior-periods a,b,...] -o LABELS.csv
    deint score LABELS.csv --truth PULSES.csv [--json]
    deint run --policy SPEC [--policy SPEC ...] (--suite SUITE | --scenario NAME) [--out RESULTS.jsonl]
              [--workers N] [--executor local|ray [--address ADDR]] [--split test|validation|train]
    deint suites [SUITE]
    deint policies [NAME]
    deint tune POLICY --suite SUITE [--division online|low-latency|offline] [--budget N]
    deint leaderboard (--suite SUITE | --all) [--policies A,B,...] [--workers N] [--time]
    deint leaderboard submit FILE --suite SUITE --name NAME
    deint leaderboard export --suite SUITE --policy SPEC -o FILE
    deint tdc convert INPUT OUTPUT [--float64]

PULSES and LABELS may also be Turing Deinterleaving Challenge files (.h5/.hdf5; see deint_env.formats.tdc).

Bad input is one line `deint: error: ...` on stderr and exit status 2; Ctrl-C is one line and 130.
Tables and JSON go to stdout, status lines to stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import io
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator


from deint_env import formats, tdc_scores
from deint_env.formats import tdc
from deint_env.errors import DeintError
from deint_env.cli_boards import _add_leaderboard, _add_tune
from deint_env.cli_import import _add_import_sb3
from deint_env.cli_plot import _add_plot
from deint_env.cli_util import (EXIT_ERROR, EXIT_INTERRUPTED, _check_folders, _check_paths, _decimal_float, _Parser,
                                _policy_inputs, _run_policies, _status, read_label_file)

# ---------------------------------------------------------------------------------------------------
# deint simulate
# ---------------------------------------------------------------------------------------------------
def _add_simulate(sub) -> None:
    p = sub.add_parser(
        "simulate", help="simulate one episode of a scenario into a pulse file",
        description="Simulate episode SEED of SCENARIO and write it as a pulse file (toa[,amplitude],source"
                    "[,sources]), or, for an -o ending .h5/.hdf5 or with --format tdc, as a Turing "
                    "Deinterleaving Challenge file (float64 data: time_of_arrival and every descriptor the "
                    "episode has, frequency, pulse_width, angle_of_arrival, amplitude; labels: the sources, "
                    "-1 spurious).  --priors-out writes the public priors a policy is given for this episode "
                    "(for a scenario with explicit or perturbed priors these are NOT the true parameters); "
                    "--true-priors-out writes the true periods and phases with the channel statistics, "
                    "which is what `deint label --policy genie` needs to label as the oracle does (exactly "
                    "so for constant-PRI, always-on sources).")
    p.add_argument("scenario", metavar="SCENARIO",
                   help="a scenario name (SUITE/SCENARIO, or a bare name unique across suites; see "
                        "`deint suites SUITE`) or a scenario JSON file (a ScenarioSpec dict)")
    p.add_argument("--seed", type=int, required=True, help="the episode seed")
    p.add_argument("-o", "--output", required=True, metavar="PULSES.csv", help="the pulse file to write")
    p.add_argument("--priors-out", metavar="PRIORS.json", help="also write the public priors")
    p.add_argument("--true-priors-out", metavar="TRUE.json",
                   help="also write the true parameters (periods, phases, channel statistics) for genie")
    p.add_argument("--no-truth", action="store_true", help="leave out the source (truth) columns")
    p.add_argument("--format", choices=("csv", "tdc"), default=None,
                   help="the pulse file's format (default: by the suffix of -o, .h5/.hdf5 = tdc, else csv)")
    p.set_defaults(func=cmd_simulate)


def _scenario(text: str):
    from deint_env.scenario import ScenarioSpec
    from deint_env.suites import resolve_scenario

    # a FIFO or a device is read as a file too, and refused as not regular (not looked up as a name)
    if os.path.exists(text) and (text.endswith(".json") or not os.path.isdir(text)):
        try:
            return ScenarioSpec.from_dict(formats.read_json(text))
        except DeintError as e:
            msg = str(e)
            raise DeintError(msg if msg.startswith(text) else f"{text}: {msg}") from None
    if text.endswith(".json"):
        raise DeintError(f"{text}: no such scenario file")
    return resolve_scenario(text)


def cmd_simulate(args: argparse.Namespace) -> int:
    from deint_env.simulate import simulate

    _check_paths({"SCENARIO": args.scenario if os.path.isfile(args.scenario) else None},
                 {"-o": args.output, "--priors-out": args.priors_out, "--true-priors-out": args.true_priors_out})
    spec = _scenario(args.scenario)
    episode = simulate(spec, args.seed)
    # Every output is formatted (and so validated) before any is written.
    if args.format == "tdc" or (args.format is None and tdc.is_tdc_path(args.output)):
        train = tdc.train_from_episode(episode, truth=not args.no_truth)
        outputs = [(args.output, train.to_bytes("float64", where=args.output))]
    else:
        if episode.descriptors:
            _status(f"deint: a CSV pulse file holds toa and amplitude; {', '.join(episode.descriptors)} left out "
                    f"(-o FILE.h5 or --format tdc keeps them)")
        outputs = [(args.output, formats.format_pulses(episode, truth=not args.no_truth))]
    if args.priors_out:
        outputs.append((args.priors_out, formats.format_priors(episode.priors, where=args.priors_out)))
    if args.true_priors_out:
        true = formats.true_priors(episode)
        outputs.append((args.true_priors_out, formats.format_priors(true, where=args.true_priors_out)))
    formats.write_all(outputs)  # all or none
    _status(f"deint: {len(episode)} pulses of {spec.name} (seed {args.seed}) -> "
            + ", ".join(path for path, _ in outputs))
    return 0


# ---------------------------------------------------------------------------------------------------
# deint label
# ---------------------------------------------------------------------------------------------------
def _add_label(sub) -> None:
    p = sub.add_parser(
        "label", help="label a pulse file with a policy",
        description="Label every pulse of PULSES.csv with a policy and write LABELS.csv (toa,label; "
                    "label -1 = spurious).  The policy sees only the pulses and the priors, never the file's "
                    "source columns.  Priors come from a priors file, or from --prior-periods (phases "
                    "unknown), or --n-sources alone (blind: N labels, no priors); a blind deinterleaver (cdif, sdif, "
                    "pri-transform, dbscan, hdbscan, seq, renewal-ml) runs with none (32 labels) and measures "
                    "the TOA noise itself.  `genie` labels from the "
                    "periods and phases in the priors file as if they were the truth: give it the file of "
                    "`deint simulate --true-priors-out` to get the oracle labelling.  A .h5/.hdf5 input or "
                    "output is a Turing Deinterleaving Challenge file (blind: give --n-sources N; a `tdc` "
                    "model policy gets its full PDW rows); an .h5 output holds the input's rows and the "
                    "predicted labels (-1 = spurious).")
    p.add_argument("pulses", metavar="PULSES.csv")
    p.add_argument("--policy", required=True, metavar="SPEC",
                   help="NAME or NAME:key=value,... (see `deint policies`)")
    p.add_argument("--priors", metavar="PRIORS.json", help="the priors file")
    p.add_argument("--n-sources", type=int, metavar="N", help="number of sources (alone: blind labelling)")
    p.add_argument("--prior-periods", metavar="a,b,...", help="the sources' prior periods")
    p.add_argument("--lag", type=int, metavar="D",
                   help="the decision lag; a policy whose lag is fixed must already have it, one with a "
                        "lag or lookahead parameter gets it set")
    p.add_argument("--seed", type=int, default=0, help="seed of a stochastic policy (default 0)")
    p.add_argument("-o", "--output", required=True, metavar="LABELS.csv", help="the label file to write")
    p.set_defaults(func=cmd_label)


BLIND_LABELS = 32  # the label budget of `deint label` with a blind policy and no priors


def _finds_own_trains(spec: str) -> bool:
    """Whether the policy runs without priors: it plays only the blind mode (registry `modes`), or its
    class says it finds its own tracks in blind mode (`blind_ok`, as renewal-ml)."""
    from deint_env.policies import parse_policy_spec, policy_info

    info = policy_info(parse_policy_spec(spec)[0])
    return info.modes == ("blind",) or bool(getattr(info.load(), "blind_ok", False))


def _cli_priors(args: argparse.Namespace):
    from deint_env.episode import Priors

    if args.priors is not None:
        if args.n_sources is not None or args.prior_periods is not None:
            raise DeintError("give either --priors or --n-sources/--prior-periods, not both")
        return formats.read_priors(args.priors)
    if args.n_sources is not None and args.n_sources < 1:
        raise DeintError(f"--n-sources={args.n_sources} is invalid: an integer >= 1")
    if args.prior_periods is None:
        if args.n_sources is None:
            if _finds_own_trains(args.policy):  # a blind deinterleaver needs no priors: BLIND_LABELS tracks
                return Priors.from_json_dict({"blind": True, "label_budget": BLIND_LABELS}, where="blind policy")
            raise DeintError("the policy needs priors: give --priors PRIORS.json, or --prior-periods a,b,... "
                             "(or --n-sources N for blind labelling)")
        return Priors.from_json_dict({"blind": True, "label_budget": args.n_sources}, where="--n-sources")
    try:
        periods = [_decimal_float(x) for x in args.prior_periods.split(",")]
    except ValueError:
        raise DeintError(f"--prior-periods={args.prior_periods!r} is invalid: comma-separated positive numbers") \
            from None
    if args.n_sources is not None and args.n_sources != len(periods):
        raise DeintError(f"--n-sources={args.n_sources} but --prior-periods lists {len(periods)} periods; "
                         f"they must agree")
    if not all(math.isfinite(t) for t in periods):
        raise DeintError(f"--prior-periods={args.prior_periods!r} is invalid: comma-separated positive numbers")
    return Priors.from_json_dict({"period": periods}, where="--prior-periods")


def _policy_with_lag(spec: str, lag: int | None):
    """The policy of `spec`, run at `lag` if given: set through its `lag` or `lookahead` parameter
    when it has one the spec leaves free, else it must already run at that lag."""
    from deint_env.policies import canonical_spec, make_policy, parse_policy_spec, policy_info

    policy = make_policy(spec)
    if lag is None or policy.lag == lag:
        return policy
    name, kwargs = parse_policy_spec(spec)
    params = inspect.signature(policy_info(name).load()).parameters
    knob = next((k for k in ("lag", "lookahead") if k in params and k not in kwargs), None)
    if knob is not None:
        policy = make_policy(canonical_spec(name, {**kwargs, knob: lag}))
        if policy.lag == lag:
            return policy
    raise DeintError(f"--lag {lag} is invalid for policy {spec!r}: it runs with lag {policy.lag}"
                     + ("" if knob is None else f" even with {knob}={lag}") + "; drop --lag")


@contextlib.contextmanager
def _compile_notice(spec: str) -> Iterator[None]:
    """While inside, the first kernel numba compiles for the policy of `spec` prints one status line.
    numba loads a kernel from its disk cache without compiling it, so the line appears exactly when a
    wait is coming (the first run after an install or after a change of the kernel's source) and never
    on a warm cache.  A policy whose module does not import numba gets nothing: importing numba just to
    listen would cost every other policy its import time."""
    from deint_env.policies import parse_policy_spec, policy_info

    name = parse_policy_spec(spec)[0]
    policy_info(name).load()  # imports the policy's module, and numba with it when the policy has kernels
    if "numba" not in sys.modules:
        yield
        return
    from numba.core import event
    from numba.core.caching import NullCache

    class Notice(event.Listener):
        said = False

        def on_start(self, ev: event.Event) -> None:
            if not self.said:
                self.said = True
                why = ("not cacheable: compiled in every process" if isinstance(ev.data["dispatcher"]._cache, NullCache)
                       else "first run after an install or update; cached for later calls")
                _status(f"deint: compiling {name}'s kernels ({why}) ...")

        def on_end(self, ev: event.Event) -> None:
            pass

    with event.install_listener("numba:compile", Notice()):
        yield


def cmd_label(args: argparse.Namespace) -> int:
    from deint_env.play import play  # not from runner, which imports every part of a run
    from deint_env.policies import check_policy_seed, is_oracle

    _check_paths({"PULSES": args.pulses, "--priors": args.priors, **_policy_inputs([args.policy])},
                 {"-o": args.output})
    check_policy_seed(args.seed, "--seed")
    priors = _cli_priors(args)
    with _compile_notice(args.policy):
        policy = _policy_with_lag(args.policy, args.lag)
        train = None
        if tdc.is_tdc_path(args.pulses):  # a TDC file; a TDC model policy is given its full PDW rows
            train = tdc.read_tdc(args.pulses)
            episode = train.episode(priors, name=Path(args.pulses).name)
            if hasattr(policy, "attach_data"):
                policy.attach_data(train.model_input())
            if hasattr(policy, "attach_features"):  # a blind deinterleaver: the file's other descriptors
                policy.attach_features(train.features)
        else:
            episode = formats.read_pulses(args.pulses, priors)
        t0 = time.perf_counter()
        result = play(policy, episode, policy_seed=args.seed, oracle=is_oracle(args.policy), scored=False)
        seconds = time.perf_counter() - t0
    if tdc.is_tdc_path(args.output):  # a TDC file: the input's rows with the predicted labels
        tdc.write_labels(args.output, train or episode, result.labels, priors.n_labels, f"labels of {args.policy}")
    else:
        formats.write_labels(args.output, episode.toa, result.labels, priors.n_labels)
    _status(f"deint: labelled {len(episode)} pulses with {args.policy} (lag {policy.lag}) in {seconds:.2f} s "
            f"-> {args.output}")
    return 0


# ---------------------------------------------------------------------------------------------------
# deint score
# ---------------------------------------------------------------------------------------------------
def _add_score(sub) -> None:
    p = sub.add_parser(
        "score", help="score a label file against a truth pulse file",
        description="Score LABELS.csv against the source columns of PULSES.csv: label accuracy, per-source "
                    "error probability P_e and its mean, permutation-matched and link accuracy, spurious "
                    "precision/recall and the clustering metrics (V-measure, ARI, AMI, ...).  Anchored "
                    "by default (label i names source i); --blind scores links (accuracy = link accuracy).  "
                    "A .h5/.hdf5 truth (or label) file is a Turing Deinterleaving Challenge file: its emitter "
                    "ids are scored blind (cluster_mcc and cluster_f1 are the challenge's cluster-wise scores).")
    p.add_argument("labels", metavar="LABELS.csv")
    p.add_argument("--truth", required=True, metavar="PULSES.csv",
                   help="the pulse file with the source column (from `deint simulate`)")
    p.add_argument("--n-labels", type=int, metavar="N",
                   help="labels other than spurious (default: max(true sources, largest label + 1))")
    p.add_argument("--blind", action="store_true", help="score links (blind mode) instead of labels")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=cmd_score)




def _score_tdc(args: argparse.Namespace) -> dict[str, Any]:
    """Blind scores against a TDC file's emitter ids (see `deint_env.tdc_scores.score_labels`)."""
    truth = tdc.read_tdc(args.truth)
    if truth.labels is None:
        raise DeintError(f"{args.truth}: has no 'labels' dataset; score needs the true emitter ids")
    if args.n_labels is not None and not 1 <= args.n_labels <= formats.MAX_LABEL + 1:
        raise DeintError(f"--n-labels={args.n_labels} is invalid: an integer in [1, {formats.MAX_LABEL + 1}]")
    labels = read_label_file(args.labels, truth.toa, args.truth, args.n_labels)
    return tdc_scores.score_labels(labels, truth.labels, args.n_labels)


def cmd_score(args: argparse.Namespace) -> int:
    from deint_env.metrics import label_metrics
    from deint_env.results import json_ready

    if tdc.is_tdc_path(args.truth):  # TDC truth: emitter ids without priors, always scored blind
        return _print_metrics(args, json_ready(_score_tdc(args)))
    truth = formats.read_pulse_table(args.truth)
    if truth.source is None:
        raise DeintError(f"{args.truth}: has no 'source' column; score needs a truth file "
                         f"(`deint simulate` without --no-truth)")
    if args.n_labels is not None and not 1 <= args.n_labels <= formats.MAX_LABEL + 1:
        raise DeintError(f"--n-labels={args.n_labels} is invalid: an integer in [1, {formats.MAX_LABEL + 1}]")
    labels = read_label_file(args.labels, truth.toa, args.truth, args.n_labels)
    n_labels = args.n_labels or max(truth.n_sources, int(labels.max()) + 1, 1)
    metrics = label_metrics(formats.from_file_labels(labels, n_labels), truth.source, truth.mask, n_labels,
                            args.blind, clustering=True)
    return _print_metrics(args, json_ready({"n_labels": n_labels, "blind": args.blind, **metrics}))


def _print_metrics(args: argparse.Namespace, metrics: dict[str, Any]) -> int:
    if args.json:
        print(json.dumps(metrics, allow_nan=False))
    else:
        print(_metrics_table(metrics))
    return 0


def _metrics_table(m: dict[str, Any]) -> str:
    rows = []
    for key, value in m.items():
        if key == "pe":
            rows += [(f"pe[source {i}]", v) for i, v in enumerate(value)]
        else:
            rows.append((key, value))
    width = max(len(k) for k, _ in rows)

    def fmt(v: Any) -> str:
        if v is None:
            return "n/a"
        return f"{v:.4f}" if isinstance(v, float) else str(v)

    return "\n".join(f"{k.ljust(width)}  {fmt(v)}" for k, v in rows)


# ---------------------------------------------------------------------------------------------------
# deint run
# ---------------------------------------------------------------------------------------------------
def _add_run(sub) -> None:
    p = sub.add_parser(
        "run", help="evaluate policies on a suite or a scenario",
        description="Play every policy on every seed of a suite (or one scenario) split and print the "
                    "summary (accuracy, normalised score with 95% intervals, ...).  Each finished episode "
                    "is appended to the results file (default runs/TARGET-SPLIT.jsonl) and episodes "
                    "already in it are not played again, so an interrupted run resumes when rerun.")
    p.add_argument("--policy", action="append", default=[], metavar="SPEC",
                   help="a policy, NAME or NAME:key=value,... (repeat for several)")
    p.add_argument("--policies", metavar="A,B,...",
                   help="several policies by plain name, comma-separated (use --policy for parameters)")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--suite", help="a suite name (see `deint suites`)")
    target.add_argument("--scenario", help="one scenario: SUITE/SCENARIO or a unique bare name")
    p.add_argument("--split", choices=("test", "validation", "train"), default="test",
                   help="the seed split (default test; validation: the last 1000 train seeds, for choices)")
    p.add_argument("--max-seeds", type=int, metavar="K", help="only the first K seeds of each scenario")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="worker processes (default 1); with --executor ray, the CPUs of the Ray instance "
                        "started here")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local: this process or a process pool (default); ray: Ray tasks (the [ray] extra)")
    p.add_argument("--address", metavar="ADDR",
                   help="with --executor ray: the Ray cluster to join (e.g. auto or ray://HOST:10001); "
                        "default: start a local Ray instance")
    p.add_argument("--out", metavar="RESULTS.jsonl", help="the results file (default runs/TARGET-SPLIT.jsonl)")
    p.add_argument("--json", action="store_true", help="print the summary rows as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_run)


def cmd_run(args: argparse.Namespace) -> int:
    from deint_env.results import json_ready
    from deint_env.runner import evaluate, format_table, read_records, resolve_target, summarise
    from deint_env.suites import list_suites, load_suite

    policies = _run_policies(args)
    if args.suite is not None:
        target = load_suite(args.suite).name  # one line for an unknown suite
    elif args.scenario in list_suites():
        raise DeintError(f"--scenario {args.scenario!r} names a suite; use --suite {args.scenario}")
    else:
        (suite, _, entry), = resolve_target(args.scenario)
        target = f"{suite}/{entry.name}"
    if args.max_seeds is not None and args.max_seeds < 1:
        raise DeintError(f"--max-seeds={args.max_seeds} is invalid: an integer >= 1")
    out = Path(args.out) if args.out else Path("runs") / f"{target}-{args.split}.jsonl"
    if out.is_dir():
        raise DeintError(f"--out {out} is a directory; name a results file")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DeintError(f"{out}: cannot create its directory ({e.strerror or e})") from None
    before = len(read_records(out))
    records = evaluate(policies, target, split=args.split, max_seeds=args.max_seeds, workers=args.workers,
                       out=out, progress=not args.no_progress, executor=args.executor, address=args.address)
    rows = summarise(records)
    print(json.dumps(json_ready(rows), allow_nan=False) if args.json else format_table(rows))
    _status(f"deint: {len(records)} episodes ({len(read_records(out)) - before} played now) in {out}")
    return 0


# ---------------------------------------------------------------------------------------------------
# deint suites, deint policies
# ---------------------------------------------------------------------------------------------------
def _add_suites(sub) -> None:
    p = sub.add_parser("suites", help="list the suites, or one suite's scenarios",
                       description="Without SUITE: every suite with its version, size, tags, seed counts, "
                                   "content hash and whether that matches the published hash.  With SUITE: "
                                   "its scenarios.")
    p.add_argument("suite", nargs="?", metavar="SUITE")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_suites)


def _published(suite) -> str:
    from deint_env.suites import history

    try:
        versions = history().get(suite.name)
    except FileNotFoundError:  # nothing is published yet
        versions = None
    if not versions:
        return "unpublished"
    last = versions[-1]["hash"]
    return "published" if last == suite.content_hash else f"CHANGED (published {last})"


def _span(values: list[int]) -> str:
    lo, hi = min(values), max(values)
    return str(lo) if lo == hi else f"{lo}-{hi}"


from deint_env.tables import text_table as _table  # noqa: E402 -- the one table formatter


def _suite_summary(suite) -> dict[str, Any]:
    return {"suite": suite.name, "version": suite.version, "scenarios": len(suite),
            "tags": sorted({t for e in suite for t in e.tags}),
            "train_seeds": _span([len(e.train) for e in suite]), "test_seeds": _span([len(e.test) for e in suite]),
            "hash": suite.content_hash, "status": _published(suite), "description": suite.description}


def _scenario_row(entry) -> dict[str, Any]:
    spec = entry.spec
    n = len(spec.sources)
    return {"scenario": entry.name, "tags": list(entry.tags),
            "sources": f"{spec.n_active[0]}-{spec.n_active[1]}" if spec.n_active else str(n),
            "n_pulses": spec.n_pulses, "jitter": spec.toa_jitter_std, "settings": entry.settings,
            "train_seeds": len(entry.train), "test_seeds": len(entry.test)}


def cmd_suites(args: argparse.Namespace) -> int:
    from deint_env.suites import list_suites, load_suite

    if args.suite is None:
        rows = [_suite_summary(load_suite(name)) for name in list_suites()]
        if args.json:
            print(json.dumps(rows, indent=1))
        else:
            print(_table(["suite", "version", "scenarios", "tags", "train seeds", "test seeds", "hash", "status"],
                         [[r["suite"], str(r["version"]), str(r["scenarios"]), ",".join(r["tags"]) or "-",
                           r["train_seeds"], r["test_seeds"], r["hash"], r["status"]] for r in rows]))
        return 0
    suite = load_suite(args.suite)
    rows = [_scenario_row(e) for e in suite]
    if args.json:
        print(json.dumps({**_suite_summary(suite), "entries": rows}, indent=1))
        return 0
    s = _suite_summary(suite)
    print(f"{s['suite']} (version {s['version']}, hash {s['hash']}, {s['status']}): {s['description']}")
    print(_table(["scenario", "tags", "sources", "n_pulses", "jitter", "settings"],
                 [[r["scenario"], ",".join(r["tags"]) or "-", r["sources"], str(r["n_pulses"]), f"{r['jitter']:g}",
                   " ".join(f"{k}={v}" for k, v in r["settings"].items()) or "-"] for r in rows]))
    return 0


def _add_policies(sub) -> None:
    p = sub.add_parser("policies", help="list the registered policies",
                       description="Every registered policy with its kind (reference, learned, oracle: sees the "
                                   "truth, adapter: runs a model you name), the modes it plays, its version and "
                                   "limits; * marks the leaderboards' default set.  With NAME: that policy's "
                                   "description and its parameters (type, default, range or choices, meaning).")
    p.add_argument("name", nargs="?", metavar="NAME", help="one policy: show its parameters")
    p.set_defaults(func=cmd_policies)


def cmd_policies(args: argparse.Namespace) -> int:
    from deint_env.policies import default_policies, list_policies, policy_info

    if args.name is not None:
        info = policy_info(args.name)
        declared = info.declaration()
        print(f"{info.name} ({info.kind}, {'+'.join(info.modes)}, version {info.version}): {info.description}")
        if declared is None:
            print("(no declared parameters)")
        elif not declared.params:
            print("no parameters")
        else:
            print(_table(["parameter", "type", "default", "range", "meaning"], [list(r) for r in declared.table()]))
        return 0
    default = set(default_policies())

    def limits(p) -> str:
        return ", ".join(f"{k}={v}" for k, v in vars(p.limits).items() if v is not None) or "-"

    print(_table(["policy", "kind", "modes", "version", "limits", "needs", "description"],
                 [[p.name + ("*" if p.name in default else ""), p.kind, "+".join(p.modes), str(p.version), limits(p),
                   f"[{p.extra}]" if p.extra else "-", p.description] for p in list_policies()]))
    return 0


# ---------------------------------------------------------------------------------------------------
# deint reproduce
# ---------------------------------------------------------------------------------------------------
def _add_reproduce(sub) -> None:
    p = sub.add_parser("reproduce", help="run a paper experiment: its figure (PNG) and our numbers beside the paper's",
                       description="Run one published experiment (or 'all'), write its figure and table to --out, "
                                   "and print the table.  Without NAME, list the experiments.")
    p.add_argument("name", nargs="?", help="an experiment name, or 'all'")
    p.add_argument("--out", default="reproduce", help="output folder (default ./reproduce)")
    p.add_argument("--quick", action="store_true", help="few seeds and short episodes (a smoke run)")
    p.set_defaults(func=cmd_reproduce)


def cmd_reproduce(args: argparse.Namespace) -> int:
    from baselines.reproduce import list_experiments, run_experiment

    known = list_experiments()
    _check_folders({"--out": args.out})
    if not args.name:
        print(_table(["experiment", "what"], [[k, v] for k, v in known.items()]))
        return 0
    names = list(known) if args.name == "all" else [args.name]
    for name in names:
        started = time.perf_counter()
        report = run_experiment(name, args.out, quick=args.quick)
        print(report.table() + "\n")
        _status(f"deint: {name} in {time.perf_counter() - started:.1f} s -> "
                f"{', '.join(str(Path(args.out) / f) for f in report.files + [name + '.txt'])}")
    return 0


# ---------------------------------------------------------------------------------------------------
# deint train
# ---------------------------------------------------------------------------------------------------
MAX_EVAL_EPISODES = 10_000  # validation episodes per evaluation (default 32), each evaluation is played in full
MAX_TRAIN_STEPS = 10**12  # --timesteps and --eval-every: years of training at thousands of steps a second


def _add_train(sub) -> None:
    p = sub.add_parser("train", help="train a learned agent on train seeds (needs the [rl] extra)",
                       description="Train a stable-baselines3 / sb3-contrib agent (the permutation-equivariant track "
                                   "network on the token features) on the train seeds of a suite or scenarios, with "
                                   "periodic safetensors checkpoints and validation; rerun to resume (agents/train.py).")
    p.add_argument("--suite", default=None, help="train on every scenario of this suite (sampled per episode)")
    p.add_argument("--scenario", action="append", default=[], help="SUITE/SCENARIO to train on (repeatable)")
    p.add_argument("--tags", default="", help="only scenarios with all these tags (comma-separated)")
    p.add_argument("--algo", default="maskable-ppo",
                   help="maskable-ppo (default), ppo, recurrent-ppo (LSTM memory), a2c, dqn, dagger, bc (behaviour "
                        "cloning), seq (the supervised pointer sequence labeller, blind scenarios) or lmht (mht's "
                        "learned scorer)")
    p.add_argument("--expert", default="truth",
                   help="dagger / bc: imitate 'truth' (default) or a reference policy spec (e.g. mht, fdp, genie)")
    p.add_argument("--timesteps", type=int, default=None, help="total steps (default: the YAML's n_timesteps)")
    p.add_argument("--n-envs", type=int, default=None, help="parallel episodes (default: the YAML's n_envs)")
    p.add_argument("--time-budget", type=float, default=None, help="stop after this many seconds of training")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lag", type=int, default=0, help="decision lag = look-ahead pulses featured")
    p.add_argument("--eval-every", type=int, default=50_000, help="steps between checkpoints and validation")
    p.add_argument("--eval-episodes", type=int, default=32, help="validation episodes per evaluation")
    p.add_argument("--hyperparams", default=None, help="YAML file (default: agents/hyperparams/ALGO.yml)")
    p.add_argument("-o", "--out", default=None, help="run directory (default: runs/train/ALGO-TARGET)")
    p.add_argument("--into-package", action="store_true", help="allow an output directory inside the package")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)


def cmd_train(args: argparse.Namespace) -> int:
    try:
        from agents.train import TrainConfig, train
    except ImportError as e:
        raise DeintError(f"training needs {e.name}: pip install 'deint-bench[rl]'") from None
    for name in ("timesteps", "n_envs", "eval_every", "eval_episodes"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise DeintError(f"--{name.replace('_', '-')}={value} must be >= 1")
        if value is not None and name in ("timesteps", "eval_every") and value > MAX_TRAIN_STEPS:  # 10^20 trained on
            raise DeintError(f"--{name.replace('_', '-')}={value} is invalid: at most 10^12 steps (years of training; "
                             f"--time-budget bounds a run by time)")
    _check_folders({"-o": args.out})
    if args.time_budget is not None and not args.time_budget > 0:
        raise DeintError(f"--time-budget={args.time_budget} must be > 0 seconds")
    if not 0 <= args.seed < 2**32:  # stable-baselines3 seeds numpy's legacy generator
        raise DeintError(f"--seed={args.seed} is invalid: an integer in [0, 2^32)")
    if args.eval_episodes > MAX_EVAL_EPISODES:
        raise DeintError(f"--eval-episodes={args.eval_episodes} is invalid: an integer in [1, {MAX_EVAL_EPISODES}]")
    target = args.suite or (args.scenario[0].replace("/", "-") if args.scenario else "none")
    out = Path(args.out) if args.out else Path("runs") / "train" / f"{args.algo}-{target}"
    config = TrainConfig(out=out, algo=args.algo, suite=args.suite, scenarios=tuple(args.scenario),
                         tags=tuple(t for t in args.tags.split(",") if t), lag=args.lag, n_envs=args.n_envs,
                         timesteps=args.timesteps, time_budget=args.time_budget, seed=args.seed,
                         eval_every=args.eval_every, eval_episodes=args.eval_episodes,
                         hyperparams_file=Path(args.hyperparams) if args.hyperparams else None,
                         into_package=args.into_package, progress=not args.no_progress, expert=args.expert)
    result = train(config)
    _status(f"deint: trained {result.timesteps} steps in {result.seconds:.0f} s -> {result.last}"
            + (f" (best: {result.best})" if result.best else ""))
    return 0


# ---------------------------------------------------------------------------------------------------
# deint dataset
# ---------------------------------------------------------------------------------------------------
def _add_dataset(sub) -> None:
    p = sub.add_parser("dataset", help="export a reference policy's demonstrations as a Minari dataset",
                       description="Record a policy playing the first seeds of a split of a suite or scenarios as a "
                                   "Minari dataset: observations, actions (the policy's labels), rewards, and in the "
                                   "infos the true and the policy's label of each step's pulse (agents/dataset.py).")
    p.add_argument("dataset_id", help="Minari dataset id NAMESPACE/NAME-vN, e.g. deint/core-fdp-v0")
    p.add_argument("--suite", default=None, help="every scenario of this suite")
    p.add_argument("--scenario", action="append", default=[], help="SUITE/SCENARIO (repeatable)")
    p.add_argument("--tags", default="", help="only scenarios with all these tags (comma-separated)")
    p.add_argument("--split", choices=("train", "validation", "test"), default="train",
                   help="the seed split (default train)")
    p.add_argument("--seeds", type=int, default=2, help="episodes per scenario: the split's first seeds (default 2)")
    p.add_argument("--policy", default="fdp", help="the demonstrating policy spec (default fdp)")
    p.add_argument("--env", choices=("raw", "tokens"), default="raw",
                   help="raw: Deinterleave-v0 observations and labels; tokens: DeinterleaveTokens-v0 (track actions)")
    p.add_argument("--max-tracks", type=int, default=8, help="tokens env: padded track count (default 8)")
    p.add_argument("--root", default=None,
                   help="datasets directory (default: $MINARI_DATASETS_PATH, else ~/.minari/datasets)")
    p.set_defaults(func=cmd_dataset)


def cmd_dataset(args: argparse.Namespace) -> int:
    try:
        from agents.dataset import DatasetConfig, write_dataset
    except ImportError as e:
        raise DeintError(f"deint dataset needs {e.name}: pip install 'minari[create]'") from None
    if args.max_tracks < 1:
        raise DeintError(f"--max-tracks={args.max_tracks} must be >= 1")
    _check_folders({"--root": args.root})
    config = DatasetConfig(args.dataset_id, policy=args.policy, suite=args.suite, scenarios=tuple(args.scenario),
                           tags=tuple(t for t in args.tags.split(",") if t), split=args.split, seeds=args.seeds,
                           env=args.env, max_tracks=args.max_tracks, root=Path(args.root) if args.root else None)
    dest, episodes = write_dataset(config)
    _status(f"deint: wrote {episodes} episodes to {dest} (minari.load_dataset({args.dataset_id!r}) with "
            f"MINARI_DATASETS_PATH={dest.parents[len(Path(args.dataset_id).parts) - 1]})")
    return 0


# ---------------------------------------------------------------------------------------------------
# deint tdc
# ---------------------------------------------------------------------------------------------------
def _add_tdc(sub) -> None:
    p = sub.add_parser("tdc", help="Turing Deinterleaving Challenge files (HDF5): convert",
                       description="Files of the Turing Deinterleaving Challenge (needs the [tdc] extra); "
                                   "`deint label` and `deint score` also read and write them directly.")
    actions = p.add_subparsers(dest="tdc_command", metavar="ACTION", required=True)
    c = actions.add_parser("convert", help="convert a pulse file between CSV and a TDC .h5 file",
                           description="Convert INPUT to OUTPUT, one a pulse CSV (toa[,amplitude][,source]) and "
                                       "the other a TDC file (.h5/.hdf5: data with its feature names, int8 "
                                       "labels, -1 = spurious).  TDC features other than toa and amplitude do "
                                       "not fit a pulse CSV and are dropped (the status line names them).")
    c.add_argument("input", metavar="INPUT")
    c.add_argument("output", metavar="OUTPUT")
    c.add_argument("--float64", action="store_true",
                   help="write TDC data as float64 (exact TOAs) instead of the challenge's float32")
    c.set_defaults(func=cmd_tdc_convert)


def cmd_tdc_convert(args: argparse.Namespace) -> int:
    _check_paths({"INPUT": args.input}, {"OUTPUT": args.output})
    _status("deint: " + tdc.convert(args.input, args.output, "float64" if args.float64 else "float32"))
    return 0


# ---------------------------------------------------------------------------------------------------
# the parser and main
# ---------------------------------------------------------------------------------------------------
# One parser builder per subcommand, in help order: a builder adds its subparser and sets `func` to a
# `cmd_*(args) -> int`.
SUBCOMMANDS: list[Callable[[Any], None]] = [_add_simulate, _add_label, _add_score, _add_run, _add_suites,
                                            _add_policies, _add_leaderboard, _add_reproduce, _add_train, _add_tune,
                                            _add_dataset, _add_import_sb3, _add_tdc, _add_plot]


class _VersionAction(argparse.Action):
    """`--version`, as argparse's "version" action prints it, reading the installed version only when asked
    (importlib.metadata: start-up time of every other command)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="show program's version number and exit")

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from deint_env.version import __version__

        print(f"deint-bench {__version__}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="deint", description="deint-bench: pulse-train deinterleaving benchmark.")
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in SUBCOMMANDS:
        add(sub)
    return parser


def _defer_unused_numpy_modules() -> None:
    """Make numpy.f2py and numpy.testing lazy modules (executed on their first attribute use).

    numba's BLAS check imports scipy.linalg, and scipy 1.17's array-API shim copies every public
    attribute of numpy, which imports those two: 0.12 s of a 1-s `deint label` (numpy.f2py compiles
    its Fortran-parsing regexes), for modules the command never uses.  Only the command does this: a
    library user's process keeps numpy's own import behaviour."""
    import importlib.util

    import numpy

    for name in ("numpy.f2py", "numpy.testing"):
        if name in sys.modules:
            continue
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            continue
        spec.loader = importlib.util.LazyLoader(spec.loader)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        setattr(numpy, name.rpartition(".")[2], module)  # as the import system does for a submodule


def main(argv: list[str] | None = None) -> int:
    """Run `deint`; returns the exit status (the console script passes it to sys.exit)."""
    _defer_unused_numpy_modules()
    if isinstance(sys.stdout, io.TextIOWrapper):  # an ASCII stdout (PYTHONIOENCODING=ascii) and the help's 'Δ'
        sys.stdout.reconfigure(errors="backslashreplace")
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # --help, --version and usage errors: argparse has printed them
        return 0 if e.code is None else e.code if isinstance(e.code, int) else EXIT_ERROR
    try:
        return args.func(args)
    except DeintError as e:
        print(f"deint: error: {str(e).replace(chr(10), ' ')}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt as e:
        print(f"deint: {e.args[0] if e.args else 'interrupted'}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. `deint suites | head`: the reader left; not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:  # a file the formats layer does not open itself (e.g. a results file)
        what = f"{e.filename}: {e.strerror}" if e.filename and e.strerror else str(e)
        print(f"deint: error: {what}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())

"""Evaluating policies on scenarios and suites (DESIGN sections 5-6).

`evaluate(policies, target)` runs every (scenario, seed, policy) job of a suite split on a local
process pool (or, with `executor="ray"`, as tasks on a Ray instance or cluster: the same records but
for the wall-clock `us_per_pulse`), writes one JSON line per finished episode as it goes, and skips
the jobs already in the file, so an interrupted run resumes where it stopped.  A job plays the policy through the env
(`play`): the policy sees only observations and the public priors (oracles also get the episode) and
its compute time is measured.  Each record also carries the episode's genie and random accuracies,
so the normalised score (acc - random) / (genie - random) needs nothing else.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from deint_env.envs.deinterleave import DeinterleaveEnv
from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.labels import correct_anchored, correct_link
from deint_env.metrics import AGGREGATES, estimation_metrics, matched_labels, normalised_score, stratified_bootstrap
from deint_env.policies import Policy, canonical_spec, is_oracle, make_policy, parse_policy_spec
from deint_env.progress import Progress
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.suites import find_entry, list_suites, load_suite

SPLITS = ("test", "train")
EXECUTORS = ("local", "ray")


# ---------------------------------------------------------------------------------------------------
# one episode
# ---------------------------------------------------------------------------------------------------
@dataclass
class PlayResult:
    labels: np.ndarray
    metrics: dict[str, Any]
    estimates: dict[str, np.ndarray] | None
    seconds: float  # the policy's own time: reset + every act


def play(policy: Policy, episode: Episode, *, policy_seed: int = 0, oracle: bool = False,
         clustering: bool = True) -> PlayResult:
    """Run `policy` over `episode` through the env; the policy sees observations and public priors."""
    env = DeinterleaveEnv.for_episode(episode, lag=policy.lag, clustering_metrics=clustering)
    obs, info = env.load_episode(episode)
    info["policy_seed"] = int(policy_seed)
    if oracle:
        info["episode"] = episode
    priors = Priors.from_info(info["priors"])
    clock = time.perf_counter
    t0 = clock()
    policy.reset(priors, info)
    spent = clock() - t0
    step, act = env.step, policy.act
    while True:
        t0 = clock()
        action = act(obs)
        spent += clock() - t0
        obs, _, terminated, _, info = step(action)
        if terminated:
            break
    estimates = None
    if hasattr(policy, "estimates"):
        est = policy.estimates()
        estimates = {k: np.asarray(v, dtype=np.float64) for k, v in est.items()} if est is not None else None
    return PlayResult(env.labels.copy(), env.metrics(), estimates, spent)


def accuracy_of(labels: np.ndarray, episode: Episode) -> float:
    """The env's reward rule, averaged: anchored label accuracy, or link accuracy in blind mode."""
    rule = correct_link if episode.blind else correct_anchored
    return float(np.mean(rule(labels, episode.source, episode.mask, episode.n_labels)))


def reference_accuracies(episode: Episode) -> tuple[float, float]:
    """(genie, random) accuracy on this episode; random labels are seeded by the episode's seed."""
    from baselines.genie import episode_genie_labels

    rng = np.random.default_rng([episode.seed, 0x7A4D0])
    random_labels = rng.integers(0, episode.n_labels + 1, len(episode))
    return accuracy_of(episode_genie_labels(episode), episode), accuracy_of(random_labels, episode)


# ---------------------------------------------------------------------------------------------------
# jobs and records
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Job:
    policy: str
    scenario: dict[str, Any]  # the spec as a dict: jobs cross process boundaries
    seed: int
    split: str
    suite: str | None = None
    suite_hash: str | None = None
    tags: tuple[str, ...] = ()
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> tuple:
        return record_key({"policy": self.policy, "scenario": self.scenario["name"], "seed": self.seed,
                           "scenario_hash": ScenarioSpec.from_dict(self.scenario).content_hash})


def record_key(r: dict[str, Any]) -> tuple:
    return r["policy"], r["scenario"], r["scenario_hash"], r["seed"]


def resolve_target(target: str) -> list[tuple[str | None, str | None, Any]]:
    """A suite name -> all its entries; a scenario name -> that one entry (with its suite)."""
    if target in list_suites():
        suite = load_suite(target)
        return [(suite.name, suite.content_hash, e) for e in suite]
    suite_name = target.split("/", 1)[0] if "/" in target else None
    entry = find_entry(target)
    if suite_name is None:
        suite_name = next(s for s in list_suites() if any(e.name == entry.name for e in load_suite(s)))
    return [(suite_name, load_suite(suite_name).content_hash, entry)]


def make_jobs(policies: Iterable[str], target: str, split: str = "test", max_seeds: int | None = None) -> list[Job]:
    if split not in SPLITS:
        raise DeintError(f"split={split!r} is invalid: one of {', '.join(SPLITS)}")
    canon = []
    for p in policies:
        name, kwargs = parse_policy_spec(p)
        make_policy(p)  # fail now, with one line, on an unknown policy or parameter
        canon.append(canonical_spec(name, kwargs))
    jobs = []
    for suite, suite_hash, entry in resolve_target(target):
        seeds = list(entry.test if split == "test" else entry.train)
        if max_seeds is not None:
            seeds = seeds[:max_seeds]
        spec = entry.spec.to_dict()
        for policy in canon:
            jobs.extend(Job(policy, spec, s, split, suite, suite_hash, entry.tags, entry.settings) for s in seeds)
    return jobs


def run_job(job: Job) -> dict[str, Any]:
    """Play one job and return its record (a flat, JSON-ready dict)."""
    from deint_env import __version__

    spec = ScenarioSpec.from_dict(job.scenario)
    policy = make_policy(job.policy)
    episode = simulate(spec, job.seed)
    rec: dict[str, Any] = {
        "suite": job.suite, "suite_hash": job.suite_hash, "scenario": spec.name,
        "scenario_hash": spec.content_hash, "tags": list(job.tags), "settings": job.settings,
        "split": job.split, "seed": job.seed, "policy": job.policy, "oracle": is_oracle(job.policy),
        "lag": policy.lag, "n_sources": episode.truth.n_sources, "version": __version__,
    }
    try:
        res = play(policy, episode, policy_seed=job.seed, oracle=is_oracle(job.policy))
    except NotApplicable as e:  # outside the policy's scope: recorded, so a rerun does not retry it
        return json_ready({**rec, "applicable": False, "reason": str(e)})
    rec["applicable"] = True
    genie_acc, random_acc = reference_accuracies(episode)
    rec.update(res.metrics)
    rec.update(genie_accuracy=genie_acc, random_accuracy=random_acc,
               score=normalised_score(res.metrics["accuracy"], random_acc, genie_acc))
    if res.estimates is not None:
        mapping = None
        if episode.blind:  # track i estimates the source the Hungarian matching gives it
            lut = matched_labels(res.labels, episode.source, episode.n_labels)
            mapping = _label_of_source(res.labels, lut, episode.truth.n_sources, episode.n_labels)
        rec.update(estimation_metrics(res.estimates, episode.truth, episode.priors.jitter_std, mapping))
    rec["us_per_pulse"] = 1e6 * res.seconds / max(len(episode), 1)
    return json_ready(rec)


def _label_of_source(labels: np.ndarray, mapped: np.ndarray, n_sources: int, n_labels: int) -> np.ndarray:
    out = np.full(n_sources, -1)
    for lab, src in zip(labels.tolist(), mapped.tolist()):
        if src < n_sources and lab < n_labels:
            out[src] = lab
    return out


def json_ready(x: Any) -> Any:
    """Plain JSON types; NaN and infinities become null (strict JSON has neither)."""
    if isinstance(x, dict):
        return {k: json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_ready(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def read_records(path: str | os.PathLike) -> list[dict[str, Any]]:
    """Records of a results file.  A torn last line (a run killed mid-write) is cut off the file."""
    path = Path(path)
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.split("\n")
    records = []
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            if n == len(lines):  # the unterminated last line: drop it, keep everything before
                good = text[: len(text) - len(line)]
                tmp = path.with_name(path.name + ".tmp")
                tmp.write_text(good)
                os.replace(tmp, path)
                break
            raise DeintError(f"{path}: line {n} is not a JSON record; fix or remove it") from None
    return records


# ---------------------------------------------------------------------------------------------------
# many episodes
# ---------------------------------------------------------------------------------------------------
def _ignore_sigint() -> None:  # workers leave Ctrl-C to the parent, which stops them cleanly
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def evaluate(policies: Iterable[str], target: str, *, split: str = "test", max_seeds: int | None = None,
             workers: int = 1, out: str | os.PathLike | None = None, progress: bool = True,
             executor: str = "local", address: str | None = None) -> list[dict[str, Any]]:
    """Run every job of `target` for every policy; return their records (resumed ones included).

    With `out`, finished episodes are appended to that JSON-lines file as they complete and jobs
    already in it are not run again.  `executor="local"` plays the jobs in this process (workers=1)
    or on a local process pool; `executor="ray"` submits them as Ray tasks (see `_run_ray`) to a Ray
    instance started here with `workers` CPUs, or to the cluster at `address` ("auto" = the one this
    machine belongs to).  Either way the records are the same but for the wall-clock us_per_pulse.
    """
    if not isinstance(workers, int) or workers < 1:
        raise DeintError(f"workers={workers!r} is invalid: an integer >= 1")
    if executor not in EXECUTORS:
        raise DeintError(f"executor={executor!r} is invalid: one of {', '.join(EXECUTORS)}")
    if address is not None and executor != "ray":
        raise DeintError(f"address={address!r} needs executor='ray' (a Ray cluster address)")
    jobs = make_jobs(policies, target, split, max_seeds)
    wanted = {j.key for j in jobs}
    existing = [r for r in read_records(out) if record_key(r) in wanted] if out else []
    have = {record_key(r) for r in existing}
    todo = [j for j in jobs if j.key not in have]
    records = list(existing)
    sink = open(out, "a") if out else None
    bar = Progress(len(todo), desc=f"{target}", enabled=progress)

    def keep(rec: dict[str, Any]) -> None:
        records.append(rec)
        if sink is not None:
            sink.write(json.dumps(rec, sort_keys=True) + "\n")  # one write per line: never a torn record
            sink.flush()
        bar.update()

    try:
        if executor == "ray" and todo:
            _run_ray(todo, workers, keep, address)
        elif workers == 1 or len(todo) <= 1:
            for job in todo:
                keep(run_job(job))
        else:
            _run_pool(todo, workers, keep)
    except KeyboardInterrupt:
        bar.close()
        saved = f"; {len(records)} of {len(jobs)} episodes are saved in {out}, rerun to resume" if out else ""
        raise KeyboardInterrupt(f"interrupted{saved}") from None
    finally:
        if sink is not None:
            sink.close()
    bar.close()
    return records


def _run_pool(todo: list[Job], workers: int, keep) -> None:
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_ignore_sigint)
    try:
        pending = {pool.submit(run_job, j) for j in todo}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                keep(f.result())
    except BaseException:
        for f in pending:
            f.cancel()
        for proc in list(getattr(pool, "_processes", {}).values()):  # running jobs are not worth waiting for
            proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _run_ray(todo: list[Job], workers: int, keep, address: str | None) -> None:
    """Play the jobs as Ray tasks and `keep` each record as it arrives (in completion order).

    Without `address` a private Ray instance with `workers` CPUs is started and shut down at the end;
    with one, the cluster there is joined (its nodes need deint-bench installed) and left running.
    If Ray is already initialised in this process, that instance is used as it is.  At most four
    tasks per cluster CPU are in flight, so an interrupt cancels little and memory stays flat.
    """
    try:
        import ray
    except ImportError:
        raise DeintError("executor 'ray' needs ray: pip install 'deint-bench[ray]'") from None
    import logging

    started = not ray.is_initialized()
    if started:
        try:
            if address is None:
                ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING)
            else:
                ray.init(address=address, logging_level=logging.WARNING)
        except ConnectionError as e:
            raise DeintError(f"cannot reach a Ray cluster at {address!r} ({e})") from None
    task = ray.remote(num_cpus=1, max_retries=0)(run_job)
    pending: list[Any] = []
    try:
        window = max(4 * int(ray.cluster_resources().get("CPU", workers)), 1)
        queue = iter(todo)
        for job in queue:
            pending.append(task.remote(job))
            if len(pending) >= window:
                break
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                try:
                    rec = ray.get(ref)
                except ray.exceptions.RayTaskError as e:  # the job's own error, as the pool raises it
                    cause = getattr(e, "cause", None)
                    raise (cause if isinstance(cause, Exception) else e) from None
                keep(rec)
                nxt = next(queue, None)
                if nxt is not None:
                    pending.append(task.remote(nxt))
    except BaseException:
        for ref in pending:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()


# ---------------------------------------------------------------------------------------------------
# summaries
# ---------------------------------------------------------------------------------------------------
def summarise(records: list[dict[str, Any]], reps: int = 2000, seed: int = 0) -> list[dict[str, Any]]:
    """Per policy: episode count, mean metrics, and the normalised score's mean and IQM with
    stratified-bootstrap 95 % intervals (strata = scenarios).  Episodes a policy cannot play (not
    applicable) are left out of its scores and counted in `coverage`."""
    rows = []
    for policy in sorted({r["policy"] for r in records}):
        every = [r for r in records if r["policy"] == policy]
        rs = [r for r in every if r.get("applicable", True)]
        strata: dict[str, list[float]] = {}
        for r in rs:
            if r.get("score") is not None:
                strata.setdefault(r["scenario"], []).append(r["score"])
        row: dict[str, Any] = {"policy": policy, "episodes": len(rs), "coverage": len(rs) / len(every),
                               "oracle": bool(every[0].get("oracle"))}
        for name, fn in AGGREGATES.items():
            point, lo, hi = stratified_bootstrap([np.array(v) for v in strata.values()], fn, reps, seed)
            row[f"score_{name}"], row[f"score_{name}_low"], row[f"score_{name}_high"] = point, lo, hi
        for key in ("accuracy", "matched_accuracy", "mean_pe", "v_measure", "ari", "period_rel_error",
                    "period_crlb_ratio", "us_per_pulse", "lag"):
            vals = [r[key] for r in rs if r.get(key) is not None]
            row[key] = float(np.mean(vals)) if vals else math.nan
        rows.append(row)
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    head = ["policy", "episodes", "coverage", "accuracy", "score IQM [95% CI]", "score mean", "mean P_e",
            "V-measure", "us/pulse", "lag"]
    def f(v: float, spec: str = ".3f") -> str:
        return "-" if v is None or not math.isfinite(v) else format(v, spec)

    body = []
    for r in rows:
        name = r["policy"] + (" (oracle)" if r["oracle"] else "")
        body.append([name, str(r["episodes"]), f"{r['coverage']:.0%}", f(r["accuracy"]),
                     f"{f(r['score_iqm'])} [{f(r['score_iqm_low'])}, {f(r['score_iqm_high'])}]",
                     f(r["score_mean"]), f(r["mean_pe"]), f(r["v_measure"]), f(r["us_per_pulse"], ".1f"),
                     f(r["lag"], ".0f")])
    widths = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(b, widths)) for b in body]
    return "\n".join(lines)

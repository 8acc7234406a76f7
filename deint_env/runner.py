"""Evaluating policies on scenarios and suites (docs/design.md sections 5-6).

`evaluate(policies, target)` runs every (scenario, seed, policy) job of a suite split on a local
process pool (or, with `executor="ray"`, as tasks on a Ray instance or cluster: the same records but
for the wall-clock `us_per_pulse`), appends one `EpisodeRecord` line per finished episode to a results
file as it goes (holding the file's writer lock, see `deint_env.results`), and skips the jobs already
in it, so an interrupted run resumes where it stopped.  Records are keyed on the policy's canonical
spec and its registry `version`: records of another version are stale and replayed, never mixed in.

A job plays the policy through the env (`play`): the policy sees only observations and the public
priors (oracles also get the episode) and its compute time is measured.  A policy that plays episodes
in lock-step (`deint_env.policies.BatchPolicy`: the `agent` family) has its jobs grouped into batches,
one worker task each (`make_tasks`), played by `play_batch` with the labels each would get alone; each
of a batch's records carries the batch's compute time per pulse.  Each record also carries the
episode's genie and random accuracies, so the normalised score (acc - random) / (genie - random) needs
nothing else.  A policy that fails on an episode -- an exception, a label that is not an exact integer
in range, a worker process that dies -- gets a fault record for it (its error, one line) and the run
goes on; the summary lists faults and a rerun retries them.

Pool workers ignore Ctrl-C (the parent stops them) and, on Linux, ask the kernel to kill them when the
parent dies (prctl PR_SET_PDEATHSIG), so a killed run leaves no workers behind.  Elsewhere a killed
parent's workers end when they next find the pool's queues gone.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import sys
from collections import Counter, deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from deint_env.aggregate import aggregate_entry
from deint_env.episode import Episode
from deint_env.errors import DeintError, NotApplicable
from deint_env.labels import correct_anchored, correct_link
from deint_env.metrics import estimation_metrics, matched_labels, normalised_score
from deint_env.play import PlayResult, play, play_batch  # also this module's API (docs/api.md)
from deint_env.policies import (BatchPolicy, Policy, canonical_spec, is_oracle, make_policy, parse_policy_spec,
                                spec_version)
from deint_env.progress import progress_bar
from deint_env.results import EpisodeRecord, RecordKey, ResultsWriter, json_ready, read_records, results_lock
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.stats import MIN_SEEDS, have_rliable
from deint_env.suites import SPLITS, find_entry, list_suites, load_suite
from deint_env.tables import entry_table
from deint_env.version import __version__

EXECUTORS = ("local", "ray")


# ---------------------------------------------------------------------------------------------------
# one episode (`play`, `play_batch`: deint_env.play)
# ---------------------------------------------------------------------------------------------------
def accuracy_of(labels: np.ndarray, episode: Episode) -> float:
    """The env's reward rule, averaged: anchored label accuracy, or link accuracy in blind mode."""
    rule = correct_link if episode.blind else correct_anchored
    return float(np.mean(rule(labels, episode.source, episode.mask, episode.n_labels)))


def reference_accuracies(episode: Episode) -> tuple[float, float]:
    """(genie, random) accuracy on this episode; random labels are seeded by the episode's seed."""
    from deint_env.oracle import episode_genie_labels

    rng = np.random.default_rng([episode.seed, 0x7A4D0])
    random_labels = rng.integers(0, episode.n_labels + 1, len(episode))
    return accuracy_of(episode_genie_labels(episode), episode), accuracy_of(random_labels, episode)


# ---------------------------------------------------------------------------------------------------
# jobs
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
    policy_version: int | str = 1

    @property
    def key(self) -> RecordKey:
        return RecordKey(self.policy, self.scenario["name"], ScenarioSpec.from_dict(self.scenario).content_hash,
                         self.seed, self.policy_version)


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
    canon = []
    for p in policies:
        name, kwargs = parse_policy_spec(p)
        policy = make_policy(p)  # fail now, with one line, on an unknown policy or parameter
        canon.append((canonical_spec(name, kwargs), spec_version(p, policy)))
    return target_jobs(canon, target, split, max_seeds)


def target_jobs(canon: list[tuple[str, int | str]], target: str, split: str = "test",
                max_seeds: int | None = None) -> list[Job]:
    """The jobs of every (policy name, version) in `canon` on every seed of `target`'s `split`."""
    if split not in SPLITS:
        raise DeintError(f"split={split!r} is invalid: one of {', '.join(SPLITS)}")
    if max_seeds is not None and (not isinstance(max_seeds, int) or isinstance(max_seeds, bool) or max_seeds < 1):
        raise DeintError(f"max_seeds={max_seeds!r} is invalid: an integer >= 1 (or None: every seed)")
    jobs = []
    for suite, suite_hash, entry in resolve_target(target):
        seeds = list(entry.seeds(split))
        if max_seeds is not None:
            seeds = seeds[:max_seeds]
        spec = entry.spec.to_dict()
        for policy, version in canon:
            jobs.extend(Job(policy, spec, s, split, suite, suite_hash, entry.tags, entry.settings, version)
                        for s in seeds)
    return jobs


def one_line(e: BaseException) -> str:
    """An error as one line: its type and the first line of its message."""
    text = str(e).strip().splitlines()
    return type(e).__name__ + (f": {text[0]}" if text else "")


def _record(job: Job, spec: ScenarioSpec, oracle: bool | None = None, **fields: Any) -> EpisodeRecord:
    """`oracle`: None reads the registry (a policy given as an object is named by the caller, not registered)."""
    return EpisodeRecord(
        policy=job.policy, scenario=spec.name, scenario_hash=spec.content_hash, seed=job.seed, split=job.split,
        suite=job.suite, suite_hash=job.suite_hash, tags=tuple(job.tags), settings=job.settings,
        oracle=is_oracle(job.policy) if oracle is None else oracle, version=__version__,
        policy_version=job.policy_version, **fields)


def fault_record(job: Job, error: str) -> EpisodeRecord:
    """The record of an episode the policy failed on (`error`: one line); the run goes on without it."""
    spec = ScenarioSpec.from_dict(job.scenario)
    return _record(job, spec, lag=None, n_sources=simulate(spec, job.seed).truth.n_sources, fault=error)


# A local pool forks its workers at once (the fork start method): 10^5 asked for would fork 10^5 processes
MAX_WORKERS = 1024

# The (policy spec, scenario) pairs this process has played.  A compiled (numba) policy's first play in a
# process loads its kernels from the cache, or compiles them: ~0.5 s (seconds in a fresh clone) that would
# be timed as that episode's (500 us a pulse on a 1000-pulse episode, more than the policy's own time over
# a whole board).  Some kernels are first called only by some episodes (mht's FDP start when priors fail
# their test), so each spec plays the job's own episode untimed first, once per scenario (an episode of
# more than _WARM_FULL pulses: its scenario's first _WARM_PULSES, which call nearly all of them).
_WARMED: set[tuple[str, str]] = set()
_WARM_FULL = 5000
_WARM_PULSES = 200


def _warm_up(job: Job, spec: ScenarioSpec, episode: Episode) -> None:
    """The untimed first play of `job.policy` on the job's scenario in this process (see _WARMED).  Its
    result is never used, so its failure is not the job's: the timed play that follows meets any fault of
    the policy itself."""
    if (job.policy, spec.name) in _WARMED:
        return
    _WARMED.add((job.policy, spec.name))
    try:
        warm = episode if len(episode) <= _WARM_FULL else simulate(replace(spec, n_pulses=_WARM_PULSES), job.seed)
        play(make_policy(job.policy), warm, policy_seed=job.seed, oracle=is_oracle(job.policy), clustering=False)
    except Exception:  # noqa: BLE001 -- its outcome is discarded (docstring)
        pass


def run_job(job: Job, policy: Policy | None = None) -> EpisodeRecord:
    """Play one job and return its record.  A policy's exception (or a bad label) is its fault on this
    episode: recorded, not raised.  The time recorded is the policy's compute time (`play`), after a
    warm-up play in a process that has not played the policy on this scenario yet (`_warm_up`).
    `policy`: an object to play instead of building `job.policy` from the registry (`job.policy` is then
    only its name; it is not an oracle and gets no warm-up: rebuilding it is the registry's job)."""
    spec = ScenarioSpec.from_dict(job.scenario)
    episode = simulate(spec, job.seed)
    n_sources = episode.truth.n_sources
    lag = None
    oracle = False if policy is not None else is_oracle(job.policy)
    if policy is None:
        _warm_up(job, spec, episode)
    try:
        if policy is None:
            policy = make_policy(job.policy)
        lag = policy.lag
        res = play(policy, episode, policy_seed=job.seed, oracle=oracle)
    except NotApplicable as e:  # outside the policy's scope: recorded, so a rerun does not retry it
        return _record(job, spec, oracle, lag=lag, n_sources=n_sources, applicable=False, reason=str(e))
    except Exception as e:  # noqa: BLE001 -- any failure of the policy is recorded for its episode
        return _record(job, spec, oracle, lag=lag, n_sources=n_sources, fault=one_line(e))
    return _played_record(job, spec, episode, res, oracle, lag)


def _played_record(job: Job, spec: ScenarioSpec, episode: Episode, res: PlayResult, oracle: bool,
                   lag: int) -> EpisodeRecord:
    """The record of a played episode: its metrics, normalised score, estimation errors and time."""
    n_sources = episode.truth.n_sources
    genie_acc, random_acc = reference_accuracies(episode)
    metrics: dict[str, Any] = dict(res.metrics)
    metrics.pop("lag", None)  # the env reports it; the record holds it once, as its field (as a results file does)
    metrics.update(genie_accuracy=genie_acc, random_accuracy=random_acc,
                   score=normalised_score(res.metrics["accuracy"], random_acc, genie_acc))
    if res.estimates is not None:
        mapping = None
        if episode.blind:  # track i estimates the source the Hungarian matching gives it
            lut = matched_labels(res.labels, episode.source, episode.n_labels)
            mapping = _label_of_source(res.labels, lut, episode.truth.n_sources, episode.n_labels)
        metrics.update(estimation_metrics(res.estimates, episode.truth, episode.priors.jitter_std, mapping))
    metrics["us_per_pulse"] = 1e6 * res.seconds / max(len(episode), 1)
    return _record(job, spec, oracle, lag=lag, n_sources=n_sources, metrics=json_ready(metrics))


# How many episodes of one policy a worker task plays in lock-step when the policy is a BatchPolicy: the
# per-step costs shared (the features' numpy calls, the forward pass's call) fall with the batch, and 64
# holds a core-v0 board's first test seeds (45) in one batch.
BATCH = 64


def batch_size(spec: str) -> int:
    """How many of `spec`'s jobs one task plays together: BATCH for a BatchPolicy (no oracle, no
    `estimates()`, which a batched play does not collect), else 1.  Builds the policy once."""
    if is_oracle(spec):
        return 1
    try:
        policy = make_policy(spec)
    except Exception:  # noqa: BLE001 -- a policy that cannot be built plays alone and gets its faults there
        return 1
    return BATCH if isinstance(policy, BatchPolicy) and not hasattr(policy, "estimates") else 1


def run_batch(jobs: Sequence[Job]) -> list[EpisodeRecord]:
    """Play jobs of one BatchPolicy spec in lock-step (`play_batch`) and return their records, in order,
    each with the batch's time per pulse (after an untimed warm-up batch of the scenarios this process
    has not played the spec on, as `run_job` warms up).  If the batch fails (an exception, a bad label),
    every job is played alone (`run_job`), so the fault is recorded for the episode that causes it and
    the others get the records playing alone gives."""
    specs = [ScenarioSpec.from_dict(j.scenario) for j in jobs]
    episodes = [simulate(s, j.seed) for s, j in zip(specs, jobs)]
    name = jobs[0].policy
    cold = [i for i, s in enumerate(specs) if (name, s.name) not in _WARMED]
    if cold:
        _WARMED.update((name, specs[i].name) for i in cold)
        warm = [episodes[i] if len(episodes[i]) <= _WARM_FULL else
                simulate(replace(specs[i], n_pulses=_WARM_PULSES), jobs[i].seed) for i in cold]
        with contextlib.suppress(Exception):  # its outcome is discarded, as _warm_up's
            play_batch(make_policy(name), warm, policy_seeds=[jobs[i].seed for i in cold], clustering=False)
    try:
        policy = make_policy(name)
        results = play_batch(policy, episodes, policy_seeds=[j.seed for j in jobs])
    except Exception:  # noqa: BLE001 -- replayed alone, where a fault is its own episode's
        return [run_job(j) for j in jobs]
    return [_record(j, s, False, lag=policy.lag, n_sources=e.truth.n_sources, applicable=False, reason=str(r))
            if isinstance(r, NotApplicable) else _played_record(j, s, e, r, False, policy.lag)
            for j, s, e, r in zip(jobs, specs, episodes, results)]


Task = tuple[Job, ...]  # what one worker call plays: one job, or a batch of one BatchPolicy spec's jobs


def run_task(task: Task) -> list[EpisodeRecord]:
    return run_batch(task) if len(task) > 1 else [run_job(task[0])]


def make_tasks(jobs: Sequence[Job], workers: int = 1) -> list[Task]:
    """The jobs as worker tasks: a BatchPolicy spec's jobs (`batch_size`) in near-equal batches of at most
    BATCH, at least `workers` of them when it has that many jobs (so every worker gets one), each batch
    where its first job was in the queue; every other job alone, where it was."""
    starting: dict[int, Task] = {}  # id(first job) -> its task
    for spec in dict.fromkeys(j.policy for j in jobs):
        mine = [j for j in jobs if j.policy == spec]
        most = batch_size(spec) if len(mine) > 1 else 1
        size = -(-len(mine) // min(max(-(-len(mine) // most), workers), len(mine))) if most > 1 else 1
        starting.update((id(mine[i]), tuple(mine[i:i + size])) for i in range(0, len(mine), size))
    return [starting[id(j)] for j in jobs if id(j) in starting]


def _label_of_source(labels: np.ndarray, mapped: np.ndarray, n_sources: int, n_labels: int) -> np.ndarray:
    out = np.full(n_sources, -1)
    for lab, src in zip(labels.tolist(), mapped.tolist()):
        if src < n_sources and lab < n_labels:
            out[src] = lab
    return out


# ---------------------------------------------------------------------------------------------------
# many episodes
# ---------------------------------------------------------------------------------------------------
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _worker_init(parent: int) -> None:
    """Pool workers leave Ctrl-C to the parent (which stops them) and die with it (Linux)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        if os.getppid() != parent:  # the parent died before the request took effect
            os._exit(1)


def check_workers(workers: Any) -> None:
    """One line for a worker count that is not an integer in [1, MAX_WORKERS]."""
    if not isinstance(workers, int) or isinstance(workers, bool) or not 1 <= workers <= MAX_WORKERS:
        raise DeintError(f"workers={workers!r} is invalid: an integer in [1, {MAX_WORKERS}]")


def evaluate(policies: Iterable[str], target: str, *, split: str = "test", max_seeds: int | None = None,
             workers: int = 1, out: str | os.PathLike | None = None, progress: bool = True,
             executor: str = "local", address: str | None = None) -> list[EpisodeRecord]:
    """Run every job of `target` for every policy; return their records (resumed ones included).

    With `out`, finished episodes are appended to that results file as they complete (another process
    writing it is refused with one line) and its records of these jobs are not played again (faults
    aside: those are retried).  `executor="local"` plays the jobs in this process (workers=1) or on a
    local process pool; `executor="ray"` submits them as Ray tasks (see `_run_ray`) to a Ray instance
    started here with `workers` CPUs, or to the cluster at `address` ("auto" = the one this machine
    belongs to).  Either way the records are the same but for the wall-clock us_per_pulse.  Locally, a
    BatchPolicy's jobs are played in batches (`make_tasks`: one task per batch); Ray plays every job alone.
    """
    check_workers(workers)
    if executor not in EXECUTORS:
        raise DeintError(f"executor={executor!r} is invalid: one of {', '.join(EXECUTORS)}")
    if address is not None and executor != "ray":
        raise DeintError(f"address={address!r} needs executor='ray' (a Ray cluster address)")
    jobs = make_jobs(policies, target, split, max_seeds)
    with results_lock(out) if out else contextlib.nullcontext():
        wanted = {j.key for j in jobs}
        records = [r for r in read_records(out) if r.key in wanted and r.fault is None] if out else []
        have = {r.key for r in records}
        todo = [j for j in jobs if j.key not in have]
        sink = ResultsWriter(out) if out else None
        bar = progress_bar(len(todo), desc=target, enabled=progress)

        def keep(rec: EpisodeRecord) -> None:
            if sink is not None:
                sink.append(rec)
            if rec.fault is None:
                records.append(rec)
            else:
                faults.append(rec)
            bar.update(1)

        faults: list[EpisodeRecord] = []
        try:
            if executor == "ray" and todo:
                _run_ray(todo, workers, keep, address)
            elif workers == 1 or len(todo) <= 1:
                for task in make_tasks(todo):
                    for rec in run_task(task):
                        keep(rec)
            else:
                _run_pool(make_tasks(todo, workers), workers, keep)
        except KeyboardInterrupt:
            bar.close()
            saved = ""
            if sink is not None:  # count what reached the file: the interrupt may land between a write and its tally
                sink.close()
                sink = None
                kept = sum(1 for r in read_records(out) if r.key in wanted and r.fault is None)
                saved = f"; {kept} of {len(jobs)} episodes are saved in {out}, rerun to resume"
            raise KeyboardInterrupt(f"interrupted{saved}") from None
        finally:
            bar.close()
            if sink is not None:
                sink.close()
    return records + faults


@contextlib.contextmanager
def _pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A process pool that, on any exception (Ctrl-C included), is stopped without waiting for its
    running jobs.  Futures are never cancelled by hand: the pool's manager thread would then fail
    setting their result (InvalidStateError: CANCELLED) when the terminated workers break it."""
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init, initargs=(os.getpid(),))
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            with contextlib.suppress(Exception):
                proc.terminate()
        raise
    pool.shutdown()


def _next_task(queue: deque[Task], running: Iterable[Task], played: set[str]) -> Task | None:
    """Take from `queue` the first task that may start now: one whose policy has finished a task in this
    pool (`played`: its kernels are compiled and cached) or has none in flight.  While a worker compiles a
    policy's numba kernels (seconds to a minute in a fresh clone), another worker that started the same
    policy would compile them too; it plays other policies' tasks instead.  None: every queued task waits."""
    busy = {t[0].policy for t in running} - played
    for i, task in enumerate(queue):
        if task[0].policy not in busy:
            del queue[i]
            return task
    return None


def _run_pool(todo: list[Task], workers: int, keep: Callable[[EpisodeRecord], None]) -> None:
    """Play the tasks (`make_tasks`) on a process pool, at most two per worker in flight (`_next_task`
    chooses which).  A worker that dies breaks the pool and fails every task in flight; their jobs are
    then replayed one by one, each in a pool of its own, so that only the job that kills its worker gets
    the fault."""
    queue, window = deque(todo), 2 * workers
    played: set[str] = set()
    while queue:
        suspects: list[Job] = []
        with _pool(workers) as pool:
            running: dict[Any, Task] = {}
            while queue or running:
                while queue and len(running) < window and not suspects:
                    task = _next_task(queue, running.values(), played)
                    if task is None:
                        break
                    running[pool.submit(run_task, task)] = task
                if not running:
                    break
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for f in done:
                    task = running.pop(f)
                    played.add(task[0].policy)
                    try:
                        records = f.result()
                    except BrokenProcessPool:
                        suspects.extend(task)
                        continue
                    for rec in records:
                        keep(rec)
        for job in suspects:
            with _pool(1) as alone:
                try:
                    rec = alone.submit(run_job, job).result()
                except BrokenProcessPool as e:
                    rec = fault_record(job, f"the worker process died ({one_line(e)})")
            keep(rec)


RAY_PROBE_SECONDS = 10.0
# An HTTP/2 client preface and an empty SETTINGS frame (RFC 9113 3.4, 6.5): a gRPC server (Ray's GCS, a
# Ray Client server) answers with a SETTINGS frame of its own (type 0x4) at once.
_H2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _probe_ray(address: str) -> None:
    """Fail within seconds, with one line, where joining a cluster that answers nothing would retry
    for minutes (ray.init at a port that accepts and stays silent did not return in 200 s)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise DeintError(f"address={address!r} is invalid: 'auto', HOST:PORT or ray://HOST:PORT")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_PROBE_SECONDS) as sock:
            sock.settimeout(RAY_PROBE_SECONDS)
            sock.sendall(_H2_HELLO)
            head = sock.recv(9)
    except OSError as e:
        raise DeintError(f"cannot reach a Ray cluster at {address!r} ({e.strerror or e})") from None
    if len(head) < 9 or head[3] != 4:
        raise DeintError(f"cannot reach a Ray cluster at {address!r}: it does not answer as a Ray head (gRPC) does")


def _run_ray(todo: list[Job], workers: int, keep: Callable[[EpisodeRecord], None], address: str | None) -> None:
    """Play the jobs as Ray tasks and `keep` each record as it arrives (in completion order).

    Without `address` a private Ray instance with `workers` CPUs is started and shut down at the end
    (in a `finally`, interrupts included); with one, the cluster there is joined (its nodes need
    deint-bench installed) and left running.  If Ray is already initialised in this process, that
    instance is used as it is.  At most four tasks per cluster CPU are in flight, so an interrupt
    cancels little and memory stays flat.  A task whose worker dies is that job's fault.
    """
    try:
        import ray
    except ImportError:
        raise DeintError("executor 'ray' needs ray: pip install 'deint-bench[ray]'") from None
    import logging

    started = not ray.is_initialized()
    try:
        if started:
            try:
                if address is None:
                    ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING)
                else:
                    if address != "auto":
                        _probe_ray(address)
                    ray.init(address=address, logging_level=logging.WARNING)
            except ConnectionError as e:
                raise DeintError(f"cannot reach a Ray cluster at {address!r} ({e})") from None
        task = ray.remote(num_cpus=1, max_retries=0)(run_job)
        pending: dict[Any, Job] = {}
        try:
            window = max(4 * int(ray.cluster_resources().get("CPU", workers)), 1)
            queue = deque(todo)
            while queue or pending:
                while queue and len(pending) < window:
                    job = queue.popleft()
                    pending[task.remote(job)] = job
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    job = pending.pop(ref)
                    try:
                        rec = ray.get(ref)
                    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as e:
                        rec = fault_record(job, f"the Ray worker died ({one_line(e)})")
                    except ray.exceptions.RayTaskError as e:  # the job's own error, as the pool raises it
                        cause = getattr(e, "cause", None)
                        raise (cause if isinstance(cause, Exception) else e) from None
                    keep(rec)
        except BaseException:
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            raise
    finally:
        if started and ray.is_initialized():
            ray.shutdown()


# ---------------------------------------------------------------------------------------------------
# summaries
# ---------------------------------------------------------------------------------------------------
def summarise(records: list[EpisodeRecord], reps: int = 2000, seed: int = 0) -> list[dict[str, Any]]:
    """Per policy, the row `deint_env.aggregate.aggregate_entry` makes (the leaderboard's own path):
    counts, coverage and faults, every metric of the metric table, and the normalised score's IQM and
    mean with stratified-bootstrap 95 % intervals (strata = scenarios; the intervals need rliable and
    at least `MIN_SEEDS` episodes of every scenario, and are NaN otherwise: `format_table` says why).
    Records of one scenario are taken in seed order."""
    by_policy: dict[str, list[EpisodeRecord]] = {}
    for r in sorted(records, key=lambda r: (r.policy, r.scenario, r.seed)):
        by_policy.setdefault(r.policy, []).append(r)
    rows = []
    for policy, recs in by_policy.items():
        groups = {"all": sorted({r.scenario for r in recs})}
        seeds = min(Counter(r.scenario for r in recs).values())
        intervals = have_rliable() and seeds >= MIN_SEEDS
        row = aggregate_entry(recs, groups, reps=reps, seed=seed, intervals=intervals).row
        row["seeds_per_scenario"] = seeds
        rows.append(row)
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    """`summarise`'s rows as `deint run` prints them, faulted episodes listed below."""
    out = entry_table(rows, summary=True)
    if rows and not have_rliable():
        out += "\n(no intervals: they need rliable: pip install 'deint-bench[leaderboard]')"
    elif rows and min(r["seeds_per_scenario"] for r in rows) < MIN_SEEDS:
        out += (f"\n(no intervals: {min(r['seeds_per_scenario'] for r in rows)} seed(s) per scenario; intervals "
                f"need at least {MIN_SEEDS}: a bootstrap over fewer would print zero-width intervals)")
    return out

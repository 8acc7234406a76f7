"""Interval estimates, performance profiles and probability of improvement with rliable.

rliable (Agarwal et al. 2021, the `[leaderboard]` extra) is the field's standard for honest aggregates
over few runs: the interquartile mean (IQM) and mean with stratified-bootstrap percentile intervals,
score distributions (performance profiles) with bootstrap bands, and the probability of improvement.
Here a stratum is a scenario and its samples are the scores of its test seeds.

rliable takes scores as (runs x tasks) matrices.  Strata of equal size are stacked into one matrix,
strata of another size (a policy that could not play every episode) into further ones, and all are
resampled by rliable's `StratifiedIndependentBootstrap` (each column on its own): one code path for
even and uneven strata.  Point estimates are the statistic of all scores concatenated in stratum
order, exactly as `deint_env.metrics.stratified_bootstrap` computes them (with `trim_mean25` and
`score_fractions`, rliable's arithmetic without its wrappers, so that points need no rliable).
rliable resamples with numpy's global generator (its `random_state` argument does not reach the
resampling), so every estimate seeds it and puts the previous state back: reruns give identical numbers.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from deint_env.errors import DeintError

CONFIDENCE = 0.95
NAN3 = (math.nan, math.nan, math.nan)
# fewer episodes per scenario than this: no intervals (a bootstrap over 1-2 seeds prints near-zero widths)
MIN_SEEDS = 3
TAUS = np.linspace(0.0, 1.0, 51)  # performance-profile thresholds (build computes them, plots draws them)


def rliable() -> tuple[Any, Any]:
    """rliable's `library` and `metrics` modules, or one clear line on how to install them."""
    try:
        from rliable import library, metrics
    except ImportError as e:
        raise DeintError(f"leaderboards need rliable ({e.name or 'it'} is missing): "
                         f"pip install 'deint-bench[leaderboard]'") from None
    return library, metrics


def have_rliable() -> bool:
    return importlib.util.find_spec("rliable") is not None


def rliable_version() -> str:
    from importlib.metadata import version

    return version("rliable")


@contextlib.contextmanager
def _seeded(seed: int) -> Iterator[None]:
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def _clean(strata: Sequence[Any]) -> list[np.ndarray]:
    return [a for a in (np.asarray(s, dtype=np.float64).ravel() for s in strata) if a.size]


def _blocks(strata: list[np.ndarray]) -> tuple[list[np.ndarray], list[list[int]]]:
    """(runs x tasks) matrices, one per stratum size, and the stratum index of each matrix column."""
    by_size: dict[int, list[int]] = {}
    for i, s in enumerate(strata):
        by_size.setdefault(s.size, []).append(i)
    order = [by_size[n] for n in sorted(by_size)]
    return [np.stack([strata[i] for i in idx], axis=1) for idx in order], order


# Bootstrap replicates: every replicate's statistics are kept (--reps 10^8 asked for 41 GiB); 10^5 is 50
# times rliable's 2000, far past where a 95 % interval's bounds stop moving.
MIN_REPS, MAX_REPS = 100, 100_000


def check_reps(reps: object) -> int:
    if not isinstance(reps, int) or isinstance(reps, bool) or not MIN_REPS <= reps <= MAX_REPS:
        raise DeintError(f"reps={reps!r} is invalid: an integer in [{MIN_REPS}, {MAX_REPS}] (bootstrap replicates)")
    return reps


def _bootstrap(blocks: list[np.ndarray], stat, reps: int, seed: int) -> np.ndarray:
    """rliable's percentile interval of `stat(*blocks)`: a (2, k) array of low and high bounds."""
    check_reps(reps)
    library, _ = rliable()
    with _seeded(seed):
        _, cis = library.get_interval_estimates({"x": blocks}, stat, reps=reps,
                                                confidence_interval_size=CONFIDENCE)
    return np.asarray(cis["x"], dtype=np.float64).reshape(2, -1)


def _unblock(bs: Sequence[np.ndarray], cols: list[list[int]], n: int) -> list[np.ndarray]:
    per: list[Any] = [None] * n
    for b, idx in zip(bs, cols):
        for j, i in enumerate(idx):
            per[i] = b[:, j]
    return per


Triple = tuple[float, float, float]


def estimates(strata: Mapping[str, Any], groups: Mapping[str, Sequence[str]], taus: np.ndarray | None = None,
              reps: int = 2000, seed: int = 0,
              intervals: bool = True) -> tuple[dict[str, dict[str, Triple]], tuple[np.ndarray, ...] | None]:
    """Interval estimates of one policy's scores, from one stratified bootstrap.

    `strata` maps a scenario to its scores; `groups` maps a group name (e.g. "all", a tag) to the
    scenarios it pools.  Returns ({group: {"iqm": (point, low, high), "mean": (...)}}, profile), the
    profile being (fraction of episodes scoring above each tau, low, high) -- rliable's score
    distribution with its band -- when `taus` is given.  A group with no scores gets NaN; so do the
    bounds with `intervals=False` (points only, no rliable needed).
    """
    names = [k for k in strata if np.size(strata[k])]
    arrays = _clean([strata[k] for k in names])
    where = {k: i for i, k in enumerate(names)}
    members = {g: [where[s] for s in ss if s in where] for g, ss in groups.items()}
    live = [g for g in groups if members[g]]
    out = {g: {"iqm": NAN3, "mean": NAN3} for g in groups}
    if not arrays:
        return out, None if taus is None else (np.full(len(taus), np.nan),) * 3

    def stat(per: Sequence[np.ndarray], iqm, profile) -> np.ndarray:
        parts = []
        for g in live:
            x = np.concatenate([per[i] for i in members[g]])
            parts.append([iqm(x), np.mean(x)])
        values = np.asarray(parts, dtype=np.float64).ravel()
        if taus is not None:
            values = np.concatenate([values, profile(np.concatenate(per), taus)])
        return values

    # Points: the scores in stratum order (as deint_env.metrics computes them); replicates: the same
    # arithmetic on each resample.
    points = stat(arrays, trim_mean25, score_fractions)
    if intervals:
        blocks, cols = _blocks(arrays)
        cis = _bootstrap(blocks, lambda *bs: stat(_unblock(bs, cols, len(arrays)), trim_mean25, score_fractions),
                         reps, seed)
    else:
        cis = np.full((2, points.size), np.nan)
    for k, g in enumerate(live):
        out[g] = {s: (float(points[2 * k + j]), float(cis[0, 2 * k + j]), float(cis[1, 2 * k + j]))
                  for j, s in enumerate(("iqm", "mean"))}
    if taus is None:
        return out, None
    m = 2 * len(live)
    return out, (points[m:], cis[0, m:], cis[1, m:])


def trim_mean25(x: np.ndarray) -> float:
    """scipy.stats.trim_mean(x, 0.25) (rliable's IQM) for a 1-D array, step for step, minus its wrappers."""
    n = x.size
    lo = int(0.25 * n)
    return float(np.mean(np.partition(x, (lo, n - lo - 1))[lo:n - lo]))


def score_fractions(x: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """rliable's `score_distributions(x, taus)` (the share of scores above each tau), vectorised."""
    return np.mean(x[:, None] > np.asarray(taus)[None, :], axis=0)


def improvement_pairs(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 over all pairs of one task's runs: rliable's per-task probability of
    improvement (the Mann-Whitney U statistic over n_x n_y), computed without scipy's per-call cost."""
    gt = np.count_nonzero(x[:, None] > y[None, :])
    eq = np.count_nonzero(x[:, None] == y[None, :])
    return (gt + 0.5 * eq) / (x.size * y.size)


def probability_of_improvement(x: Mapping[str, Any], y: Mapping[str, Any], reps: int = 2000,
                               seed: int = 0) -> tuple[float, float, float, int]:
    """(P(X > Y), low, high, tasks): rliable's average probability of improvement of X over Y over the
    scenarios both have scores on, with its stratified-bootstrap interval (X and Y resampled apart)."""
    library, metrics = rliable()
    tasks = [t for t in x if t in y and np.size(x[t]) and np.size(y[t])]
    if not tasks:
        return math.nan, math.nan, math.nan, 0
    xs = [np.asarray(x[t], dtype=np.float64).ravel() for t in tasks]
    ys = [np.asarray(y[t], dtype=np.float64).ravel() for t in tasks]
    point = float(np.mean([metrics.probability_of_improvement(a[:, None], b[:, None]) for a, b in zip(xs, ys)]))
    xb, xcols = _blocks(xs)
    yb, ycols = _blocks(ys)
    n_x = len(xb)

    def stat(*bs: np.ndarray) -> np.ndarray:
        px, py = _unblock(bs[:n_x], xcols, len(tasks)), _unblock(bs[n_x:], ycols, len(tasks))
        return np.array([np.mean([improvement_pairs(a, b) for a, b in zip(px, py)])])

    cis = _bootstrap(xb + yb, stat, reps, seed)
    return point, float(cis[0, 0]), float(cis[1, 0]), len(tasks)

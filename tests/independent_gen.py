"""An independent pulse-file generator for the dense-scene checks (tests/test_dense_independent.py,
benchmarks/bench_dense.py): plain numpy, deliberately not `deint_env.sim`, so that the trackers are
judged on files they were not shaped around (issue #22: a user's own generator labelled through
`deint label`).

Sources have constant PRIs, periods log-uniform in [t_min, t_max] kept 3 % apart (two sources of
equal period cannot be told apart by any tracker, the genie included), phases uniform over the first
period (at most `phase_span` time units), white Gaussian TOA jitter, each arrival missed with
probability `missing`, and spurious pulses uniform over the span, `spurious` per source pulse.  No
merging: two arrivals closer than the jitter are both received (dense scenes do that).

A cell writes `pulses.csv` (toa,source; -1 = spurious) and a priors JSON: periods 1 % off, the true
phases, the jitter, and the rates stated, left out (unknown) or stated 0.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

RATES = ("stated", "unknown", "zero")  # how the priors give the channel's rates
STATED_MISSING, STATED_SPURIOUS = 0.02, 0.02  # the "stated" column's channel; the others are clean


class Cell(NamedTuple):
    toa: np.ndarray
    source: np.ndarray  # -1: spurious
    period: np.ndarray
    phase: np.ndarray
    jitter: float
    missing: float
    spurious: float


def periods(n: int, rng: np.random.Generator, t_min: float, t_max: float, gap: float = 0.03) -> np.ndarray:
    """n periods log-uniform in [t_min, t_max], no two within `gap` (relative) of each other."""
    out: list[float] = []
    while len(out) < n:
        t = float(np.exp(rng.uniform(np.log(t_min), np.log(t_max))))
        if all(abs(t - u) > gap * min(t, u) for u in out):
            out.append(t)
    return np.array(out)


def generate(n: int, jitter_rel: float, n_pulses: int, seed: int, missing: float = 0.0, spurious: float = 0.0,
             t_min: float = 12.0, t_max: float = 160.0, phase_span: float = 64.0) -> Cell:
    """About `n_pulses` received pulses of n constant-PRI sources (the first n_pulses in time)."""
    rng = np.random.default_rng(seed)
    t = periods(n, rng, t_min, t_max)
    t[0] = t_min  # the jitter is relative to the shortest period: make it exactly t_min
    phase = rng.uniform(0.0, np.minimum(t, phase_span))
    jitter = jitter_rel * t_min
    rate = float(np.sum(1.0 / t))
    span = 1.3 * n_pulses / (rate * (1.0 - missing) * (1.0 + spurious))
    toa, src = [], []
    for i in range(n):
        arrivals = phase[i] + t[i] * np.arange(int(span / t[i]) + 1)
        kept = arrivals[rng.random(arrivals.size) >= missing]
        toa.append(kept + rng.normal(0.0, jitter, kept.size))
        src.append(np.full(kept.size, i))
    n_spur = rng.poisson(spurious * sum(a.size for a in toa))
    toa.append(rng.uniform(0.0, span, n_spur))
    src.append(np.full(n_spur, -1))
    toa, src = np.concatenate(toa), np.concatenate(src)
    order = np.argsort(toa, kind="stable")
    toa, src = toa[order][:n_pulses], src[order][:n_pulses]
    return Cell(toa, src, t, phase, jitter, missing, spurious)


def make_cell(n: int, jitter_rel: float, rates: str, n_pulses: int, seed: int) -> Cell:
    """The matrix's cell: the "stated" column's channel misses and adds pulses, the others are clean."""
    if rates not in RATES:
        raise ValueError(f"rates={rates!r} must be one of {RATES}")
    noisy = rates == "stated"
    return generate(n, jitter_rel, n_pulses, seed, STATED_MISSING if noisy else 0.0,
                    STATED_SPURIOUS if noisy else 0.0)


def priors_json(cell: Cell, rates: str, seed: int) -> dict:
    """Priors as a user states them: periods 1 % off (either way), the true phases, the jitter; the
    rates truthfully ("stated"), left out ("unknown") or stated 0 ("zero")."""
    rng = np.random.default_rng(seed + 7919)
    off = 1.0 + 0.01 * rng.choice([-1.0, 1.0], cell.period.size)
    out = {"period": (cell.period * off).tolist(), "phase": cell.phase.tolist(), "jitter_std": cell.jitter}
    if rates == "stated":
        out |= {"missing_prob": cell.missing, "spurious_rate": cell.spurious}
    elif rates == "zero":
        out |= {"missing_prob": 0.0, "spurious_rate": 0.0}
    return out


def write_cell(folder: Path, cell: Cell, priors: dict) -> tuple[Path, Path]:
    """pulses.csv (toa,source; floats as repr, exact) and priors.json in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    pulses, pri = folder / "pulses.csv", folder / "priors.json"
    pulses.write_text("toa,source\n" + "".join(f"{t!r},{s}\n" for t, s in zip(cell.toa.tolist(),
                                                                               cell.source.tolist())))
    pri.write_text(json.dumps(priors))
    return pulses, pri


def read_labels(path: Path) -> np.ndarray:
    """The label column of a `deint label` output (-1 = spurious)."""
    rows = Path(path).read_text().split("\n")[1:]
    return np.array([int(r.rsplit(",", 1)[1]) for r in rows if r.strip()], dtype=np.int64)


def accuracy(labels: np.ndarray, cell: Cell) -> float:
    """Label accuracy as `deint score` prints it (no merged pulses here: a label is right or wrong)."""
    return float(np.mean(labels == cell.source))


def true_priors(cell: Cell) -> dict:
    """The truth as priors (periods, phases, jitter and the channel's rates): what `deint label --policy
    genie` needs to label as the known-parameter ceiling does."""
    return {"period": cell.period.tolist(), "phase": cell.phase.tolist(), "jitter_std": cell.jitter,
            "missing_prob": cell.missing, "spurious_rate": cell.spurious}


def label_cli(folder: Path, pulses: Path, priors: Path, policy: str) -> np.ndarray | None:
    """`deint label PULSES --policy POLICY --priors PRIORS -o LABELS` (the command's main, in this
    process) and the labels it wrote (-1 = spurious); None when the command refused (exit status 2, e.g.
    a policy's source limit)."""
    from deint_env.cli import main

    out = folder / "labels.csv"
    status = main(["label", str(pulses), "--policy", policy, "--priors", str(priors), "-o", str(out)])
    if status == 2:
        return None
    if status != 0:
        raise RuntimeError(f"deint label --policy {policy} exited with {status} on {pulses}")
    return read_labels(out)


def run_cell(folder: Path, n: int, jitter_rel: float, rates: str, n_pulses: int, seed: int,
             policies: tuple[str, ...], refused_ok: bool = False) -> dict[str, float]:
    """One cell of the matrix: its files written to `folder`, each policy's labels through the CLI and
    their accuracy; "genie" is the known-parameter ceiling (the true parameters and rates as priors).  A
    policy the command refuses fails the cell, or scores NaN with `refused_ok`."""
    cell = make_cell(n, jitter_rel, rates, n_pulses, seed)
    pulses, priors = write_cell(folder, cell, priors_json(cell, rates, seed))
    truth = folder / "true_priors.json"
    truth.write_text(json.dumps(true_priors(cell)))
    out = {}
    for policy, path in (("genie", truth),) + tuple((p, priors) for p in policies):
        labels = label_cli(folder, pulses, path, policy)
        if labels is None and not refused_ok:
            raise RuntimeError(f"deint label refused --policy {policy} on {pulses}")
        out[policy] = math.nan if labels is None else accuracy(labels, cell)
    return out

"""An agile pulse-train generator written for the blind tests and benchmark, in plain numpy and
independent of `deint_env.sim`, so that a mistake shared by the simulator and the policies would show.

Files in the style of the renewal-process deinterleaving data sets (Young et al. 2019): a few radars
(3 by default) whose PRIs are jittered (i.i.d. intervals: a renewal process), random-level staggered,
deeply sliding (saw-tooth) or sinusoidally wobulated (a non-integer number of pulses per cycle), plus
white TOA noise, missing pulses and spurious pulses (a Poisson process over the record).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

KINDS = ("jittered", "stagger", "sliding", "sinusoidal")
TOA_NOISE = 0.05  # white TOA noise std, in the units of the PRIs (means 10 to 30)


class AgileFile(NamedTuple):
    toa: np.ndarray
    source: np.ndarray  # -1 = spurious
    kinds: tuple[str, ...]
    # the truth an emitter library would state, per radar: its mean PRI and its PRI modulation in the
    # priors format of docs/cli.md (a sinusoid's phase and a cycle's position at the first pulse are left
    # unknown, as a library cannot know them)
    period: tuple[float, ...] = ()
    modulation: tuple[dict, ...] = ()


def intervals(kind: str, mean: float, n: int, rng: np.random.Generator) -> tuple[np.ndarray, float, dict]:
    """n successive PRIs of one radar with mean PRI about `mean`, straight from the definitions; and the
    radar's true mean PRI and modulation (see `AgileFile`)."""
    k = np.arange(n)
    if kind == "jittered":  # renewal: each interval uniform within +-5 % of the mean
        return mean * (1 + 0.05 * rng.uniform(-1, 1, n)), mean, {"kind": "constant"}
    if kind == "stagger":  # 2 to 6 levels drawn at random within +-35 % of the mean, repeated
        levels = mean * rng.uniform(0.65, 1.35, rng.integers(2, 7))
        pri = levels[(k + rng.integers(levels.size)) % levels.size]
        return pri, float(levels.mean()), {"kind": "stagger", "pattern": (levels / levels.mean()).tolist(),
                                           "random_start": True}
    if kind == "sliding":  # a saw-tooth sweep 30 to 60 % deep over 16 to 48 pulses
        depth, cycle = rng.uniform(0.3, 0.6), int(rng.integers(16, 49))
        pri = mean * (1 + depth * (((k + rng.integers(cycle)) % cycle) / (cycle - 1) - 0.5))
        return pri, mean, {"kind": "sliding", "depth": float(depth), "cycle": cycle, "random_start": True}
    if kind == "sinusoidal":  # a sine 10 to 25 % deep, a non-integer 20 to 60 pulses per cycle
        depth, cycle = rng.uniform(0.1, 0.25), rng.uniform(20, 60)
        pri = mean * (1 + depth * np.sin(2 * math.pi * k / cycle + rng.uniform(0, 2 * math.pi)))
        return pri, mean, {"kind": "sinusoidal", "depth": float(depth), "cycle": float(cycle)}
    raise ValueError(kind)


def means(n_radars: int, rng: np.random.Generator) -> np.ndarray:
    """Mean PRIs log-uniform in [10, 30], pairwise at least 12 % apart (radars told apart by PRI)."""
    while True:
        m = np.exp(rng.uniform(math.log(10), math.log(30), n_radars))
        r = np.sort(m)
        if n_radars < 2 or np.all(r[1:] / r[:-1] > 1.12):
            return m


def agile_file(kinds: tuple[str, ...], seed: int, n_pulses: int = 1000, missing: float = 0.0,
               spurious: float = 0.0) -> AgileFile:
    """About `n_pulses` received pulses from one radar per entry of `kinds`: each emission is lost with
    probability `missing`; `spurious` spurious pulses per received radar pulse, uniform over the record."""
    rng = np.random.default_rng(seed)
    mean = means(len(kinds), rng)
    duration = n_pulses / ((1 - missing) * (1 + spurious) * float(np.sum(1 / mean)))
    toas, labels, periods, mods = [], [], [], []
    for i, (kind, m) in enumerate(zip(kinds, mean)):
        pri, period, mod = intervals(kind, float(m), int(2 * duration / m) + 4, rng)
        periods.append(float(period))
        mods.append(mod)
        t = rng.uniform(0, m) + np.concatenate([[0.0], np.cumsum(pri[:-1])])
        t = t[t < duration]
        t = t[rng.random(t.size) >= missing]
        toas.append(t + TOA_NOISE * rng.standard_normal(t.size))
        labels.append(np.full(t.size, i))
    n_true = sum(t.size for t in toas)
    c = rng.poisson(spurious * n_true)
    toas.append(rng.uniform(0, duration, c))
    labels.append(np.full(c, -1))
    toa, src = np.concatenate(toas), np.concatenate(labels)
    order = np.argsort(toa, kind="stable")
    return AgileFile(toa[order], src[order].astype(np.int64), tuple(kinds), tuple(periods), tuple(mods))


def library_priors(f: AgileFile, missing: float, spurious: float, phases: bool = False) -> dict:
    """A priors file such as an emitter library gives: each radar's mean PRI and modulation (the file's
    truth), the TOA noise, the channel's rates and, for jittered radars, the PRI jitter; the phases (each
    radar's first received pulse, within half a period) only if `phases`."""
    pri_jitter = float(np.mean(f.period)) * 0.05 / math.sqrt(3) if "jittered" in f.kinds else 0.0
    out = {"period": list(f.period), "period_std": [0.01 * p for p in f.period], "jitter_std": TOA_NOISE,
           "pri_jitter_std": pri_jitter, "missing_prob": missing, "spurious_rate": spurious,
           "modulation": list(f.modulation)}
    if phases:
        out["phase"] = [float(f.toa[f.source == i][0]) for i in range(len(f.kinds))]
        out["phase_std"] = [0.5 * p for p in f.period]
    return out


def write_pulses(path: Path, f: AgileFile) -> None:
    """A pulse CSV with the truth (`source`, -1 = spurious), which policies never see."""
    rows = "".join(f"{t!r},{s}\n" for t, s in zip(f.toa.tolist(), f.source.tolist()))
    Path(path).write_text("toa,source\n" + rows)


def read_labels(path: Path) -> np.ndarray:
    """The labels of a `deint label` output (-1 = spurious)."""
    return np.array([int(r.split(",")[1]) for r in Path(path).read_text().split()[1:]], dtype=np.int64)


def matched_accuracy(labels: np.ndarray, truth: np.ndarray) -> float:
    """Hungarian-matched accuracy, computed here independently of deint_env.metrics: labels are
    mapped one-to-one onto sources (spurious -1 onto -1 only) to maximise the pulses that agree."""
    from scipy.optimize import linear_sum_assignment

    lab = np.unique(labels[labels >= 0])
    src = np.unique(truth[truth >= 0])
    agree = np.array([[np.sum((labels == a) & (truth == s)) for s in src] for a in lab]).reshape(lab.size, src.size)
    rows, cols = linear_sum_assignment(-agree) if agree.size else ((), ())
    hits = int(sum(agree[r, c] for r, c in zip(rows, cols))) + int(np.sum((labels < 0) & (truth < 0)))
    return hits / truth.size


# The grid: every kind alone (3 radars of that kind) and mixed, on a clean channel, with missing and
# with spurious pulses, and both.
CHANNELS = {"clean": (0.0, 0.0), "miss20": (0.2, 0.0), "spur20": (0.0, 0.2), "miss30-spur10": (0.3, 0.1),
            "miss20-spur20": (0.2, 0.2)}
SCENES = {**{k: (k,) * 3 for k in KINDS}, "mixed": ("stagger", "sliding", "sinusoidal")}


def grid(seeds: range = range(1)):
    """(name, kinds, missing, spurious, seed) for every scene, channel and seed."""
    for scene, kinds in SCENES.items():
        for ch, (miss, spur) in CHANNELS.items():
            for s in seeds:
                yield f"{scene}-{ch}-s{s}", kinds, miss, spur, 1000 * s + 17 * len(scene) + len(ch)

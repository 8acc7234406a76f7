"""The PRI model of one extracted train: constant, stagger (with its levels), sliding or sinusoidal.

- Sub-trains of one frame period F (found separately by sequence search at F) form a stagger; its
  levels are the gaps between the sub-trains' phases within a frame, in emission order.  Equal
  levels mean a constant PRI F / m that was extracted at a multiple.
- One train: its line fit t = a + k T.  Residuals at the TOA noise level mean constant; otherwise the
  successive PRIs d_n (between pulses one PRI apart) are fitted with a sinusoid
  T (1 + depth sin(2 pi n / cycle + psi)) and a saw-tooth T (1 + depth (((n + p) mod cycle) /
  (cycle - 1) - 1/2)) (the simulator's conventions), and the better one is kept when it explains at
  least half of the PRI variance.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from deint_env.modulation import PRIModel


class LineFit(NamedTuple):
    """t ~ origin + k period, by least squares."""

    origin: float
    period: float
    period_std: float
    resid_std: float


def line_fit(t: np.ndarray, k: np.ndarray) -> LineFit:
    k = np.asarray(k, dtype=np.float64)
    km, tm = k.mean(), t.mean()
    skk = float(np.sum((k - km) ** 2))
    slope = float(np.sum((k - km) * (t - tm)) / skk) if skk > 0 else math.nan
    resid = t - (tm + slope * (k - km))
    dof = max(t.size - 2, 1)
    s = float(math.sqrt(np.sum(resid**2) / dof))
    return LineFit(float(tm - slope * km), slope, s / math.sqrt(skk) if skk > 0 else math.inf, s)


def _circular_groups(phases: np.ndarray, period: float, tol: float) -> np.ndarray:
    """Sorted phases in [0, period) with those closer than tol (circularly) merged into their mean."""
    ph = np.sort(np.mod(phases, period))
    groups = [[ph[0]]]
    for x in ph[1:]:
        if x - groups[-1][-1] <= tol:
            groups[-1].append(x)
        else:
            groups.append([x])
    if len(groups) > 1 and groups[0][0] + period - groups[-1][-1] <= tol:  # wrap-around
        groups[0] = [x - period for x in groups.pop()] + groups[0]
    return np.sort(np.mod([np.mean(g) for g in groups], period))


def stagger_model(frame: float, origins: np.ndarray, sigma: float) -> tuple[PRIModel, np.ndarray]:
    """The model of sub-trains sharing the frame period F, and the distinct sub-train phases.

    Sub-trains on one phase (pieces of one lattice) are merged; if the phases all lie on a lattice
    F / n (a constant train extracted in pieces, some perhaps missing) the model is constant F / n;
    otherwise a stagger whose levels are the gaps between the phases, in emission order.  `sigma`:
    the sub-trains' TOA scatter (their largest residual spread, or the TOA noise)."""
    tol = 4 * sigma + 1e-3 * frame
    phases = _circular_groups(np.asarray(origins, dtype=np.float64), frame, tol)
    levels = np.diff(np.concatenate([phases, [phases[0] + frame]]))
    n = max(1, round(frame / float(levels.min())))
    sub = frame / n
    off = np.mod(phases - phases[0] + tol, sub) - tol  # each phase's distance from the F/n lattice
    if n <= 2 * phases.size and np.all(np.abs(off) <= tol):  # at most half the sub-trains missing
        return PRIModel("constant", sub), phases[:1]
    # sub-trains found at a multiple of the frame repeat their levels: keep one cycle
    m = levels.size
    cycle = next(d for d in range(1, m + 1) if m % d == 0 and np.all(np.abs(levels - np.roll(levels, d)) <= 2 * tol))
    return cycle_model(levels[:cycle], tol), phases


def _slots(levels: np.ndarray) -> np.ndarray:
    """The PRIs of one frame from the gaps between the sub-train phases found.  A gap within 1.5 times
    the smallest, or in a run of three alike, is one PRI (a sweep's or wobulation's PRIs differ by
    less, a dwell repeats its PRI); another holds
    q = round(gap / local) PRIs, q - 1 sub-trains missing, with `local` the mean of the nearest
    one-PRI gaps on either side, and is split into q equal PRIs."""
    m = levels.size
    # a dwell holds a long PRI for several pulses: a gap in a run of three or more alike (within 10 %)
    # is a PRI, not a hole (two holes side by side make two alike gaps)
    step = np.abs(levels - np.roll(levels, -1)) <= 0.1 * levels  # level i like level i + 1
    run3 = step & np.roll(step, 1)  # i - 1, i, i + 1 alike
    like = run3 | np.roll(run3, 1) | np.roll(run3, -1)
    single = (levels <= 1.5 * levels.min()) | like
    idx = np.flatnonzero(single)
    q = np.ones(m, dtype=np.int64)
    for i in np.flatnonzero(~single):
        after = idx[np.argmin(np.mod(idx - i, m))]
        before = idx[np.argmin(np.mod(i - idx, m))]
        q[i] = max(1, round(float(levels[i] / (0.5 * (levels[after] + levels[before])))))
    return np.repeat(levels / q, q)


def _sliding_fit(p: np.ndarray) -> tuple[float, float, int]:
    """(rss, depth, rotation) of the best saw-tooth a + b x_j, x_j = ((j + r) mod M) / (M - 1) - 1/2, b > 0."""
    m = p.size
    best = (math.inf, 0.0, 0)
    for r in range(m):
        x = np.mod(np.arange(m) + r, m) / (m - 1) - 0.5
        xc = x - x.mean()
        b = float(xc @ (p - p.mean()) / (xc @ xc))
        rss = float(np.sum((p - p.mean() - b * xc) ** 2))
        if b > 0 and rss < best[0]:
            best = (rss, b / float(p.mean()), r)
    return best


def _harmonic_fit(p: np.ndarray, h: int) -> tuple[float, float]:
    """(rss, depth) of a + c cos(2 pi h j / M) + s sin(2 pi h j / M): h wobulation cycles per frame."""
    j = np.arange(p.size)
    x = np.stack([np.ones(p.size), np.cos(2 * np.pi * h * j / p.size), np.sin(2 * np.pi * h * j / p.size)], 1)
    coef, *_ = np.linalg.lstsq(x, p, rcond=None)
    return float(np.sum((p - x @ coef) ** 2)), float(math.hypot(coef[1], coef[2]) / coef[0])


def _dwell_fits(p: np.ndarray) -> list[tuple[float, int, np.ndarray]]:
    """Per dwell length c: (rss, c, dwell PRIs) of the best piecewise-constant cycle of M / c dwells (2 to 8)
    of c equal PRIs, over the rotations."""
    m = p.size
    out = []
    for c in range(2, m // 2 + 1):
        if m % c or not 2 <= m // c <= 8:
            continue
        best = (math.inf, c, np.empty(0))
        for r in range(c):
            runs = np.roll(p, -r).reshape(m // c, c)
            rss = float(np.sum((runs - runs.mean(1, keepdims=True)) ** 2))
            if rss < best[0]:
                best = (rss, c, runs.mean(1))
        out.append(best)
    return out


def cycle_model(levels: np.ndarray, tol: float) -> PRIModel:
    """The model of a periodic PRI sequence found as sub-trains of one frame (its levels: one frame's PRIs,
    in emission order).  A few levels are a stagger; a long cycle (8 or more PRIs) may be a sliding
    saw-tooth, a wobulation or dwell-and-switch, whose frames are periodic too: each of the four is
    fitted to the PRIs (`_slots`) and the one with the least BIC, M log(rss / M) + k log M with the
    rss floored at the level noise (tol, the sub-trains' phase tolerance), is kept: a shape with 3 or
    4 parameters beats the M-level stagger when it explains the levels to their noise."""
    if levels.size < 8:
        return PRIModel("stagger", float(levels.mean()), tuple(float(v) for v in levels))
    p = _slots(levels)
    m = p.size
    floor = (0.5 * tol) ** 2

    def bic(rss: float, k: int) -> float:
        return m * math.log(max(rss / m, floor)) + k * math.log(m)

    mean = float(p.mean())
    options = [(bic(0.0, levels.size), PRIModel("stagger", float(levels.mean()), tuple(float(v) for v in levels)))]
    rss, depth, _ = _sliding_fit(p)
    options.append((bic(rss, 3), PRIModel("sliding", mean, (), depth, float(m))))
    for h in (1, 2, 3):
        rss, depth = _harmonic_fit(p, h)
        options.append((bic(rss, 4), PRIModel("sinusoidal", mean, (), depth, m / h)))
    for rss, c, dwell in _dwell_fits(p):
        options.append((bic(rss, dwell.size + 2), PRIModel("dwell_switch", mean, tuple(float(v) for v in dwell), 0.0,
                                                           float(c))))
    return min(options, key=lambda o: o[0])[1]


def _sine_rss(n: np.ndarray, d: np.ndarray, f: float) -> tuple[float, float]:
    x = np.stack([np.ones_like(d), np.cos(2 * np.pi * f * n), np.sin(2 * np.pi * f * n)], axis=1)
    coef, *_ = np.linalg.lstsq(x, d, rcond=None)
    return float(np.sum((d - x @ coef) ** 2)), float(math.hypot(coef[1], coef[2]) / coef[0])


def _sine_fit(n: np.ndarray, d: np.ndarray, max_cycle: float) -> tuple[float, float, float]:
    """(rss, depth, cycle) of the best sinusoid: a frequency grid, then a golden-section search within
    the best grid step."""
    grid = np.linspace(1.0 / max_cycle, 1.0 / 3.0, 400)
    rss = [_sine_rss(n, d, f)[0] for f in grid]
    i = int(np.argmin(rss))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    g = (math.sqrt(5) - 1) / 2
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    for _ in range(40):
        if _sine_rss(n, d, a)[0] < _sine_rss(n, d, b)[0]:
            hi, b = b, a
            a = hi - g * (hi - lo)
        else:
            lo, a = a, b
            b = lo + g * (hi - lo)
    f = 0.5 * (lo + hi)
    r, depth = _sine_rss(n, d, f)
    return (r, depth, float(1.0 / f)) if r <= rss[i] else (rss[i], _sine_rss(n, d, grid[i])[1], float(1.0 / grid[i]))


def _sawtooth_fit(n: np.ndarray, d: np.ndarray, max_cycle: int) -> tuple[float, float, float]:
    """(rss, depth, cycle) of the best saw-tooth over integer cycles and offsets."""
    best = (math.inf, 0.0, 0.0)
    mean = d.mean()
    for c in range(4, max_cycle + 1):
        s = (np.mod(n[None, :] + np.arange(c)[:, None], c) / (c - 1) - 0.5)  # (offset, pulse)
        sc = s - s.mean(1, keepdims=True)
        dc = d - mean
        slope = (sc @ dc) / np.maximum(np.sum(sc**2, 1), 1e-300)
        rss = np.sum((dc[None, :] - slope[:, None] * sc) ** 2, 1)
        p = int(np.argmin(rss))
        if rss[p] < best[0] and slope[p] > 0:
            best = (float(rss[p]), float(slope[p] / mean), float(c))
    return best


def single_train_model(t: np.ndarray, k: np.ndarray, sigma: float) -> PRIModel:
    fit = line_fit(t, k)
    if fit.resid_std <= 2.0 * sigma + 1e-3 * fit.period or t.size < 12:
        return PRIModel("constant", fit.period)
    one = np.flatnonzero(np.diff(k) == 1)  # PRIs between pulses one period apart
    if one.size < 12:
        return PRIModel("constant", fit.period)
    n, d = k[one].astype(np.float64), np.diff(t)[one]
    rss0 = float(np.sum((d - d.mean()) ** 2))
    max_cycle = int(min(200, max(6, one.size // 2)))
    sine = _sine_fit(n, d, max_cycle)
    saw = _sawtooth_fit(n, d, max_cycle)
    # the shapes by BIC on the PRIs (rss floored at the differenced TOA noise, 2 sigma^2 per PRI); the
    # best must explain half the PRI variance
    options = [(sine[0], 4, PRIModel("sinusoidal", float(d.mean()), (), sine[1], sine[2])),
               (saw[0], 4, PRIModel("sliding", float(d.mean()), (), saw[1], saw[2]))]
    dwell = _chain_dwell(n, d, sigma)
    if dwell is not None:
        options.append((dwell[0], len(dwell[1].levels) + 2, dwell[1]))
    size = d.size
    rss, _, model = min(options, key=lambda o: size * math.log(max(o[0] / size, 2 * sigma**2)) + o[1] * math.log(size))
    if rss <= 0.5 * rss0:
        return model
    # no cycle explains the PRIs, yet their means over blocks of B PRIs wander beyond the TOA noise
    # (a steady PRI's block mean telescopes to (w_end - w_start) / B: std sqrt(2) sigma / B): drifting
    b = 10
    blocks = d[: d.size // b * b].reshape(-1, b).mean(1)
    spread = 1.4826 * float(np.median(np.abs(blocks - np.median(blocks))))
    if blocks.size >= 4 and spread > 3.0 * math.sqrt(2) * sigma / b:
        return PRIModel("drifting", float(d.mean()))
    return PRIModel("constant", fit.period)


def _chain_dwell(n: np.ndarray, d: np.ndarray, sigma: float) -> tuple[float, PRIModel] | None:
    """A dwell-and-switch train followed through its switches: its PRIs hold a value for c pulses, then
    jump to the next of a few values.  Fitted over dwell lengths c and offsets (PRIs indexed by their
    period count n); (rss, model) when the dwell means explain the PRIs to their noise (2 sqrt(2) sigma
    per PRI) and the dwell values repeat in a cycle (of 2 to 8 dwells of 8 or more pulses, seen twice), else None."""
    best = None
    n = np.asarray(n, dtype=np.int64)
    for c in range(8, max(9, n.size // 6)):  # dwells of 8 pulses or more
        for off in range(c):
            dw = (n + off) // c
            ids, inv = np.unique(dw, return_inverse=True)
            means = np.bincount(inv, d) / np.bincount(inv)
            rss = float(np.sum((d - means[inv]) ** 2))
            # BIC over the dwell lengths (a divisor of the true length fits as well, with more dwells)
            score = d.size * math.log(max(rss / d.size, 1e-300)) + ids.size * math.log(d.size)
            if best is None or score < best[5]:
                best = (rss, c, off, ids, means, score)
    if best is None or best[0] > d.size * (2.0 * math.sqrt(2) * sigma) ** 2:
        return None
    _, c, off, ids, means, _ = best
    tol = 4.0 * sigma + 0.02 * float(d.mean())
    for m in range(2, 9):  # the smallest cycle of dwell values the means follow
        pos = ids % m
        vals = np.array([np.median(means[pos == j]) if np.any(pos == j) else np.nan for j in range(m)])
        if ids.size >= 2 * m and np.all(np.isfinite(vals)) and np.all(np.abs(means - vals[pos]) <= tol) \
                and np.ptp(vals) > tol:  # the cycle seen twice
            start = int(ids[0] % m)
            return best[0], PRIModel("dwell_switch", float(np.mean(vals)), tuple(float(v) for v in np.roll(vals, -start)),
                                     0.0, float(c))
    return None

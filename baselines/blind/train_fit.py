"""A PRI model fitted to one train's TOAs by least squares over its emission counts (`fit_train`).

With n_i the emission count of a train's pulse i (missed emissions skipped), each model's arrival times are
linear in its continuous parameters once its discrete ones (cycle, cycle position) are fixed:
- constant: t(n) = a + T n;
- stagger of m levels L_j (the cycle position absorbed into their order): t(n) = a + sum_j L_j C_j(n), C_j(n) the
  emissions k < n with k mod m = j;
- sliding (the simulator's saw-tooth, 0 < depth < 1): t(n) = a + T n + T depth S(n + o) - T depth S(o),
  S(k) = sum_{j<k} ((j mod c) / (c - 1) - 1/2);
- sinusoidal: t(n) = a + T n + T depth (cos psi A(n) + sin psi B(n)), A, B the sums of sin and cos(2 pi k / c).
So each kind is a least-squares fit over a grid of its discrete parameters, the kind chosen by BIC (each searched
discrete parameter priced as one more).  The counts come first from the intervals (`first_counts`), then from
the fitted model's nearest predicted emissions (`_recount`), which also drop the pulses far from any (another
train's, or spurious).  Measured on the independent generator's radars (each one's own pulses, seed 3 and 4):
sweeps and wobulations are found with their cycle and depth, clean or with missing or spurious pulses, but for
a few deep sweeps among missing pulses taken for a wobulation of the same cycle; a stagger among missing pulses
is often not (its levels, up to 2:1, make the counts ambiguous).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from deint_env.errors import DeintError
from deint_env.scenario import Modulation

SLIDING_CYCLES = range(4, 97)  # saw-tooth cycles tried (pulses)
SINE_CYCLES = np.arange(4.0, 120.0, 0.25)  # wobulation cycles tried, refined around the best
STAGGER_LEVELS = range(2, 9)
REFITS = 4  # count assignments from a fitted model
MIN_PULSES = 8  # fewer make no model (cdif-renewal's MIN_TRAIN)
# a sweep or wobulation shallower than this is a constant PRI: a jittered (renewal) train's random walk about its
# line fits a sine or sweep of depth ~0.01 better by BIC (14 of seed 3's 15 jittered trains, without this floor)
MIN_DEPTH = 0.03
MISS_NATS = math.log(10)  # -log q at the unstated missing rate 0.1 (cdif-renewal's UNSTATED_MISSING)
# a dropped pulse's price: a counting that drops pulses to fit must gain more than this per pulse dropped
DROP_NATS = 10.0
OUTLIER = 5.0  # a pulse this many robust residual deviations from its predicted emission is not the train's


class TrainFit(NamedTuple):
    kind: str
    period: float
    modulation: Modulation | None
    rss: float
    bic: float
    used: int  # pulses the fit kept


def first_counts(t: np.ndarray, follow: bool) -> tuple[np.ndarray, np.ndarray]:
    """Emission counts from the intervals, and the pulses counted: each interval from the last pulse counted is a
    whole number of a reference PRI, the last single interval (`follow`: a sweep's or wobulation's PRI moves little
    from one emission to the next) or the train's median interval (a stagger's levels jump, so the last one
    misleads); a pulse less than half the reference after the last one counted is a stray, not counted (else
    every stray would shift the counts after it by one)."""
    p = float(np.median(np.diff(t)))  # a single PRI while fewer than half the emissions are missed
    n, keep = np.zeros(t.size, dtype=np.int64), np.ones(t.size, dtype=bool)
    last = 0
    for i in range(1, t.size):
        g = float(t[i] - t[last])
        if g < 0.5 * p:
            keep[i] = False
            continue
        m = max(1, round(g / p))
        n[i] = n[last] + m
        last = i
        if follow:
            p = g / m
    return n, keep


def _perp(y: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """y's residual against the line a + T n (last axis), and the line's basis."""
    base = np.stack([np.ones(n.size), n - n.mean()], 1)
    base /= np.linalg.norm(base, axis=0)
    return y - (y @ base) @ base.T, base


def _best_column_fit(y: np.ndarray, n: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of y on (1, n, one set of columns): cols (G, N, P); the RSS (G,) and coefficients on the
    columns (G, P)."""
    yp, base = _perp(y, n)
    cp = cols - np.einsum("gqp,mq->gmp", np.einsum("gnp,nq->gqp", cols, base), base)
    gram = np.einsum("gnp,gnq->gpq", cp, cp) + 1e-12 * np.eye(cols.shape[2])
    rhs = np.einsum("gnp,n->gp", cp, yp)
    coef = np.linalg.solve(gram, rhs[..., None])[..., 0]
    rss = float(yp @ yp) - np.einsum("gp,gp->g", coef, rhs)
    return np.maximum(rss, 0.0), coef


def _saw_sums(c: int, length: int) -> np.ndarray:
    r = np.arange(length) % c / (c - 1) - 0.5
    return np.concatenate([[0.0], np.cumsum(r)])


def _sine_sums(c: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(G, N, 2): sum_{k<n} sin(w k) and cos(w k), w = 2 pi / c."""
    w = 2 * math.pi / np.asarray(c, dtype=np.float64)[:, None]
    z = (1 - np.exp(1j * w * n[None])) / (1 - np.exp(1j * w))
    return np.stack([z.imag, z.real], 2)


class _Model(NamedTuple):
    kind: str
    rss: float
    params: int
    predict: object  # counts -> TOAs
    period: float
    modulation: Modulation | None


def _fits(t: np.ndarray, n: np.ndarray) -> list[_Model]:
    """Every kind's best fit to pulses t at counts n."""
    out = []
    x = np.stack([np.ones(n.size), n], 1).astype(np.float64)
    coef = np.linalg.lstsq(x, t, rcond=None)[0]
    a, period = float(coef[0]), float(coef[1])
    rss = float(np.sum((t - x @ coef) ** 2))
    out.append(_Model("constant", rss, 2, lambda k, a=a, p=period: a + p * k, period, Modulation("constant")))
    top = int(n.max()) + 1
    for m in STAGGER_LEVELS:
        if n.size < 3 * m:
            break
        cnt = np.stack([np.maximum(0, -((j - n) // m)) for j in range(m)], 1).astype(np.float64)
        xs = np.concatenate([np.ones((n.size, 1)), cnt], 1)
        coef = np.linalg.lstsq(xs, t, rcond=None)[0]
        lv = coef[1:]
        if lv.min() <= 0:
            continue
        rss = float(np.sum((t - xs @ coef) ** 2))
        try:
            mod = Modulation("stagger", pattern=tuple((lv / lv.mean()).tolist()), random_start=True)
        except DeintError:
            continue

        def pred(k, a=float(coef[0]), lv=lv, m=m):
            return a + sum(lv[j] * np.maximum(0, -((j - k) // m)) for j in range(m))
        out.append(_Model("stagger", rss, m + 1, pred, float(lv.mean()), mod))
    # sliding: every (cycle, offset)
    best = None
    for c in SLIDING_CYCLES:
        if c > top:
            break
        s = _saw_sums(c, top + c)
        cols = (s[n[None, :] + np.arange(c)[:, None]] - s[np.arange(c)][:, None])[..., None]
        rss, co = _best_column_fit(t, n, cols)
        g = int(np.argmin(rss))
        if best is None or rss[g] < best[0]:
            best = (float(rss[g]), c, g)
    if best is not None:
        _, c, o = best
        s = _saw_sums(c, top + 4 * c)
        col = s[n + o] - s[o]
        xs = np.stack([np.ones(n.size), n, col], 1)
        coef = np.linalg.lstsq(xs, t, rcond=None)[0]
        period, depth = float(coef[1]), float(coef[2] / coef[1])
        if 0 < depth < 1:
            mod = Modulation("sliding", depth=depth, cycle=c, random_start=True)

            def pred(k, coef=coef, s=s, o=o):
                k = np.clip(k, 0, s.size - 1 - o)
                return coef[0] + coef[1] * k + coef[2] * (s[k + o] - s[o])
            out.append(_Model("sliding", float(np.sum((t - xs @ coef) ** 2)), 5, pred, period, mod))
    # sinusoidal: a grid of cycles, then a finer one around the best
    grid = SINE_CYCLES[SINE_CYCLES <= 2 * top]
    if grid.size:
        rss, _ = _best_column_fit(t, n, _sine_sums(grid, n))
        c0 = float(grid[int(np.argmin(rss))])
        fine = np.linspace(c0 - 0.25, c0 + 0.25, 21)
        rss, _ = _best_column_fit(t, n, _sine_sums(fine, n))
        c = float(fine[int(np.argmin(rss))])
        xs = np.concatenate([np.stack([np.ones(n.size), n], 1), _sine_sums(np.array([c]), n)[0]], 1)
        coef = np.linalg.lstsq(xs, t, rcond=None)[0]
        period = float(coef[1])
        depth = float(math.hypot(coef[2], coef[3]) / period)
        if 0 < depth < 1:
            mod = Modulation("sinusoidal", depth=depth, cycle=c)

            def pred(k, coef=coef, c=c):
                return np.concatenate([np.stack([np.ones(k.size), k], 1), _sine_sums(np.array([c]), k)[0]], 1) @ coef
            out.append(_Model("sinusoidal", float(np.sum((t - xs @ coef) ** 2)), 5, pred, period, mod))
    return out


def _bic(m: _Model, size: int) -> float:
    return size * math.log(max(m.rss, 1e-300) / size) + m.params * math.log(size)


def _recount(t: np.ndarray, model: _Model, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pulse's count as the nearest predicted emission; (counts, kept): pulses more than `OUTLIER` robust
    deviations from every emission (another train's, or spurious), or a second pulse on one emission, are not
    kept."""
    span = np.arange(int(n.max()) * 2 + 8)
    e = np.asarray(model.predict(span), dtype=np.float64)
    rising = np.concatenate([[True], np.diff(e) > 0])
    span, e = span[rising], e[rising]
    j = np.clip(np.searchsorted(e, t), 1, e.size - 1)
    j = np.where(np.abs(t - e[j - 1]) < np.abs(t - e[j]), j - 1, j)
    r = t - e[j]
    keep = np.abs(r) <= OUTLIER * 1.4826 * float(np.median(np.abs(r))) + 1e-9
    first = np.concatenate([[True], np.diff(span[j]) > 0])
    return span[j], keep & first


def _score(model: _Model, counts: np.ndarray, used: int, size: int) -> float:
    """BIC of the fit, plus the renewal model's price of the emissions it calls missed (`MISS_NATS` each) and of
    the pulses it drops (`DROP_NATS`), in BIC's units (2 nats): so a short period that fits anything, or a fit
    that keeps only a few of the pulses, does not win."""
    missed = int(counts.max()) + 1 - used
    return _bic(model, used) + 2 * (MISS_NATS * missed + DROP_NATS * (size - used))


def _refine(t: np.ndarray, n: np.ndarray, keep: np.ndarray) -> tuple[_Model | None, np.ndarray, float]:
    """Fit, recount from the fit, fit again (`REFITS` times): the last fit, the pulses it kept, its score."""
    best, score = None, math.inf
    for _ in range(REFITS):
        tk, nk = t[keep], n[keep] - n[keep][0]
        if tk.size < MIN_PULSES:
            break
        best = min(_fits(tk, nk), key=lambda m: _bic(m, tk.size))
        score = _score(best, nk, tk.size, t.size)
        n, keep = _recount(t, best, nk)
    return best, keep, score


def fit_train(t: np.ndarray, counts: np.ndarray | None = None) -> TrainFit | None:
    """The PRI model of a train's pulses (sorted TOAs), chosen by BIC, from the first counting of lower `_score`
    (from the intervals, or `counts` where given: a frame's, -1 for a pulse not counted); None for too few pulses.
    A sweep or wobulation shallower than `MIN_DEPTH` is taken for a constant PRI: a jittered train's random walk
    fits one."""
    t = np.asarray(t, dtype=np.float64)
    if t.size < MIN_PULSES:
        return None
    starts = [first_counts(t, follow) for follow in (True, False)]
    if counts is not None:
        starts.append((np.asarray(counts), np.asarray(counts) >= 0))
    runs = [r for r in (_refine(t, *start) for start in starts) if r[0] is not None]
    if not runs:
        return None
    model, keep, _ = min(runs, key=lambda r: r[2])
    used = int(keep.sum())
    if model.kind in ("sliding", "sinusoidal") and model.modulation.depth < MIN_DEPTH:
        n, counted = first_counts(t[keep], False)
        model = _fits(t[keep][counted], n[counted])[0]
    return TrainFit(model.kind, model.period, model.modulation, model.rss, _bic(model, max(used, 1)), used)

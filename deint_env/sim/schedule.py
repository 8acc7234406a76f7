"""Each source's schedule: the episode's drawn source parameters, and the noise-free emission times
(modulated, cumulatively jittered, inside the on-windows) with their PRIs and amplitudes."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from deint_env.scenario import Modulation, Range, ScenarioSpec, SourceSpec
from deint_env.sim.descriptors import EmitterDraws
from deint_env.sim.rows import compact
from deint_env.sim.streams import AMPLITUDE, CUMULATIVE, MODULATION, fill, stream

MIN_INTERVAL = 0.05  # intervals are clipped at this fraction of the PRI so a source never runs backwards
RANDOM_MODULATIONS = ("sinusoidal", "drifting", "random_stagger")  # drawn per episode


def _is_random(mod: Modulation) -> bool:
    """Whether a modulation draws part of its PRIs per episode (its kind, or a drawn cycle position)."""
    return mod.kind in RANDOM_MODULATIONS or mod.random_start


class SourceDraw(NamedTuple):
    """One episode's sources as drawn (its DRAW stream): per source, period, phase and mean amplitude."""

    period: list[float]
    phase: list[float]
    amp_mean: list[float]


class Emissions(NamedTuple):
    """One source's emissions, a row per episode: times (padding: >= the horizon), the PRI after
    each, emitted amplitudes (or None) and each row's count."""

    t: np.ndarray
    pri: np.ndarray
    amp: np.ndarray | None
    count: np.ndarray


@dataclass
class Draws:
    """The per-episode draws and derived constants of episodes with the same sources (one row each)."""

    seeds: list[int]
    period: np.ndarray  # (E, k)
    phase: np.ndarray  # (E, k)
    amp_mean: np.ndarray  # (E, k)
    h0: np.ndarray  # (E,) nominal duration: the windows' unit
    spur_intensity: np.ndarray  # (E,)
    t_start: np.ndarray  # (E,)
    emitters: EmitterDraws | None = None  # the pulse descriptors' draws (None: TOAs only)

    def take(self, rows: np.ndarray) -> Draws:
        return Draws([self.seeds[j] for j in rows.tolist()], self.period[rows], self.phase[rows],
                      self.amp_mean[rows], self.h0[rows], self.spur_intensity[rows], self.t_start[rows],
                      None if self.emitters is None else self.emitters.take(rows))


def draw_sources(spec: ScenarioSpec, draw: np.random.Generator) -> SourceDraw:
    """The episode's source count and per-source period, phase and mean amplitude (its DRAW stream)."""
    sources = spec.sources
    if spec.n_active is not None:
        lo, hi = spec.n_active
        sources = sources[: int(draw.integers(lo, hi + 1))]
    period = [_draw(s.period, draw) for s in sources]
    phase = [_draw(s.phase, draw) if s.phase is not None else draw.random() * t for s, t in zip(sources, period)]
    amp_mean = [_draw(s.amplitude, draw) for s in sources]
    return SourceDraw(period, phase, amp_mean)


def _draw(p: float | Range, rng: np.random.Generator) -> float:
    return p.draw(rng) if isinstance(p, Range) else float(p)


def emissions(src: SourceSpec, period: np.ndarray, phase: np.ndarray, amp_mean: np.ndarray, m: np.ndarray,
              cum_std: float, h0: np.ndarray, horizon: np.ndarray, seeds: list[int], i: int,
              track_amplitude: bool) -> Emissions:
    """Source i's emissions in [phase, horizon) inside its on-windows, per episode (row), from m
    scheduled ones: times, the PRI after each, emitted amplitudes (or None), and their counts;
    padding: times >= the horizon."""
    t, pri = _times(src.modulation, period, phase, m, cum_std, seeds, i)
    count = (t < horizon[:, None]).sum(axis=1)
    short = (count >= m).nonzero()[0]  # the m-th emission is before the horizon (random rows only)
    while short.size:
        m[short] *= 2
        t_short, pri_short = _times(src.modulation, period[short], phase[short], m[short], cum_std,
                                       [seeds[j] for j in short.tolist()], i)
        grow = max(t_short.shape[1] - t.shape[1], 0)
        t, pri = np.pad(t, ((0, 0), (0, grow)), constant_values=np.inf), np.pad(pri, ((0, 0), (0, grow)))
        t[short] = np.inf
        t[short, :t_short.shape[1]], pri[short, :t_short.shape[1]] = t_short, pri_short
        count[short] = (t_short < horizon[short, None]).sum(axis=1)
        short = short[count[short] >= m[short]]
    width = count.max()
    t, pri = t[:, :width], pri[:, :width]
    amp = None
    if track_amplitude:
        amp = np.broadcast_to(amp_mean[:, None], t.shape)
        if src.amplitude_std > 0:
            z = np.zeros(t.shape)
            fill([z], seeds, AMPLITUDE, i, counts=count[:, None])
            amp = np.maximum(amp + src.amplitude_std * z, 0.0)
    if src.active:
        on = np.arange(t.shape[1]) < count[:, None]
        inside = np.zeros(t.shape, bool)
        for j, (a, b) in enumerate(src.active):
            stop = math.inf if (j == len(src.active) - 1 and b >= 1.0) else (b * h0)[:, None]
            inside |= (t >= (a * h0)[:, None]) & (t < stop)
        count, t, pri, amp = compact(on & inside, t, pri, amp)
    return Emissions(t, pri, amp, count)


def _times(mod: Modulation, period: np.ndarray, phase: np.ndarray, m: np.ndarray, cum_std: float,
              seeds: list[int], i: int) -> tuple[np.ndarray, np.ndarray]:
    """Emission times and PRIs of at least m[j] emissions per row: exactly m[j] (then +inf) where
    the intervals are random; where they are not, the rest of the row continues the schedule (so
    either way, the m-th emission is before the horizon iff at least m emissions are)."""
    width = int(m.max())
    pri = _pri(mod, period, m, width, seeds, i)
    intervals = pri  # PRIs are positive: only jittered intervals need clipping
    if cum_std > 0:
        z = np.zeros(pri.shape)
        fill([z], seeds, CUMULATIVE, i, counts=m[:, None])
        intervals = np.maximum(pri + cum_std * z, MIN_INTERVAL * pri)
    t = np.empty(pri.shape)
    t[:, 0] = phase
    np.cumsum(intervals[:, :-1], axis=1, out=t[:, 1:])
    t[:, 1:] += phase[:, None]
    if cum_std > 0 or _is_random(mod):
        t[np.arange(width) >= m[:, None]] = np.inf
    return t, pri


def _pri(mod: Modulation, period: np.ndarray, m: np.ndarray, width: int, seeds: list[int], i: int) -> np.ndarray:
    """PRI_n for n = 0..width-1 (the interval after pulse n) per row, per `Modulation`'s definitions;
    random modulations are drawn per episode and defined up to m[j] only (zeros past it)."""
    kind = mod.kind
    if _is_random(mod):
        out = np.zeros((period.size, width))
        for row, t, c, seed in zip(out, period.tolist(), m.tolist(), seeds):
            row[:c] = _random_pri(mod, t, c, seed, i)
        return out
    if kind == "constant":
        return np.broadcast_to(period[:, None], (period.size, width))
    return period[:, None] * _cyclic_ratio(mod, np.arange(width))


def _cyclic_ratio(mod: Modulation, n: np.ndarray) -> np.ndarray:
    """PRI_n / T of a cyclic kind (stagger, dwell_switch, sliding) at cycle positions n."""
    kind = mod.kind
    if kind == "stagger" or (kind == "dwell_switch" and not mod.dwells):
        pattern = np.asarray(mod.pattern) / np.mean(mod.pattern)
        return pattern[n % pattern.size if kind == "stagger" else (n // mod.cycle) % pattern.size]
    if kind == "dwell_switch":  # dwells of their own lengths: the dwell holding each position of the cycle
        ends = np.cumsum(mod.dwells)
        return mod.level_ratios()[np.searchsorted(ends, n % ends[-1], side="right")]
    if mod.relative_to == "start":
        return (1.0 + mod.depth * ((n % mod.cycle) / (mod.cycle - 1))) / (1.0 + mod.depth / 2)
    return 1.0 + mod.depth * ((n % mod.cycle) / (mod.cycle - 1) - 0.5)


def _random_pri(mod: Modulation, period: float, m: int, seed: int, i: int) -> np.ndarray:
    """One episode's m PRIs of a modulation with a random part (its own MODULATION stream)."""
    n = np.arange(m)
    rng = stream(seed, MODULATION, i)
    if mod.kind == "sinusoidal":
        psi = 2 * np.pi * rng.random()
        return period * (1.0 + mod.depth * np.sin(2 * np.pi * n / mod.cycle + psi))
    if mod.random_start:  # the cycle position of the first pulse, uniform over the cycle
        return period * _cyclic_ratio(mod, n + int(rng.integers(mod.cycle_length)))
    if mod.kind == "random_stagger":
        return period * mod.level_ratios()[_levels(mod, rng.random(m))]
    # drifting (MK94 II-C-2): PRI_{n+1} = alpha PRI_n + drift_std v_n, a first-order recursion.
    drive = np.empty(m)
    drive[0] = period
    drive[1:] = mod.drift_std * rng.standard_normal(m - 1)
    from scipy.signal import lfilter  # here: scipy.signal is slow to import and only drifting PRIs use it
    pri = lfilter([1.0], [1.0, -mod.alpha], drive)
    return np.maximum(pri, MIN_INTERVAL * period)


def _levels(mod: Modulation, u: np.ndarray) -> np.ndarray:
    """random_stagger's levels s_0..s_{m-1} from uniforms u (inverse CDFs): s_0 ~ pi, then i.i.d. from
    pi, or from row s_{n-1} of the transition matrix."""
    k = len(mod.pattern)
    start = np.minimum(np.searchsorted(np.cumsum(mod.level_probs()), u, side="right"), k - 1)
    if not mod.transition:
        return start
    cdf = np.cumsum(np.array(mod.transition), axis=1)
    s = np.empty(u.size, dtype=np.int64)
    s[:1] = start[:1]
    for j in range(1, u.size):
        s[j] = min(int(np.searchsorted(cdf[s[j - 1]], u[j], side="right")), k - 1)
    return s

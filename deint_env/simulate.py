"""The pulse simulator: `simulate(spec, seed)` -> `Episode`, vectorised numpy, bit-reproducible.

Order of effects, as a receiver sees them: each source emits on its own (modulated, cumulatively
jittered) schedule inside its on-windows; each emission is independently missed with
`missing_prob`; the survivors get white Gaussian TOA noise (sigma_w); a Poisson stream of spurious
pulses is added; everything is sorted by TOA; pulses closer than `coincidence_resolution` to their
predecessor merge into it (earlier TOA, summed amplitude, every source in the bit mask); the first
`n_pulses` are kept; amplitude measurement noise is added.

Every random stream is keyed by (seed, role, source), so the same spec and seed give the same
episode bit for bit, whatever env flavour asks for it, and a stream that a scenario does not use is
never made (making one costs ~10 us, a noticeable share of a short episode).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from deint_env.episode import Episode, Priors, Truth
from deint_env.errors import DeintError
from deint_env.scenario import Modulation, Range, ScenarioSpec, SourceSpec

_MIN_INTERVAL = 0.05  # intervals are clipped at this fraction of the PRI so a source never runs backwards
# The random streams' roles (the second word of their seed key).
DRAW, MISSING, JITTER, SPURIOUS, AMPLITUDE_NOISE, PRIORS, MODULATION, CUMULATIVE, AMPLITUDE = range(9)


def stream(seed: int, role: int, index: int = 0) -> np.random.Generator:
    """The generator of one role (and source): independent of every other by SeedSequence hashing."""
    return np.random.default_rng([seed, role, index])


def check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise DeintError(f"seed={seed!r} is invalid: an integer in [0, 2^63)")
    return int(seed)


def simulate(spec: ScenarioSpec, seed: int) -> Episode:
    """Simulate one episode of `spec`; see the module docstring for the order of effects."""
    seed = check_seed(seed)
    draw = stream(seed, DRAW)

    sources = spec.sources
    if spec.n_active is not None:
        lo, hi = spec.n_active
        sources = sources[: int(draw.integers(lo, hi + 1))]
    k = len(sources)
    period = np.array([_draw(s.period, draw) for s in sources])
    phase = np.array([_draw(s.phase, draw) if s.phase is not None else draw.random() * t
                      for s, t in zip(sources, period)])
    amp_mean = np.array([_draw(s.amplitude, draw) for s in sources])

    rate = float(np.sum(1.0 / period))
    h0 = spec.n_pulses / rate  # nominal duration: the windows' unit
    spur_intensity = spec.spurious_rate * rate
    t_start = float(min(phase.min(), 0.0))
    received_rate = rate * (1.0 - spec.missing_prob) + spur_intensity
    received_rate *= math.exp(-received_rate * spec.coincidence_resolution)  # merging thins the stream
    horizon = float(phase.max()) + (1.15 * spec.n_pulses + 20) / received_rate

    # Doubling the horizon replays the same streams, so the loop is as deterministic as one pass.
    for _ in range(16):
        sched, pulses = _generate(spec, seed, sources, period, phase, amp_mean, h0, horizon, t_start,
                                  spur_intensity)
        if pulses[0].size >= spec.n_pulses:
            break
        horizon *= 2
    else:  # pragma: no cover - validation keeps one source on to the end
        raise DeintError(f"scenario {spec.name!r}: fewer than {spec.n_pulses} pulses were generated")

    toa, source, mask, amplitude = (None if a is None else a[: spec.n_pulses] for a in pulses)
    if spec.amplitudes and spec.amplitude_noise_std > 0:
        amplitude = amplitude + spec.amplitude_noise_std * stream(seed, AMPLITUDE_NOISE).standard_normal(toa.size)
    truth = _truth(sched, period, phase, source, mask, toa[-1] + 8 * spec.toa_jitter_std
                   + spec.coincidence_resolution)
    priors = _priors(spec, period, phase, amp_mean, seed)
    return Episode(scenario=spec.name, seed=seed, toa=toa, amplitude=amplitude,
                   source=source, mask=mask, truth=truth, priors=priors)


def _draw(p: float | Range, rng: np.random.Generator) -> float:
    return p.draw(rng) if isinstance(p, Range) else float(p)


def _generate(spec, seed, sources, period, phase, amp_mean, h0, horizon, t_start, spur_intensity):
    # --- each source's schedule (noise-free emission times) ---
    times, pris, amps = [], [], []
    for i, src in enumerate(sources):
        t, pri, amp = _emissions(src, period[i], phase[i], amp_mean[i], spec.pri_jitter_std, h0, horizon,
                                 seed, i, spec.amplitudes)
        times.append(t), pris.append(pri), amps.append(amp)
    counts = np.array([t.size for t in times])
    offsets = np.concatenate([[0], np.cumsum(counts)])
    sched_t = np.concatenate(times)
    sched_src = np.repeat(np.arange(len(sources), dtype=np.int32), counts)

    # --- the receiver: misses, TOA noise, spurious pulses ---
    keep = None
    if spec.missing_prob > 0:
        keep = stream(seed, MISSING).random(sched_t.size) >= spec.missing_prob
    y = sched_t if keep is None else sched_t[keep]
    src = sched_src if keep is None else sched_src[keep]
    amp = None
    if spec.amplitudes:
        amp = np.concatenate(amps)
        amp = amp if keep is None else amp[keep]
    if spec.toa_jitter_std > 0:
        y = y + spec.toa_jitter_std * stream(seed, JITTER).standard_normal(y.size)
    if spur_intensity > 0:
        srng = stream(seed, SPURIOUS)
        n_spur = int(srng.poisson(spur_intensity * (horizon - t_start)))
        y = np.concatenate([y, t_start + (horizon - t_start) * np.sort(srng.random(n_spur))])
        src = np.concatenate([src, np.full(n_spur, -1, np.int32)])
        if amp is not None:
            amp = np.concatenate([amp, srng.uniform(0.5 * amp_mean.min(), 1.5 * amp_mean.max(), n_spur)])
    # The stable sort merges the few time-ordered runs (one per source, one of spurious pulses) fast;
    # with many runs numpy's SIMD default sort is faster.  Without ties every sort gives the same
    # order; with ties (exact coincidences without jitter) only the stable one is platform-independent.
    stable = len(sources) <= 3
    order = np.argsort(y, kind="stable" if stable else None)
    toa = y[order]
    if not stable and np.any(toa[1:] == toa[:-1]):
        order = np.argsort(y, kind="stable")
        toa = y[order]
    # Past `complete`, emissions after the horizon (not generated) could still have landed: cut there,
    # and gather the other columns only for the pulses the episode keeps.
    complete = horizon - 8 * spec.toa_jitter_std - spec.coincidence_resolution
    cut = int(np.searchsorted(toa, complete))
    starts = None
    if spec.coincidence_resolution > 0 and cut > 1:
        starts = np.flatnonzero(np.concatenate([[True], np.diff(toa[:cut]) >= spec.coincidence_resolution]))
        if starts.size > spec.n_pulses:
            cut = int(starts[spec.n_pulses])
            starts = starts[: spec.n_pulses]
    elif cut > spec.n_pulses:
        cut = spec.n_pulses
    order, toa = order[:cut], toa[:cut]
    src = src[order]
    amp = None if amp is None else amp[order]
    # One gather gives each pulse its bit; index -1 (spurious) picks the trailing 0.
    bit_of = np.append(np.left_shift(np.uint64(1), np.arange(len(sources), dtype=np.uint64)), np.uint64(0))
    bits = bit_of[src]
    if starts is not None and starts.size < toa.size:
        toa, src, bits, amp = _merge(toa, src, bits, amp, starts)
    sched = (sched_t, np.concatenate(pris), offsets)
    return sched, (toa, src, bits, amp)


def _emissions(src: SourceSpec, period: float, phase: float, amp_mean: float, cum_std: float, h0: float,
               horizon: float, seed: int, i: int, track_amplitude: bool):
    """One source's emission times in [phase, horizon), the PRI after each, and emitted amplitudes."""
    if horizon <= phase:
        return np.zeros(0), np.zeros(0), (np.zeros(0) if track_amplitude else None)
    m = int((horizon - phase) / (period * src.modulation.min_ratio())) + 16
    while True:
        pri = _pri(src.modulation, period, m, seed, i)
        intervals = pri if cum_std == 0 else pri + cum_std * stream(seed, CUMULATIVE, i).standard_normal(m)
        np.maximum(intervals, _MIN_INTERVAL * pri, out=intervals)
        t = np.empty(m)
        t[0] = phase
        np.cumsum(intervals[:-1], out=t[1:])
        t[1:] += phase
        if t[-1] >= horizon:
            break
        m *= 2
    n = int(np.searchsorted(t, horizon))
    t, pri = t[:n], pri[:n]
    amp = np.full(n, amp_mean) if track_amplitude else None
    if track_amplitude and src.amplitude_std > 0:
        amp += src.amplitude_std * stream(seed, AMPLITUDE, i).standard_normal(n)
        np.maximum(amp, 0.0, out=amp)
    if src.active:
        on = np.zeros(n, bool)
        for j, (a, b) in enumerate(src.active):
            stop = math.inf if (j == len(src.active) - 1 and b >= 1.0) else b * h0
            on |= (t >= a * h0) & (t < stop)
        t, pri, amp = t[on], pri[on], (None if amp is None else amp[on])
    return t, pri, amp


def _pri(mod: Modulation, period: float, m: int, seed: int, i: int) -> np.ndarray:
    """PRI_n for n = 0..m-1 (the interval after pulse n), per `Modulation`'s definitions."""
    kind = mod.kind
    if kind == "constant":
        return np.full(m, period)
    n = np.arange(m)
    if kind in ("stagger", "dwell_switch"):
        pattern = np.asarray(mod.pattern) / np.mean(mod.pattern)
        idx = n % pattern.size if kind == "stagger" else (n // mod.cycle) % pattern.size
        return period * pattern[idx]
    if kind == "sliding":
        return period * (1.0 + mod.depth * ((n % mod.cycle) / (mod.cycle - 1) - 0.5))
    if kind == "sinusoidal":
        psi = 2 * np.pi * stream(seed, MODULATION, i).random()
        return period * (1.0 + mod.depth * np.sin(2 * np.pi * n / mod.cycle + psi))
    # drifting (MK94 II-C-2): PRI_{n+1} = alpha PRI_n + drift_std v_n, a first-order recursion.
    drive = np.empty(m)
    drive[0] = period
    drive[1:] = mod.drift_std * stream(seed, MODULATION, i).standard_normal(m - 1)
    pri = lfilter([1.0], [1.0, -mod.alpha], drive)
    return np.maximum(pri, _MIN_INTERVAL * period)


def _merge(toa, src, bits, amp, starts):
    """Merge each run of pulses closer than the resolution to their predecessor (group `starts`).

    Merged runs are rare, so the work is a gather at the run starts plus scatters of the few others.
    """
    is_start = np.zeros(toa.size, bool)
    is_start[starts] = True
    rest = np.flatnonzero(~is_start)
    group = np.searchsorted(starts, rest, side="right") - 1
    mask = bits[starts]
    np.bitwise_or.at(mask, group, bits[rest])
    if amp is not None:
        merged_amp = amp[starts]
        np.add.at(merged_amp, group, amp[rest])  # energies add (MK94 II-A)
        amp = merged_amp
    primary = src[starts]
    # A run led by a spurious pulse takes its first real member as its primary source.
    real = src[rest] >= 0
    led_by_spurious = primary[group[real]] < 0
    if led_by_spurious.any():
        g, members = group[real][led_by_spurious], rest[real][led_by_spurious]
        _, first = np.unique(g, return_index=True)
        primary[g[first]] = src[members[first]]
    return toa[starts], primary, mask, amp


def _truth(sched, period, phase, source, mask, t_end) -> Truth:
    sched_t, sched_pri, offsets = sched
    k = period.size
    # Trim each source's schedule to the episode (plus the margin a late, jittered pulse needs).
    keep_t, keep_p, counts, final = [], [], [], np.empty(k)
    for i in range(k):
        t = sched_t[offsets[i]:offsets[i + 1]]
        p = sched_pri[offsets[i]:offsets[i + 1]]
        n = int(np.searchsorted(t, t_end, side="right"))
        keep_t.append(t[:n]), keep_p.append(p[:n]), counts.append(n)
        final[i] = p[n - 1] if n else np.nan
    n_received = np.bincount(source[source >= 0], minlength=k).astype(np.int64)
    multi = np.bitwise_and(mask, mask - np.uint64(1)) != 0  # merged pulses: more than one bit set
    if multi.any():
        m_mask, m_src = mask[multi], source[multi]
        for i in range(k):
            n_received[i] += np.count_nonzero((np.right_shift(m_mask, np.uint64(i)) & np.uint64(1)).astype(bool)
                                              & (m_src != i))
    return Truth(period=period, phase=phase, final_period=final, n_received=n_received,
                 schedule_toa=np.concatenate(keep_t), schedule_pri=np.concatenate(keep_p),
                 schedule_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))


def _priors(spec: ScenarioSpec, period, phase, amp_mean, seed: int) -> Priors:
    common = dict(jitter_std=spec.toa_jitter_std, pri_jitter_std=spec.pri_jitter_std,
                  missing_prob=spec.missing_prob, spurious_rate=spec.spurious_rate,
                  coincidence_resolution=spec.coincidence_resolution)
    if spec.blind:
        return Priors(n_labels=spec.label_budget, blind=True, **common)
    ps = spec.priors
    k = period.size
    rate = 1.0 / period
    if ps.kind == "explicit":
        n = len(ps.period)
        p_period = np.array(ps.period)
        p_phase = np.array(ps.phase) if ps.phase else np.full(n, np.nan)
        p_period_std = np.broadcast_to(np.array(ps.period_std), (n,)).copy()
        p_phase_std = np.broadcast_to(np.array(ps.phase_std), (n,)).copy()
        if not ps.phase:
            p_phase_std[:] = np.nan
        if ps.source_prob:
            prob = np.array(ps.source_prob)
        elif n == k:  # the relative frequencies are known (MK94 IV-2)
            prob = rate / rate.sum()
        else:
            prob = np.full(n, 1.0 / n)
    else:
        z = stream(seed, PRIORS).standard_normal((2, k))
        p_period = period * ps.period_bias * (1.0 + ps.period_error * z[0])
        p_period_std = p_period * max(ps.period_error, abs(ps.period_bias - 1.0), 1e-3)
        if ps.phase_error is None:
            p_phase = np.full(k, np.nan)
            p_phase_std = np.full(k, np.nan)
        else:
            p_phase = phase + ps.phase_error * period * z[1]
            p_phase_std = period * max(ps.phase_error, 1e-3)
        prob = np.array(ps.source_prob) if ps.source_prob else rate / rate.sum()
        n = k
    amplitude = amplitude_std = None
    if spec.amplitudes:
        amplitude = np.zeros(n)
        amplitude_std = np.full(n, spec.amplitude_noise_std)
        m = min(n, k)
        amplitude[:m] = amp_mean[:m]
        amplitude_std[:m] = np.hypot([s.amplitude_std for s in spec.sources[:m]], spec.amplitude_noise_std)
        amplitude_std = np.maximum(amplitude_std, 1e-3 * max(amp_mean.max(), 1e-9))
        if n > k:  # phantom tracks: the mean amplitude of the real ones
            amplitude[k:] = amp_mean.mean()
    return Priors(n_labels=n, period=p_period, phase=p_phase, period_std=p_period_std, phase_std=p_phase_std,
                  source_prob=prob, amplitude=amplitude, amplitude_std=amplitude_std, **common)

"""The pulse simulator: `simulate_many(spec, seeds)` -> `Episode`s, batched numpy, bit-reproducible.

Order of effects, as a receiver sees them: each source emits on its own (modulated, cumulatively
jittered) schedule inside its on-windows; each emission is independently missed with
`missing_prob`; the survivors get white Gaussian TOA noise (sigma_w); a Poisson stream of spurious
pulses is added; everything is sorted by TOA; pulses closer than `coincidence_resolution` to their
predecessor merge into it (earlier TOA, summed amplitude, every source in the bit mask); the first
`n_pulses` are kept; amplitude measurement noise is added.

Every random stream is keyed by (seed, role, source), so the same spec and seed give the same
episode bit for bit, whatever env flavour asks for it and however many episodes are simulated
together; a stream that a scenario does not use is never made (making one costs ~7 us, a
noticeable share of a short episode).

Batching: the episodes of one call are simulated together as the rows of 2-D arrays (padded with
values that sort last, or masked), so the numpy call overhead, most of a 1000-pulse episode's
cost, is paid once per batch.  Python loops over episodes remain where each episode draws from its
own generators (whose seeding is itself batched, see `streams`), where each episode gets its own
arrays and objects, and on the rare per-episode paths (merged pulses, random modulations, a
horizon that falls short).  Each row goes through exactly the float operations, in the same
order, as a lone episode would: sequential sums (`cumsum`), elementwise arithmetic and reductions
along contiguous rows do not depend on the batch; transcendental functions (`math.exp`, `np.sin`)
are applied per episode.  tests/test_episode_hashes.py pins the episodes bit for bit.

With `spec.waveform` (DM89's front end, `ScenarioSpec.waveform`) the episode's pulses then go through
the channel and the detection-oriented Kalman filter, and the episode holds the detections.
"""

from __future__ import annotations

import dataclasses

import itertools
import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np
from scipy.signal import lfilter

from deint_env.episode import Episode, Priors, Truth
from deint_env.errors import DeintError
from deint_env.scenario import Modulation, Range, ScenarioSpec, SourceSpec

_MIN_INTERVAL = 0.05  # intervals are clipped at this fraction of the PRI so a source never runs backwards
# The random streams' roles (the second word of their seed key).
DRAW, MISSING, JITTER, SPURIOUS, AMPLITUDE_NOISE, PRIORS, MODULATION, CUMULATIVE, AMPLITUDE, WAVEFORM = range(10)
_RANDOM_MODULATIONS = ("sinusoidal", "drifting")  # drawn per episode
# Episodes simulated together hold about this many pulses: the temporaries then stay in cache and are
# reused by the allocator (fresh pages fault, and faults are costly).
_BATCH_PULSES = 1 << 18


def stream(seed: int, role: int, index: int = 0) -> np.random.Generator:
    """The generator of one role (and source): independent of every other by SeedSequence hashing."""
    return np.random.default_rng([seed, role, index])


# Seeding a batch: numpy's SeedSequence (O'Neill's seed_seq hash) and PCG64 seeding, vectorised.
_SEED_BATCH = 32  # from this many streams on, seeding them together beats numpy's ~7 us per stream
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R, _MASK32 = np.uint32(0xCA01F9DD), np.uint32(0x4973F715), 0xFFFFFFFF
_PCG_MULT, _MASK128 = 0x2360ED051FC65DA44385DF649FCCF645, 2**128 - 1


def streams(seeds: Sequence[int], role: int, index: int = 0) -> Iterator[np.random.Generator]:
    """`stream(seed, role, index)` for each seed in turn, each to be used up before the next is asked
    for.  A batch's generator states are computed together (numpy's SeedSequence hashing and PCG64
    seeding, which numpy keeps stable, in vectorised arithmetic; tests compare them with `stream`)
    and loaded into one reused generator: ~1 us a stream instead of ~7."""
    if len(seeds) < _SEED_BATCH:
        yield from (stream(seed, role, index) for seed in seeds)
        return
    bit_generator = np.random.PCG64()
    rng = np.random.Generator(bit_generator)
    for state, inc in _pcg64_states(seeds, role, index):
        bit_generator.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc},
                               "has_uint32": 0, "uinteger": 0}
        yield rng


def _pcg64_states(seeds: Sequence[int], role: int, index: int) -> list[tuple[int, int]]:
    """The PCG64 (state, inc) that `np.random.default_rng([seed, role, index])` starts from."""
    seed = np.array(seeds, np.uint64)
    lo, hi = (seed & np.uint64(_MASK32)).astype(np.uint32), (seed >> np.uint64(32)).astype(np.uint32)
    two = hi > 0  # a seed >= 2^32 takes two entropy words, lowest first
    entropy = [lo, np.where(two, hi, np.uint32(role)), np.where(two, np.uint32(role), np.uint32(index)),
               np.where(two, np.uint32(index), np.uint32(0))]  # short entropy is hashed as if 0-padded
    hash_const = _INIT_A

    def hashmix(value):
        nonlocal hash_const
        value = value ^ np.uint32(hash_const)
        hash_const = hash_const * _MULT_A & _MASK32
        value = value * np.uint32(hash_const)
        return value ^ (value >> np.uint32(16))

    pool = [hashmix(word) for word in entropy]
    for i_src in range(4):
        for i_dst in range(4):
            if i_src != i_dst:
                mixed = _MIX_L * pool[i_dst] - _MIX_R * hashmix(pool[i_src])
                pool[i_dst] = mixed ^ (mixed >> np.uint32(16))
    hash_const = _INIT_B
    words = []  # generate_state(4, np.uint64): 8 words, little-endian pairs
    for i in range(8):
        value = pool[i % 4] ^ np.uint32(hash_const)
        hash_const = hash_const * _MULT_B & _MASK32
        value = value * np.uint32(hash_const)
        words.append((value ^ (value >> np.uint32(16))).astype(np.uint64))
    w = [(words[2 * j] | (words[2 * j + 1] << np.uint64(32))).tolist() for j in range(4)]
    states = []
    for w0, w1, w2, w3 in zip(*w):  # pcg_setseq_128_srandom_r(initstate, initseq)
        inc = ((w2 << 64 | w3) << 1 | 1) & _MASK128
        states.append((((inc + (w0 << 64 | w1)) * _PCG_MULT + inc) & _MASK128, inc))
    return states


def check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise DeintError(f"seed={seed!r} is invalid: an integer in [0, 2^63)")
    return int(seed)


def simulate(spec: ScenarioSpec, seed: int) -> Episode:
    """Simulate one episode of `spec`; see the module docstring for the order of effects."""
    return simulate_many(spec, [seed])[0]


def simulate_many(spec: ScenarioSpec, seeds: Sequence[int]) -> list[Episode]:
    """One episode of `spec` per seed, each bit-identical to `simulate(spec, seed)`, made together."""
    seeds = [check_seed(s) for s in seeds]
    size = max(1, _BATCH_PULSES // spec.n_pulses)
    episodes = [episode for start in range(0, len(seeds), size)
                for episode in _simulate_batch(spec, seeds[start:start + size])]
    return [_detect(spec, ep) for ep in episodes] if spec.waveform is not None else episodes


def _detect(spec: ScenarioSpec, ep: Episode) -> Episode:
    """The waveform front end (`ScenarioSpec.waveform`): the episode's pulses through DM89's channel and
    detector; the detections, with their true sources, become the episode."""
    from baselines.dokf import detect_pulses  # the detector is a reference algorithm of baselines/

    w = spec.waveform
    height = ep.amplitude if ep.amplitude is not None else np.ones(len(ep))
    origin = min(0.0, float(ep.toa[0]))  # the detector's grid starts at 0
    horizon = float(ep.toa[-1] - origin)
    lam = w.spike_prob if w.spike_prob is not None else min(0.5, len(ep) * w.sample_period / max(horizon, 1e-300))
    sigma_r = w.spike_std if w.spike_std is not None else float(np.sqrt(np.mean(height ** 2)))
    det = detect_pulses(ep.toa - origin, height, w.sample_period, w.channel, w.noise_std, lam, sigma_r,
                        stream(ep.seed, WAVEFORM))
    hit = det.pulse >= 0
    source = np.where(hit, ep.source[np.maximum(det.pulse, 0)], -1).astype(np.int32)
    mask = np.zeros(det.toa.size, dtype=np.uint64)  # every pulse on a detection's sample is in it
    carried = det.detection >= 0
    np.bitwise_or.at(mask, det.detection[carried], ep.mask[carried])
    k = ep.truth.n_sources
    n_received = np.array([np.count_nonzero(np.right_shift(mask, np.uint64(i)) & np.uint64(1)) for i in range(k)],
                          dtype=np.int64)
    truth = dataclasses.replace(ep.truth, n_received=n_received)
    return dataclasses.replace(ep, toa=det.toa + origin, amplitude=det.amplitude if ep.amplitude is not None
                               else None, source=source, mask=mask, truth=truth)


def _simulate_batch(spec: ScenarioSpec, seeds: list[int]) -> list[Episode]:
    drawn = [_draw_sources(spec, rng) for rng in streams(seeds, DRAW)]
    episodes: list[Episode] = [None] * len(seeds)  # type: ignore[list-item]
    # Episodes with the same sources share arrays; only blind `n_active` scenarios have several groups.
    for k in sorted({len(period) for period, _, _ in drawn}):
        rows = [j for j, (period, _, _) in enumerate(drawn) if len(period) == k]
        period, phase, amp_mean = (np.array([drawn[j][f] for j in rows]) for f in range(3))
        group = _simulate_group(spec, spec.sources[:k], [seeds[j] for j in rows], period, phase, amp_mean)
        for j, episode in zip(rows, group):
            episodes[j] = episode
    return episodes


def _draw_sources(spec: ScenarioSpec, draw: np.random.Generator) -> tuple[list[float], list[float], list[float]]:
    """The episode's source count and per-source period, phase and mean amplitude (its DRAW stream)."""
    sources = spec.sources
    if spec.n_active is not None:
        lo, hi = spec.n_active
        sources = sources[: int(draw.integers(lo, hi + 1))]
    period = [_draw(s.period, draw) for s in sources]
    phase = [_draw(s.phase, draw) if s.phase is not None else draw.random() * t for s, t in zip(sources, period)]
    amp_mean = [_draw(s.amplitude, draw) for s in sources]
    return period, phase, amp_mean


def _draw(p: float | Range, rng: np.random.Generator) -> float:
    return p.draw(rng) if isinstance(p, Range) else float(p)


def _fill(blocks: list[np.ndarray], seeds: list[int], role: int, index: int = 0, counts: np.ndarray | None = None,
          normal: bool = True) -> None:
    """Deal each episode's standard normals (or uniforms in [0, 1)) from its own stream (seed, role,
    index) to row j of each block in turn, `counts[j, b]` entries of block b (default: whole rows).

    A draw of size a then one of size b continue the stream exactly as one draw of size a + b, so
    the rows hold exactly what the lone episode draws in one call."""
    per_row = itertools.repeat([block.shape[1] for block in blocks]) if counts is None else counts.tolist()
    for j, (rng, row_counts) in enumerate(zip(streams(seeds, role, index), per_row)):
        draw = rng.standard_normal if normal else rng.random
        for block, c in zip(blocks, row_counts):
            draw(out=block[j, :c])


def _compact(keep: np.ndarray, t: np.ndarray, *others: np.ndarray | None):
    """Move each row's kept entries to its front, in order: their counts, the times (+inf past the
    kept ones) and the other arrays.  (Boolean masks pair the kept and the front entries row-major.)"""
    count = keep.sum(axis=1)
    shape = (count.size, count.max())
    front = None if count.min() == shape[1] else np.arange(shape[1]) < count[:, None]  # None: no padding
    out = []
    for a, pad in ((t, np.inf), *((a, 0.0) for a in others)):
        if a is None:
            pass
        elif a.strides[1] == 0:  # constant along each row (a broadcast): it stays so
            a = np.broadcast_to(a[:, :1], shape)
        elif front is None:
            a = a[keep].reshape(shape)
        else:
            b = np.full(shape, pad)
            b[front] = a[keep]
            a = b
        out.append(a)
    return (count, *out)


def _take_rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """`np.take_along_axis(a, idx, axis=1)` for a C-contiguous `a`, as one flat take (2-5x faster)."""
    if a.shape[0] > 1:  # (one row: the flat indices are idx itself)
        idx = idx + (np.arange(a.shape[0]) * a.shape[1])[:, None]
    return np.take(a.ravel(), idx)


@dataclass
class _Group:
    """The per-episode draws and derived constants of episodes with the same sources (one row each)."""

    seeds: list[int]
    period: np.ndarray  # (E, k)
    phase: np.ndarray  # (E, k)
    amp_mean: np.ndarray  # (E, k)
    h0: np.ndarray  # (E,) nominal duration: the windows' unit
    spur_intensity: np.ndarray  # (E,)
    t_start: np.ndarray  # (E,)

    def take(self, rows: np.ndarray) -> _Group:
        return _Group([self.seeds[j] for j in rows.tolist()], self.period[rows], self.phase[rows],
                      self.amp_mean[rows], self.h0[rows], self.spur_intensity[rows], self.t_start[rows])


def _simulate_group(spec: ScenarioSpec, sources: tuple[SourceSpec, ...], seeds: list[int], period: np.ndarray,
                    phase: np.ndarray, amp_mean: np.ndarray) -> list[Episode]:
    rate = (1.0 / period).sum(axis=1)
    pmin = phase.min(axis=1)
    g = _Group(seeds, period, phase, amp_mean, h0=spec.n_pulses / rate, spur_intensity=spec.spurious_rate * rate,
               t_start=np.where(pmin > 0.0, 0.0, pmin))  # min(phase.min(), 0.0)
    received_rate = rate * (1.0 - spec.missing_prob) + g.spur_intensity
    # merging thins the stream (math.exp per episode: np.exp may round differently)
    received_rate *= [math.exp(-r * spec.coincidence_resolution) for r in received_rate.tolist()]
    horizon = phase.max(axis=1) + (1.15 * spec.n_pulses + 20) / received_rate
    priors = _priors(spec, g)

    episodes: list[Episode] = [None] * len(seeds)  # type: ignore[list-item]
    # An episode whose horizon falls short is redone with the horizon doubled: the same streams replay,
    # so this is as deterministic as one pass.  Each doubling halves the rows redone together, so a
    # batch never holds much more than _BATCH_PULSES pulses' worth of work.
    todo = [(np.arange(len(seeds)), horizon, 0)]  # (rows, their horizons, doublings so far)
    while todo:
        rows, horizon, doublings = todo.pop()
        if doublings == 8:  # 256x the nominal duration: validation should make this unreachable
            raise DeintError(f"scenario {spec.name!r}: fewer than {spec.n_pulses} pulses within 256 times the "
                             "nominal duration (do the sources stop, or merge into one another?)")
        batch = g if rows.size == len(seeds) else g.take(rows)
        done, toa, source, mask, amplitude, truths = _generate(spec, sources, batch, horizon)
        for j, t, s, m, a, truth in zip(rows[done].tolist(), toa, source, mask, amplitude, truths):
            episodes[j] = Episode(scenario=spec.name, seed=seeds[j], toa=t, amplitude=a, source=s, mask=m,
                                  truth=truth, priors=priors[j])
        rows, horizon = rows[~done], horizon[~done] * 2
        size = max(1, _BATCH_PULSES // (spec.n_pulses << (doublings + 1)))
        todo += [(rows[a:a + size], horizon[a:a + size], doublings + 1) for a in range(0, rows.size, size)]
    return episodes


def _generate(spec: ScenarioSpec, sources: tuple[SourceSpec, ...], g: _Group, horizon: np.ndarray):
    """Simulate every row up to its horizon: which rows made n_pulses pulses, and their episodes'
    toa, source, mask, amplitude (rows, or Nones) and truth.

    Each source's pulses stay in a (rows, width) block, every row's own pulses first, in time order,
    then padding at or past the horizon; the blocks side by side, spurious pulses last, are the lone
    episode's concatenation with the padding in between, which sorts after every pulse that counts."""
    n_rows, k, n = len(g.seeds), len(sources), spec.n_pulses
    # --- each source's schedule (noise-free emission times) ---
    # m emissions per source, doubled until the m-th reaches the horizon, as per episode: a row with
    # random intervals must draw exactly what the lone episode draws.  (m >= 1 even past the horizon.)
    min_ratio = np.array([src.modulation.min_ratio() for src in sources])
    m = np.maximum(((horizon[:, None] - g.phase) / (g.period * min_ratio)).astype(np.int64) + 16, 1)
    sched = [_emissions(src, g.period[:, i], g.phase[:, i], g.amp_mean[:, i], m[:, i], spec.pri_jitter_std, g.h0,
                        horizon, g.seeds, i, spec.amplitudes) for i, src in enumerate(sources)]
    y, amp, col_src = _receive(spec, g, horizon, sched)

    # --- sort each row; past `complete`, emissions after the horizon (not generated) could still
    # have landed, so only the pulses before it count ---
    bit_of = np.left_shift(np.uint64(1), np.arange(k + 1, dtype=np.uint64))
    bit_of[k] = 0  # source -1 (spurious): no bit
    # The stable sort merges the few time-ordered runs (one per source, one of spurious pulses) fast;
    # with many runs numpy's SIMD default sort is faster.  Without ties every sort gives the same
    # order; with ties (exact coincidences without jitter) only the stable one is platform-independent.
    stable = k <= 3
    order = np.argsort(y, axis=1, kind="stable" if stable else None)
    complete = horizon - 8 * spec.toa_jitter_std - spec.coincidence_resolution
    # The sorted pulses that decide the episode: without merging, pulses n - 1 and n (a tie between
    # them matters); with it, the runs up to the cut.
    if spec.coincidence_resolution > 0:
        cut = (y < complete[:, None]).sum(axis=1)
        seen = cut.max()
    else:
        seen = min(n + 1, y.shape[1])
    toa = _take_rows(y, order[:, :seen])
    if not stable:
        tied = (((toa[:, 1:] == toa[:, :-1]) & (toa[:, 1:] < np.inf)).any(axis=1)).nonzero()[0]
        if tied.size:
            order[tied] = np.argsort(y[tied], axis=1, kind="stable")
            toa[tied] = _take_rows(y[tied], order[tied, :seen])
    del y  # free the big temporaries as soon as they are used up: the allocator reuses their pages
    merged = np.zeros(n_rows, bool)
    if spec.coincidence_resolution > 0:
        starts = np.ones(toa.shape, bool)  # the first pulse of each run closer than the resolution
        with np.errstate(invalid="ignore"):  # inf - inf in the padding, which is past the row's cut
            starts[:, 1:] = np.diff(toa, axis=1) >= spec.coincidence_resolution
        if cut.min() < seen:
            starts &= np.arange(seen) < cut[:, None]
        n_runs = starts.sum(axis=1)
        done = n_runs >= n
        runs = {}  # the first pulses of the n runs kept, of the rows that had more
        for r in (n_runs > n).nonzero()[0].tolist():  # keep n runs: cut where run n + 1 starts
            first = starts[r].nonzero()[0]
            cut[r], runs[r] = first[n], first[:n]
        merged = done & (cut > n)
    else:
        done = toa[:, n - 1] < complete if seen >= n else np.zeros(n_rows, bool)

    # --- the kept pulses of the finished rows; merged rows (rare) go through `_merge` one by one ---
    d = done.nonzero()[0]
    merged_d = merged[d].nonzero()[0]
    # Most rows keep their first n sorted pulses as they are; usually all rows finish at once, and
    # slices then gather without copying rows first.
    plain = slice(None) if d.size == n_rows and not merged_d.size else d[~merged[d]]
    head = order[plain, :n]
    if merged_d.size:
        toa_d, src_d = np.empty((d.size, n)), np.empty((d.size, n), np.int32)
        mask_d, amp_d = np.empty((d.size, n), np.uint64), None if amp is None else np.empty((d.size, n))
        rest = (~merged[d]).nonzero()[0]
        toa_d[rest], src_d[rest] = toa[plain, :n], col_src[head]
        mask_d[rest] = bit_of[src_d[rest]]
        if amp is not None:
            amp_d[rest] = _take_rows(amp[plain], head)
    else:
        toa_d, src_d = np.ascontiguousarray(toa[plain, :n]), col_src[head]
        mask_d = bit_of[src_d]
        amp_d = None if amp is None else _take_rows(amp[plain], head)
    for j in merged_d.tolist():
        r, c = d[j], cut[d[j]]
        o = order[r, :c]
        src = col_src[o]
        first = runs[r] if r in runs else starts[r, :c].nonzero()[0]
        _merge(toa[r, :c], src, bit_of[src], None if amp is None else amp[r][o], first,
               (toa_d[j], src_d[j], mask_d[j], None if amp_d is None else amp_d[j]))
    del order, head, toa, amp
    if spec.amplitudes and spec.amplitude_noise_std > 0:
        z = np.empty(amp_d.shape)
        _fill([z], [g.seeds[r] for r in d.tolist()], AMPLITUDE_NOISE)
        amp_d = amp_d + spec.amplitude_noise_std * z

    t_end = np.full(n_rows, -np.inf)  # no truth for the unfinished rows
    t_end[d] = toa_d[:, -1] + 8 * spec.toa_jitter_std + spec.coincidence_resolution
    truths = _truth(g.period[d], g.phase[d], [t for t, _, _, _ in sched], [p for _, p, _, _ in sched], d, t_end,
                    src_d, mask_d, merged_d.size > 0)
    return done, toa_d, src_d, mask_d, [None] * d.size if amp_d is None else amp_d, truths


def _receive(spec: ScenarioSpec, g: _Group, horizon: np.ndarray, sched: list):
    """The receiver: misses, TOA noise and spurious pulses.  Returns each episode's received pulses
    as a row (the source blocks side by side, spurious pulses last; padding sorts last), their
    amplitudes (or None) and each column's source (-1: spurious)."""
    n_rows, k = len(g.seeds), len(sched)
    counts = np.array([c for _, _, _, c in sched]).T  # (rows, sources)
    ys, amps = [t for t, _, _, _ in sched], [a for _, _, a, _ in sched]

    if spec.missing_prob > 0:
        counts, ys, amps = _miss(spec.missing_prob, g.seeds, counts, ys, amps)
    labels = list(range(k))
    if spec.spurious_rate > 0:
        span = horizon - g.t_start
        amp_lo, amp_hi = 0.5 * g.amp_mean.min(axis=1), 1.5 * g.amp_mean.max(axis=1)
        spur_u, spur_a = [], []
        for j, (rng, lam) in enumerate(zip(streams(g.seeds, SPURIOUS), (g.spur_intensity * span).tolist())):
            c = int(rng.poisson(lam))
            spur_u.append(np.sort(rng.random(c)))
            if amps[0] is not None:
                spur_a.append(rng.uniform(amp_lo[j], amp_hi[j], c))
        labels.append(-1)

    # One row per episode: the source blocks side by side, then the spurious pulses.
    widths = [t.shape[1] for t in ys] + ([max(u.size for u in spur_u)] if len(labels) > k else [])
    edges = [0, *itertools.accumulate(widths)]
    y = np.zeros((n_rows, edges[-1]))
    blocks = [y[:, a:b] for a, b in zip(edges, edges[1:])]
    if spec.toa_jitter_std > 0:  # the normals are drawn in place: y = t + sigma_w z
        _fill(blocks[:k], g.seeds, JITTER, counts=counts)
        for block, t in zip(blocks, ys):
            block *= spec.toa_jitter_std
            block += t
    else:
        for block, t in zip(blocks, ys):
            block[...] = t
    amp = None
    if amps[0] is not None:
        amp = np.zeros(y.shape)
        for a, b, block in zip(edges, edges[1:], amps):
            amp[:, a:b] = block
    if len(labels) > k:
        spur = blocks[k]
        spur[...] = np.inf
        for j, u in enumerate(spur_u):
            spur[j, :u.size] = u
            if amp is not None:
                amp[j, edges[k]:edges[k] + u.size] = spur_a[j]
        spur *= span[:, None]  # t_start + span * u, in place
        spur += g.t_start[:, None]

    return y, amp, np.repeat(np.array(labels, np.int32), widths)


def _miss(prob: float, seeds: list[int], counts: np.ndarray, ts: list[np.ndarray], amps: list[np.ndarray | None]):
    """Each emission is missed with probability `prob`: the kept counts, times and amplitudes."""
    us = [np.zeros(t.shape) for t in ts]  # padding: 0, never kept
    _fill(us, seeds, MISSING, counts=counts, normal=False)
    kept = [_compact(u >= prob, t, a) for u, t, a in zip(us, ts, amps)]
    return np.array([c for c, _, _ in kept]).T, [t for _, t, _ in kept], [a for _, _, a in kept]


def _emissions(src: SourceSpec, period: np.ndarray, phase: np.ndarray, amp_mean: np.ndarray, m: np.ndarray,
               cum_std: float, h0: np.ndarray, horizon: np.ndarray, seeds: list[int], i: int, track_amplitude: bool):
    """Source i's emissions in [phase, horizon) inside its on-windows, per episode (row), from m
    scheduled ones: times, the PRI after each, emitted amplitudes (or None), and their counts;
    padding: times >= the horizon."""
    t, pri = _schedule(src.modulation, period, phase, m, cum_std, seeds, i)
    count = (t < horizon[:, None]).sum(axis=1)
    short = (count >= m).nonzero()[0]  # the m-th emission is before the horizon (random rows only)
    while short.size:
        m[short] *= 2
        t_short, pri_short = _schedule(src.modulation, period[short], phase[short], m[short], cum_std,
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
            _fill([z], seeds, AMPLITUDE, i, counts=count[:, None])
            amp = np.maximum(amp + src.amplitude_std * z, 0.0)
    if src.active:
        on = np.arange(t.shape[1]) < count[:, None]
        inside = np.zeros(t.shape, bool)
        for j, (a, b) in enumerate(src.active):
            stop = math.inf if (j == len(src.active) - 1 and b >= 1.0) else (b * h0)[:, None]
            inside |= (t >= (a * h0)[:, None]) & (t < stop)
        count, t, pri, amp = _compact(on & inside, t, pri, amp)
    return t, pri, amp, count


def _schedule(mod: Modulation, period: np.ndarray, phase: np.ndarray, m: np.ndarray, cum_std: float,
              seeds: list[int], i: int) -> tuple[np.ndarray, np.ndarray]:
    """Emission times and PRIs of at least m[j] emissions per row: exactly m[j] (then +inf) where
    the intervals are random; where they are not, the rest of the row continues the schedule (so
    either way, the m-th emission is before the horizon iff at least m emissions are)."""
    width = int(m.max())
    pri = _pri(mod, period, m, width, seeds, i)
    intervals = pri  # PRIs are positive: only jittered intervals need clipping
    if cum_std > 0:
        z = np.zeros(pri.shape)
        _fill([z], seeds, CUMULATIVE, i, counts=m[:, None])
        intervals = np.maximum(pri + cum_std * z, _MIN_INTERVAL * pri)
    t = np.empty(pri.shape)
    t[:, 0] = phase
    np.cumsum(intervals[:, :-1], axis=1, out=t[:, 1:])
    t[:, 1:] += phase[:, None]
    if cum_std > 0 or mod.kind in _RANDOM_MODULATIONS:
        t[np.arange(width) >= m[:, None]] = np.inf
    return t, pri


def _pri(mod: Modulation, period: np.ndarray, m: np.ndarray, width: int, seeds: list[int], i: int) -> np.ndarray:
    """PRI_n for n = 0..width-1 (the interval after pulse n) per row, per `Modulation`'s definitions;
    random modulations are drawn per episode and defined up to m[j] only (zeros past it)."""
    kind = mod.kind
    if kind in _RANDOM_MODULATIONS:
        out = np.zeros((period.size, width))
        for row, t, c, seed in zip(out, period.tolist(), m.tolist(), seeds):
            row[:c] = _random_pri(mod, t, c, seed, i)
        return out
    if kind == "constant":
        return np.broadcast_to(period[:, None], (period.size, width))
    n = np.arange(width)
    if kind in ("stagger", "dwell_switch"):
        pattern = np.asarray(mod.pattern) / np.mean(mod.pattern)
        ratio = pattern[n % pattern.size if kind == "stagger" else (n // mod.cycle) % pattern.size]
    else:  # sliding
        ratio = 1.0 + mod.depth * ((n % mod.cycle) / (mod.cycle - 1) - 0.5)
    return period[:, None] * ratio


def _random_pri(mod: Modulation, period: float, m: int, seed: int, i: int) -> np.ndarray:
    """One episode's m PRIs of a modulation with a random part (its own MODULATION stream)."""
    n = np.arange(m)
    if mod.kind == "sinusoidal":
        psi = 2 * np.pi * stream(seed, MODULATION, i).random()
        return period * (1.0 + mod.depth * np.sin(2 * np.pi * n / mod.cycle + psi))
    # drifting (MK94 II-C-2): PRI_{n+1} = alpha PRI_n + drift_std v_n, a first-order recursion.
    drive = np.empty(m)
    drive[0] = period
    drive[1:] = mod.drift_std * stream(seed, MODULATION, i).standard_normal(m - 1)
    pri = lfilter([1.0], [1.0, -mod.alpha], drive)
    return np.maximum(pri, _MIN_INTERVAL * period)


def _merge(toa, src, bits, amp, starts, out) -> None:
    """Merge each run of pulses closer than the resolution to their predecessor (group `starts`)
    into `out` = (toa, source, mask, amplitude or None) rows.

    Merged runs are rare, so the work is a gather at the run starts plus scatters of the few others.
    """
    out_toa, primary, mask, out_amp = out
    is_start = np.zeros(toa.size, bool)
    is_start[starts] = True
    rest = np.flatnonzero(~is_start)
    group = np.searchsorted(starts, rest, side="right") - 1
    # (The run starts are valid indices; mode="clip" spares np.take the buffered copy of `out`.)
    np.take(toa, starts, out=out_toa, mode="clip")
    np.take(bits, starts, out=mask, mode="clip")
    np.bitwise_or.at(mask, group, bits[rest])
    if amp is not None:
        np.take(amp, starts, out=out_amp, mode="clip")
        np.add.at(out_amp, group, amp[rest])  # energies add (MK94 II-A)
    np.take(src, starts, out=primary, mode="clip")
    # A run led by a spurious pulse takes its first real member as its primary source.
    real = src[rest] >= 0
    led_by_spurious = primary[group[real]] < 0
    if led_by_spurious.any():
        g, members = group[real][led_by_spurious], rest[real][led_by_spurious]
        _, first = np.unique(g, return_index=True)
        primary[g[first]] = src[members[first]]


def _truth(period, phase, sched_t, sched_pri, rows, t_end, source, mask, merged: bool) -> list[Truth]:
    """The truth of the finished `rows` (pulses `source`, `mask`; `merged`: whether any pulse merged):
    each source's schedule trimmed to the episode, plus the margin a late, jittered pulse needs
    (`t_end` per row of the batch)."""
    n_done, k = period.shape
    # A prefix of each source's time-ordered schedule; gathering the prefixes row by row copies only
    # what is kept (a vectorised gather would read the padding too, about as much again).
    counts = np.array([(t <= t_end[:, None]).sum(axis=1)[rows] for t in sched_t]).T  # (rows, sources)
    final = np.full((n_done, k), np.nan)
    for i, (p, c) in enumerate(zip(sched_pri, counts.T)):
        some = c.nonzero()[0]
        final[some, i] = p[rows[some], c[some] - 1]
    offsets = np.zeros((n_done, k + 1), np.int64)
    np.cumsum(counts, axis=1, out=offsets[:, 1:])

    # Received pulses per (row, source): one bincount over row-offset sources (-1, spurious, -> column 0).
    offset = (np.arange(n_done, dtype=np.int64) * (k + 1) + 1)[:, None]
    n_received = np.bincount((source + offset).ravel(), minlength=n_done * (k + 1)).reshape(n_done, k + 1)[:, 1:]
    n_received = np.ascontiguousarray(n_received, dtype=np.int64)
    multi = np.bitwise_and(mask, mask - np.uint64(1)) != 0 if merged else None  # more than one bit set
    if merged and multi.any():  # a merged pulse also counts for its other sources
        per_row = multi.sum(axis=1)
        some = per_row.nonzero()[0]
        first = (np.cumsum(per_row) - per_row)[some]  # where each row's merged pulses start, row-major
        m_mask, m_src = mask[multi], source[multi]
        for i in range(k):
            member = (np.right_shift(m_mask, np.uint64(i)) & np.uint64(1)).astype(bool) & (m_src != i)
            n_received[some, i] += np.add.reduceat(member, first, dtype=np.int64)
    return [Truth(period=per, phase=ph, final_period=fin, n_received=rec,
                  schedule_toa=np.concatenate([t[r, :c] for t, c in zip(sched_t, row)]),
                  schedule_pri=np.concatenate([p[r, :c] for p, c in zip(sched_pri, row)]), schedule_offsets=off)
            for per, ph, fin, rec, off, r, row in zip(period, phase, final, n_received, offsets, rows.tolist(),
                                                      counts.tolist())]


def _priors(spec: ScenarioSpec, g: _Group) -> list[Priors]:
    common = dict(jitter_std=spec.toa_jitter_std, pri_jitter_std=spec.pri_jitter_std,
                  missing_prob=spec.missing_prob, spurious_rate=spec.spurious_rate,
                  coincidence_resolution=spec.coincidence_resolution)
    if spec.blind:
        return [Priors(n_labels=spec.label_budget, blind=True, **common) for _ in g.seeds]
    ps = spec.priors
    period, phase, amp_mean = g.period, g.phase, g.amp_mean
    n_rows, k = period.shape
    rate = 1.0 / period

    def rows(values) -> np.ndarray:  # one row per episode
        return np.repeat(np.asarray(values, dtype=np.float64)[None], n_rows, axis=0)

    if ps.kind == "explicit":
        n = len(ps.period)
        p_period = rows(ps.period)
        p_phase = rows(ps.phase if ps.phase else np.full(n, np.nan))
        p_period_std = rows(np.broadcast_to(np.array(ps.period_std), (n,)))
        p_phase_std = rows(np.broadcast_to(np.array(ps.phase_std), (n,)) if ps.phase else np.full(n, np.nan))
        if ps.source_prob:
            prob = rows(ps.source_prob)
        elif n == k:  # the relative frequencies are known (MK94 IV-2)
            prob = rate / rate.sum(axis=1, keepdims=True)
        else:
            prob = np.full((n_rows, n), 1.0 / n)
    else:
        z = np.empty((n_rows, 2, k))
        _fill([z.reshape(n_rows, 2 * k)], g.seeds, PRIORS)  # each episode's (2, k) draw
        p_period = period * ps.period_bias * (1.0 + ps.period_error * z[:, 0])
        p_period_std = p_period * max(ps.period_error, abs(ps.period_bias - 1.0), 1e-3)
        if ps.phase_error is None:
            p_phase = np.full((n_rows, k), np.nan)
            p_phase_std = np.full((n_rows, k), np.nan)
        else:
            p_phase = phase + ps.phase_error * period * z[:, 1]
            p_phase_std = period * max(ps.phase_error, 1e-3)
        prob = rows(ps.source_prob) if ps.source_prob else rate / rate.sum(axis=1, keepdims=True)
        n = k
    amplitude = amplitude_std = [None] * n_rows
    if spec.amplitudes:
        amplitude = np.zeros((n_rows, n))
        std = np.full(n, spec.amplitude_noise_std)
        m = min(n, k)
        amplitude[:, :m] = amp_mean[:, :m]
        std[:m] = np.hypot([s.amplitude_std for s in spec.sources[:m]], spec.amplitude_noise_std)
        top = amp_mean.max(axis=1)
        amplitude_std = np.maximum(std, 1e-3 * np.where(1e-9 > top, 1e-9, top)[:, None])  # max(top, 1e-9)
        if n > k:  # phantom tracks: the mean amplitude of the real ones
            amplitude[:, k:] = amp_mean.mean(axis=1)[:, None]
    # PriorSpec.modulation: the sources' modulations as specified (no per-episode draw), none for phantoms
    modulation = tuple([s.modulation for s in spec.sources[:min(n, k)]] + [None] * (n - k)) if ps.modulation \
        else None
    return [Priors(n_labels=n, period=per, phase=ph, period_std=per_std, phase_std=ph_std, source_prob=pi,
                   amplitude=amp, amplitude_std=amp_std, modulation=modulation, **common)
            for per, ph, per_std, ph_std, pi, amp, amp_std in zip(p_period, p_phase, p_period_std, p_phase_std, prob,
                                                                  amplitude, amplitude_std)]

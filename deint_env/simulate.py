"""The pulse simulator: `simulate_many(spec, seeds)` -> `Episode`s, batched numpy, bit-reproducible.

Order of effects, as a receiver sees them: each source emits on its own (modulated, cumulatively
jittered) schedule inside its on-windows; each emission is independently missed with
`missing_prob`; the survivors get white Gaussian TOA noise (sigma_w); a Poisson stream of spurious
pulses is added; with pulse descriptors (`ScenarioSpec.receiver`, `sim.descriptors`) every pulse gets
its frequency, pulse width and AoA, its amplitude the antennas' gains, and the pulses below the
receiver's threshold are lost; everything is sorted by TOA; pulses closer than `coincidence_resolution` to their
predecessor merge into it (earlier TOA, summed amplitude, every source in the bit mask; with
`merge="emission"` the noise-free arrivals are compared instead, see `sim.merging.merge_at_emission`); the first
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
the channel and the detection-oriented Kalman filter (`deint_env.receiver`), and the episode holds the
detections.

The parts, in `deint_env.sim`: `streams` (the random streams and their batched seeding), `schedule`
(the sources' draws and noise-free emissions), `impairments` (misses, TOA noise, spurious pulses),
`descriptors` (pulse descriptor words, antenna scans, the receiver's threshold),
`merging` (coincident pulses), `truth` and `priors` (what an episode knows and tells a policy), `rows`
(row helpers).  This module runs them in order, batch by batch.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from deint_env.episode import Episode, Truth
from deint_env.errors import DeintError, shown
from deint_env.receiver import detect_pulses
from deint_env.scenario import ScenarioSpec, SourceSpec
from deint_env.sim.descriptors import draw_emitters, heard_fraction
from deint_env.sim.impairments import receive
from deint_env.sim.merging import MergedRow, merge
from deint_env.sim.priors import episode_priors
from deint_env.sim.rows import take_rows
from deint_env.sim.schedule import Draws, SourceDraw, draw_sources, emissions
from deint_env.sim.streams import AMPLITUDE_NOISE, DRAW, WAVEFORM, check_seed, fill, stream, streams
from deint_env.sim.truth import truths

MAX_SEEDS = 10**6  # seeds of one `simulate_many` call
# Episodes simulated together hold about this many pulses: the temporaries then stay in cache and are
# reused by the allocator (fresh pages fault, and faults are costly).
_BATCH_PULSES = 1 << 18


class _Generated(NamedTuple):
    """One pass over a batch: which rows made n_pulses pulses, and the finished rows' episodes."""

    done: np.ndarray  # (rows,) bool
    toa: np.ndarray  # (finished rows, n_pulses)
    source: np.ndarray
    mask: np.ndarray
    amplitude: np.ndarray | list[None]
    descriptors: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None]  # frequency, pulse width, AoA
    truths: list[Truth]


def simulate(spec: ScenarioSpec, seed: int) -> Episode:
    """Simulate one episode of `spec`; see the module docstring for the order of effects."""
    return simulate_many(spec, [seed])[0]


def simulate_many(spec: ScenarioSpec, seeds: Sequence[int]) -> list[Episode]:
    """One episode of `spec` per seed, each bit-identical to `simulate(spec, seed)`, made together.

    At most `MAX_SEEDS` (10^6) seeds a call (more is refused before any is simulated): the episodes are
    returned as one list, held in memory together; simulate a longer range in blocks."""
    if not isinstance(spec, ScenarioSpec):
        raise DeintError(f"spec={shown(spec)} is invalid: a ScenarioSpec (deint_env.resolve_scenario(NAME) gives one)")
    bad = f"seeds={shown(seeds)} is invalid: a sequence of integers in [0, 2^63)"
    if isinstance(seeds, (str, bytes, bytearray, Mapping)):  # b'ab' iterates as the seeds 97 and 98
        raise DeintError(bad)
    try:  # an iterable of any length (range(10**12)) is read no further than the bound
        head = list(itertools.islice(seeds, MAX_SEEDS + 1))
    except TypeError:
        raise DeintError(bad) from None
    if len(head) > MAX_SEEDS:
        raise DeintError(f"seeds={shown(seeds)} is invalid: at most {MAX_SEEDS} seeds a call (the episodes are held "
                         f"in memory together); simulate them in blocks")
    seeds = [check_seed(s) for s in head]
    size = max(1, _BATCH_PULSES // spec.n_pulses)
    episodes = [episode for start in range(0, len(seeds), size)
                for episode in _simulate_batch(spec, seeds[start:start + size])]
    return [_detect(spec, ep) for ep in episodes] if spec.waveform is not None else episodes


def _detect(spec: ScenarioSpec, ep: Episode) -> Episode:
    """The waveform front end (`ScenarioSpec.waveform`): the episode's pulses through DM89's channel and
    detector; the detections, with their true sources, become the episode."""
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
    drawn = [draw_sources(spec, rng) for rng in streams(seeds, DRAW)]
    episodes: list[Episode] = [None] * len(seeds)  # type: ignore[list-item]
    # Episodes with the same sources share arrays; only blind `n_active` scenarios have several groups.
    for k in sorted({len(d.period) for d in drawn}):
        rows = [j for j, d in enumerate(drawn) if len(d.period) == k]
        period, phase, amp_mean = (np.array([getattr(drawn[j], f) for j in rows]) for f in SourceDraw._fields)
        group = _simulate_group(spec, spec.sources[:k], [seeds[j] for j in rows], period, phase, amp_mean)
        for j, episode in zip(rows, group):
            episodes[j] = episode
    return episodes


def _simulate_group(spec: ScenarioSpec, sources: tuple[SourceSpec, ...], seeds: list[int], period: np.ndarray,
                    phase: np.ndarray, amp_mean: np.ndarray) -> list[Episode]:
    rate = (1.0 / period).sum(axis=1)
    pmin = phase.min(axis=1)
    g = Draws(seeds, period, phase, amp_mean, h0=spec.n_pulses / rate, spur_intensity=spec.spurious_rate * rate,
               t_start=np.where(pmin > 0.0, 0.0, pmin),  # min(phase.min(), 0.0)
               emitters=draw_emitters(sources, seeds) if spec.has_descriptors else None)
    heard = rate
    if spec.receiver is not None and spec.receiver.threshold > 0:  # the threshold thins the sources' pulses
        heard = np.maximum((heard_fraction(spec, sources, g.emitters, amp_mean) / period).sum(axis=1), 0.05 * rate)
    received_rate = heard * (1.0 - spec.missing_prob) + g.spur_intensity
    # merging thins the stream (math.exp per episode: np.exp may round differently)
    received_rate *= [math.exp(-r * spec.coincidence_resolution) for r in received_rate.tolist()]
    horizon = phase.max(axis=1) + (1.15 * spec.n_pulses + 20) / received_rate
    priors = episode_priors(spec, g)

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
        out = _generate(spec, sources, batch, horizon)
        done = out.done
        for j, t, s, m, a, desc, truth in zip(rows[done].tolist(), out.toa, out.source, out.mask, out.amplitude,
                                              out.descriptors, out.truths):
            f, w, aoa = desc if desc is not None else (None, None, None)
            episodes[j] = Episode(scenario=spec.name, seed=seeds[j], toa=t, amplitude=a, source=s, mask=m,
                                  truth=truth, priors=priors[j], frequency=f, pulse_width=w, aoa=aoa)
        rows, horizon = rows[~done], horizon[~done] * 2
        size = max(1, _BATCH_PULSES // (spec.n_pulses << (doublings + 1)))
        todo += [(rows[a:a + size], horizon[a:a + size], doublings + 1) for a in range(0, rows.size, size)]
    return episodes


def _generate(spec: ScenarioSpec, sources: tuple[SourceSpec, ...], g: Draws, horizon: np.ndarray) -> _Generated:
    """Simulate every row up to its horizon (see `_Generated`).

    Each source's pulses stay in a (rows, width) block, every row's own pulses first, in time order,
    then padding at or past the horizon; the blocks side by side, spurious pulses last, are the lone
    episode's concatenation with the padding in between, which sorts after every pulse that counts."""
    n_rows, k, n = len(g.seeds), len(sources), spec.n_pulses
    # --- each source's schedule (noise-free emission times) ---
    # m emissions per source, doubled until the m-th reaches the horizon, as per episode: a row with
    # random intervals must draw exactly what the lone episode draws.  (m >= 1 even past the horizon.)
    min_ratio = np.array([src.modulation.min_ratio() for src in sources])
    m = np.maximum(((horizon[:, None] - g.phase) / (g.period * min_ratio)).astype(np.int64) + 16, 1)
    sched = [emissions(src, g.period[:, i], g.phase[:, i], g.amp_mean[:, i], m[:, i], spec.pri_jitter_std, g.h0,
                        horizon, g.seeds, i, spec.amplitudes) for i, src in enumerate(sources)]
    y, amp, col_src, desc = receive(spec, g, horizon, sched)

    # --- sort each row; past `complete`, emissions after the horizon (not generated) could still
    # have landed, so only the pulses before it count ---
    bit_of = np.left_shift(np.uint64(1), np.minimum(np.arange(k + 1), 63).astype(np.uint64))
    bit_of[min(k, 64):] = 0  # source -1 (spurious), and sources past the 64-bit mask (they never merge): no bit
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
    toa = take_rows(y, order[:, :seen])
    if not stable:
        tied = (((toa[:, 1:] == toa[:, :-1]) & (toa[:, 1:] < np.inf)).any(axis=1)).nonzero()[0]
        if tied.size:
            order[tied] = np.argsort(y[tied], axis=1, kind="stable")
            toa[tied] = take_rows(y[tied], order[tied, :seen])
    del y  # free the big temporaries as soon as they are used up: the allocator reuses their pages
    merged = np.zeros(n_rows, bool)
    if spec.coincidence_resolution > 0:
        starts = np.ones(toa.shape, bool)  # the first pulse of each run closer than the resolution
        with np.errstate(invalid="ignore"):  # inf - inf in the padding, which is past the row's cut
            gap = np.diff(toa, axis=1)
            # merge="emission": the runs were formed before the noise and share one TOA (merge_at_emission)
            starts[:, 1:] = gap > 0 if spec.merge == "emission" else gap >= spec.coincidence_resolution
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
    desc = () if desc is None else tuple(desc)
    if merged_d.size:
        toa_d, src_d = np.empty((d.size, n)), np.empty((d.size, n), np.int32)
        mask_d, amp_d = np.empty((d.size, n), np.uint64), None if amp is None else np.empty((d.size, n))
        desc_d = [np.empty((d.size, n)) for _ in desc]
        rest = (~merged[d]).nonzero()[0]
        toa_d[rest], src_d[rest] = toa[plain, :n], col_src[head]
        mask_d[rest] = bit_of[src_d[rest]]
        if amp is not None:
            amp_d[rest] = take_rows(amp[plain], head)
        for x, x_d in zip(desc, desc_d):
            x_d[rest] = take_rows(x[plain], head)
    else:
        toa_d, src_d = np.ascontiguousarray(toa[plain, :n]), col_src[head]
        mask_d = bit_of[src_d]
        amp_d = None if amp is None else take_rows(amp[plain], head)
        desc_d = [take_rows(x[plain], head) for x in desc]
    for j in merged_d.tolist():
        r, c = d[j], cut[d[j]]
        o = order[r, :c]
        src = col_src[o]
        first = runs[r] if r in runs else starts[r, :c].nonzero()[0]
        merge(toa[r, :c], src, bit_of[src], None if amp is None else amp[r][o], first,
              MergedRow(toa_d[j], src_d[j], mask_d[j], None if amp_d is None else amp_d[j],
                        tuple(x_d[j] for x_d in desc_d)), tuple(x[r][o] for x in desc))
    del order, head, toa, amp, desc
    if spec.amplitudes and spec.amplitude_noise_std > 0:
        z = np.empty(amp_d.shape)
        fill([z], [g.seeds[r] for r in d.tolist()], AMPLITUDE_NOISE)
        amp_d = amp_d + spec.amplitude_noise_std * z

    t_end = np.full(n_rows, -np.inf)  # no truth for the unfinished rows
    t_end[d] = toa_d[:, -1] + 8 * spec.toa_jitter_std + spec.coincidence_resolution
    out_truths = truths(g.period[d], g.phase[d], [e.t for e in sched], [e.pri for e in sched], d, t_end, src_d, mask_d,
                        merged_d.size > 0)
    return _Generated(done, toa_d, src_d, mask_d, [None] * d.size if amp_d is None else amp_d,
                      list(zip(*desc_d)) if desc_d else [None] * d.size, out_truths)

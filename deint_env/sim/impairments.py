"""The receiver's impairments, before sorting and merging: missed emissions, white Gaussian TOA noise,
a Poisson stream of spurious pulses and, with pulse descriptors, the antenna gains and the
receiver's threshold (`sim.descriptors`)."""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from deint_env.scenario import ScenarioSpec
from deint_env.sim.descriptors import Descriptors, describe
from deint_env.sim.merging import merge_at_emission
from deint_env.sim.rows import compact
from deint_env.sim.schedule import Draws, Emissions
from deint_env.sim.streams import JITTER, MISSING, SPURIOUS, fill, streams


class Received(NamedTuple):
    """Each episode's received pulses as a row (the source blocks side by side, spurious pulses last;
    padding sorts last), their amplitudes (or None), each column's source (-1: spurious) and, with
    pulse descriptors, each column's (else None; a pulse the threshold drops has TOA +inf)."""

    toa: np.ndarray
    amplitude: np.ndarray | None
    column_source: np.ndarray
    descriptors: Descriptors | None


def receive(spec: ScenarioSpec, g: Draws, horizon: np.ndarray, sched: list[Emissions]) -> Received:
    """The receiver: misses, TOA noise and spurious pulses, for every row at once."""
    n_rows, k = len(g.seeds), len(sched)
    counts = np.array([e.count for e in sched]).T  # (rows, sources)
    ys, amps = [e.t for e in sched], [e.amp for e in sched]

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
        fill(blocks[:k], g.seeds, JITTER, counts=counts)
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
    desc = None
    if g.emitters is not None:
        desc = describe(spec, spec.sources[:k], g.emitters, g.seeds, y, amp, ys, counts, edges,
                        [u.size for u in spur_u] if len(labels) > k else None)
    if spec.merge == "emission":
        noise_free = y.copy()  # spurious pulses: their own times
        for a, b, t in zip(edges, edges[1:], ys):
            noise_free[:, a:b] = t
        if desc is not None:  # a pulse the receiver does not hear merges with nothing
            noise_free[y == np.inf] = np.inf
        merge_at_emission(y, noise_free, spec.coincidence_resolution)

    return Received(y, amp, np.repeat(np.array(labels, np.int32), widths), desc)


def _miss(prob: float, seeds: list[int], counts: np.ndarray, ts: list[np.ndarray], amps: list[np.ndarray | None]):
    """Each emission is missed with probability `prob`: the kept counts, times and amplitudes."""
    us = [np.zeros(t.shape) for t in ts]  # padding: 0, never kept
    fill(us, seeds, MISSING, counts=counts, normal=False)
    kept = [compact(u >= prob, t, a) for u, t, a in zip(us, ts, amps)]
    return np.array([c for c, _, _ in kept]).T, [t for _, t, _ in kept], [a for _, _, a in kept]

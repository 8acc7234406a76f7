"""Pulse descriptor words (`scenario.DescriptorSpec`, `scenario.ReceiverSpec`): each episode's emitter
draws, and each received pulse's frequency, pulse width, angle of arrival and antenna gains; a pulse
whose received amplitude is below the receiver's threshold is not heard (its TOA becomes padding).

Everything here draws from the DESCRIPTOR_DRAW and DESCRIPTOR_PULSE streams only, so a scenario's
TOA streams, and so its TOAs, do not move when its sources gain descriptors (but for the pulses the
threshold drops and the horizon that their loss lengthens)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from deint_env.scenario import Param, Range, ScenarioSpec, SourceSpec
from deint_env.sim.streams import DESCRIPTOR_DRAW, DESCRIPTOR_PULSE, fill, streams

_PER_SOURCE = 7  # uniforms each source draws per episode (EmitterDraws' per-source fields)
_GRID = 256  # angles per antenna pattern in `heard_fraction`


class EmitterDraws(NamedTuple):
    """Each episode's emitter draws (DESCRIPTOR_DRAW): a row per episode, a column per source."""

    frequency: np.ndarray  # centre, MHz
    pulse_width: np.ndarray  # us
    aoa: np.ndarray  # degrees at time 0
    aoa_rate: np.ndarray  # degrees per TOA unit
    scan_period: np.ndarray
    scan_phase: np.ndarray  # circular: boresight at time 0; sector: the sweep's position (cycles)
    sector_offset: np.ndarray  # sector: the sector's centre less the receiver's bearing, degrees
    look_phase: np.ndarray  # (E,) a scanning receiver's look direction at time 0

    def take(self, rows: np.ndarray) -> EmitterDraws:
        return EmitterDraws(*(a[rows] for a in self))


class Descriptors(NamedTuple):
    """Every column of the received rows (`impairments.Received`): frequency, pulse width and AoA."""

    frequency: np.ndarray
    pulse_width: np.ndarray
    aoa: np.ndarray


def _from_uniform(p: Param, u: np.ndarray) -> np.ndarray:
    """`Range.draw` of uniforms u, vectorised (a number stays itself)."""
    if not isinstance(p, Range):
        return np.full(u.shape, float(p))
    if p.log:
        return np.exp(np.log(p.low) + u * (np.log(p.high) - np.log(p.low)))
    return p.low + u * (p.high - p.low)


def draw_emitters(sources: tuple[SourceSpec, ...], seeds: list[int]) -> EmitterDraws:
    """The episodes' per-source descriptor draws: a fixed number of uniforms per source, so each
    episode draws the same whatever it uses."""
    k = len(sources)
    u = np.empty((len(seeds), _PER_SOURCE * k + 1))
    fill([u], seeds, DESCRIPTOR_DRAW, normal=False)
    v = u[:, :-1].reshape(len(seeds), k, _PER_SOURCE)
    ds = [s.descriptors for s in sources]
    col = [np.stack([f(d, v[:, i, j]) for i, d in enumerate(ds)], axis=1) for j, f in enumerate((
        lambda d, x: _from_uniform(d.frequency, x),
        lambda d, x: _from_uniform(d.pulse_width, x),
        lambda d, x: 360.0 * x if d.aoa is None else _from_uniform(d.aoa, x),
        lambda d, x: _from_uniform(d.aoa_rate, x),
        lambda d, x: _from_uniform(d.scan_period, x),
        lambda d, x: x if d.scan == "sector" else 360.0 * x,
        lambda d, x: d.sector * (x - 0.5)))]
    return EmitterDraws(*col, look_phase=360.0 * u[:, -1])


def pattern_db(theta: np.ndarray, beamwidth: float, beam: str, sidelobe_db: float) -> np.ndarray:
    """An antenna's gain (dB) at `theta` degrees off boresight: a Gaussian main lobe (-3 dB at half the
    beamwidth) or sinc^2 (the same 3 dB width, with its own sidelobes), floored at `sidelobe_db`."""
    if beam == "gaussian":
        g = -12.0 * (theta / beamwidth) ** 2
    else:  # np.sinc(x)^2 = 1/2 at x = 0.4429: scaled so that theta = beamwidth / 2 is the 3 dB point
        with np.errstate(divide="ignore"):
            g = 20.0 * np.log10(np.abs(np.sinc(0.8858 * theta / beamwidth)))
    return np.maximum(g, sidelobe_db)


def _wrap(deg: np.ndarray) -> np.ndarray:
    """Angles to [-180, 180)."""
    return (deg + 180.0) % 360.0 - 180.0


def _emitter_gain_db(d, e: EmitterDraws, i: int, t: np.ndarray, aoa: np.ndarray) -> np.ndarray | float:
    """Source i's antenna gain towards the receiver at times t (the receiver lies at aoa + 180 from it)."""
    if d.scan == "none":
        return 0.0
    period, phase = e.scan_period[:, i, None], e.scan_phase[:, i, None]
    if d.scan == "circular":
        boresight = phase + 360.0 * t / period
    else:  # a triangle sweep over the sector, out and back once per period
        x = t / period + phase
        sweep = 1.0 - 4.0 * np.abs(x - np.floor(x) - 0.5)
        boresight = e.aoa[:, i, None] + 180.0 + e.sector_offset[:, i, None] + 0.5 * d.sector * sweep
    return pattern_db(_wrap(boresight - aoa - 180.0), d.beamwidth, d.beam, d.sidelobe_db)


def _receiver_gain_db(spec: ScenarioSpec, e: EmitterDraws, t: np.ndarray, aoa: np.ndarray) -> np.ndarray | float:
    rx = spec.receiver
    if rx is None or rx.mode == "staring":
        return 0.0
    look = e.look_phase[:, None] + 360.0 * t / rx.scan_period
    return pattern_db(_wrap(look - aoa), rx.beamwidth, rx.beam, rx.sidelobe_db)


def heard_fraction(spec: ScenarioSpec, sources: tuple[SourceSpec, ...], e: EmitterDraws,
                   amp_mean: np.ndarray) -> np.ndarray:
    """(E, k): the share of each source's pulses above the receiver's threshold, over its scan and the
    receiver's (independent angles on a grid; amplitude fluctuation left out) -- to size the horizon."""
    rx = spec.receiver
    grid = (np.arange(_GRID) + 0.5) * (360.0 / _GRID) - 180.0
    rx_db = np.zeros(1) if rx.mode == "staring" else pattern_db(grid, rx.beamwidth, rx.beam, rx.sidelobe_db)
    out = np.empty(amp_mean.shape)
    for i, s in enumerate(sources):
        d = s.descriptors
        if d.scan == "circular":
            tx_db = pattern_db(grid, d.beamwidth, d.beam, d.sidelobe_db)[None]
        elif d.scan == "sector":  # the sweep spends equal time at every angle of the sector
            off = e.sector_offset[:, i, None] + 0.5 * d.sector * np.linspace(-1.0, 1.0, _GRID)
            tx_db = pattern_db(_wrap(off), d.beamwidth, d.beam, d.sidelobe_db)
        else:
            tx_db = np.zeros((1, 1))
        need = 20.0 * np.log10(rx.threshold / amp_mean[:, i])  # dB of gain a pulse needs
        heard = tx_db[:, :, None] + rx_db[None, None, :] >= need[:, None, None]
        out[:, i] = heard.mean(axis=(1, 2))
    return out


def describe(spec: ScenarioSpec, sources: tuple[SourceSpec, ...], e: EmitterDraws, seeds: list[int],
             y: np.ndarray, amp: np.ndarray, times: list[np.ndarray], counts: np.ndarray, edges: list[int],
             n_spurious: list[int] | None) -> Descriptors:
    """Every received pulse's descriptors, in the column layout of `y` (source blocks at `edges`, their
    noise-free `times` and `counts` per row; then `n_spurious` spurious pulses per row, or None).
    Scales `amp` by the antenna gains and sets the TOA of every pulse below the threshold to +inf
    (padding), both in place."""
    rx = spec.receiver
    k, n_rows = len(sources), y.shape[0]
    width = edges[k]
    # Each row draws its pulses' uniforms and normals in one go, block by block: the same numbers
    # whatever else is simulated with it.
    valid = np.concatenate([np.arange(t.shape[1]) < counts[:, i, None] for i, t in enumerate(times)], axis=1)
    u, z = np.zeros((2, n_rows, width)), np.zeros((4, n_rows, width))
    drawn_u, drawn_z, spur = [], [], []
    for rng, c, s in zip(streams(seeds, DESCRIPTOR_PULSE), counts.sum(axis=1).tolist(), n_spurious or [0] * n_rows):
        drawn_u.append(rng.random((2, c)))
        drawn_z.append(rng.standard_normal((4, c)))
        spur.append(rng.random((3, s)))
    u[:, valid] = np.concatenate(drawn_u, axis=1)
    z[:, valid] = np.concatenate(drawn_z, axis=1)

    freq, pw, aoa = np.zeros(y.shape), np.zeros(y.shape), np.zeros(y.shape)
    f_noise, pw_noise, aoa_noise = ((rx.frequency_noise_std, rx.pulse_width_noise_std, rx.aoa_noise_std)
                                    if rx is not None else (0.0, 0.0, 0.0))
    threshold = rx.threshold if rx is not None else 0.0
    for i, (s, t) in enumerate(zip(sources, times)):
        d, a, b = s.descriptors, edges[i], edges[i + 1]
        ub, zb = u[:, :, a:b], z[:, :, a:b]
        tt = np.where(np.isfinite(t), t, 0.0)  # padding: any finite time (never kept)
        f = e.frequency[:, i, None] + d.frequency_std * zb[0] + f_noise * zb[1]
        if d.frequency_hops:
            hops = np.asarray(d.frequency_hops)
            f = f + hops[np.minimum((ub[0] * hops.size).astype(np.int64), hops.size - 1)]
        w = np.broadcast_to(e.pulse_width[:, i, None], t.shape)
        if d.pulse_width_levels:
            levels = np.asarray(d.pulse_width_levels)
            w = w * levels[np.minimum((ub[1] * levels.size).astype(np.int64), levels.size - 1)]
        true_aoa = e.aoa[:, i, None] + e.aoa_rate[:, i, None] * tt
        gain_db = _emitter_gain_db(d, e, i, tt, true_aoa) + _receiver_gain_db(spec, e, tt, true_aoa)
        freq[:, a:b] = f
        pw[:, a:b] = np.maximum(w + pw_noise * zb[2], 0.0)  # a measured width is never negative
        aoa[:, a:b] = (true_aoa + aoa_noise * zb[3]) % 360.0
        if not np.isscalar(gain_db) or gain_db != 0.0:
            amp[:, a:b] *= 10.0 ** (gain_db / 20.0)
        if threshold > 0:
            block = y[:, a:b]
            block[amp[:, a:b] < threshold] = np.inf
    if n_spurious is not None:  # spurious pulses: uniform over the sources' descriptor ranges, any AoA
        f_lo = min(s.descriptors.frequency_span()[0] for s in sources)
        f_hi = max(s.descriptors.frequency_span()[1] for s in sources)
        w_lo = min(s.descriptors.pulse_width_span()[0] for s in sources)
        w_hi = max(s.descriptors.pulse_width_span()[1] for s in sources)
        for j, v in enumerate(spur):
            c = slice(width, width + v.shape[1])
            freq[j, c], pw[j, c], aoa[j, c] = f_lo + v[0] * (f_hi - f_lo), w_lo + v[1] * (w_hi - w_lo), 360.0 * v[2]
    return Descriptors(freq, pw, aoa)

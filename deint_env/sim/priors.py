"""The priors a scenario's episodes hand a policy: explicit values, or the truth blurred by the
scenario's prior errors (each episode's own PRIORS stream)."""

from __future__ import annotations

import numpy as np

from deint_env.episode import Priors
from deint_env.scenario import ScenarioSpec
from deint_env.sim.schedule import Draws
from deint_env.sim.streams import PRIORS, fill


def episode_priors(spec: ScenarioSpec, g: Draws) -> list[Priors]:
    """The public priors each episode hands a policy (`ScenarioSpec.priors`; blind: the label budget)."""
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
        fill([z.reshape(n_rows, 2 * k)], g.seeds, PRIORS)  # each episode's (2, k) draw
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
    library = _library(spec, g) if ps.descriptors else [{}] * n_rows
    return [Priors(n_labels=n, period=per, phase=ph, period_std=per_std, phase_std=ph_std, source_prob=pi,
                   amplitude=amp, amplitude_std=amp_std, modulation=modulation, **lib, **common)
            for per, ph, per_std, ph_std, pi, amp, amp_std, lib in zip(p_period, p_phase, p_period_std, p_phase_std,
                                                                       prob, amplitude, amplitude_std, library)]


# The spreads' floors: a descriptor stated exactly (no jitter, no noise) still gets a spread, so that a
# likelihood built on the library stays finite.
_MIN_STD = {"frequency": 1e-3, "pulse_width": 1e-4, "aoa": 1e-3}  # MHz, us, degrees


def _library(spec: ScenarioSpec, g: Draws) -> list[dict[str, np.ndarray]]:
    """`PriorSpec.descriptors`: each episode's per-source descriptor means and spreads (an emitter library)."""
    e, rx = g.emitters, spec.receiver
    noise = ((rx.frequency_noise_std, rx.pulse_width_noise_std, rx.aoa_noise_std) if rx is not None
             else (0.0, 0.0, 0.0))
    ds = [s.descriptors for s in spec.sources[:g.period.shape[1]]]
    hops = [np.asarray(d.frequency_hops or (0.0,)) for d in ds]
    levels = [np.asarray(d.pulse_width_levels or (1.0,)) for d in ds]
    frequency = e.frequency + np.array([h.mean() for h in hops])
    f_std = np.hypot(np.hypot([d.frequency_std for d in ds], [h.std() for h in hops]), noise[0])
    pulse_width = e.pulse_width * np.array([v.mean() for v in levels])
    w_std = np.hypot(e.pulse_width * np.array([v.std() for v in levels]), noise[1])
    # the AoA drifts over the episode: a uniform spread of |rate| H0 about its start
    a_std = np.hypot(np.abs(e.aoa_rate) * g.h0[:, None] / np.sqrt(12.0), noise[2])
    values = {"frequency": frequency, "frequency_std": np.broadcast_to(np.maximum(f_std, _MIN_STD["frequency"]),
                                                                       frequency.shape),
              "pulse_width": pulse_width, "pulse_width_std": np.maximum(w_std, _MIN_STD["pulse_width"]),
              "aoa": e.aoa % 360.0, "aoa_std": np.maximum(a_std, _MIN_STD["aoa"])}
    return [{name: np.array(v[r]) for name, v in values.items()} for r in range(g.period.shape[0])]

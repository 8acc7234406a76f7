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
    return [Priors(n_labels=n, period=per, phase=ph, period_std=per_std, phase_std=ph_std, source_prob=pi,
                   amplitude=amp, amplitude_std=amp_std, modulation=modulation, **common)
            for per, ph, per_std, ph_std, pi, amp, amp_std in zip(p_period, p_phase, p_period_std, p_phase_std, prob,
                                                                  amplitude, amplitude_std)]

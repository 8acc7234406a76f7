"""The DM89 waveform front end of the simulator (ScenarioSpec.waveform)."""

from __future__ import annotations

import numpy as np
import pytest

from deint_env import DeintError, ScenarioSpec, SourceSpec, make_policy, simulate, simulate_many
from deint_env.runner import play
from deint_env.scenario import WaveformSpec

BASE = ScenarioSpec(name="wf", sources=(SourceSpec(11.0, 3.0), SourceSpec(30.0, 4.0), SourceSpec(80.0, 6.0)),
                    n_pulses=300, toa_jitter_std=0.5, amplitudes=True)


def test_clean_channel_detects_every_pulse_on_its_own_sample():
    spec = BASE.replace(waveform=WaveformSpec(sample_period=1.0, noise_std=0.005))
    ep, ref = simulate(spec, 1), simulate(BASE, 1)
    # pulses landing on one sample share a detection; with low noise nothing else is lost or added
    on_sample = np.unique(np.rint(ref.toa)).size
    assert len(ep) == on_sample and np.all(ep.source >= 0)
    np.testing.assert_allclose(ep.toa, np.unique(np.rint(ref.toa)))
    assert ep.truth.n_received.sum() >= len(ep)


def test_noise_makes_misses_and_false_alarms_deterministically():
    spec = BASE.replace(waveform=WaveformSpec(sample_period=1.0, noise_std=0.25))
    ep = simulate(spec, 2)
    ref = simulate(BASE, 2)
    assert np.any(ep.source < 0)  # false alarms
    assert ep.truth.n_received.sum() < ref.truth.n_received.sum()  # misses
    again = simulate_many(spec, [2])[0]
    np.testing.assert_array_equal(again.toa, ep.toa)
    np.testing.assert_array_equal(again.mask, ep.mask)
    assert np.all(np.diff(ep.toa) >= 0)


def test_front_end_episodes_play_through_the_env_and_round_trip():
    spec = BASE.replace(waveform=WaveformSpec(sample_period=0.5, noise_std=0.05), amplitudes=False)
    assert ScenarioSpec.from_dict(spec.to_dict()) == spec
    ep = simulate(spec, 0)
    assert ep.amplitude is None
    res = play(make_policy("genie"), ep, oracle=True)
    assert res.metrics["n_pulses"] == len(ep) and res.metrics["accuracy"] > 0.5


@pytest.mark.parametrize("bad, field", [({"sample_period": 0.0}, "sample_period"),
                                         ({"sample_period": 1.0, "noise_std": 0.0}, "noise_std"),
                                         ({"sample_period": 1.0, "denominator": [0.0, 1.0]}, "denominator"),
                                         ({"sample_period": 1.0, "spike_prob": 1.5}, "spike_prob"),
                                         ({"sample_period": 1.0, "nope": 1}, "nope")])
def test_bad_waveform_fields_are_named(bad, field):
    with pytest.raises(DeintError, match=field):
        ScenarioSpec.from_dict({**BASE.to_dict(), "waveform": bad})


def test_a_sample_period_too_fine_for_the_episode_is_refused_at_construction():
    """Issue 26: the front end steps through every sample; 10^-12 would be ~10^15 samples (a memory bomb)."""
    with pytest.raises(DeintError, match=r"^waveform.sample_period=1e-12 is invalid: at least .* would need ~.* samples"):
        BASE.replace(waveform=WaveformSpec(sample_period=1e-12, noise_std=0.05))

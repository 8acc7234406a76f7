"""MK94's merging model (`ScenarioSpec.merge="emission"`) and the paper-v1 suite built on it."""

from __future__ import annotations

import numpy as np
import pytest

from deint_env.errors import DeintError
from deint_env.scenario import ScenarioSpec, SourceSpec
from deint_env.simulate import simulate, simulate_many
from deint_env.suites import find_entry, load_suite


def _spec(**kw) -> ScenarioSpec:
    base = dict(name="t", sources=(SourceSpec(period=10.0, phase=0.0), SourceSpec(period=15.0, phase=0.0)),
                n_pulses=400, toa_jitter_std=2.0, coincidence_resolution=0.5)
    return ScenarioSpec(**{**base, **kw})


def _multi(mask: np.ndarray) -> np.ndarray:
    return np.bitwise_and(mask, mask - np.uint64(1)) != 0


def _schedules(ep) -> list[np.ndarray]:
    off = ep.truth.schedule_offsets
    return [ep.truth.schedule_toa[off[i]:off[i + 1]] for i in range(ep.truth.n_sources)]


@pytest.mark.parametrize("kw, words", [
    ({"merge": "exact"}, ["merge='exact'", "received, emission"]),
    ({"merge": "emission", "coincidence_resolution": 0.0}, ["merge='emission'", "coincidence_resolution > 0"]),
])
def test_bad_merge_models_are_one_line_errors(kw, words):
    with pytest.raises(DeintError) as info:
        _spec(**kw)
    assert "\n" not in str(info.value) and all(w in str(info.value) for w in words)
    with pytest.raises(DeintError):
        ScenarioSpec.from_dict({**_spec().to_dict(), **kw})


def test_default_merge_keeps_old_spec_hashes():
    spec = _spec()
    assert spec.merge == "received" and "merge" not in spec.to_dict()
    assert ScenarioSpec.from_dict(_spec(merge="emission").to_dict()).merge == "emission"


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_exactly_simultaneous_arrivals_merge_whatever_the_jitter(seed):
    """T = 10 and 15 from 0 coincide every 30: with merge="emission" each coincidence is one pulse
    carrying both sources, at the jittered TOA of source 0's arrival, and nothing else merges; the
    received model (sigma_w = 2 >> resolution 0.5) merges only a few of them."""
    ep = simulate(_spec(merge="emission"), seed)
    s0, s1 = _schedules(ep)
    horizon = ep.toa[-1] - 10.0  # away from the cut at the end
    both = np.intersect1d(s0, s1)
    both = both[both < horizon]
    multi = _multi(ep.mask) & (ep.toa < horizon)
    assert both.size > 20 and multi.sum() == both.size
    assert np.all(ep.mask[multi] == 3) and np.all(ep.source[multi] == 0)
    assert np.all(np.abs(ep.toa[multi] - both) < 8.0)  # each near its own coincidence (sigma_w = 2)
    assert np.all(np.diff(ep.toa) >= 0)
    # the pulses kept are exactly the schedule minus one member of each coincidence
    kept = np.sum(np.concatenate([s0, s1]) < horizon) - both.size
    assert abs(np.sum(ep.toa < horizon) - kept) <= 2  # jitter moves a pulse or two across the horizon
    received = simulate(_spec(), seed)
    assert _multi(received.mask).sum() < 0.5 * both.size


def test_merged_amplitudes_add_and_batches_agree():
    spec = _spec(merge="emission", amplitudes=True, spurious_rate=0.2, toa_jitter_std=0.3,
                 sources=(SourceSpec(period=10.0, phase=0.0, amplitude=1.0),
                          SourceSpec(period=15.0, phase=0.0, amplitude=2.0)))
    eps = simulate_many(spec, list(range(40)))
    for seed in (0, 13, 39):
        one = simulate(spec, seed)
        assert np.array_equal(one.toa, eps[seed].toa) and np.array_equal(one.mask, eps[seed].mask)
    ep = eps[0]
    amp = ep.amplitude[ep.mask == 3]  # the two sources' 1 + 2, plus any spurious pulse merged in
    assert amp.size > 10 and np.all(amp >= 3.0 - 1e-12) and np.mean(np.isclose(amp, 3.0)) > 0.8


def test_noise_free_channel_merges_within_the_resolution_of_the_schedule():
    """Without jitter the TOA is the schedule's: arrivals 0.3 apart merge at resolution 0.5 (at the
    earlier one), 0.6 apart do not."""
    for gap, merges in ((0.3, True), (0.6, False)):
        spec = _spec(toa_jitter_std=0.0, merge="emission",
                     sources=(SourceSpec(period=10.0, phase=0.0), SourceSpec(period=20.0, phase=gap)))
        ep = simulate(spec, 0)
        assert bool(_multi(ep.mask).any()) == merges
        if merges:
            assert np.all(np.mod(ep.toa[_multi(ep.mask)], 20.0) == 0.0)


# ---- paper-v1 ---------------------------------------------------------------------------------
def test_paper_v1_is_paper_v0_but_for_mk94_merging():
    v0, v1 = load_suite("paper-v0"), load_suite("paper-v1")
    assert [e.name for e in v0] == [e.name for e in v1]
    changed = [b.name for a, b in zip(v0, v1) if a.spec != b.spec]
    assert changed == ["mk94-missing-two", "mk94-pt-missing-three"]
    for a, b in zip(v0, v1):
        if b.name in changed:
            assert b.spec.merge == "emission" and b.settings["merge"] == "emission"
            assert b.spec.replace(merge="received", description=a.spec.description) == a.spec
        else:
            assert a == b


@pytest.mark.parametrize("name, lost_v0, lost_v1", [("mk94-missing-two", (0.045, 0.065), (0.022, 0.026)),
                                                    ("mk94-pt-missing-three", (0.08, 0.10), (0.028, 0.033))])
def test_paper_v1_loses_the_papers_share_of_pulses(name, lost_v0, lost_v1):
    """Fig. 12 (T = 11, 30): one arrival in 41 coincides (2.4 %); Fig. 13 (T = 11, 30, 80): ~3 %.
    paper-v0's merging of the jittered arrivals loses ~5 % and ~9 %."""
    for suite, (lo, hi) in (("paper-v0", lost_v0), ("paper-v1", lost_v1)):
        e = find_entry(f"{suite}/{name}")
        eps = simulate_many(e.spec, list(e.test)[:5])
        lost = [1 - len(ep) / np.sum(ep.truth.schedule_toa <= ep.toa[-1]) for ep in eps]
        assert lo < np.mean(lost) < hi, (suite, np.mean(lost))

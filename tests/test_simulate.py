"""The pulse simulator: determinism, the order of effects, every modulation, windows, priors, truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from deint_env import simulate
from deint_env.errors import DeintError
from deint_env.sim.streams import stream, streams
from deint_env.simulate import simulate_many
from deint_env.scenario import Modulation, PriorSpec, Range, ScenarioSpec, SourceSpec
from deint_env.suites import resolve_scenario


def bits_of(mask: np.ndarray, i: int) -> np.ndarray:
    return ((mask >> np.uint64(i)) & np.uint64(1)).astype(bool)


def one_source(mod: Modulation, n: int = 400, period: float = 10.0, phase: float = 2.0) -> ScenarioSpec:
    return ScenarioSpec(name="mod", sources=(SourceSpec(period=period, phase=phase, modulation=mod),), n_pulses=n)


RICH = ScenarioSpec(
    name="rich", n_pulses=800, toa_jitter_std=0.2, pri_jitter_std=0.3, missing_prob=0.1,
    coincidence_resolution=0.4, spurious_rate=0.2, amplitudes=True, amplitude_noise_std=0.05,
    sources=(SourceSpec(period=Range(8.0, 12.0), amplitude=Range(1.0, 2.0), amplitude_std=0.1),
             SourceSpec(period=Range(13.0, 20.0, log=True), modulation=Modulation("sinusoidal", depth=0.1, cycle=30)),
             SourceSpec(period=25.0, modulation=Modulation("drifting", alpha=1.0, drift_std=0.05),
                        active=((0.1, 0.6),))),
    priors=PriorSpec(period_error=0.02, phase_error=0.1))


def assert_same_episode(a, b):
    for name in ("toa", "source", "mask", "amplitude"):
        x, y = getattr(a, name), getattr(b, name)
        if x is None:
            assert y is None
        else:
            assert x.dtype == y.dtype and np.array_equal(x, y), name
    for name in ("period", "phase", "final_period", "n_received", "schedule_toa", "schedule_pri",
                 "schedule_offsets"):
        assert np.array_equal(getattr(a.truth, name), getattr(b.truth, name), equal_nan=True), name
    pa, pb = a.priors.as_info(), b.priors.as_info()
    assert pa.keys() == pb.keys()
    for k in pa:
        if isinstance(pa[k], np.ndarray):
            assert np.array_equal(pa[k], pb[k], equal_nan=True), k
        else:
            assert pa[k] == pb[k], k


# ---- determinism -------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["rich", "paper-v0/mk94-three", "robust-v0/robust-combined", "agile-v0/agile-drifting",
                                  "blind-v0/blind-n2to5-jitter0.1", "paper-v0/cm00-random5-jitter23"])
def test_same_seed_bit_identical(name):
    s = RICH if name == "rich" else resolve_scenario(name).replace(n_pulses=500)
    a, b = simulate(s, 123), simulate(s, 123)
    assert_same_episode(a, b)
    c = simulate(s, 124)
    assert not np.array_equal(a.toa, c.toa)


def test_dtypes_and_shapes():
    ep = simulate(RICH, 5)
    n = RICH.n_pulses
    assert len(ep) == n and ep.toa.shape == (n,) and ep.toa.dtype == np.float64
    assert ep.source.shape == (n,) and np.issubdtype(ep.source.dtype, np.integer)
    assert ep.mask.shape == (n,) and ep.mask.dtype == np.uint64
    assert ep.amplitude.shape == (n,) and ep.amplitude.dtype == np.float64
    assert ep.scenario == "rich" and ep.seed == 5


@pytest.mark.parametrize("seed", [-1, 2**63, 1.5, True, "3"])
def test_bad_seed(seed):
    with pytest.raises(DeintError, match="seed"):
        simulate(RICH, seed)


# ---- the structure of every episode (property test) ---------------------------------------------
@st.composite
def small_specs(draw):
    k = draw(st.integers(1, 4))
    periods = [draw(st.floats(1.0, 50.0)) for _ in range(k)]
    sources = []
    for t in periods:
        phase = draw(st.one_of(st.none(), st.floats(0.0, 60.0)))
        sources.append(SourceSpec(period=t, phase=phase))
    res = draw(st.sampled_from([0.0, 0.0, 0.3, 1.0]))
    res = res if res < min(periods) / 2 else 0.0  # validation: a source must not merge with itself
    return ScenarioSpec(
        name="prop", sources=tuple(sources), n_pulses=draw(st.integers(1, 300)),
        toa_jitter_std=draw(st.sampled_from([0.0, 0.1, 0.5])),
        pri_jitter_std=draw(st.floats(0.0, 0.3)) * min(periods) / 3,
        missing_prob=draw(st.sampled_from([0.0, 0.2, 0.6])), coincidence_resolution=res,
        spurious_rate=draw(st.sampled_from([0.0, 0.1, 1.0])), amplitudes=draw(st.booleans()))


@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(s=small_specs(), seed=st.integers(0, 2**63 - 1))
def test_property_episode_structure(s, seed):
    ep = simulate(s, seed)
    k = len(s.sources)
    assert len(ep) == s.n_pulses
    assert np.all(np.isfinite(ep.toa))
    assert np.all(np.diff(ep.toa) >= 0)
    if s.coincidence_resolution > 0:  # merging leaves no two pulses closer than the resolution
        assert np.all(np.diff(ep.toa) >= s.coincidence_resolution)
    assert ep.source.min() >= -1 and ep.source.max() < k
    assert np.array_equal(ep.source < 0, ep.mask == 0)  # spurious iff no source bit
    real = ep.source >= 0
    assert np.all(bits_of(ep.mask[real], 0) | (ep.source[real] != 0))
    for j in np.flatnonzero(real)[:50]:
        assert (int(ep.mask[j]) >> int(ep.source[j])) & 1
    assert int(np.bitwise_or.reduce(ep.mask)) < (1 << k)
    for i in range(k):
        assert ep.truth.n_received[i] == np.count_nonzero(bits_of(ep.mask, i))
    assert (ep.amplitude is not None) == s.amplitudes
    if s.missing_prob == 0 and s.spurious_rate == 0 and s.coincidence_resolution == 0:
        assert np.all(real)
    assert_same_episode(ep, simulate(s, seed))


# ---- noise-free schedules ----------------------------------------------------------------------
def test_constant_pri_sources_are_exactly_periodic():
    periods, phases = [11.0, 17.0, 29.5], [3.0, 4.0, 0.25]
    s = ScenarioSpec(name="c", sources=tuple(SourceSpec(period=t, phase=p) for t, p in zip(periods, phases)),
                     n_pulses=2000)
    ep = simulate(s, 0)
    assert np.all(ep.source >= 0)
    assert np.array_equal(ep.mask, np.left_shift(np.uint64(1), ep.source.astype(np.uint64)))
    for i, (t, p) in enumerate(zip(periods, phases)):
        x = ep.toa[ep.source == i]
        n = np.arange(x.size)
        np.testing.assert_allclose(x, p + n * t, rtol=0, atol=1e-9 * x.max())
        assert ep.truth.n_received[i] == x.size
        np.testing.assert_allclose(ep.truth.source_schedule(i)[: x.size], x, rtol=0, atol=1e-9 * x.max())
        assert ep.truth.period[i] == t and ep.truth.phase[i] == p and ep.truth.final_period[i] == t
    # The first n_pulses arrivals of the merged schedules: nothing earlier was dropped.
    all_sched = np.sort(np.concatenate([p + np.arange(2000) * t for t, p in zip(periods, phases)]))[:2000]
    np.testing.assert_allclose(ep.toa, all_sched, rtol=0, atol=1e-8)


def test_drawn_period_and_phase_stay_in_range():
    s = ScenarioSpec(name="r", sources=(SourceSpec(period=Range(5.0, 6.0)), SourceSpec(period=Range(1.0, 100.0, log=True),
                                                                                     phase=Range(3.0, 4.0))),
                     n_pulses=300)
    for seed in range(20):
        tr = simulate(s, seed).truth
        assert 5.0 <= tr.period[0] <= 6.0 and 0.0 <= tr.phase[0] < tr.period[0]  # phase None: uniform [0, T)
        assert 1.0 <= tr.period[1] <= 100.0 and 3.0 <= tr.phase[1] <= 4.0


# ---- receiver effects ----------------------------------------------------------------------------
def test_missing_fraction_matches_probability():
    p = 0.2
    s = ScenarioSpec(name="m", sources=(SourceSpec(period=10.0, phase=0.0), SourceSpec(period=13.0, phase=1.0)),
                     n_pulses=20_000, missing_prob=p)
    ep = simulate(s, 7)
    t_last = ep.toa[-1]
    scheduled = sum(int(np.count_nonzero(ep.truth.source_schedule(i) <= t_last)) for i in range(2))
    received = int(ep.truth.n_received.sum())
    assert received == len(ep)
    assert abs(1 - received / scheduled - p) < 0.015  # binomial sd ~ 0.0025
    # the survivors are exactly on their schedules (no jitter)
    for i in range(2):
        assert np.all(np.isin(ep.toa[ep.source == i], ep.truth.source_schedule(i)))


def test_spurious_count_matches_rate():
    r = 0.25
    s = ScenarioSpec(name="s", sources=(SourceSpec(period=10.0, phase=0.0), SourceSpec(period=15.0, phase=0.0)),
                     n_pulses=20_000, spurious_rate=r)
    ep = simulate(s, 3)
    n_spur = int(np.count_nonzero(ep.source < 0))
    n_real = len(ep) - n_spur
    assert abs(n_spur / n_real - r) < 0.03  # Poisson sd ~ 0.004
    assert np.all(ep.mask[ep.source < 0] == 0)
    # spurious times are uniform: the share in the first half of the episode is ~ 1/2
    spur = ep.toa[ep.source < 0]
    assert abs(np.mean(spur < 0.5 * (ep.toa[0] + ep.toa[-1])) - 0.5) < 0.05


def test_toa_jitter_is_white_and_non_cumulative():
    sd = 0.5
    s = ScenarioSpec(name="j", sources=(SourceSpec(period=10.0, phase=0.0),), n_pulses=5000, toa_jitter_std=sd)
    ep = simulate(s, 11)
    err = ep.toa - 10.0 * np.arange(5000)
    assert abs(err.std() - sd) < 0.05 and abs(err.mean()) < 0.05
    assert abs(np.corrcoef(err[:-1], err[1:])[0, 1]) < 0.1  # white: no random walk


def test_pri_jitter_is_cumulative():
    sd = 0.3
    s = ScenarioSpec(name="j", sources=(SourceSpec(period=10.0, phase=0.0),), n_pulses=5000, pri_jitter_std=sd)
    ep = simulate(s, 11)
    d = np.diff(ep.toa)
    assert abs(d.mean() - 10.0) < 0.05 and abs(d.std() - sd) < 0.03
    assert abs(np.corrcoef(d[:-1], d[1:])[0, 1]) < 0.1  # independent intervals (a random walk of arrivals)


def test_coincident_pulses_merge():
    s = ScenarioSpec(name="c", sources=(SourceSpec(period=10.0, phase=0.0), SourceSpec(period=15.0, phase=0.0)),
                     n_pulses=40, coincidence_resolution=0.5, amplitudes=True)
    ep = simulate(s, 0)
    # arrivals: the union of 10k and 15k, the multiples of 30 once each
    expected = np.unique(np.concatenate([10.0 * np.arange(60), 15.0 * np.arange(40)]))[:40]
    np.testing.assert_array_equal(ep.toa, expected)
    both = ep.toa % 30 == 0
    assert np.array_equal(ep.mask[both], np.full(both.sum(), 3, np.uint64))
    assert np.all(ep.source[both] == 0)  # the earliest member (source order breaks the tie)
    assert np.array_equal(ep.mask[(ep.toa % 10 == 0) & ~both], np.full(np.sum((ep.toa % 10 == 0) & ~both), 1, np.uint64))
    assert np.all(ep.mask[ep.toa % 10 != 0] == 2) and np.all(ep.source[ep.toa % 10 != 0] == 1)
    np.testing.assert_allclose(ep.amplitude[both], 2.0)  # summed amplitudes
    np.testing.assert_allclose(ep.amplitude[~both], 1.0)
    assert ep.truth.n_received[0] == np.count_nonzero(ep.toa % 10 == 0)
    assert ep.truth.n_received[1] == np.count_nonzero(ep.toa % 15 == 0)


def test_coincident_pulses_without_resolution_stay_apart():
    s = ScenarioSpec(name="c", sources=(SourceSpec(period=10.0, phase=0.0), SourceSpec(period=15.0, phase=0.0)),
                     n_pulses=40)
    ep = simulate(s, 0)
    expected = np.sort(np.concatenate([10.0 * np.arange(60), 15.0 * np.arange(40)]))[:40]
    np.testing.assert_array_equal(ep.toa, expected)
    at30 = np.flatnonzero(ep.toa == 30.0)
    assert at30.size == 2
    assert sorted(ep.source[at30].tolist()) == [0, 1]
    assert np.all(np.isin(ep.mask, [1, 2]))


def test_merge_chains_merge_whole():
    # pulses at 0, 0.3, 0.6 (three sources), resolution 0.5: every gap < 0.5, so one pulse
    s = ScenarioSpec(name="c", sources=(SourceSpec(period=100.0, phase=0.0), SourceSpec(period=100.0, phase=0.3),
                                        SourceSpec(period=100.0, phase=0.6)), n_pulses=4, coincidence_resolution=0.5)
    ep = simulate(s, 0)
    np.testing.assert_allclose(ep.toa, [0.0, 100.0, 200.0, 300.0])
    assert np.all(ep.mask == 7) and np.all(ep.source == 0)


def test_spurious_merged_into_a_real_pulse_keeps_the_real_source():
    s = ScenarioSpec(name="c", sources=(SourceSpec(period=1.0, phase=0.0),), n_pulses=3000, spurious_rate=0.5,
                     coincidence_resolution=0.3)
    ep = simulate(s, 1)
    real = ep.source == 0
    assert np.array_equal(real, ep.mask == 1) and np.all(ep.mask[~real] == 0)
    on_grid = np.isclose(ep.toa, np.round(ep.toa), atol=1e-9)
    assert np.all(real[on_grid])  # a pulse on the source's grid is never called spurious
    # A spurious pulse just before a grid pulse absorbs it: the merged pulse keeps the earlier TOA and
    # is the source's; the grid time itself then has no pulse of its own.
    absorbed = ep.toa[real & ~on_grid]
    assert absorbed.size > 0
    grid_after = np.ceil(absorbed)
    assert not np.any(np.isin(grid_after, ep.toa))
    assert np.all(np.diff(ep.toa) >= 0.3)
    assert np.count_nonzero(real) == ep.truth.n_received[0]


# ---- modulations (Modulation's docstring) ---------------------------------------------------------
def intervals(mod: Modulation, n: int = 400, period: float = 10.0):
    ep = simulate(one_source(mod, n, period), 4)
    assert ep.toa[0] == 2.0
    d = np.diff(ep.toa)
    np.testing.assert_allclose(ep.truth.source_pri(0)[: n - 1], d, rtol=1e-9)  # the truth records the PRIs
    return d, np.arange(n - 1)


def test_stagger_pattern_cycles():
    pat = (1.0, 1.3, 1.7)
    d, n = intervals(Modulation("stagger", pattern=pat))
    np.testing.assert_allclose(d, 10.0 * np.array(pat)[n % 3] / np.mean(pat), rtol=1e-9)
    assert math.isclose(d[:3].sum(), 30.0)


def test_dwell_switch_holds():
    pat, cycle = (1.0, 1.4, 0.8), 20
    d, n = intervals(Modulation("dwell_switch", pattern=pat, cycle=cycle))
    np.testing.assert_allclose(d, 10.0 * np.array(pat)[(n // cycle) % 3] / np.mean(pat), rtol=1e-9)
    assert np.ptp(d[:cycle]) < 1e-9 and not math.isclose(d[cycle - 1], d[cycle])


def test_sliding_saw_tooth():
    depth, cycle = 0.3, 32
    d, n = intervals(Modulation("sliding", depth=depth, cycle=cycle))
    np.testing.assert_allclose(d, 10.0 * (1 + depth * ((n % cycle) / (cycle - 1) - 0.5)), rtol=1e-9)
    assert math.isclose(d.min(), 10.0 * (1 - depth / 2)) and math.isclose(d.max(), 10.0 * (1 + depth / 2))


def test_sinusoidal_bounded_and_sinusoidal():
    depth, cycle = 0.2, 25
    d, n = intervals(Modulation("sinusoidal", depth=depth, cycle=cycle))
    s = (d / 10.0 - 1) / depth  # = sin(2 pi n / cycle + psi)
    assert np.all(np.abs(s) <= 1 + 1e-9)
    assert s.max() > 0.95 and s.min() < -0.95  # reaches close to +-depth within a few cycles
    # a sinusoid of angular step a satisfies s[n+1] + s[n-1] = 2 cos(a) s[n] whatever its phase psi
    np.testing.assert_allclose(s[2:] + s[:-2], 2 * np.cos(2 * np.pi / cycle) * s[1:-1], atol=1e-7)
    # psi is drawn per episode: another seed gives another phase
    other = np.diff(simulate(one_source(Modulation("sinusoidal", depth=depth, cycle=cycle)), 5).toa)
    assert not np.allclose(other, d)


def test_drifting_alpha_one_without_noise_is_constant():
    d, _ = intervals(Modulation("drifting", alpha=1.0, drift_std=0.0))
    np.testing.assert_allclose(d, 10.0, rtol=1e-12)


def test_drifting_alpha_geometric():
    alpha = 0.999
    d, n = intervals(Modulation("drifting", alpha=alpha, drift_std=0.0))
    np.testing.assert_allclose(d, 10.0 * alpha**n, rtol=1e-9)


def test_drifting_random_walk_increments():
    ds = 0.02
    d, _ = intervals(Modulation("drifting", alpha=1.0, drift_std=ds), n=3000)
    inc = np.diff(d)  # PRI_{n+1} - PRI_n = drift_std v_n
    assert abs(inc.std() - ds) < 0.1 * ds and abs(inc.mean()) < 0.1 * ds


# ---- on-windows, amplitudes, blind draws ------------------------------------------------------------
def test_dropout_window():
    periods = (10.0, 13.0, 17.0)
    srcs = (SourceSpec(period=10.0, phase=0.0), SourceSpec(period=13.0, phase=1.0),
            SourceSpec(period=17.0, phase=2.0, active=((0.0, 0.5),)))
    s = ScenarioSpec(name="w", sources=srcs, n_pulses=1000)
    ep = simulate(s, 0)
    h0 = 1000 / sum(1 / t for t in periods)
    late = ep.toa[ep.source == 2]
    assert late.size > 0 and late.max() < 0.5 * h0
    assert late.max() + 17.0 >= 0.5 * h0  # it ran until the window closed
    assert ep.toa[-1] > 0.5 * h0  # the episode goes on without it


def test_onset_window_and_two_windows():
    srcs = (SourceSpec(period=10.0, phase=0.0),
            SourceSpec(period=7.0, phase=0.0, active=((0.2, 0.4), (0.6, 2.0))))
    s = ScenarioSpec(name="w", sources=srcs, n_pulses=1000)
    ep = simulate(s, 0)
    h0 = 1000 / (1 / 10.0 + 1 / 7.0)
    x = ep.toa[ep.source == 1]
    inside = ((x >= 0.2 * h0) & (x < 0.4 * h0)) | (x >= 0.6 * h0)
    assert x.size > 0 and np.all(inside)
    assert np.any(x < 0.4 * h0) and np.any(x >= 0.6 * h0)


def test_amplitudes_only_when_asked():
    base = ScenarioSpec(name="a", sources=(SourceSpec(period=10.0, phase=0.0, amplitude=3.0),
                                           SourceSpec(period=14.5, phase=1.0, amplitude=5.0)), n_pulses=200)
    assert simulate(base, 0).amplitude is None
    ep = simulate(base.replace(amplitudes=True), 0)
    assert ep.amplitude is not None and ep.amplitude.shape == ep.toa.shape
    np.testing.assert_allclose(ep.amplitude[ep.source == 0], 3.0)
    np.testing.assert_allclose(ep.amplitude[ep.source == 1], 5.0)
    np.testing.assert_allclose(ep.priors.amplitude, [3.0, 5.0])
    noisy = simulate(base.replace(amplitudes=True, amplitude_noise_std=0.1), 0)
    err = noisy.amplitude - np.where(noisy.source == 0, 3.0, 5.0)
    assert 0.05 < err.std() < 0.15
    assert np.array_equal(noisy.toa, ep.toa)  # amplitude noise does not move the pulses


def test_blind_n_active_draws():
    s = ScenarioSpec(name="b", sources=tuple(SourceSpec(period=10.0 + i) for i in range(5)), n_pulses=100,
                     blind=True, label_budget=8, n_active=(2, 4), priors=PriorSpec(kind="none"))
    seen = set()
    for seed in range(40):
        ep = simulate(s, seed)
        k = ep.truth.n_sources
        assert 2 <= k <= 4
        assert ep.source.max() < k and ep.truth.n_received.size == k
        np.testing.assert_allclose(ep.truth.period, 10.0 + np.arange(k))  # the first k sources
        assert ep.priors.blind and ep.priors.n_labels == 8
        seen.add(k)
    assert seen == {2, 3, 4}


# ---- priors ------------------------------------------------------------------------------------------
def test_explicit_priors_reproduce_the_spec():
    s = resolve_scenario("paper-v0/mk94-three").replace(n_pulses=50)
    p = simulate(s, 0).priors
    np.testing.assert_array_equal(p.period, [39.0, 40.0, 90.0])
    np.testing.assert_array_equal(p.phase, [3.0, 4.0, 2.0])
    np.testing.assert_array_equal(p.period_std, [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(p.phase_std, [1.0, 1.0, 1.0])
    assert p.jitter_std == 3.0 and p.n_labels == 3 and not p.blind
    # relative frequencies known (MK94 IV-2): pi_i proportional to 1/T_i of the true sources
    rate = 1 / np.array([11.0, 30.0, 80.0])
    np.testing.assert_allclose(p.source_prob, rate / rate.sum())
    post = simulate(resolve_scenario("paper-v0/mk94-pt-post").replace(n_pulses=50), 0).priors
    assert post.n_labels == 4
    np.testing.assert_array_equal(post.source_prob, [0.25] * 4)
    np.testing.assert_array_equal(post.period_std, [1e3] * 4)


def test_explicit_priors_without_phases_are_nan():
    s = ScenarioSpec(name="e", sources=(SourceSpec(period=10.0),), n_pulses=10,
                     priors=PriorSpec(kind="explicit", period=(9.0, 12.0), period_std=(0.5, 0.7), phase_std=(1.0,)))
    p = simulate(s, 0).priors
    np.testing.assert_array_equal(p.period, [9.0, 12.0])
    np.testing.assert_array_equal(p.period_std, [0.5, 0.7])
    assert np.all(np.isnan(p.phase)) and not p.phase_known.any()
    np.testing.assert_array_equal(p.source_prob, [0.5, 0.5])  # more tracks than sources: uniform


def test_perturbed_priors_exact_when_error_free():
    s = RICH.replace(priors=PriorSpec(kind="perturbed", period_error=0.0, period_bias=1.0, phase_error=0.0))
    ep = simulate(s, 9)
    np.testing.assert_array_equal(ep.priors.period, ep.truth.period)
    np.testing.assert_array_equal(ep.priors.phase, ep.truth.phase)
    rate = 1 / ep.truth.period
    np.testing.assert_allclose(ep.priors.source_prob, rate / rate.sum())
    assert ep.priors.jitter_std == s.toa_jitter_std and ep.priors.missing_prob == s.missing_prob


def test_perturbed_priors_bias_error_and_unknown_phase():
    s = RICH.replace(priors=PriorSpec(kind="perturbed", period_bias=1 / 0.9, phase_error=None))
    ep = simulate(s, 9)
    np.testing.assert_allclose(ep.priors.period, ep.truth.period / 0.9, rtol=1e-12)
    assert np.all(np.isnan(ep.priors.phase)) and np.all(np.isnan(ep.priors.phase_std))
    # period_error: relative errors spread like period_error (pooled over seeds)
    s = RICH.replace(n_pulses=20, priors=PriorSpec(kind="perturbed", period_error=0.05, phase_error=0.1))
    rel, ph = [], []
    for seed in range(150):
        e = simulate(s, seed)
        rel.append(e.priors.period / e.truth.period - 1)
        ph.append((e.priors.phase - e.truth.phase) / e.truth.period)
    assert 0.04 < np.std(rel) < 0.06 and 0.08 < np.std(ph) < 0.12


def test_truth_n_received_counts_mask_bits():
    ep = simulate(RICH, 21)
    for i in range(ep.truth.n_sources):
        assert ep.truth.n_received[i] == np.count_nonzero(bits_of(ep.mask, i))
    assert np.any(np.bitwise_and(ep.mask, ep.mask - np.uint64(1)) != 0)  # RICH does merge some pulses
    # the schedule is grouped by source and time-ordered within one
    for i in range(ep.truth.n_sources):
        assert np.all(np.diff(ep.truth.source_schedule(i)) > 0)
    assert ep.truth.schedule_offsets[-1] == ep.truth.schedule_toa.size == ep.truth.schedule_pri.size


# ---- the priors file (docs/design.md section 7) round trip -----------------------------------------
def _priors_round_trip(spec):
    import json

    from deint_env.episode import Priors

    p = simulate(spec, 0).priors
    q = Priors.from_json_dict(json.loads(json.dumps(p.to_json_dict())))
    a, b = p.as_info(), q.as_info()
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], np.ndarray):
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
        else:
            assert a[k] == b[k], k


@pytest.mark.parametrize("name", ["paper-v0/mk94-three", "paper-v0/cm00-five-jitter23", "robust-v0/robust-combined",
                                  "paper-v0/mk94-pt-post", "blind-v0/blind-n2to5-jitter0.1"])
def test_priors_file_round_trip(name):
    _priors_round_trip(resolve_scenario(name).replace(n_pulses=20))
    _priors_round_trip(RICH)


def test_blind_priors_file_keeps_the_channel_statistics():
    spec = resolve_scenario("blind-v0/blind-n2to5-jitter0.1").replace(n_pulses=20, missing_prob=0.1,
                                                                      spurious_rate=0.2, coincidence_resolution=0.3)
    _priors_round_trip(spec)


# ---- valid specs that cannot be simulated (validation gaps) ---------------------------------------------
def test_blind_n_active_with_windowed_first_source():
    try:
        s = ScenarioSpec(name="b", sources=(SourceSpec(period=10.0, active=((0.0, 0.5),)), SourceSpec(period=12.0)),
                         n_pulses=100, blind=True, label_budget=2, n_active=(1, 2), priors=PriorSpec(kind="none"))
    except DeintError:
        return  # rejected at construction: fine
    for seed in range(10):
        assert len(simulate(s, seed)) == 100


def test_resolution_above_the_pri_is_rejected():
    with pytest.raises(DeintError, match="coincidence_resolution"):
        ScenarioSpec(name="d", sources=(SourceSpec(period=10.0, phase=0.0),), n_pulses=10, coincidence_resolution=20.0)


def test_drifting_growth_simulates_without_warnings():
    import warnings

    # alpha = 1.004 over 1000 pulses: the period grows ~55-fold, inside the 100-fold validation bound
    s = ScenarioSpec(name="d", sources=(SourceSpec(period=10.0, phase=0.0,
                                                   modulation=Modulation("drifting", alpha=1.004)),), n_pulses=1000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ep = simulate(s, 0)
    d = np.diff(ep.toa)
    np.testing.assert_allclose(d, 10.0 * 1.004 ** np.arange(999), rtol=1e-9)


def test_drifting_growth_beyond_100_fold_is_rejected():
    with pytest.raises(DeintError, match="modulation.alpha"):
        ScenarioSpec(name="d", sources=(SourceSpec(period=10.0, modulation=Modulation("drifting", alpha=1.01)),),
                     n_pulses=1000)


def test_drifting_alpha_top_of_range():
    try:
        s = ScenarioSpec(name="d", sources=(SourceSpec(period=10.0, phase=0.0,
                                                       modulation=Modulation("drifting", alpha=1.1)),), n_pulses=1000)
    except DeintError:
        return
    ep = simulate(s, 0)
    assert len(ep) == 1000 and np.all(np.isfinite(ep.toa))


# ---- simulate_many: the batch path, episode for episode the same as simulate ---------------------------
MANY = {
    "rich": RICH,  # amplitudes, merges, spurious, missing, cumulative jitter, sinusoidal, drifting, window
    "core": resolve_scenario("core-v0/core-n3-spread4-jitter0.2").replace(n_pulses=300),
    "many-sources": resolve_scenario("core-v0/core-n8-spread16-jitter0.2").replace(n_pulses=300),
    "blind-n-active": resolve_scenario("blind-v0/blind-n2to5-jitter0.5").replace(n_pulses=200),
    "merged": resolve_scenario("robust-v0/robust-combined").replace(n_pulses=300),
    "dropout-retry": resolve_scenario("robust-v0/robust-dropout").replace(n_pulses=300),  # horizons redone
    "agile": resolve_scenario("agile-v0/agile-all-stagger").replace(n_pulses=300),
    "ties": ScenarioSpec(name="ties", n_pulses=300,
                         sources=tuple(SourceSpec(period=t, phase=0.0) for t in (10.0, 15.0, 6.0, 12.0))),
    "phantom-amplitudes": ScenarioSpec(
        name="phantom", n_pulses=200, toa_jitter_std=1.0, amplitudes=True, amplitude_noise_std=0.1,
        sources=(SourceSpec(period=11.0, phase=3.0, amplitude=2.0, amplitude_std=0.3),
                 SourceSpec(period=Range(15.0, 20.0), amplitude=Range(0.5, 1.5), active=((0.2, 0.5), (0.6, 2.0)))),
        priors=PriorSpec(kind="explicit", period=(10.0, 18.0, 30.0), phase=(2.0, 4.0, 5.0), period_std=(1.0,),
                         phase_std=(1.0,))),
}


@pytest.mark.parametrize("name", list(MANY))
def test_simulate_many_equals_simulate(name):
    spec = MANY[name]
    seeds = [0, 1, 2**32 - 1, 2**32, 2**63 - 1] + list(range(1000, 1035))  # >= 32: the batch seeding
    many = simulate_many(spec, seeds)
    assert [e.seed for e in many] == seeds
    for seed, ep in zip(seeds, many):
        assert_same_episode(ep, simulate(spec, seed))


def test_simulate_many_splits_large_batches():
    spec = resolve_scenario("core-v0/core-n2-spread4-jitter0.2").replace(n_pulses=20_000)  # 13 episodes a batch
    seeds = list(range(30))
    for seed, ep in zip(seeds, simulate_many(spec, seeds)):
        assert_same_episode(ep, simulate(spec, seed))


def test_simulate_many_edge_cases():
    assert simulate_many(RICH, []) == []
    with pytest.raises(DeintError, match="seed"):
        simulate_many(RICH, [1, -1])
    a, b = simulate_many(RICH, [3, 4])
    a.toa[:] = 0.0  # episodes of one batch share no writable data
    assert_same_episode(b, simulate(RICH, 4))


def test_streams_match_stream():
    seeds = [0, 1, 2**32 - 1, 2**32, 2**63 - 1] + list(np.random.default_rng(0).integers(0, 2**63 - 1, 60).tolist())
    for role, index in ((0, 0), (2, 0), (8, 5), (7, 63)):
        for seed, rng in zip(seeds, streams(seeds, role, index)):
            ref = stream(seed, role, index)
            assert rng.bit_generator.state == ref.bit_generator.state
            assert np.array_equal(rng.standard_normal(5), ref.standard_normal(5))

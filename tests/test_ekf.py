"""CM00's EKF bank and LP's coupled EKFs (baselines.ekf, baselines.coupled) and their reproductions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from baselines.coupled import EKFCoupled
from baselines.ekf import EKFBank, pulse_count, round_down, smooth_count, smooth_count_jacobian
from baselines.reproduce import run_experiment
from baselines.reproduce.cm00 import paper_errors, run
from deint_env import ScenarioSpec, SourceSpec, make_policy, simulate
from deint_env.errors import DeintError
from deint_env.runner import play
from deint_env.scenario import PriorSpec
from deint_env.suites import find_entry

EXACT = PriorSpec(kind="perturbed", period_error=0.0, phase_error=0.0)


def three_trains(n_pulses: int = 600, priors: PriorSpec = EXACT) -> ScenarioSpec:
    """Three noise-free trains whose pulses never fall on a sampling instant (a TOA exactly on the grid
    would be counted or not by float rounding)."""
    sources = (SourceSpec(period=1.0, phase=0.313), SourceSpec(period=1.3713, phase=0.917),
               SourceSpec(period=2.9311, phase=2.111))
    return ScenarioSpec(name="three", sources=sources, n_pulses=n_pulses, priors=priors)


def five_trains(n_pulses: int):
    return simulate(find_entry("paper-v0/cm00-five-jitter0").spec.replace(n_pulses=n_pulses), 0)


def test_smooth_count_derivatives_match_finite_differences():
    rng = np.random.default_rng(0)
    f = rng.uniform(0.02, 0.2, 50)
    th = rng.uniform(0.1, 2 * math.pi - 0.1, 50)
    k = rng.uniform(0, 5000, 50)
    df, dth = smooth_count_jacobian(f, th, k)
    hf, hth = 1e-9, 1e-6
    fd_f = (smooth_count(f + hf, th, k) - smooth_count(f - hf, th, k)) / (2 * hf)
    fd_th = (smooth_count(f, th + hth, k) - smooth_count(f, th - hth, k)) / (2 * hth)
    np.testing.assert_allclose(df, fd_f, rtol=1e-4, atol=1e-2)
    np.testing.assert_allclose(dth, fd_th, rtol=1e-5, atol=1e-7)
    # (7) literally: k + 2k cos(2 pi f k - theta), -1/2pi - cos(2 pi f k - theta)/pi
    c = np.cos(2 * math.pi * f * k - th)
    np.testing.assert_allclose(df, k + 2 * k * c)
    np.testing.assert_allclose(dth, -1 / (2 * math.pi) - c / math.pi)


def test_smooth_count_follows_the_count():
    """The A = 1 smoothing stays within a pulse of the count, and its mean over a cycle is the count's."""
    f, th = 0.0731, 2.0
    k = np.arange(0, 2000)
    h, hs = pulse_count(f, th, k), smooth_count(f, th, k)
    assert np.max(np.abs(h - hs)) < 1.0
    assert abs(np.mean(h - hs)) < 0.01


def test_count_model_matches_the_true_count():
    ep = simulate(three_trains(), 0)
    tr = ep.truth
    ts = 0.0937
    k = np.arange(int(ep.toa[-1] / ts))
    observed = np.searchsorted(ep.toa, k * ts, side="right")  # pulses with TOA <= k Ts
    f, th = ts / tr.period, 2 * math.pi * tr.phase / tr.period
    model = pulse_count(f[:, None], th[:, None], k[None]).sum(axis=0)
    np.testing.assert_array_equal(model, observed)
    # 2 pi-periodic in theta: a phase pushed out of [0, 2 pi) is the same train
    shifted = pulse_count(f[:, None], th[:, None] + 2 * math.pi * np.array([[1], [-1], [2]]), k[None]).sum(axis=0)
    np.testing.assert_array_equal(shifted, observed)


def test_round_down():
    assert round_down(0.0153846) == pytest.approx(0.015)
    assert round_down(0.01) == pytest.approx(0.01)
    assert round_down(123.0) == pytest.approx(120.0)


def test_from_the_truth_it_stays_put_and_labels_perfectly():
    ep = simulate(three_trains(), 0)
    pol = EKFBank(n_filters=4)
    res = play(pol, ep, policy_seed=0)
    assert res.metrics["accuracy"] == 1.0
    est = pol.estimates()
    np.testing.assert_allclose(est["period"], ep.truth.period, rtol=1e-5)
    np.testing.assert_allclose(est["phase"], ep.truth.phase, atol=1e-3)


def test_converges_from_ten_percent_prf_error_on_five_trains():
    """CM00 Tables I-II, shortened to 1000 pulses (measured over 12 bank seeds: max PRF error <= 0.07 %,
    max phase error <= 4.6 %, second-half label accuracy >= 0.85)."""
    ep = five_trains(1000)
    assert np.all(np.abs(ep.priors.period / ep.truth.period - 1 / 0.9) < 1e-12) and np.all(np.isnan(ep.priors.phase))
    r = run(EKFBank(), ep, 0)
    est = r["policy"].estimates()
    prf, ph = paper_errors(est["period"], est["phase"], ep)
    assert prf.max() < 0.1 and ph.max() < 6.0
    assert np.mean(r["labels"][500:] == ep.source[500:]) > 0.8


def test_deterministic_given_the_seed():
    ep = five_trains(300)
    a, b, c = (run(EKFBank(n_filters=8), ep, s) for s in (3, 3, 4))
    np.testing.assert_array_equal(a["labels"], b["labels"])
    np.testing.assert_array_equal(a["policy"].x, b["policy"].x)
    assert not np.array_equal(a["policy"].x, c["policy"].x)
    fixed = [run(EKFBank(n_filters=8, seed=7), ep, s)["policy"].x for s in (1, 2)]  # own seed wins
    np.testing.assert_array_equal(*fixed)


def test_known_phases_are_used():
    """Priors with phases (2 % of a period off) start the bank around them: no phase search needed
    (measured: accuracy 0.90, the misses are near-coincident pulses; period errors <= 3e-4)."""
    ep = simulate(three_trains(priors=PriorSpec(kind="perturbed", period_error=0.01, phase_error=0.02)), 1)
    pol = EKFBank(n_filters=2)
    res = play(pol, ep, policy_seed=0)
    assert res.metrics["accuracy"] > 0.85
    np.testing.assert_allclose(pol.estimates()["period"], ep.truth.period, rtol=1e-3)


def test_coupled_runs_and_gives_finite_estimates():
    ep = simulate(find_entry("paper-v0/cm00-near-equal").spec.replace(n_pulses=400), 0)
    pol = make_policy("ekf-coupled:n_filters=4")
    res = play(pol, ep, policy_seed=0)
    est = pol.estimates()
    assert np.all(np.isfinite(est["period"])) and np.all(est["period"] > 0) and np.all(np.isfinite(est["phase"]))
    assert np.all((pol.c >= 0) & (pol.c <= 1)) and np.all(np.diagonal(pol.c, axis1=1, axis2=2) == 0)
    assert 0 <= res.metrics["accuracy"] <= 1


def test_coupled_with_full_subtraction_tracks_from_the_truth():
    ep = simulate(three_trains(), 0)
    pol = EKFCoupled(n_filters=2, mu=0.0, c0=1.0)
    assert play(pol, ep, policy_seed=0).metrics["accuracy"] == 1.0


def test_registered_and_validated():
    assert isinstance(make_policy("ekf-bank:n_filters=4,oversample=12"), EKFBank)
    for bad in ("ekf-bank:n_filters=0", "ekf-bank:oversample=1", "ekf-bank:label_scale=x", "ekf-coupled:asym=1.5"):
        with pytest.raises(DeintError):
            make_policy(bad)
    blind = simulate(find_entry("blind-v0/blind-n2to2-jitter0.1").spec.replace(n_pulses=50), 0)
    with pytest.raises(DeintError, match="needs priors"):
        play(make_policy("ekf-bank"), blind)


@pytest.mark.parametrize("name", ["cm00-tables-1-2", "cm00-fig6-table3", "cm00-tables-4-5"])
def test_reproductions_quick(tmp_path, name):
    rep = run_experiment(name, tmp_path, quick=True)
    assert rep.rows and rep.files
    for f in rep.files:
        assert (tmp_path / f).stat().st_size > 1000
    assert (tmp_path / f"{name}.txt").exists() and (tmp_path / f"{name}.json").exists()

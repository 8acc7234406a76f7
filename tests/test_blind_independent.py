"""Every blind policy labels files of its own generator (tests/independent_agile.py, plain numpy, not
deint_env.sim) through `deint label`, with `--n-sources K` and with nothing: no priors file, so the
TOA noise is measured from the pulses (baselines/blind/noise.py).

Accuracy is the Hungarian-matched accuracy, computed here independently of deint_env.metrics.  The
fast tests take a few files; the full grid (every scene and channel) is `slow`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.blind import policy as blind_policy
from baselines.blind.noise import estimate_noise
from deint_env.cli import main
from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError
from deint_env.policies import make_policy
from deint_env.runner import play
from independent_agile import (KINDS, TOA_NOISE, agile_file, grid, matched_accuracy, read_labels,
                               write_pulses)

BLIND = ("cdif", "sdif", "pri-transform", "dbscan", "hdbscan", "renewal-ml", "seq")
K = 3


def label(tmp_path, capsys, f, policy: str, *args: str) -> np.ndarray:
    write_pulses(tmp_path / "p.csv", f)
    code = main(["label", str(tmp_path / "p.csv"), "--policy", policy, *args, "-o", str(tmp_path / "l.csv")])
    assert code == 0, capsys.readouterr().err
    labels = read_labels(tmp_path / "l.csv")
    budget = K if args else 32
    assert labels.shape == f.toa.shape and labels.min() >= -1 and labels.max() < budget, policy
    return labels


@pytest.mark.parametrize("policy", BLIND)
def test_every_blind_policy_runs_with_k_and_with_nothing(tmp_path, capsys, policy):
    """With --n-sources 3 and with no priors at all, each policy labels the file: valid labels in its
    budget, some pulses given to trains (not all called spurious)."""
    f = agile_file(("stagger", "jittered", "jittered"), seed=5, n_pulses=400)
    for args in (("--n-sources", str(K)), ()):
        assert (label(tmp_path, capsys, f, policy, *args) >= 0).any(), (policy, args)


def test_renewal_ml_without_k_or_priors_is_accepted_by_the_cli(tmp_path, capsys):
    """renewal-ml used to refuse to run blind without a stated jitter; now it measures it."""
    f = agile_file(("jittered",) * 3, seed=2, n_pulses=300)
    labels = label(tmp_path, capsys, f, "renewal-ml")
    assert np.unique(labels[labels >= 0]).size >= K


def test_noise_estimate_tells_white_noise_from_pri_jitter():
    """On constant trains only the white noise is measured; on a renewal process (jittered PRIs) the
    PRI jitter dominates and grows with the jitter; within 30 % of the truth where it is identifiable."""
    rng = np.random.default_rng(0)
    toa = np.sort(np.concatenate([np.arange(rng.uniform(0, p), 20000, p) for p in (13.0, 17.3, 23.9)]))
    toa = np.sort(toa + 0.2 * rng.standard_normal(toa.size))
    est = estimate_noise(toa)
    assert est.toa == pytest.approx(0.2, rel=0.3) and est.pri < est.toa  # white noise dominates
    # jittered: +-5 % uniform intervals, sigma_v = 0.05 T / sqrt(3)
    f = agile_file(("jittered",) * 3, seed=4)
    est = estimate_noise(f.toa)
    assert est.pri > 3 * TOA_NOISE and est.pri == pytest.approx(0.05 * est.period / np.sqrt(3), rel=0.5)
    # a stagger's frame is a constant train: the white noise is measured there
    est = estimate_noise(agile_file(("stagger",) * 3, seed=1).toa)
    assert est.toa == pytest.approx(TOA_NOISE, rel=0.3)


@pytest.mark.parametrize("policy", ["cdif", "sdif", "dbscan", "hdbscan"])
def test_600_random_pulses_with_no_priors_are_labelled(policy):
    """The hostile input that took cdif 34-64 s (its times: benchmarks/bench_blind_agile.py and
    bench_startup.py): 600 pulses of no train, no priors, labelled; the noise is measured, not searched."""
    toa = np.sort(np.random.default_rng(1).uniform(0, 1000, 600))
    ep = Episode(scenario="random", seed=0, toa=toa, amplitude=None, source=np.zeros(600, np.int32),
                 mask=np.zeros(600, np.uint64), truth=None, priors=Priors(n_labels=32, blind=True))
    labels = play(make_policy(policy), ep, clustering=False).labels
    assert labels.shape == (600,) and labels.min() >= 0 and labels.max() <= 32


@pytest.mark.parametrize("policy", ["cdif", "renewal-ml"])
def test_records_too_long_are_refused_in_one_line(policy):
    p = make_policy(policy)
    limit = blind_policy.MAX_PULSES if policy == "cdif" else p.MAX_PULSES
    with pytest.raises(DeintError, match=f"at most {limit} pulses"):
        p.reset(Priors(n_labels=3, blind=True), {"n_pulses": limit + 1})


def anchored_priors(tmp_path, f, kinds, missing: float, spurious: float) -> str:
    """A priors file with each radar's mean PRI, first arrival and the channel's true statistics."""
    period, phase = [], []
    for i in range(len(kinds)):
        t = f.toa[f.source == i]
        period.append(float((t[-1] - t[0]) / ((t.size - 1) / (1 - missing))))
        phase.append(float(t[0]))
    pri_jitter = float(np.mean(period)) * 0.05 / np.sqrt(3)
    (tmp_path / "pr.json").write_text(json.dumps({
        "period": period, "phase": phase, "period_std": [0.01 * p for p in period],
        "phase_std": [0.5 * p for p in period], "jitter_std": TOA_NOISE, "pri_jitter_std": pri_jitter,
        "missing_prob": missing, "spurious_rate": spurious}))
    return str(tmp_path / "pr.json")


def renewal_gap(tmp_path, capsys, name: str) -> tuple[float, float]:
    """(blind with --n-sources 3, anchored with the true statistics) matched accuracy on grid file `name`."""
    _, kinds, missing, spurious, seed = next(c for c in grid(range(3)) if c[0] == name)
    f = agile_file(kinds, seed, missing=missing, spurious=spurious)
    blind = matched_accuracy(label(tmp_path, capsys, f, "renewal-ml", "--n-sources", str(K)), f.source)
    pr = anchored_priors(tmp_path, f, kinds, missing, spurious)
    assert main(["label", str(tmp_path / "p.csv"), "--policy", "renewal-ml", "--priors", pr,
                 "-o", str(tmp_path / "a.csv")]) == 0
    return blind, matched_accuracy(read_labels(tmp_path / "a.csv"), f.source)


def test_blind_renewal_ml_within_005_of_anchored_on_jittered_pris(tmp_path, capsys):
    blind, anchored = renewal_gap(tmp_path, capsys, "jittered-clean-s0")
    assert anchored > 0.9 and blind >= anchored - 0.05, (blind, anchored)


@pytest.mark.slow
def test_blind_renewal_ml_close_to_anchored_on_jittered_pris_clean_and_missing(tmp_path, capsys):
    """Three files each, clean and 20 % missing: blind within 0.05 of anchored on average and within
    0.09 on every file (measured: 0.02 to 0.08 behind, 0.04 on average).  Not reached with spurious
    pulses (0.3 to 0.45 behind): with a spurious option a new track's first pulses cost more than
    calling them spurious, and the beam drops the born track before its later pulses repay it."""
    gaps = []
    for name in [f"jittered-{ch}-s{s}" for ch in ("clean", "miss20") for s in range(3)]:
        blind, anchored = renewal_gap(tmp_path, capsys, name)
        assert anchored > 0.9 and blind >= anchored - 0.09, (name, blind, anchored)
        gaps.append(anchored - blind)
    assert np.mean(gaps) <= 0.05, gaps


def test_staggered_trains_found_blind(tmp_path, capsys):
    """Random-level staggers, clean and with 20 % missing: cdif and sdif keep each one train."""
    for name, kinds, miss, spur, seed in grid():
        if name.startswith("stagger-clean"):
            f = agile_file(kinds, seed, missing=miss, spurious=spur)
            for policy in ("cdif", "sdif"):
                acc = matched_accuracy(label(tmp_path, capsys, f, policy, "--n-sources", str(K)), f.source)
                assert acc > 0.95, (policy, acc)


@pytest.mark.slow
@pytest.mark.parametrize("case", list(grid()), ids=lambda c: c[0])
def test_full_grid_every_blind_policy_runs(tmp_path, capsys, case):
    """Every scene and channel of the grid: every blind policy gives valid labels with --n-sources 3
    (the accuracies are benchmarks/bench_blind_agile.py's table; the 0.90 target is not reached)."""
    name, kinds, miss, spur, seed = case
    f = agile_file(kinds, seed, missing=miss, spurious=spur)
    assert set(kinds) <= set(KINDS)
    for policy in BLIND:
        label(tmp_path, capsys, f, policy, "--n-sources", str(K))


def test_matched_accuracy_is_the_one_deint_score_reports(tmp_path, capsys):
    """The accuracy these tests compute agrees with `deint score`'s matched_accuracy."""
    f = agile_file(("stagger",) * 3, seed=3, n_pulses=300, spurious=0.1)
    labels = label(tmp_path, capsys, f, "cdif", "--n-sources", str(K))
    capsys.readouterr()
    assert main(["score", str(tmp_path / "l.csv"), "--truth", str(tmp_path / "p.csv"), "--n-labels", str(K),
                 "--json"]) == 0
    reported = json.loads(capsys.readouterr().out)["matched_accuracy"]
    assert reported == pytest.approx(matched_accuracy(labels, f.source), abs=1e-9)

"""Blind deinterleavers (baselines/blind): CDIF, SDIF, the PRI transform, DBSCAN / HDBSCAN.

Pulses come from a small generator written here, independent of deint_env.simulate."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.blind.pri_transform import pri_transform
from deint_env.oracle import genie_labels
from deint_env.cli import main
from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.labels import correct_link
from deint_env.modulation import PRIModel, modulation_scores
from deint_env.policies import make_policy
from deint_env.runner import play


def pulses(pris: list[list[float]], phases: list[float], duration: float, jitter: float, seed: int = 0,
           amplitudes: list[float] | None = None):
    """Trains of cyclic PRI sequences (one level: constant; several: stagger) with white TOA jitter,
    merged and sorted: (toa, source, amplitude or None)."""
    rng = np.random.default_rng(seed)
    toa, src, amp = [], [], []
    global SCHEDULE
    SCHEDULE = []
    for i, (levels, phase) in enumerate(zip(pris, phases)):
        n = int(duration / np.mean(levels)) + 1
        gaps = np.resize(np.asarray(levels, dtype=float), n - 1)
        t = phase + np.concatenate([[0.0], np.cumsum(gaps)])
        t = t[t < duration]
        SCHEDULE.append(t.copy())
        t = t + rng.normal(0, jitter, t.size)
        toa.append(t), src.append(np.full(t.size, i))
        if amplitudes is not None:
            amp.append(amplitudes[i] + rng.normal(0, 0.01, t.size))
    order = np.argsort(np.concatenate(toa), kind="stable")
    a = np.concatenate(amp)[order] if amplitudes is not None else None
    return np.concatenate(toa)[order], np.concatenate(src)[order].astype(np.int32), a


def episode(toa, source, amp=None, n_labels=8, jitter=0.0) -> Episode:
    mask = np.left_shift(np.uint64(1), source.astype(np.uint64))
    return Episode(scenario="test", seed=0, toa=toa, amplitude=amp, source=source, mask=mask, truth=None,
                   priors=Priors(n_labels=n_labels, blind=True, jitter_std=jitter))


def link_accuracy(labels, ep) -> float:
    return float(np.mean(correct_link(labels, ep.source, ep.mask, ep.n_labels)))


SCHEDULE: list[np.ndarray] = []  # the noise-free emissions of the last `pulses` call


def genie_accuracy(ep, jitter: float) -> float:
    """Link accuracy of the known-parameter MAP labelling (baselines.genie) of the last trains made."""
    src = np.concatenate([np.full(s.size, i) for i, s in enumerate(SCHEDULE)])
    labels = genie_labels(ep.toa, np.concatenate(SCHEDULE), src, jitter, 0.0, 0.0, 0.0)
    return link_accuracy(np.where(labels < 0, ep.n_labels, labels), ep)


THREE = ([[13.0], [29.0], [47.0]], [1.0, 5.0, 11.0])


@pytest.mark.parametrize("name", ["cdif", "sdif", "pri-transform"])
def test_three_constant_trains_found_and_labelled(name):
    toa, src, _ = pulses(*THREE, duration=3000, jitter=0.1, seed=1)
    ep = episode(toa, src, jitter=0.1)
    policy = make_policy(name)
    res = play(policy, ep, clustering=False)
    assert policy.trains_found == 3
    assert link_accuracy(res.labels, ep) >= 0.95 * genie_accuracy(ep, 0.1)
    period = np.sort(policy.estimates()["period"][np.isfinite(policy.estimates()["period"])])
    np.testing.assert_allclose(period, [13.0, 29.0, 47.0], rtol=2e-4)
    assert [m.kind for m in policy.modulations() if m is not None] == ["constant"] * 3


@pytest.mark.parametrize("name", ["cdif", "pri-transform"])
def test_stagger_is_one_train_with_its_levels(name):
    # a 2-level stagger (sub-PRIs 12 and 18: frame 30) beside a constant train of PRI 23
    toa, src, _ = pulses([[12.0, 18.0], [23.0]], [2.0, 7.0], duration=3000, jitter=0.1, seed=2)
    ep = episode(toa, src, jitter=0.1)
    policy = make_policy(name)
    res = play(policy, ep, clustering=False)
    assert policy.trains_found == 2
    assert link_accuracy(res.labels, ep) >= 0.95 * genie_accuracy(ep, 0.1)
    models = sorted((m for m in policy.modulations() if m is not None), key=lambda m: m.kind)
    assert [m.kind for m in models] == ["constant", "stagger"]
    assert models[0].period == pytest.approx(23.0, rel=1e-3)
    assert sorted(models[1].levels) == pytest.approx([12.0, 18.0], abs=0.05)


def test_unknown_jitter_is_measured():
    # no jitter in the priors (as `deint label` without priors): sigma is measured from the trains
    toa, src, _ = pulses(*THREE, duration=1500, jitter=0.3, seed=3)
    ep = episode(toa, src, jitter=0.0)
    policy = make_policy("cdif")
    res = play(policy, ep, clustering=False)
    assert policy.trains_found == 3
    assert link_accuracy(res.labels, ep) >= 0.9 * genie_accuracy(ep, 0.3)


def test_windows_carry_labels_across():
    toa, src, _ = pulses(*THREE, duration=3000, jitter=0.1, seed=4)
    ep = episode(toa, src, jitter=0.1)
    policy = make_policy("pri-transform:window=120")
    res = play(policy, ep, clustering=False)
    assert policy.lag == 119 and len(policy.trains_per_window) == -(-len(toa) // 120)
    # labels carried across the 4 window changes (a lost label costs one link per train per change)
    assert link_accuracy(res.labels, ep) >= 0.95 * genie_accuracy(ep, 0.1)


def test_pri_transform_suppresses_subharmonics():
    # Nishiguchi & Kobayashi's point (their 3-train example, our parameters): the difference histogram
    # has peaks at multiples of every PRI, the transform only at the PRIs themselves
    toa, _, _ = pulses([[13.3], [29.7], [47.1]], [1.0, 5.0, 11.0], duration=3000, jitter=0.05, seed=5)
    centres, mag, count, _ = pri_transform(toa, 5.0, 100.0, 0.005, 0.01, 0.05)
    peak = lambda x, arr: arr[np.abs(centres - x) <= 0.5].max() / (3000 / x)  # noqa: E731
    for t in (13.3, 29.7, 47.1):
        assert peak(t, mag) > 0.8  # coherent at the PRI: |D| ~ the train's number of intervals
    for t in (26.6, 39.9, 59.4, 94.2):  # 2x13.3, 3x13.3, 2x29.7, 2x47.1
        assert peak(t, count) > 0.8  # the histogram has the multiple
        assert peak(t, mag) < 0.3  # the transform suppresses it


def test_improved_pri_transform_survives_jitter():
    # Nishiguchi & Kobayashi's other point: with jitter the original transform (disjoint bins, phases
    # from t = 0) loses its peaks, the improved one (overlapping bins, shifted origins) keeps them
    toa, _, _ = pulses([[13.3], [29.7], [47.1]], [1.0, 5.0, 11.0], duration=3000, jitter=0.3, seed=10)
    for improved, lo, hi in ((True, 0.8, None), (False, None, 0.3)):
        centres, mag, _, _ = pri_transform(toa, 5.0, 100.0, 0.005 if improved else 0.2, 0.01, 0.3, improved=improved)
        for t in (13.3, 29.7, 47.1):
            near = np.abs(centres - t) <= 1.0
            peak = mag[near].max() / (3000 / t)  # against the train's number of intervals
            assert (peak > lo) if improved else (peak < hi)


def test_hdbscan_uses_amplitude_and_dbscan_runs():
    toa, src, amp = pulses(*THREE, duration=3000, jitter=0.1, seed=6, amplitudes=[1.0, 2.0, 3.0])
    ep = episode(toa, src, amp, jitter=0.1)
    policy = make_policy("hdbscan")
    res = play(policy, ep, clustering=False)
    assert policy.trains_found >= 3
    from sklearn.metrics import v_measure_score

    assert v_measure_score(src, res.labels) > 0.8
    d = make_policy("dbscan:eps=0.2")
    play(d, ep, clustering=False)
    assert d.trains_found >= 1


def test_anchored_scenarios_and_bad_parameters_are_refused():
    toa, src, _ = pulses(*THREE, duration=500, jitter=0.1)
    anchored = Episode(scenario="t", seed=0, toa=toa, amplitude=None, source=src,
                       mask=np.left_shift(np.uint64(1), src.astype(np.uint64)), truth=None,
                       priors=Priors(n_labels=3, period=np.array([13.0, 29.0, 47.0])))
    with pytest.raises(NotApplicable):
        play(make_policy("cdif"), anchored)
    for bad in ("cdif:window=1", "sdif:min_fill=2", "pri-transform:pri_min=-1", "hdbscan:min_cluster_size=1"):
        with pytest.raises(DeintError):
            make_policy(bad)


def test_cli_labels_a_file_without_priors(tmp_path, capsys):
    toa, src, _ = pulses(*THREE, duration=2000, jitter=0.2, seed=7)
    f = tmp_path / "p.csv"
    f.write_text("toa\n" + "".join(f"{t!r}\n" for t in toa.tolist()))
    out = tmp_path / "l.csv"
    assert main(["label", str(f), "--policy", "cdif", "-o", str(out)]) == 0
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    labels = rows[:, 1].astype(int)
    labels = np.where(labels < 0, 32, labels)
    ep = episode(toa, src, n_labels=32)
    assert link_accuracy(labels, ep) >= 0.95 * genie_accuracy(ep, 0.2)


def test_modulation_scores():
    truth = [PRIModel("constant", 20.0), PRIModel("stagger", 15.0, (12.0, 18.0)),
             PRIModel("sinusoidal", 30.0, (), 0.1, 50.0)]
    found = [PRIModel("stagger", 15.1, (18.1, 12.0)), PRIModel("constant", 20.2), None,
             PRIModel("sliding", 30.0, (), 0.1, 50.0)]
    s = modulation_scores(found, truth, np.array([1, 0, 3]))
    assert s.n_scored == 3 and s.kind_accuracy == pytest.approx(2 / 3)
    assert s.period_rel_error == pytest.approx(np.mean([0.01, 0.1 / 15]))
    assert s.level_rel_error == pytest.approx(np.mean([0.0, 0.1 / 18]))  # the best rotation
    assert np.isnan(s.depth_rel_error)


def test_tdc_file_descriptors_presort_then_pri(tmp_path):
    # two emitters with one PRI (only their frequency tells them apart) and a third: a TDC file with
    # a frequency column, labelled through `deint label` with no priors
    from deint_env.formats import tdc
    from deint_env.tdc_scores import tdc_scores

    toa, src, _ = pulses([[20.0], [20.0], [31.0]], [3.0, 11.0, 7.0], duration=3000, jitter=0.1, seed=8)
    freq = np.array([9000.0, 9400.0, 9700.0])[src] + np.random.default_rng(0).normal(0, 2.0, toa.size)
    f = tmp_path / "p.h5"
    tdc.write_tdc(f, toa, labels=src, features={"frequency": freq}, dtype="float64")
    scores = {}
    for name in ("cdif", "hdbscan"):
        out = tmp_path / f"{name}.h5"
        assert main(["label", str(f), "--policy", name, "-o", str(out)]) == 0
        scores[name] = tdc_scores(src, tdc.read_tdc(out).labels)["v_measure"]
    assert scores["cdif"] > 0.95
    # without the frequency the two PRI-20 emitters are one train at PRI 20 / 2 ... or a stagger
    ep = episode(toa, src, jitter=0.1)
    policy = make_policy("cdif")
    labels = play(policy, ep, clustering=False).labels
    assert policy.trains_found == 2
    assert tdc_scores(src, labels)["v_measure"] < scores["cdif"]


def test_pri_model_fits():
    from baselines.blind.pri_models import single_train_model, stagger_model

    rng = np.random.default_rng(9)
    n = np.arange(400)
    # wobulated: PRI_n = 20 (1 + 0.1 sin(2 pi n / 50 + 0.3)); and a saw-tooth sweep of depth 0.3, cycle 32
    for kind, pri in (("sinusoidal", 20 * (1 + 0.1 * np.sin(2 * np.pi * n / 50 + 0.3))),
                      ("sliding", 20 * (1 + 0.3 * ((n % 32) / 31 - 0.5)))):
        t = np.concatenate([[0.0], np.cumsum(pri)]) + rng.normal(0, 0.05, n.size + 1)
        m = single_train_model(t, np.arange(n.size + 1), 0.05)
        assert m.kind == kind and m.period == pytest.approx(20.0, rel=0.01)
        assert m.depth == pytest.approx(0.1 if kind == "sinusoidal" else 0.3, rel=0.1)
        assert m.cycle == pytest.approx(50 if kind == "sinusoidal" else 32, rel=0.05)
    t = np.arange(300) * 20.0 + rng.normal(0, 0.05, 300)
    assert single_train_model(t, np.arange(300), 0.05).kind == "constant"
    # pieces of a constant PRI-10 train at frame 40 (one piece missing, one found twice): constant 10
    model, phases = stagger_model(40.0, np.array([3.0, 13.02, 33.0, 3.01]), 0.05)
    assert model.kind == "constant" and model.period == pytest.approx(10.0) and phases.size == 1
    model, phases = stagger_model(30.0, np.array([2.0, 14.0]), 0.05)
    assert model.kind == "stagger" and model.levels == pytest.approx((12.0, 18.0))


def test_modulation_identified_on_a_simulated_stagger():
    # agile-v0's two-level stagger made blind: the stagger is one train, its model and levels right
    from deint_env.modulation import episode_modulation_scores
    from deint_env.scenario import ScenarioSpec
    from deint_env.simulate import simulate
    from deint_env.suites import find_entry

    d = find_entry("agile-v0/agile-stagger2").spec.to_dict()
    d.update(priors={"kind": "none"}, blind=True, label_budget=8)
    spec = ScenarioSpec.from_dict(d)
    ep = simulate(spec, 1000000)
    policy = make_policy("cdif")
    res = play(policy, ep, clustering=False)
    assert policy.trains_found == 3
    s = episode_modulation_scores(policy.modulations(), spec, ep.truth.period, res.labels, ep.source, ep.n_labels)
    assert s.n_scored == 3 and s.kind_accuracy == 1.0
    assert s.level_rel_error < 0.01 and s.period_rel_error < 1e-3
    only = episode_modulation_scores(policy.modulations(), spec, ep.truth.period, res.labels, ep.source,
                                     ep.n_labels, modulated_only=True)
    assert only.n_scored == 1 and only.kind_accuracy == 1.0


def _cycle(kind: str, rng) -> np.ndarray:
    """One frame's PRIs (mean 13) of a long periodic modulation, rotated, with level noise."""
    n = np.arange(60)
    pri = {"sliding": 13 * (1 + 0.3 * ((n[:32] % 32) / 31 - 0.5)),
           "sinusoidal": 13 * (1 + 0.3 * np.sin(2 * np.pi * n[:50] / 50 + 1)),
           "dwell_switch": 13 * np.repeat([1.0, 1.4, 0.8], 20) / np.mean([1.0, 1.4, 0.8])}[kind]
    return np.roll(pri, 5) + rng.normal(0, 0.04, pri.size)


@pytest.mark.parametrize("kind", ["sliding", "sinusoidal", "dwell_switch"])
def test_cycle_model_tells_long_frames_apart(kind):
    # a sweep, a wobulation and a dwell cycle found as sub-trains of their frame: each is told apart from
    # a many-level stagger, also with two sub-trains missing (their gaps hold two PRIs)
    from baselines.blind.pri_models import cycle_model

    levels = _cycle(kind, np.random.default_rng(1))
    holed = np.delete(levels, [3, 6])
    holed[2] += levels[3]
    holed[4] += levels[6]
    for lv in (levels, holed):
        m = cycle_model(lv, 0.5)
        assert m.kind == kind and m.period == pytest.approx(13.0, rel=0.01)
        if kind == "dwell_switch":
            assert m.cycle == 20 and sorted(m.levels) == pytest.approx(sorted(13 * np.array([1.0, 1.4, 0.8]) / 1.0667),
                                                                         rel=0.01)
        else:
            assert m.depth == pytest.approx(0.3, rel=0.03) and m.cycle == (32 if kind == "sliding" else 50)
    few = cycle_model(np.array([10.0, 13.0, 17.0]), 0.5)  # a 3-level stagger stays one
    assert few.kind == "stagger" and few.levels == (10.0, 13.0, 17.0)


def test_single_train_drifting_and_dwell():
    from baselines.blind.pri_models import single_train_model

    rng = np.random.default_rng(3)
    drift = 13 + np.cumsum(rng.normal(0, 0.02, 400))  # MK94's alpha = 1 source: a random-walk PRI
    t = np.concatenate([[0.0], np.cumsum(drift)]) + rng.normal(0, 0.1, 401)
    assert single_train_model(t, np.arange(401), 0.1).kind == "drifting"
    dwell = np.tile(np.repeat([12.0, 17.0, 10.0], 20), 7)
    t = np.concatenate([[0.0], np.cumsum(dwell)]) + rng.normal(0, 0.1, dwell.size + 1)
    m = single_train_model(t, np.arange(t.size), 0.1)
    assert m.kind == "dwell_switch" and m.cycle == 20
    assert sorted(m.levels) == pytest.approx([10.0, 12.0, 17.0], abs=0.05)
    t = np.arange(400) * 13.0 + rng.normal(0, 0.1, 400)
    assert single_train_model(t, np.arange(400), 0.1).kind == "constant"


def test_pieces_of_a_drifting_train_are_merged():
    # a drifting train walked at 3 times its PRI gives three off-lattice chains: they are one train
    from baselines.blind.pipeline import merge_interleaved
    from baselines.blind.search import Chain

    rng = np.random.default_rng(4)
    t = np.concatenate([[0.0], np.cumsum(13 + np.cumsum(rng.normal(0, 0.02, 299)))])
    chains = [Chain(np.arange(r, 300, 3), np.arange(len(range(r, 300, 3))), len(range(r, 300, 3))) for r in range(3)]
    merged = merge_interleaved(t, chains, 0.05)
    assert len(merged) == 1 and merged[0].index.tolist() == list(range(300))
    assert merged[0].k.tolist() == list(range(300))


def test_dwell_switch_scores():
    truth = [PRIModel("dwell_switch", 13.0, (12.0, 17.0, 10.0), 0.0, 20.0)]
    s = modulation_scores([PRIModel("dwell_switch", 13.1, (17.0, 10.0, 12.3), 0.0, 19.0)], truth, np.array([0]))
    assert s.kind_accuracy == 1.0 and s.level_rel_error == pytest.approx(0.3 / 12 / 3)  # the best rotation
    assert s.cycle_rel_error == pytest.approx(0.05) and np.isnan(s.depth_rel_error)


def test_sliding_identified_on_a_simulated_episode():
    # agile-v0's saw-tooth sweep (depth 0.3, 32 pulses) made blind: found as 32 sub-trains of its frame,
    # identified as sliding with its depth and cycle
    from deint_env.modulation import episode_modulation_scores
    from deint_env.scenario import ScenarioSpec
    from deint_env.simulate import simulate
    from deint_env.suites import find_entry

    d = find_entry("agile-v0/agile-sliding").spec.to_dict()
    d.update(priors={"kind": "none"}, blind=True, label_budget=8)
    spec = ScenarioSpec.from_dict(d)
    ep = simulate(spec, 1000000)
    policy = make_policy("cdif")
    res = play(policy, ep, clustering=False)
    s = episode_modulation_scores(policy.modulations(), spec, ep.truth.period, res.labels, ep.source, ep.n_labels,
                                  modulated_only=True)
    assert s.n_scored == 1 and s.kind_accuracy == 1.0
    assert s.depth_rel_error < 0.05 and s.cycle_rel_error == 0.0 and s.period_rel_error < 1e-3

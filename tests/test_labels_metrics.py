"""Labels and metrics on hand-made cases whose answers are worked out in the comments."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sklearn import metrics as skm

from deint_env.episode import Truth
from deint_env.labels import (NO_PRED, SPURIOUS_PRED, correct_anchored, correct_link, label_predecessors,
                              true_predecessors)
from deint_env.metrics import (clustering_metrics, clusterwise_mcc_f1, crlb_period_var, estimation_metrics, iqm,
                               label_metrics, matched_labels, mean, normalised_score, per_source_error,
                               stratified_bootstrap)

U = np.uint64

# A hand-made two-source episode (spurious label = 2):
#   pulse  0: source 0                 mask 0b01
#   pulse  1: source 1                 mask 0b10
#   pulse  2: spurious                 mask 0
#   pulse  3: sources 0 and 1 merged   mask 0b11 (primary 0)
#   pulse  4: source 1                 mask 0b10
#   pulse  5: source 0                 mask 0b01
SOURCE = np.array([0, 1, -1, 0, 1, 0], dtype=np.int32)
MASK = np.array([1, 2, 0, 3, 2, 1], dtype=U)
SPUR = 2


# ---- anchored correctness ----------------------------------------------------------------------------
def test_correct_anchored_merged_and_spurious():
    # the true labelling is right everywhere; the merged pulse is right under 0 and under 1
    assert correct_anchored(np.array([0, 1, 2, 0, 1, 0]), SOURCE, MASK, SPUR).all()
    assert correct_anchored(np.array([0, 1, 2, 1, 1, 0]), SOURCE, MASK, SPUR).all()
    # pulse 0 as 1 (wrong), 1 as 0 (wrong), spurious as 0 (wrong), merged as spurious (wrong),
    # pulse 4 as spurious (wrong), pulse 5 as 0 (right)
    got = correct_anchored(np.array([1, 0, 0, 2, 2, 0]), SOURCE, MASK, SPUR)
    assert got.tolist() == [False, False, False, False, False, True]


def test_correct_anchored_more_tracks_than_sources():
    # 4 prior tracks (spurious label 4) for 2 true sources: labels 2 and 3 are never right
    got = correct_anchored(np.array([2, 3, 4, 0, 3, 0]), SOURCE, MASK, 4)
    assert got.tolist() == [False, False, True, True, False, True]


# ---- link correctness ------------------------------------------------------------------------------
def test_true_predecessors_with_merged_and_spurious():
    tp = true_predecessors(SOURCE, MASK)
    # source 0 pulses: 0, 3, 5   -> pred(0) none, pred(3) = 0, pred(5) = 3
    # source 1 pulses: 1, 3, 4   -> pred(1) none, pred(3) = 1 (alternative, via source 1), pred(4) = 3
    # pulse 2 is spurious
    assert tp.pred.tolist() == [NO_PRED, NO_PRED, SPURIOUS_PRED, 0, 3, 3]
    assert tp.alternatives() == {3: {1}}
    assert tp.alt_pulse.tolist() == [3] and tp.alt_pred.tolist() == [1]


def test_true_predecessors_merged_with_secondary_first_pulse():
    # pulse 0 merges sources 0 and 1 (primary 1): it is source 0's first pulse too
    source = np.array([1, 0, 1], dtype=np.int32)
    mask = np.array([3, 1, 2], dtype=U)
    tp = true_predecessors(source, mask)
    assert tp.pred.tolist() == [NO_PRED, 0, 0]
    assert tp.alternatives() == {0: {NO_PRED}}


def test_correct_link_three_source_merge():
    # pulses 0, 1, 2 are sources 0, 1, 2; pulse 3 merges all three (primary 0), spurious label 3.
    # pulse 3's valid predecessors: 0 (via source 0) and the alternatives 1 and 2.
    source = np.array([0, 1, 2, 0], dtype=np.int32)
    mask = np.array([1, 2, 4, 7], dtype=U)
    tp = true_predecessors(source, mask)
    assert tp.pred.tolist() == [NO_PRED, NO_PRED, NO_PRED, 0]
    assert tp.alternatives() == {3: {1, 2}}
    for label_of_merged in (0, 1, 2):  # each names one of the three valid predecessors
        labels = np.array([0, 1, 2, label_of_merged])
        assert correct_link(labels, source, mask, 3).tolist() == [True] * 4, label_of_merged
    assert correct_link(np.array([0, 1, 2, 3]), source, mask, 3).tolist() == [True, True, True, False]


def test_label_predecessors():
    # label 0 at pulses 0, 3, 5; label 1 at 1, 4; spurious at 2
    got = label_predecessors(np.array([0, 1, 2, 0, 1, 0]), SPUR)
    assert got.tolist() == [NO_PRED, NO_PRED, SPURIOUS_PRED, 0, 1, 3]


def test_correct_link_hand_cases():
    # labels 0,1,2,0,1,0: named preds -1,-1,-2,0,1,3; true -1,-1,-2,0,3,3 (+ alt 3:1)
    # pulse 4 names 1 but its true predecessor in source 1 is the merged pulse 3 -> wrong
    got = correct_link(np.array([0, 1, 2, 0, 1, 0]), SOURCE, MASK, SPUR)
    assert got.tolist() == [True, True, True, True, False, True]
    # labels 0,1,2,1,1,0: named -1,-1,-2,1,3,0.  pulse 3 names 1, an alternative -> right;
    # pulse 4 names 3 -> right; pulse 5 names 0, true 3 -> wrong
    got = correct_link(np.array([0, 1, 2, 1, 1, 0]), SOURCE, MASK, SPUR)
    assert got.tolist() == [True, True, True, True, True, False]
    # Link labels are permutation-free: swapping the two labels changes nothing
    got_swapped = correct_link(np.array([1, 0, 2, 0, 0, 1]), SOURCE, MASK, SPUR)
    assert got_swapped.tolist() == [True, True, True, True, True, False]
    # the spurious pulse labelled 1: named pred 1 (wrong, it links to nothing) and it becomes label
    # 1's last pulse, so pulse 3 (label 1) names 2 (wrong: neither 0 nor 1) and pulse 4 names 3 (right)
    got = correct_link(np.array([0, 1, 1, 1, 1, 0]), SOURCE, MASK, SPUR)
    assert got.tolist() == [True, True, False, False, True, False]
    # a real pulse labelled spurious is always wrong
    got = correct_link(np.array([2, 1, 2, 0, 1, 0]), SOURCE, MASK, SPUR)
    # pulse 0 spurious: wrong; pulse 3 names none (label 0's first use) but true 0 / alt 1 -> wrong
    assert got.tolist() == [False, True, True, False, False, True]


def test_correct_link_accepts_precomputed_truth():
    lab = np.array([0, 1, 2, 1, 1, 0])
    assert np.array_equal(correct_link(lab, SOURCE, MASK, SPUR, true_predecessors(SOURCE, MASK)),
                          correct_link(lab, SOURCE, MASK, SPUR))


# ---- label_metrics ------------------------------------------------------------------------------------
def test_label_metrics_perfect():
    m = label_metrics(np.array([0, 1, 2, 0, 1, 0]), SOURCE, MASK, 2, blind=False)
    assert m["n_pulses"] == 6
    assert m["accuracy"] == 1.0 and m["matched_accuracy"] == 1.0 and m["mean_pe"] == 0.0
    assert m["pe"] == [0.0, 0.0]
    assert m["spurious_precision"] == 1.0 and m["spurious_recall"] == 1.0
    assert m["link_accuracy"] == pytest.approx(5 / 6)  # pulse 4's link is broken by the merge


def test_label_metrics_hand_case():
    labels = np.array([0, 0, 2, 0, 1, 2])
    m = label_metrics(labels, SOURCE, MASK, 2, blind=False)
    # correct: T F T T T F -> 4/6
    assert m["accuracy"] == pytest.approx(4 / 6)
    # P_e (MK94 5.1): source 0's pulses 0, 3, 5 -> wrong only 5 -> 1/3; source 1's 1, 3, 4 -> wrong 1 -> 1/3
    assert m["pe"] == pytest.approx([1 / 3, 1 / 3])
    assert m["mean_pe"] == pytest.approx(1 / 3)
    # said spurious: pulses 2, 5; truly spurious: 2 -> precision 1/2, recall 1
    assert m["spurious_precision"] == pytest.approx(0.5) and m["spurious_recall"] == 1.0
    # links: named -1,0,-2,1,-1,-2; true -1,-1,-2,0(alt 1),3,3 -> T F T T F F
    assert m["link_accuracy"] == pytest.approx(0.5)
    # Hungarian on (label, primary source) counts: l0: s0 x2, s1 x1; l1: s1 x1 -> identity
    assert m["matched_accuracy"] == pytest.approx(4 / 6)


def test_matched_accuracy_permutation():
    # the perfect labelling with labels 0 and 1 swapped
    labels = np.array([1, 0, 2, 1, 0, 1])
    m = label_metrics(labels, SOURCE, MASK, 2, blind=False)
    # unmatched: only the spurious pulse 2 and the merged pulse 3 (label 1 is one of its sources)
    assert m["accuracy"] == pytest.approx(2 / 6)
    assert m["matched_accuracy"] == 1.0
    assert matched_labels(labels, SOURCE, 2).tolist() == [0, 1, 2, 0, 1, 0]
    # P_e uses the unmatched labels in anchored mode: source 0 (0, 3, 5): 3 right -> 2/3; source 1 (1, 3, 4) -> 2/3
    assert m["pe"] == pytest.approx([2 / 3, 2 / 3])
    # blind mode: accuracy is link accuracy, P_e and matched accuracy after matching
    b = label_metrics(labels, SOURCE, MASK, 2, blind=True)
    assert b["accuracy"] == b["link_accuracy"] == pytest.approx(5 / 6)
    assert b["matched_accuracy"] == 1.0 and b["mean_pe"] == 0.0


def test_matched_labels_unmatched_label_becomes_spurious():
    # three labels for two sources: label 2 gets no source and maps to spurious (3)
    source = np.array([0, 0, 1, 1, 1], dtype=np.int32)
    labels = np.array([2, 2, 0, 0, 1])
    # counts: l2->s0: 2, l0->s1: 2, l1->s1: 1 -> match l2->0, l0->1; l1 unmatched
    assert matched_labels(labels, source, 3).tolist() == [0, 0, 1, 1, 3]


def test_per_source_error_nan_for_absent_source():
    mask = np.array([1, 4, 4], dtype=U)  # source 1 never appears
    pe = per_source_error(np.array([True, False, True]), mask)
    assert pe[0] == 0.0 and math.isnan(pe[1]) and pe[2] == 0.5


def test_spurious_precision_recall_edge_cases():
    source = np.array([0, 1], dtype=np.int32)
    mask = np.array([1, 2], dtype=U)
    m = label_metrics(np.array([0, 1]), source, mask, 2, blind=False)  # nothing spurious, nothing said
    assert m["spurious_precision"] == 1.0 and m["spurious_recall"] == 1.0
    m = label_metrics(np.array([2, 1]), source, mask, 2, blind=False)  # a false alarm
    assert m["spurious_precision"] == 0.0
    s2, m2 = np.array([0, -1], dtype=np.int32), np.array([1, 0], dtype=U)
    m = label_metrics(np.array([0, 0]), s2, m2, 2, blind=False)  # a missed spurious pulse
    assert m["spurious_recall"] == 0.0 and m["spurious_precision"] == 0.0


def test_label_metrics_rejects_bad_labels():
    with pytest.raises(ValueError):
        label_metrics(np.array([0, 1, 3, 0, 1, 0]), SOURCE, MASK, 2, blind=False)
    with pytest.raises(ValueError):
        label_metrics(np.array([0, 1]), SOURCE, MASK, 2, blind=False)


# ---- clustering metrics ---------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(5))
def test_clustering_metrics_equal_sklearn(seed):
    rng = np.random.default_rng(seed)
    source = rng.integers(-1, 4, 300)
    labels = np.where(rng.random(300) < 0.6, source + 1, rng.integers(0, 6, 300))
    m = clustering_metrics(source, labels)
    assert m["v_measure"] == pytest.approx(skm.v_measure_score(source, labels))
    assert m["ari"] == pytest.approx(skm.adjusted_rand_score(source, labels))
    assert m["ami"] == pytest.approx(skm.adjusted_mutual_info_score(source, labels))
    # homogeneity / completeness are asymmetric: the truth comes first
    assert m["homogeneity"] == pytest.approx(skm.homogeneity_score(source, labels))
    assert m["completeness"] == pytest.approx(skm.completeness_score(source, labels))
    assert m["homogeneity"] != pytest.approx(m["completeness"])


def test_label_metrics_include_clustering_on_request():
    m = label_metrics(np.array([0, 1, 2, 0, 1, 0]), SOURCE, MASK, 2, blind=False)
    assert m["v_measure"] == 1.0 and m["ari"] == 1.0 and m["cluster_f1"] == 1.0 and m["cluster_mcc"] == 1.0
    m = label_metrics(np.array([0, 1, 2, 0, 1, 0]), SOURCE, MASK, 2, blind=False, clustering=False)
    assert "v_measure" not in m


def test_clusterwise_mcc_f1_hand_case():
    source = np.array([0, 0, 0, 1, 1, 1])
    labels = np.array([5, 5, 7, 7, 7, 7])
    # contingency [[2, 1], [0, 3]]
    # class 0 vs cluster 5: tp 2, fp 0, fn 1, tn 3 -> F1 4/5, MCC (2*3 - 0)/sqrt(2*3*3*4) = 6/sqrt(72)
    # class 0 vs cluster 7: tp 1, fp 3, fn 2, tn 0 -> F1 2/7, MCC (0 - 6)/sqrt(4*3*3*2) < 0: best is cluster 5
    # class 1 vs cluster 7: tp 3, fp 1, fn 0, tn 2 -> F1 6/7, MCC (3*2 - 0)/sqrt(4*3*3*2) = 6/sqrt(72)
    # the worst class: F1 min(4/5, 6/7) = 4/5, MCC 6/sqrt(72)
    m = clusterwise_mcc_f1(source, labels)
    assert m["cluster_f1"] == pytest.approx(4 / 5)
    assert m["cluster_mcc"] == pytest.approx(6 / math.sqrt(72))
    assert 6 / math.sqrt(72) == pytest.approx(skm.matthews_corrcoef(source == 0, labels == 5))
    assert 6 / math.sqrt(72) == pytest.approx(skm.matthews_corrcoef(source == 1, labels == 7))


@pytest.mark.parametrize("seed", range(3))
def test_clusterwise_mcc_matches_sklearn_one_vs_rest(seed):
    # with as many clusters as classes and a dominant diagonal, each class's best cluster is its own
    rng = np.random.default_rng(seed)
    source = rng.integers(0, 3, 200)
    labels = np.where(rng.random(200) < 0.8, source, rng.integers(0, 3, 200))
    m = clusterwise_mcc_f1(source, labels)
    mcc = [skm.matthews_corrcoef(source == i, labels == i) for i in range(3)]
    f1 = [skm.f1_score(source == i, labels == i) for i in range(3)]
    assert m["cluster_mcc"] == pytest.approx(np.min(mcc))
    assert m["cluster_f1"] == pytest.approx(np.min(f1))


def test_clusterwise_one_cluster_for_three_classes():
    # each class against the one cluster: tp 1, fp 2, fn 0, tn 0 -> F1 1/2, MCC 0 (tn + fn = 0); worst: 1/2, 0
    m = clusterwise_mcc_f1(np.array([0, 1, 2]), np.array([9, 9, 9]))
    assert m["cluster_f1"] == pytest.approx(0.5)
    assert m["cluster_mcc"] == 0.0


def test_clusterwise_worst_class_decides():
    # class 2 is split evenly over two clusters that also hold the other classes: it is the worst
    source = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2])
    labels = np.array([0, 0, 0, 0, 1, 1, 1, 1, 0, 1])
    # class 2 vs cluster 0: tp 1, fp 4, fn 1 -> F1 2/7; the same against cluster 1
    assert clusterwise_mcc_f1(source, labels)["cluster_f1"] == pytest.approx(2 / 7)


# ---- estimation --------------------------------------------------------------------------------------
def test_crlb_formula():
    # var T >= 12 sigma^2 / (n (n^2 - 1)); for n = 10, sigma = 2: 48 / 990
    assert crlb_period_var(2.0, np.array([10]))[0] == pytest.approx(48 / 990)
    # it is sigma^2 / sum (k - mean k)^2, the variance of the least-squares slope
    for n in (2, 5, 37):
        k = np.arange(n)
        assert crlb_period_var(0.7, np.array([n]))[0] == pytest.approx(0.49 / np.sum((k - k.mean()) ** 2))
    assert np.isinf(crlb_period_var(1.0, np.array([0, 1]))).all()


def hand_truth() -> Truth:
    return Truth(period=np.array([10.0, 20.0]), phase=np.array([1.0, 5.0]), final_period=np.array([10.0, 20.0]),
                 n_received=np.array([11, 5]), schedule_toa=np.zeros(0), schedule_pri=np.zeros(0),
                 schedule_offsets=np.array([0, 0, 0]))


def test_estimation_metrics_hand_case():
    est = {"period": [10.5, 19.0], "phase": [1.5, 27.0]}
    m = estimation_metrics(est, hand_truth(), jitter_std=1.0)
    # relative period errors 0.5/10 and 1/20 -> 0.05
    assert m["period_rel_error"] == pytest.approx(0.05)
    # phase errors as fractions of the period, circular: 0.5/10 = 0.05 and (22/20 = 1.1) -> 0.1
    assert m["phase_error"] == pytest.approx(0.075)
    # CRLB: n=11 -> 12/(11*120) = 1/110; n=5 -> 12/(5*24) = 0.1; ratios 0.25*110 = 27.5 and 1/0.1 = 10
    assert m["period_crlb_ratio"] == pytest.approx(math.sqrt((27.5 + 10) / 2))


def test_estimation_metrics_without_jitter_and_with_mapping():
    est = {"period": [19.0, 10.5]}
    m = estimation_metrics(est, hand_truth(), jitter_std=0.0, label_of_source=np.array([1, 0]))
    assert m["period_rel_error"] == pytest.approx(0.05)
    assert math.isnan(m["phase_error"])  # no phase estimates
    assert math.isnan(m["period_crlb_ratio"])  # no jitter: the bound is 0
    # an unmatched source is left out
    m = estimation_metrics({"period": [10.0, 30.0]}, hand_truth(), 1.0, label_of_source=np.array([0, -1]))
    assert m["period_rel_error"] == 0.0
    m = estimation_metrics({"period": []}, hand_truth(), 1.0)
    assert math.isnan(m["period_rel_error"])


def test_normalised_score():
    assert normalised_score(0.7, 0.5, 0.9) == pytest.approx(0.5)
    assert normalised_score(0.9, 0.5, 0.9) == pytest.approx(1.0)
    assert normalised_score(0.5, 0.5, 0.9) == 0.0
    assert normalised_score(0.3, 0.5, 0.9) == pytest.approx(-0.5)
    assert math.isnan(normalised_score(0.7, 0.6, 0.6))


# ---- aggregates ---------------------------------------------------------------------------------------
def test_iqm_by_hand():
    x = np.array([100.0, 1, 2, 3, 4, 5, 6, 7])
    # sorted 1..7, 100: drop 2 at each end -> mean(3, 4, 5, 6) = 4.5
    assert iqm(x) == pytest.approx(4.5)
    assert iqm(np.arange(12.0)) == pytest.approx(np.mean(np.arange(3.0, 9.0)))
    assert math.isnan(iqm(np.array([])))
    assert mean(np.array([1.0, 2.0, 6.0])) == pytest.approx(3.0)


@pytest.mark.parametrize("stat", [mean, iqm])
def test_stratified_bootstrap(stat):
    rng = np.random.default_rng(0)
    small = [rng.normal(0.5, 0.2, 10), rng.normal(0.8, 0.1, 10)]
    a = stratified_bootstrap(small, stat, reps=500, seed=3)
    assert a == stratified_bootstrap(small, stat, reps=500, seed=3)
    assert a != stratified_bootstrap(small, stat, reps=500, seed=4)
    point, lo, hi = a
    assert point == pytest.approx(float(stat(np.concatenate(small))))
    assert lo <= point <= hi and lo < hi
    big = [rng.normal(0.5, 0.2, 1000), rng.normal(0.8, 0.1, 1000)]
    p2, lo2, hi2 = stratified_bootstrap(big, stat, reps=500, seed=3)
    assert lo2 <= p2 <= hi2
    assert (hi2 - lo2) < 0.5 * (hi - lo)  # width ~ 1/sqrt(n): 10x the samples, ~1/3 the width


def test_stratified_bootstrap_keeps_strata():
    # two strata of constants: every replicate keeps 5 zeros and 5 ones, so the mean never moves
    p, lo, hi = stratified_bootstrap([np.zeros(5), np.ones(5)], mean, reps=200, seed=0)
    assert p == lo == hi == 0.5
    assert all(math.isnan(v) for v in stratified_bootstrap([], mean))


# ---- against a plain-loop reference on simulated episodes -----------------------------------------------
def reference_link(labels, mask, spur):
    """One pulse at a time: the true predecessors are the last pulse of each member source."""
    last_src: dict[int, int] = {}
    last_lab: dict[int, int] = {}
    out = []
    for j, (lab, m) in enumerate(zip(labels.tolist(), mask.tolist())):
        members = [i for i in range(64) if (m >> i) & 1]
        truth = {last_src.get(i, NO_PRED) for i in members} or {SPURIOUS_PRED}
        if lab == spur:
            named = SPURIOUS_PRED
        else:
            named = last_lab.get(lab, NO_PRED)
            last_lab[lab] = j
        for i in members:
            last_src[i] = j
        out.append(named in truth)
    return np.array(out)


def reference_anchored(labels, source, mask, spur):
    return np.array([(s < 0) if lab == spur else bool((int(m) >> int(lab)) & 1)
                     for lab, s, m in zip(labels, source, mask)])


@pytest.mark.parametrize("seed", range(3))
def test_labels_match_reference_on_simulated_episodes(seed):
    from deint_env import simulate
    from deint_env.scenario import ScenarioSpec, SourceSpec

    s = ScenarioSpec(name="ref", sources=tuple(SourceSpec(period=5.0 + 2.5 * i) for i in range(5)), n_pulses=1500,
                     toa_jitter_std=0.1, coincidence_resolution=0.4, spurious_rate=0.2)
    ep = simulate(s, seed)
    assert np.any(np.bitwise_and(ep.mask, ep.mask - U(1)) != 0) and np.any(ep.source < 0)
    rng = np.random.default_rng(seed)
    perfect = np.where(ep.source >= 0, ep.source, 5)
    for labels in (perfect, np.where(rng.random(len(ep)) < 0.7, perfect, rng.integers(0, 6, len(ep)))):
        assert np.array_equal(correct_link(labels, ep.source, ep.mask, 5), reference_link(labels, ep.mask, 5))
        assert np.array_equal(correct_anchored(labels, ep.source, ep.mask, 5),
                              reference_anchored(labels, ep.source, ep.mask, 5))
    assert correct_anchored(perfect, ep.source, ep.mask, 5).all()


@pytest.mark.parametrize("blind", [False, True])
@pytest.mark.parametrize("clustering", [False, True])
def test_metric_keys_are_what_label_metrics_returns(blind, clustering):
    """The stated keys (an env's info layout before any labelling) are label_metrics' own, in order."""
    from deint_env.metrics import label_metrics, metric_keys

    source = np.array([0, 1, -1, 0, 1], np.int32)
    labels = np.array([0, 1, 2, 1, 1])
    mask = np.where(source >= 0, np.left_shift(1, np.maximum(source, 0)), 0).astype(np.uint64)
    assert tuple(label_metrics(labels, source, mask, 2, blind, clustering=clustering)) == metric_keys(clustering)

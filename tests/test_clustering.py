"""deint_env.clustering against scikit-learn: random labellings (hypothesis) and the edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn import metrics as skm

from deint_env import clustering
from deint_env.metrics import clustering_metrics

TOL = 1e-10


def sklearn_scores(true, pred) -> clustering.ClusteringScores:
    return clustering.ClusteringScores(
        skm.homogeneity_score(true, pred), skm.completeness_score(true, pred), skm.v_measure_score(true, pred),
        skm.adjusted_rand_score(true, pred), skm.adjusted_mutual_info_score(true, pred))


def assert_same(true, pred) -> None:
    got = clustering.scores(np.asarray(true), np.asarray(pred))
    want = sklearn_scores(np.asarray(true), np.asarray(pred))
    for name, g, w in zip(got._fields, got, want):
        assert abs(g - w) <= TOL, (name, g, w)


labellings = st.integers(0, 120).flatmap(lambda n: st.tuples(
    st.lists(st.integers(-1, 6), min_size=n, max_size=n), st.lists(st.integers(-1, 9), min_size=n, max_size=n)))


@settings(max_examples=120, deadline=None)
@given(labellings)
def test_random_labellings_equal_sklearn(pair):
    true, pred = pair
    assert_same(true, pred)


@settings(max_examples=40, deadline=None)
@given(labellings, st.integers(0, 2**32 - 1))
def test_noisy_copies_and_relabellings_equal_sklearn(pair, seed):
    true, _ = pair
    true = np.asarray(true, dtype=np.int64)
    rng = np.random.default_rng(seed)
    assert_same(true, true)  # identical
    assert_same(true, 40 - 3 * true)  # a renaming of the same partition
    noisy = np.where(rng.random(true.size) < 0.8, true, rng.integers(-1, 7, true.size))
    assert_same(true, noisy)
    assert_same(noisy, true)


@pytest.mark.parametrize("n", [1, 2, 3, 7, 50, 400])
def test_edge_cases_equal_sklearn(n):
    one, singles = np.zeros(n, np.int64), np.arange(n)
    rng = np.random.default_rng(n)
    some = rng.integers(0, 4, n)
    for true, pred in [(one, one), (one, singles), (singles, one), (singles, singles), (singles, singles[::-1]),
                       (some, one), (one, some), (some, singles), (singles, some)]:
        assert_same(true, pred)


def test_empty_labellings_score_one_as_sklearn():
    empty = np.zeros(0, np.int64)
    assert clustering.scores(empty, empty) == (1.0, 1.0, 1.0, 1.0, 1.0) == sklearn_scores(empty, empty)


def test_large_labellings_equal_sklearn():
    """Big classes (the expected-MI sum runs over many counts, in chunks) and many singletons."""
    rng = np.random.default_rng(3)
    true = rng.integers(0, 5, 30_000)
    pred = np.where(rng.random(true.size) < 0.7, true, rng.integers(0, 7, true.size))
    assert_same(true, pred)
    singles = np.arange(600)
    assert_same(singles, rng.permutation(singles) // 2)


def test_expected_mutual_info_closed_form():
    """n singletons against n/2 pairs: a singleton falls in a given pair with probability 2/n, so
    E[MI] = (n * n/2 cells) * (1/n) log(n/2) * (2/n) = log(n/2).  scikit-learn adds the 4.5e6 terms
    one by one and is 1e-10 off at n = 3000; grouped by cluster sizes ours is one term."""
    n = 3000
    a, b = np.ones(n, np.int64), np.full(n // 2, 2, np.int64)
    assert clustering.expected_mutual_info(a, b, n) == pytest.approx(math.log(n / 2), rel=1e-11)


def test_expected_mutual_info_chunks_agree(monkeypatch):
    a, b, n = np.array([300, 500, 200]), np.array([100, 400, 450, 50]), 1000
    whole = clustering.expected_mutual_info(a, b, n)
    monkeypatch.setattr(clustering, "_EMI_CHUNK", 37)
    assert clustering.expected_mutual_info(a, b, n) == pytest.approx(whole, rel=1e-13)


def test_label_metrics_use_them():
    rng = np.random.default_rng(0)
    source = rng.integers(-1, 3, 200)
    labels = np.where(rng.random(200) < 0.7, source, rng.integers(-1, 4, 200))
    m = clustering_metrics(source, labels)
    want = sklearn_scores(source, labels)
    for key in ("homogeneity", "completeness", "v_measure", "ari", "ami"):
        assert m[key] == pytest.approx(getattr(want, key), abs=TOL)

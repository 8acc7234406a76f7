"""baselines/blind/density.py's DBSCAN and HDBSCAN against scikit-learn's, label for label (numbering
included): random mixtures of Gaussian blobs and uniform noise, data sets with exact duplicate rows and
with coarse (tied) values, and the `dbscan`, `hdbscan` and `pdw-hdbscan` policies on episodes of their
suites run once with density.py and once with scikit-learn in its place."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN, HDBSCAN

from baselines.blind import clustering, density
from baselines.pdw import hdbscan as pdw_hdbscan
from deint_env.policies import make_policy
from deint_env.runner import play
from deint_env.simulate import simulate
from deint_env.suites import load_suite


def blobs(rng: np.random.Generator, n: int, d: int, kind: str) -> np.ndarray:
    """n rows in d columns: 1-5 Gaussian blobs of random widths and a uniform share of noise, in random
    order; `dups`: a third of the rows copies of others; `coarse`: values rounded to 0.1 (many ties)."""
    k = int(rng.integers(1, 6))
    centres = rng.uniform(-3, 3, (k, d))
    m = int(n * rng.uniform(0.5, 1.0))
    x = np.vstack([centres[rng.integers(0, k, m)] + rng.normal(0, rng.uniform(0.05, 0.5), (m, d)),
                   rng.uniform(-4, 4, (n - m, d))])[rng.permutation(n)]
    if kind == "dups" and n > 1:
        x[rng.integers(0, n, n // 3)] = x[rng.integers(0, n, n // 3)]
    elif kind == "coarse":
        x = np.round(x, 1)
    return x


def cases(seeds: range):
    for seed in seeds:
        rng = np.random.default_rng(seed)
        n = int(rng.choice([1, 2, 3, 7, 12, 40, 150, 400, 900, 2000], p=[.04, .04, .04, .08, .1, .2, .2, .15, .1, .05]))
        yield rng, n, blobs(rng, n, int(rng.integers(1, 7)), ("plain", "dups", "coarse")[seed % 3])


@pytest.mark.parametrize("chunk", range(4))
def test_dbscan_equals_sklearn(chunk):
    for rng, n, x in cases(range(60 * chunk, 60 * chunk + 60)):
        eps, least = float(rng.choice([0.05, 0.1, 0.3, 0.7, 1.5])), int(rng.integers(1, 12))
        want = DBSCAN(eps=eps, min_samples=least).fit_predict(x)
        np.testing.assert_array_equal(density.dbscan(x, eps, least), want, err_msg=f"n={n} eps={eps} {least}")


@pytest.mark.parametrize("chunk", range(4))
def test_hdbscan_equals_sklearn(chunk):
    compared_with_epsilon = 0
    for rng, n, x in cases(range(1000 + 60 * chunk, 1000 + 60 * chunk + 60)):
        if n < 2:  # scikit-learn refuses a single row; density.py calls it noise
            assert density.hdbscan(x, 5).tolist() == [-1] * n
            continue
        size = int(rng.integers(2, 40))
        least = None if rng.random() < 0.4 else int(rng.integers(1, 15))
        least = None if least is None else min(least, n)
        if size > n and least is None:
            least = n
        epsilon = float(rng.choice([0.0, 0.0, 0.05, 0.2, 0.5, 1.0]))
        try:
            want = HDBSCAN(min_cluster_size=size, min_samples=least, cluster_selection_epsilon=epsilon,
                           copy=True).fit_predict(x)
        except TypeError:  # scikit-learn 1.9.1 under numpy 2.4: `traverse_upwards` fails past one level
            assert epsilon > 0
            continue
        compared_with_epsilon += epsilon > 0
        np.testing.assert_array_equal(density.hdbscan(x, size, least, epsilon), want,
                                      err_msg=f"n={n} size={size} least={least} epsilon={epsilon}")
    assert compared_with_epsilon >= 5


def test_duplicates_ties_and_sizes_at_the_row_count():
    rng = np.random.default_rng(7)
    x = np.repeat(rng.normal(size=(30, 3)), rng.integers(1, 9, 30), axis=0)[::-1].copy()  # clumps of copies
    lattice = rng.integers(0, 4, (300, 2)).astype(float)  # a few distinct points, each many times
    for data in (x, lattice, np.zeros((10, 2))):
        n = data.shape[0]
        for eps, least in ((0.0001, 3), (0.5, 5), (1.0, n)):
            np.testing.assert_array_equal(density.dbscan(data, eps, least),
                                          DBSCAN(eps=eps, min_samples=least).fit_predict(data))
        for size, least in ((2, None), (5, 3), (min(40, n), 1), (n, None), (n + 3, n)):
            want = HDBSCAN(min_cluster_size=size, min_samples=least, copy=True).fit_predict(data)
            np.testing.assert_array_equal(density.hdbscan(data, size, least), want)
    with pytest.raises(ValueError, match="min_samples"):
        density.hdbscan(np.zeros((4, 2)), 5)


def episodes(suite: str, names: tuple[str, ...]):
    for name in names:
        entry = load_suite(suite).entry(name)
        yield simulate(entry.spec, entry.seeds("train")[2])  # a train seed: nothing here scores a policy


@pytest.mark.parametrize("spec, module, name, oracle, suite, names", [
    ("dbscan", clustering, "dbscan", lambda x, eps, least: DBSCAN(eps=eps, min_samples=least).fit_predict(x),
     "blind-v0", ("blind-n2to5-jitter0.1", "blind-n4to6-jitter0.5")),
    ("hdbscan:min_samples=4", clustering, "hdbscan",
     lambda x, size, least: HDBSCAN(min_cluster_size=size, min_samples=least, copy=True).fit_predict(x),
     "blind-v0", ("blind-n2to5-jitter0.1", "blind-n4to6-jitter0.1")),
    ("pdw-hdbscan:scale=robust", pdw_hdbscan, "hdbscan",
     lambda x, size, least, epsilon: HDBSCAN(min_cluster_size=size, min_samples=least, copy=True,
                                             cluster_selection_epsilon=epsilon).fit_predict(x),
     "pdw-v0", ("pdw-staring-n10-blind", "pdw-scanning-n30-blind")),
])
def test_policy_labels_equal_a_run_with_sklearn(monkeypatch, spec, module, name, oracle, suite, names):
    for ep in episodes(suite, names):
        ours = play(make_policy(spec), ep, clustering=False).labels
        with monkeypatch.context() as m:
            m.setattr(module, name, oracle)
            theirs = play(make_policy(spec), ep, clustering=False).labels
        np.testing.assert_array_equal(ours, theirs)
        assert len(np.unique(ours)) > 2

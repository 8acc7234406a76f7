"""Clustering scores from the contingency table, with numpy: V-measure, homogeneity, completeness,
adjusted Rand index and adjusted mutual information (arithmetic normaliser).

They are scikit-learn's definitions (`sklearn.metrics.cluster`, which the tests compare against to
1e-10), computed without its input validation and sparse-matrix round trips, which cost milliseconds
per call and made every episode's last env step ~100x a normal one.  Everything is computed from the
non-zero cells of the contingency table (classes x clusters), so one-pulse clusters cost O(n), not
O(n^2).  Natural logarithms throughout, as scikit-learn.

Edge cases follow scikit-learn: no samples give 1.0 everywhere; a labelling with one class or one
cluster has zero entropy (homogeneity / completeness 1.0 for that side, MI 0, AMI 0 unless both
sides are a single group, then 1.0).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

_EPS = float(np.finfo(np.float64).eps)
_EMI_CHUNK = 1 << 20  # terms of the expected-MI sum evaluated at once (bounds its memory to ~50 MB)


class Contingency(NamedTuple):
    """The non-zero cells of the classes x clusters table, row-major (class, then cluster)."""

    n: int  # samples
    row: np.ndarray  # class index of each cell
    col: np.ndarray  # cluster index of each cell
    count: np.ndarray  # int64 samples in each cell
    a: np.ndarray  # int64 class sizes (row sums)
    b: np.ndarray  # int64 cluster sizes (column sums)


class ClusteringScores(NamedTuple):
    homogeneity: float
    completeness: float
    v_measure: float
    ari: float
    ami: float


def contingency(labels_true: np.ndarray, labels_pred: np.ndarray) -> Contingency:
    true = np.asarray(labels_true).ravel()
    pred = np.asarray(labels_pred).ravel()
    if true.shape != pred.shape:
        raise ValueError(f"{pred.size} predicted labels for {true.size} true labels")
    _, t = np.unique(true, return_inverse=True)
    _, c = np.unique(pred, return_inverse=True)
    a = np.bincount(t).astype(np.int64)
    b = np.bincount(c).astype(np.int64)
    cells, count = np.unique(t.astype(np.int64) * max(b.size, 1) + c, return_counts=True)
    row, col = np.divmod(cells, max(b.size, 1))
    return Contingency(int(true.size), row, col, count.astype(np.int64), a, b)


def entropy(sizes: np.ndarray) -> float:
    """Entropy of a labelling from its group sizes (scikit-learn's `_entropy`, term for term)."""
    if sizes.size == 0:
        return 1.0
    if sizes.size == 1:
        return 0.0
    p = sizes.astype(np.float64)
    total = float(p.sum())
    return float(-np.sum((p / total) * (np.log(p) - math.log(total))))


def mutual_info(ct: Contingency) -> float:
    """Mutual information of the two labellings (scikit-learn's `mutual_info_score`, term for term,
    so that identical labellings give MI equal to their entropy to the last bit)."""
    if ct.a.size == 1 or ct.b.size == 1:
        return 0.0
    nz = ct.count.astype(np.float64)
    total = float(ct.n)
    outer = ct.a[ct.row] * ct.b[ct.col]
    log_outer = -np.log(outer) + math.log(float(ct.a.sum())) + math.log(float(ct.b.sum()))
    p = nz / total
    mi = p * (np.log(nz) - math.log(total)) + p * log_outer
    mi = np.where(np.abs(mi) < _EPS, 0.0, mi)
    return float(max(mi.sum(), 0.0))


def expected_mutual_info(a: np.ndarray, b: np.ndarray, n: int) -> float:
    """E[MI] of two random labellings with class sizes `a` and cluster sizes `b` (the hypergeometric
    model of Vinh, Epps & Bailey 2010, eq. 24a), vectorised.

    The term of a cell depends only on the pair of sizes (a_i, b_j), so pairs of distinct sizes are
    summed once and weighted by how often they occur; each pair contributes the sum over
    n_ij = max(1, a_i + b_j - n) .. min(a_i, b_j) of
    n_ij/n * log(n n_ij / (a_i b_j)) * a_i! b_j! (n-a_i)! (n-b_j)! / (n! n_ij! (a_i-n_ij)! (b_j-n_ij)! (n-a_i-b_j+n_ij)!).
    """
    if a.size == 1 or b.size == 1:
        return 0.0  # a labelling with zero entropy shares no information
    av, a_mult = np.unique(a, return_counts=True)
    bv, b_mult = np.unique(b, return_counts=True)
    ai, bj = (x.ravel() for x in np.meshgrid(av, bv, indexing="ij"))
    weight = np.outer(a_mult, b_mult).ravel().astype(np.float64)
    start = np.maximum(1, ai + bj - n)
    length = np.maximum(np.minimum(ai, bj) - start + 1, 0)
    keep = length > 0
    ai, bj, weight, start, length = ai[keep], bj[keep], weight[keep], start[keep], length[keep]
    ln = math.log(n)
    from scipy.special import gammaln  # here: scipy.special is slow to import
    lgf = gammaln(np.arange(n + 2, dtype=np.float64))  # log(k - 1)!: every gamma argument is an integer
    # per pair: log(a! b! (n-a)! (n-b)! / n!) and log(a b)
    const = lgf[ai + 1] + lgf[bj + 1] + lgf[n - ai + 1] + lgf[n - bj + 1] - lgf[n + 1]
    log_ab = np.log(ai) + np.log(bj)
    total = 0.0
    ends = np.cumsum(length)
    first = 0
    while first < ai.size:  # chunks of pairs with at most _EMI_CHUNK terms (one pair may exceed it)
        base = ends[first - 1] if first else 0
        last = max(int(np.searchsorted(ends, base + _EMI_CHUNK, side="right")), first + 1)
        reps = length[first:last]
        pair = np.repeat(np.arange(first, last), reps)
        nij = start[pair] + np.arange(int(reps.sum())) - np.repeat(np.cumsum(reps) - reps, reps)
        aa, bb = ai[pair], bj[pair]
        gln = const[pair] - lgf[nij + 1] - lgf[aa - nij + 1] - lgf[bb - nij + 1] - lgf[n - aa - bb + nij + 1]
        term = nij / n * (ln + np.log(nij) - log_ab[pair]) * np.exp(gln)
        total += float(np.dot(weight[pair], term))
        first = last
    return total


def adjusted_rand(ct: Contingency) -> float:
    """Adjusted Rand index from the pair-confusion counts (exact Python integers, as scikit-learn)."""
    n = ct.n
    sum_squares = int(np.dot(ct.count, ct.count))
    sa, sb = int(np.dot(ct.a, ct.a)), int(np.dot(ct.b, ct.b))
    tp = sum_squares - n
    fp = sb - sum_squares  # pairs together in the clustering, apart in the truth
    fn = sa - sum_squares
    tn = n * n - fp - fn - sum_squares
    if fn == 0 and fp == 0:
        return 1.0  # no samples, or full agreement
    return 2.0 * (tp * tn - fn * fp) / ((tp + fn) * (fn + tn) + (tp + fp) * (fp + tn))


def adjusted_mutual_info(ct: Contingency, mi: float, h_true: float, h_pred: float) -> float:
    """AMI with the arithmetic-mean normaliser: (MI - E[MI]) / (mean(H_true, H_pred) - E[MI])."""
    if ct.a.size == ct.b.size and ct.a.size <= 1:
        return 1.0  # nothing split, on either side: a perfect match
    if ct.a.size == 1 or ct.b.size == 1:
        return 0.0
    emi = expected_mutual_info(ct.a, ct.b, ct.n)
    # Keep 0/0 away when the expectation equals the maximum, preserving signs (scikit-learn's rule).
    den = (h_true + h_pred) / 2 - emi
    den = min(den, -_EPS) if den < 0 else max(den, _EPS)
    num = mi - emi
    num = min(num, -_EPS) if num < 0 else max(num, _EPS)
    return num / den


def scores(labels_true: np.ndarray, labels_pred: np.ndarray) -> ClusteringScores:
    """Every score of one labelling against the truth, from one contingency table."""
    ct = contingency(labels_true, labels_pred)
    if ct.n == 0:
        return ClusteringScores(1.0, 1.0, 1.0, 1.0, 1.0)
    h_true, h_pred = entropy(ct.a), entropy(ct.b)
    mi = mutual_info(ct)
    hom = mi / h_true if h_true else 1.0
    com = mi / h_pred if h_pred else 1.0
    v = 0.0 if hom + com == 0.0 else 2.0 * hom * com / (hom + com)
    return ClusteringScores(float(hom), float(com), float(v), adjusted_rand(ct),
                            adjusted_mutual_info(ct, mi, h_true, h_pred))

"""Scoring a labelling (docs/design.md section 6): per-episode metrics and suite aggregates.

Per episode: label accuracy (the env's reward rule), per-source error probability P_e^i (MK94 eq. 5.1)
and its mean, permutation-matched accuracy (Hungarian over the confusion matrix), link accuracy,
spurious precision/recall, the Turing Deinterleaving Challenge's clustering metrics (V-measure, ARI,
AMI, homogeneity, completeness as scikit-learn defines them; cluster-wise MCC and F1), and the estimation errors
of a policy's `estimates()` against the truth and the Cramer-Rao bound.

Across episodes: `METRICS`, the one metric table (key, label, format, how it aggregates, which way
is better) that the runner's summary, the leaderboard and its renderers all read: adding a metric
is a function here and one `Metric` line.  The normalised score is aggregated as its IQM and mean
with stratified-bootstrap intervals (`deint_env.aggregate`); `stratified_bootstrap` below is the
plain-numpy statement of that method, against which the rliable path is tested.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from deint_env import clustering
from deint_env.labels import correct_anchored, correct_link, true_predecessors


# ---------------------------------------------------------------------------------------------------
# per-episode label metrics
# ---------------------------------------------------------------------------------------------------
# The keys `label_metrics` returns, in its order (tests/test_labels_metrics.py holds them equal), stated
# so that an env can lay out its info before any labelling without computing one (a probe would import
# scipy.optimize: 0.4 s of every `deint label`).
LABEL_KEYS = ("n_pulses", "accuracy", "matched_accuracy", "link_accuracy", "mean_pe", "pe", "spurious_precision",
              "spurious_recall")
CLUSTERING_KEYS = ("v_measure", "homogeneity", "completeness", "ari", "ami", "cluster_mcc", "cluster_f1")


def metric_keys(clustering: bool = True) -> tuple[str, ...]:
    """The keys of `label_metrics(..., clustering=clustering)`."""
    return LABEL_KEYS + CLUSTERING_KEYS if clustering else LABEL_KEYS


def label_metrics(labels: np.ndarray, source: np.ndarray, mask: np.ndarray, n_labels: int, blind: bool,
                  clustering: bool = True) -> dict[str, float]:
    """All label metrics of one episode.  `labels` has one entry per pulse (n_labels = spurious)."""
    labels = np.asarray(labels, dtype=np.int64)
    if labels.shape != source.shape:
        raise ValueError(f"{labels.size} labels for {source.size} pulses")
    if labels.size and (labels.min() < 0 or labels.max() > n_labels):
        raise ValueError(f"labels must lie in [0, {n_labels}] ({n_labels} = spurious)")
    spur = n_labels
    link = correct_link(labels, source, mask, spur, true_predecessors(source, mask))
    mapped = matched_labels(labels, source, n_labels)
    matched = correct_anchored(mapped, source, mask, spur)
    anchored = matched if blind else correct_anchored(labels, source, mask, spur)
    out: dict[str, float] = {
        "n_pulses": int(labels.size),
        "accuracy": float(np.mean(link if blind else anchored)) if labels.size else math.nan,
        "matched_accuracy": float(np.mean(matched)) if labels.size else math.nan,
        "link_accuracy": float(np.mean(link)) if labels.size else math.nan,
    }
    # P_e^i (MK94 eq. 5.1): the share of source i's pulses not attributed to it.  In blind mode the
    # labels are first mapped to sources by the Hungarian matching.
    pe = per_source_error(anchored, mask, source)
    out["mean_pe"] = float(np.nanmean(pe)) if np.any(np.isfinite(pe)) else math.nan
    out["pe"] = [None if not np.isfinite(v) else float(v) for v in pe]
    true_spur, said_spur = source < 0, labels == spur
    tp = int(np.sum(true_spur & said_spur))
    out["spurious_precision"] = tp / int(said_spur.sum()) if said_spur.any() else float(not true_spur.any())
    out["spurious_recall"] = tp / int(true_spur.sum()) if true_spur.any() else 1.0
    if clustering:
        out.update(clustering_metrics(source, labels))
    return out


def per_source_error(correct: np.ndarray, mask: np.ndarray, source: np.ndarray | None = None) -> np.ndarray:
    """P_e^i for every source bit present in `mask`, and every source in `source` (sources 64 and up,
    which have no bit), NaN for a source with no pulse."""
    k = n_sources(source, mask)
    pe = np.full(k, np.nan)
    for i in range(k):
        has = (np.right_shift(mask, np.uint64(i)) & np.uint64(1)).astype(bool) if i < 64 else source == i
        if has.any():
            pe[i] = 1.0 - float(np.mean(correct[has]))
    return pe


def n_sources(source: np.ndarray | None, mask: np.ndarray) -> int:
    """How many sources an episode's truth numbers: the highest mask bit or source, plus one."""
    allbits = int(np.bitwise_or.reduce(mask)) if mask.size else 0
    top = int(source.max()) + 1 if source is not None and source.size else 0
    return max(allbits.bit_length(), top)


def matched_labels(labels: np.ndarray, source: np.ndarray, n_labels: int) -> np.ndarray:
    """Relabel by the permutation that best matches labels to sources (Hungarian on the confusion
    matrix of primary sources); "spurious" stays spurious and unmatched labels become spurious."""
    spur = n_labels
    k = int(source.max()) + 1 if source.size and source.max() >= 0 else 0
    real_l, real_s = labels < spur, source >= 0
    both = real_l & real_s
    conf = np.zeros((n_labels, max(k, 1)), dtype=np.int64)
    np.add.at(conf, (labels[both], source[both]), 1)
    from scipy.optimize import linear_sum_assignment  # here: scipy.optimize is slow to import (`deint --help`)
    rows, cols = linear_sum_assignment(-conf)
    lut = np.full(n_labels + 1, spur, dtype=np.int64)
    lut[rows] = cols
    return lut[labels]


def clustering_metrics(source: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """The Turing Deinterleaving Challenge's metric set (V-measure is its primary).

    Spurious pulses form one more true class (-1) and "spurious" one more predicted cluster, as the
    TDC scores noise when no `default_label` is set.  Cluster-wise MCC and F1 are the TDC's: each
    true class's best cluster, then the worst class (`clusterwise_mcc_f1`).
    """
    s = clustering.scores(source, labels)  # scikit-learn's definitions, from the contingency table
    out = {"v_measure": s.v_measure, "homogeneity": s.homogeneity, "completeness": s.completeness,
           "ari": s.ari, "ami": s.ami}
    out.update(clusterwise_mcc_f1(source, labels))
    return out


def clusterwise_mcc_f1(source: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """The TDC's cluster-wise MCC and F1: for every true class, the best binary score ("in this
    cluster" against "in this class") over the predicted clusters; then the worst class."""
    classes, t = np.unique(np.asarray(source), return_inverse=True)
    clusters, c = np.unique(np.asarray(labels), return_inverse=True)
    n = t.size
    if n == 0:
        return {"cluster_mcc": math.nan, "cluster_f1": math.nan}
    tp = np.zeros((classes.size, clusters.size), dtype=np.float64)
    np.add.at(tp, (t.ravel(), c.ravel()), 1.0)
    fn = tp.sum(1, keepdims=True) - tp  # in the class, not in the cluster
    fp = tp.sum(0, keepdims=True) - tp  # in the cluster, not in the class
    tn = n - tp - fp - fn
    with np.errstate(divide="ignore", invalid="ignore"):
        f1 = np.where(tp > 0, 2 * tp / (2 * tp + fp + fn), 0.0)
        den = np.sqrt((tp + fp) * (tp + fn) * (tn + fp) * (tn + fn))
        mcc = np.where(den > 0, (tp * tn - fp * fn) / den, 0.0)
    return {"cluster_mcc": float(mcc.max(1).min()), "cluster_f1": float(f1.max(1).min())}


# ---------------------------------------------------------------------------------------------------
# estimation metrics
# ---------------------------------------------------------------------------------------------------
def crlb_period_var(jitter_std: float, n: np.ndarray) -> np.ndarray:
    """Cramer-Rao bound on the variance of a period estimate from n pulses of a known sequence in
    white TOA noise: var T >= 12 sigma^2 / (n (n^2 - 1)) (line fit to arrival times)."""
    n = np.asarray(n, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(n >= 2, 12.0 * jitter_std**2 / (n * (n * n - 1.0)), np.inf)


def estimation_metrics(estimates: dict[str, Any], truth: Any, jitter_std: float,
                       label_of_source: np.ndarray | None = None) -> dict[str, float]:
    """Errors of a policy's final per-track period/phase estimates against the true sources.

    Track i estimates source i (anchored), or the source `label_of_source` maps to it (blind).
    period_rel_error: mean |T_hat - T| / T; phase_error: mean circular |phi_hat - phi| as a fraction of
    the period; period_crlb_ratio: sqrt(mean (T_hat - T)^2 / CRLB), 1 = efficient (NaN without jitter).
    """
    period = np.asarray(estimates.get("period", []), dtype=np.float64)
    phase = np.asarray(estimates.get("phase", np.full(period.size, np.nan)), dtype=np.float64)
    k = truth.n_sources
    track = np.arange(k) if label_of_source is None else np.asarray(label_of_source)
    ok = (track >= 0) & (track < period.size)
    if not ok.any():
        return {"period_rel_error": math.nan, "phase_error": math.nan, "period_crlb_ratio": math.nan}
    src = np.flatnonzero(ok)
    t_true = truth.final_period[src]
    t_hat = period[track[src]]
    rel = np.abs(t_hat - t_true) / t_true
    ph = phase[track[src]]
    frac = (ph - truth.phase[src]) / truth.period[src]
    ph_err = np.abs(frac - np.round(frac))
    crlb = crlb_period_var(jitter_std, truth.n_received[src])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (t_hat - t_true) ** 2 / crlb
    finite = np.isfinite(ratio) & (crlb > 0)
    return {
        "period_rel_error": float(np.nanmean(rel)) if np.any(np.isfinite(rel)) else math.nan,
        "phase_error": float(np.nanmean(ph_err)) if np.any(np.isfinite(ph_err)) else math.nan,
        "period_crlb_ratio": float(math.sqrt(np.mean(ratio[finite]))) if finite.any() else math.nan,
    }


def normalised_score(acc: float, acc_random: float, acc_genie: float) -> float:
    """(acc - acc_random) / (acc_genie - acc_random); NaN when genie is no better than random."""
    span = acc_genie - acc_random
    return (acc - acc_random) / span if span > 1e-12 else math.nan


# ---------------------------------------------------------------------------------------------------
# aggregates (rliable's interval estimates)
# ---------------------------------------------------------------------------------------------------
def iqm(x: np.ndarray, axis: int = -1) -> Any:
    """Interquartile mean: the mean of the middle 50 % (scipy's trim_mean at 25 %)."""
    from scipy.stats import trim_mean

    x = np.asarray(x, dtype=np.float64)
    return trim_mean(x, 0.25, axis=axis) if x.size else math.nan


def mean(x: np.ndarray, axis: int = -1) -> Any:
    x = np.asarray(x, dtype=np.float64)
    return np.mean(x, axis=axis) if x.size else math.nan


def stratified_bootstrap(strata: Sequence[np.ndarray], stat: Callable[..., Any], reps: int = 2000,
                         seed: int = 0, alpha: float = 0.05) -> tuple[float, float, float]:
    """(point, low, high): `stat` over all samples, and its percentile interval when every stratum
    (scenario) is resampled with replacement on its own (rliable's stratified bootstrap).

    `stat(x, axis)` reduces along `axis`; all bootstrap replicates are drawn and reduced at once.
    """
    strata = [np.asarray(s, dtype=np.float64).ravel() for s in strata if np.size(s)]
    if not strata:
        return math.nan, math.nan, math.nan
    point = float(stat(np.concatenate(strata), axis=-1))
    rng = np.random.default_rng(seed)
    replicates = np.concatenate([s[rng.integers(0, s.size, (reps, s.size))] for s in strata], axis=1)
    stats = stat(replicates, axis=1)
    lo, hi = np.quantile(stats, [alpha / 2, 1 - alpha / 2])
    return point, float(lo), float(hi)


# ---------------------------------------------------------------------------------------------------
# the metric table
# ---------------------------------------------------------------------------------------------------
REDUCERS: dict[str, Callable[[np.ndarray], float]] = {"mean": np.mean, "median": np.median}


@dataclass(frozen=True)
class Metric:
    """One per-episode metric as tables show it.  `key` is its name in episode records; `aggregate`
    names its reduction over an entry's played episodes (`REDUCERS`: "median" for heavy-tailed
    errors, where one lost track would swamp a mean); `summary`: also a column of `deint run`'s table
    (the leaderboard shows every metric)."""

    key: str
    label: str
    fmt: str = ".3f"
    aggregate: str = "mean"
    higher_is_better: bool | None = True  # None: neither (e.g. a lag)
    summary: bool = False

    def reduce(self, values: list[float]) -> float | None:
        return float(REDUCERS[self.aggregate](np.asarray(values, dtype=np.float64))) if values else None

    def cell(self, value: Any) -> str:
        return "-" if value is None or not math.isfinite(value) else format(value, self.fmt)


# The headline: the normalised score, aggregated as IQM and mean with 95 % stratified-bootstrap intervals.
SCORE = "score"
METRICS: tuple[Metric, ...] = (
    Metric("accuracy", "accuracy", summary=True),
    Metric("matched_accuracy", "matched accuracy"),
    Metric("mean_pe", "mean P_e", higher_is_better=False, summary=True),
    Metric("v_measure", "V-measure", summary=True),
    Metric("ari", "ARI"),
    Metric("ami", "AMI"),
    Metric("link_accuracy", "link accuracy"),
    Metric("period_rel_error", "period rel. error", ".2e", "median", higher_is_better=False),
    Metric("period_crlb_ratio", "period error / CRLB", ".3g", "median", higher_is_better=False),
    Metric("us_per_pulse", "us/pulse", ".1f", higher_is_better=False, summary=True),
    Metric("lag", "lag", ".0f", higher_is_better=None, summary=True),
)

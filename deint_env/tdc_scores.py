"""The Turing Deinterleaving Challenge's scores (see `deint_env.formats.tdc` for its files).

`tdc_scores` reproduces the challenge's `evaluate_labels` (`models/evaluate.py`): homogeneity,
completeness, V-measure, ARI and AMI (scikit-learn's definitions, computed by `deint_env.clustering`),
the cluster-wise MCC and F1 (for each true emitter the best score over predicted clusters, then the
worst emitter), and the discount: with a
``default_label``, pulses whose *true* label is it are dropped and every score is multiplied by the
fraction kept.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from deint_env import clustering
from deint_env.errors import DeintError
from deint_env.labels import source_bits
from deint_env.scenario import MAX_SOURCES


def tdc_scores(labels_true: np.ndarray, labels_pred: np.ndarray, default_label: int | None = None) -> dict[str, float]:
    """The challenge's `evaluate_labels` for one train: homogeneity, completeness, v_measure, ari,
    ami, cluster-wise mcc and f1, and the discount.  With `default_label` (the model's
    "no emitter" id) pulses whose true label is it are left out and every score is multiplied by the
    share of pulses kept (the discount)."""
    from deint_env.metrics import clusterwise_mcc_f1

    true = np.asarray(labels_true).ravel()
    pred = np.asarray(labels_pred).ravel()
    if true.shape != pred.shape:
        raise DeintError(f"{pred.size} predicted labels for {true.size} true labels")
    discount = 1.0
    if default_label is not None and true.size:
        keep = true != default_label
        discount = float(keep.mean())
        true, pred = true[keep], pred[keep]
    if true.size == 0:
        return dict.fromkeys(("homogeneity", "completeness", "v_measure", "ari", "ami", "mcc", "f1"), math.nan) | {
            "discount": discount}
    out = clustering.scores(true, pred)._asdict()
    cw = clusterwise_mcc_f1(true, pred)
    out.update(mcc=cw["cluster_mcc"], f1=cw["cluster_f1"])
    return {k: discount * float(v) for k, v in out.items()} | {"discount": discount}


def score_labels(pred: np.ndarray, truth: np.ndarray, n_labels: int | None = None) -> dict[str, Any]:
    """Score predicted ids against TDC truth ids (negative = spurious / noise, both sides) in blind
    mode: our label metrics when the truth has at most 128 emitters (else the clustering metrics
    alone); the cluster-wise MCC/F1 there are the TDC's own (`metrics.clusterwise_mcc_f1`)."""
    from deint_env.metrics import clustering_metrics, label_metrics

    pred = np.asarray(pred, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    ids = np.unique(pred[pred >= 0])
    if n_labels is None:
        n_labels = max(int(ids.size), 1)
        env = np.where(pred >= 0, np.searchsorted(ids, pred), n_labels)
    else:
        env = np.where(pred >= 0, pred, n_labels)
    emitters = np.unique(truth[truth >= 0])
    source = np.where(truth >= 0, np.searchsorted(emitters, truth), -1).astype(np.int32)
    out: dict[str, Any] = {"n_labels": int(n_labels), "blind": True, "n_emitters": int(emitters.size)}
    if emitters.size <= MAX_SOURCES:
        mask = source_bits(source)
        out.update(label_metrics(env, source, mask, int(n_labels), True, clustering=True))
    else:  # our truth tables stop at 128 sources; the clustering metrics do not
        out.update(n_pulses=int(pred.size), **clustering_metrics(source, env))
    return out

"""Density clustering of pulse descriptors: DBSCAN and HDBSCAN as scikit-learn defines them, the method
of the Turing Deinterleaving Challenge's baseline (implemented in baselines/blind/density.py and tested
label for label against scikit-learn, so a labelling call does not pay scikit-learn's ~1 s import).

Descriptors per pulse: every column the pulses have besides the TOA (amplitude; a TDC file's
frequency, pulse width, angle of arrival) and, from the TOAs, the differences to the previous and
the next pulse (the TOA itself orders pulses but does not group them).  Each column is standardised
(median and interquartile range, robust to outliers).  A cluster's PRI estimate is the median of the
differences between its successive pulses, its model constant; noise (-1) is spurious.
"""

from __future__ import annotations

import numpy as np

from baselines.blind.density import dbscan, hdbscan
from baselines.blind.descriptors import standardised
from baselines.blind.pipeline import Deinterleaving, FoundTrain
from baselines.blind.policy import WINDOW, BlindWindowPolicy
from deint_env.errors import NotApplicable
from deint_env.modulation import PRIModel
from deint_env.params import Param, declare


def descriptors(toa: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """(n, d) standardised descriptors: extra columns, then the TOA differences to both neighbours."""
    gaps = np.diff(toa)
    fill = float(np.median(gaps)) if gaps.size else 0.0
    return standardised({**(extra or {}), "dt_prev": np.concatenate([[fill], gaps]),
                         "dt_next": np.concatenate([gaps, [fill]])})


def cluster_result(toa: np.ndarray, ids: np.ndarray) -> Deinterleaving:
    """Clusters as trains (ids numbered 0.. in first-pulse order, -1 = spurious)."""
    labels = np.full(toa.size, -1, dtype=np.int64)
    trains = []
    real = np.unique(ids[ids >= 0])
    firsts = sorted(real.tolist(), key=lambda c: int(np.flatnonzero(ids == c)[0]))
    for n, c in enumerate(firsts):
        pulses = np.flatnonzero(ids == c)
        labels[pulses] = n
        gaps = np.diff(toa[pulses])
        period = float(np.median(gaps)) if gaps.size else float("nan")
        trains.append(FoundTrain(pulses, PRIModel("constant", period), float(toa[pulses[0]]), toa[pulses]))
    return Deinterleaving(labels, trains)


class ClusterPolicy(BlindWindowPolicy):
    """Base of `dbscan` / `hdbscan`: cluster each window's descriptors (with `attach_features`, also
    columns such as a TDC file's frequency or angle of arrival)."""

    name = "cluster"  # the registered name, for messages (as ekf-bank's)

    def label_window(self, toa: np.ndarray, amplitude: np.ndarray | None) -> Deinterleaving:
        extra: dict[str, np.ndarray] = {}
        if amplitude is not None:
            extra["amplitude"] = amplitude
        extra.update(self.window_features(toa.size))
        with np.errstate(over="ignore", invalid="ignore"):  # checked below, in one line
            x = descriptors(toa, extra)
        if not np.isfinite(x).all():  # TOA differences near float64's limit overflow when standardised
            i = int(np.flatnonzero(~np.isfinite(x).all(axis=1))[0])
            raise NotApplicable(f"{self.name}: the descriptors of pulse {i} (TOA {float(toa[i]):.3g}) overflow "
                                f"float64; the TOAs and their differences must stay well below 1e308")
        return cluster_result(toa, self.cluster(x))

    def cluster(self, x: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class DBSCANPolicy(ClusterPolicy):
    """`dbscan`: DBSCAN as scikit-learn defines it (eps in standardised units, min_samples)."""

    name = "dbscan"

    PARAMS = declare(Param("eps", float, 0.1, "DBSCAN's neighbourhood radius (standardised units)", low=0,
                           low_open=True),
                     Param("min_samples", int, 5, "DBSCAN's core-point neighbourhood size", low=1),
                     WINDOW)

    def __init__(self, eps: float = 0.1, min_samples: int = 5, window: int = 1000):
        self.PARAMS.check(locals())
        super().__init__(window)
        self.eps, self.min_samples = float(eps), min_samples

    def cluster(self, x: np.ndarray) -> np.ndarray:
        return dbscan(x, self.eps, self.min_samples)


class HDBSCANPolicy(ClusterPolicy):
    """`hdbscan`: HDBSCAN as scikit-learn defines it (min_cluster_size, min_samples)."""

    name = "hdbscan"

    PARAMS = declare(Param("min_cluster_size", int, 20, "HDBSCAN's smallest cluster", low=2),
                     Param("min_samples", int, None, "HDBSCAN's core-point neighbourhood size (none: min_cluster_size)",
                           low=1, optional=True),
                     WINDOW)

    def __init__(self, min_cluster_size: int = 20, min_samples: int | None = None, window: int = 1000):
        self.PARAMS.check(locals())
        super().__init__(window)
        self.min_cluster_size, self.min_samples = min_cluster_size, min_samples

    def cluster(self, x: np.ndarray) -> np.ndarray:
        least = None if self.min_samples is None else min(self.min_samples, x.shape[0])  # a short window
        return hdbscan(x, min(self.min_cluster_size, x.shape[0]), least)

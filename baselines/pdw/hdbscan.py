"""`pdw-hdbscan`: the Turing Deinterleaving Challenge's baseline, HDBSCAN as scikit-learn defines it on
each window's pulse descriptor words (baselines/blind/density.py, tested label for label against
scikit-learn, so a labelling call does not pay scikit-learn's ~1 s import).

What the challenge's public material says of its baseline (alan-turing-institute/
turing-deinterleaving-challenge: README's leader board, `examples/identity_model.ipynb`, issue #8): HDBSCAN
"directly on the raw PDWs" (all five columns: TOA, centre frequency, pulse width, AoA, amplitude),
un-normalised ("the most naive benchmark"), on windows of 1024 pulses, scikit-learn's parameters left at
their defaults (min_cluster_size 5, min_samples = min_cluster_size) but `cluster_selection_epsilon`
(0, 0.05, 0.1, 0.5 tried) and `copy=True`, HDBSCAN's noise (-1) kept as "no emitter".  That is the
default here (`scale=none`), with one change: the AoA is a point on a circle of radius 180/pi degrees
(`aoa_plane`) instead of a number in [0, 360), so that 359 and 1 degrees are neighbours and nearby
angles keep their distance in degrees.  `scale=robust` centres each column on its median and divides
it by its interquartile range (the challenge's technical annex lists it among PDW normalisations); raw
TOAs in microseconds otherwise outweigh the other columns and cut an emitter into pieces in time.
"""

from __future__ import annotations

import numpy as np

from baselines.blind.density import hdbscan
from baselines.blind.descriptors import standardised
from baselines.pdw.policy import Clusters, PDWPolicy, PDWs, aoa_plane
from baselines.windowed import MAX_WINDOW
from deint_env.params import Param, declare

SCALES = ("none", "robust")


def pdw_matrix(p: PDWs, scale: str) -> np.ndarray:
    """(n, 5 or 6): TOA, frequency, pulse width, the AoA plane's two columns and the amplitude if any."""
    plane = aoa_plane(p.aoa)
    cols = {"toa": p.toa, "frequency": p.frequency, "pulse_width": p.pulse_width, "aoa_x": plane[:, 0],
            "aoa_y": plane[:, 1]}
    if p.amplitude is not None:
        cols["amplitude"] = p.amplitude
    return standardised(cols) if scale == "robust" else np.column_stack(list(cols.values()))


def hdbscan_clusters(x: np.ndarray, min_cluster_size: int, min_samples: int | None = None,
                     epsilon: float = 0.0) -> Clusters:
    """HDBSCAN (scikit-learn's, baselines/blind/density.py) on the rows of x (noise: -1), its sizes held
    to the row count, as Clusters with no PRI; fewer than 2 rows are noise."""
    n = x.shape[0]
    if n < 2:
        return Clusters(np.full(n, -1, dtype=np.int64), np.zeros(0))
    least = None if min_samples is None else min(min_samples, n)
    ids = hdbscan(x, min(min_cluster_size, n), least, epsilon)
    return Clusters(ids, np.full(int(ids.max()) + 1, np.nan))


class PDWHDBSCANPolicy(PDWPolicy):
    """`pdw-hdbscan`: HDBSCAN on the PDWs of each window (noise: spurious)."""

    PARAMS = declare(
        Param("min_cluster_size", int, 5, "HDBSCAN's smallest cluster (the challenge's: scikit-learn's default)",
              low=2),
        Param("min_samples", int, None, "HDBSCAN's core-point neighbourhood size (none: min_cluster_size)",
              low=1, optional=True),
        Param("cluster_selection_epsilon", float, 0.0, "HDBSCAN's distance below which clusters are not split",
              low=0),
        Param("scale", str, "none", "none: the PDWs as they are (the challenge's baseline); robust: each column "
              "centred on its median and divided by its interquartile range", choices=SCALES),
        Param("window", int, 1024, "pulses per batch (the challenge's windows; the lag is window - 1)", low=2,
              high=MAX_WINDOW))

    def __init__(self, min_cluster_size: int = 5, min_samples: int | None = None,
                 cluster_selection_epsilon: float = 0.0, scale: str = "none", window: int = 1024):
        self.PARAMS.check(locals())
        super().__init__(window)
        self.min_cluster_size, self.min_samples = min_cluster_size, min_samples
        self.epsilon, self.scale = float(cluster_selection_epsilon), scale

    def label_window(self, p: PDWs) -> Clusters:
        return hdbscan_clusters(pdw_matrix(p, self.scale), self.min_cluster_size, self.min_samples, self.epsilon)

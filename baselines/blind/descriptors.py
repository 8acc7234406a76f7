"""Pulse descriptors (TOA differences, amplitude, a TDC file's frequency, pulse width, angle of
arrival) as one robustly scaled matrix, for density clustering and for pre-sorting before the PRI
analysis."""

from __future__ import annotations

import numpy as np


def standardised(columns: dict[str, np.ndarray]) -> np.ndarray:
    """(n, d): each column centred on its median and scaled by its interquartile range."""
    x = np.stack([np.asarray(v, dtype=np.float64) for v in columns.values()], axis=1)
    med = np.median(x, axis=0)
    iqr = np.subtract(*np.percentile(x, [75, 25], axis=0))
    return (x - med) / np.where(iqr > 0, iqr, 1.0)

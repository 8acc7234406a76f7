"""The pulse-descriptor policies' common part: the descriptors buffered from the observations, windows
labelled as batches, and emitters carried from one window to the next by their descriptors.

A policy buffers one pulse descriptor word per received pulse (`WindowedPolicy`: `window` pulses, lag
window - 1), labels the window with `label_window` (one cluster id per pulse, -1 = spurious) and emits
the labels one per step.  An emitter of a new window keeps the label of the previous window's emitter
whose descriptors (and PRI, when both have one) it matches; otherwise it takes the label least
recently used.  Emitters beyond the label budget are labelled spurious, the smallest first.

An episode without descriptors (a TOA-only scenario) is refused as not applicable: at `reset` when its
info says so (`has_descriptors`), else at the first pulse.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from baselines.windowed import WindowedPolicy
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable

DESCRIPTORS = ("frequency", "pulse_width", "aoa")  # the observation keys, MHz, us, degrees in [0, 360)
DEGREE = 180.0 / math.pi  # the AoA plane's radius: two angles d degrees apart lie about d apart
_MAD = 1.4826  # MAD -> standard deviation for a normal sample
# a match across windows: every descriptor within this many spreads, the PRIs within this fraction
_MATCH_SPREADS = 4.0
_MATCH_PRI = 0.01
MAX_PDW = 1e150  # the largest |TOA| or |descriptor| a window is clustered with: its squares stay finite


class PDWs(NamedTuple):
    """One window's pulse descriptor words, one entry per pulse, in arrival order."""

    toa: np.ndarray
    frequency: np.ndarray
    pulse_width: np.ndarray
    aoa: np.ndarray  # degrees
    amplitude: np.ndarray | None


class Clusters(NamedTuple):
    """A window's labelling: a cluster id per pulse (-1 = spurious) and each cluster's PRI (NaN: none)."""

    ids: np.ndarray
    periods: np.ndarray


class Signature(NamedTuple):
    """An emitter's descriptors in one window: (frequency, pulse width, AoA) centres and robust spreads."""

    centre: np.ndarray
    spread: np.ndarray
    period: float


def members_of(ids: np.ndarray, m: int) -> list[np.ndarray]:
    """The pulse indices of clusters 0..m-1 (ids -1 left out), each in arrival order."""
    bounds = np.cumsum(np.bincount(ids + 1, minlength=m + 1))
    return np.split(np.argsort(ids, kind="stable"), bounds)[1:m + 1]


def aoa_plane(aoa: np.ndarray) -> np.ndarray:
    """(n, 2): each angle as a point on a circle of radius 180/pi, so that 359 and 1 degrees are 2 apart
    (an angle's wrap-around would otherwise put them 358 apart)."""
    rad = np.radians(aoa)
    return DEGREE * np.column_stack([np.cos(rad), np.sin(rad)])


def angle_difference(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """a - b in degrees, wrapped to [-180, 180)."""
    return np.mod(np.asarray(a) - np.asarray(b) + 180.0, 360.0) - 180.0


def circular_centre(aoa: np.ndarray) -> float:
    """The direction of the mean unit vector, in degrees [0, 360)."""
    rad = np.radians(aoa)
    return float(np.mod(np.degrees(np.arctan2(np.sin(rad).mean(), np.cos(rad).mean())), 360.0))


def signature(p: PDWs, idx: np.ndarray, period: float) -> Signature:
    """The centres (medians; the AoA's circular centre) and spreads (1.4826 MAD, floored at a millionth
    of the centre so that noise-free descriptors still compare) of pulses `idx`."""
    aoa = p.aoa[idx]
    centre = np.array([np.median(p.frequency[idx]), np.median(p.pulse_width[idx]), circular_centre(aoa)])
    dev = np.column_stack([p.frequency[idx] - centre[0], p.pulse_width[idx] - centre[1],
                           angle_difference(aoa, centre[2])])
    spread = _MAD * np.median(np.abs(dev - np.median(dev, axis=0)), axis=0)
    return Signature(centre, np.maximum(spread, 1e-6 * np.abs(centre) + 1e-12), float(period))


def _distance(a: Signature, b: Signature) -> float:
    """The largest descriptor difference in units of the match tolerance (> 1: no match); inf when both
    have PRIs that differ."""
    diff = np.abs(b.centre - a.centre)
    diff[2] = abs(float(angle_difference(b.centre[2], a.centre[2])))
    if math.isfinite(a.period) and math.isfinite(b.period) and abs(a.period - b.period) > _MATCH_PRI * a.period:
        return math.inf
    return float(np.max(diff / (_MATCH_SPREADS * np.maximum(a.spread, b.spread))))


class PDWPolicy(WindowedPolicy):
    """Base of `pdw-hdbscan` and `pdw-pipeline`: subclasses give `label_window(pdws) -> Clusters`."""

    def label_window(self, p: PDWs) -> Clusters:
        raise NotImplementedError

    # ---- protocol ----------------------------------------------------------------------------------
    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if not priors.blind:
            raise NotApplicable("the pulse-descriptor clusterers find their own emitters: blind scenarios only")
        if info.get("has_descriptors") is False:
            raise NotApplicable(self._no_descriptors())
        self.priors = priors
        self.n_labels = priors.n_labels
        self._amp = bool(info.get("has_amplitude", False))
        self._start()
        self._windows = 0
        self._last_used = np.full(self.n_labels, -1, dtype=np.int64)  # window number of each label's last use
        self._previous: dict[int, Signature] = {}  # label -> its emitter in the previous window

    @staticmethod
    def _no_descriptors() -> str:
        return (f"the pdw-* policies sort pulse descriptor words: this scenario has none (no "
                f"{', '.join(DESCRIPTORS)} per pulse)")

    def _row(self, obs: dict[str, Any]) -> tuple[float, ...]:
        try:
            desc = tuple(float(obs[k][0]) for k in DESCRIPTORS)
        except KeyError:  # the env gives descriptors only for scenarios that have them
            raise NotApplicable(self._no_descriptors()) from None
        amp = (float(obs["amplitude"][0]),) if self._amp else ()
        return (float(obs["toa"][0]), *desc, *amp)

    def _label_rows(self, rows: list[tuple[float, ...]]) -> list[int]:
        x = np.asarray(rows, dtype=np.float64)
        big = np.argwhere(~(np.abs(x) <= MAX_PDW))
        if big.size:  # their squared distances would overflow to inf (HDBSCAN then never ends)
            i, j = map(int, big[0])
            name = ("toa", *DESCRIPTORS, "amplitude")[j]
            raise DeintError(f"the pulse at toa={float(x[i, 0])!r} has {name}={float(x[i, j])!r}; the pdw-* policies "
                             f"cluster TOAs and descriptors of magnitude up to {MAX_PDW:g}")
        p = PDWs(x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4] if self._amp else None)
        return self._to_labels(p, self.label_window(p)).tolist()

    # ---- labels across windows ---------------------------------------------------------------------
    def _to_labels(self, p: PDWs, clusters: Clusters) -> np.ndarray:
        w = self._windows
        self._windows += 1
        ids = clusters.ids
        out = np.full(ids.size, self.n_labels, dtype=np.int64)
        sizes = np.bincount(ids[ids >= 0], minlength=clusters.periods.size)
        order = np.argsort(-sizes, kind="stable")
        order = order[sizes[order] > 0]
        members = members_of(ids, clusters.periods.size)
        current: dict[int, Signature] = {}
        for c in order:
            idx = members[c]
            sig = signature(p, idx, clusters.periods[c])
            lab = self._continuing(sig, current)
            if lab is None:
                free = [j for j in range(self.n_labels) if j not in current]
                if not free:
                    continue  # over the label budget: spurious
                lab = min(free, key=lambda j: self._last_used[j])
            current[lab] = sig
            self._last_used[lab] = w
            out[idx] = lab
        self._previous = current
        return out

    def _continuing(self, sig: Signature, taken: dict[int, Signature]) -> int | None:
        """The label of the previous window's emitter nearest `sig` within the match tolerance."""
        best, best_d = None, 1.0
        for lab, old in self._previous.items():
            if lab in taken:
                continue
            d = _distance(old, sig)
            if d <= best_d:
                best, best_d = lab, d
        return best

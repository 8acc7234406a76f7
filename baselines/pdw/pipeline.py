"""`pdw-pipeline`: the classical EW deinterleaving pipeline on pulse descriptor words (Wiley, ELINT: The
Interception and Analysis of Radar Signals, 2006, ch. 12: sort on the slowly varying parameters, then
analyse the TOAs of each sort).

For each window (default the largest the env allows, 10001 pulses: lag 10000):

1. Parameter cells: HDBSCAN (scikit-learn's, in baselines/blind/density.py) on the frequency, pulse width
   and AoA (its plane: `aoa_plane`), each column centred on its median and divided by its interquartile
   range.  The amplitude is left out (it follows the antenna scan and the range, not the emitter).  A
   pulse HDBSCAN calls noise joins the nearest cell when it lies within 4 robust deviations of it in
   every column (a descriptor's noise tail), else it is spurious.
2. PRI analysis and sequence search within each cell (`baselines.blind.pipeline.deinterleave`: a PRI
   detector, the sequence search, re-association): a cell holding several emitters of like parameters
   is split into their trains, and pulses of no train are spurious (noise rejection).  The TOA noise
   is the priors' when stated, else measured once per window on the largest cell
   (`baselines.blind.noise.estimate_noise`; the receiver's noise is common to every emitter).
3. Agile emitters: cells whose AoAs agree within 4 combined deviations form a group (the AoA is the one
   descriptor an emitter does not change from pulse to pulse); the pulses of a group of several cells
   that no cell's train took are pooled and deinterleaved together (an emitter hopping frequency or
   pulse width pulse to pulse leaves each hop's cell only a share of its lattice).  Constant-PRI trains
   of one group with the same PRI (within 4 combined deviations of their line fits) on the same lattice
   (one train's first pulse where the other's fit predicts it, within 4 deviations) are one emitter
   (the hops of burst-to-burst agility), merged.  Modulated trains are never merged.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from baselines.blind.density import hdbscan
from baselines.blind.descriptors import standardised
from baselines.blind.detectors import CDIF, SDIF, PRITransform
from baselines.blind.noise import estimate_noise
from baselines.blind.pipeline import Detector, SearchParams, deinterleave
from baselines.blind.pri_models import LineFit, line_fit
from baselines.pdw.policy import (Clusters, PDWPolicy, PDWs, angle_difference, aoa_plane, circular_centre,
                                  members_of)
from baselines.windowed import MAX_WINDOW
from deint_env.params import Param, declare

DETECTORS: dict[str, type] = {"pri-transform": PRITransform, "cdif": CDIF, "sdif": SDIF}
_MAD = 1.4826
_GATE = 4.0  # deviations: a noise pulse's cell, cells alike, trains of one PRI and lattice


class Train(NamedTuple):
    pulses: np.ndarray  # window indices, time-ordered
    period: float  # NaN for a modulated train (never merged)
    fit: LineFit | None  # the constant train's lattice
    group: int  # its cells' group (AoA alike)


def cell_features(p: PDWs) -> np.ndarray:
    plane = aoa_plane(p.aoa)
    return standardised({"frequency": p.frequency, "pulse_width": p.pulse_width, "aoa_x": plane[:, 0],
                         "aoa_y": plane[:, 1]})


def attach_noise(z: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """HDBSCAN's noise pulses joined to the nearest cell that holds them within `_GATE` deviations in
    every column (-1 otherwise)."""
    m = int(ids.max()) + 1
    noise = np.flatnonzero(ids < 0)
    if m == 0 or noise.size == 0:
        return ids
    cells = [z[idx] for idx in members_of(ids, m)]
    centre = np.array([np.median(x, axis=0) for x in cells])
    spread = np.maximum([_MAD * np.median(np.abs(x - c), axis=0) for x, c in zip(cells, centre)], 1e-9)
    dev = np.abs(z[noise, None, :] - centre[None]) / spread[None]  # (noise, cells, columns)
    worst = dev.max(axis=2)
    near = worst.argmin(axis=1)
    out = ids.copy()
    ok = worst[np.arange(noise.size), near] <= _GATE
    out[noise[ok]] = near[ok]
    return out


def cell_groups(p: PDWs, members: list[np.ndarray]) -> np.ndarray:
    """A group number per cell: cells whose AoAs agree within `_GATE` combined deviations, joined
    transitively (connected components).  The AoA is the one descriptor an emitter cannot change from
    pulse to pulse: frequency and pulse-width agility both split an emitter into cells of one AoA."""
    aoa = np.array([circular_centre(p.aoa[idx]) for idx in members])
    s = np.array([_MAD * np.median(np.abs(angle_difference(p.aoa[idx], a))) for idx, a in zip(members, aoa)])
    alike = np.abs(angle_difference(aoa[:, None], aoa[None])) <= _GATE * np.hypot(s[:, None], s[None]) + 1e-9
    return _components(alike)


def _components(adj: np.ndarray) -> np.ndarray:
    """Connected components of a symmetric boolean adjacency matrix, numbered in order of first member."""
    n = adj.shape[0]
    comp = np.full(n, -1, dtype=np.int64)
    k = 0
    for s in range(n):
        if comp[s] >= 0:
            continue
        todo = [s]
        comp[s] = k
        while todo:
            nxt = np.flatnonzero(adj[todo].any(axis=0) & (comp < 0))
            comp[nxt] = k
            todo = nxt.tolist()
        k += 1
    return comp


def merge_trains(trains: list[Train], sigma: float) -> list[list[int]]:
    """Trains that are one emitter: constant trains of one group with the same PRI and lattice.  Each
    entry lists the trains of one emitter."""
    n = len(trains)
    const = np.array([tr.fit is not None for tr in trains], dtype=bool)
    fit = np.array([tr.fit if tr.fit is not None else (0.0, 1.0, 0.0, 0.0) for tr in trains]).reshape(n, 4)
    origin, period, period_std, resid = fit.T
    group = np.array([tr.group for tr in trains])
    alike = const[:, None] & const[None] & (group[:, None] == group[None])
    same_pri = np.abs(period[:, None] - period[None]) <= _GATE * np.hypot(period_std[:, None], period_std[None]) \
        + 1e-9 * period[:, None]
    gap = origin[None] - origin[:, None]  # [a, b]: b's first lattice point from a's
    k = np.round(gap / period[:, None])
    miss = np.abs(gap - k * period[:, None])
    on_lattice = miss <= _GATE * np.sqrt(resid[:, None] ** 2 + resid[None] ** 2 + sigma ** 2
                                         + (k * period_std[:, None]) ** 2)
    same = alike & same_pri & on_lattice
    comp = _components(same | same.T | np.eye(n, dtype=bool))
    return [np.flatnonzero(comp == c).tolist() for c in range(int(comp.max()) + 1 if n else 0)]


class PDWPipelinePolicy(PDWPolicy):
    """`pdw-pipeline`: parameter cells, PRI analysis within each, agile emitters' cells merged."""

    PARAMS = declare(
        Param("detector", str, "pri-transform", "the PRI detector run within each cell", choices=tuple(DETECTORS)),
        Param("min_pulses", int, 6, "the fewest pulses of a cell and of a train", low=3),
        Param("min_fill", float, 0.8, "the least share of a train's expected arrivals found", low=0, high=1,
              low_open=True),
        Param("max_miss", int, 3, "missed pulses the sequence search bridges", low=0, high=1000),
        Param("window", int, MAX_WINDOW, "pulses per batch (the lag is window - 1)", low=2, high=MAX_WINDOW))

    def __init__(self, detector: str = "pri-transform", min_pulses: int = 6, min_fill: float = 0.8,
                 max_miss: int = 3, window: int = MAX_WINDOW):
        self.PARAMS.check(locals())
        super().__init__(window)
        self.detector: Detector = DETECTORS[detector]()
        self.min_pulses, self.min_fill, self.max_miss = min_pulses, float(min_fill), max_miss

    def label_window(self, p: PDWs) -> Clusters:
        n = p.toa.size
        if n < self.min_pulses:
            return Clusters(np.full(n, -1, dtype=np.int64), np.zeros(0))
        z = cell_features(p)
        cells = attach_noise(z, hdbscan(z, self.min_pulses))
        m = int(cells.max()) + 1
        if m == 0:
            return Clusters(np.full(n, -1, dtype=np.int64), np.zeros(0))
        members = members_of(cells, m)
        groups = cell_groups(p, members)
        sigma = self._sigma(p.toa[max(members, key=len)])
        trains: list[Train] = []
        for c, idx in enumerate(members):
            trains += self._trains(p.toa, idx, sigma, int(groups[c]))
        free = cells >= 0
        for tr in trains:
            free[tr.pulses] = False
        for g in np.flatnonzero(np.bincount(groups) > 1):  # groups of several cells: agile emitters
            idx = np.flatnonzero(free & np.isin(cells, np.flatnonzero(groups == g)))
            trains += self._trains(p.toa, idx, sigma, int(g))
        ids = np.full(n, -1, dtype=np.int64)
        emitters = merge_trains(trains, sigma)
        periods = np.full(len(emitters), np.nan)
        for e, parts in enumerate(emitters):
            for i in parts:
                ids[trains[i].pulses] = e
            periods[e] = trains[parts[0]].period
        return Clusters(ids, periods)

    def _sigma(self, toa: np.ndarray) -> float:
        """The TOA noise: the priors', else measured on `toa` (floored at a thousandth of its median
        spacing, as `baselines.blind.policy` floors it)."""
        if self.priors.jitter_std > 0:
            return float(self.priors.jitter_std)
        floor = 1e-3 * float(np.median(np.diff(toa))) if toa.size > 1 else 1e-9
        est = estimate_noise(toa).walk
        return max(est, floor) if est > 0 else 10 * floor

    def _trains(self, toa: np.ndarray, idx: np.ndarray, sigma: float, group: int) -> list[Train]:
        """The trains the PRI analysis finds among pulses `idx`."""
        if idx.size < self.min_pulses:
            return []
        t = toa[idx]
        med = float(np.median(np.diff(t)))
        pri_max = max(min(float(t[-1] - t[0]) / self.min_pulses, 100 * med), 1e-9)
        pri_min = min(max(0.5 * med, 12 * sigma), 0.5 * pri_max)
        pr = self.priors
        params = SearchParams(sigma=sigma, pri_min=pri_min, pri_max=pri_max, min_pulses=self.min_pulses,
                              min_fill=self.min_fill, max_miss=self.max_miss,
                              missing_prob=float(np.nan_to_num(pr.missing_prob)),
                              spurious_rate=float(np.nan_to_num(pr.spurious_rate)))
        out = []
        for tr in deinterleave(t, self.detector, params).trains:
            if tr.pulses.size < self.min_pulses:
                continue
            fit = None
            if tr.model.kind == "constant":
                k = np.round((t[tr.pulses] - t[tr.pulses[0]]) / tr.model.period)
                fit = line_fit(t[tr.pulses], k)
            out.append(Train(idx[tr.pulses], tr.model.period if fit is not None else math.nan, fit, group))
        return out

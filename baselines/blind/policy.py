"""The blind deinterleavers as policies: windowed batch decisions with a declared lag.

A policy buffers `window` pulses (lag window - 1), deinterleaves the window as a batch when its last
pulse arrives (the last, shorter window at the first padding step) and emits the window's labels one
per step.  Trains are carried across windows: a train of a new window keeps the label of the previous
window's train whose PRI it matches and whose lattice its first pulse continues; otherwise it takes
the label least recently used (a new track: the link to its first pulse is "none" only if the label
is fresh, so at most one link is lost per re-used label).  Trains beyond the label budget are labelled
spurious (the smallest trains first).

Without a known TOA noise (priors.jitter_std = 0, e.g. `deint label` with no priors or a TDC file)
the noise is measured first, from the widths of the difference peaks (`noise.estimate_noise`), and
checked against the residuals of the trains found (`HistogramPolicy._label_unknown_noise`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from baselines.blind.density import dbscan
from baselines.blind.descriptors import standardised
from baselines.blind.detectors import CDIF, SDIF, PRITransform
from baselines.blind.noise import estimate_noise
from baselines.blind.pipeline import Deinterleaving, Detector, SearchParams, deinterleave
from baselines.blind.pri_models import line_fit
from baselines.windowed import MAX_WINDOW, WindowedPolicy
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable, check
from deint_env.params import Param, declare
from deint_env.modulation import PRIModel


# windows cost up to ~0.4 s per 1000 pulses (pri-transform; a smeared difference histogram, a second
# pass with the measured noise), so a record of a million pulses could take minutes: refused, with the
# reason, instead
MAX_PULSES = 100_000


WINDOW = Param("window", int, 1000, "pulses per batch (the lag is window - 1)", low=2, high=MAX_WINDOW)
PARAMS = declare(
    WINDOW,
    Param("align", bool, True, "re-associate the pulses to the trains' estimated schedules by MAP alignment "
          "(false: the papers' search alone)"),
    Param("pri_min", float, None, "the shortest PRI searched, in TOA units (none: from the data)", low=0,
          low_open=True, optional=True),
    Param("pri_max", float, None, "the longest PRI searched, above pri_min (none: from the data)", low=0,
          low_open=True, optional=True),
    Param("min_pulses", int, 6, "the fewest pulses a train has", low=3),
    Param("min_fill", float, 0.8, "the least share of a train's expected arrivals found", low=0, high=1,
          low_open=True),
    Param("max_miss", int, 3, "missed pulses the sequence search bridges", low=0, high=1000),
    Param("presort_eps", float, 0.3, "DBSCAN eps of the presort on pulse descriptors (standardised units)", low=0,
          low_open=True),
)


class BlindWindowPolicy(WindowedPolicy):
    """Base: windows of pulses (`WindowedPolicy`), labels carried across windows, estimates."""

    def __init__(self, window: int = 1000):
        WINDOW.validate(window)
        super().__init__(window)
        self._features: dict[str, np.ndarray] | None = None
        self._sigma_used = 0.0  # the TOA noise the last window was deinterleaved with

    def attach_features(self, features: dict[str, np.ndarray] | None) -> None:
        """Pulse descriptors besides TOA and amplitude (a TDC file's frequency, pulse width, angle of
        arrival) for the next episodes, one value per pulse; a window reads only its own pulses'."""
        self._features = None if not features else {k: np.asarray(v, dtype=np.float64) for k, v in
                                                     features.items()}

    def window_features(self, n: int) -> dict[str, np.ndarray]:
        """The attached descriptors of the window being labelled (its n pulses)."""
        if self._features is None:
            return {}
        done = self._seen - n
        return {k: v[done:done + n] for k, v in self._features.items()}

    # ---- to implement ------------------------------------------------------------------------------
    def label_window(self, toa: np.ndarray, amplitude: np.ndarray | None) -> Deinterleaving:
        raise NotImplementedError

    # ---- protocol ----------------------------------------------------------------------------------
    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if not priors.blind:
            raise NotApplicable("blind deinterleavers find their own trains: blind scenarios only (no prior tracks)")
        self.priors = priors
        self.n_labels = priors.n_labels
        n = info.get("n_pulses")
        if n is not None and n > MAX_PULSES:
            raise DeintError(f"the blind deinterleavers label at most {MAX_PULSES} pulses in one run (up to about "
                             f"0.4 ms a pulse); this record has {n}: split it into files of fewer pulses")
        if self._features is not None and n is not None:
            bad = [k for k, v in self._features.items() if v.shape != (n,)]
            if bad:
                raise DeintError(f"attached descriptor {bad[0]} has {self._features[bad[0]].size} values for an "
                                 f"episode of {n} pulses")
        self._amp = bool(info.get("has_amplitude", False))
        self._noise_estimate: float | None = None  # the TOA noise measured when the priors give none
        self._start()
        self._last_used = np.full(self.n_labels, -1, dtype=np.int64)  # window number of each label's last use
        self._tracks: list[tuple[PRIModel, float] | None] = [None] * self.n_labels  # (model, last pulse)
        self._phase = np.full(self.n_labels, np.nan)
        self._windows = 0
        self.trains_found = 0  # trains found in the last window (the whole episode when it fits one)
        self.trains_per_window: list[int] = []

    def _row(self, obs: dict[str, Any]) -> tuple[float, ...]:
        toa = float(obs["toa"][0])
        return (toa, float(obs["amplitude"][0])) if self._amp else (toa,)

    def estimates(self) -> dict[str, np.ndarray]:
        """Per label: the mean PRI of its last train and the arrival of its first pulse (NaN if unused)."""
        period = np.array([m[0].period if m is not None else np.nan for m in self._tracks])
        return {"period": period, "phase": self._phase.copy()}

    def modulations(self) -> list[PRIModel | None]:
        """Per label: the PRI model of its last train (None if the label was never used)."""
        return [m[0] if m is not None else None for m in self._tracks]

    # ---- windows -----------------------------------------------------------------------------------
    def _label_rows(self, rows: list[tuple[float, ...]]) -> list[int]:
        block = np.asarray(rows, dtype=np.float64)
        toa = block[:, 0]
        amp = block[:, 1] if self._amp else None
        return self._to_labels(toa, self.label_window(toa, amp)).tolist()

    def _to_labels(self, toa: np.ndarray, result: Deinterleaving) -> np.ndarray:
        w = self._windows
        self._windows += 1
        self.trains_found = len(result.trains)
        self.trains_per_window.append(self.trains_found)
        out = np.full(toa.size, self.n_labels, dtype=np.int64)
        order = sorted(range(len(result.trains)), key=lambda i: -result.trains[i].pulses.size)
        taken: set[int] = set()
        for i in order:
            train = result.trains[i]
            if train.pulses.size == 0:
                continue
            first = float(toa[train.pulses[0]])
            lab = self._continuing(train.model, first, taken)
            if lab is None:
                free = [j for j in range(self.n_labels) if j not in taken]
                if not free:
                    continue  # over the label budget: spurious
                lab = min(free, key=lambda j: self._last_used[j])
                self._phase[lab] = first
            taken.add(lab)
            self._last_used[lab] = w
            self._tracks[lab] = (train.model, float(toa[train.pulses[-1]]))
            out[train.pulses] = lab
        return out

    def _continuing(self, model: PRIModel, first: float, taken: set[int]) -> int | None:
        """The label whose previous train this one continues: same PRI, first pulse on its lattice."""
        sigma = self._sigma_used
        for j, track in enumerate(self._tracks):
            if track is None or j in taken or self._last_used[j] != self._windows - 2:
                continue
            old, last = track
            # (a one-pulse cluster has no period: it continues nothing)
            if not math.isfinite(old.period) or old.kind != model.kind \
                    or not abs(old.period - model.period) <= 0.01 * old.period + 4 * sigma:
                continue
            frame = old.period * max(len(old.levels), 1)
            steps = (first - last) / frame
            if old.kind != "constant" or abs(steps - round(steps)) * frame <= 4 * sigma + 0.002 * old.period * steps:
                return j
        return None


class HistogramPolicy(BlindWindowPolicy):
    """A PRI detector (CDIF, SDIF or the PRI transform), sequence search and re-association."""

    detector: Detector

    def __init__(self, window: int = 1000, align: bool = True, pri_min: float | None = None,
                 pri_max: float | None = None, min_pulses: int = 6, min_fill: float = 0.8, max_miss: int = 3,
                 presort_eps: float = 0.3):
        super().__init__(window)
        PARAMS.check(locals())
        check(pri_min is None or pri_max is None or pri_min < pri_max, "pri_min", pri_min,
              f"below pri_max={pri_max}")
        self.presort_eps = float(presort_eps)
        self.align = align
        self.pri_min, self.pri_max = pri_min, pri_max
        self.min_pulses, self.min_fill, self.max_miss = min_pulses, float(min_fill), int(max_miss)

    def _params(self, toa: np.ndarray, sigma: float) -> SearchParams:
        gaps = np.diff(toa)
        med = float(np.median(gaps)) if gaps.size else 1.0
        span = float(toa[-1] - toa[0]) if toa.size > 1 else 1.0
        pri_max = self.pri_max or max(min(span / self.min_pulses, 100 * med), 1e-9)
        pri_min = self.pri_min or min(max(0.5 * med, 12 * sigma), 0.5 * pri_max)
        pr = self.priors
        return SearchParams(sigma=sigma, pri_min=pri_min, pri_max=pri_max, min_pulses=self.min_pulses,
                            min_fill=self.min_fill, max_miss=self.max_miss,
                            # rates the priors leave unknown (NaN): re-associate as the genie does, with none
                            missing_prob=float(np.nan_to_num(pr.missing_prob)),
                            spurious_rate=float(np.nan_to_num(pr.spurious_rate)))

    def label_window(self, toa: np.ndarray, amplitude: np.ndarray | None) -> Deinterleaving:
        """Deinterleave by PRI; with attached descriptors (frequency, pulse width, angle of arrival),
        pulses are first pre-sorted into groups of like descriptors (DBSCAN, as an EW receiver sorts
        by RF and AOA before the TOA analysis) and each group is deinterleaved on its own."""
        feats = self.window_features(toa.size)
        if not feats:
            return self._label_toas(toa)
        ids = dbscan(standardised(feats), self.presort_eps, self.min_pulses)
        labels = np.full(toa.size, -1, dtype=np.int64)
        trains = []
        for g in np.unique(ids):
            idx = np.flatnonzero(ids == g)
            if idx.size < self.min_pulses:
                continue
            part = self._label_toas(toa[idx])
            for tr in part.trains:
                labels[idx[tr.pulses]] = len(trains)
                trains.append(tr._replace(pulses=idx[tr.pulses]))
        return Deinterleaving(labels, trains)

    def _label_toas(self, toa: np.ndarray) -> Deinterleaving:
        sigma = self.priors.jitter_std
        if sigma > 0:
            self._sigma_used = sigma
            return deinterleave(toa, self.detector, self._params(toa, sigma), align=self.align)
        return self._label_unknown_noise(toa)

    def _label_unknown_noise(self, toa: np.ndarray) -> Deinterleaving:
        """The TOA noise unknown (no priors file, a TDC file): measured from the difference peaks
        (`noise.estimate_noise`: one interval's deviation, white noise and PRI jitter together), the
        window deinterleaved with it, and once more with the spread of the residuals of the constant
        trains found when that is off by more than half (a peak widened by a modulated or chance
        train, or a record with no clean peak at all: then 1 % of the median pulse spacing first)."""
        gaps = np.diff(toa)
        # a thousandth of the spacing, and never below the TOAs' own precision (coincident pulses)
        floor = max(1e-3 * (float(np.median(gaps)) if gaps.size else 1.0), 1e-12 * (1.0 + float(np.abs(toa).max())))
        if self._noise_estimate is None:  # the receiver's noise: measured on the first window, kept after
            self._noise_estimate = estimate_noise(toa).walk
        est = self._noise_estimate
        sigma = max(est, floor) if est > 0 else 10 * floor
        result = deinterleave(toa, self.detector, self._params(toa, sigma), align=self.align)
        measured = self._measured_sigma(toa, result)
        if measured is not None and not 0.5 * sigma <= measured <= 2.0 * sigma:
            sigma = max(measured, floor)
            result = deinterleave(toa, self.detector, self._params(toa, sigma), align=self.align)
        self._sigma_used = sigma
        return result

    @staticmethod
    def _measured_sigma(toa: np.ndarray, first: Deinterleaving) -> float | None:
        res = []
        for tr in first.trains:
            if tr.model.kind != "constant" or tr.pulses.size < 6:
                continue
            t = toa[tr.pulses]
            k = np.round((t - t[0]) / tr.model.period)
            fit = line_fit(t, k)
            res.append(t - fit.origin - k * fit.period)
        if not res:
            return None
        r = np.concatenate(res)
        return float(1.4826 * np.median(np.abs(r - np.median(r)))) or None


class CDIFPolicy(HistogramPolicy):
    """`cdif`: Mardia's CDIF (1989) + sequence search."""

    PARAMS = CDIF.PARAMS.plus(*PARAMS)

    def __init__(self, x: float = 0.5, **kw: Any):
        super().__init__(**kw)
        self.detector = CDIF(x)


class SDIFPolicy(HistogramPolicy):
    """`sdif`: Milojevic & Popovic's SDIF (1992) + sequence search."""

    PARAMS = SDIF.PARAMS.plus(*PARAMS)

    def __init__(self, x: float = 0.1, k: float = 0.3, **kw: Any):
        super().__init__(**kw)
        self.detector = SDIF(x, k)


class PRITransformPolicy(HistogramPolicy):
    """`pri-transform`: Nishiguchi & Kobayashi's jitter-robust PRI transform (2000) + sequence search."""

    PARAMS = PRITransform.PARAMS.plus(*PARAMS)

    def __init__(self, eps: float = 0.01, alpha: float = 0.3, beta: float = 0.15, gamma: float = 4.0, **kw: Any):
        super().__init__(**kw)
        self.detector = PRITransform(eps, alpha, beta, gamma)

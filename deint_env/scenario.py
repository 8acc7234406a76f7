"""Scenario specifications: frozen, validated, JSON-serialisable descriptions of one kind of episode.

A `ScenarioSpec` fixes everything `simulate(spec, seed)` needs; the seed fixes the rest.  Fields that
may vary from episode to episode (a source's period, phase or amplitude) take either a number or a
`Range` drawn once per episode.  Every field is checked at construction and a bad one raises a
`DeintError` naming the field, the value and the allowed range.

Units are the user's: the MK94 scenarios use abstract time units, the CM00 ones milliseconds.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from deint_env.errors import DeintError, check
from deint_env.descriptor_spec import MAX_DESCRIPTOR, DescriptorSpec, ReceiverSpec  # noqa: F401 -- re-exported
from deint_env.spec_fields import Param, Range, _floats, _is_number, _number, _param, _param_low, _param_mean  # noqa: F401

MAX_SOURCES = 128  # the TSRD's scenes hold up to 90 emitters
MAX_MERGING_SOURCES = 64  # merged-pulse membership is a uint64 bit mask: merging scenes stop at 64
# One time scale per scenario (ScenarioSpec._check_time_scales): the published suites span periods
# 0.125-160, phases within 5 periods and jitter within 10 of the smallest period
MIN_PERIOD, MAX_PERIOD, MAX_PERIOD_RATIO = 1e-9, 1e12, 1e4
MAX_SAMPLES = 5e7  # a waveform front end's samples per episode (each is a Kalman step of the detector)
# A modulation's size: the agile trackers build tables of levels x levels and of a cycle's pulses (10^4
# levels asked for 7 GiB, a cycle of 10^18 pulses exabytes); the suites use at most 5 levels, 35-pulse dwells
MAX_LEVELS, MAX_CYCLE = 64, 10**6
MAX_DRIFT = 1e30  # a drifting PRI's step deviation (TOA units): the trackers square it over the period
# A waveform channel's coefficients: the detector's Kalman state has as many, stepped once per sample (DM89's
# channel has 5; 10^5 asked numpy for a 74.5 GiB matrix)
MAX_CHANNEL_TAPS = 16


MODULATIONS = ("constant", "stagger", "sliding", "sinusoidal", "drifting", "dwell_switch", "random_stagger")
SLIDING_REFERENCES = ("mean", "start")  # Modulation.relative_to
CYCLIC = ("stagger", "dwell_switch", "sliding")  # kinds whose cycle position `random_start` may draw


@dataclass(frozen=True)
class Modulation:
    """How a source's pulse repetition interval (PRI) moves from pulse to pulse.

    With n the source's own pulse index (PRI_n: the interval after pulse n), T its period (its mean
    PRI) and o the cycle position of its first pulse (0, or drawn per episode when `random_start`):
    - ``constant``: PRI_n = T.
    - ``stagger``: PRI_n = T * pattern[(n + o) mod m] / mean(pattern)  (m-position stagger).
    - ``dwell_switch``: PRI_n = T * pattern[j(n + o)] / w, j(p) the dwell holding position p mod sum(d)
      of a cycle of dwells d = `dwells` (pattern[j] held d_j pulses; empty: `cycle` pulses each) and
      w = sum_j d_j pattern[j] / sum_j d_j the pulse-weighted mean level.
    - ``sliding``: a saw-tooth sweep with ramp position r_n = ((n + o) mod cycle) / (cycle - 1):
      relative_to="mean": PRI_n = T * (1 + depth * (r_n - 1/2)), 0 < depth < 1 (depth relative to T);
      relative_to="start": PRI_n = T * (1 + depth * r_n) / (1 + depth / 2), any depth > 0 (depth
      relative to the ramp's first PRI, which is T / (1 + depth / 2): a ramp may span more than it).
    - ``sinusoidal``: PRI_n = T * (1 + depth * sin(2 pi n / cycle + psi)), psi drawn per episode
      (wobulation); the cycle (pulses) may be any number >= 2, not only a whole one.
    - ``random_stagger``: PRI_n = T * pattern[s_n] / sum_k pi_k pattern[k], the level s_n drawn at
      every pulse: i.i.d. with probabilities `probs` (empty: uniform), or a Markov chain with
      P(s_n = j | s_{n-1} = i) = transition[i][j] started from its stationary distribution pi.
    - ``drifting``: PRI_0 = T, PRI_{n+1} = alpha * PRI_n + drift_std * v_n, v_n ~ N(0, 1): the stochastic
      source of MK94 section II-C-2 (alpha in place of I in the (1,1) block of F, with G v_k != 0).
    """

    kind: str = "constant"
    pattern: tuple[float, ...] = ()
    depth: float = 0.0
    cycle: int | float = 0
    alpha: float = 1.0
    drift_std: float = 0.0
    probs: tuple[float, ...] = ()
    transition: tuple[tuple[float, ...], ...] = ()
    dwells: tuple[int, ...] = ()
    relative_to: str = "mean"
    random_start: bool = False

    def __post_init__(self) -> None:
        check(self.kind in MODULATIONS, "modulation.kind", self.kind, f"one of {', '.join(MODULATIONS)}")
        object.__setattr__(self, "pattern", _floats(self.pattern, "modulation.pattern"))
        for name in ("depth", "alpha", "drift_std"):
            object.__setattr__(self, name, _number(getattr(self, name), f"modulation.{name}"))
        k = self.kind
        levelled = ("stagger", "dwell_switch", "random_stagger")
        if k in levelled:
            check(2 <= len(self.pattern) <= MAX_LEVELS and min(self.pattern) > 0, "modulation.pattern", self.pattern,
                  f"{k} needs at least two (at most {MAX_LEVELS}) positive PRI multipliers")
        else:
            check(not self.pattern, "modulation.pattern", self.pattern, f"only {'/'.join(levelled)} take a pattern")
        self._check_levels()
        needs_cycle = k in ("sliding", "sinusoidal") or (k == "dwell_switch" and not self.dwells)
        if isinstance(self.cycle, np.integer):  # numpy's integers as the other fields take them
            object.__setattr__(self, "cycle", int(self.cycle))
        if k == "sinusoidal":  # a wobulation's cycle need not be whole; a whole float is stored as an int
            check(_is_number(self.cycle) and 2 <= self.cycle <= MAX_CYCLE, "modulation.cycle", self.cycle,
                  f"sinusoidal needs a number >= 2 and <= {MAX_CYCLE:.0e} (pulses per cycle, not necessarily whole)")
            if float(self.cycle).is_integer():
                object.__setattr__(self, "cycle", int(self.cycle))
        else:
            check(isinstance(self.cycle, int) and not isinstance(self.cycle, bool)
                  and (2 <= self.cycle <= MAX_CYCLE if needs_cycle else self.cycle == 0), "modulation.cycle",
                  self.cycle,
                  f"{k} needs " + (f"an integer >= 2 and <= {MAX_CYCLE:.0e} (pulses)" if needs_cycle else
                                   "0 (its dwells give the lengths)" if k == "dwell_switch" else "0"))
        check(self.relative_to in SLIDING_REFERENCES and (k == "sliding" or self.relative_to == "mean"),
              "modulation.relative_to", self.relative_to,
              f"one of {', '.join(SLIDING_REFERENCES)} (sliding only; other kinds leave it 'mean')")
        needs_depth = k in ("sliding", "sinusoidal")
        if k == "sliding" and self.relative_to == "start":
            check(0 < self.depth <= 100, "modulation.depth", self.depth,
                  "sliding relative_to='start' needs 0 < depth <= 100 (the ramp's span over its first PRI)")
        else:
            check(0 < self.depth < 1 if needs_depth else self.depth == 0, "modulation.depth", self.depth,
                  f"{k} needs " + ("0 < depth < 1" + (" (a deeper ramp: relative_to='start', depth relative to "
                                                     "the ramp's first PRI)" if k == "sliding" else "")
                                   if needs_depth else "0"))
        check(isinstance(self.random_start, bool) and (k in CYCLIC or not self.random_start),
              "modulation.random_start", self.random_start,
              f"true or false; true only for {', '.join(CYCLIC)} (sinusoidal always draws its phase)")
        if k == "drifting":
            check(0.9 <= self.alpha <= 1.1, "modulation.alpha", self.alpha, "0.9 <= alpha <= 1.1 (see also "
                  "ScenarioSpec: the period may change at most 100-fold over the episode)")
            check(0 <= self.drift_std <= MAX_DRIFT, "modulation.drift_std", self.drift_std,
                  f"a number in [0, {MAX_DRIFT:g}]")
        else:
            check(self.alpha == 1.0 and self.drift_std == 0.0, "modulation.alpha", (self.alpha, self.drift_std),
                  "alpha and drift_std are for kind='drifting' only")

    def _check_levels(self) -> None:
        """random_stagger's `probs` / `transition` and dwell_switch's `dwells`."""
        k, m = self.kind, len(self.pattern)
        object.__setattr__(self, "probs", _floats(self.probs, "modulation.probs"))
        check(isinstance(self.transition, (list, tuple)), "modulation.transition", self.transition,
              "a list of rows (lists of numbers)")
        object.__setattr__(self, "transition", tuple(_floats(row, "modulation.transition") for row in self.transition))
        check(isinstance(self.dwells, (list, tuple)) and all(
            isinstance(d, int) and not isinstance(d, bool) and d >= 1 for d in self.dwells)
            and sum(self.dwells) <= MAX_CYCLE, "modulation.dwells", self.dwells,
            f"a list of whole numbers of pulses >= 1, {MAX_CYCLE:.0e} in all at most")
        object.__setattr__(self, "dwells", tuple(self.dwells))
        if k != "random_stagger":
            for name in ("probs", "transition"):
                check(not getattr(self, name), f"modulation.{name}", getattr(self, name),
                      f"{name} is for kind='random_stagger' only")
        if k != "dwell_switch":
            check(not self.dwells, "modulation.dwells", self.dwells, "dwells are for kind='dwell_switch' only")
        elif self.dwells:
            check(len(self.dwells) == m and self.cycle == 0, "modulation.dwells", self.dwells,
                  f"one dwell per pattern level ({m}), with cycle left 0")
        if self.probs:
            check(len(self.probs) == m and min(self.probs) > 0 and abs(sum(self.probs) - 1) < 1e-6,
                  "modulation.probs", self.probs, f"{m} positive level probabilities summing to 1")
            check(not self.transition, "modulation.transition", self.transition,
                  "give probs (i.i.d. levels) or transition (a Markov chain), not both")
        if self.transition:
            p = np.array(self.transition) if all(len(r) == m for r in self.transition) else None
            check(p is not None and p.shape == (m, m) and (p >= 0).all() and np.allclose(p.sum(axis=1), 1, atol=1e-6),
                  "modulation.transition", self.transition,
                  f"a row-stochastic {m}x{m} matrix (rows: from level i, entries >= 0 summing to 1)")
            reach = np.linalg.matrix_power(np.eye(m) + (p > 0), m - 1)
            check(bool((reach > 0).all()), "modulation.transition", self.transition,
                  "an irreducible chain (every level reachable from every other), so its stationary "
                  "distribution, from which it starts, is unique")

    def level_probs(self) -> np.ndarray:
        """random_stagger: pi, the levels' long-run probabilities (probs, uniform, or the chain's
        stationary distribution: the left eigenvector of transition for eigenvalue 1)."""
        m = len(self.pattern)
        if self.transition:
            p = np.array(self.transition)
            a = np.vstack([p.T - np.eye(m), np.ones(m)])
            pi = np.linalg.lstsq(a, np.r_[np.zeros(m), 1.0], rcond=None)[0]
            return np.maximum(pi, 0.0) / np.maximum(pi, 0.0).sum()
        return np.array(self.probs) if self.probs else np.full(m, 1.0 / m)

    def level_ratios(self) -> np.ndarray:
        """The PRI of each pattern level over T: random_stagger's pattern / sum(pi pattern), dwell_switch's
        pattern / (its pulse-weighted mean), stagger's pattern / mean(pattern)."""
        pat = np.asarray(self.pattern, dtype=np.float64)
        if self.kind == "random_stagger":
            return pat / float(self.level_probs() @ pat)
        if self.kind == "dwell_switch" and self.dwells:
            d = np.asarray(self.dwells, dtype=np.float64)
            return pat / float(d @ pat / d.sum())
        return pat / np.mean(pat)

    @property
    def cycle_length(self) -> int:
        """Pulses in one cycle of a cyclic kind (stagger: m, dwell_switch: the dwells' sum, sliding: cycle)."""
        if self.kind == "stagger":
            return len(self.pattern)
        if self.kind == "dwell_switch":
            return sum(self.dwells) if self.dwells else self.cycle * len(self.pattern)
        return int(self.cycle)

    def sliding_depth(self) -> float:
        """The sliding ramp's peak-to-peak sweep over T (the `relative_to="mean"` depth of the same ramp)."""
        return self.depth / (1 + self.depth / 2) if self.relative_to == "start" else self.depth

    def min_ratio(self) -> float:
        """A lower bound of PRI_n / T over the deterministic part of the modulation."""
        if self.kind in ("stagger", "dwell_switch", "random_stagger"):
            if self.kind == "stagger" or not (self.dwells or self.kind == "random_stagger"):
                return min(self.pattern) / (sum(self.pattern) / len(self.pattern))
            return float(self.level_ratios().min())
        if self.kind == "sliding" and self.relative_to == "start":
            return 1.0 / (1.0 + self.depth / 2)  # the ramp's first PRI
        if self.kind in ("sliding", "sinusoidal"):
            return 1.0 - self.depth
        return 1.0  # drifting: a guess; the generator doubles its count when it falls short

@dataclass(frozen=True)
class SourceSpec:
    """One periodic pulse source.

    period: mean PRI T (number or Range).  phase: arrival time of the first scheduled pulse (number or
    Range; None = uniform in [0, period)).  amplitude / amplitude_std: mean emitted amplitude and its
    pulse-to-pulse fluctuation.  active: on-windows [start, stop) as fractions of the nominal episode
    duration H0 = n_pulses / sum_i(1/T_i); empty = always on; a last window with stop >= 1 stays open
    to the end of the episode (use windows for dropout and onset).  descriptors: its pulse
    descriptor words (frequency, pulse width, AoA, antenna scan; see DescriptorSpec), None: TOAs only.
    """

    period: Param
    phase: Param | None = None
    modulation: Modulation = field(default_factory=Modulation)
    amplitude: Param = 1.0
    amplitude_std: float = 0.0
    active: tuple[tuple[float, float], ...] = ()
    descriptors: DescriptorSpec | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "period", _param(self.period, "source.period", positive=True))
        if self.phase is not None:
            object.__setattr__(self, "phase", _param(self.phase, "source.phase"))
        if isinstance(self.modulation, dict):
            object.__setattr__(self, "modulation", _from_dict(Modulation, self.modulation, "modulation"))
        check(isinstance(self.modulation, Modulation), "source.modulation", self.modulation, "a Modulation")
        object.__setattr__(self, "amplitude", _param(self.amplitude, "source.amplitude", positive=True))
        object.__setattr__(self, "amplitude_std", _number(self.amplitude_std, "source.amplitude_std", 0.0))
        check(isinstance(self.active, (list, tuple)), "source.active", self.active, "a list of [start, stop] windows")
        windows = []
        for w in self.active:
            w = _floats(w, "source.active")
            check(len(w) == 2 and 0 <= w[0] < w[1], "source.active", self.active,
                  "a list of [start, stop] fractions of the nominal duration with 0 <= start < stop")
            windows.append(w)
        check(all(a[1] <= b[0] for a, b in zip(windows, windows[1:])), "source.active", self.active,
              "windows must be sorted and must not overlap")
        object.__setattr__(self, "active", tuple(windows))
        if isinstance(self.descriptors, dict):
            object.__setattr__(self, "descriptors", _from_dict(DescriptorSpec, self.descriptors, "descriptors"))
        check(self.descriptors is None or isinstance(self.descriptors, DescriptorSpec), "source.descriptors",
              self.descriptors, "a DescriptorSpec or null")


# DM89 section 4's fourth-order ARMA channel V(z) = B(z^-1) / A(z^-1), the front end's default.
DM89_CHANNEL = ((0.91003, -2.4203, 2.3408, -0.82997), (1.0, -3.3198, 4.5146, -2.9511, 0.79699))


@dataclass(frozen=True)
class WaveformSpec:
    """An optional waveform front end (docs/design.md section 8, DM89): the received pulses become spikes on a
    grid of `sample_period` (a pulse's amplitude is its spike's height; 1 without amplitudes), pass
    through the channel V(z) = numerator / denominator (default: DM89's fourth-order ARMA), get white
    noise of std `noise_std`, and are detected online by Dai & Mendel's detection-oriented Kalman
    filter.  The episode holds the detections: misses and false alarms come from detection.  The
    detector's spike probability per sample and spike spread default to the expected pulses per
    sample and the rms pulse amplitude (`spike_prob`, `spike_std` override them).
    """

    sample_period: float
    numerator: tuple[float, ...] = DM89_CHANNEL[0]
    denominator: tuple[float, ...] = DM89_CHANNEL[1]
    noise_std: float = 0.03
    spike_prob: float | None = None
    spike_std: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "sample_period", _number(self.sample_period, "waveform.sample_period", 0.0))
        check(self.sample_period > 0, "waveform.sample_period", self.sample_period, "must be > 0")
        for name in ("numerator", "denominator"):
            object.__setattr__(self, name, _floats(getattr(self, name), f"waveform.{name}"))
        check(1 <= len(self.numerator) <= MAX_CHANNEL_TAPS and any(self.numerator), "waveform.numerator",
              self.numerator, f"1 to {MAX_CHANNEL_TAPS} coefficients, at least one nonzero")
        check(1 <= len(self.denominator) <= MAX_CHANNEL_TAPS and self.denominator[0] != 0, "waveform.denominator",
              self.denominator, f"1 to {MAX_CHANNEL_TAPS} coefficients, the leading one != 0")
        object.__setattr__(self, "noise_std", _number(self.noise_std, "waveform.noise_std", 0.0))
        check(self.noise_std > 0, "waveform.noise_std", self.noise_std, "must be > 0 (the detector needs noise)")
        if self.spike_prob is not None:
            object.__setattr__(self, "spike_prob", _number(self.spike_prob, "waveform.spike_prob", 0.0, 1.0))
            check(0 < self.spike_prob < 1, "waveform.spike_prob", self.spike_prob, "0 < spike_prob < 1")
        if self.spike_std is not None:
            object.__setattr__(self, "spike_std", _number(self.spike_std, "waveform.spike_std", 0.0))
            check(self.spike_std > 0, "waveform.spike_std", self.spike_std, "must be > 0")

    @property
    def channel(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        return self.numerator, self.denominator


PRIOR_KINDS = ("explicit", "perturbed", "none")
MERGE_MODELS = ("received", "emission")  # ScenarioSpec.merge


@dataclass(frozen=True)
class PriorSpec:
    """What the policy is told before the first pulse (reset info "priors").

    kind="explicit": the papers' x_{1|0} and Sigma_{1|0}: `period`, `phase` (empty = phases unknown),
    `period_std`, `phase_std` (one value for all, or one per prior track).  There may be more prior
    tracks than true sources (MK94's PT run that assumes N=4 for three sources).
    kind="perturbed": from the truth, period_prior = T * period_bias * (1 + period_error * z) with
    z ~ N(0,1), phase_prior = phase + phase_error * T * z' (phase_error None = phases unknown).
    kind="none": nothing but the label budget (blind mode).
    `source_prob`: the a-priori source probabilities pi_i; empty = proportional to the true pulse
    rates 1/T_i (MK94 section IV-2: known relative frequencies).
    `modulation`: the priors name each source's PRI modulation (an emitter library's entry): its kind
    and the spec's parameters (pattern, depth, cycle, alpha, drift_std), never what an episode draws
    (a sinusoid's phase, a drift's path); phantom tracks of explicit priors name none.
    `descriptors` (perturbed priors of a scenario with pulse descriptors): the priors also hold each
    source's descriptor means and spreads, as an emitter library does: the episode's drawn centre
    frequency (plus its mean hop), pulse width (times its mean level) and initial AoA, with spreads
    from its jitter, hops, levels, drift over the episode and the receiver's measurement noise.
    """

    kind: str = "perturbed"
    period: tuple[float, ...] = ()
    phase: tuple[float, ...] = ()
    period_std: tuple[float, ...] = ()
    phase_std: tuple[float, ...] = ()
    period_error: float = 0.0
    period_bias: float = 1.0
    phase_error: float | None = 0.0
    source_prob: tuple[float, ...] = ()
    modulation: bool = False
    descriptors: bool = False

    def __post_init__(self) -> None:
        check(self.kind in PRIOR_KINDS, "priors.kind", self.kind, f"one of {', '.join(PRIOR_KINDS)}")
        for name in ("period", "phase", "period_std", "phase_std", "source_prob"):
            object.__setattr__(self, name, _floats(getattr(self, name), f"priors.{name}"))
        if self.kind == "explicit":
            n = len(self.period)
            check(n >= 1 and min(self.period) > 0, "priors.period", self.period,
                  "explicit priors need a positive period per prior track")
            check(len(self.phase) in (0, n), "priors.phase", self.phase, f"empty or {n} values")
            for name in ("period_std", "phase_std"):
                v = getattr(self, name)
                check(len(v) in (1, n) and min(v) > 0, f"priors.{name}", v, f"1 or {n} positive values")
            check(len(self.source_prob) in (0, n), "priors.source_prob", self.source_prob, f"empty or {n} values")
        else:
            for name in ("period", "phase", "period_std", "phase_std"):
                check(not getattr(self, name), f"priors.{name}", getattr(self, name),
                      f"only explicit priors list values")
        object.__setattr__(self, "period_error", _number(self.period_error, "priors.period_error", 0.0, 0.5))
        object.__setattr__(self, "period_bias", _number(self.period_bias, "priors.period_bias", 0.5, 2.0))
        check(self.phase_error is None or (_is_number(self.phase_error) and math.isfinite(self.phase_error)
                                           and self.phase_error >= 0),
              "priors.phase_error", self.phase_error, "None (phase unknown) or >= 0 (fraction of the period)")
        if self.source_prob:
            check(min(self.source_prob) > 0 and abs(sum(self.source_prob) - 1) < 1e-6, "priors.source_prob",
                  self.source_prob, "positive values summing to 1")
        check(isinstance(self.modulation, bool) and not (self.modulation and self.kind == "none"),
              "priors.modulation", self.modulation, "true or false (false for kind='none': blind priors name nothing)")
        check(isinstance(self.descriptors, bool) and not (self.descriptors and self.kind != "perturbed"),
              "priors.descriptors", self.descriptors, "true or false (true only for kind='perturbed', whose "
              "tracks are the sources)")


@dataclass(frozen=True)
class ScenarioSpec:
    """A kind of episode: the sources, the channel's impairments, the episode length and the priors.

    name: identifier (lower-case words joined by '-').  sources: the pulse sources.  n_pulses: episode
    length in received pulses.  toa_jitter_std: sigma_w, white Gaussian TOA measurement noise
    (non-cumulative).  pri_jitter_std: cumulative jitter, the std of each interval (arrival times
    random-walk).  missing_prob: each emitted pulse is independently lost with this probability.
    coincidence_resolution: a received pulse closer than this to its predecessor merges into it (the
    merged pulse keeps the earlier TOA and sums the amplitudes, MK94 section VI).  merge: what the
    resolution compares: "received" (default), the jittered TOAs, as a receiver resolves pulses; or
    "emission", the noise-free arrival times, as MK94 VI-A-2 and VI-B merge exactly simultaneous
    arrivals: such a run is received once, at the jittered TOA of its earliest arrival.  spurious_rate:
    expected spurious pulses per source pulse (a Poisson process of intensity
    spurious_rate * sum_i 1/T_i).  amplitudes: whether pulses carry an amplitude; amplitude_noise_std
    is its measurement noise.  priors: see PriorSpec.  blind: unknown number of sources and no priors;
    the action then names one of `label_budget` labels and is rewarded per link.  n_active: in blind
    mode, the number of sources (the first k of `sources`) drawn per episode from [lo, hi].
    waveform: an optional DM89 front end (see WaveformSpec): n_pulses pulses enter the receiver and
    the episode holds what the detector makes of them.  receiver: the receiver of a scenario whose
    sources carry pulse descriptor words (see ReceiverSpec; None with descriptors: a staring receiver
    without threshold or measurement noise).  Descriptors are all or none: every source has them or
    none does, and they need amplitudes=true.
    """

    name: str
    sources: tuple[SourceSpec, ...]
    n_pulses: int
    toa_jitter_std: float = 0.0
    pri_jitter_std: float = 0.0
    missing_prob: float = 0.0
    coincidence_resolution: float = 0.0
    merge: str = "received"
    spurious_rate: float = 0.0
    amplitudes: bool = False
    amplitude_noise_std: float = 0.0
    priors: PriorSpec = field(default_factory=PriorSpec)
    blind: bool = False
    label_budget: int = 0
    n_active: tuple[int, int] | None = None
    waveform: WaveformSpec | None = None
    receiver: ReceiverSpec | None = None
    description: str = ""

    def __post_init__(self) -> None:
        check(isinstance(self.name, str) and 0 < len(self.name) <= 80
              and all(c.isalnum() or c in "-_." for c in self.name), "name", self.name,
              "1-80 characters of letters, digits, '-', '_', '.'")
        check(isinstance(self.sources, (list, tuple)), "sources", self.sources, "a list of sources")
        srcs = tuple(_from_dict(SourceSpec, s, "source") if isinstance(s, dict) else s for s in self.sources)
        check(1 <= len(srcs) <= MAX_SOURCES and all(isinstance(s, SourceSpec) for s in srcs), "sources",
              len(srcs), f"1 to {MAX_SOURCES} SourceSpec entries")
        object.__setattr__(self, "sources", srcs)
        check(isinstance(self.n_pulses, int) and not isinstance(self.n_pulses, bool)
              and 1 <= self.n_pulses <= 10_000_000, "n_pulses", self.n_pulses, "an integer in [1, 10^7]")
        for name in ("amplitudes", "blind"):
            check(isinstance(getattr(self, name), bool), name, getattr(self, name), "must be true or false")
        check(isinstance(self.description, str), "description", self.description, "must be a string")
        for name, hi in (("toa_jitter_std", math.inf), ("pri_jitter_std", math.inf), ("missing_prob", 0.9),
                         ("coincidence_resolution", math.inf), ("spurious_rate", 10.0),
                         ("amplitude_noise_std", MAX_DESCRIPTOR)):
            v = getattr(self, name)
            check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 <= v <= hi,
                  name, v, f"a number in [0, {hi}]")
            object.__setattr__(self, name, float(v))
        check(self.merge in MERGE_MODELS, "merge", self.merge, f"one of {', '.join(MERGE_MODELS)}")
        check(self.merge == "received" or self.coincidence_resolution > 0, "merge", self.merge,
              "'emission' needs a coincidence_resolution > 0 (how close noise-free arrivals merge)")
        self._check_time_scales(srcs)
        min_period = min(_param_low(s.period) * s.modulation.min_ratio() for s in srcs)
        check(self.pri_jitter_std <= min_period / 3, "pri_jitter_std", self.pri_jitter_std,
              f"at most a third of the smallest PRI ({min_period:g}) so intervals stay positive")
        # a drifting period shrinks as alpha^n (<= 100-fold, below) and random-walks: allow 6 sigma of
        # the walk, down to the generator's clip at 5 % of the period
        shrunk = min([max(0.05, min(1.0, s.modulation.alpha) ** self.n_pulses) * _param_low(s.period)
                      - 6 * s.modulation.drift_std * math.sqrt(self.n_pulses)
                      for s in srcs if s.modulation.kind == "drifting"] + [min_period])
        shrunk = max(shrunk, 0.05 * min(_param_low(s.period) for s in srcs))
        check(self.coincidence_resolution < min(min_period, shrunk) / 2, "coincidence_resolution",
              self.coincidence_resolution, f"below half the smallest PRI ({min(min_period, shrunk):g}), or a "
              "source would merge with itself")
        for s in srcs:  # alpha^n over a source's <= n_pulses pulses: keep the period within 100x
            if s.modulation.kind == "drifting":
                check(abs(math.log(s.modulation.alpha)) * self.n_pulses <= math.log(100.0), "modulation.alpha",
                      s.modulation.alpha, f"the period may change at most 100-fold over {self.n_pulses} pulses: "
                      f"|ln alpha| * n_pulses <= ln 100")
        check(self.amplitudes or self.amplitude_noise_std == 0, "amplitude_noise_std", self.amplitude_noise_std,
              "needs amplitudes=true")
        if isinstance(self.waveform, dict):
            object.__setattr__(self, "waveform", _from_dict(WaveformSpec, self.waveform, "waveform"))
        check(self.waveform is None or isinstance(self.waveform, WaveformSpec), "waveform", self.waveform,
              "a WaveformSpec or null")
        if self.waveform is not None:  # the front end walks every sample of the episode: bound how many
            highs = [src.period.high if isinstance(src.period, Range) else src.period for src in srcs]
            samples = self.n_pulses * max(highs) / len(srcs) / self.waveform.sample_period
            check(samples <= MAX_SAMPLES, "waveform.sample_period", self.waveform.sample_period,
                  f"at least {self.n_pulses * max(highs) / len(srcs) / MAX_SAMPLES:.3g}: {self.n_pulses} pulses "
                  f"of periods up to {max(highs):g} would need ~{samples:.3g} samples (at most {MAX_SAMPLES:.0e})")
        if isinstance(self.priors, dict):
            object.__setattr__(self, "priors", _from_dict(PriorSpec, self.priors, "priors"))
        check(isinstance(self.priors, PriorSpec), "priors", self.priors, "a PriorSpec")
        self._check_descriptors(srcs)
        always = len(srcs)  # the sources every episode plays
        if self.blind:
            check(self.priors.kind == "none", "priors.kind", self.priors.kind, "blind scenarios take kind='none'")
            check(isinstance(self.label_budget, int) and not isinstance(self.label_budget, bool)
                  and len(srcs) <= self.label_budget <= 256, "label_budget",
                  self.label_budget, f"an integer in [{len(srcs)}, 256] (at least the number of sources)")
            if self.n_active is not None:
                na = self.n_active
                check(isinstance(na, (list, tuple)) and len(na) == 2 and all(
                    isinstance(v, int) and not isinstance(v, bool) for v in na) and 1 <= na[0] <= na[1] <= len(srcs),
                    "n_active", na, f"[lo, hi] integers with 1 <= lo <= hi <= {len(srcs)}")
                object.__setattr__(self, "n_active", (int(na[0]), int(na[1])))
                always = self.n_active[0]
        else:
            check(self.priors.kind != "none", "priors.kind", self.priors.kind,
                  "anchored scenarios need explicit or perturbed priors")
            check(self.label_budget == 0 and self.n_active is None, "label_budget", self.label_budget,
                  "label_budget and n_active are for blind scenarios")
            if self.priors.kind == "explicit":
                check(len(self.priors.period) >= len(srcs), "priors.period", self.priors.period,
                      f"at least one prior track per source ({len(srcs)})")
            if self.priors.kind == "perturbed":
                check(not self.priors.source_prob or len(self.priors.source_prob) == len(srcs),
                      "priors.source_prob", self.priors.source_prob, f"{len(srcs)} values")
        check(any(not s.active or s.active[-1][1] >= 1.0 for s in srcs[:always]), "source.active",
              [list(map(list, s.active)) for s in srcs[:always]],
              "a source every episode plays must stay on to the end (no windows, or a last window with stop >= 1)")

    def _check_descriptors(self, srcs: tuple[SourceSpec, ...]) -> None:
        """Descriptors all or none (one observation layout per scenario), the receiver with them, and
        merging only where the membership bit mask holds every source."""
        if isinstance(self.receiver, dict):
            object.__setattr__(self, "receiver", _from_dict(ReceiverSpec, self.receiver, "receiver"))
        check(self.receiver is None or isinstance(self.receiver, ReceiverSpec), "receiver", self.receiver,
              "a ReceiverSpec or null")
        has = [s.descriptors is not None for s in srcs]
        check(all(has) or not any(has), "source.descriptors", f"{sum(has)} of {len(srcs)} sources",
              "every source or none (one observation layout per scenario)")
        check(any(has) or not self.priors.descriptors, "priors.descriptors", self.priors.descriptors,
              "false: the sources have no pulse descriptors")
        if any(has):
            check(self.amplitudes, "amplitudes", self.amplitudes, "true: a pulse descriptor word carries an amplitude")
            check(self.waveform is None, "waveform", self.waveform, "null: the waveform front end keeps TOAs only")
        else:
            check(self.receiver is None, "receiver", self.receiver, "null: a receiver needs sources with descriptors")
        merges = self.coincidence_resolution > 0 or self.waveform is not None
        check(not merges or len(srcs) <= MAX_MERGING_SOURCES, "sources", len(srcs),
              f"at most {MAX_MERGING_SOURCES} where pulses merge (coincidence_resolution > 0 or a waveform front "
              f"end): a merged pulse's sources are a 64-bit mask")

    @property
    def has_descriptors(self) -> bool:
        return self.sources[0].descriptors is not None

    def _check_time_scales(self, srcs: tuple[SourceSpec, ...]) -> None:
        """Periods, phases and jitter on one time scale: the simulator sizes each source's schedule by the
        horizon over its period, so a period of 1e-300 beside one of 10 (or a phase of 1e300) would ask
        for an astronomically long schedule instead of failing here with one line."""
        lows = [_param_low(s.period) for s in srcs]
        highs = [s.period.high if isinstance(s.period, Range) else s.period for s in srcs]
        for v in lows + highs:
            check(MIN_PERIOD <= v <= MAX_PERIOD, "source.period", v, f"in [{MIN_PERIOD:g}, {MAX_PERIOD:g}] (TOA units)")
        check(max(highs) <= MAX_PERIOD_RATIO * min(lows), "source.period", [min(lows), max(highs)],
              f"periods within a factor {MAX_PERIOD_RATIO:g} of one another (one time scale per scenario)")
        for s in srcs:
            if s.phase is not None:
                lo, hi = (s.phase.low, s.phase.high) if isinstance(s.phase, Range) else (s.phase, s.phase)
                check(max(abs(lo), abs(hi)) <= MAX_PERIOD_RATIO * max(highs), "source.phase", s.phase,
                      f"within {MAX_PERIOD_RATIO:g} times the largest period ({max(highs):g}) of 0; a late start is "
                      "an `active` window")
        check(self.toa_jitter_std <= MAX_PERIOD_RATIO * max(highs), "toa_jitter_std", self.toa_jitter_std,
              f"at most {MAX_PERIOD_RATIO:g} times the largest period ({max(highs):g})")

    # ---- derived -------------------------------------------------------------------------------
    @property
    def n_labels(self) -> int:
        """Labels other than 'spurious': the prior tracks (anchored) or the label budget (blind)."""
        if self.blind:
            return self.label_budget
        if self.priors.kind == "explicit":
            return len(self.priors.period)
        return len(self.sources)

    @property
    def spurious_label(self) -> int:
        return self.n_labels

    @property
    def mean_rate(self) -> float:
        """Expected source pulses per unit time (all sources on), from the mean periods."""
        return float(sum(1.0 / _param_mean(s.period) for s in self.sources))

    # ---- serialisation ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; fields at their default are left out so new fields keep old hashes."""
        return _to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScenarioSpec:
        return _from_dict(cls, d, "scenario")

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @property
    def content_hash(self) -> str:
        return hashlib.sha256(self.to_json().encode()).hexdigest()[:16]

    def replace(self, **changes: Any) -> ScenarioSpec:
        return dataclasses.replace(self, **changes)


def _to_dict(obj: Any) -> Any:
    if isinstance(obj, Range):
        return {"low": obj.low, "high": obj.high, **({"log": True} if obj.log else {})}
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in fields(obj):
            v = getattr(obj, f.name)
            default = f.default if f.default is not dataclasses.MISSING else (
                f.default_factory() if f.default_factory is not dataclasses.MISSING else dataclasses.MISSING)
            if default is not dataclasses.MISSING and v == default:
                continue
            out[f.name] = _to_dict(v)
        return out
    if isinstance(obj, tuple):
        return [_to_dict(v) for v in obj]
    return obj


def _from_dict(cls: type, d: Any, what: str) -> Any:
    if not isinstance(d, dict):
        raise DeintError(f"{what} must be a JSON object, got {type(d).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise DeintError(f"{what} field {unknown[0]!r} is unknown; allowed: {', '.join(sorted(names))}")
    kwargs = dict(d)
    if cls is ScenarioSpec and "sources" in kwargs:
        check(isinstance(kwargs["sources"], (list, tuple)), "sources", kwargs["sources"], "a list of sources")
        kwargs["sources"] = tuple(kwargs["sources"])
    if cls is ScenarioSpec and isinstance(kwargs.get("n_active"), list):
        kwargs["n_active"] = tuple(kwargs["n_active"])
    if cls is SourceSpec and "active" in kwargs:
        check(isinstance(kwargs["active"], (list, tuple)), "source.active", kwargs["active"], "a list of windows")
        kwargs["active"] = tuple(tuple(w) if isinstance(w, list) else w for w in kwargs["active"])
    missing = [f.name for f in fields(cls) if f.name not in kwargs and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:  # said here: the TypeError would name Python's __init__ and its positional arguments
        raise DeintError(f"{what}: field {missing[0]!r} is required; required: {', '.join(missing)}")
    try:
        return cls(**kwargs)
    except TypeError as e:
        raise DeintError(f"{what}: {e}") from None

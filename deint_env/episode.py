"""What an episode is made of: the received pulses, the truth behind them and the public priors."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deint_env.errors import DeintError, shown


DESCRIPTORS = ("frequency", "pulse_width", "aoa")  # Episode's optional pulse descriptor arrays
# Priors' emitter library: each descriptor's per-track mean and spread (MHz, us, degrees)
LIBRARY = ("frequency", "frequency_std", "pulse_width", "pulse_width_std", "aoa", "aoa_std")
SCALARS = ("jitter_std", "pri_jitter_std", "missing_prob", "spurious_rate", "coincidence_resolution")
RATES = ("missing_prob", "spurious_rate")  # NaN = unknown (a policy estimates it), distinct from 0
DEFAULT_WIDTH_REL = 0.05  # a priors file's unstated period and phase deviations: this fraction of each period
# Numbers a priors file may hold, in any time unit: the trackers square and multiply them (a jitter of
# 1e200 overflowed to a traceback in seven policies; a period of 5e-324 has no finite rate), and 1e30
# leaves room for fourth powers while spanning seconds to picoseconds.
MAX_MAGNITUDE, MIN_POSITIVE = 1e30, 1e-30


@dataclass(frozen=True, eq=False)
class Priors:
    """The public priors handed to a policy at reset: never the truth.

    Arrays have one entry per prior track (label 0..n_labels-1); an unknown phase is NaN.  The jitters
    and the coincidence resolution are treated as known, as in the papers.  The missing and spurious
    rates may be unknown (NaN): a priors file that does not state them (or states null) leaves them
    unknown, not zero; simulated episodes state their true rates.
    `spurious_rate` is in spurious pulses per source pulse.  `modulation` (None: not given) names
    each track's PRI modulation where the priors know it (`PriorSpec.modulation`): its kind and its
    deterministic parameters, never an episode's own draws (a sinusoid's phase, a drift's path).
    `frequency` (MHz), `pulse_width` (us), `aoa` (degrees) and their `_std`s (None: not given): each
    track's pulse descriptor means and spreads, as an emitter library states them.
    """

    n_labels: int
    blind: bool = False
    period: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phase: np.ndarray = field(default_factory=lambda: np.zeros(0))
    period_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phase_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    source_prob: np.ndarray = field(default_factory=lambda: np.zeros(0))
    jitter_std: float = 0.0
    pri_jitter_std: float = 0.0
    missing_prob: float = 0.0
    spurious_rate: float = 0.0
    coincidence_resolution: float = 0.0
    amplitude: np.ndarray | None = None
    amplitude_std: np.ndarray | None = None
    modulation: tuple[Any, ...] | None = None  # per track a `scenario.Modulation` or None (not named)
    frequency: np.ndarray | None = None
    frequency_std: np.ndarray | None = None
    pulse_width: np.ndarray | None = None
    pulse_width_std: np.ndarray | None = None
    aoa: np.ndarray | None = None
    aoa_std: np.ndarray | None = None

    @property
    def spurious_label(self) -> int:
        return self.n_labels

    @property
    def phase_known(self) -> np.ndarray:
        return np.isfinite(self.phase)

    def as_info(self) -> dict[str, Any]:
        """A fresh dict of fresh arrays (Gymnasium's checker forbids sharing data between calls)."""
        out: dict[str, Any] = {"n_labels": self.n_labels, "blind": self.blind}
        for name in ("period", "phase", "period_std", "phase_std", "source_prob"):
            out[name] = np.array(getattr(self, name), dtype=np.float64)
        for name in SCALARS:
            out[name] = float(getattr(self, name))
        if self.amplitude is not None:
            out["amplitude"] = np.array(self.amplitude, dtype=np.float64)
            out["amplitude_std"] = np.array(self.amplitude_std, dtype=np.float64)
        if self.modulation is not None:
            out["modulation"] = _modulation_json(self.modulation)
        for name in LIBRARY:
            if getattr(self, name) is not None:
                out[name] = np.array(getattr(self, name), dtype=np.float64)
        return out

    @classmethod
    def from_info(cls, info: dict[str, Any]) -> Priors:
        if not isinstance(info, Mapping):  # a list has no .get: an AttributeError
            raise DeintError(f"priors: info={shown(info)} is invalid: a mapping of the env's info fields")
        n, blind = info.get("n_labels"), info.get("blind", False)
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
            raise DeintError(f"priors: n_labels={n!r} must be an integer >= 1")
        if not isinstance(blind, (bool, np.bool_)):
            raise DeintError(f"priors: blind={blind!r} must be true or false")
        kw = {k: info[k] for k in ("n_labels", "blind", *SCALARS) if k in info}
        for k in ("period", "phase", "period_std", "phase_std", "source_prob", "amplitude", "amplitude_std", *LIBRARY):
            if info.get(k) is not None:
                try:
                    kw[k] = np.asarray(info[k], dtype=np.float64)
                except (TypeError, ValueError):
                    raise DeintError(f"priors: {k}={shown(info[k])} must be an array of numbers") from None
        if "period" in kw and not np.all(kw["period"] > 0):  # a NaN period would reach every policy
            raise DeintError(f"priors: period={shown(kw['period'].tolist())} must be positive numbers")
        if info.get("modulation") is not None:
            kw["modulation"] = _parse_modulation(info["modulation"], int(info["n_labels"]), "priors")
        return cls(**kw)

    # ---- the priors file of docs/design.md section 7 --------------------------------------------
    def known_scalars(self) -> dict[str, float]:
        """The scalars, unknown rates left out."""
        return {k: getattr(self, k) for k in SCALARS if not (k in RATES and math.isnan(getattr(self, k)))}

    def to_json_dict(self) -> dict[str, Any]:
        """`{"period": [...], "phase": [...], "jitter_std": s, ...}`; unknown phases and rates are left out."""
        if self.blind:
            return {"blind": True, "label_budget": self.n_labels, **self.known_scalars()}
        out: dict[str, Any] = {"period": self.period.tolist()}
        if np.all(np.isfinite(self.phase)):
            out["phase"] = self.phase.tolist()
            out["phase_std"] = self.phase_std.tolist()
        out.update(period_std=self.period_std.tolist(), source_prob=self.source_prob.tolist(),
                   **self.known_scalars())
        if self.amplitude is not None:
            out["amplitude"] = self.amplitude.tolist()
            out["amplitude_std"] = self.amplitude_std.tolist()
        if self.modulation is not None:
            out["modulation"] = _modulation_json(self.modulation)
        for name in LIBRARY:
            if getattr(self, name) is not None:
                out[name] = getattr(self, name).tolist()
        return out

    @classmethod
    def from_json_dict(cls, d: Any, where: str = "priors") -> Priors:
        """Parse and validate a priors file; every problem is one `DeintError` line."""
        if not isinstance(d, dict):
            raise DeintError(f"{where}: must be a JSON object with at least 'period'")
        allowed = {"period", "phase", "period_std", "phase_std", "source_prob", "amplitude", "amplitude_std",
                   "modulation", "blind", "label_budget", *SCALARS, *LIBRARY}
        unknown = sorted(set(d) - allowed)
        if unknown:
            raise DeintError(f"{where}: key {unknown[0]!r} is unknown; allowed: {', '.join(sorted(allowed))}")

        def scalar(key: str, default: float, lo: float = 0.0, hi: float = math.inf) -> float:
            if key in RATES and d.get(key) is None:
                return math.nan  # not stated (or null): unknown
            v = d.get(key, default)
            hi = min(hi, MAX_MAGNITUDE)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not (lo <= v <= hi):
                unknown_ok = " or null (unknown)" if key in RATES else ""
                raise DeintError(f"{where}: {key}={v!r} must be a number in [{lo}, {hi}]{unknown_ok}")
            return float(v)

        def _scalars() -> dict[str, float]:
            return {"jitter_std": scalar("jitter_std", 0.0), "pri_jitter_std": scalar("pri_jitter_std", 0.0),
                    "missing_prob": scalar("missing_prob", 0.0, hi=0.9),
                    "spurious_rate": scalar("spurious_rate", 0.0, hi=10.0),
                    "coincidence_resolution": scalar("coincidence_resolution", 0.0)}

        blind = d.get("blind", False)
        if not isinstance(blind, bool):  # "false", "yes" and 1 are not JSON booleans (and "false" is truthy)
            raise DeintError(f"{where}: blind={blind!r} must be true or false")
        if blind:
            tracks = sorted(set(d) - {"blind", "label_budget", *SCALARS})
            if tracks:  # blind priors have no tracks: a period or phase here would be silently dropped
                raise DeintError(f"{where}: {tracks[0]} is for anchored priors; blind priors (\"blind\": true) take "
                                 f"label_budget and {', '.join(SCALARS)} only")
            budget = d.get("label_budget")
            if type(budget) is not int or not 1 <= budget <= 256:
                raise DeintError(f"{where}: label_budget={budget!r} must be an integer in [1, 256]")
            return cls(n_labels=budget, blind=True, **_scalars())
        if "label_budget" in d:
            raise DeintError(f"{where}: label_budget is for blind priors (\"blind\": true); anchored priors have "
                             f"one label per period")

        def vector(key: str, n: int | None, positive: bool) -> np.ndarray | None:
            if key not in d:
                return None
            v = d[key]
            ok = isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
            arr = np.asarray(v, dtype=np.float64) if ok else None
            if arr is None or not np.all(np.abs(arr) <= MAX_MAGNITUDE) or (positive and np.any(arr < MIN_POSITIVE)) \
                    or (n is not None and arr.size != n) or arr.size == 0:
                want = f"{n} " if n is not None else ""
                raise DeintError(f"{where}: {key} must be a list of {want}{'positive ' if positive else ''}numbers of "
                                 f"size in [{MIN_POSITIVE if positive else 0:g}, {MAX_MAGNITUDE:g}], got {shown(v)}")
            return arr

        period = vector("period", None, True)
        if period is None:
            raise DeintError(f"{where}: 'period' (a list of the sources' periods) is required")
        n = period.size
        phase = vector("phase", n, False)
        period_std = vector("period_std", n, True)
        phase_std = vector("phase_std", n, True)
        prob = vector("source_prob", n, True)
        if prob is not None and abs(prob.sum() - 1) > 1e-6:
            raise DeintError(f"{where}: source_prob must sum to 1, got {prob.sum():g}")
        amplitude = vector("amplitude", n, True)
        amplitude_std = vector("amplitude_std", n, True)
        for spread, mean in (("phase_std", phase), ("amplitude_std", amplitude)):
            if spread in d and mean is None:  # a spread without its mean would be silently dropped
                raise DeintError(f"{where}: {spread} needs {spread[:-4]} (the means it is the spread of)")
        library = {}
        for name in LIBRARY[::2]:  # each descriptor's mean and spread come together
            mean, std = vector(name, n, name != "aoa"), vector(f"{name}_std", n, True)
            if (mean is None) != (std is None):
                raise DeintError(f"{where}: {name} and {name}_std go together (a track's mean and its spread); "
                                 f"got only {name if std is None else name + '_std'}")
            if name == "aoa" and mean is not None and not np.all((mean >= 0) & (mean <= 360)):
                raise DeintError(f"{where}: aoa must be degrees in [0, 360], got {mean.tolist()!r}"[:300])
            library.update({name: mean, f"{name}_std": std})
        rate = 1.0 / period
        return cls(
            n_labels=n,
            period=period,
            phase=phase if phase is not None else np.full(n, np.nan),
            period_std=period_std if period_std is not None else DEFAULT_WIDTH_REL * period,
            phase_std=phase_std if phase_std is not None else (DEFAULT_WIDTH_REL * period if phase is not None
                                                               else np.full(n, np.nan)),
            source_prob=prob if prob is not None else rate / rate.sum(),
            amplitude=amplitude,
            amplitude_std=amplitude_std if amplitude_std is not None else (
                None if amplitude is None else 0.1 * amplitude),
            modulation=None if d.get("modulation") is None else _parse_modulation(d["modulation"], n, where),
            **library,
            **_scalars(),
        )


def _modulation_json(modulation: tuple[Any, ...]) -> list[dict[str, Any] | None]:
    from deint_env.scenario import _to_dict

    return [None if m is None else {"kind": m.kind, **_to_dict(m)} for m in modulation]


def _parse_modulation(value: Any, n: int, where: str) -> tuple[Any, ...]:
    """`modulation`: a list of one entry per track, each null (not named) or a modulation object as in
    a scenario file (`{"kind": "stagger", "pattern": [1, 1.5]}`; kinds and fields of
    `deint_env.scenario.Modulation`)."""
    from deint_env.scenario import Modulation, _from_dict

    if not isinstance(value, list) or len(value) != n:
        raise DeintError(f"{where}: modulation must be a list of {n} entries (one per track: null or an object "
                         f"like {{\"kind\": \"stagger\", \"pattern\": [1, 1.5]}}), got {value!r}")
    out = []
    for m in value:
        if m is None or isinstance(m, Modulation):
            out.append(m)
            continue
        try:
            out.append(_from_dict(Modulation, m, "modulation"))
        except DeintError as e:
            raise DeintError(f"{where}: {e}") from None
    return tuple(out)


@dataclass(frozen=True, eq=False)
class Truth:
    """The truth behind an episode (for scoring and for oracle policies only).

    Per true source i: the period T_i drawn for this episode, the phase (first scheduled arrival), the
    PRI in force at the end of the episode, and how many received pulses it contributed to.  The
    schedule is every emission before TOA measurement noise, missing pulses and merging: grouped by
    source (rows schedule_offsets[i]:schedule_offsets[i+1]), time-ordered within a source.
    """

    period: np.ndarray
    phase: np.ndarray
    final_period: np.ndarray
    n_received: np.ndarray
    schedule_toa: np.ndarray
    schedule_pri: np.ndarray
    schedule_offsets: np.ndarray

    @property
    def n_sources(self) -> int:
        return int(self.period.size)

    def source_schedule(self, i: int) -> np.ndarray:
        return self.schedule_toa[self.schedule_offsets[i]:self.schedule_offsets[i + 1]]

    def source_pri(self, i: int) -> np.ndarray:
        return self.schedule_pri[self.schedule_offsets[i]:self.schedule_offsets[i + 1]]


@dataclass(frozen=True, eq=False)
class Episode:
    """One simulated (or loaded) pulse train.

    toa: sorted float64 times of arrival.  amplitude: float64 or None.  source: the primary source of
    each received pulse (int32, -1 = spurious).  mask: uint64 bit mask of every source merged into the
    pulse (0 for a spurious pulse; sources 64 and up, which never merge, have no bit: `source` names
    them).  truth: see `Truth` (None for files without truth).  priors: what a policy is told.
    frequency (MHz), pulse_width (us), aoa (degrees in [0, 360)): the pulse descriptor words, float64
    arrays like `toa`, or None where the scenario (or file) has none.
    """

    scenario: str
    seed: int
    toa: np.ndarray
    amplitude: np.ndarray | None
    source: np.ndarray
    mask: np.ndarray
    truth: Truth | None
    priors: Priors
    frequency: np.ndarray | None = None
    pulse_width: np.ndarray | None = None
    aoa: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.toa.size)

    @property
    def n_labels(self) -> int:
        return self.priors.n_labels

    @property
    def descriptors(self) -> dict[str, np.ndarray]:
        """The pulse descriptor arrays it has, by name (in DESCRIPTORS order)."""
        return {name: getattr(self, name) for name in DESCRIPTORS if getattr(self, name) is not None}

    @property
    def blind(self) -> bool:
        return self.priors.blind

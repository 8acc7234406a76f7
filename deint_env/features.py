"""Per-track token features for learned agents, for any number of sources (layout version 3; 2 is still computed).

One observation describes the pulse the next action labels, as one *token* per label track (padded
to a declared maximum `max_tracks` = M, with a mask) plus a few *pulse* (global) features.  The
action space is `Discrete(M + 1)`: label i < M names track i, label M means spurious, and labels of
tracks the scenario lacks are masked (`action_masks()`, sb3-contrib MaskablePPO's convention).  One
network can therefore play 2 to M sources, anchored (tracks = the prior tracks) or blind (tracks =
the labels the agent opened itself; a track's period is learned from its own labels).

Everything is batched: `TrackFeatures` holds the state of N episodes in (N, M) numpy arrays and
computes all N observations in one compiled call (`deint_env.features_kernels`, row by row: at N = 1,
numpy's per-call overhead made the features most of a learned agent's time), so the same code serves a
single env (N = 1), the native vector env, the multi-scenario env and the `agent` policy playing
episodes alone or in lock-step, and gives identical features in all.

Token features (per track i; all 0 for absent tracks and for steps that label nothing), with P the
track's period estimate (the prior period shrunk towards the agent's own labelled intervals; blind:
the labelled intervals alone, unknown until the track holds two pulses), "anchor" the last pulse the
agent labelled i (before that, in anchored mode, a virtual pulse one prior period before the prior
phase), t the pulse to label and u the episode's time unit (mean received interval so far):

    exists, used, log_count, has_period, anchored, since, resid, missed, gap, log_period, since_unit,
    amp, period_drift, then per look-ahead pulse j = 1..K: ahead_resid_j, ahead_self_j

- since = (t - anchor) / P; resid = since - n with n = max(round(since), 1); missed = n - 1.
- gap = (t - previous received pulse) / P; log_period = log(P / u); since_unit = (t - anchor) / u.
- amp = (amplitude - the track's mean amplitude) / its prior spread (blind: / the pulse amplitude's).
- period_drift = P / prior period - 1 (anchored only).
- Version 3 adds z = resid * P / sigma, the residual in jitter units (sigma = the stated jitter std,
  floored at 0.1 % of P), and per look-ahead pulse ahead_z_j, ahead_self_z_j (ahead_resid_j and
  ahead_self_j likewise scaled): the residuals of version 2 are fractions of a period, so a jitter of a
  few hundredths of a period (the core-v0 spreads) is below what the network resolves, and two close
  pulses of different tracks get swapped.
- ahead_resid_j = the residual (as resid) of look-ahead pulse j against the track's anchor, and
  ahead_self_j its residual against t itself: "would t's successor in this track be where pulse j is".

Pulse features: valid, first, blind, n_labels / M, spurious_rate, missing_prob, jitter_std / u,
has_amplitude, then per look-ahead pulse j: ahead_valid_j, ahead_gap_j = (t_j - t) / u.

With lag D (= the layout's `lookahead` K) the action at step k labels pulse k - D and pulses
k - D + 1 .. k are its look-ahead.  Every value is clipped to [-CLIP, CLIP].
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from gymnasium import spaces

from deint_env.episode import Priors
from deint_env.errors import DeintError

LAYOUT = "tracks"
VERSION = 3
VERSIONS = (2, 3)  # layouts this module computes (2: checkpoints trained before the z-scores)
CLIP = 10.0
MAX_TRACKS = 256
MAX_LOOKAHEAD = 16
TOKEN_FEATURES = ("exists", "used", "log_count", "has_period", "anchored", "since", "resid", "missed", "gap",
                  "log_period", "since_unit", "amp", "period_drift")
PULSE_FEATURES = ("valid", "first", "blind", "n_labels", "spurious_rate", "missing_prob", "jitter", "has_amplitude")
# As in `deint_env.wrappers` (layout 1): a labelled interval moves the period estimate only when it
# lies within this fraction of a period of the predicted arrival, and the prior weighs one period.
PERIOD_GATE = 0.15
PRIOR_WEIGHT = 1.0


@dataclass(frozen=True)
class TrackLayout:
    """The declared shape of the token observation: checkpoints record it and refuse any other."""

    max_tracks: int = 8
    lookahead: int = 0
    flat: bool = False
    version: int = VERSION

    def __post_init__(self) -> None:
        for name, value, lo, hi in (("max_tracks", self.max_tracks, 1, MAX_TRACKS),
                                    ("lookahead", self.lookahead, 0, MAX_LOOKAHEAD)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
                raise DeintError(f"{name}={value!r} is invalid: an integer in [{lo}, {hi}]")
        if self.version not in VERSIONS:
            raise DeintError(f"track feature layout version {self.version!r} is not computed by this deint_env "
                             f"(it computes versions {', '.join(map(str, VERSIONS))}): retrain the agent")

    @property
    def token_names(self) -> list[str]:
        if self.version == 2:
            ahead = [f"{f}_{j}" for j in range(1, self.lookahead + 1) for f in ("ahead_resid", "ahead_self")]
            return list(TOKEN_FEATURES) + ahead
        ahead = [f"{f}_{j}" for j in range(1, self.lookahead + 1)
                 for f in ("ahead_resid", "ahead_self", "ahead_z", "ahead_self_z")]
        return list(TOKEN_FEATURES) + ["z"] + ahead

    @property
    def pulse_names(self) -> list[str]:
        ahead = [f"{f}_{j}" for j in range(1, self.lookahead + 1) for f in ("ahead_valid", "ahead_gap")]
        return list(PULSE_FEATURES) + ahead

    @property
    def n_actions(self) -> int:
        return self.max_tracks + 1

    def observation_space(self) -> spaces.Space:
        m, f, g = self.max_tracks, len(self.token_names), len(self.pulse_names)
        if self.flat:
            return spaces.Box(-CLIP, CLIP, shape=(g + m * f,), dtype=np.float32)
        return spaces.Dict({"tracks": spaces.Box(-CLIP, CLIP, shape=(m, f), dtype=np.float32),
                            "mask": spaces.Box(0.0, 1.0, shape=(m,), dtype=np.float32),
                            "pulse": spaces.Box(-CLIP, CLIP, shape=(g,), dtype=np.float32)})

    def to_dict(self) -> dict[str, Any]:
        return {"layout": LAYOUT, **asdict(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrackLayout:
        if d.get("layout") != LAYOUT:
            raise DeintError(f"feature layout {d.get('layout')!r} is not {LAYOUT!r}")
        unknown = sorted(set(d) - {"layout", "max_tracks", "lookahead", "flat", "version"})
        if unknown:
            raise DeintError(f"feature layout key {unknown[0]!r} is unknown")
        return cls(**{k: v for k, v in d.items() if k != "layout"})

    @classmethod
    def from_space(cls, space: spaces.Space) -> TrackLayout | None:
        """The token (Dict) layout whose observation space is `space`, or None: an agent trained outside
        deint (an SB3 model) carries only its space.  A flat layout is not recovered: one Box width fits
        several (track count, look-ahead) pairs."""
        if not (isinstance(space, spaces.Dict) and "tracks" in space.spaces and len(space["tracks"].shape) == 2
                and 1 <= space["tracks"].shape[0] <= MAX_TRACKS):
            return None
        m = space["tracks"].shape[0]
        fits = [cls(m, la, False, v) for la in range(MAX_LOOKAHEAD + 1) for v in VERSIONS
                if cls(m, la, False, v).observation_space() == space]
        return fits[0] if len(fits) == 1 else None

    def check_fits(self, n_labels: int, lag: int, where: str = "scenario") -> None:
        if n_labels > self.max_tracks:
            raise DeintError(f"{where} has {n_labels} label tracks; this feature layout holds at most "
                             f"{self.max_tracks}")
        if lag != self.lookahead:
            raise DeintError(f"{where} runs with lag {lag}; this feature layout looks {self.lookahead} pulses "
                             "ahead, so it needs lag = lookahead")


def _resid(x: np.ndarray) -> np.ndarray:
    return x - np.maximum(np.rint(x), 1.0)


class TrackFeatures:
    """The token features of N episodes at once (module doc).  Per step: `label(actions)` for the
    pulses just described (rows that were not `ready` ignore theirs), then `observe(toa, amp, valid)`
    with the env's new raw observations, then `observation()`.  `reset_rows(rows, priors)` starts
    new episodes in some rows (before their first `observe`)."""

    def __init__(self, n: int, layout: TrackLayout):
        self.layout = layout
        self.n = int(n)
        m, w = layout.max_tracks, layout.lookahead + 2
        shape = (self.n, m)
        self.n_labels = np.zeros(self.n, np.int64)
        self.blind = np.zeros(self.n, bool)
        self.exists = np.zeros(shape, bool)
        self.prior_period = np.full(shape, np.nan)
        self.period = np.full(shape, np.nan)
        self.anchor = np.full(shape, np.nan)
        self.count = np.zeros(shape, np.int64)
        self.span_time = np.zeros(shape)
        self.span_periods = np.zeros(shape)
        self.amp_mean = np.full(shape, np.nan)
        self.amp_scale = np.ones(shape)
        self.has_amp = np.zeros(self.n, bool)
        self.scalars = np.zeros((self.n, 3))  # spurious_rate, missing_prob, jitter_std
        # Pulse window: column 0 the pulse before the one to label, 1 the one to label, 2.. look-ahead.
        self.win_toa = np.full((self.n, w), np.nan)
        self.win_amp = np.zeros((self.n, w))
        self.first_toa = np.full(self.n, np.nan)
        self.labelled = np.zeros(self.n, np.int64)  # pulses labelled so far in the episode
        self._rows = np.arange(self.n)

    # ---- episode starts ------------------------------------------------------------------------------
    def reset_rows(self, rows: np.ndarray | list[int], priors: list[Priors], has_amplitude: list[bool]) -> None:
        lay = self.layout
        for r, p, has_amp in zip(np.asarray(rows).tolist(), priors, has_amplitude):
            nl = p.n_labels
            if nl > lay.max_tracks:
                raise DeintError(f"the scenario has {nl} label tracks; this feature layout holds at most "
                                 f"{lay.max_tracks}")
            self.n_labels[r] = nl
            self.blind[r] = p.blind
            self.exists[r] = np.arange(lay.max_tracks) < nl
            self.prior_period[r] = np.nan
            self.anchor[r] = np.nan
            self.amp_mean[r] = np.nan
            self.amp_scale[r] = 1.0
            if not p.blind:
                self.prior_period[r, :nl] = p.period
                # Before a track's first label its anchor is a virtual pulse one period before the prior phase.
                self.anchor[r, :nl] = p.phase - p.period
                if p.amplitude is not None:
                    self.amp_mean[r, :nl] = p.amplitude
                    self.amp_scale[r, :nl] = np.maximum(p.amplitude_std, 1e-12)
            self.has_amp[r] = bool(has_amp)
            # a rate the priors leave unknown (NaN) is fed as 0, as agents were trained on stated rates
            self.scalars[r] = (np.nan_to_num(p.spurious_rate), np.nan_to_num(p.missing_prob), p.jitter_std)
        rows = np.asarray(rows, np.int64)
        self.period[rows] = self.prior_period[rows]
        self.count[rows] = 0
        self.span_time[rows] = 0.0
        self.span_periods[rows] = 0.0
        self.win_toa[rows] = np.nan
        self.win_amp[rows] = 0.0
        self.first_toa[rows] = np.nan
        self.labelled[rows] = 0

    # ---- the stream --------------------------------------------------------------------------------
    @property
    def ready(self) -> np.ndarray:
        """Per row: whether the next action labels a pulse (the one `observation()` describes)."""
        return np.isfinite(self.win_toa[:, 1])

    def observe(self, toa: np.ndarray, amp: np.ndarray, valid: np.ndarray) -> None:
        """Shift each row's window by one raw observation (a padding one, valid = 0, shifts in nothing).
        Column 0 (the previous pulse) is left alone: `label` moves the labelled pulse there."""
        valid = np.asarray(valid, bool).reshape(self.n)
        toa, amp = np.asarray(toa, np.float64).reshape(self.n), np.asarray(amp, np.float64).reshape(self.n)
        self.win_toa[:, 1:-1] = self.win_toa[:, 2:]
        self.win_amp[:, 1:-1] = self.win_amp[:, 2:]
        self.win_toa[:, -1] = np.where(valid, toa, np.nan)
        self.win_amp[:, -1] = np.where(valid, amp, 0.0)
        self.first_toa = np.where(np.isfinite(self.first_toa), self.first_toa, self.win_toa[:, -1])

    def label(self, actions: np.ndarray) -> None:
        """Record each ready row's label (0..M-1 a track, M or an absent track: spurious), in one compiled
        call (`deint_env.features_kernels.label_rows`): a labelled interval within PERIOD_GATE of a
        period of the predicted arrival moves the track's period estimate, the prior weighing
        PRIOR_WEIGHT periods (blind: a track's second pulse gives its first period)."""
        from deint_env.features_kernels import label_rows  # numba loads with the first label, not the module

        label_rows(np.asarray(actions, np.int64), self.n_labels, self.win_toa, self.win_amp, self.labelled,
                   self.count, self.period, self.anchor, self.span_time, self.span_periods, self.prior_period,
                   self.amp_mean, PERIOD_GATE, PRIOR_WEIGHT)

    # ---- the observation -----------------------------------------------------------------------------
    def action_masks(self) -> np.ndarray:
        """(N, M + 1) bool: the tracks each row's scenario has, and spurious."""
        return np.concatenate([self.exists, np.ones((self.n, 1), bool)], axis=1)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(tracks (N, M, F), pulse (N, G)) float32, in one compiled call (`deint_env.features_kernels`,
        which keeps the formulas of the module doc operation for operation; the logarithms come from numpy
        here, see there)."""
        from deint_env.features_kernels import token_arrays  # numba loads with the first observation, not the module

        lay = self.layout
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = (self.win_toa[:, 1] - self.first_toa) / np.maximum(self.labelled, 1)
            unit = np.where((self.labelled > 0) & (unit > 0), unit, np.nan)  # the episode's time unit u
            log_period = np.log(self.period / unit[:, None])
            log_count = np.log1p(self.count)
        return token_arrays(self.win_toa, self.win_amp, unit, self.exists, self.count, self.period, self.anchor,
                            self.prior_period, self.amp_mean, self.amp_scale, self.blind, self.has_amp, self.scalars,
                            self.n_labels, log_count, log_period, lay.max_tracks, lay.lookahead, lay.version >= 3,
                            len(lay.token_names), len(lay.pulse_names), CLIP)

    def observation(self) -> dict[str, np.ndarray] | np.ndarray:
        """The batched observation in the layout's form (Dict of arrays, or flat (N, G + M F))."""
        tracks, pulse = self.arrays()
        if self.layout.flat:
            return np.concatenate([pulse, tracks.reshape(self.n, -1)], axis=1)
        return {"tracks": tracks, "mask": self.exists.astype(np.float32), "pulse": pulse}

    def env_actions(self, actions: np.ndarray, spurious: np.ndarray | int) -> np.ndarray:
        """Token actions (M = spurious) -> the env's labels (its own spurious label); a label naming an
        absent track is spurious too (masked agents never choose one)."""
        a = np.asarray(actions, np.int64).reshape(self.n)
        return np.where((a >= 0) & (a < self.n_labels), a, spurious).astype(np.int64)

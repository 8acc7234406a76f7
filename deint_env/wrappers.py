"""Wrappers for learned agents (docs/design.md section 4): float32, scale-free, fixed-shape pulse features.

`FeatureTracker` turns the raw pulse stream plus the labels the agent has given so far into one flat
feature vector per decision.  `PulseFeatures` runs it inside an env (it sees the agent's actions);
a policy outside any env (e.g. `agents.policy.AgentPolicy`) runs the same tracker from (obs, priors), so
an agent sees identical features in training and in evaluation.  `SplitSeeds` makes an env play only
a suite's train (or test) seeds.

Feature layout (version `FEATURE_VERSION`), every value clipped to [-CLIP, CLIP]:

    [valid, first] + n_labels blocks of [gap, known, used, since, resid, missed, amp]

- valid: 1 when this step's action labels a pulse (the described one), else 0 and all else is 0.
- first: 1 for the episode's first pulse (it has no previous pulse).
- gap: the interval from the previous received pulse to this one, in units of track i's prior period.
- known: track i has an anchor: a pulse the agent labelled i, or else a known prior phase.
- used: the agent has labelled at least one pulse i.
- since: time from the anchor to this pulse in units of track i's period.  The anchor is the last
  pulse the agent labelled i; before that, a virtual pulse one prior period before the prior phase,
  so a pulse arriving at the prior phase has since = 1.  The period is the agent's running estimate
  from its own consecutive labels, shrunk towards the prior period (it starts at the prior).
- resid: since - n, with n = max(round(since), 1) the number of periods elapsed: how far (in periods)
  the pulse is from the track's predicted arrival; ~0 when it is on schedule.
- missed: n - 1, the periods the track skipped.
- amp: (amplitude - mean amplitude of the pulses labelled i) / the prior amplitude spread of track i
  (the prior mean amplitude before the first use); 0 when the scenario has no amplitudes.
Unknown tracks (no anchor) have since = resid = missed = 0.

With lag D the action at step k labels pulse k - D; the features describe that pulse (the oldest
one not yet labelled), computed from the labels of every earlier pulse, so the first D steps carry
valid = 0.  Look-ahead pulses are not (yet) featured.

Anchored mode only: the features are measured in units of the prior periods.  Blind scenarios have
no priors and raise `DeintError`.

`TrackTokens` / `TrackTokensVector` (end of this module) give the newer token features of
`deint_env.features` (layout 2): any number of sources up to a declared maximum, action masks,
look-ahead pulses, blind scenarios, computed in numpy for a whole vector env at once.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from deint_env.episode import Priors
from deint_env.errors import DeintError
from deint_env.suites import SeedRange

FEATURE_VERSION = 1
CLIP = 10.0
GLOBAL_FEATURES = ("valid", "first")
TRACK_FEATURES = ("gap", "known", "used", "since", "resid", "missed", "amp")
# A labelled interval updates the period estimate only when it lies within this fraction of a period
# of the predicted arrival: one wrong label must not drag the estimate to another source's period.
PERIOD_GATE = 0.15
# Weight of the prior period in the running estimate, in periods of observed data.
PRIOR_WEIGHT = 1.0


def feature_size(n_labels: int) -> int:
    return len(GLOBAL_FEATURES) + n_labels * len(TRACK_FEATURES)


def feature_names(n_labels: int) -> list[str]:
    return list(GLOBAL_FEATURES) + [f"{f}{i}" for i in range(n_labels) for f in TRACK_FEATURES]


def feature_space(n_labels: int) -> spaces.Box:
    return spaces.Box(-CLIP, CLIP, shape=(feature_size(n_labels),), dtype=np.float32)


class FeatureTracker:
    """The features of the pulse to be labelled next, from the pulses seen and the labels given.

    Per decision: `observe(obs)` with each raw observation, then `features()`, then, when `ready`
    was true, `label(action)` for the pulse just described.  `reset(priors)` starts an episode.
    """

    def __init__(self, n_labels: int, lag: int = 0):
        self.n_labels = int(n_labels)
        self.lag = int(lag)
        self.size = feature_size(self.n_labels)

    def reset(self, priors: Priors) -> None:
        if priors.blind:
            raise DeintError("the pulse features need anchored priors (periods); blind scenarios have none")
        if priors.n_labels != self.n_labels:
            raise DeintError(f"priors have {priors.n_labels} tracks; this feature tracker expects {self.n_labels}")
        n = self.n_labels
        self._prior_period = priors.period.astype(np.float64).tolist()
        phase = priors.phase.astype(np.float64).tolist()
        # Before a track's first label its anchor is a virtual pulse one period before the prior phase.
        self._anchor = [ph - p if math.isfinite(ph) else math.nan for ph, p in zip(phase, self._prior_period)]
        self._used = [False] * n
        self._period = list(self._prior_period)
        self._span_time = [0.0] * n  # accepted labelled intervals: total time and total periods
        self._span_periods = [0.0] * n
        if priors.amplitude is not None:
            self._amp_mean = priors.amplitude.astype(np.float64).tolist()
            self._amp_scale = [max(float(s), 1e-12) for s in priors.amplitude_std]
        else:
            self._amp_mean = self._amp_scale = None
        self._amp_count = [0] * n
        self._pending: deque[tuple[float, float, float]] = deque()  # (toa, amplitude, previous toa)
        self._last_toa = math.nan
        self._ended = False

    def observe(self, obs: dict[str, Any]) -> None:
        """Take one raw env observation (a padding observation, valid = 0, marks the stream's end)."""
        if not int(obs["valid"]):
            self._ended = True
            return
        toa = float(obs["toa"][0])
        self._pending.append((toa, float(obs["amplitude"][0]), self._last_toa))
        self._last_toa = toa

    @property
    def ready(self) -> bool:
        """Whether the next action labels a pulse (the one `features()` describes)."""
        return bool(self._pending) and (len(self._pending) > self.lag or self._ended)

    def features(self) -> np.ndarray:
        out = np.zeros(self.size, dtype=np.float64)
        if not self.ready:
            return out.astype(np.float32)
        toa, amp, prev = self._pending[0]
        out[0] = 1.0
        out[1] = 0.0 if math.isfinite(prev) else 1.0
        width = len(TRACK_FEATURES)
        for i in range(self.n_labels):
            b = len(GLOBAL_FEATURES) + i * width
            if math.isfinite(prev):
                out[b] = (toa - prev) / self._prior_period[i]
            anchor = self._anchor[i]
            if math.isfinite(anchor):
                since = (toa - anchor) / self._period[i]
                n = max(round(since), 1)
                out[b + 1] = 1.0
                out[b + 3] = since
                out[b + 4] = since - n
                out[b + 5] = n - 1
            out[b + 2] = float(self._used[i])
            if self._amp_mean is not None:
                out[b + 6] = (amp - self._amp_mean[i]) / self._amp_scale[i]
        return np.clip(out, -CLIP, CLIP).astype(np.float32)

    def label(self, action: int) -> None:
        """The agent's label for the described pulse: updates that track's anchor, period, amplitude."""
        if not self.ready:
            raise DeintError("label() called with no pulse awaiting a label")
        toa, amp, _ = self._pending.popleft()
        i = int(action)
        if not 0 <= i < self.n_labels:  # spurious (range checks are the env's job)
            return
        if self._used[i]:
            d = toa - self._anchor[i]
            n = max(round(d / self._period[i]), 1)
            if abs(d - n * self._period[i]) <= PERIOD_GATE * self._period[i]:
                self._span_time[i] += d
                self._span_periods[i] += n
                p = self._prior_period[i]
                self._period[i] = (PRIOR_WEIGHT * p + self._span_time[i]) / (PRIOR_WEIGHT + self._span_periods[i])
        self._anchor[i] = toa
        self._used[i] = True
        if self._amp_mean is not None:
            if self._amp_count[i] == 0:  # the prior mean gives way to the labelled pulses
                self._amp_mean[i] = amp
            else:
                self._amp_mean[i] += (amp - self._amp_mean[i]) / (self._amp_count[i] + 1)
            self._amp_count[i] += 1


class PulseFeatures(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Raw Dict observations -> `Box(-CLIP, CLIP, (2 + 7 n_labels,), float32)` features (module doc).

    Wraps a `DeinterleaveEnv` (possibly under other wrappers) in anchored mode; the reset info's
    priors and lag configure the features, and each action is recorded for the pulse it labels.
    """

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)  # lets env.spec.make() rebuild the wrapper stack
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if getattr(base, "blind", False):
            raise DeintError("PulseFeatures needs an anchored scenario; blind scenarios have no priors")
        self.tracker = FeatureTracker(base.n_labels, base.lag)
        self.observation_space = feature_space(base.n_labels)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.tracker.reset(Priors.from_info(info["priors"]))
        self.tracker.observe(obs)
        return self.tracker.features(), info

    def step(self, action):
        labels = self.tracker.ready
        obs, reward, terminated, truncated, info = self.env.step(action)  # the env validates the action
        if labels:
            self.tracker.label(action)
        self.tracker.observe(obs)
        return self.tracker.features(), reward, terminated, truncated, info


class SplitSeeds(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Every reset plays an episode seed drawn from `seeds` (e.g. a suite entry's train range).

    `reset(seed=s)` reseeds the draw, so a run is reproducible; the env's own seed is the drawn one.
    """

    def __init__(self, env: gym.Env, seeds: range | SeedRange):
        gym.utils.RecordConstructorArgs.__init__(self, seeds=seeds)
        gym.Wrapper.__init__(self, env)
        self.seeds = range(seeds.start, seeds.stop)
        if len(self.seeds) == 0:
            raise DeintError("SplitSeeds needs a non-empty seed range")
        self._draw = np.random.default_rng()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._draw = np.random.default_rng(seed)
        episode_seed = self.seeds[int(self._draw.integers(len(self.seeds)))]
        return self.env.reset(seed=episode_seed, options=options)


# ---- token features (layout 2, `deint_env.features`): any number of sources, blind too -------------
def _token_actions(actions: Any, n: int, m: int) -> np.ndarray:
    """`n` token actions as integers in [0, m] (m = spurious), as the action space has them; anything
    else (a float, a boolean, a track past m or below 0) is one line, not a silent spurious label."""
    a = np.asarray(actions)
    if a.dtype.kind not in "iu" or a.size != n or ((a < 0) | (a > m)).any():
        what = "a track" if n == 1 else f"{n} tracks"
        raise DeintError(f"action={actions!r} is invalid: {what} in [0, {m}] ({m} = spurious)")
    return a.reshape(n)


class TrackTokens(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Raw observations -> the per-track token observation of `deint_env.features` (a Dict of
    `tracks` (M, F), `mask` (M,) and `pulse` (G,), or with `flat=True` one Box), for anchored and blind
    scenarios with up to `max_tracks` labels.  The action space is `Discrete(max_tracks + 1)` (label
    max_tracks = spurious); `action_masks()` marks the labels this scenario has.  The env's lag is the
    number of look-ahead pulses featured."""

    def __init__(self, env: gym.Env, max_tracks: int = 8, flat: bool = False):
        gym.utils.RecordConstructorArgs.__init__(self, max_tracks=max_tracks, flat=flat)
        gym.Wrapper.__init__(self, env)
        from deint_env.features import TrackFeatures, TrackLayout

        base = env.unwrapped
        self.layout = TrackLayout(max_tracks=max_tracks, lookahead=base.lag, flat=flat)
        self.layout.check_fits(base.n_labels, base.lag)
        self.features = TrackFeatures(1, self.layout)
        self.observation_space = self.layout.observation_space()
        self.action_space = spaces.Discrete(self.layout.n_actions)
        self._spurious = base.n_labels

    def _observe(self, obs: dict[str, Any]):
        self.features.observe(obs["toa"], obs["amplitude"], obs["valid"])
        out = self.features.observation()
        return out[0] if isinstance(out, np.ndarray) else {k: v[0] for k, v in out.items()}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.features.reset_rows([0], [Priors.from_info(info["priors"])], [info["has_amplitude"]])
        return self._observe(obs), info

    def step(self, action):
        action = _token_actions(action, 1, self.layout.max_tracks)
        label = int(self.features.env_actions(action, self._spurious)[0])
        obs, reward, terminated, truncated, info = self.env.step(label)
        self.features.label(action)
        return self._observe(obs), reward, terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        return self.features.action_masks()[0]


class TrackTokensVector(gym.vector.VectorWrapper):
    """`TrackTokens` for a whole native vector env (`DeinterleaveVectorEnv` or the multi-scenario
    `MixedScenarioVectorEnv`), the features of all sub-envs computed together in numpy.  Step for
    step it matches `num_envs` single `TrackTokens` envs.  `action_masks()` is (num_envs, M + 1)."""

    def __init__(self, env: gym.vector.VectorEnv, max_tracks: int = 8, flat: bool = False):
        super().__init__(env)
        from gymnasium.vector.utils import batch_space

        from deint_env.features import TrackFeatures, TrackLayout

        base = env.unwrapped
        self.layout = TrackLayout(max_tracks=max_tracks, lookahead=base.lag, flat=flat)
        self.layout.check_fits(base.n_labels, base.lag)
        self.features = TrackFeatures(self.num_envs, self.layout)
        self.single_observation_space = self.layout.observation_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.single_action_space = spaces.Discrete(self.layout.n_actions)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._spurious = base.n_labels

    def _restart(self, rows: np.ndarray) -> None:
        episodes = [self.env.unwrapped.episodes[i] for i in rows.tolist()]
        self.features.reset_rows(rows, [ep.priors for ep in episodes], [ep.amplitude is not None for ep in episodes])

    def _observe(self, obs: dict[str, np.ndarray]):
        self.features.observe(obs["toa"][:, 0], obs["amplitude"][:, 0], obs["valid"])
        return self.features.observation()

    def reset(self, *, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        self._restart(np.arange(self.num_envs))
        return self._observe(obs), infos

    def step(self, actions):
        actions = _token_actions(actions, self.num_envs, self.layout.max_tracks)
        obs, reward, terminated, truncated, infos = self.env.step(self.features.env_actions(actions, self._spurious))
        self.features.label(actions)
        started = infos.get("_n_pulses")  # the sub-envs that began a new episode on this step
        if started is not None and started.any():
            self._restart(np.flatnonzero(started))
        return self._observe(obs), reward, terminated, truncated, infos

    def action_masks(self) -> np.ndarray:
        return self.features.action_masks()

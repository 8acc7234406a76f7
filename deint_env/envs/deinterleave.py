"""The single deinterleaving environment: one received pulse per step, one label per step."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from deint_env.episode import Episode
from deint_env.errors import DeintError
from deint_env.labels import NO_PRED, SPURIOUS_PRED, true_predecessors
from deint_env.metrics import label_metrics
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.suites import resolve_scenario

DEFAULT_SCENARIO = "paper-v0/mk94-two-var1"
_BIG = float(np.finfo(np.float64).max)  # TOAs may be any finite float64; Gymnasium warns on infinite bounds


def observation_space() -> spaces.Dict:
    """Raw pulse observations: float64 TOA and amplitude (0 when the scenario has none), and `valid`
    (0 on the padding steps that follow the last pulse when lag > 0)."""
    return spaces.Dict({
        "toa": spaces.Box(-_BIG, _BIG, shape=(1,), dtype=np.float64),
        "amplitude": spaces.Box(-_BIG, _BIG, shape=(1,), dtype=np.float64),
        "valid": spaces.Discrete(2),
    })


def check_lag(lag: object) -> int:
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or not 0 <= int(lag) <= 10_000:
        raise DeintError(f"lag={lag!r} is invalid: an integer in [0, 10000]")
    return int(lag)


class DeinterleaveEnv(gym.Env[dict, int]):
    """
    ## Description
    Several periodic pulse sources share one receiver.  Each step shows one received pulse (its time
    of arrival and, in some scenarios, its amplitude) and asks which source sent it.  Episodes come
    from a `ScenarioSpec` (see `deint_env.suites` for the published ones) through `simulate(spec,
    seed)`: the same scenario and seed give the same episode, bit for bit, in every env flavour.

    ## Action Space
    `Discrete(n_labels + 1)`.  Anchored mode: label i < n_labels names prior track i (the sources as
    ordered by the priors); label n_labels means "spurious / belongs to no source".  Blind mode: the
    same with n_labels = the scenario's label budget; a label names a track the agent opened itself.
    With `lag = D`, the action at step k labels pulse k - D; the first D actions label nothing.

    ## Observation Space
    `Dict(toa=Box(float64, (1,)), amplitude=Box(float64, (1,)), valid=Discrete(2))`: step k's
    observation carries pulse k (raw float64 TOA; amplitude 0 when the scenario has none).  After the
    last pulse come D padding observations with valid = 0.  Learned agents use the float32 feature
    wrapper `deint_env.wrappers.PulseFeatures`.

    ## Rewards
    1.0 for a right label, else 0.0.  Anchored: right if it names the pulse's source (any of them for
    a merged pulse) or "spurious" for a spurious pulse.  Blind: right if the label's previous pulse is
    the pulse's true predecessor in its source ("none" for a source's first pulse); a spurious pulse
    is right only when labelled spurious.  See `deint_env.labels`.

    ## Starting State
    `reset(seed=s)` plays episode `simulate(scenario, s)`; `reset()` draws the episode seed from the
    env's generator.  The reset info holds `priors` (the public priors: periods, phases, their spreads,
    source probabilities, jitter, never the truth), `n_pulses`, `lag`, `has_amplitude`, `scenario`.

    ## Episode End
    Terminates (`terminated=True`) on the step that labels the last pulse, i.e. after n_pulses + D
    steps.  Never truncates; wrap with `TimeLimit` to cut episodes short.  The last step's info holds
    `metrics` (`deint_env.metrics.label_metrics` of the episode's labels).

    ## Arguments
    `scenario`: a ScenarioSpec, its dict, or a scenario name ("suite/scenario" or a unique bare name;
    default "paper-v0/mk94-two-var1").  `lag`: decision delay D >= 0.  `render_mode`: None, "ansi"
    or "rgb_array".  `clustering_metrics`: whether the final metrics include the scikit-learn
    clustering scores (True; False saves a few ms per episode during training).

    ## Version History
    - v0: initial release.
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 30}

    def __init__(self, scenario: ScenarioSpec | str | dict | None = DEFAULT_SCENARIO, lag: int = 0,
                 render_mode: str | None = None, clustering_metrics: bool = True, *,
                 n_labels: int | None = None, blind: bool = False):
        # scenario=None (with n_labels) makes an env that only plays given episodes: see `for_episode`.
        self.spec_scenario = resolve_scenario(scenario) if scenario is not None else None
        self.lag = check_lag(lag)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise DeintError(f"render_mode={render_mode!r} is invalid: None, 'ansi' or 'rgb_array'")
        self.render_mode = render_mode
        self.clustering_metrics = clustering_metrics
        self.n_labels = self.spec_scenario.n_labels if self.spec_scenario is not None else int(n_labels)
        self.blind = self.spec_scenario.blind if self.spec_scenario is not None else blind
        self.action_space = spaces.Discrete(self.n_labels + 1)
        self.observation_space = observation_space()
        self.episode: Episode | None = None
        self._step = 0

    @classmethod
    def for_episode(cls, episode: Episode, lag: int = 0, clustering_metrics: bool = True) -> DeinterleaveEnv:
        """An env that plays one given episode (e.g. read from a pulse file); call `load_episode`."""
        return cls(None, lag=lag, clustering_metrics=clustering_metrics, n_labels=episode.n_labels,
                   blind=episode.blind)

    # ---- gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if self.spec_scenario is None:
            raise gym.error.Error("this env plays given episodes only: use load_episode()")
        episode_seed = seed if seed is not None else int(self.np_random.integers(0, 2**63 - 1))
        return self.load_episode(simulate(self.spec_scenario, episode_seed))

    def load_episode(self, episode: Episode) -> tuple[dict[str, Any], dict[str, Any]]:
        """Play a given episode (simulated, or read from a pulse file) from its first pulse; returns
        the first observation and the reset info, like `reset`."""
        if episode.n_labels != self.n_labels or episode.blind != self.blind:
            raise DeintError(f"episode has {episode.n_labels} labels (blind={episode.blind}); this env expects "
                             f"{self.n_labels} (blind={self.blind})")
        self.episode = episode
        n = len(episode)
        self._n = n
        self._toa = episode.toa
        self._amp = episode.amplitude if episode.amplitude is not None else np.zeros(n)
        # The label check reads the primary source first: a Python list indexes faster than numpy,
        # and its small ints are shared objects, so it costs one pointer a pulse.
        self._src = episode.source.tolist()
        self.labels = np.full(n, -1, dtype=np.int64)
        self._step = 0
        if self.blind:
            truth = true_predecessors(episode.source, episode.mask)
            self._pred = truth.pred.tolist()
            self._alt = truth.alternatives()
            self._last = [NO_PRED] * self.n_labels
        return self._observation(0), self._reset_info()

    def step(self, action):
        if self.episode is None or self._step >= self._n + self.lag:
            raise gym.error.ResetNeeded("call reset() before step() and after the episode ends")
        j = self._step - self.lag
        reward = 0.0
        if j >= 0:
            a = int(action)
            if not 0 <= a <= self.n_labels:
                raise DeintError(f"action={action!r} is invalid: a label in [0, {self.n_labels}]"
                                 f" ({self.n_labels} = spurious)")
            self.labels[j] = a
            reward = 1.0 if self._is_correct(j, a) else 0.0
        self._step += 1
        terminated = j == self._n - 1
        info: dict[str, Any] = {}
        if terminated:
            info["metrics"] = self.metrics()
        return self._observation(self._step), reward, terminated, False, info

    def _is_correct(self, j: int, a: int) -> bool:
        spur = self.n_labels
        if not self.blind:
            if a == spur:
                return self._src[j] < 0
            return a == self._src[j] or (a < 64 and (int(self.episode.mask[j]) >> a) & 1 == 1)
        if a == spur:
            return self._pred[j] == SPURIOUS_PRED
        named = self._last[a]
        self._last[a] = j
        return named == self._pred[j] or named in self._alt.get(j, ())

    def metrics(self) -> dict[str, Any]:
        """Label metrics of the pulses labelled so far (all of them once the episode has ended)."""
        done = max(0, min(self._step - self.lag, self._n))
        ep = self.episode
        m = label_metrics(self.labels[:done], ep.source[:done], ep.mask[:done], self.n_labels, self.blind,
                          clustering=self.clustering_metrics)
        m["lag"] = self.lag
        return m

    def _observation(self, k: int) -> dict[str, Any]:
        if k < self._n:
            return {"toa": self._toa[k:k + 1].copy(), "amplitude": self._amp[k:k + 1].copy(), "valid": np.int64(1)}
        return {"toa": np.zeros(1), "amplitude": np.zeros(1), "valid": np.int64(0)}

    def _reset_info(self) -> dict[str, Any]:
        return {"priors": self.episode.priors.as_info(), "n_pulses": self._n, "lag": self.lag,
                "has_amplitude": self.episode.amplitude is not None, "scenario": self.episode.scenario}

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() needs render_mode='ansi' or 'rgb_array' at construction")
            return None
        from deint_env.envs.render import render_ansi, render_rgb

        done = max(0, min(self._step - self.lag, self._n)) if self.episode is not None else 0
        ep = self.episode
        args = (ep.toa[:done], self.labels[:done], ep.source[:done], self.n_labels) if ep is not None else (
            np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int32), self.n_labels)
        return render_ansi(*args) if self.render_mode == "ansi" else render_rgb(*args)

"""The native vector env: N deinterleaving episodes stepped together, a handful of numpy ops a step."""

from __future__ import annotations

import math
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from deint_env.envs.deinterleave import DEFAULT_SCENARIO, check_lag, observation_space
from deint_env.episode import Episode
from deint_env.errors import DeintError
from deint_env.labels import NO_PRED, SPURIOUS_PRED, true_predecessors
from deint_env.metrics import label_metrics
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.suites import resolve_scenario

_ALL_BITS = np.uint64(2**64 - 1)


class DeinterleaveVectorEnv(VectorEnv):
    """
    ## Description
    `num_envs` copies of `DeinterleaveEnv` stepped together with batched numpy, like Gymnasium's
    `CartPoleVectorEnv`.  Step for step it gives the same observations, rewards and terminations as
    N single envs: sub-env i plays the episodes the single env reset with seed s + i would play.

    ## Action Space
    `MultiDiscrete([n_labels + 1] * num_envs)`: one label per sub-env, as in the single env (label
    n_labels = spurious; with `lag = D` the action at step k labels pulse k - D).

    ## Observation Space
    The single env's `Dict` batched: `toa` and `amplitude` `(num_envs, 1)` float64, `valid`
    `(num_envs,)` int64.

    ## Rewards
    float64 array, 1.0 for a right label, else 0.0, by the single env's anchored or blind (link) rules.

    ## Starting State
    `reset(seed=s)` gives sub-env i episode `simulate(scenario, s + i)` and a generator seeded with
    s + i; `reset(seed=[s0, s1, ...])` takes one seed (or None) per sub-env.  Without a seed, and on
    every autoreset, sub-env i draws its episode seed from its own generator as the single env does.
    The reset info is the single env's (`priors`, `n_pulses`, `lag`, `has_amplitude`, `scenario`)
    batched the Gymnasium way (arrays with `_key` masks); an autoreset step carries it for the sub-envs
    that reset.  `episodes[i]` is the episode sub-env i is playing.

    ## Episode End
    Sub-env i terminates after n_pulses + D steps.  Autoreset mode NEXT_STEP: on its next step the
    action is ignored, it starts a new episode and returns that episode's first observation with
    reward 0 and `terminated=False`.  Never truncates.  On a terminating step the info holds
    `episode_accuracy` (float64, NaN for sub-envs still running) and its mask `_episode_accuracy`;
    until the next `step()`, `metrics(i)` gives the finished episode's full `label_metrics`.

    ## Arguments
    `num_envs`: number of sub-envs.  `scenario`, `lag`, `clustering_metrics`: as the single env
    (`clustering_metrics` only affects `metrics(i)`).  `render_mode`: None, "ansi" or "rgb_array"
    (`render()` returns a tuple with one frame per sub-env).

    ## Version History
    - v0: initial release.
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 30,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, scenario: ScenarioSpec | str | dict = DEFAULT_SCENARIO, lag: int = 0,
                 render_mode: str | None = None, clustering_metrics: bool = True):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise DeintError(f"num_envs={num_envs!r} is invalid: an integer >= 1")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise DeintError(f"render_mode={render_mode!r} is invalid: None, 'ansi' or 'rgb_array'")
        self.num_envs = int(num_envs)
        self.spec_scenario = resolve_scenario(scenario)
        self.lag = check_lag(lag)
        self.render_mode = render_mode
        self.clustering_metrics = clustering_metrics
        self.n_labels = self.spec_scenario.n_labels
        self.blind = self.spec_scenario.blind
        self.single_action_space = spaces.Discrete(self.n_labels + 1)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.single_observation_space = observation_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

        n_env = self.num_envs
        self.episodes: list[Episode | None] = [None] * n_env
        self._rngs: list[np.random.Generator | None] = [None] * n_env
        self._rows = np.arange(n_env)
        self._k = np.zeros(n_env, np.int64)  # steps taken in the current episode
        self._n = np.zeros(n_env, np.int64)  # pulses in the current episode
        self._end = np.zeros(n_env, np.int64)  # n + lag: the step count at which the episode ends
        self._score = np.zeros(n_env, np.float64)  # rewards collected in the current episode
        self._prev_done = np.zeros(n_env, bool)
        self._started = False
        spur = self.n_labels
        if self.blind:
            # The last pulse given each label; the extra column (label "spurious") stays SPURIOUS_PRED,
            # so a spurious label names SPURIOUS_PRED with no branch.
            self._last = np.full((n_env, spur + 1), SPURIOUS_PRED, np.int64)
            self._alt: list[dict[int, set[int]]] = [{} for _ in range(n_env)]
        else:
            # A pulse's row holds its source bits, 0 if spurious (simulate gives every real pulse its
            # source's bit, so an empty row means spurious).  Label a is right when
            # row & bit[a] == want[a]: a track needs its bit, "spurious" needs an empty row, and a
            # track past bit 63 (the single env's `a < 64` rule) can never match want = 1.
            a = np.arange(spur + 1)
            real = a < min(spur, 64)
            self._label_bit = np.where(real, np.left_shift(np.uint64(1), np.minimum(a, 63).astype(np.uint64)),
                                       np.uint64(0)).astype(np.uint64)
            self._label_want = np.where(real, self._label_bit, np.uint64(1)).astype(np.uint64)
            self._label_bit[spur] = _ALL_BITS
            self._label_want[spur] = 0
        self._allocate(self.spec_scenario.n_pulses + 1)

    # ---- storage -----------------------------------------------------------------------------------
    def _allocate(self, cap: int) -> None:
        """(num_envs, cap) rows, cap > every episode's length so column n (zeros) is the padding obs."""
        old = getattr(self, "_cap", 0)
        tables = {"_toa": (np.float64, 0), "_amp": (np.float64, 0), "_labels": (np.int64, -1)}
        tables.update({"_pred": (np.int64, SPURIOUS_PRED), "_has_alt": (bool, False)} if self.blind
                      else {"_right": (np.uint64, 0)})
        for name, (dtype, fill) in tables.items():
            new = np.full((self.num_envs, cap), fill, dtype)
            if old:
                new[:, :old] = getattr(self, name)
            setattr(self, name, new)
        self._cap = cap
        self._base = self._rows * cap  # flat index of each row's column 0

    def _load(self, i: int, episode: Episode) -> None:
        n = len(episode)
        if n + 1 > self._cap:
            self._allocate(n + 1)
        self.episodes[i] = episode
        self._toa[i, :n] = episode.toa
        self._toa[i, n:] = 0.0
        self._amp[i, :n] = episode.amplitude if episode.amplitude is not None else 0.0
        self._amp[i, n:] = 0.0
        if self.blind:
            truth = true_predecessors(episode.source, episode.mask)
            self._pred[i, :n] = truth.pred
            self._has_alt[i] = False
            self._has_alt[i, truth.alt_pulse] = True
            self._alt[i] = truth.alternatives()
            self._last[i, :-1] = NO_PRED
        else:
            self._right[i, :n] = np.where(episode.source >= 0, episode.mask, np.uint64(0))
        self._n[i] = n
        self._end[i] = n + self.lag
        self._k[i] = 0
        self._score[i] = 0.0

    def _start(self, i: int, seed: int | None, infos: dict[str, Any]) -> None:
        """Start sub-env i's next episode, exactly as the single env's reset(seed) does."""
        if seed is not None:
            self._rngs[i], _ = seeding.np_random(seed)
        elif self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random()
        episode_seed = seed if seed is not None else int(self._rngs[i].integers(0, 2**63 - 1))
        episode = simulate(self.spec_scenario, episode_seed)
        self._load(i, episode)
        self._add_info(infos, {"priors": episode.priors.as_info(), "n_pulses": len(episode), "lag": self.lag,
                               "has_amplitude": episode.amplitude is not None,
                               "scenario": self.spec_scenario.name}, i)

    # ---- gymnasium API -------------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        seeds = self._seeds(seed)
        super().reset(seed=int(seed) if isinstance(seed, (int, np.integer)) else None)
        infos: dict[str, Any] = {}
        for i, s in enumerate(seeds):
            self._start(i, s, infos)
        self._prev_done[:] = False
        self._started = True
        return self._observation(), infos

    def _seeds(self, seed: Any) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds: list[Any] = [int(seed) + i for i in range(self.num_envs)]
        elif isinstance(seed, (Sequence, np.ndarray)) and len(seed) == self.num_envs:
            seeds = list(seed)
        else:
            raise DeintError(f"seed={seed!r} is invalid: None, an integer or a list of {self.num_envs} seeds")
        for s in seeds:
            if s is not None and (isinstance(s, bool) or not isinstance(s, (int, np.integer))
                                  or not 0 <= int(s) < 2**63):
                raise DeintError(f"seed={s!r} is invalid: an integer in [0, 2^63)")
        return [None if s is None else int(s) for s in seeds]

    def step(self, actions):
        if not self._started:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(actions)
        if a.shape != (self.num_envs,) or a.dtype.kind not in "iu":
            raise DeintError(f"actions must be {self.num_envs} integer labels, got {actions!r}")
        spur = self.n_labels
        k, prev_done = self._k, self._prev_done
        j = k - self.lag  # the pulse each sub-env labels (< 0 during the first `lag` steps)
        labelling = (j >= 0) & ~prev_done
        if a.min() < 0 or a.max() > spur:
            bad = np.flatnonzero(labelling & ((a < 0) | (a > spur)))
            if bad.size:
                raise DeintError(f"actions[{bad[0]}]={a[bad[0]]!r} is invalid: a label in [0, {spur}]"
                                 f" ({spur} = spurious)")
            a = np.clip(a, 0, spur)  # the out-of-range actions are ignored ones; keep them indexable
        a = a.astype(np.int64, copy=False)
        # j < 0 (lag steps) reads and writes column 0, j = n (finished sub-envs) the padding column:
        # both are masked out of the rewards and overwritten before they matter.
        jf = self._base + np.maximum(j, 0)
        if self.blind:
            lf = self._rows * (spur + 1) + a
            last = self._last.reshape(-1)
            named = last[lf]
            ok = named == self._pred.reshape(-1)[jf]
            hot = np.flatnonzero(self._has_alt.reshape(-1)[jf] & labelling)
            for i in hot.tolist():  # merged pulses: any member source's predecessor is right too
                ok[i] |= int(named[i]) in self._alt[i][int(j[i])]
            last[lf] = np.where(labelling & (a != spur), j, named)
        else:
            ok = (self._right.reshape(-1)[jf] & self._label_bit[a]) == self._label_want[a]
        reward = (ok & labelling).astype(np.float64)
        self._labels.reshape(-1)[jf] = a
        self._score += reward
        k += 1

        infos: dict[str, Any] = {}
        for i in np.flatnonzero(prev_done).tolist():
            self._start(i, None, infos)
        terminated = k == self._end
        if terminated.any():
            infos["episode_accuracy"] = np.where(terminated, self._score / self._n, math.nan)
            infos["_episode_accuracy"] = terminated.copy()
        self._prev_done = terminated.copy()  # the caller may write to the returned array
        return self._observation(), reward, terminated, np.zeros(self.num_envs, bool), infos

    def _observation(self) -> dict[str, np.ndarray]:
        f = self._base + np.minimum(self._k, self._cap - 1)  # columns past n hold zeros
        return {"toa": self._toa.reshape(-1)[f][:, None], "amplitude": self._amp.reshape(-1)[f][:, None],
                "valid": (self._k < self._n).astype(np.int64)}

    def _done(self, i: int) -> int:
        return int(max(0, min(self._k[i] - self.lag, self._n[i])))

    def metrics(self, i: int) -> dict[str, Any]:
        """Sub-env i's label metrics so far, as the single env's `metrics()`; on a terminating step
        (before the next `step()`) those of the finished episode."""
        if self.episodes[i] is None:
            raise gym.error.ResetNeeded("call reset() first")
        done, ep = self._done(i), self.episodes[i]
        m = label_metrics(self._labels[i, :done], ep.source[:done], ep.mask[:done], self.n_labels, self.blind,
                          clustering=self.clustering_metrics)
        m["lag"] = self.lag
        return m

    def render(self) -> tuple[Any, ...] | None:
        if self.render_mode is None:
            gym.logger.warn("render() needs render_mode='ansi' or 'rgb_array' at construction")
            return None
        from deint_env.envs.render import render_ansi, render_rgb

        draw = render_ansi if self.render_mode == "ansi" else render_rgb
        frames = []
        for i, ep in enumerate(self.episodes):
            d = self._done(i) if ep is not None else 0
            toa, source = (ep.toa, ep.source) if ep is not None else (np.zeros(0), np.zeros(0, np.int32))
            frames.append(draw(toa[:d], self._labels[i, :d], source[:d], self.n_labels))
        return tuple(frames)

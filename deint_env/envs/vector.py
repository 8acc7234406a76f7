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

from deint_env.envs.deinterleave import (DEFAULT_SCENARIO, check_lag, check_reset_options, observation_space,
                                         split_seeds)
from deint_env.episode import DESCRIPTORS
from deint_env.episode import Episode
from deint_env.errors import DeintError
from deint_env.labels import NO_PRED, SPURIOUS_PRED, true_predecessors
from deint_env.metrics import label_metrics
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate_many
from deint_env.suites import resolve_scenario

_ALL_BITS = np.uint64(2**64 - 1)


# Sub-envs are simulated and stepped in one process: beyond this many, memory and a reset's time run away
# (num_envs=10**9 hung) long before any learner could use them.
MAX_ENVS = 4096

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
    The single env's `Dict` batched: `toa` and `amplitude` (and a descriptor scenario's `frequency`,
    `pulse_width`, `aoa`) `(num_envs, 1)` float64, `valid` `(num_envs,)` int64.

    ## Rewards
    float64 array, 1.0 for a right label, else 0.0, by the single env's anchored or blind (link) rules.

    ## Starting State
    `reset(seed=s)` gives sub-env i episode `simulate(scenario, s + i)` and a generator seeded with
    s + i; `reset(seed=[s0, s1, ...])` takes one seed (or None) per sub-env.  Without a seed, and on
    every autoreset, sub-env i draws its episode seed from its own generator as the single env does.
    The sub-envs that start an episode on the same step have it simulated together, in one
    `simulate_many` call (the same episodes as one `simulate` each, at a fraction of the cost).
    The reset info is the single env's (`priors`, `n_pulses`, `lag`, `has_amplitude`, `has_descriptors`,
    `scenario`) batched the Gymnasium way (arrays with `_key` masks); an autoreset step carries it for
    the sub-envs that reset.  `episodes[i]` is the episode sub-env i is playing.

    ## Episode End
    Sub-env i terminates after n_pulses + D steps.  Autoreset mode NEXT_STEP (the default): on its
    next step the action is ignored, it starts a new episode and returns that episode's first
    observation with reward 0 and `terminated=False`.  `autoreset_mode=AutoresetMode.SAME_STEP` (as
    stable-baselines3 expects) starts the new episode on the terminating step itself: that step
    returns the new episode's first observation, with the finished one's last observation in
    `final_obs` (mask `_final_obs`).  Never truncates.  On a terminating step the info holds
    `episode_accuracy` (float64, NaN for sub-envs still running) and its mask `_episode_accuracy`;
    until the next `step()`, `metrics(i)` gives the finished episode's full `label_metrics`.

    ## Arguments
    `num_envs`: number of sub-envs.  `scenario`, `lag`, `clustering_metrics`, `split`: as the single
    env (`clustering_metrics` only affects `metrics(i)`; with `split`, every sub-env's seed s + i must
    be a seed of that split, and unseeded episodes are drawn from it).  `autoreset_mode`: NEXT_STEP or
    SAME_STEP.  `render_mode`: None, "ansi" or "rgb_array"
    (`render()` returns a tuple with one frame per sub-env).

    ## Version History
    - v0: initial release.
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 30,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, scenario: ScenarioSpec | str | dict = DEFAULT_SCENARIO, lag: int = 0,
                 render_mode: str | None = None, clustering_metrics: bool = True, split: str | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP):
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise DeintError(f"autoreset_mode={autoreset_mode!r} is invalid: NextStep or SameStep") from None
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise DeintError(f"autoreset_mode={autoreset_mode!r} is invalid: NextStep or SameStep")
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or not 1 <= num_envs <= MAX_ENVS:
            raise DeintError(f"num_envs={num_envs!r} is invalid: an integer in [1, {MAX_ENVS}]")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise DeintError(f"render_mode={render_mode!r} is invalid: None, 'ansi' or 'rgb_array'")
        self.num_envs = int(num_envs)
        self.spec_scenario = resolve_scenario(scenario)
        self.split = split_seeds(scenario, self.spec_scenario, split)
        self.lag = check_lag(lag)
        self.render_mode = render_mode
        if not isinstance(clustering_metrics, (bool, np.bool_)):
            raise DeintError(f"clustering_metrics={clustering_metrics!r} is invalid: True or False")
        self.clustering_metrics = clustering_metrics
        self.n_labels = self.spec_scenario.n_labels
        self.blind = self.spec_scenario.blind
        self.single_action_space = spaces.Discrete(self.n_labels + 1)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.descriptors = DESCRIPTORS if self.spec_scenario.has_descriptors else ()
        self.single_observation_space = observation_space(self.descriptors)
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
        self._any_done = False  # whether any sub-env ended on the last step (autoresets on this one)
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
            # row & bit[a] == want[a]: a track needs its bit, "spurious" needs an empty row; a track
            # past bit 63 never matches want = 1 here and is right by its primary source (`_src`).
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
        tables.update({f"_{name}": (np.float64, 0) for name in self.descriptors})
        tables.update({"_pred": (np.int64, SPURIOUS_PRED), "_has_alt": (bool, False)} if self.blind
                      else {"_right": (np.uint64, 0)})
        if not self.blind and self.n_labels > 64:  # sources past the 64-bit mask: right by their primary source
            tables["_src"] = (np.int64, -1)
        for name, (dtype, fill) in tables.items():
            new = np.full((self.num_envs, cap), fill, dtype)
            if old:
                new[:, :old] = getattr(self, name)
            setattr(self, name, new)
        self._cap = cap
        self._base = self._rows * cap  # flat index of each row's column 0

    def _start(self, rows: list[int], seeds: list[int | None], infos: dict[str, Any]) -> None:
        """Start the next episode of each sub-env in `rows`, exactly as the single env's reset(seed)
        does; the episodes are simulated together (one scenario, so one `simulate_many` call)."""
        episode_seeds = []
        for i, seed in zip(rows, seeds):
            self.episodes[i] = None  # release the finished episode first: its memory serves the new one
            if seed is not None:
                self._rngs[i], _ = seeding.np_random(seed)
            elif self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random()
            if seed is not None:
                episode_seeds.append(seed)
            elif self.split is not None:
                episode_seeds.append(self.split.draw(self._rngs[i]))
            else:
                episode_seeds.append(int(self._rngs[i].integers(0, 2**63 - 1)))
        episodes = simulate_many(self.spec_scenario, episode_seeds)
        self._load(rows, episodes)
        m = len(rows)
        priors = [ep.priors.as_info() for ep in episodes]
        self._add_infos(infos, {"priors": {key: [p[key] for p in priors] for key in priors[0]},
                                "n_pulses": [len(ep) for ep in episodes], "lag": [self.lag] * m,
                                "has_amplitude": [ep.amplitude is not None for ep in episodes],
                                "has_descriptors": [bool(self.descriptors)] * m,
                                "scenario": [self.spec_scenario.name] * m}, rows)

    def _load(self, rows: list[int], episodes: list[Episode]) -> None:
        """Put the episodes in the rows' tables, episodes of one length with one copy a table."""
        lengths = np.array([len(ep) for ep in episodes])
        if lengths.max() + 1 > self._cap:
            self._allocate(int(lengths.max()) + 1)
        for i, episode in zip(rows, episodes):
            self.episodes[i] = episode
        rows_a = np.array(rows)
        for n in np.unique(lengths).tolist():  # (simulated episodes all have n_pulses: one length)
            sel = np.flatnonzero(lengths == n)
            r, eps = rows_a[sel], [episodes[j] for j in sel.tolist()]
            self._toa[r, :n] = np.array([ep.toa for ep in eps])
            self._toa[r, n:] = 0.0
            # One scenario's episodes all carry amplitudes, or none does.
            self._amp[r, :n] = 0.0 if eps[0].amplitude is None else np.array([ep.amplitude for ep in eps])
            self._amp[r, n:] = 0.0
            for name in self.descriptors:
                table = getattr(self, f"_{name}")
                table[r, :n] = np.array([getattr(ep, name) for ep in eps])
                table[r, n:] = 0.0
            if not self.blind:
                source, mask = np.array([ep.source for ep in eps]), np.array([ep.mask for ep in eps])
                self._right[r, :n] = np.where(source >= 0, mask, np.uint64(0))
                if self.n_labels > 64:
                    self._src[r, :n] = source
        if self.blind:
            self._has_alt[rows_a] = False
            self._last[rows_a, :-1] = NO_PRED
            for i, ep in zip(rows, episodes):
                truth = true_predecessors(ep.source, ep.mask)
                self._pred[i, :len(ep)] = truth.pred
                self._has_alt[i, truth.alt_pulse] = True
                self._alt[i] = truth.alternatives()
        self._n[rows_a] = lengths
        self._end[rows_a] = lengths + self.lag
        self._k[rows_a] = 0
        self._score[rows_a] = 0.0

    def _add_infos(self, vector_infos: dict[str, Any], values: dict[str, Any], rows: list[int]) -> dict[str, Any]:
        """Gymnasium's `_add_info` for many sub-envs at once: `values[key]` lists the `rows`' infos."""
        for key, value in values.items():
            if isinstance(value, dict):
                array = self._add_infos(vector_infos.get(key, {}), value, rows)
            else:
                array = vector_infos.get(key)
                first = value[0]
                if array is None:  # the batch dtype gymnasium gives the first sub-env's value
                    if type(first) in (int, float, bool) or isinstance(first, np.number):
                        array = np.zeros(self.num_envs, dtype=type(first))
                    elif isinstance(first, np.ndarray):
                        array = np.zeros((self.num_envs, *first.shape), dtype=first.dtype)
                    else:
                        array = np.full(self.num_envs, None, dtype=object)
                array[rows] = np.array(value) if isinstance(first, np.ndarray) else value
            mask = vector_infos.get(f"_{key}", np.zeros(self.num_envs, dtype=np.bool_))
            mask[rows] = True
            vector_infos[key], vector_infos[f"_{key}"] = array, mask
        return vector_infos

    # ---- gymnasium API -------------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        check_reset_options(options)
        seeds = self._seeds(seed)
        super().reset(seed=int(seed) if isinstance(seed, (int, np.integer)) else None)
        infos: dict[str, Any] = {}
        self._start(list(range(self.num_envs)), seeds, infos)
        self._prev_done[:] = False
        self._any_done = False
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
            if s is not None and self.split is not None:
                self.split.check(int(s))
        return [None if s is None else int(s) for s in seeds]

    def step(self, actions):
        if not self._started:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(actions)
        if a.shape != (self.num_envs,) or a.dtype.kind not in "iu":
            raise DeintError(f"actions must be {self.num_envs} integer labels, got {actions!r}")
        spur = self.n_labels
        k, prev_done = self._k, self._prev_done
        # j: the pulse each sub-env labels (< 0 during the first `lag` steps).  j < 0 (lag steps) reads
        # and writes column 0, j = n (finished sub-envs) the padding column: both are masked out of
        # the rewards and overwritten before they matter.
        if self.lag:
            j = k - self.lag
            labelling = (j >= 0) & ~prev_done
            jf = self._base + np.maximum(j, 0)
        else:  # (j is k itself: read before k moves on)
            j, labelling, jf = k, ~prev_done, self._base + k
        if a.min() < 0 or a.max() > spur:
            bad = np.flatnonzero(labelling & ((a < 0) | (a > spur)))
            if bad.size:
                raise DeintError(f"actions[{bad[0]}]={a[bad[0]]!r} is invalid: a label in [0, {spur}]"
                                 f" ({spur} = spurious)")
            a = np.clip(a, 0, spur)  # the out-of-range actions are ignored ones; keep them indexable
        a = a.astype(np.int64, copy=False)
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
            if self.n_labels > 64:
                ok |= (a >= 64) & (a < spur) & (self._src.reshape(-1)[jf] == a)
        reward = (ok & labelling).astype(np.float64)
        self._labels.reshape(-1)[jf] = a
        self._score += reward
        k += 1

        infos: dict[str, Any] = {}
        if self._any_done:
            restart = prev_done.nonzero()[0].tolist()
            self._start(restart, [None] * len(restart), infos)
        terminated = k == self._end
        self._any_done = bool(terminated.any())
        if self._any_done:
            infos["episode_accuracy"] = np.where(terminated, self._score / self._n, math.nan)
            infos["_episode_accuracy"] = terminated.copy()
            if self.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP:
                final = self._observation()
                infos["final_obs"] = np.array([{key: v[i] for key, v in final.items()} if t else None
                                               for i, t in enumerate(terminated.tolist())], dtype=object)
                infos["_final_obs"] = terminated.copy()
                restart = terminated.nonzero()[0].tolist()
                self._start(restart, [None] * len(restart), infos)
                self._any_done = False
        self._prev_done = terminated.copy() if self._any_done else np.zeros(self.num_envs, bool)
        return self._observation(), reward, terminated, np.zeros(self.num_envs, bool), infos

    def _observation(self) -> dict[str, np.ndarray]:
        # Columns past n hold zeros; only the lag's padding steps run past the last column.
        f = self._base + (np.minimum(self._k, self._cap - 1) if self.lag else self._k)
        return {"toa": self._toa.reshape(-1)[f][:, None], "amplitude": self._amp.reshape(-1)[f][:, None],
                **{name: getattr(self, f"_{name}").reshape(-1)[f][:, None] for name in self.descriptors},
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

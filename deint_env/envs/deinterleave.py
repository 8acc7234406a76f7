"""The single deinterleaving environment: one received pulse per step, one label per step."""

from __future__ import annotations

import copy
import math
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from deint_env.episode import DESCRIPTORS, Episode, Priors
from deint_env.errors import DeintError, shown
from deint_env.labels import NO_PRED, SPURIOUS_PRED, true_predecessors
from deint_env.metrics import label_metrics, metric_keys, n_sources
from deint_env.scenario import ScenarioSpec
from deint_env.sim.streams import check_seed
from deint_env.simulate import simulate
from deint_env.suites import SPLITS, SuiteEntry, find_entry, list_suites, load_suite, resolve_scenario

DEFAULT_SCENARIO = "paper-v0/mk94-two-var1"
_BIG = float(np.finfo(np.float64).max)  # TOAs may be any finite float64; Gymnasium warns on infinite bounds


TDC_PREFIX = "tdc:"  # scenario="tdc:PATH" plays a challenge file's pulses
TDC_LABELS = 128  # the label budget of a challenge file played blind (the TSRD's scenes hold up to 90 emitters)


def observation_space(descriptors: tuple[str, ...] = ()) -> spaces.Dict:
    """Raw pulse observations: float64 TOA and amplitude (0 when the scenario has none), `valid` (0 on
    the padding steps that follow the last pulse when lag > 0) and the pulse descriptors the scenario
    has (`frequency`, `pulse_width`, `aoa`: float64; none for a TOA-only scenario)."""
    box = spaces.Box(-_BIG, _BIG, shape=(1,), dtype=np.float64)
    return spaces.Dict({"toa": box, "amplitude": box, "valid": spaces.Discrete(2),
                        **{name: box for name in descriptors}})


def _tdc_episode(path: str) -> Episode:
    """A challenge file's pulses as one blind episode, its labels as the truth."""
    from deint_env.formats.tdc import read_tdc

    if not path:
        raise DeintError("scenario='tdc:' names no file: scenario='tdc:PATH' with PATH a TDC (HDF5) file")
    train = read_tdc(path)
    if train.labels is None:
        raise DeintError(f"{path}: has no 'labels' dataset; scenario='tdc:PATH' plays a file's labels as the truth")
    return train.episode(Priors(n_labels=TDC_LABELS, blind=True), name=f"{TDC_PREFIX}{path}")


def check_reset_options(options: Any) -> None:
    """The envs take no reset options: one they would ignore (a typo, a wrapper's) is refused, not dropped."""
    if options is not None and not (isinstance(options, dict) and not options):
        raise DeintError(f"options={shown(options)} is invalid: these envs take no reset options (None or {{}})")


def check_lag(lag: object) -> int:
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or not 0 <= int(lag) <= 10_000:
        raise DeintError(f"lag={lag!r} is invalid: an integer in [0, 10000]")
    return int(lag)


class SplitRange(NamedTuple):
    """The seeds an env restricted to one split of a suite scenario may play."""

    split: str
    scenario: str  # "suite/scenario", for the error messages
    seeds: range
    entry: SuiteEntry

    def check(self, seed: int) -> None:
        if seed not in self.seeds:
            other = [s for s in SPLITS if s != self.split and seed in self.entry.seeds(s)]
            what = f"a {other[0]} seed" if other else "not a seed of any split"
            raise DeintError(f"seed={seed} is {what} of {self.scenario}: this env (split={self.split!r}) plays "
                             f"{self.split} seeds [{self.seeds.start}, {self.seeds.stop}) only")

    def draw(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.seeds.start, self.seeds.stop))


def split_seeds(scenario: ScenarioSpec | str | dict | None, spec: ScenarioSpec | None,
                split: object) -> SplitRange | None:
    """The split's seed ranges of a suite scenario (named, or a spec equal to a suite's), or None."""
    if split is None:
        return None
    if split not in SPLITS:
        raise DeintError(f"split={split!r} is invalid: None, 'train', 'validation' or 'test'")
    if isinstance(scenario, str):
        entry, suite = find_entry(scenario), scenario.split("/", 1)[0] if "/" in scenario else None
    else:
        found = [(s, e) for s in list_suites() for e in load_suite(s) if spec is not None and e.spec == spec]
        if not found:
            name = spec.name if spec is not None else None
            raise DeintError(f"split={split!r} needs a suite scenario (its seed ranges); scenario {name!r} is in "
                             "no suite: name one as SUITE/SCENARIO, or use split=None")
        suite, entry = found[0]
    suite = suite or next(s for s in list_suites() if any(e is entry for e in load_suite(s)))
    return SplitRange(split, f"{suite}/{entry.name}", entry.seeds(split), entry)


def _label(action: Any) -> int | None:
    """The label an action names, or None: an integer (Python or numpy, or a one-element integer array,
    as vectorised agents hand over), never a float, a string or a boolean that int() would coerce."""
    if isinstance(action, np.ndarray):
        ok = action.size == 1 and action.ndim <= 1 and action.dtype.kind in "iu"
        return int(action.reshape(())) if ok else None
    if isinstance(action, (bool, np.bool_)) or not isinstance(action, (int, np.integer)):
        return None
    return int(action)


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
    observation carries pulse k (raw float64 TOA; amplitude 0 when the scenario has none).  A scenario
    with pulse descriptor words (`DescriptorSpec`) adds `frequency` (MHz), `pulse_width` (us) and `aoa`
    (degrees), each Box(float64, (1,)); a challenge file adds the ones it has.  After the last pulse
    come D padding observations with valid = 0 (descriptors 0).  Learned agents use the float32
    feature wrapper `deint_env.wrappers.PulseFeatures`.

    ## Rewards
    1.0 for a right label, else 0.0.  Anchored: right if it names the pulse's source (any of them for
    a merged pulse) or "spurious" for a spurious pulse.  Blind: right if the label's previous pulse is
    the pulse's true predecessor in its source ("none" for a source's first pulse); a spurious pulse
    is right only when labelled spurious.  See `deint_env.labels`.

    ## Starting State
    `reset(seed=s)` plays episode `simulate(scenario, s)`; `reset()` draws the episode seed from the
    env's generator (from the split's seed range with `split=`).  With `scenario="tdc:PATH"` every
    reset plays the file's pulses (the seed only seeds `np_random`).

    ## Info
    The same keys, with values of the same type and shape, at reset and at every step, so that
    recorders (Minari's `DataCollector(record_infos=True)`) can stack them:
    - `priors`: at reset, the public priors (`Priors.as_info()`: periods, phases, their spreads,
      source probabilities, jitter, ...; never the truth); on the steps a placeholder of the same
      keys, types and shapes with every float -inf (`n_labels` and `blind` kept);
    - `n_pulses` (int), `lag` (int), `has_amplitude` (bool), `has_descriptors` (bool: the observations
      carry pulse descriptors), `scenario` (str);
    - `metrics`: the episode's label metrics (`deint_env.metrics.label_metrics`, with the clustering
      scores unless `clustering_metrics=False`, and `lag`) on the last step; before it a placeholder:
      every float -inf, `n_pulses` 0, `pe` all -inf.  In the info `pe` (per-source error probability
      P_e^i) is a float64 array with one entry per source present in the episode (NaN for a source
      without pulses); `metrics()` gives the JSON form (a list, None for a source without pulses).
    Placeholders are -inf rather than NaN because Gymnasium's env checker compares step infos with
    `==`; every info holds fresh containers, as that checker also asks.

    ## Episode End
    Terminates (`terminated=True`) on the step that labels the last pulse, i.e. after n_pulses + D
    steps.  Never truncates; wrap with `TimeLimit` to cut episodes short.  The last step's info holds
    the episode's `metrics`.

    ## Arguments
    `scenario`: a ScenarioSpec, its dict, or a scenario name ("suite/scenario" or a unique bare name;
    default "paper-v0/mk94-two-var1"), or "tdc:PATH": a Turing Deinterleaving Challenge file played as
    one blind episode (label budget 128), its labels as the truth (a file without labels is refused).
    `lag`: decision delay D >= 0.  `render_mode`: None, "ansi", "human" or "rgb_array" (see Rendering).  `clustering_metrics`: whether the metrics include the
    clustering scores (V-measure, ARI, AMI, ...; True; computed with numpy from the contingency table,
    ~0.3 ms for a 500-pulse episode).  `split`: None, "train", "validation" or "test": play only that split's seeds of a suite
    scenario; a reset with any other seed raises `DeintError`.

    ## Rendering
    Only pulses already labelled are drawn, so rendering never shows the truth of a pending pulse.
    - "ansi": `render()` returns a text table of the last labelled pulses, label beside truth.
    - "rgb_array": `render()` returns a 480x720x3 uint8 frame: each labelled pulse at its TOA (x) against
      its ΔTOA, the time since the previous received pulse (y, log scale), coloured by the agent's labels
      (left panel) and by the true sources (middle; spurious grey), beside a PRI histogram on the same
      ΔTOA axis (grey: ΔTOAs; coloured: intervals between consecutive pulses given the same label).
    - "human": the same frame in a matplotlib window (the `plot` extra), drawn by `reset()` and every
      `step()` at most `render_fps` times a second; `render()` returns None and `close()` closes the
      window.  Under a file-only backend (MPLBACKEND=Agg) frames are drawn and nothing is shown.

    ## Version History
    - v0: initial release.
    - v0, later: the rgb_array frame became the ΔTOA-against-TOA picture with a PRI histogram, and
      render_mode "human" was added (rendering only: dynamics, spaces and rewards are unchanged, so
      the id stays v0).
    """

    metadata = {"render_modes": ["ansi", "human", "rgb_array"], "render_fps": 30}

    def __init__(self, scenario: ScenarioSpec | str | dict | None = DEFAULT_SCENARIO, lag: int = 0,
                 render_mode: str | None = None, clustering_metrics: bool = True, split: str | None = None, *,
                 n_labels: int | None = None, blind: bool = False):
        # scenario=None (with n_labels) makes an env that only plays given episodes: see `for_episode`.
        if scenario is not None and (n_labels is not None or blind is not False):
            raise DeintError(f"n_labels={n_labels!r}, blind={blind!r}: these are for scenario=None (an env that "
                             f"plays given episodes); a scenario fixes its own label count and mode")
        if scenario is None and (not isinstance(n_labels, (int, np.integer)) or isinstance(n_labels, bool)
                                 or n_labels < 1 or not isinstance(blind, (bool, np.bool_))):
            raise DeintError(f"n_labels={n_labels!r}, blind={blind!r} are invalid: scenario=None needs an integer "
                             f"n_labels >= 1 and blind true or false")
        if not isinstance(clustering_metrics, (bool, np.bool_)):
            raise DeintError(f"clustering_metrics={clustering_metrics!r} is invalid: True or False")
        self._file_episode = None
        if isinstance(scenario, str) and scenario.startswith(TDC_PREFIX):
            if split is not None:
                raise DeintError(f"split={split!r} is for suite scenarios; a challenge file has no seed splits")
            self._file_episode = _tdc_episode(scenario[len(TDC_PREFIX):])
            n_labels, blind, scenario = TDC_LABELS, True, None
        self.spec_scenario = resolve_scenario(scenario) if scenario is not None else None
        self.split = split_seeds(scenario, self.spec_scenario, split)
        self.lag = check_lag(lag)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise DeintError(f"render_mode={render_mode!r} is invalid: None, 'ansi', 'human' or 'rgb_array'")
        self.render_mode = render_mode
        # human: matplotlib is checked now (one clear line), its window opens at the first frame
        self._window = None
        if render_mode == "human":
            from deint_env.envs.render import Window

            self._window = Window(self.metadata["render_fps"])
        self.clustering_metrics = clustering_metrics
        self.n_labels = self.spec_scenario.n_labels if self.spec_scenario is not None else int(n_labels)
        self.blind = self.spec_scenario.blind if self.spec_scenario is not None else blind
        self.action_space = spaces.Discrete(self.n_labels + 1)
        self.descriptors = (DESCRIPTORS if self.spec_scenario is not None and self.spec_scenario.has_descriptors
                            else tuple(self._file_episode.descriptors) if self._file_episode is not None else ())
        self.observation_space = observation_space(self.descriptors)
        self.episode: Episode | None = None
        self._step = 0
        self._scored = True

    @classmethod
    def for_episode(cls, episode: Episode, lag: int = 0, clustering_metrics: bool = True,
                    scored: bool = True) -> DeinterleaveEnv:
        """An env that plays one given episode (e.g. read from a pulse file); call `load_episode`.
        `scored=False`: no metrics on the last step (labelling a file: its truth, if any, is not wanted,
        and the Hungarian matching would load scipy for nothing)."""
        env = cls(None, lag=lag, clustering_metrics=clustering_metrics, n_labels=episode.n_labels,
                  blind=episode.blind)
        env._scored = scored
        env.descriptors = tuple(episode.descriptors)
        env.observation_space = observation_space(env.descriptors)
        return env

    # ---- gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        check_reset_options(options)
        if seed is not None:  # a numpy integer too: gymnasium's seeding takes Python ints only (its own error)
            seed = check_seed(seed)
        super().reset(seed=seed)
        if self._file_episode is not None:
            return self.load_episode(self._file_episode)
        if self.spec_scenario is None:
            raise gym.error.Error("this env plays given episodes only: use load_episode()")
        if seed is not None and self.split is not None:
            self.split.check(seed)
        if seed is not None:
            episode_seed = seed
        elif self.split is not None:
            episode_seed = self.split.draw(self.np_random)
        else:
            episode_seed = int(self.np_random.integers(0, 2**63 - 1))
        return self.load_episode(simulate(self.spec_scenario, episode_seed))

    def load_episode(self, episode: Episode) -> tuple[dict[str, Any], dict[str, Any]]:
        """Play a given episode (simulated, or read from a pulse file) from its first pulse; returns
        the first observation and the reset info, like `reset`."""
        if not self._fits(episode):
            raise DeintError(f"episode has {episode.n_labels} labels (blind={episode.blind}); this env expects "
                             f"{self.n_labels} (blind={self.blind})")
        missing = [name for name in self.descriptors if getattr(episode, name) is None]
        if missing:
            raise DeintError(f"episode has no {', '.join(missing)}; this env observes {', '.join(self.descriptors)}")
        self.episode = episode
        n = len(episode)
        self._n = n
        self._toa = episode.toa
        self._amp = episode.amplitude if episode.amplitude is not None else np.zeros(n)
        self._desc = [(name, getattr(episode, name)) for name in self.descriptors]
        # The label check reads the primary source first: a Python list indexes faster than numpy,
        # and its small ints are shared objects, so it costs one pointer a pulse.
        self._src = episode.source.tolist()
        self.labels = np.full(n, -1, dtype=np.int64)
        self._step = 0
        self._final: dict[str, Any] | None = None
        if self.blind:
            truth = true_predecessors(episode.source, episode.mask)
            self._pred = truth.pred.tolist()
            self._alt = truth.alternatives()
            self._last = [NO_PRED] * self.n_labels
        self._n_sources = n_sources(episode.source, episode.mask)
        self._pending = self._placeholder_metrics()
        reset_info = self._reset_info()
        # Every step's info has the reset info's structure; priors and metrics are placeholders where
        # they carry nothing (see the class doc).
        self._step_info = reset_info | {"priors": _placeholder(reset_info["priors"])}
        self._step_arrays = [k for k, v in self._step_info["priors"].items() if type(v) is np.ndarray]
        reset_info["metrics"] = _placeholder(self._pending)
        if self.render_mode == "human":
            self.render()
        return self._observation(0), reset_info

    def _fits(self, episode: Episode) -> bool:
        return episode.n_labels == self.n_labels and episode.blind == self.blind

    def step(self, action):
        if self.episode is None or self._step >= self._n + self.lag:
            raise gym.error.ResetNeeded("call reset() before step() and after the episode ends")
        j = self._step - self.lag
        reward = 0.0
        if j >= 0:
            a = _label(action)
            if a is None or not 0 <= a <= self.n_labels:
                raise DeintError(f"action={action!r} is invalid: a label in [0, {self.n_labels}]"
                                 f" ({self.n_labels} = spurious)")
            self.labels[j] = a
            reward = 1.0 if self._is_correct(j, a) else 0.0
        self._step += 1
        terminated = j == self._n - 1
        # Fresh containers every step (Gymnasium's checker forbids infos that share mutable objects);
        # copying the templates is the cheapest way to make them.
        info = self._step_info.copy()
        priors = info["priors"] = info["priors"].copy()
        for k in self._step_arrays:
            priors[k] = priors[k].copy()
        if terminated and self._scored:
            self._final = self.metrics()
            info["metrics"] = _info_metrics(self._final)
        elif terminated:
            info["metrics"] = {}
        else:
            info["metrics"] = pending = self._pending.copy()
            pending["pe"] = pending["pe"].copy()
        if self.render_mode == "human":
            self.render()
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
        """Label metrics of the pulses labelled so far (all of them once the episode has ended), in
        JSON form (`pe` a list, None for a source without pulses)."""
        done = max(0, min(self._step - self.lag, self._n))
        if done == self._n and self._final is not None:
            return copy.deepcopy(self._final)  # computed on the last step
        ep = self.episode
        m = label_metrics(self.labels[:done], ep.source[:done], ep.mask[:done], self.n_labels, self.blind,
                          clustering=self.clustering_metrics)
        m["lag"] = self.lag
        return m

    def _placeholder_metrics(self) -> dict[str, Any]:
        keys = (*metric_keys(self.clustering_metrics), "lag")
        out: dict[str, Any] = dict.fromkeys(keys, -math.inf)
        out.update(n_pulses=0, pe=np.full(self._n_sources, -math.inf), lag=self.lag)
        return out

    def _observation(self, k: int) -> dict[str, Any]:
        if k < self._n:
            obs = {"toa": self._toa[k:k + 1].copy(), "amplitude": self._amp[k:k + 1].copy(), "valid": np.int64(1)}
            for name, values in self._desc:
                obs[name] = values[k:k + 1].copy()
            return obs
        return {"toa": np.zeros(1), "amplitude": np.zeros(1), "valid": np.int64(0),
                **{name: np.zeros(1) for name, _ in self._desc}}

    def _reset_info(self) -> dict[str, Any]:
        return {"priors": self.episode.priors.as_info(), "n_pulses": self._n, "lag": self.lag,
                "has_amplitude": self.episode.amplitude is not None, "has_descriptors": bool(self.descriptors),
                "scenario": self.episode.scenario}

    def render(self):
        """ansi: a text table of the last labelled pulses; rgb_array: the ΔTOA-against-TOA picture of the
        labelled pulses (`deint_env.envs.render.render_rgb`); human: that picture in a window (returns
        None; reset() and step() call it).  Pending pulses are never drawn: their truth stays hidden."""
        if self.render_mode is None:
            gym.logger.warn("render() needs render_mode='ansi', 'human' or 'rgb_array' at construction")
            return None
        done = max(0, min(self._step - self.lag, self._n)) if self.episode is not None else 0
        ep = self.episode
        args = (ep.toa[:done], self.labels[:done], ep.source[:done], self.n_labels) if ep is not None else (
            np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int32), self.n_labels)
        from deint_env.envs.render import render_ansi, render_rgb

        if self.render_mode == "ansi":
            return render_ansi(*args)
        frame = render_rgb(*args)
        if self._window is None:
            return frame
        self._window.show(frame)
        return None

    def close(self):
        if self._window is not None:
            self._window.close()


def _placeholder(d: dict[str, Any]) -> dict[str, Any]:
    """A fresh copy of `d` with every float, and every float array's entries, -inf."""
    return {k: np.full_like(v, -math.inf) if type(v) is np.ndarray and v.dtype.kind == "f"
            else -math.inf if type(v) is float else v for k, v in d.items()}


def _info_metrics(m: dict[str, Any]) -> dict[str, Any]:
    """The metrics as the info carries them: `pe` as a float64 array (NaN for a source without
    pulses), so that every step's info has the same structure."""
    out = dict(m)
    out["pe"] = np.array([math.nan if v is None else v for v in m["pe"]], dtype=np.float64)
    return out

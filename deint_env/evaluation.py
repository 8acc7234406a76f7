"""`deint_env.evaluate`: your own policy or model on a suite's episodes, scored as a board scores it.

    import deint_env
    result = deint_env.evaluate(model, suite="core-v0", max_seeds=3)      # a stable-baselines3 model
    result = deint_env.evaluate("agent:checkpoint=agent.safetensors", scenarios=["core-v0/core-n3-spread4-jitter0.05"])
    result.score, result.accuracy, result.records; print(result.table())

The policy is a spec string (played by the runner, in worker processes with `workers > 1`), an object
with the policy protocol (`lag`, `reset(priors, info)`, `act(obs)`), or a stable-baselines3 model
trained on `deint_env/DeinterleaveTokens-v0` (duck-typed: it has `predict`, `policy` and
`observation_space`).  A model is played through `SB3Policy`, which computes the token observations
as the env does and calls `model.predict` (with the action masks when its `predict` takes them, as
sb3-contrib's MaskablePPO's does); its look-ahead, hence its lag, is read from its observation space.
Nothing here imports torch or stable-baselines3: the model brings them.

The default split is "validation" (choices: checkpoints, settings, versions).  `split="test"` plays
the test seeds, with a warning: they are for a finished agent's one look, as boards count their looks
(docs/design.md 7a).  The records are `deint run`'s (`EpisodeRecord`), and the summary is the row
`deint run` and the boards compute from them (`runner.summarise`: normalised score mean and IQM with
stratified-bootstrap intervals from 3 seeds per scenario on, accuracy, every metric of the table).
"""

from __future__ import annotations

import inspect
import warnings
from collections import Counter
from typing import Any, NamedTuple, Sequence

import numpy as np

from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable, shown
from deint_env.features import TrackFeatures, TrackLayout
from deint_env.metrics import SCORE
from deint_env.results import EpisodeRecord


class Evaluation(NamedTuple):
    policy: str  # the name the records carry (a spec's canonical form, or the name given)
    split: str
    records: list[EpisodeRecord]  # one per episode, faulted and not-applicable ones included
    summary: dict[str, Any]  # the entry's row as `deint run` and the boards compute it

    @property
    def score(self) -> tuple[float, float, float]:
        """The normalised score's mean and its 95 % interval (NaN bounds below 3 seeds per scenario)."""
        s = self.summary
        return s[f"{SCORE}_mean"], s[f"{SCORE}_mean_low"], s[f"{SCORE}_mean_high"]

    @property
    def accuracy(self) -> float:
        return self.summary["accuracy"]

    def table(self) -> str:
        """The summary as `deint run` prints it."""
        from deint_env.runner import format_table

        return format_table([self.summary])


def is_sb3_model(obj: Any) -> bool:
    return all(hasattr(obj, a) for a in ("predict", "policy", "observation_space"))


class SB3Policy:
    """A stable-baselines3 model trained on `DeinterleaveTokens-v0`, as a deint policy: the token
    observations are computed from the raw ones exactly as the env computes them (`TrackFeatures`),
    and each label is `model.predict(..., deterministic=True)`'s track (masked, for a model whose
    `predict` takes `action_masks`).  A recurrent model (sb3-contrib's RecurrentPPO) steps its memory
    on every env step, as it did in training, and starts each episode afresh."""

    def __init__(self, model: Any):
        layout = TrackLayout.from_space(model.observation_space)
        if layout is None:
            raise DeintError(f"{type(model).__name__}'s observation space is not a token layout of "
                             f"DeinterleaveTokens-v0 (a Dict of tracks, mask and pulse): {model.observation_space}")
        self.layout, self.lag = layout, layout.lookahead
        self._model = model
        self._masked = "action_masks" in inspect.signature(model.predict).parameters
        self._recurrent = hasattr(model.policy, "lstm_actor")  # sb3-contrib's recurrent policies
        self._tokens = TrackFeatures(1, layout)
        self._spurious = 0
        self._state: Any = None
        self._start = True

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if priors.n_labels > self.layout.max_tracks:
            raise NotApplicable(f"the model holds at most {self.layout.max_tracks} tracks; this scenario has "
                                f"{priors.n_labels}")
        self._tokens.reset_rows([0], [priors], [bool(info.get("has_amplitude", False))])
        self._spurious = priors.n_labels
        self._state, self._start = None, True

    def act(self, obs: dict[str, Any]) -> int:
        tok = self._tokens
        tok.observe(obs["toa"], obs["amplitude"], obs["valid"])
        ready = bool(tok.ready[0])
        if not (ready or self._recurrent):
            return 0  # labels nothing (a look-ahead or padding step); a masked predict would see no track
        kwargs = {"action_masks": tok.action_masks()} if self._masked else {}
        action, self._state = self._model.predict(tok.observation(), state=self._state,
                                                  episode_start=np.array([self._start]), deterministic=True,
                                                  **kwargs)
        self._start = False
        if not ready:
            return 0
        track = np.asarray(action).reshape(1).astype(np.int64)
        tok.label(track)
        return int(tok.env_actions(track, self._spurious)[0])


def evaluate(policy: Any, *, suite: str | None = None, scenarios: Sequence[str] | None = None,
             split: str = "validation", max_seeds: int | None = None, workers: int = 1, name: str | None = None,
             progress: bool = True) -> Evaluation:
    """Play `policy` (a spec string, a policy object or an SB3 model: module doc) on every seed of
    `split` of a suite or of the named scenarios (the first `max_seeds` of each) and summarise it.
    `workers > 1` needs a spec string (an object cannot be sent to worker processes); `name` names an
    object's records (default: its class name)."""
    from deint_env.progress import progress_bar
    from deint_env.runner import evaluate as run, run_job, summarise, target_jobs

    if (suite is None) == (not scenarios):
        raise DeintError("name a suite= or some scenarios= (SUITE/SCENARIO names), not both")
    if not isinstance(progress, (bool, np.bool_)):
        raise DeintError(f"progress={progress!r} is invalid: True or False")
    if isinstance(policy, type):  # its lag, reset and act are unbound functions: it would play as nonsense
        raise DeintError(f"policy={policy.__name__} is a class; pass a policy object ({policy.__name__}(...)) or a "
                         f"policy spec string")
    if suite is not None and not isinstance(suite, str):  # `"/" in 5` below was a TypeError
        raise DeintError(f"suite={shown(suite)} is invalid: a suite name (a string; see `deint suites`)")
    if isinstance(scenarios, str):
        raise DeintError(f"scenarios={scenarios!r} is invalid: a list of SUITE/SCENARIO names")
    if suite is not None and "/" not in suite:
        from deint_env.suites import load_suite

        load_suite(suite)  # an unknown suite named as one (a target name is otherwise looked up as a scenario)
    targets = [suite] if suite is not None else list(scenarios or ())
    bad = [t for t in targets if not isinstance(t, str)]
    if bad:  # a ScenarioSpec reached the runner's name lookup (TypeError: not iterable)
        raise DeintError(f"scenarios holds {shown(bad[0])}: a list of SUITE/SCENARIO names (strings)")
    twice = [t for t, n in Counter(map(str, targets)).items() if n > 1]
    if twice:  # its seeds were played and counted twice
        raise DeintError(f"scenarios names {twice[0]!r} twice; name each scenario once")
    if split == "test":
        warnings.warn("split='test' plays the test seeds: they are for a finished agent's one look (boards count "
                      "every look); choose checkpoints and settings on split='validation'", stacklevel=2)
    if isinstance(policy, str):
        if name is not None:
            raise DeintError(f"name={name!r}: a policy spec names its own records; name= is for objects")
        records = [r for t in targets for r in run([policy], t, split=split, max_seeds=max_seeds, workers=workers,
                                                    progress=progress)]
    else:
        player = SB3Policy(policy) if is_sb3_model(policy) else policy
        if not all(hasattr(player, a) for a in ("lag", "reset", "act")):
            raise DeintError(f"{type(policy).__name__} is neither a policy (lag, reset, act), a policy spec string "
                             "nor a stable-baselines3 model")
        if workers != 1:
            raise DeintError(f"workers={workers!r}: an in-memory policy plays in this process (workers=1); "
                             "save it as a checkpoint and pass its spec to play it on worker processes")
        name = name or type(policy).__name__
        jobs = [j for t in targets for j in target_jobs([(name, getattr(player, "version", 1))], t, split, max_seeds)]
        bar = progress_bar(len(jobs), desc=name, enabled=progress)
        records = []
        for job in jobs:
            records.append(run_job(job, player))
            bar.update(1)
        bar.close()
    if not records:
        raise DeintError(f"no episode to play: {', '.join(targets)} has no {split} seeds")
    rows = summarise(records)
    return Evaluation(rows[0]["policy"], split, records, rows[0])

"""The `agent` policy: any deint checkpoint, evaluated from that one file (`agent:checkpoint=PATH`).

The checkpoint's JSON names the architecture and the feature layout; the policy rebuilds the
network (`agents.networks.build_policy`), fills it from the safetensors weights, and acts on the
same features the agent trained on (the token layout 2 of `deint_env.features`, or the flat pulse
layout 1 of `deint_env.wrappers`).  Its lag is the layout's look-ahead.  A recurrent network
(RecurrentPPO's) carries its LSTM state from step to step, stepping on every env step as in training
(look-ahead and padding steps too, which label nothing), and starts each episode from zeros.
`version` is the checkpoint's content hash: records of a retrained checkpoint written to the same
path never pass for the old one.
`ppo` is this policy on the checked-in two-source checkpoint.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agents.ablation import NETWORK, network_off
from agents.beam import VERSION as BEAM_VERSION
from agents.beam import BeamDecoder
from agents.checkpoint import Checkpoint, load_checkpoint
from agents.fast_net import NumpyTrackNet
from agents.networks import (PulseLayout, RecurrentTrackPolicy, action_scores, build_policy, layout_from_dict,
                             load_weights, recurrent_scores)
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.features import TrackFeatures
from deint_env.params import REQUIRED, Param, declare
from deint_env.policies import policy_rng
from deint_env.wrappers import FeatureTracker

CHECKPOINT_DIR = Path(__file__).resolve().parent / "checkpoints"
PPO_CHECKPOINT = CHECKPOINT_DIR / "ppo-two-source.safetensors"
DAGGER_CHECKPOINT = CHECKPOINT_DIR / "dagger-core-v0-lag3.safetensors"
ZOO_CHECKPOINT = CHECKPOINT_DIR / "dagger-all-lag3.safetensors"  # core-v0 + robust-v0 + agile-v0, layout 3
ZOO_CONSISTENCY = 0.0  # measured on train seeds: the value head did not change the scores (README)


@functools.lru_cache(maxsize=8)
def _load(path: str, mtime_ns: int, size: int) -> tuple[Checkpoint, Any]:
    """Checkpoint and rebuilt network, once per process and file version (the runner builds a policy
    per episode); a file replaced on disk has another (mtime, size) and is read again."""
    ck = load_checkpoint(path)
    net = build_policy(ck.meta.architecture, ck.meta.features)
    load_weights(net, ck.tensors, f"checkpoint {path}")
    return ck, net


def load_agent(checkpoint: str | os.PathLike) -> tuple[Checkpoint, Any]:
    path = Path(checkpoint).resolve()
    try:
        st = path.stat()
    except OSError:
        raise DeintError(f"checkpoint {checkpoint} does not exist (train one with `deint train`)") from None
    return _load(str(path), st.st_mtime_ns, st.st_size)


def checkpoint_version(checkpoint: str | os.PathLike) -> str:
    """The content key a results file should store for `agent:checkpoint=PATH` (see `Checkpoint.key`)."""
    return load_agent(checkpoint)[0].key


PARAMS = declare(
    Param("checkpoint", str, REQUIRED, "the deint checkpoint file (PATH.safetensors)"),
    Param("deterministic", bool, True, "the likeliest label (false: sampled, seeded by the runner's policy seed)"),
    NETWORK,
)
BEAM_PARAMS = declare(
    PARAMS["checkpoint"],
    Param("beam", int, 8, "hypotheses kept", low=1, high=4096),
    Param("decision_lag", int, 8, "pulses after its first score that a label is decided (added to the lag)", low=0,
          high=1000),
    Param("consistency", float, 0.0, "the weight of the value head's whole-hypothesis score (needs a checkpoint "
          "trained for it)", low=0),
    NETWORK,
)


class AgentPolicy:
    """A learned agent from a checkpoint (module doc).  `deterministic=False` samples its labels,
    seeded per episode from the runner's policy seed."""

    PARAMS = PARAMS

    def __init__(self, checkpoint: str, deterministic: bool = True, network: str = "on"):
        PARAMS.only("deterministic").check(locals())  # checkpoint: a str or a path
        self.checkpoint = str(Path(checkpoint).resolve())
        self.deterministic = deterministic
        self._off = network_off(network)
        torch.set_num_threads(1)  # a batch of one observation: thread hand-offs cost more than they save
        ck, self._net = load_agent(self.checkpoint)
        self.meta, self.version = ck.meta, ck.key
        self.layout = layout_from_dict(ck.meta.features)
        self.lag = self.layout.lookahead
        self._name = Path(self.checkpoint).name
        self._rng: np.random.Generator | None = None
        self._recurrent = isinstance(self._net, RecurrentTrackPolicy)
        self._state: tuple[torch.Tensor, torch.Tensor] | None = None
        if isinstance(self.layout, PulseLayout):
            self._tracker: FeatureTracker | None = FeatureTracker(self.layout.n_labels, lag=0)
            self._tokens: TrackFeatures | None = None
        else:
            self._tracker, self._tokens = None, TrackFeatures(1, self.layout)

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if isinstance(self.layout, PulseLayout):
            if priors.blind:
                raise NotApplicable(f"agent {self._name} uses the pulse features, which need anchored priors; "
                                    "blind scenarios have none")
            if priors.n_labels != self.layout.n_labels:
                raise NotApplicable(f"agent {self._name} was trained for {self.layout.n_labels} tracks "
                                    f"({', '.join(self.meta.scenarios)}); this scenario has {priors.n_labels}")
            self._tracker.reset(priors)
        else:
            if priors.n_labels > self.layout.max_tracks:
                raise NotApplicable(f"agent {self._name} holds at most {self.layout.max_tracks} tracks; this "
                                    f"scenario has {priors.n_labels}")
            self._tokens.reset_rows([0], [priors], [bool(info.get("has_amplitude", False))])
            self._spurious = priors.n_labels
            if self._recurrent:
                self._state = self._net.initial_state(1)
        self._rng = None if self.deterministic else policy_rng(info, None)

    def _scores(self, features: np.ndarray) -> np.ndarray:
        """The network's action scores, or with `network=off` all 0 (its output zeroed: no forward pass)."""
        if self._off:
            return np.zeros(self.layout.n_actions)
        return action_scores(self._net, features)[0].numpy()

    def _choose(self, scores: np.ndarray, mask: np.ndarray | None) -> int:
        scores = scores.astype(np.float64)
        if mask is not None:
            scores = np.where(mask, scores, -np.inf)
        if self._rng is None:
            return int(np.argmax(scores))
        p = np.exp(scores - scores.max())
        return int(self._rng.choice(len(p), p=p / p.sum()))

    def act(self, obs: dict[str, Any]) -> int:
        if self._tracker is not None:
            tracker = self._tracker
            tracker.observe(obs)
            if not tracker.ready:
                return 0
            label = self._choose(self._scores(tracker.features()[None, :]), None)
            tracker.label(label)
            return label
        tok = self._tokens
        tok.observe(obs["toa"], obs["amplitude"], obs["valid"])
        if self._recurrent and not self._off:  # the memory steps on every env step, as it did in training
            logits, self._state = recurrent_scores(self._net, tok.observation(), self._state, np.zeros(1))
        if not tok.ready[0]:
            return 0  # labels nothing (a look-ahead step or a padding step)
        if self._off:
            scores = np.zeros(tok.action_masks().shape[1])
        else:
            scores = (logits if self._recurrent else action_scores(self._net, tok.observation()))[0].numpy()
        action = self._choose(scores, tok.action_masks()[0])
        tok.label(np.array([action]))
        return int(tok.env_actions(np.array([action]), self._spurious)[0])


def agent(checkpoint: str, deterministic: bool = True, network: str = "on") -> Any:
    """`agent:checkpoint=PATH`: the agent of any deint checkpoint, rebuilt as its architecture says
    (the sequence labeller's by `agents.sequence.SequencePolicy`, an mht scorer's by `agents.lmht.LMHT`;
    both always deterministic)."""
    from agents import lmht
    from agents.sequence import ARCHITECTURE, SequencePolicy

    name = load_checkpoint(checkpoint).meta.architecture.get("name")
    if name == ARCHITECTURE:
        return SequencePolicy(checkpoint, network=network)
    if name == lmht.ARCHITECTURE:
        return lmht.LMHT(checkpoint, network=network)
    return AgentPolicy(checkpoint, deterministic, network)


agent.PARAMS = PARAMS  # type: ignore[attr-defined]


class BeamPolicy:
    """A track-network checkpoint decoded with a beam (`agents.beam`): `beam` hypotheses, each
    pulse's label decided `decision_lag` pulses after the network first scores it; the policy's lag
    is the network's look-ahead plus `decision_lag`; `consistency` weighs the value head's whole-hypothesis
    score (agents.beam).  `version` is the checkpoint's content hash and the decoder's version."""

    PARAMS = BEAM_PARAMS

    def __init__(self, checkpoint: str, beam: int = 8, decision_lag: int = 8, consistency: float = 0.0,
                 network: str = "on"):
        BEAM_PARAMS.only("beam", "decision_lag", "consistency").check(locals())
        off = network_off(network)
        self.checkpoint = str(Path(checkpoint).resolve())
        ck, _ = load_agent(self.checkpoint)
        if ck.meta.architecture.get("name") != "track-net":
            raise DeintError(f"checkpoint {checkpoint} holds a {ck.meta.architecture.get('name')!r} network; the "
                             "beam decoder reads log-probabilities of a 'track-net' (actor-critic) network")
        layout = layout_from_dict(ck.meta.features)
        self.meta = ck.meta
        self.version = f"{ck.key}/beam-{BEAM_VERSION}"
        if consistency and not ck.meta.hyperparameters.get("consistency_weight"):
            raise DeintError(f"consistency={consistency} needs a checkpoint whose value head was trained for it "
                             f"(DAgger with consistency_weight > 0); {checkpoint} was not")
        self._decoder = BeamDecoder(numpy_net(self.checkpoint, off), layout, beam, decision_lag, consistency=consistency)
        self.lag = layout.lookahead + self._decoder.decision_lag

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self._decoder.start(priors, bool(info.get("has_amplitude", False)))
        self._n = priors.n_labels

    def act(self, obs: dict[str, Any]) -> int:
        label = self._decoder.step(float(np.asarray(obs["toa"]).reshape(-1)[0]),
                                   float(np.asarray(obs["amplitude"]).reshape(-1)[0]), bool(obs["valid"]))
        return 0 if label is None else label  # label n (spurious) is the env's spurious label n as well


# the track network's output layers: the tracks' score read-out and the spurious logit
_OUTPUT_LAYERS = ("score.2.weight", "score.2.bias", "spurious.weight", "spurious.bias")


@functools.lru_cache(maxsize=8)
def _numpy_net(path: str, mtime_ns: int, size: int, off: bool) -> NumpyTrackNet:
    ck, _ = _load(path, mtime_ns, size)
    tensors = dict(ck.tensors)
    if off:  # every candidate's logit 0: uniform log-probabilities, the beam search alone
        for key in [k for k in tensors if k.endswith(_OUTPUT_LAYERS)]:
            tensors[key] = tensors[key] * 0
    return NumpyTrackNet(tensors, ck.meta.architecture.get("heads", 4))


def numpy_net(checkpoint: str | os.PathLike, off: bool = False) -> NumpyTrackNet:
    """The checkpoint's actor as numpy matrices (`off`: its output layers zeroed), once per process and
    file version."""
    path = Path(checkpoint).resolve()
    st = path.stat()
    return _numpy_net(str(path), st.st_mtime_ns, st.st_size, off)


def dagger(deterministic: bool = True, network: str = "on") -> AgentPolicy:
    """The zoo's DAgger agent for core-v0 (`deint train --suite core-v0 --algo dagger`)."""
    return AgentPolicy(str(DAGGER_CHECKPOINT), deterministic, network)


dagger.PARAMS = PARAMS.only("deterministic", "network")  # type: ignore[attr-defined]


def dagger_beam(beam: int = 8, decision_lag: int = 20, consistency: float = ZOO_CONSISTENCY,
                network: str = "on") -> BeamPolicy:
    """The zoo's agent for core-v0, robust-v0 and agile-v0 together: DAgger on their train seeds
    (agents/hyperparams/dagger-all.yml), decoded with a beam."""
    return BeamPolicy(str(ZOO_CHECKPOINT), beam, decision_lag, consistency, network)


dagger_beam.PARAMS = BEAM_PARAMS.only(  # type: ignore[attr-defined]
    "beam", "decision_lag", "consistency", "network").changed(decision_lag=20, consistency=ZOO_CONSISTENCY)


def ppo(checkpoint: str | None = None, deterministic: bool = True, network: str = "on") -> AgentPolicy:
    """The checked-in PPO agent (two sources), or another checkpoint."""
    return AgentPolicy(str(PPO_CHECKPOINT) if checkpoint is None else checkpoint, deterministic, network)


ppo.PARAMS = PARAMS.changed(checkpoint=None)  # type: ignore[attr-defined]


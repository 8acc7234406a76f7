"""The `agent` policy: any deint checkpoint, evaluated from that one file (`agent:checkpoint=PATH`).

The checkpoint's JSON names the architecture and the feature layout; the policy rebuilds the
network (`agents.networks.build_policy`), fills it from the safetensors weights, and acts on the
same features the agent trained on (the token layouts 2 and 3 of `deint_env.features`, or the flat
pulse layout 1 of `deint_env.wrappers`).  Its lag is the layout's look-ahead.  At play time the track
network and SB3's MlpPolicy run as compiled copies of the weights (`agents.fast_net`), which give
torch's labels (checked on every core-v0 scenario) at a small fraction of its per-call cost; the
policy plays many episodes in lock-step too (`deint_env.policies.BatchPolicy`), as the runner does.  A recurrent network
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
from agents.fast_net import MLPLogits, NumpyTrackNet, TrackLogits
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
    seeded per episode from the runner's policy seed.

    It is a `deint_env.policies.BatchPolicy`: `reset_batch(K)`, `reset_row`, `act_batch` play K episodes
    in lock-step (`deint_env.runner.play_batch`), their features computed together and their pulses
    scored in one call; `reset`/`act` are a batch of one.  The track network (`track-net`) and SB3's
    MlpPolicy (`sb3-mlp`) are scored by the compiled, batch-invariant copies of `agents.fast_net`
    (torch's per-call overhead is most of a step's time at a batch of one; those copies make a row's
    labels independent of the other rows); other networks (DQN's, the recurrent one) by torch, one row
    per call, so a batch labels as each episode alone does."""

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
        self._recurrent = isinstance(self._net, RecurrentTrackPolicy)
        self._fast = None if self._off else fast_logits(self.checkpoint)
        self.reset_batch(1)

    # ---- a batch of episodes (deint_env.policies.BatchPolicy) -------------------------------------------
    def reset_batch(self, n: int) -> None:
        """`n` rows, each idle until `reset_row` starts an episode in it."""
        self._n_rows = n
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._spurious = np.zeros(n, np.int64)
        if isinstance(self.layout, PulseLayout):
            self._trackers = [FeatureTracker(self.layout.n_labels, lag=0) for _ in range(n)]
        else:
            self._tokens = TrackFeatures(n, self.layout)
            self._states: list[tuple[torch.Tensor, torch.Tensor] | None] = [None] * n

    def reset_row(self, row: int, priors: Priors, info: dict[str, Any]) -> None:
        if isinstance(self.layout, PulseLayout):
            if priors.blind:
                raise NotApplicable(f"agent {self._name} uses the pulse features, which need anchored priors; "
                                    "blind scenarios have none")
            if priors.n_labels != self.layout.n_labels:
                raise NotApplicable(f"agent {self._name} was trained for {self.layout.n_labels} tracks "
                                    f"({', '.join(self.meta.scenarios)}); this scenario has {priors.n_labels}")
            self._trackers[row].reset(priors)
        else:
            if priors.n_labels > self.layout.max_tracks:
                raise NotApplicable(f"agent {self._name} holds at most {self.layout.max_tracks} tracks; this "
                                    f"scenario has {priors.n_labels}")
            self._tokens.reset_rows([row], [priors], [bool(info.get("has_amplitude", False))])
            if self._recurrent:
                self._states[row] = self._net.initial_state(1)
        self._spurious[row] = priors.n_labels
        self._rngs[row] = None if self.deterministic else policy_rng(info, None)

    def act_batch(self, rows: np.ndarray, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The labels of `rows` (their episodes' next steps) from their stacked raw observations."""
        if isinstance(self.layout, PulseLayout):
            return self._act_pulse(rows, obs)
        tok = self._tokens
        toa, amp, valid = np.zeros(self._n_rows), np.zeros(self._n_rows), np.zeros(self._n_rows, bool)
        toa[rows], amp[rows] = np.reshape(obs["toa"], -1), np.reshape(obs["amplitude"], -1)
        valid[rows] = obs["valid"]
        tok.observe(toa, amp, valid)  # idle rows take a padding observation: they hold no pulse, so stay idle
        is_ready = tok.ready[rows]
        ready = rows[is_ready]
        if self._recurrent and not self._off:  # the memory steps on every env step, as it did in training
            full = tok.observation()
            logits = {}
            for r in rows.tolist():
                logits[r], self._states[r] = recurrent_scores(
                    self._net, {k: v[r:r + 1] for k, v in full.items()}, self._states[r], np.zeros(1))
        actions = np.zeros(self._n_rows, np.int64)
        if ready.size:
            masks = tok.action_masks()
            if self._off:
                scores = np.zeros((len(ready), masks.shape[1]))
            elif self._recurrent:
                scores = np.concatenate([logits[r].numpy() for r in ready.tolist()])
            else:
                scores = self._token_scores(ready)
            actions[ready] = self._choose(ready, scores, masks[ready])
            tok.label(actions)
        # a row that labels nothing (a look-ahead or padding step) answers 0, which the env ignores
        return np.where(is_ready, tok.env_actions(actions, self._spurious)[rows], 0)

    def _token_scores(self, ready: np.ndarray) -> np.ndarray:
        """The network's action scores of the `ready` rows' observations."""
        tok = self._tokens
        if self.layout.flat:
            x = tok.observation()[ready]
            if self._fast is not None:
                return self._fast(x)
            return np.concatenate([action_scores(self._net, x[i:i + 1]).numpy() for i in range(len(x))])
        tracks, pulse = tok.arrays()
        if self._fast is not None:
            return self._fast(tracks[ready], pulse[ready], tok.n_labels[ready])
        mask = tok.exists.astype(np.float32)
        return np.concatenate([action_scores(self._net, {"tracks": tracks[r:r + 1], "mask": mask[r:r + 1],
                                                         "pulse": pulse[r:r + 1]}).numpy() for r in ready.tolist()])

    def _act_pulse(self, rows: np.ndarray, obs: dict[str, np.ndarray]) -> np.ndarray:
        out = np.zeros(len(rows), np.int64)
        ready = []
        for i, r in enumerate(rows.tolist()):
            tracker = self._trackers[r]
            tracker.observe({"toa": obs["toa"][i], "amplitude": obs["amplitude"][i], "valid": obs["valid"][i]})
            if tracker.ready:
                ready.append(i)
        if not ready:
            return out
        features = np.stack([self._trackers[rows[i]].features() for i in ready])
        if self._off:
            scores = np.zeros((len(ready), self.layout.n_actions))
        elif self._fast is not None:
            scores = self._fast(features)
        else:
            scores = np.concatenate([action_scores(self._net, f[None, :]).numpy() for f in features])
        out[ready] = self._choose(rows[ready], scores, None)
        for i in ready:
            self._trackers[rows[i]].label(int(out[i]))
        return out

    def _choose(self, rows: np.ndarray, scores: np.ndarray, masks: np.ndarray | None) -> np.ndarray:
        """Each row's action from its scores (K, A): the likeliest allowed one, or one drawn from the
        softmax by the row's own generator (`deterministic=False`)."""
        scores = scores.astype(np.float64)
        if masks is not None:
            scores = np.where(masks, scores, -np.inf)
        actions = np.argmax(scores, axis=1)
        if not self.deterministic:
            for i, r in enumerate(rows.tolist()):
                p = np.exp(scores[i] - scores[i].max())
                actions[i] = self._rngs[r].choice(len(p), p=p / p.sum())
        return actions

    # ---- one episode (deint_env.policies.Policy) ------------------------------------------------------
    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self.reset_batch(1)
        self.reset_row(0, priors, info)

    def act(self, obs: dict[str, Any]) -> int:
        return int(self.act_batch(_ROW0, {"toa": obs["toa"][None], "amplitude": obs["amplitude"][None],
                                          "valid": np.reshape(obs["valid"], 1)})[0])


_ROW0 = np.zeros(1, np.int64)


def agent(checkpoint: str, deterministic: bool = True, network: str = "on") -> Any:
    """`agent:checkpoint=PATH`: the agent of any deint checkpoint, rebuilt as its architecture says
    (the sequence labeller's by `agents.sequence.SequencePolicy`, an mht scorer's by `agents.lmht.LMHT`,
    the PDW metric labeller's by `agents.pdw_metric.PDWMetricPolicy`; all always deterministic)."""
    from agents import lmht, pdw_metric
    from agents.sequence import ARCHITECTURE, SequencePolicy

    name = load_checkpoint(checkpoint).meta.architecture.get("name")
    if name == ARCHITECTURE:
        return SequencePolicy(checkpoint, network=network)
    if name == pdw_metric.ARCHITECTURE:
        return pdw_metric.PDWMetricPolicy(checkpoint, network=network)
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


@functools.lru_cache(maxsize=8)
def _fast_logits(path: str, mtime_ns: int, size: int) -> TrackLogits | MLPLogits | None:
    ck, _ = _load(path, mtime_ns, size)
    arch, layout = ck.meta.architecture, layout_from_dict(ck.meta.features)
    if arch.get("name") == "track-net":
        return TrackLogits(_numpy_net(path, mtime_ns, size, False), len(layout.token_names))
    if arch.get("name") == "sb3-mlp":
        return MLPLogits(ck.tensors, arch["net_arch"], arch.get("activation", "tanh"))
    return None


def fast_logits(checkpoint: str | os.PathLike) -> TrackLogits | MLPLogits | None:
    """The checkpoint's actor logits as a compiled batch-invariant function (`agents.fast_net`), or None
    for a network it does not cover (DQN's, the recurrent one: torch scores those), once per process and
    file version."""
    path = Path(checkpoint).resolve()
    st = path.stat()
    return _fast_logits(str(path), st.st_mtime_ns, st.st_size)


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


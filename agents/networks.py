"""Policy networks and their rebuilding from a checkpoint's JSON (no pickles anywhere).

`TrackPolicy` / `MaskableTrackPolicy` / `TrackDQNPolicy` are stable-baselines3 policy classes for the
token observation of `deint_env.features`: one shared scorer per track token (so the network is
permutation-equivariant over tracks and plays any number of them up to the layout's maximum), a
spurious score and a value from a masked pooling over the tracks, and optionally one self-attention
layer across the tracks (a track's score can then depend on the others: "this pulse fits track 2
only because track 5's prediction is far").  Absent tracks get a logit of -1e8, so even plain PPO or
DQN never picks them; MaskablePPO's masks agree.  `RecurrentTrackPolicy` (sb3-contrib's RecurrentPPO)
adds an LSTM memory over the episode: it reads each step's pooled summary, and every track is scored
from its embedding and the memory; `recurrent_scores` steps it, carrying the LSTM state.

`build_policy(meta)` rebuilds the SB3 policy module a checkpoint describes (architecture name and
keyword arguments from an allow-list, spaces from the feature layout), and `load_weights` fills it
from the checkpoint's tensors, checking every name and shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.dqn.policies import DQNPolicy
from torch import nn

from deint_env.errors import DeintError
from deint_env.features import TrackLayout
from deint_env.wrappers import FEATURE_VERSION, feature_space

MASKED = -1e8  # the logit of an absent track


# ---- feature layouts a checkpoint can name ---------------------------------------------------------
@dataclass(frozen=True)
class PulseLayout:
    """Layout 1 (`deint_env.wrappers.PulseFeatures`): a flat vector for exactly `n_labels` tracks."""

    n_labels: int
    version: int = FEATURE_VERSION
    lookahead: int = 0

    def observation_space(self) -> spaces.Box:
        return feature_space(self.n_labels)

    @property
    def n_actions(self) -> int:
        return self.n_labels + 1

    def to_dict(self) -> dict[str, Any]:
        return {"layout": "pulse", "n_labels": self.n_labels, "version": self.version}


def layout_from_dict(d: dict[str, Any]) -> TrackLayout | PulseLayout:
    if d.get("layout") == "pulse":
        if d.get("version") != FEATURE_VERSION:
            raise DeintError(f"pulse feature layout version {d.get('version')!r}; this deint_env computes "
                             f"{FEATURE_VERSION}: retrain the agent")
        n = d.get("n_labels")
        if not isinstance(n, int) or not 1 <= n <= 256:
            raise DeintError(f"pulse feature layout n_labels={n!r} is invalid")
        return PulseLayout(n)
    return TrackLayout.from_dict(d)


# ---- the track network ------------------------------------------------------------------------------
class TrackExtractor(BaseFeaturesExtractor):
    """Token observation -> [track logits (M), spurious logit, value latent (d_model)]."""

    def __init__(self, observation_space: spaces.Dict, d_model: int = 64, attention: bool = True, heads: int = 4):
        m, f = observation_space["tracks"].shape
        g = observation_space["pulse"].shape[0]
        super().__init__(observation_space, features_dim=m + 1 + d_model)
        self.max_tracks = m
        self.embed = nn.Sequential(nn.Linear(f + g, d_model), nn.ReLU(), nn.Linear(d_model, d_model), nn.ReLU())
        self.attention = nn.MultiheadAttention(d_model, heads, batch_first=True) if attention else None
        self.norm = nn.LayerNorm(d_model) if attention else None
        self.score = nn.Sequential(nn.Linear(d_model, d_model), nn.ReLU(), nn.Linear(d_model, 1))
        self.pool = nn.Sequential(nn.Linear(2 * d_model + g, d_model), nn.ReLU())
        self.spurious = nn.Linear(d_model, 1)

    def encode(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(track embeddings (B, M, d), track mask (B, M) bool, pooled summary (B, d))."""
        tokens, pulse = obs["tracks"], obs["pulse"]
        mask = obs["mask"] > 0.5
        h = self.embed(torch.cat([tokens, pulse[:, None, :].expand(-1, tokens.shape[1], -1)], dim=-1))
        any_track = mask.any(dim=1, keepdim=True)
        if self.attention is not None:
            # A row without tracks (an all-zero terminal observation) attends to everything rather than NaN.
            ignore = ~(mask | ~any_track)
            a, _ = self.attention(h, h, h, key_padding_mask=ignore, need_weights=False)
            h = self.norm(h + a)
        w = mask.unsqueeze(-1).to(h.dtype)
        mean = (h * w).sum(1) / w.sum(1).clamp(min=1.0)
        top = torch.where(any_track, (h + (w - 1.0) * 1e4).amax(1), torch.zeros_like(mean))
        return h, mask, self.pool(torch.cat([mean, top, pulse], dim=-1))

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        h, mask, pooled = self.encode(obs)
        scores = self.score(h).squeeze(-1).masked_fill(~mask, MASKED)
        return torch.cat([scores, self.spurious(pooled), pooled], dim=-1)


class SplitLatent(nn.Module):
    """The mlp_extractor of the track policies: the extractor already made the logits."""

    def __init__(self, n_actions: int, latent_dim_vf: int):
        super().__init__()
        self.n_actions = n_actions
        self.latent_dim_pi, self.latent_dim_vf = n_actions, latent_dim_vf

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return features[:, :self.n_actions]

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return features[:, self.n_actions:]


class _TrackActorCritic:
    def __init__(self, observation_space, action_space, lr_schedule, d_model: int = 64, attention: bool = True,
                 heads: int = 4, **kwargs):
        kwargs["features_extractor_class"] = TrackExtractor
        kwargs["features_extractor_kwargs"] = dict(d_model=d_model, attention=attention, heads=heads)
        kwargs.setdefault("ortho_init", False)
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        n = int(self.action_space.n)
        self.mlp_extractor = SplitLatent(n, self.features_dim - n)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = nn.Identity()  # the logits come straight from the per-track scorer
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)


class TrackPolicy(_TrackActorCritic, ActorCriticPolicy):
    """The track network for PPO and A2C."""


class MaskableTrackPolicy(_TrackActorCritic, MaskableActorCriticPolicy):
    """The track network for sb3-contrib's MaskablePPO."""


class _FirstColumns(nn.Module):
    def __init__(self, n: int):
        super().__init__()
        self.n = n

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return features[:, :self.n]


class TrackDQNPolicy(DQNPolicy):
    """The track network for DQN: the per-track scores and the spurious score are the Q-values."""

    def __init__(self, observation_space, action_space, lr_schedule, d_model: int = 64, attention: bool = True,
                 heads: int = 4, **kwargs):
        kwargs["features_extractor_class"] = TrackExtractor
        kwargs["features_extractor_kwargs"] = dict(d_model=d_model, attention=attention, heads=heads)
        kwargs.setdefault("net_arch", [])
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def make_q_net(self):
        q = super().make_q_net()
        q.q_net = _FirstColumns(int(self.action_space.n))
        return q


# ---- the recurrent track network (sb3-contrib RecurrentPPO) -------------------------------------------
class RecurrentTrackExtractor(TrackExtractor):
    """The track encoder without its heads: [track embeddings (M*d), track mask (M), pooled summary (d)].
    The heads come after the LSTM (`RecurrentTrackHeads`), so every track is scored against the memory."""

    def __init__(self, observation_space: spaces.Dict, d_model: int = 64, attention: bool = True, heads: int = 4):
        super().__init__(observation_space, d_model, attention, heads)
        del self.score, self.spurious  # they read the memory too: RecurrentTrackHeads
        self._features_dim = self.max_tracks * (d_model + 1) + d_model

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        h, mask, pooled = self.encode(obs)
        return torch.cat([h.flatten(1), mask.to(h.dtype), pooled], dim=-1)


class TrackMemory(nn.Module):
    """The LSTM of the recurrent track policy, called as sb3-contrib calls an `nn.LSTM` (input
    (seq, batch, input_size), states (h, c)): it reads the pooled summary of each step and passes the
    track embeddings through, so its output is [embeddings, mask, pooled, memory]."""

    def __init__(self, input_size: int, d_model: int, hidden_size: int, num_layers: int):
        super().__init__()
        self.input_size, self.d_model = input_size, d_model
        self.lstm = nn.LSTM(d_model, hidden_size, num_layers=num_layers)

    @property
    def hidden_size(self) -> int:
        return self.lstm.hidden_size

    @property
    def num_layers(self) -> int:
        return self.lstm.num_layers

    def forward(self, x: torch.Tensor, states: tuple[torch.Tensor, torch.Tensor]):
        memory, states = self.lstm(x[..., -self.d_model:], states)
        return torch.cat([x, memory], dim=-1), states


class RecurrentTrackHeads(nn.Module):
    """The mlp_extractor of `RecurrentTrackPolicy`: each track's logit from its embedding and the
    memory (one shared scorer, so still permutation-equivariant), spurious and value from [pooled, memory]."""

    def __init__(self, max_tracks: int, d_model: int, hidden_size: int):
        super().__init__()
        self.m, self.d = max_tracks, d_model
        self.latent_dim_pi, self.latent_dim_vf = max_tracks + 1, d_model + hidden_size
        self.score = nn.Sequential(nn.Linear(d_model + hidden_size, d_model), nn.ReLU(), nn.Linear(d_model, 1))
        self.spurious = nn.Linear(d_model + hidden_size, 1)

    def forward(self, latent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(latent), self.forward_critic(latent)

    def forward_actor(self, latent: torch.Tensor) -> torch.Tensor:
        m, d = self.m, self.d
        h = latent[:, :m * d].reshape(-1, m, d)
        mask = latent[:, m * d:m * (d + 1)] > 0.5
        summary = latent[:, m * (d + 1):]  # [pooled, memory]
        memory = summary[:, None, d:].expand(-1, m, -1)
        scores = self.score(torch.cat([h, memory], dim=-1)).squeeze(-1).masked_fill(~mask, MASKED)
        return torch.cat([scores, self.spurious(summary)], dim=-1)

    def forward_critic(self, latent: torch.Tensor) -> torch.Tensor:
        return latent[:, self.m * (self.d + 1):]


class RecurrentTrackPolicy(RecurrentActorCriticPolicy):
    """The track network with an LSTM memory over the episode's steps, for sb3-contrib's RecurrentPPO:
    encoder (RecurrentTrackExtractor) -> TrackMemory -> RecurrentTrackHeads.  The critic has its own
    TrackMemory (sb3-contrib's default, `enable_critic_lstm`)."""

    def __init__(self, observation_space, action_space, lr_schedule, d_model: int = 64, attention: bool = True,
                 heads: int = 4, lstm_hidden_size: int = 64, n_lstm_layers: int = 1, **kwargs):
        kwargs["features_extractor_class"] = RecurrentTrackExtractor
        kwargs["features_extractor_kwargs"] = dict(d_model=d_model, attention=attention, heads=heads)
        kwargs.setdefault("ortho_init", False)
        self.d_model = d_model  # _build_mlp_extractor (called by the base __init__) needs it
        super().__init__(observation_space, action_space, lr_schedule, lstm_hidden_size=lstm_hidden_size,
                         n_lstm_layers=n_lstm_layers, shared_lstm=False, enable_critic_lstm=True, **kwargs)
        # The base made plain LSTMs over all features; ours read the pooled summary only.
        self.lstm_actor = TrackMemory(self.features_dim, d_model, lstm_hidden_size, n_lstm_layers)
        self.lstm_critic = TrackMemory(self.features_dim, d_model, lstm_hidden_size, n_lstm_layers)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = RecurrentTrackHeads(self.observation_space["tracks"].shape[0], self.d_model,
                                                 self.lstm_output_dim)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = nn.Identity()  # the logits come straight from the per-track scorer

    def initial_state(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The actor's zero (h, c) for `n` episodes."""
        shape = (self.lstm_actor.num_layers, n, self.lstm_actor.hidden_size)
        return torch.zeros(shape), torch.zeros(shape)


# ---- rebuilding from JSON ----------------------------------------------------------------------------
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
ARCHITECTURES = ("sb3-mlp", "track-net", "track-dqn", "recurrent-track-net")


def _constant(_: float) -> float:
    return 0.0


def build_policy(architecture: dict[str, Any], features: dict[str, Any]) -> BasePolicy:
    """The policy module an architecture JSON names, for the observation space of `features`."""
    arch = dict(architecture)
    name = arch.pop("name", None)
    layout = layout_from_dict(features)
    obs_space, act_space = layout.observation_space(), spaces.Discrete(layout.n_actions)
    try:
        if name == "sb3-mlp":
            if isinstance(obs_space, spaces.Dict):
                raise DeintError("architecture 'sb3-mlp' needs a flat feature layout")
            act = arch.pop("activation", "tanh")
            if act not in ACTIVATIONS:
                raise DeintError(f"activation {act!r} is unknown; known: {', '.join(ACTIVATIONS)}")
            net_arch = arch.pop("net_arch")
            if arch:
                raise TypeError(f"unexpected keys {sorted(arch)}")
            return ActorCriticPolicy(obs_space, act_space, _constant, net_arch=list(net_arch),
                                     activation_fn=ACTIVATIONS[act])
        if name in ("track-net", "track-dqn"):
            if not isinstance(obs_space, spaces.Dict):
                raise DeintError(f"architecture {name!r} needs the token (non-flat) feature layout")
            cls = TrackPolicy if name == "track-net" else TrackDQNPolicy
            return cls(obs_space, act_space, _constant, **arch)
        if name == "recurrent-track-net":
            if not isinstance(obs_space, spaces.Dict):
                raise DeintError(f"architecture {name!r} needs the token (non-flat) feature layout")
            return RecurrentTrackPolicy(obs_space, act_space, _constant, **arch)
    except (TypeError, KeyError, ValueError) as e:
        if isinstance(e, DeintError):
            raise
        raise DeintError(f"architecture {name!r}: bad parameters ({e})") from None
    raise DeintError(f"architecture {name!r} is unknown; known: {', '.join(ARCHITECTURES)}")


def architecture_of(policy: BasePolicy) -> dict[str, Any]:
    """The JSON that `build_policy` turns back into `policy`'s module."""
    if isinstance(policy, RecurrentTrackPolicy):
        fx = policy.features_extractor
        return {"name": "recurrent-track-net", "d_model": policy.d_model, "attention": fx.attention is not None,
                "heads": fx.attention.num_heads if fx.attention is not None else 4,
                "lstm_hidden_size": policy.lstm_actor.hidden_size, "n_lstm_layers": policy.lstm_actor.num_layers}
    if isinstance(policy, (_TrackActorCritic, TrackDQNPolicy)):
        fx = policy.q_net.features_extractor if isinstance(policy, TrackDQNPolicy) else policy.features_extractor
        name = "track-dqn" if isinstance(policy, TrackDQNPolicy) else "track-net"
        return {"name": name, "d_model": fx.pool[0].out_features, "attention": fx.attention is not None,
                "heads": fx.attention.num_heads if fx.attention is not None else 4}
    if type(policy) in (ActorCriticPolicy, MaskableActorCriticPolicy):
        kw = policy._get_constructor_parameters()
        act = next(k for k, v in ACTIVATIONS.items() if v is kw["activation_fn"])
        net_arch = kw["net_arch"]
        if isinstance(net_arch, dict):
            if net_arch.get("pi") != net_arch.get("vf"):
                raise DeintError("only MLPs with the same actor and critic layers are saved")
            net_arch = net_arch["pi"]
        return {"name": "sb3-mlp", "net_arch": list(net_arch), "activation": act}
    raise DeintError(f"policy class {type(policy).__name__} has no checkpoint architecture")


def weights_of(policy: nn.Module) -> dict[str, torch.Tensor]:
    """Parameters and buffers, each shared tensor once (SB3 shares the features extractor)."""
    return {**dict(policy.named_parameters()), **dict(policy.named_buffers())}


def load_weights(policy: nn.Module, tensors: dict[str, torch.Tensor], where: str) -> None:
    expected = weights_of(policy)
    if set(tensors) != set(expected):
        extra, missing = sorted(set(tensors) - set(expected)), sorted(set(expected) - set(tensors))
        raise DeintError(f"{where}: its tensors do not match its architecture "
                         f"({'unexpected ' + extra[0] if extra else 'missing ' + missing[0]})")
    with torch.no_grad():
        for name, target in expected.items():
            t = tensors[name]
            if t.shape != target.shape or t.dtype != target.dtype:
                raise DeintError(f"{where}: tensor {name} is {tuple(t.shape)} {t.dtype}, the architecture needs "
                                 f"{tuple(target.shape)} {target.dtype}")
            target.copy_(t)
    policy.eval()


def action_scores(policy: BasePolicy, obs: dict[str, np.ndarray] | np.ndarray) -> torch.Tensor:
    """Logits (actor-critic) or Q-values (DQN) of a batch of observations (float32, already in the
    layout's range, so SB3's observation preprocessing is skipped: it costs more than the network
    on a batch of one)."""
    with torch.inference_mode():
        x: Any = ({k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in obs.items()} if isinstance(obs, dict)
                  else torch.from_numpy(np.ascontiguousarray(obs)))
        if isinstance(policy, DQNPolicy):
            return policy.q_net.q_net(policy.q_net.features_extractor(x))
        features = policy.pi_features_extractor(x)
        return policy.action_net(policy.mlp_extractor.forward_actor(features))


def recurrent_scores(policy: RecurrentTrackPolicy, obs: dict[str, np.ndarray],
                     states: tuple[torch.Tensor, torch.Tensor],
                     starts: np.ndarray) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Logits of one step of `len(starts)` episodes and the actor's next LSTM states; rows with
    `starts` set begin an episode (their states are zeroed first, as in RecurrentPPO's rollouts)."""
    with torch.inference_mode():
        x = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in obs.items()}
        features = policy.pi_features_extractor(x)
        latent, states = policy._process_sequence(features, states, torch.as_tensor(starts, dtype=torch.float32),
                                                  policy.lstm_actor)
        return policy.action_net(policy.mlp_extractor.forward_actor(latent)), states

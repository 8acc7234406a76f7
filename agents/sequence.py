"""`seq`: a supervised pointer-style sequence labeller, the deep-deinterleaving baseline (blind mode).

For each pulse j the model looks at the `window` pulses before it and the `lag` pulses after it (its
look-ahead equals its lag) and scores which of the `window` earlier pulses is j's predecessor in the
same train, or "new" (a train's first pulse) or "spurious".  Each earlier pulse i is a token whose
features are measured relative to j: its gap d = t_j - t_i (scale-free: over the visible pulses'
mean spacing) and the lattice evidence for a train of PRI d through i and j — how close the visible
pulses come to t_i - m d (m = 1..3), to the midpoint (a train of PRI d/2) and to t_j + m d (the
look-ahead) — plus the amplitude difference when the pulses carry one.  A Transformer encoder over
the window's tokens (and learned "new" and "spurious" tokens) lets candidates compare (a gap against
its harmonics, two candidates of like gap); one linear read-out gives the pointer logits, and a
chain head adds, per candidate, how its own chain's last two intervals agree with d.

It is trained on simulator truth (`deint_env.labels.true_predecessors`) on train seeds only, with a
cross-entropy over the pointer classes; the chain features come from the true chains (a share of
links hidden) or, for a share of episodes (`own_chains`), from the agent's own decoding, so that it
learns how far its own chains can be trusted.  Decoding turns pointers into blind labels: labels are
chains, pulse j joins the chain whose last pulse scores highest (a pulse already continued is no
longer offered, so every chain stays a chain), or opens one on a fresh label (else the least
recently used), or is called spurious; when its favourite predecessor is already continued (by more
than `margin` logits) it opens a chain rather than take another chain's place.  Features depend only
on pulses up to j + lag, so a label never depends on pulses beyond the lag.  The encoder runs over a
batch of pulses in one pass (`batch=B` encodes B pulses at once, lag + B - 1, for speed); the chain
head and the decoder run pulse by pulse.

Anchored mode (priors given) is not played: mapping chains to the priors' sources is left undone.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np
import torch
from torch import nn

from agents.ablation import NETWORK, network_off
from agents.config import TrainConfig, TrainResult
from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.labels import NO_PRED, SPURIOUS_PRED, correct_link, true_predecessors
from deint_env.params import Param, declare

ARCHITECTURE = "seq-pointer"
FEATURE_LAYOUT = "pointer-pairs"
FEATURE_VERSION = 2
DEFAULT_MARGIN = 2.0  # ChainDecoder's margin in play (chosen on validation seeds: 0 and 1e9 did worse)
# a longer record is refused (reset): at about 1.6 ms a pulse (10^4 pulses: 16 s of CPU) 25,000 take 40 s; the
# 10^5 it allowed took minutes
MAX_PULSES = 25_000
DECODER_VERSION = 2  # bump when ChainDecoder's labels change: results are keyed on it with the checkpoint
BACK_MULTIPLES = (1.0, 2.0, 3.0)  # t_i - m d
FORWARD_MULTIPLES = (1.0, 2.0, 3.0)  # t_j + m d (the look-ahead)
N_FEATURES = 2 + 3 * (len(BACK_MULTIPLES) + 1 + len(FORWARD_MULTIPLES)) + 2
N_CHAIN = 6  # chain features per candidate (`chain_features`)


@dataclass(frozen=True)
class SeqLayout:
    """The feature layout: candidates per pulse, pulses visible before it, look-ahead (= lag)."""

    window: int = 64
    context: int = 256
    lag: int = 32

    def __post_init__(self):
        for name, lo in (("window", 1), ("context", 1), ("lag", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= 10_000:
                raise DeintError(f"{name}={v!r} is invalid: an integer in [{lo}, 10000]")
        if self.context < self.window:
            raise DeintError(f"context={self.context} must be >= window={self.window}")

    def to_dict(self) -> dict[str, Any]:
        return {"layout": FEATURE_LAYOUT, "version": FEATURE_VERSION, **asdict(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str) -> SeqLayout:
        if d.get("layout") != FEATURE_LAYOUT or d.get("version") != FEATURE_VERSION:
            raise DeintError(f"{where}: feature layout {d.get('layout')!r} version {d.get('version')!r} is not "
                             f"{FEATURE_LAYOUT!r} version {FEATURE_VERSION}")
        return cls(**{k: d[k] for k in ("window", "context", "lag")})


class PairFeatures(NamedTuple):
    x: np.ndarray  # (n, window, N_FEATURES) float32: candidate i = j - 1 - c for column c
    valid: np.ndarray  # (n, window) bool: the candidate exists
    cand: np.ndarray  # (n, window) int64: the candidate's pulse index (0 where absent)
    gap: np.ndarray  # (n, window) float64: t_j - t_i
    scale: np.ndarray  # (n, 1) float64: the visible pulses' mean spacing


def pair_features(toa: np.ndarray, amplitude: np.ndarray | None, targets: np.ndarray, layout: SeqLayout,
                  n_avail: int) -> PairFeatures:
    """Features of every candidate predecessor of each pulse in `targets` (module doc).  Pulse j sees
    pulses [j - context, min(j + lag + 1, n_avail)) only."""
    t = np.asarray(targets, dtype=np.int64)
    W = layout.window
    lo = np.maximum(t - layout.context, 0)
    hi = np.minimum(t + layout.lag + 1, n_avail)  # exclusive
    ci = t[:, None] - np.arange(1, W + 1)[None, :]
    valid = ci >= 0
    ci = np.maximum(ci, 0)
    tj = toa[t][:, None]
    ti = toa[ci]
    t_lo, t_hi = toa[lo], toa[hi - 1]
    scale = np.maximum((t_hi - t_lo) / np.maximum(hi - 1 - lo, 1), 1e-12)[:, None]  # mean spacing
    d = np.maximum(tj - ti, 1e-9 * scale)
    expected = np.stack([ti - m * d for m in BACK_MULTIPLES] + [0.5 * (ti + tj)]
                        + [tj + m * d for m in FORWARD_MULTIPLES], axis=-1)  # (n, W, M)
    idx = np.searchsorted(toa[:n_avail], expected)
    lo3, hi3 = lo[:, None, None], (hi - 1)[:, None, None]
    a = np.clip(idx - 1, lo3, hi3)
    b = np.clip(idx, lo3, hi3)
    r = np.minimum(np.abs(toa[a] - expected), np.abs(toa[b] - expected))
    avail = (expected >= t_lo[:, None, None]) & (expected <= t_hi[:, None, None])
    d3, s3 = d[..., None], scale[..., None]
    lattice = np.stack([np.minimum(r / d3, 0.5) * 2.0, np.log1p(np.minimum(r / s3, 1e3)),
                        np.ones_like(r)], axis=-1) * avail[..., None]  # (n, W, M, 3)
    n = t.size
    cols = [np.log(d / scale)[..., None], np.broadcast_to(np.arange(1, W + 1) / W, (n, W))[..., None],
            lattice.reshape(n, W, -1)]
    if amplitude is not None:
        amp = np.abs(np.asarray(amplitude, dtype=np.float64))
        csum = np.concatenate([[0.0], np.cumsum(amp[:n_avail])])
        amp_scale = np.maximum((csum[hi] - csum[lo]) / np.maximum(hi - lo, 1), 1e-12)[:, None]
        diff = np.abs(amplitude[t][:, None] - amplitude[ci]) / amp_scale
        cols += [np.log1p(np.minimum(diff, 1e3))[..., None], np.ones((n, W, 1))]
    else:
        cols += [np.zeros((n, W, 2))]
    x = np.concatenate(cols, axis=-1) * valid[..., None]
    return PairFeatures(x.astype(np.float32), valid, ci, d, scale)


def chain_features(toa: np.ndarray, pred: np.ndarray, f: PairFeatures) -> np.ndarray:
    """(n, window, N_CHAIN) float32: how each candidate's own chain agrees with the gap d = t_j - t_i:
    for its chain's last two intervals g (i's predecessor in its chain, and that one's), whether
    there is one and |g - d| over d and over the mean spacing.  `pred[i]` is i's predecessor in its
    chain (-1: none), from the truth in training and from the labels already given in play."""
    p1 = np.where(f.valid, pred[f.cand], -1)
    p2 = np.where(p1 >= 0, pred[np.maximum(p1, 0)], -1)
    t1, t2 = toa[np.maximum(p1, 0)], toa[np.maximum(p2, 0)]
    cols = []
    for g, has in ((toa[f.cand] - t1, p1 >= 0), (t1 - t2, p2 >= 0)):
        r = np.abs(g - f.gap)
        cols += [has, np.minimum(r / f.gap, 0.5) * 2.0 * has, np.log1p(np.minimum(r / f.scale, 1e3)) * has]
    return np.stack(cols, axis=-1).astype(np.float32)


def chain_truth(episode: Episode) -> np.ndarray:
    """Each pulse's predecessor in its source (-1: none or spurious), the chains a perfect labeller makes."""
    pred = true_predecessors(episode.source, episode.mask).pred
    return np.where(pred >= 0, pred, -1)


def pointer_targets(episode: Episode, targets: np.ndarray, window: int) -> np.ndarray:
    """The class of each target pulse: c (predecessor j - 1 - c), `window` (new) or `window` + 1
    (spurious).  A predecessor beyond the window counts as new: the model cannot point at it."""
    pred = true_predecessors(episode.source, episode.mask).pred[targets]
    c = targets - 1 - pred
    return np.where(pred == SPURIOUS_PRED, window + 1,
                    np.where((pred == NO_PRED) | (c >= window), window, c)).astype(np.int64)


class PointerNet(nn.Module):
    """Token MLP, Transformer encoder over the candidates + "new" + "spurious", linear pointer read-out,
    plus a chain head: a ReLU MLP on each candidate's encoding and its chain features, added to its
    logit.  The encoder sees only the pulses (batched over many pulses in play); the chain head
    depends on the labels already given, so it runs pulse by pulse (`ChainHead`, in numpy)."""

    def __init__(self, window: int, d_model: int = 48, heads: int = 4, layers: int = 2, ff: int = 96):
        super().__init__()
        self.window = window
        self.kwargs = {"d_model": d_model, "heads": heads, "layers": layers, "ff": ff}
        self.embed = nn.Sequential(nn.Linear(N_FEATURES, d_model), nn.GELU(), nn.Linear(d_model, d_model))
        self.special = nn.Parameter(torch.randn(2, d_model) * 0.1)  # "new", "spurious"
        layer = nn.TransformerEncoderLayer(d_model, heads, ff, dropout=0.0, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.out = nn.Linear(d_model, 1)
        self.chain = nn.Sequential(nn.Linear(d_model + N_CHAIN, ff), nn.ReLU(), nn.Linear(ff, 1))

    def encode(self, x: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, W, F), (B, W) bool -> candidate encodings (B, W, d) and base logits (B, W + 2), absent
        candidates at -inf."""
        b = x.shape[0]
        h = torch.cat([self.embed(x), self.special.expand(b, 2, -1)], dim=1)
        keep = torch.cat([valid, torch.ones(b, 2, dtype=torch.bool)], dim=1)
        h = self.encoder(h, src_key_padding_mask=~keep)
        return h[:, :self.window], self.out(h).squeeze(-1).masked_fill(~keep, -math.inf)

    def forward(self, x: torch.Tensor, valid: torch.Tensor, chain: torch.Tensor) -> torch.Tensor:
        """Logits (B, W + 2) given the chain features (B, W, N_CHAIN)."""
        h, base = self.encode(x, valid)
        extra = self.chain(torch.cat([h, chain], dim=-1)).squeeze(-1)
        return base + nn.functional.pad(extra, (0, 2))

    def architecture(self) -> dict[str, Any]:
        return {"name": ARCHITECTURE, "window": self.window, **self.kwargs}


def build_net(architecture: dict[str, Any], where: str) -> PointerNet:
    if architecture.get("name") != ARCHITECTURE:
        raise DeintError(f"{where}: architecture {architecture.get('name')!r} is not {ARCHITECTURE!r}")
    kw = {k: architecture[k] for k in ("d_model", "heads", "layers", "ff") if k in architecture}
    return PointerNet(int(architecture["window"]), **kw)


def encode(net: PointerNet, feats: PairFeatures, chunk: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Candidate encodings (n, W, d) and base logits (n, W + 2), `chunk` pulses per forward pass."""
    hs, bs = [], []
    with torch.inference_mode():
        for k in range(0, feats.x.shape[0], chunk):
            h, b = net.encode(torch.from_numpy(feats.x[k:k + chunk]), torch.from_numpy(feats.valid[k:k + chunk]))
            hs.append(h.numpy()), bs.append(b.numpy())
    if not hs:
        return np.zeros((0, net.window, net.kwargs["d_model"]), np.float32), np.zeros((0, net.window + 2), np.float32)
    return np.concatenate(hs), np.concatenate(bs)


class ChainHead:
    """The network's chain head in numpy (one pulse at a time costs microseconds, not a torch call)."""

    def __init__(self, net: PointerNet):
        first, last = net.chain[0], net.chain[2]
        self.w1, self.b1 = first.weight.detach().numpy().T.copy(), first.bias.detach().numpy().copy()
        self.w2, self.b2 = last.weight.detach().numpy()[0].copy(), float(last.bias.detach().numpy()[0])

    def __call__(self, h: np.ndarray, chain: np.ndarray) -> np.ndarray:
        """(W, d), (W, N_CHAIN) -> (W,) logit increments."""
        z = np.concatenate([h, chain], axis=-1) @ self.w1 + self.b1
        return np.maximum(z, 0.0) @ self.w2 + self.b2


class ChainDecoder:
    """Pointers -> blind labels, one pulse at a time (module doc)."""

    def __init__(self, n_labels: int, window: int, margin: float = 0.0):
        self.n_labels, self.window, self.margin = n_labels, window, margin
        self.tail = np.full(n_labels, -1, dtype=np.int64)  # each label's last pulse
        self.last_use = np.full(n_labels, -1, dtype=np.int64)
        self.label_of_tail: dict[int, int] = {}
        self.pred: list[int] = []  # each decoded pulse's predecessor in its chain (-1: none)
        self.n = 0  # pulses decoded
        self.chain_of_label = np.full(n_labels, -1, dtype=np.int64)
        self.lengths: list[int] = []  # pulses per chain opened

    @property
    def chains(self) -> int:
        """Chains opened (a train broken by a mistake counts once per piece)."""
        return len(self.lengths)

    def trains(self, min_pulses: int) -> int:
        """Chains holding at least `min_pulses` pulses."""
        return sum(n >= min_pulses for n in self.lengths)

    def decode(self, logits: np.ndarray) -> int:
        j = self.n
        self.n += 1
        W = self.window
        best, choice = logits[W], -1  # "new"
        if logits[W + 1] > best:
            best, choice = logits[W + 1], -2
        for i, lab in self.label_of_tail.items():
            c = j - 1 - i
            if c < W and logits[c] > best:
                best, choice = logits[c], lab
        if choice >= 0 and logits[:W].max() > best + self.margin:
            # The favourite predecessor already has a successor (an earlier mistake took it): joining
            # another chain would take that one's place in turn and pass the mistake on to every
            # later pulse; a new chain costs this one link and leaves the other chains whole.
            choice = -1
        if choice == -2:
            self.pred.append(-1)
            return self.n_labels  # spurious
        self.pred.append(-1 if choice == -1 else int(self.tail[choice]))
        if choice == -1:
            fresh = np.flatnonzero(self.last_use < 0)
            choice = int(fresh[0]) if fresh.size else int(np.argmin(self.last_use))
            self.chain_of_label[choice] = len(self.lengths)
            self.lengths.append(0)
        self.lengths[self.chain_of_label[choice]] += 1
        old = int(self.tail[choice])
        if old >= 0:
            self.label_of_tail.pop(old, None)
        self.tail[choice] = j
        self.last_use[choice] = j
        self.label_of_tail[j] = choice
        # A chain whose tail left the window can no longer be pointed at.
        for i in [i for i in self.label_of_tail if j - i >= W]:
            del self.label_of_tail[i]
        return choice


def label_pulses(net: PointerNet, head: ChainHead, layout: SeqLayout, dec: ChainDecoder, toa: np.ndarray,
                 amplitude: np.ndarray | None, n_avail: int, upto: int) -> list[int]:
    """Labels of pulses [dec.n, upto): their encodings in one batch, then pulse by pulse the chain
    head (on the chains decoded so far) and the decoder."""
    targets = np.arange(dec.n, upto)
    feats = pair_features(toa, amplitude, targets, layout, n_avail)
    h, base = encode(net, feats)
    pred = np.full(upto, -1, dtype=np.int64)
    pred[:dec.n] = dec.pred
    out = []
    W = layout.window
    for k, j in enumerate(targets.tolist()):
        one = PairFeatures(*(a[k:k + 1] for a in feats))
        logits = base[k].astype(np.float64)
        logits[:W] += head(h[k], chain_features(toa, pred, one)[0])
        out.append(dec.decode(logits))
        pred[j] = dec.pred[j]
    return out


def label_episode(net: PointerNet, layout: SeqLayout, toa: np.ndarray, amplitude: np.ndarray | None,
                  n_labels: int, margin: float = DEFAULT_MARGIN) -> tuple[np.ndarray, int]:
    """Blind labels of a whole pulse stream at once (the same labels the policy emits); (labels, chains)."""
    dec = ChainDecoder(n_labels, layout.window, margin)
    labels = label_pulses(net, ChainHead(net), layout, dec, toa, amplitude, toa.size, toa.size)
    return np.array(labels, dtype=np.int64), dec.chains


# ---------------------------------------------------------------------------------------------------
# the policy
# ---------------------------------------------------------------------------------------------------
TRAIN_MIN_PULSES = 10
CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "seq-blind-v0.safetensors"


class SequencePolicy:
    """`seq`: the pointer labeller from a checkpoint (default: the zoo's blind-v0 one).  Pulse j is
    labelled when pulse j + lag has arrived (with `batch=B`, B pulses at a time: lag + B - 1).
    `margin`: how much a taken predecessor must outscore every free one before the pulse opens a new
    chain instead (`ChainDecoder`)."""

    PARAMS = declare(
        Param("checkpoint", str, None, "the checkpoint (none: agents/checkpoints/seq-blind-v0.safetensors)",
              optional=True),
        Param("batch", int, 1, "pulses scored per pass (the lag grows by batch - 1)", low=1, high=4096),
        Param("margin", float, DEFAULT_MARGIN, "logits a taken predecessor must outscore every free one by before "
              "the pulse opens a new chain", low=0),
        NETWORK,
    )

    def __init__(self, checkpoint: str | None = None, batch: int = 1, margin: float = DEFAULT_MARGIN,
                 network: str = "on"):
        from agents.checkpoint import load_checkpoint

        self.PARAMS.only("batch", "margin").check(locals())  # checkpoint: a str or a path
        torch.set_num_threads(1)
        path = Path(checkpoint) if checkpoint else CHECKPOINT
        ck = load_checkpoint(path)
        where = f"checkpoint {path}"
        self.meta = ck.meta
        self.layout = SeqLayout.from_dict(ck.meta.features, where)
        self.net = build_net(ck.meta.architecture, where)
        self.net.load_state_dict(ck.tensors, strict=True)
        self.net.eval()
        if network_off(network):  # the ablation: both read-outs zeroed, every candidate's logit 0
            with torch.no_grad():
                for layer in (self.net.out, self.net.chain[2]):
                    layer.weight.zero_(), layer.bias.zero_()
        self.head = ChainHead(self.net)
        self.margin = float(margin)
        self.version = f"{ck.key}+decoder{DECODER_VERSION}"  # results keyed on the weights and the decoding
        self.batch = batch
        self.lag = self.layout.lag + batch - 1

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if not priors.blind:
            raise NotApplicable("seq finds its own trains: blind scenarios only (mapping chains to prior tracks is "
                                "not done)")
        self._amp = bool(info.get("has_amplitude", False))
        if (info.get("n_pulses") or 0) > MAX_PULSES:
            raise DeintError(f"seq labels at most {MAX_PULSES} pulses in one run (about 1.6 ms a pulse); this "
                             f"record has {info['n_pulses']}: split it into files of fewer pulses")
        cap = int(info.get("n_pulses") or 1024)
        self._toa = np.zeros(cap)
        self._ampl = np.zeros(cap) if self._amp else None
        self._n = 0  # pulses received
        self._out: list[int] = []  # labels of pulses [0, decoder.n)
        self._step = 0
        self._done = False
        self.decoder = ChainDecoder(priors.n_labels, self.layout.window, self.margin)

    @property
    def trains_found(self) -> int:
        """Chains of at least TRAIN_MIN_PULSES pulses (the trains it found; fragments left out)."""
        return self.decoder.trains(TRAIN_MIN_PULSES)

    def _grow(self) -> None:
        self._toa = np.concatenate([self._toa, np.zeros(self._toa.size)])
        if self._ampl is not None:
            self._ampl = np.concatenate([self._ampl, np.zeros(self._ampl.size)])

    def _score(self, upto: int) -> None:
        """Labels of pulses [decoder.n, upto)."""
        if upto > self.decoder.n:
            self._out += label_pulses(self.net, self.head, self.layout, self.decoder, self._toa, self._ampl, self._n,
                                      upto)

    def act(self, obs: dict[str, Any]) -> int:
        if int(obs["valid"]):
            if self._n == self._toa.size:
                self._grow()
            self._toa[self._n] = float(obs["toa"][0])
            if self._ampl is not None:
                self._ampl[self._n] = float(obs["amplitude"][0])
            self._n += 1
            ready = self._n - self.layout.lag  # pulses whose look-ahead is complete
            if ready - self.decoder.n >= self.batch:
                self._score(ready)
        elif not self._done:  # the stream ended: every remaining pulse has all the look-ahead there is
            self._done = True
            self._score(self._n)
        due = self._step - self.lag
        self._step += 1
        return self._out[due] if due >= 0 else 0


# ---------------------------------------------------------------------------------------------------
# training (`deint train --algo seq`)
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SeqParams:
    """agents/hyperparams/seq.yml."""

    window: int = 64
    context: int = 256
    episodes_per_step: int = 4
    pulses_per_episode: int = 128
    learning_rate: float = 1e-3
    chain_dropout: float = 0.1  # share of true chain links hidden from the chain features in training
    own_chains: float = 0.0  # share of episodes whose chain features come from the agent's own labels
    n_timesteps: int = 2_000_000  # labelled pulses seen by the optimiser
    validation_episodes: int = 16
    d_model: int = 48
    heads: int = 4
    layers: int = 2
    ff: int = 96

    @classmethod
    def from_yaml(cls, entry: dict[str, Any], where: str) -> SeqParams:
        names = set(cls.__dataclass_fields__)
        unknown = sorted(set(entry) - names)
        if unknown:
            raise DeintError(f"{where}: key {unknown[0]!r} is unknown for seq; keys: {', '.join(sorted(names))}")
        kw = dict(entry)
        if "n_timesteps" in kw:
            kw["n_timesteps"] = int(float(kw["n_timesteps"]))
        return cls(**kw)


def own_chains(net: PointerNet, layout: SeqLayout, ep: Episode) -> np.ndarray:
    """The chains the agent itself makes of `ep` (its predecessors as decoded): in play the chain
    features come from its own labels, mistakes included, so training on them too teaches it how far
    to trust them (as DAgger does for actions)."""
    net.eval()
    dec = ChainDecoder(ep.n_labels, layout.window, DEFAULT_MARGIN)
    label_pulses(net, ChainHead(net), layout, dec, ep.toa, ep.amplitude, len(ep), len(ep))
    net.train()
    return np.array(dec.pred, dtype=np.int64)


def validate(net: PointerNet, layout: SeqLayout, episodes: Sequence[Episode]) -> float:
    """Mean link accuracy of the decoded labels over `episodes`."""
    net.eval()
    acc = []
    for ep in episodes:
        labels, _ = label_episode(net, layout, ep.toa, ep.amplitude, ep.n_labels)
        acc.append(float(np.mean(correct_link(labels, ep.source, ep.mask, ep.n_labels))))
    net.train()
    return float(np.mean(acc))


PHASE_KEYS = ("n_timesteps", "seed", "eval_every")  # a phase's run keys; the rest are SeqParams


def train_seq_phases(config: TrainConfig, out: Path, hyperparams: tuple[str, dict[str, Any]]) -> TrainResult:
    """`deint train --algo seq`: one `train_seq` run, or, when the YAML entry has `phases`, one run per
    phase into the same `out`, each resuming from the last one's `last.safetensors`.  A phase is a
    mapping: `n_timesteps` (where it ends, counted from the start of the recipe), `seed` (added to
    --seed), `eval_every` (replaces --eval-every) and SeqParams keys overriding the entry's.  Each
    phase is the very call a `deint train` command with those values makes (same function, same
    arguments, resuming from the same file), so the recipe gives what its phases run by hand give;
    phases already done in `out` are skipped, so a rerun resumes."""
    from agents.checkpoint import load_checkpoint

    key, entry = hyperparams
    entry = dict(entry)
    phases = entry.pop("phases", None)
    if phases is None:
        return train_seq(config, out, (key, entry))
    where = f"hyper-parameters {key!r}"
    if not isinstance(phases, list) or not phases or not all(isinstance(ph, dict) for ph in phases):
        raise DeintError(f"{where}: phases must be a non-empty list of mappings")
    if config.timesteps is not None:
        raise DeintError(f"{where} declares {len(phases)} training phases, which end where their n_timesteps say; "
                         "--timesteps does not apply")
    ends = []
    for i, ph in enumerate(phases, 1):
        if "n_timesteps" not in ph:
            raise DeintError(f"{where}: phase {i} has no n_timesteps")
        ends.append(int(float(ph["n_timesteps"])))
        SeqParams.from_yaml({**entry, **{k: v for k, v in ph.items() if k not in PHASE_KEYS}}, f"{where}, phase {i}")
    if any(b <= a for a, b in zip([0, *ends], ends)):
        raise DeintError(f"{where}: the phases' n_timesteps must increase; they are {ends}")
    last = out / "last.safetensors"
    t0, evaluations, result = time.perf_counter(), [], None
    for i, (ph, end) in enumerate(zip(phases, ends), 1):
        if last.is_file() and load_checkpoint(last).meta.timesteps >= end:
            continue  # done by an earlier run of the recipe
        budget = None if config.time_budget is None else config.time_budget - (time.perf_counter() - t0)
        if budget is not None and budget <= 0:
            break
        cfg = replace(config, timesteps=end, seed=config.seed + int(ph.get("seed", 0)),
                      eval_every=int(float(ph.get("eval_every", config.eval_every))), time_budget=budget)
        params = {**entry, **{k: v for k, v in ph.items() if k not in PHASE_KEYS}, "n_timesteps": end}
        if config.progress:
            print(f"deint: seq phase {i}/{len(phases)} to {end} pulses", flush=True)
        result = train_seq(cfg, out, (key, params), notes={"phase": f"{i}/{len(phases)}"})
        evaluations += result.evaluations
        if result.timesteps < end:
            break  # the time budget ran out: a rerun resumes this phase
    if result is None:  # every phase was already done
        done = load_checkpoint(last).meta.timesteps if last.is_file() else 0
        best = out / "best.safetensors"
        return TrainResult(last, best if best.is_file() else None, done, 0.0, [])
    return TrainResult(result.last, result.best, result.timesteps, time.perf_counter() - t0, evaluations)


def train_seq(config: TrainConfig, out: Path, hyperparams: tuple[str, dict[str, Any]],
              notes: dict[str, Any] | None = None) -> TrainResult:
    """Train the pointer labeller on the train seeds of `config`'s scenarios (blind ones) into `out`,
    with `hyperparams` (the YAML key used, its entry), saving `last` / `best` safetensors checkpoints
    (`notes` added to their metadata notes) after every validation; resumable from `last`."""
    from agents.checkpoint import CheckpointMeta, load_checkpoint, save_checkpoint
    from deint_env import __version__
    from deint_env.envs.mixed import select_entries, split_seeds
    from deint_env.simulate import simulate_many
    from deint_env.suites import load_suite

    entries = select_entries(config.suite, config.scenarios, config.tags)
    anchored = [n for n, e in entries if not e.spec.blind]
    if anchored:
        raise DeintError(f"seq trains on blind scenarios only; {anchored[0]} is anchored")
    hp_key, entry = hyperparams
    p = SeqParams.from_yaml(entry, f"hyper-parameters {hp_key!r}")
    layout = SeqLayout(window=p.window, context=p.context, lag=config.lag)
    total = int(config.timesteps or p.n_timesteps)
    torch.manual_seed(config.seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    net = PointerNet(p.window, p.d_model, p.heads, p.layers, p.ff)
    opt = torch.optim.Adam(net.parameters(), lr=p.learning_rate)
    out.mkdir(parents=True, exist_ok=True)
    last, best_path = out / "last.safetensors", out / "best.safetensors"
    done, seconds_before, best, evaluations = 0, 0.0, -math.inf, []
    if last.is_file():
        ck = load_checkpoint(last)
        if ck.meta.algorithm != "seq" or ck.meta.architecture != net.architecture():
            raise DeintError(f"{last} holds a {ck.meta.algorithm} agent of another shape; choose another output "
                             "directory")
        net.load_state_dict({k: v for k, v in ck.tensors.items() if not k.startswith("optim.")})
        done = ck.meta.timesteps
        seconds_before = float(ck.meta.notes.get("train_seconds", 0.0))
        b = ck.meta.notes.get("best_validation_accuracy")
        best = -math.inf if b is None else float(b)
        if config.progress:
            print(f"deint: resuming {last} at {done} pulses", flush=True)
    names = [n for n, _ in entries]
    train_ranges = [split_seeds(e, "train") for _, e in entries]
    val_eps = [ep for (_, e) in entries for ep in
               simulate_many(e.spec, list(split_seeds(e, "validation"))[:max(1, p.validation_episodes // len(entries))])]
    suite_hashes = {s: load_suite(s).content_hash for s in sorted({n.split("/")[0] for n in names})}
    rng = np.random.default_rng([config.seed, done])
    t0 = time.perf_counter()

    def meta() -> CheckpointMeta:
        import safetensors
        return CheckpointMeta(
            architecture=net.architecture(), features=layout.to_dict(), algorithm="seq", scenarios=names,
            suite_hashes=suite_hashes, train_seeds=[min(r.start for r in train_ranges), max(r.stop for r in train_ranges)],
            timesteps=int(done), hyperparameters={**asdict(p), "lag": config.lag, "hyperparams_key": hp_key},
            versions={"deint_bench": __version__, "torch": torch.__version__, "numpy": np.__version__,
                      "safetensors": safetensors.__version__},
            seed=config.seed,
            notes={"train_seconds": round(seconds_before + time.perf_counter() - t0, 1),
                   "best_validation_accuracy": None if best == -math.inf else best,
                   "validation": "link accuracy on the first validation seeds of each scenario", **(notes or {})})

    def checkpoint() -> None:
        nonlocal best
        score = validate(net, layout, val_eps)
        rec = {"timesteps": done, "validation_link_accuracy": round(score, 4),
               "seconds": round(seconds_before + time.perf_counter() - t0, 1)}
        evaluations.append(rec)
        if score > best:
            best = score
            save_checkpoint(best_path, net.state_dict(), meta())
        save_checkpoint(last, net.state_dict(), meta())
        with open(out / "eval.jsonl", "a") as f:
            f.write(json.dumps(rec) + "\n")
        if config.progress:
            print(f"  {done} pulses: validation link accuracy {score:.4f} ({rec['seconds']} s)", flush=True)

    next_eval = done + config.eval_every
    try:
        while done < total:
            if config.time_budget is not None and time.perf_counter() - t0 > config.time_budget:
                break
            xs, vs, ys, cs = [], [], [], []
            for _ in range(p.episodes_per_step):
                k = int(rng.integers(len(entries)))
                r = train_ranges[k]
                ep = simulate_many(entries[k][1].spec, [int(rng.integers(r.start, r.stop))])[0]
                tg = np.sort(rng.choice(len(ep), min(p.pulses_per_episode, len(ep)), replace=False))
                f = pair_features(ep.toa, ep.amplitude, tg, layout, len(ep))
                chains = own_chains(net, layout, ep) if rng.random() < p.own_chains else \
                    np.where(rng.random(len(ep)) < p.chain_dropout, -1, chain_truth(ep))
                xs.append(f.x), vs.append(f.valid), ys.append(pointer_targets(ep, tg, p.window))
                cs.append(chain_features(ep.toa, chains, f))
            logits = net(torch.from_numpy(np.concatenate(xs)), torch.from_numpy(np.concatenate(vs)),
                         torch.from_numpy(np.concatenate(cs)))
            loss = nn.functional.cross_entropy(logits, torch.from_numpy(np.concatenate(ys)))
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            done += int(sum(len(y) for y in ys))
            if done >= next_eval:
                next_eval += config.eval_every
                checkpoint()
        if not evaluations or evaluations[-1]["timesteps"] != done:
            checkpoint()
    finally:
        torch.set_num_threads(threads)
    return TrainResult(last, best_path if best_path.is_file() else None, done,
                       seconds_before + time.perf_counter() - t0, evaluations)

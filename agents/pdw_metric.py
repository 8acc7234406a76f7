"""`pdw-metric`: a learned pulse-descriptor labeller, a transformer trained by deep metric learning whose
per-pulse embeddings are clustered window by window (after arXiv:2503.13476: a transformer over pulse
descriptor sequences trained with a metric-learning loss, then its embeddings clustered; AMI 0.882 on
its 5-descriptor data).

Features (`window_features`), per pulse of a window, 7 columns:

- log of the TOA difference to the previous pulse of the window (the first pulse: the window's median
  difference), the pulse's position in the window's span (-1 at its first TOA, +1 at its last),
- frequency, log pulse width, log amplitude (amplitudes that are not all positive are taken as dB
  already and used as they are; no amplitude: a column of zeros),
- the AoA as (cos, sin) on the unit circle (not scaled: 3 degrees of noise is 0.05).

Every column but the position and the AoA's two is scaled per window, robustly: centred on its
median, divided by its interquartile range (floored), then compressed by asinh, so that a window
dominated by one emitter (a tiny IQR) leaves the others large but finite.  Per-window scaling makes the
features unit-free: a file in other units or bands (2-18 GHz) reads like the training windows.

Network (`MetricNet`): a two-layer MLP lifting the 7 features to d_model, a pre-norm transformer encoder
(`layers` x `heads`, no positional encoding: order enters through the position and TOA-difference
features), a linear map to `embed` dimensions, L2-normalised.

Loss: supervised contrastive (Khosla et al., 2020) within each training window, temperature `tau`:
for every pulse of an emitter (anchor), the pulses of the same emitter are its positives and every
other pulse of the window its negatives; spurious pulses are never anchors nor positives (each is a
class of its own: pushed away from everything).

Labelling (`PDWMetricPolicy`, a `baselines.pdw.policy.PDWPolicy`): the policy buffers `window` pulses
(lag window - 1), embeds them, clusters the embeddings with HDBSCAN (as scikit-learn defines it:
`baselines.blind.density`; `min_cluster_size`; noise: spurious) and hands the clusters to PDWPolicy,
which carries emitter labels from window to window by their descriptors (the pdw-* policies' own code).  `network=off` (the ablation) clusters the
7 scaled features themselves, the same way.

Trained on pdw-v0's blind scenarios, TRAIN seeds only; every setting (window, min_cluster_size, the
checkpoint kept) was chosen on VALIDATION seeds.  Rebuild the shipped checkpoint with

    nice python -m agents.pdw_metric --out agents/checkpoints/pdw-metric-v1.safetensors

(`--help` lists the training arguments, `Args`, whose defaults are the shipped checkpoint's; 1 thread, 80
minutes of wall time, the rate decayed by a cosine: the shipped checkpoint is step 13,997 of 15,740, its best
validation).  docs/pdw.md reports it and its predecessor, pdw-metric-v0.safetensors (`checkpoint=`).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from agents.ablation import NETWORK, network_off
from baselines.pdw.hdbscan import hdbscan_clusters
from baselines.pdw.policy import Clusters, PDWPolicy, PDWs
from baselines.windowed import MAX_WINDOW
from deint_env.episode import Episode
from deint_env.errors import DeintError
from deint_env.params import Param, declare

ARCHITECTURE = "pdw-metric"
FEATURE_LAYOUT = "pdw-metric-window"
FEATURE_VERSION = 1
FEATURES = ("log_dtoa", "position", "frequency", "log_pulse_width", "log_amplitude", "aoa_cos", "aoa_sin")
N_FEATURES = len(FEATURES)
SUITE = "pdw-v0"
CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "pdw-metric-v1.safetensors"
# chosen on pdw-v0's validation seeds: window 512 / 1024 / 2048 x min_cluster_size 3-24 with the v0
# checkpoint (the first 2 seeds of each 10^4-pulse blind scenario: 2048 and 12 best, V 0.904); with v1,
# min_cluster_size 8 / 12 / 16 / 20 / 24 at window 2048 on seeds 3-7 (never used to pick the checkpoint):
# V 0.878 / 0.896 / 0.912 / 0.907 / 0.900
DEFAULT_WINDOW = 2048
DEFAULT_MIN_CLUSTER = 16


# ---------------------------------------------------------------------------------------------------
# features
# ---------------------------------------------------------------------------------------------------
def _robust(x: np.ndarray) -> np.ndarray:
    """(x - median) / IQR (floored at a millionth of the median's size), compressed by asinh."""
    med = np.median(x)
    q75, q25 = np.percentile(x, [75, 25])
    iqr = max(q75 - q25, 1e-6 * abs(med) + 1e-9)
    return np.arcsinh((x - med) / iqr)


def window_features(p: PDWs) -> np.ndarray:
    """(n, N_FEATURES) float32: the features of one window's pulses (module doc)."""
    toa = np.asarray(p.toa, dtype=np.float64)
    n = toa.size
    out = np.zeros((n, N_FEATURES), dtype=np.float64)
    if n == 0:
        return out.astype(np.float32)
    dt = np.diff(toa)
    first = np.median(dt) if dt.size else 1.0
    out[:, 0] = _robust(np.log(np.maximum(np.concatenate([[first], dt]), 1e-3)))
    span = toa[-1] - toa[0]
    out[:, 1] = 2.0 * (toa - toa[0]) / span - 1.0 if span > 0 else 0.0
    out[:, 2] = _robust(np.asarray(p.frequency, dtype=np.float64))
    out[:, 3] = _robust(np.log(np.maximum(np.asarray(p.pulse_width, dtype=np.float64), 1e-6)))
    if p.amplitude is not None:
        a = np.asarray(p.amplitude, dtype=np.float64)
        out[:, 4] = _robust(np.log(a) if np.all(a > 0) else a)  # not all positive: dB already
    rad = np.radians(np.asarray(p.aoa, dtype=np.float64))
    out[:, 5], out[:, 6] = np.cos(rad), np.sin(rad)
    return out.astype(np.float32)


def episode_pdws(ep: Episode, lo: int = 0, hi: int | None = None) -> PDWs:
    """Pulses [lo, hi) of a descriptor episode as a window."""
    s = slice(lo, hi)
    return PDWs(ep.toa[s], ep.frequency[s], ep.pulse_width[s], ep.aoa[s],
                None if ep.amplitude is None else ep.amplitude[s])


# ---------------------------------------------------------------------------------------------------
# the network
# ---------------------------------------------------------------------------------------------------
class MetricNet(nn.Module):
    """Pulse features (B, W, N_FEATURES) -> L2-normalised embeddings (B, W, embed)."""

    def __init__(self, d_model: int = 64, heads: int = 4, layers: int = 3, ff: int = 128, embed: int = 32):
        super().__init__()
        self.shape = {"d_model": d_model, "heads": heads, "layers": layers, "ff": ff, "embed": embed}
        self.lift = nn.Sequential(nn.Linear(N_FEATURES, d_model), nn.GELU(), nn.Linear(d_model, d_model))
        layer = nn.TransformerEncoderLayer(d_model, heads, ff, dropout=0.0, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(d_model)
        self.out = nn.Linear(d_model, embed)

    def architecture(self) -> dict[str, Any]:
        return {"name": ARCHITECTURE, **self.shape}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.normalize(self.out(self.norm(self.encoder(self.lift(x)))), dim=-1)


def build_net(architecture: dict[str, Any], where: str) -> MetricNet:
    arch = dict(architecture)
    if arch.pop("name", None) != ARCHITECTURE:
        raise DeintError(f"{where} holds a {architecture.get('name')!r} network, not {ARCHITECTURE!r}")
    try:
        return MetricNet(**arch)
    except TypeError as e:
        raise DeintError(f"{where}: its architecture {architecture} does not build: {e}") from None


def embed(net: MetricNet, x: np.ndarray) -> np.ndarray:
    """(n, embed) float64 embeddings of one window's features."""
    with torch.no_grad():
        return net(torch.from_numpy(x)[None]).numpy()[0].astype(np.float64)


def supcon_loss(z: torch.Tensor, y: torch.Tensor, tau: float) -> torch.Tensor:
    """Supervised contrastive loss of embeddings z (B, W, E) with classes y (B, W) (-1: spurious, never
    a positive nor an anchor), averaged over the anchors that have a positive."""
    sim = torch.einsum("bie,bje->bij", z, z) / tau
    eye = torch.eye(z.shape[1], dtype=torch.bool)[None]
    sim = sim.masked_fill(eye, -1e9)
    log_prob = sim - torch.logsumexp(sim, dim=2, keepdim=True)
    pos = (y[:, :, None] == y[:, None, :]) & (y[:, :, None] >= 0) & ~eye
    n_pos = pos.sum(2)
    anchor = n_pos > 0
    per = (log_prob * pos).sum(2)[anchor] / n_pos[anchor]
    return -per.mean()


# ---------------------------------------------------------------------------------------------------
# the policy
# ---------------------------------------------------------------------------------------------------
class PDWMetricPolicy(PDWPolicy):
    """`pdw-metric`: the metric-learning labeller (module doc).  Labels `window` pulses at a time
    (lag window - 1); `network=off` clusters the scaled features instead of the embeddings."""

    PARAMS = declare(
        Param("checkpoint", str, None, "the checkpoint (none: agents/checkpoints/pdw-metric-v1.safetensors)",
              optional=True),
        Param("window", int, DEFAULT_WINDOW, "pulses per batch (the lag is window - 1)", low=2, high=MAX_WINDOW),
        Param("min_cluster_size", int, DEFAULT_MIN_CLUSTER, "HDBSCAN's smallest cluster on the embeddings "
              "(min_samples the same)", low=2),
        NETWORK,
    )

    def __init__(self, checkpoint: str | None = None, window: int = DEFAULT_WINDOW,
                 min_cluster_size: int = DEFAULT_MIN_CLUSTER, network: str = "on"):
        from agents.checkpoint import load_checkpoint

        self.PARAMS.only("window", "min_cluster_size").check(locals())
        super().__init__(window)
        torch.set_num_threads(1)
        path = Path(checkpoint) if checkpoint else CHECKPOINT
        ck = load_checkpoint(path)
        where = f"checkpoint {path}"
        f = ck.meta.features
        if f.get("layout") != FEATURE_LAYOUT or f.get("version") != FEATURE_VERSION:
            raise DeintError(f"{where}: feature layout {f.get('layout')!r} version {f.get('version')!r} is not "
                             f"{FEATURE_LAYOUT!r} version {FEATURE_VERSION}")
        self.net = build_net(ck.meta.architecture, where)
        try:
            self.net.load_state_dict(ck.tensors, strict=True)
        except RuntimeError as e:
            raise DeintError(f"{where}: its tensors do not fit its architecture ({str(e).splitlines()[0]})") from None
        self.net.eval()
        self.meta = ck.meta
        self.off = network_off(network)
        self.min_cluster_size = min_cluster_size
        self.version = ck.key  # results keyed on the weights

    def points(self, p: PDWs) -> np.ndarray:
        """What is clustered: the embeddings, or (network=off) the scaled features."""
        x = window_features(p)
        return x.astype(np.float64) if self.off else embed(self.net, x)

    def label_window(self, p: PDWs) -> Clusters:
        return hdbscan_clusters(self.points(p), self.min_cluster_size)

    def label_episode(self, ep: Episode) -> np.ndarray:
        """Every pulse's label, as the protocol would give them (windows of `window` pulses in order),
        without the per-pulse stepping: for validation and timing."""
        from deint_env.episode import Priors

        self.reset(Priors(n_labels=ep.n_labels, blind=True), {"has_amplitude": ep.amplitude is not None})
        out = [self._to_labels(w, self.label_window(w))
               for w in (episode_pdws(ep, lo, lo + self.window) for lo in range(0, len(ep), self.window))]
        return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


# ---------------------------------------------------------------------------------------------------
# training: python -m agents.pdw_metric --out PATH
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Args:
    """Training arguments (each is a --flag of `python -m agents.pdw_metric`)."""

    out: str = str(CHECKPOINT)  # where the best checkpoint (on validation) is written
    seed: int = 0  # torch's and the sampler's seed
    minutes: float = 80.0  # wall-clock training budget
    steps: int = 100_000  # optimiser steps at most (the budget usually ends training first)
    windows: tuple[int, ...] = (256, 512, 1024, 2048)  # training window lengths, one drawn per step
    pulses_per_step: int = 2048  # windows per step = pulses_per_step // window length
    pool: int = 48  # simulated train episodes kept; one replaced every `refresh` steps
    refresh: int = 2
    learning_rate: float = 1e-3
    schedule: str = "cosine"  # the rate decays to 0 over the wall-clock budget (or "constant")
    tau: float = 0.1  # the contrastive loss's temperature
    d_model: int = 96
    heads: int = 4
    layers: int = 4
    ff: int = 192
    embed: int = 32
    eval_every: float = 10.0  # minutes between validations (V-measure of the labelling; best kept)
    val_seeds: int = 2  # first validation seeds of each 10^4-pulse blind scenario used while training
    val_window: int = 2048  # the labelling settings of the validations that pick the checkpoint (the
    val_min_cluster_size: int = 12  # policy's defaults, chosen with the previous checkpoint)


def learning_rate(args: Args, done: float) -> float:
    """The optimiser's rate when `done` (0-1) of the wall-clock budget is spent (the budget is time, not
    steps, so the cosine decays over time)."""
    if args.schedule == "cosine":
        return 0.5 * args.learning_rate * (1.0 + math.cos(math.pi * min(1.0, max(0.0, done))))
    return args.learning_rate


def blind_entries() -> list[Any]:
    from deint_env.suites import load_suite

    return [e for e in load_suite(SUITE) if e.spec.blind]


def validation_score(net: MetricNet, episodes: Sequence[Episode], window: int, min_cluster_size: int) -> float:
    """Mean V-measure of pdw-metric's labels (this net) over `episodes`."""
    from deint_env.metrics import clustering_metrics

    policy = PDWMetricPolicy.__new__(PDWMetricPolicy)  # the policy around an in-memory net
    PDWPolicy.__init__(policy, window)
    policy.net, policy.off, policy.min_cluster_size = net, False, min_cluster_size
    net.eval()
    scores = [clustering_metrics(ep.source, policy.label_episode(ep))["v_measure"] for ep in episodes]
    net.train()
    return float(np.mean(scores))


def train(args: Args) -> dict[str, Any]:
    from agents.checkpoint import CheckpointMeta, save_checkpoint
    from deint_env import __version__
    from deint_env.simulate import simulate
    from deint_env.suites import load_suite

    if args.schedule not in ("constant", "cosine"):
        raise DeintError(f"--schedule {args.schedule!r} is unknown: use constant or cosine")
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)
    rng = np.random.default_rng(args.seed)
    entries = blind_entries()
    ranges = [e.seeds("train") for e in entries]
    val_eps = [simulate(e.spec, s) for e in entries if e.spec.n_pulses <= 10_000
               for s in list(e.seeds("validation"))[:args.val_seeds]]
    net = MetricNet(args.d_model, args.heads, args.layers, args.ff, args.embed)
    opt = torch.optim.AdamW(net.parameters(), lr=args.learning_rate, weight_decay=1e-4)

    def draw() -> Episode:
        k = int(rng.integers(len(entries)))
        return simulate(entries[k].spec, int(rng.integers(ranges[k].start, ranges[k].stop)))

    pool = [draw() for _ in range(args.pool)]
    t0 = time.perf_counter()
    budget = 60.0 * args.minutes
    next_eval, best, history, step, losses = 60.0 * args.eval_every, -math.inf, [], 0, []

    def evaluate() -> None:
        nonlocal best
        score = validation_score(net, val_eps, args.val_window, args.val_min_cluster_size)
        rec = {"step": step, "minutes": round((time.perf_counter() - t0) / 60, 1),
               "loss": round(float(np.mean(losses[-50:])), 4), "validation_v_measure": round(score, 4)}
        history.append(rec)
        print(rec, flush=True)
        if score > best:
            best = score
            import safetensors
            meta = CheckpointMeta(
                architecture=net.architecture(), features={"layout": FEATURE_LAYOUT, "version": FEATURE_VERSION,
                                                           "columns": list(FEATURES)},
                algorithm="supcon", scenarios=[f"{SUITE}/{e.name}" for e in entries],
                suite_hashes={SUITE: load_suite(SUITE).content_hash},
                train_seeds=[min(r.start for r in ranges), max(r.stop for r in ranges)],
                timesteps=int(step * args.pulses_per_step),
                hyperparameters={k: list(v) if isinstance(v, tuple) else v for k, v in asdict(args).items() if k != "out"},
                versions={"deint_bench": __version__, "torch": torch.__version__, "numpy": np.__version__,
                          "safetensors": safetensors.__version__},
                seed=args.seed,
                notes={"train_seconds": round(time.perf_counter() - t0, 1), "steps": step,
                       "best_validation_v_measure": round(best, 4),
                       "validation": f"V-measure on the first {args.val_seeds} validation seed(s) of each 10^4-pulse "
                                     f"blind {SUITE} scenario (window {args.val_window}, min_cluster_size "
                                     f"{args.val_min_cluster_size})", "history": history})
            save_checkpoint(args.out, net.state_dict(), meta)

    net.train()
    while step < args.steps and time.perf_counter() - t0 < budget:
        w = int(rng.choice(args.windows))
        xs, ys = [], []
        for _ in range(max(1, args.pulses_per_step // w)):
            ep = pool[int(rng.integers(len(pool)))]
            lo = int(rng.integers(0, len(ep) - w + 1))
            xs.append(window_features(episode_pdws(ep, lo, lo + w)))
            ys.append(ep.source[lo:lo + w].astype(np.int64))
        for group in opt.param_groups:
            group["lr"] = learning_rate(args, (time.perf_counter() - t0) / budget)
        z = net(torch.from_numpy(np.stack(xs)))
        loss = supcon_loss(z, torch.from_numpy(np.stack(ys)), args.tau)
        opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        losses.append(loss.item())
        step += 1
        if step % args.refresh == 0:
            pool[int(rng.integers(len(pool)))] = draw()
        if step % 50 == 0:
            print(f"step {step} loss {np.mean(losses[-50:]):.4f} {time.perf_counter() - t0:.0f} s", flush=True)
        if time.perf_counter() - t0 >= next_eval:
            next_eval += 60.0 * args.eval_every
            evaluate()
    if not history or history[-1]["step"] != step:
        evaluate()
    return {"steps": step, "seconds": round(time.perf_counter() - t0, 1), "best_validation_v_measure": best,
            "history": history}


def parse_args(argv: Sequence[str] | None = None) -> Args:
    parser = argparse.ArgumentParser(prog="python -m agents.pdw_metric", description=__doc__.split("\n\n")[0])
    for f in dataclasses.fields(Args):
        if f.type in ("tuple[int, ...]",):
            parser.add_argument(f"--{f.name.replace('_', '-')}", type=int, nargs="+", default=list(f.default))
        else:
            typ = {"str": str, "int": int, "float": float}[f.type]
            parser.add_argument(f"--{f.name.replace('_', '-')}", type=typ, default=f.default)
    ns = vars(parser.parse_args(argv))
    ns["windows"] = tuple(ns["windows"])
    return Args(**ns)


if __name__ == "__main__":
    print(train(parse_args()))

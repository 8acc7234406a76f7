"""DAgger (Ross, Gordon & Bagnell 2011) from the simulator's truth, for the track network (torch directly).

The expert is the truth itself: the right label of the pulse being described (its source's prior
track, or spurious), which is what the genie's labelling reaches whenever the schedule is
unambiguous.  Iteration i rolls the batched token env out with the expert's action with probability
beta_i = beta_decay^i and the learner's greedy action otherwise, so the learner sees the states its
own mistakes lead to (its features depend on its past labels); every described pulse is stored with
the expert's label, and the network is fitted by cross-entropy on the aggregate (capped at `buffer`
samples, oldest dropped).  In blind mode the right label depends on the learner's own track naming:
the expert continues the track holding the pulse's true predecessor, or opens an unused one.  Checkpoints are the same single-file format as the RL agents
(architecture `track-net`), so `agent:checkpoint=PATH` plays them and PPO can fine-tune them.

`--algo bc` is plain behaviour cloning: the same loop with beta = 1 throughout (only the expert's
own states).  `--expert SPEC` imitates a reference policy's labels instead of the truth
(agents.experts).  Each iteration's loss, beta and sample count go to TensorBoard (agents.tb).

With `consistency_weight` > 0 the value head is trained too (binary cross-entropy), to tell whether
the state described is still consistent with the truth (each track's last label right and no wrong
label among the last `consistency_window`): the beam decoder (agents.beam) scores whole hypotheses
with it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from tqdm import tqdm

from agents.checkpoint import load_checkpoint
from agents.config import TrainConfig, TrainResult, hp_int
from agents.networks import TrackPolicy, action_scores, architecture_of, load_weights
from deint_env.envs.tokens import make_tokens_vector_env
from deint_env.errors import DeintError, check
from deint_env.features import TrackLayout
from deint_env.labels import SPURIOUS_PRED

@dataclass(frozen=True)
class DaggerParams:
    n_envs: int = 32
    rollout_steps: int = 1000  # env steps per iteration (x n_envs samples)
    epochs: int = 2
    batch_size: int = 512
    learning_rate: float = 1e-3
    beta_decay: float = 0.5
    buffer: int = 400_000
    # Weight of the consistency loss (0: none): the value head learns whether the state is still
    # consistent with the truth (every track's last label right, no wrong label in the last
    # `consistency_window` pulses), a learned score of whole hypotheses for beam decoding (agents.beam).
    consistency_weight: float = 0.0
    consistency_window: int = 16
    policy_kwargs: dict | None = None

    @classmethod
    def from_yaml(cls, entry: dict[str, Any]) -> DaggerParams:
        known = set(cls.__dataclass_fields__) | {"n_timesteps", "max_tracks"}
        unknown = sorted(set(entry) - known)
        if unknown:
            raise DeintError(f"dagger hyper-parameter {unknown[0]!r} is unknown; known: {', '.join(sorted(known))}")
        for key, hi in (("n_envs", 4096), ("rollout_steps", 10**6), ("epochs", 1000), ("batch_size", 10**6),
                        ("buffer", 10**18), ("consistency_window", 10**6)):
            hp_int(entry, key, 1, hi, "dagger hyper-parameters")  # 1: the default is not looked at
        for key, lo, hi in (("learning_rate", 0.0, 1.0), ("beta_decay", 0.0, 1.0), ("consistency_weight", 0.0, 1e6)):
            value = entry.get(key, getattr(cls, key))
            check(isinstance(value, (int, float)) and not isinstance(value, bool) and lo <= value <= hi
                  and (value > 0 or key != "learning_rate"), f"dagger hyper-parameters: {key}", value,
                  f"a number in {'(' if key == 'learning_rate' else '['}{lo:g}, {hi:g}]")
        return cls(**{k: v for k, v in entry.items() if k in cls.__dataclass_fields__})


def expert_actions(env, max_tracks: int) -> np.ndarray:
    """The truth's label (track index, or max_tracks = spurious) of each sub-env's described pulse.

    Anchored: the pulse's source.  Blind (link rewards): the track the learner gave the pulse's true
    predecessor, or for a source's first pulse a track the learner has not used yet (its link is
    "none"), so the expert continues the learner's own track naming.
    """
    feats, base = env.features, env.env.unwrapped
    out = np.full(env.num_envs, max_tracks, np.int64)
    for i in np.flatnonzero(feats.ready).tolist():
        j = int(feats.labelled[i])
        if not base.blind:
            s = int(base.episodes[i].source[j])
            out[i] = s if s >= 0 else max_tracks
            continue
        pred = int(base._pred[i, j])
        if pred == SPURIOUS_PRED:
            continue
        track = int(base._labels[i, pred]) if pred >= 0 else -1
        if not 0 <= track < feats.n_labels[i] or base._last[i, track] != pred:
            free = np.flatnonzero(feats.exists[i] & (feats.count[i] == 0))
            # No free track left: reuse the one idle longest (its link is lost either way).
            track = int(free[0]) if free.size else int(np.nanargmin(np.where(feats.exists[i], feats.anchor[i], np.inf)))
        out[i] = track
    return out


def _logits(policy: TrackPolicy, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """(action logits, consistency logit) of a batch."""
    features = policy.extract_features(obs, policy.pi_features_extractor)
    latent_pi, latent_vf = policy.mlp_extractor(features)
    return latent_pi, policy.value_net(latent_vf).squeeze(-1)


class _Consistency:
    """Per sub-env: is the learner's labelling so far consistent with the truth (class doc of DaggerParams)."""

    def __init__(self, n_envs: int, max_tracks: int, window: int):
        self.anchor_ok = np.ones((n_envs, max_tracks + 1), bool)
        self.recent_ok = np.ones((n_envs, window), bool)

    def target(self, feats) -> np.ndarray:
        fresh = feats.labelled == 0  # a new episode (nothing labelled yet)
        self.anchor_ok[fresh] = True
        self.recent_ok[fresh] = True
        return self.anchor_ok.all(1) & self.recent_ok.all(1)

    def record(self, feats, ready: np.ndarray, act: np.ndarray, expert: np.ndarray) -> None:
        rows = np.flatnonzero(ready)
        right = act[rows] == expert[rows]
        self.anchor_ok[rows, act[rows]] = right
        self.recent_ok[rows, feats.labelled[rows] % self.recent_ok.shape[1]] = right


def dagger(config: TrainConfig, run, expert) -> TrainResult:
    """Run DAgger (or BC) as `deint train --algo dagger|bc` does (`run` is agents.train's `_Run`,
    `expert` an agents.experts.Expert)."""
    params = DaggerParams.from_yaml({**run.algo_kwargs, "policy_kwargs": run.policy_kwargs, "n_envs": run.n_envs})
    torch.manual_seed(config.seed)
    layout = TrackLayout(max_tracks=run.max_tracks, lookahead=config.lag)
    policy = TrackPolicy(layout.observation_space(), spaces.Discrete(layout.n_actions), lambda _: params.learning_rate,
                         **(params.policy_kwargs or {}))
    optimizer = torch.optim.Adam(policy.parameters(), lr=params.learning_rate)
    last = run.out / "last.safetensors"
    done, iteration = 0, 0
    if last.is_file():
        ck = load_checkpoint(last)
        if (ck.meta.algorithm != config.algo or ck.meta.architecture != architecture_of(policy)
                or ck.meta.hyperparameters.get("expert", "truth") != expert.name):
            raise DeintError(f"{last} holds a {ck.meta.algorithm} agent; this run trains another: choose another "
                             "output directory")
        load_weights(policy, ck.tensors, f"checkpoint {last}")
        done, iteration = ck.meta.timesteps, int(ck.meta.notes.get("iteration", 0))
        run.seconds_before = float(ck.meta.notes.get("train_seconds", 0.0))
        best = ck.meta.notes.get("best_validation_accuracy")
        run.best_score = -np.inf if best is None else float(best)
    env = make_tokens_vector_env(params.n_envs, **run.env_kwargs)
    env.reset(seed=config.seed + iteration)
    rng = np.random.default_rng([config.seed, iteration])
    keys = ("tracks", "mask", "pulse")
    buf: dict[str, list[np.ndarray]] = {k: [] for k in (*keys, "action", "consistent")}
    consistency = _Consistency(params.n_envs, layout.max_tracks, params.consistency_window)
    stored = 0
    next_eval = done + config.eval_every

    class _Model:  # what run.checkpoint / run.meta read
        def __init__(self):
            self.policy, self.num_timesteps = policy, done

    model = _Model()
    obs = env.features.observation()
    bar = tqdm(total=run.timesteps, initial=min(done, run.timesteps), unit="step", disable=not config.progress,
               desc=f"{config.algo} ({expert.name})")

    def out_of_time() -> bool:  # checked every env step and every batch, as SB3's callbacks are: a round can be long
        return config.time_budget is not None and time.perf_counter() - run.t0 >= config.time_budget

    def stop() -> bool:
        return done >= run.timesteps or out_of_time()

    while not stop():
        beta = 1.0 if config.algo == "bc" else params.beta_decay ** iteration
        policy.eval()
        t_iter, done_before = time.perf_counter(), done
        for _ in range(params.rollout_steps):
            if stop():
                break
            ready = env.features.ready
            target = expert.actions(env, layout.max_tracks)
            consistent = consistency.target(env.features)
            if beta < 1.0:
                greedy = np.where(env.action_masks(), action_scores(policy, obs).numpy(), -np.inf).argmax(1)
                act = np.where(rng.random(env.num_envs) < beta, target, greedy)
            else:
                act = target
            if ready.any():
                for k in keys:
                    buf[k].append(obs[k][ready])
                buf["action"].append(target[ready])
                buf["consistent"].append(consistent[ready])
                stored += int(ready.sum())
            consistency.record(env.features, ready, act, target)
            obs, *_ = env.step(act)
            done += env.num_envs
        if done == done_before or not buf["action"]:  # stopped before a new step, or no pulse ready yet
            break
        while stored > params.buffer and len(buf["action"]) > 1:  # drop the oldest rollout steps
            stored -= len(buf["action"][0])
            for k in buf:
                buf[k].pop(0)
        data = {k: torch.as_tensor(np.concatenate(buf[k])) for k in buf}
        policy.train()
        n = len(data["action"])
        losses = []
        for _ in range(params.epochs):
            order = torch.as_tensor(rng.permutation(n))
            for b in range(0, n, params.batch_size):
                if losses and out_of_time():
                    break
                idx = order[b:b + params.batch_size]
                logits, value = _logits(policy, {k: data[k][idx] for k in keys})
                loss = torch.nn.functional.cross_entropy(logits, data["action"][idx])
                if params.consistency_weight:
                    loss = loss + params.consistency_weight * torch.nn.functional.binary_cross_entropy_with_logits(
                        value, data["consistent"][idx].float())
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                losses.append(loss.item())
        iteration += 1
        model.num_timesteps = done
        run.iteration = iteration
        bar.update(done - done_before)
        if run.tb is not None:
            for tag, value in (("train/loss", float(np.mean(losses))), ("train/beta", beta), ("train/samples", n),
                               ("train/iteration", iteration),
                               ("time/steps_per_second", (done - done_before) / (time.perf_counter() - t_iter))):
                run.tb.add_scalar(tag, value, done)
        if done >= next_eval or done >= run.timesteps:
            next_eval = done + config.eval_every
            run.checkpoint(model)
    bar.close()
    if not run.evaluations or run.evaluations[-1]["timesteps"] != done:
        run.checkpoint(model)
    best = run.out / "best.safetensors"
    return TrainResult(last, best if best.is_file() else None, done,
                       run.seconds_before + time.perf_counter() - run.t0, run.evaluations)


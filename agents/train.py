"""Training learned agents (`deint train`): SB3 / sb3-contrib on the batched token features.

    deint train --suite core-v0 --algo maskable-ppo --n-envs 16 --time-budget 1800 --out runs/train/core
    deint train --scenario core-v0/core-n6-spread4-jitter0.05 --algo ppo --timesteps 200000
    deint train --scenario core-v0/core-n6-spread4-jitter0.05 --algo recurrent-ppo --timesteps 200000
    deint train --suite core-v0 --algo dagger --time-budget 900       # imitation of the truth (agents.imitation)
    deint train --suite core-v0 --algo bc --expert mht --timesteps 200000   # behaviour cloning of mht's labels

Hyper-parameters come from rl-zoo-style YAML files, one per algorithm (`agents/hyperparams/ALGO.yml`),
keyed by scenario (`suite/scenario`), then suite, then `default`; `--hyperparams FILE` names another
file.  Training draws episodes from the train seeds minus the validation tail
(`deint_env.envs.mixed.split_seeds`); every `eval_every` steps it writes `last.safetensors`, plays
the validation seeds greedily and keeps the best as `best.safetensors` (both single-file, pickle-free
checkpoints for `agent:checkpoint=PATH`), and appends the evaluation to `eval.jsonl`.  A rerun with
the same output directory resumes from `last.safetensors` (its weights and step count; the optimiser
moments and a DQN replay buffer start afresh).  The output directory may not lie inside the installed
package unless `into_package=True` (`--into-package`).  TensorBoard logs go to `OUT/tensorboard`:
SB3's own scalars (`tensorboard_log`), the imitation loop's (agents.imitation) and, for every
algorithm, `eval/validation_accuracy`.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecMonitor

from agents.checkpoint import CheckpointMeta, load_checkpoint, save_checkpoint
from agents.config import TrainConfig, TrainResult, hp_int, whole
from agents.experts import TRUTH
from agents.networks import (MaskableTrackPolicy, RecurrentTrackPolicy, TrackDQNPolicy, TrackPolicy, action_scores,
                             architecture_of, load_weights, recurrent_scores, weights_of)
from agents.tb import next_run_dir, tensorboard_available, writer
from agents.vec_env import TokenVecEnv
from deint_env.envs.mixed import select_entries, split_seeds
from deint_env.envs.vector import MAX_ENVS
from deint_env.errors import DeintError, check
from deint_env.features import MAX_TRACKS
from deint_env.suites import load_suite

ALGOS = ("ppo", "maskable-ppo", "recurrent-ppo", "a2c", "dqn", "dagger", "bc", "seq", "lmht")
IMITATION = ("dagger", "bc")  # agents.imitation; their YAML is dagger.yml
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
PACKAGE_DIRS = tuple(Path(__file__).resolve().parent.parent / d for d in ("agents", "deint_env", "baselines"))
# Keys of a YAML entry that are not the algorithm's own keyword arguments (as in rl-zoo).
RUN_KEYS = ("n_envs", "n_timesteps", "policy", "max_tracks")
MAX_D_MODEL = 1024  # the track network's width: its largest layers hold d_model^2 weights (4 MB at 1024)


def _algo_class(algo: str):
    if algo == "ppo":
        from stable_baselines3 import PPO
        return PPO, TrackPolicy
    if algo == "a2c":
        from stable_baselines3 import A2C
        return A2C, TrackPolicy
    if algo == "dqn":
        from stable_baselines3 import DQN
        return DQN, TrackDQNPolicy
    if algo == "maskable-ppo":
        from sb3_contrib import MaskablePPO
        return MaskablePPO, MaskableTrackPolicy
    if algo == "recurrent-ppo":
        from sb3_contrib import RecurrentPPO
        return RecurrentPPO, RecurrentTrackPolicy
    raise DeintError(f"--algo {algo!r} is unknown; known: {', '.join(ALGOS)}")


def load_hyperparams(algo: str, keys: list[str], path: Path | None = None) -> tuple[str, dict[str, Any]]:
    """(the key used, its entry) from the algorithm's YAML: the first of `keys` present, else default."""
    path = path or HYPERPARAMS_DIR / f"{'dagger' if algo in IMITATION else algo}.yml"
    if not path.is_file():
        raise DeintError(f"hyper-parameter file {path} does not exist")
    try:
        table = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise DeintError(f"{path}: is not UTF-8 text; a hyper-parameter file is YAML") from None
    except yaml.YAMLError as e:
        raise DeintError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(table, dict):
        raise DeintError(f"{path}: must map suite or scenario names to hyper-parameters")
    for key in [*keys, "default"]:
        if key in table:
            entry = table[key]
            if not isinstance(entry, dict):
                raise DeintError(f"{path}: entry {key!r} must be a mapping")
            return key, dict(entry)
    raise DeintError(f"{path} has no entry for {', '.join(keys)} and no 'default'")


def check_policy_kwargs(kwargs: Any, where: str) -> dict[str, Any]:
    """The entry's policy_kwargs: a mapping whose track-network sizes are bounded before any weight is made."""
    check(isinstance(kwargs, dict), f"{where}: policy_kwargs", kwargs, "a mapping of the network's arguments")
    d_model = hp_int(kwargs, "d_model", 64, MAX_D_MODEL, where, "policy_kwargs.")
    heads = hp_int(kwargs, "heads", 4, d_model, where, "policy_kwargs.")
    check(d_model % heads == 0, f"{where}: policy_kwargs.heads", heads, f"a divisor of d_model={d_model}")
    hp_int(kwargs, "lstm_hidden_size", 64, MAX_D_MODEL, where, "policy_kwargs.")
    hp_int(kwargs, "n_lstm_layers", 1, 16, where, "policy_kwargs.")
    arch = kwargs.get("net_arch", [])
    layers = [arch.get(k, []) for k in ("pi", "vf", "qf")] if isinstance(arch, dict) else [arch]
    check(all(isinstance(v, list) and all(whole(w, MAX_D_MODEL) for w in v) for v in layers),
          f"{where}: policy_kwargs.net_arch", arch, f"lists of layer widths, integers in [1, {MAX_D_MODEL}]")
    return dict(kwargs)


def _check_out(out: Path, into_package: bool) -> Path:
    out = out.resolve()
    if not into_package and any(out == d or d in out.parents for d in PACKAGE_DIRS):
        raise DeintError(f"output {out} lies inside the installed package; choose another directory "
                         "or pass --into-package")
    return out


def _versions() -> dict[str, str]:
    import gymnasium
    import sb3_contrib
    import stable_baselines3

    from deint_env import __version__
    return {"deint_bench": __version__, "stable_baselines3": stable_baselines3.__version__,
            "sb3_contrib": sb3_contrib.__version__, "torch": torch.__version__, "gymnasium": gymnasium.__version__,
            "numpy": np.__version__}


def _hyperparam_keys(config: TrainConfig) -> list[str]:
    """The YAML keys to look up, most specific first: the one scenario trained on, then the suite."""
    return ([config.scenarios[0]] if len(config.scenarios) == 1 else []) + ([config.suite] if config.suite else [])


def evaluate_greedy(policy, env_kwargs: dict[str, Any], episodes: int, seed: int = 0) -> float:
    """Mean episode accuracy of `policy` (greedy, masked) over `episodes` validation episodes (a
    recurrent policy carries its LSTM state, reset when an episode ends)."""
    n = min(episodes, 16)
    env = TokenVecEnv.make(n, **{**env_kwargs, "split": "validation"})
    env.seed(seed)
    obs = env.reset()
    scores: list[float] = []
    recurrent = isinstance(policy, RecurrentTrackPolicy)
    state, starts = (policy.initial_state(n) if recurrent else None), np.ones(n, bool)
    while len(scores) < episodes:
        if recurrent:
            logits, state = recurrent_scores(policy, obs, state, starts)
            q = logits.numpy()
        else:
            q = action_scores(policy, obs).numpy()
        actions = np.where(env.action_masks(), q, -np.inf).argmax(axis=1)
        env.step_async(actions)
        obs, _, dones, infos = env.step_wait()
        scores += [infos[i]["episode_accuracy"] for i in np.flatnonzero(dones).tolist()]
        starts = dones
    env.close()
    return float(np.mean(scores[:episodes]))


class _Checkpointer(BaseCallback):
    """Periodic save + validation, and the time budget."""

    def __init__(self, run: _Run):
        super().__init__()
        self.run = run
        self.next_eval = run.config.eval_every

    def _on_training_start(self) -> None:
        self.next_eval = self.num_timesteps + self.run.config.eval_every

    def _on_step(self) -> bool:
        run = self.run
        if self.num_timesteps >= self.next_eval:
            self.next_eval += run.config.eval_every
            run.checkpoint(self.model)
        budget = run.config.time_budget
        return budget is None or time.perf_counter() - run.t0 < budget


class _Run:
    def __init__(self, config: TrainConfig):
        self.config = config
        self.out = _check_out(Path(config.out), config.into_package)
        entries = select_entries(config.suite, config.scenarios, config.tags)
        self.scenarios = [n for n, _ in entries]
        suites = sorted({n.split("/")[0] for n in self.scenarios})
        self.suite_hashes = {s: load_suite(s).content_hash for s in suites}
        self.train_ranges = sorted({(r.start, r.stop) for _, e in entries for r in [split_seeds(e, "train")]})
        self.max_labels = max(e.spec.n_labels for _, e in entries)
        self.blind = any(e.spec.blind for _, e in entries)
        self.hp_key, hp = load_hyperparams(config.algo, _hyperparam_keys(config), config.hyperparams_file)
        where = f"hyper-parameters {self.hp_key!r} for {config.algo}"
        self.n_envs = config.n_envs or hp_int(hp, "n_envs", 8, MAX_ENVS, where)
        self.timesteps = config.timesteps or hp_int(hp, "n_timesteps", 10**6, 10**15, where)
        self.max_tracks = max(hp_int(hp, "max_tracks", 8, MAX_TRACKS, where), self.max_labels)
        self.policy_kwargs = check_policy_kwargs(hp.get("policy_kwargs", {}), where)
        self.algo_kwargs = {k: v for k, v in hp.items() if k not in RUN_KEYS and k != "policy_kwargs"}
        self.env_kwargs = dict(suite=config.suite, scenarios=list(config.scenarios) or None,
                               tags=list(config.tags) or None, lag=config.lag, max_tracks=self.max_tracks)
        self.best_score = -np.inf
        self.evaluations: list[dict[str, Any]] = []
        self.t0 = time.perf_counter()
        self.seconds_before = 0.0
        self.iteration = 0  # DAgger's iteration count (agents.imitation)
        self.tb = None  # the imitation loop's SummaryWriter (SB3 logs through its own logger)

    def meta(self, model) -> CheckpointMeta:
        from deint_env.features import TrackLayout

        layout = TrackLayout(max_tracks=self.max_tracks, lookahead=self.config.lag)
        hp = {**self.algo_kwargs, "policy_kwargs": self.policy_kwargs, "n_envs": self.n_envs,
              "max_tracks": self.max_tracks, "hyperparams_key": self.hp_key}
        if self.config.algo in IMITATION:
            hp["expert"] = self.config.expert
        return CheckpointMeta(
            architecture=architecture_of(model.policy), features=layout.to_dict(), algorithm=self.config.algo,
            scenarios=self.scenarios, suite_hashes=self.suite_hashes,
            train_seeds=list(self.train_ranges[0]),
            timesteps=int(model.num_timesteps), hyperparameters=json.loads(json.dumps(hp, default=str)),
            versions=_versions(), seed=self.config.seed,
            notes={"train_seconds": round(self.seconds_before + time.perf_counter() - self.t0, 1),
                   "iteration": self.iteration,
                   "best_validation_accuracy": None if self.best_score == -np.inf else self.best_score,
                   "train_seed_ranges": [list(r) for r in self.train_ranges]})

    def checkpoint(self, model) -> None:
        policy = model.policy
        t0 = time.perf_counter()
        score = evaluate_greedy(policy, self.env_kwargs, self.config.eval_episodes, seed=self.config.seed)
        record = {"timesteps": int(model.num_timesteps), "validation_accuracy": round(score, 4),
                  "seconds": round(self.seconds_before + time.perf_counter() - self.t0, 1),
                  "eval_seconds": round(time.perf_counter() - t0, 2)}  # of "seconds", spent validating
        self.evaluations.append(record)
        if score > self.best_score:
            self.best_score = score
            save_checkpoint(self.out / "best.safetensors", weights_of(policy), self.meta(model))
        save_checkpoint(self.out / "last.safetensors", weights_of(policy), self.meta(model))
        if self.tb is not None:
            self.tb.add_scalar("eval/validation_accuracy", score, record["timesteps"])
            self.tb.flush()
        elif hasattr(model, "logger"):  # SB3: written with the rollout's scalars
            model.logger.record("eval/validation_accuracy", score)
        with open(self.out / "eval.jsonl", "a") as f:
            f.write(json.dumps(record) + "\n")
        if self.config.progress:
            print(f"  {record['timesteps']} steps: validation accuracy {score:.3f} ({record['seconds']} s)", flush=True)


def train(config: TrainConfig) -> TrainResult:
    if config.algo not in ALGOS:
        raise DeintError(f"--algo {config.algo!r} is unknown; known: {', '.join(ALGOS)}")
    if config.expert != TRUTH and config.algo not in IMITATION:
        raise DeintError(f"--expert applies to {' and '.join(IMITATION)}, not to --algo {config.algo}")
    if config.algo == "seq":  # the supervised pointer labeller: its own loop, no SB3 model (agents.sequence)
        from agents.sequence import train_seq_phases
        return train_seq_phases(config, _check_out(Path(config.out), config.into_package),
                                load_hyperparams("seq", _hyperparam_keys(config), config.hyperparams_file))
    if config.algo == "lmht":  # mht's learned scorer: its own loop (agents.lmht)
        from agents.lmht import train_config
        return train_config(config, _check_out(Path(config.out), config.into_package),
                            load_hyperparams("lmht", _hyperparam_keys(config), config.hyperparams_file))
    run = _Run(config)
    if config.algo in IMITATION:
        from agents.experts import make_expert
        from agents.imitation import DaggerParams, dagger

        expert = make_expert(config.expert)  # an unknown spec fails before anything is written
        DaggerParams.from_yaml({**run.algo_kwargs, "policy_kwargs": run.policy_kwargs, "n_envs": run.n_envs})
        if config.expert != TRUTH and run.blind:
            raise DeintError(f"--expert {config.expert!r} imitates anchored labels; blind scenarios need --expert truth")
        run.out.mkdir(parents=True, exist_ok=True)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        run.tb = writer(next_run_dir(run.out / "tensorboard", config.algo), config.progress)
        try:
            return dagger(config, run, expert)
        finally:
            torch.set_num_threads(threads)
            if run.tb is not None:
                run.tb.close()
    run.out.mkdir(parents=True, exist_ok=True)
    algo_cls, policy_cls = _algo_class(config.algo)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small networks: thread hand-offs cost more than they save
    tb = str(run.out / "tensorboard") if tensorboard_available() else None
    if tb is None and config.progress:
        print("deint: tensorboard is not installed, so no TensorBoard logs (pip install tensorboard)", flush=True)
    try:
        venv = VecMonitor(TokenVecEnv.make(run.n_envs, **run.env_kwargs))
        try:
            model = algo_cls(policy_cls, venv, seed=config.seed, device="cpu", tensorboard_log=tb,
                             policy_kwargs=run.policy_kwargs, **run.algo_kwargs)
        except (TypeError, ValueError) as e:  # an unknown keyword, or a value SB3 or torch refuses (lr=nan)
            raise DeintError(f"hyper-parameters {run.hp_key!r} for {config.algo}: {str(e).splitlines()[0]}") from None
        last = run.out / "last.safetensors"
        done = 0
        if last.is_file():  # resume
            ck = load_checkpoint(last)
            if ck.meta.architecture != architecture_of(model.policy) or ck.meta.algorithm != config.algo:
                raise DeintError(f"{last} holds a {ck.meta.algorithm} {ck.meta.architecture['name']} agent; "
                                 "this run trains another: choose another output directory")
            load_weights(model.policy, ck.tensors, f"checkpoint {last}")
            model.policy.set_training_mode(True)
            done = ck.meta.timesteps
            run.seconds_before = float(ck.meta.notes.get("train_seconds", 0.0))
            best = ck.meta.notes.get("best_validation_accuracy")
            run.best_score = -np.inf if best is None else float(best)
            model.num_timesteps = done
            if config.progress:
                print(f"deint: resuming {last} at {done} steps", flush=True)
        remaining = run.timesteps - done
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=_Checkpointer(run), reset_num_timesteps=False,
                        progress_bar=config.progress, tb_log_name=config.algo)
            if not run.evaluations or run.evaluations[-1]["timesteps"] != model.num_timesteps:
                run.checkpoint(model)
                model.logger.dump(model.num_timesteps)
        venv.close()
    finally:
        torch.set_num_threads(threads)
    best = run.out / "best.safetensors"
    return TrainResult(last, best if best.is_file() else None, int(model.num_timesteps),
                       run.seconds_before + time.perf_counter() - run.t0, run.evaluations)


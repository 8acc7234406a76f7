"""Generalisation report (issue 9, item 9): how far a learned agent carries beyond what it was trained on,
and what each training algorithm costs per million env steps on this machine.

(a) train vs test seeds, (b) held-out conditions: a DAgger agent (the simulator's truth as expert) is
trained on train seeds of the core-v0 scenarios with 2-4 sources, period spreads 1.5 and 4 and
jitters 0.05 and 0.2 only, then played on the test seeds of 6- and 8-source scenarios, of the unseen
spread 16 and of the unseen jitter 0.5.  Beside it, on the very same episodes: the checked-in zoo agent
(trained on every core-v0 scenario, the same network and lag) and the paper algorithm fdp.
(c) cost: each `deint train` algorithm (its shipped YAML, the track network) for a bounded number of
steps on one scenario, plus RecurrentPPO (sb3-contrib, MlpLstmPolicy on the flat token features;
not a `deint train` algorithm), against SB3 PPO on CartPole-v1 measured in the same run (before and
after the others, to show the machine's drift).  Training steps only: the validation time is
subtracted.

    nice python benchmarks/generalisation.py --train-budget 720 --cost-steps 32768 --cost-budget 90 \
        --work runs/generalisation --out leaderboards/GENERALISATION.md

With `--work DIR` the parts are kept (`DIR/costs.json`, the held-out agent in `DIR/held-out/`) and a
rerun reuses what is there instead of measuring or training it again.

Accuracy is the env's per-episode label accuracy (fraction of pulses given their source), averaged
over the episodes of a group; a group's episodes are the first `--seeds` seeds of each scenario's
split.  Figures are printed and written as markdown, never asserted.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from agents.checkpoint import read_meta
from agents.config import TrainConfig
from agents.networks import action_scores
from agents.policy import load_agent
from agents.train import train
from deint_env.envs.mixed import split_seeds
from deint_env.envs.tokens import make_tokens_vector_env
from deint_env.policies import make_policy
from deint_env.runner import accuracy_of, play
from deint_env.simulate import simulate
from deint_env.suites import find_entry

ROOT = Path(__file__).resolve().parents[1]
ZOO = ROOT / "agents" / "checkpoints" / "dagger-core-v0-lag3.safetensors"
COST_SCENARIO = "core-v0/core-n6-spread4-jitter0.05"
CARTPOLE = dict(n_steps=128, batch_size=512, n_epochs=4, learning_rate=3e-4, gamma=0.5, device="cpu",
                policy_kwargs=dict(net_arch=[64, 64]))


def core(n: int, spread: str, jitter: str) -> str:
    return f"core-v0/core-n{n}-spread{spread}-jitter{jitter}"


SEEN_SPREADS, SEEN_JITTERS = ("1.5", "4"), ("0.05", "0.2")
TRAIN = [core(n, s, j) for n in (2, 3, 4) for s in SEEN_SPREADS for j in SEEN_JITTERS]
GROUPS = {  # name -> (scenarios, split)
    "(a) training conditions, train seeds": (TRAIN, "train"),
    "(a) training conditions, test seeds": (TRAIN, "test"),
    "(b) 6 sources (seen spreads, jitters)": ([core(6, s, j) for s in SEEN_SPREADS for j in SEEN_JITTERS], "test"),
    "(b) 8 sources (seen spreads, jitters)": ([core(8, s, j) for s in SEEN_SPREADS for j in SEEN_JITTERS], "test"),
    "(b) unseen spread 16 (2-4 sources)": ([core(n, "16", j) for n in (2, 3, 4) for j in SEEN_JITTERS], "test"),
    "(b) unseen jitter 0.5 (2-4 sources)": ([core(n, s, "0.5") for n in (2, 3, 4) for s in SEEN_SPREADS], "test"),
}


@dataclass(frozen=True)
class Cost:
    name: str
    network: str
    steps: int
    seconds: float

    @property
    def per_million(self) -> float:
        return self.seconds / self.steps * 1e6


def agent_accuracies(checkpoint: Path, scenario: str, seeds: range) -> list[float]:
    """Greedy episode accuracy of the checkpoint on `scenario` at each of `seeds`, all episodes batched."""
    ck, net = load_agent(checkpoint)
    layout = ck.meta.features
    env = make_tokens_vector_env(len(seeds), scenario=scenario, lag=layout["lookahead"], max_tracks=layout["max_tracks"])
    obs, _ = env.reset(seed=seeds.start)  # sub-env i plays episode seed seeds.start + i
    acc = np.full(len(seeds), np.nan)
    while np.isnan(acc).any():
        actions = np.where(env.action_masks(), action_scores(net, obs).numpy(), -np.inf).argmax(1)
        obs, _, terminated, _, info = env.step(actions)
        if terminated.any():
            first = terminated & np.isnan(acc)
            acc[first] = info["episode_accuracy"][first]
    env.close()
    return acc.tolist()


def reference_accuracies(spec: str, scenario: str, seeds: range) -> list[float]:
    entry = find_entry(scenario)
    return [accuracy_of(play(make_policy(spec), ep, clustering=False).labels, ep)
            for ep in (simulate(entry.spec, s) for s in seeds)]


def first_seeds(scenario: str, split: str, n: int) -> range:
    start = split_seeds(find_entry(scenario), split).start
    return range(start, start + n)


def group_table(agents: dict[str, Path], seeds: int) -> list[dict]:
    """One row per group: each agent's and fdp's mean accuracy on the same episodes."""
    rows = []
    for group, (scenarios, split) in GROUPS.items():
        row = {"group": group, "scenarios": len(scenarios), "episodes": len(scenarios) * seeds}
        for name, path in agents.items():
            row[name] = float(np.mean([a for sc in scenarios
                                       for a in agent_accuracies(path, sc, first_seeds(sc, split, seeds))]))
        row["fdp"] = float(np.mean([a for sc in scenarios
                                    for a in reference_accuracies("fdp", sc, first_seeds(sc, split, seeds))]))
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def train_cost(algo: str, tmp: Path, steps: int, budget: float, expert: str = "truth") -> Cost:
    result = train(TrainConfig(out=tmp / f"cost-{algo}-{expert}", algo=algo, scenarios=(COST_SCENARIO,), n_envs=16,
                               timesteps=steps, time_budget=budget, eval_every=10**12, eval_episodes=2,
                               progress=False, expert=expert))
    evaluating = sum(e["eval_seconds"] for e in result.evaluations)
    name = algo if algo not in ("dagger", "bc") else f"{algo} (expert {expert})"
    return Cost(name, "track network d64 + attention", result.timesteps, result.seconds - evaluating)


def sb3_cost(make, steps: int, budget: float) -> Cost:
    from stable_baselines3.common.callbacks import BaseCallback

    class Budget(BaseCallback):
        def _on_step(self) -> bool:
            return time.perf_counter() - t0 < budget

    name, network, model = make()
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, callback=Budget())
    seconds = time.perf_counter() - t0
    model.env.close()
    return Cost(name, network, model.num_timesteps, seconds)


def cartpole(steps: int, budget: float) -> Cost:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    return sb3_cost(lambda: ("CartPole-v1 PPO (reference)", "MlpPolicy 64x64",
                             PPO("MlpPolicy", make_vec_env("CartPole-v1", n_envs=16), seed=0, **CARTPOLE)), steps, budget)


def recurrent_ppo(steps: int, budget: float) -> Cost:
    from sb3_contrib import RecurrentPPO

    from agents.vec_env import TokenVecEnv

    return sb3_cost(lambda: ("recurrent-ppo (sb3-contrib, not in deint train)", "MlpLstmPolicy on flat tokens",
                             RecurrentPPO("MlpLstmPolicy", TokenVecEnv.make(16, scenario=COST_SCENARIO, flat=True),
                                          seed=0, **{**CARTPOLE, "policy_kwargs": {}})), steps, budget)


def markdown(costs: list[Cost], rows: list[dict], args, trained: dict) -> str:
    lines = ["# Generalisation and training cost", "",
             f"Generated by `benchmarks/generalisation.py` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}) on this "
             "project's 2-core machine while other jobs shared it (load average about 10); every figure below was "
             "measured by it (with `--work`, the two tables may come from two invocations).", "",
             "## Train vs test seeds, held-out conditions", "",
             f"Held-out agent: `deint train --algo dagger --lag 3 --time-budget {args.train_budget:g}` on the train seeds "
             f"of {len(TRAIN)} core-v0 scenarios (2-4 sources, spreads {'/'.join(SEEN_SPREADS)}, jitters "
             f"{'/'.join(SEEN_JITTERS)}): {trained['timesteps']} steps in {trained['seconds']:.0f} s, best validation "
             f"accuracy {trained['validation']:.3f}.  Zoo agent: `{ZOO.relative_to(ROOT)}` (all 45 core-v0 scenarios, "
             "the same network, lag 3).  Each group: the first "
             f"{args.seeds} seeds of each scenario's split; mean episode label accuracy.", "",
             "| group | scenarios | episodes | held-out agent | zoo agent (saw every condition) | fdp |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['group']} | {r['scenarios']} | {r['episodes']} | {r['held-out']:.3f} | {r['zoo']:.3f} "
                     f"| {r['fdp']:.3f} |")
    if not costs:
        return "\n".join(lines) + "\n"
    lines += ["", "## Cost per million env steps", "",
              f"On `{COST_SCENARIO}`, 16 envs, lag 0, at most {args.cost_steps} steps or {args.cost_budget:g} s each "
              "(the steps column says how many were run), training only (validation time subtracted).  "
              "CartPole-v1 PPO (MlpPolicy 64x64, n_steps 128, batch 512, 4 epochs, 16 envs) ran first and last as the "
              "machine's reference; its mean is the ratio's base.", "",
              "| algorithm | network | steps run | steps/s | seconds per 1M steps | steps/s vs CartPole PPO |",
              "|---|---|---|---|---|---|"]
    ref = float(np.mean([c.steps / c.seconds for c in costs if c.name.startswith("CartPole")]))
    for c in costs:
        sps = c.steps / c.seconds
        lines.append(f"| {c.name} | {c.network} | {c.steps} | {sps:,.0f} | {c.per_million:,.0f} | {sps / ref:.2f}x |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-budget", type=float, default=720, help="seconds of DAgger training for (a), (b)")
    parser.add_argument("--seeds", type=int, default=4, help="episodes per scenario and group")
    parser.add_argument("--cost-steps", type=int, default=32768)
    parser.add_argument("--cost-budget", type=float, default=90, help="seconds at most per algorithm in (c)")
    parser.add_argument("--out", default=None, help="markdown file to write (default: print only)")
    parser.add_argument("--skip-cost", action="store_true")
    parser.add_argument("--work", default=None, help="keep (and reuse) the measured parts here (default: a temporary directory)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(args.work or d)
        tmp.mkdir(parents=True, exist_ok=True)
        costs_file = tmp / "costs.json"
        costs: list[Cost] = []
        if costs_file.is_file():
            costs = [Cost(**c) for c in json.loads(costs_file.read_text())]
        elif not args.skip_cost:
            costs.append(cartpole(args.cost_steps, args.cost_budget))
            for algo, expert in (("ppo", "truth"), ("maskable-ppo", "truth"), ("a2c", "truth"), ("dqn", "truth"),
                                 ("dagger", "truth"), ("bc", "truth"), ("bc", "mht")):
                costs.append(train_cost(algo, tmp, args.cost_steps, args.cost_budget, expert))
                print(costs[-1], flush=True)
            costs.append(recurrent_ppo(args.cost_steps, args.cost_budget))
            costs.append(cartpole(args.cost_steps, args.cost_budget))
            costs_file.write_text(json.dumps([asdict(c) for c in costs], indent=1))
        for c in costs:
            print(f"{c.name:50s} {c.steps:7d} steps {c.steps / c.seconds:8.0f} steps/s", flush=True)
        best = tmp / "held-out" / "best.safetensors"
        if not best.is_file():
            train(TrainConfig(out=tmp / "held-out", algo="dagger", scenarios=tuple(TRAIN), lag=3,
                              time_budget=args.train_budget, eval_every=64_000, eval_episodes=32, progress=False))
        meta = read_meta(tmp / "held-out" / "last.safetensors")
        trained = {"timesteps": meta.timesteps, "seconds": meta.notes["train_seconds"],
                   "validation": meta.notes["best_validation_accuracy"]}
        print(trained, flush=True)
        rows = group_table({"held-out": best, "zoo": ZOO}, args.seeds)
    text = markdown(costs, rows, args, trained)
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()

"""Learned agents (stable-baselines3 / torch).  `POLICIES` is this package's entry in the
`deint_bench.policies` entry point group: the factories are strings, so torch and stable-baselines3
load when a policy is first built.

Checkpoints are single safetensors files (`agents.checkpoint`); loading one never unpickles.
"""

from deint_env.policies import Limits, PolicyInfo

POLICIES = (
    PolicyInfo("agent", "agents.policy:agent", kind="learned", ablation="network=off", extra="rl", required=("checkpoint",),
               description="a learned agent from a deint checkpoint file (agent:checkpoint=PATH.safetensors)"),
    PolicyInfo("agent-beam", "agents.policy:BeamPolicy", kind="learned", ablation="network=off", modes=("anchored",), extra="rl",
               required=("checkpoint",),
               description="a track-network checkpoint decoded with a beam of its own log-probabilities "
                           "(agent-beam:checkpoint=PATH,beam=8,decision_lag=8; lag = look-ahead + decision_lag)"),
    PolicyInfo("dagger-beam", "agents.policy:dagger_beam", kind="learned", ablation="network=off", modes=("anchored",), extra="rl",
               division_params=(("online", "decision_lag=0"),),
               limits=Limits(max_sources=8),
               description="the zoo's agent for core-v0, robust-v0 and agile-v0 (agents/checkpoints/"
                           "dagger-all-lag3.safetensors, DAgger on their train seeds, token layout 3), decoded "
                           "with a beam of 8 of its own log-probabilities; lag 3 + decision_lag 20 = 23"),
    PolicyInfo("lmht", "agents.lmht:LMHT", kind="learned", ablation="network=off", modes=("anchored",), extra="rl",
               limits=Limits(max_sources=256),  # mht's search (baselines/__init__.py)
               division_params=(("online", "lag=3,nscan=3"), ("low-latency", "lag=64")),
               description="mht's tracker whose candidate scores carry a trained correction (one small network shared "
                           "by every candidate: agents/lmht.py, agents/checkpoints/lmht-v1.safetensors, trained on "
                           "core-v0 + robust-v0 train seeds; searching with a score margin of 12 nats, 2.5 "
                           "hypotheses per source, restarts after one missed arrival, period jumps after "
                           "deviating hits: agents.lmht.SEARCH; "
                           "lmht:checkpoint=PATH,beam=B,margin=M,...)"),
    PolicyInfo("dagger", "agents.policy:dagger", kind="learned", ablation="network=off", modes=("anchored",), extra="rl",
               description="the zoo's DAgger agent (agents/checkpoints/dagger-core-v0-lag3.safetensors): trained on "
                           "core-v0's train seeds, plays 2-8 sources, lag 3"),
    PolicyInfo("seq", "agents.sequence:SequencePolicy", kind="learned", ablation="network=off", modes=("blind",), extra="rl",
               description="supervised pointer sequence labeller (Transformer over the pulse window, look-ahead = lag 32; "
                           "agents/checkpoints/seq-blind-v0.safetensors, trained on blind-v0's train seeds): blind only"),
    PolicyInfo("pdw-metric", "agents.pdw_metric:PDWMetricPolicy", kind="learned", ablation="network=off", modes=("blind",),
               extra="rl",
               description="blind, PDWs: a transformer trained by deep metric learning (supervised contrastive) on "
                           "pdw-v0's train seeds embeds each pulse of a 2048-pulse window; HDBSCAN clusters the "
                           "embeddings, emitters carried across windows as the pdw-* policies do (agents/checkpoints/"
                           "pdw-metric-v1.safetensors; lag = window - 1; network=off: the scaled features clustered)"),
    PolicyInfo("ppo", "agents.policy:ppo", kind="learned", ablation="network=off", modes=("anchored",), extra="rl",
               description="PPO (stable-baselines3 MLP) on the pulse features; trained on a two-source scenario"),
)

"""Learned agents (stable-baselines3 / torch).  `POLICIES` is this package's entry in the
`deint_bench.policies` entry point group: the factories are strings, so torch and stable-baselines3
load when a policy is first built.

Checkpoints are single safetensors files (`agents.checkpoint`); loading one never unpickles.
"""

from deint_env.policies import PolicyInfo

POLICIES = (
    PolicyInfo("agent", "agents.policy:AgentPolicy", kind="learned", extra="rl",
               description="a learned agent from a deint checkpoint file (agent:checkpoint=PATH.safetensors)"),
    PolicyInfo("ppo", "agents.policy:ppo", kind="learned", modes=("anchored",), extra="rl",
               description="PPO (stable-baselines3 MLP) on the pulse features; trained on a two-source scenario"),
)

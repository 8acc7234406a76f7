"""Learned agents (stable-baselines3 / torch).  Importing this package only registers their names:
the entry points are strings, so torch and stable-baselines3 load when a policy is first built.

Checkpoints are single safetensors files (`agents.checkpoint`); loading one never unpickles.
"""

from deint_env.policies import register_policy

register_policy("agent", "agents.policy:AgentPolicy", extra="rl",
                description="a learned agent from a deint checkpoint file (agent:checkpoint=PATH.safetensors)")
register_policy("ppo", "agents.policy:ppo", extra="rl",
                description="PPO (stable-baselines3 MLP) on the pulse features; trained on a two-source scenario")

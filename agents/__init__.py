"""Learned agents (stable-baselines3 / torch).  `POLICIES` is this package's entry in the
`deint_bench.policies` entry point group: the factories are strings, so torch and stable-baselines3
load when a policy is first built."""

from deint_env.policies import PolicyInfo

POLICIES = (
    PolicyInfo("ppo", "agents.ppo:PPOPolicy", kind="learned", modes=("anchored",), extra="rl",
               description="PPO (stable-baselines3 MLP) on the pulse features; trained on a two-source scenario"),
)

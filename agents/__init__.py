"""Learned agents (stable-baselines3 / torch).  Importing this package only registers their names:
the entry points are strings, so torch and stable-baselines3 load when a policy is first built."""

from deint_env.policies import register_policy

register_policy("ppo", "agents.ppo:PPOPolicy", extra="rl",
                description="PPO (stable-baselines3 MLP) on the pulse features; trained on a two-source scenario")

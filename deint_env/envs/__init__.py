"""The Gymnasium environments: the single env, the native vector env and their viewer."""

from deint_env.envs.deinterleave import DeinterleaveEnv

__all__ = ["DeinterleaveEnv"]

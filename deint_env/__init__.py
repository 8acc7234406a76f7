"""deint-bench: a Gymnasium benchmark for pulse-train deinterleaving.

    import gymnasium as gym, deint_env
    env = gym.make("deint_env/Deinterleave-v0", scenario="paper-v0/mk94-three", lag=3)
"""

from deint_env.episode import Episode, Priors, Truth
from deint_env.errors import DeintError
from deint_env.policies import BatchPolicy, Policy, PolicyInfo, list_policies, make_policy, register_policy
from deint_env.registration import env_ids, register_envs
from deint_env.scenario import DescriptorSpec, Modulation, PriorSpec, Range, ReceiverSpec, ScenarioSpec, SourceSpec
from deint_env.simulate import simulate, simulate_many
from deint_env.suites import list_suites, load_suite, resolve_scenario

register_envs()


def __getattr__(name: str):
    """`evaluate` and `Evaluation` load on first use (they bring the token features), and so does
    `__version__` (read from the installed metadata by importlib.metadata): neither `deint --help` nor
    `deint label` nor a plain `import deint_env` needs them (start-up time, benchmarks/bench_startup.py)."""
    if name in ("evaluate", "Evaluation"):
        from deint_env import evaluation

        return getattr(evaluation, name)
    if name == "__version__":
        from deint_env.version import __version__

        return __version__
    raise AttributeError(f"module 'deint_env' has no attribute {name!r}")

__all__ = [
    "BatchPolicy", "DeintError", "DescriptorSpec", "Episode", "Evaluation", "Modulation", "Policy", "PolicyInfo",
    "PriorSpec", "Priors", "Range", "ReceiverSpec", "ScenarioSpec", "SourceSpec", "Truth", "env_ids", "evaluate",
    "list_policies", "list_suites", "load_suite", "make_policy", "register_policy", "resolve_scenario", "simulate",
    "simulate_many", "__version__",
]

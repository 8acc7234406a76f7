"""deint-bench: a Gymnasium benchmark for pulse-train deinterleaving.

    import gymnasium as gym, deint_env
    env = gym.make("deint_env/Deinterleave-v0", scenario="paper-v0/mk94-three", lag=3)
"""

from importlib.metadata import PackageNotFoundError, version

from deint_env.episode import Episode, Priors, Truth
from deint_env.errors import DeintError
from deint_env.policies import Policy, PolicyInfo, list_policies, make_policy, register_policy
from deint_env.registration import env_ids, register_envs
from deint_env.scenario import Modulation, PriorSpec, Range, ScenarioSpec, SourceSpec
from deint_env.simulate import simulate, simulate_many
from deint_env.suites import list_suites, load_suite, resolve_scenario

try:
    __version__ = version("deint-bench")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"

register_envs()

__all__ = [
    "DeintError", "Episode", "Modulation", "Policy", "PolicyInfo", "PriorSpec", "Priors", "Range", "ScenarioSpec",
    "SourceSpec", "Truth", "env_ids", "list_policies", "list_suites", "load_suite", "make_policy", "register_policy",
    "resolve_scenario", "simulate", "simulate_many", "__version__",
]

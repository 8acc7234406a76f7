"""Gymnasium ids (registered idempotently, with string entry points).

`deint_env/Deinterleave-v0` takes any scenario (`scenario=SPEC_OR_NAME`); the paper scenarios also
get ids of their own, MiniGrid-style.  `gym.make_vec` on any id gives the native vector env.
"""

from __future__ import annotations

import gymnasium as gym

ENTRY = "deint_env.envs.deinterleave:DeinterleaveEnv"
VECTOR_ENTRY = "deint_env.envs.vector:DeinterleaveVectorEnv"
# The token-feature env for learned agents (any number of sources; `deint_env.features`); not in
# `env_ids()`, which lists the raw envs.
TOKENS_ID = "deint_env/DeinterleaveTokens-v0"

# id suffix -> the paper scenario it plays
PAPER_IDS = {
    "MK94-SingleSource": "paper-v0/mk94-single-var9",
    "MK94-SingleSourceHighJitter": "paper-v0/mk94-single-var10000",
    "MK94-TwoSources": "paper-v0/mk94-two-var1",
    "MK94-TwoSourcesWide": "paper-v0/mk94-two-wide",
    "MK94-ThreeSources": "paper-v0/mk94-three",
    "MK94-EightSources": "paper-v0/mk94-eight",
    "MK94-PT-ThreeSources": "paper-v0/mk94-pt-three",
    "MK94-PT-FiveSources": "paper-v0/mk94-pt-five",
    "MK94-PT-Posterior": "paper-v0/mk94-pt-post",
    "MK94-Missing-TwoSources": "paper-v0/mk94-missing-two",
    "MK94-PT-Missing-ThreeSources": "paper-v0/mk94-pt-missing-three",
    "CM00-FiveTrains": "paper-v0/cm00-five-jitter0",
    "CM00-FiveTrainsJitter": "paper-v0/cm00-five-jitter23",
    "CM00-NearEqualPRF": "paper-v0/cm00-near-equal",
}


def env_ids() -> list[str]:
    return ["deint_env/Deinterleave-v0"] + [f"deint_env/{k}-v0" for k in PAPER_IDS]


def register_envs() -> None:
    def reg(env_id: str, **kwargs) -> None:
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY, vector_entry_point=VECTOR_ENTRY, kwargs=kwargs)

    reg("deint_env/Deinterleave-v0")
    if TOKENS_ID not in gym.registry:
        gym.register(id=TOKENS_ID, entry_point="deint_env.envs.tokens:make_tokens_env",
                     vector_entry_point="deint_env.envs.tokens:make_tokens_vector_env")
    for suffix, scenario in PAPER_IDS.items():
        reg(f"deint_env/{suffix}-v0", scenario=scenario)

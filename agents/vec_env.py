"""The batched token-feature env as a stable-baselines3 `VecEnv` (no per-env Python objects).

SB3 resets a finished sub-env within the same step, so the native env runs in Gymnasium's SAME_STEP
autoreset mode; the terminal observation SB3 asks for is the all-zero one (after the last label no
pulse is left to describe, exactly what the features say then).  `env_method("action_masks")` serves
sb3-contrib's MaskablePPO.

Making one also sets torch to one thread, once per process, unless the user chose a count: the
track network is small, and on a 2-core machine SB3 trains 5-6x slower with torch's default threads
(`deint train` sets one thread itself).
"""

from __future__ import annotations

from typing import Any, Sequence

import os
import sys

import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from deint_env.envs.tokens import make_tokens_vector_env
from deint_env.wrappers import TrackTokensVector


# Set by the user: torch (OpenMP, MKL) reads these for its thread count, and we leave it alone.
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
_threads_decided = False  # once per process: a later torch.set_num_threads(N) of the user's stands


def one_torch_thread() -> None:
    """Set torch to one thread (and say so on stderr) the first time an env is made in this process,
    unless a THREAD_VARS variable is set or torch already runs one thread."""
    global _threads_decided
    if _threads_decided:
        return
    _threads_decided = True
    if any(os.environ.get(v) for v in THREAD_VARS) or torch.get_num_threads() == 1:
        return
    torch.set_num_threads(1)
    print("deint: torch set to 1 thread (SB3 trains the small track network several times faster so on a few "
          "cores); to choose another count, set OMP_NUM_THREADS=N or call torch.set_num_threads(N) after "
          "TokenVecEnv.make", file=sys.stderr, flush=True)


class TokenVecEnv(VecEnv):
    """`TrackTokensVector` (SAME_STEP autoreset) behind SB3's VecEnv API."""

    def __init__(self, env: TrackTokensVector):
        if env.env.unwrapped.metadata["autoreset_mode"] is not AutoresetMode.SAME_STEP:
            raise ValueError("TokenVecEnv needs the native env in SAME_STEP autoreset mode")
        one_torch_thread()
        self.env = env
        self.render_mode = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self._actions: np.ndarray | None = None
        space = env.single_observation_space
        self._terminal = ({k: np.zeros(s.shape, s.dtype) for k, s in space.spaces.items()}
                          if hasattr(space, "spaces") else np.zeros(space.shape, space.dtype))

    @classmethod
    def make(cls, num_envs: int, **kwargs: Any) -> TokenVecEnv:
        """`make_tokens_vector_env(num_envs, **kwargs)` in SAME_STEP mode, as a VecEnv."""
        return cls(make_tokens_vector_env(num_envs, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs))

    def reset(self):
        seeds = None if all(s is None for s in self._seeds) else self._seeds
        obs, infos = self.env.reset(seed=seeds)
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs).astype(np.int64)

    def step_wait(self):
        obs, reward, terminated, truncated, infos = self.env.step(self._actions)
        dones = terminated | truncated
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(dones).tolist():
            out[i] = {"terminal_observation": self._terminal, "TimeLimit.truncated": bool(truncated[i]),
                      "episode_accuracy": float(infos["episode_accuracy"][i])}
        return obs, reward.astype(np.float32), dones, out

    def action_masks(self) -> np.ndarray:
        return self.env.action_masks()

    def close(self) -> None:
        self.env.close()

    def _indices(self, indices: None | int | Sequence[int]) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        if method_name != "action_masks":
            raise AttributeError(f"TokenVecEnv sub-envs have no method {method_name!r}")
        masks = self.env.action_masks()
        return [masks[i] for i in self._indices(indices)]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "render_mode":
            return [None] * len(self._indices(indices))
        if attr_name == "action_masks":  # how MaskablePPO asks whether masks are supported
            return [self.action_masks] * len(self._indices(indices))
        value = getattr(self.env.unwrapped, attr_name)
        return [value] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError("TokenVecEnv sub-envs share one batched env; their attributes cannot be set one by one")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

"""The optimal scheme of MK94 section II-G: the source sequence of least prediction-error cost (2.18)
over all N^kappa sequences (2.19), for short trains.

Costs are sums of non-negative squared errors, so a uniform-cost (best-first) search over the tree of
sequences returns the optimal full sequence as soon as it is popped, having expanded only sequences
cheaper than the optimum: the exact argmin of (2.19) without enumerating all N^kappa paths.  Each
search node holds its per-source KF blocks (`baselines.kalman`), so a node costs O(N) to copy and
O(1) to extend.  `max_nodes` bounds the work: exceeding it is an error, never a silent cut.
"""

from __future__ import annotations

import heapq
from typing import Any

import numpy as np

from baselines.kalman import Block, DLMModel, innovation, predict, prior_block, update
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.params import Param, declare

_MIN_JITTER_REL = 1e-6


def tree_search(ys: np.ndarray, priors: Priors, max_nodes: int = 2_000_000) -> tuple[np.ndarray, float]:
    """(sequence, cost): the exact minimiser of J = sum_k e_k^2 (2.18)-(2.19) over all sequences."""
    n = priors.n_labels
    model = DLMModel.from_priors(priors, min_jitter=_MIN_JITTER_REL * float(np.min(priors.period)))
    start = tuple(np.asarray(a, dtype=np.float64) for a in prior_block(priors))
    heap: list[tuple[float, int, tuple]] = [(0.0, 0, (start, ()))]
    pushed, kappa = 1, len(ys)
    while heap:
        cost, _, (blocks, seq) = heapq.heappop(heap)
        k = len(seq)
        if k == kappa:
            return np.array(seq, dtype=np.int64), cost
        # expand: every source fires pulse k
        pred = predict(Block(*blocks), model)
        e, s = innovation(pred, ys[k], model)
        upd = update(pred, e, s, model)
        for i in range(n):
            child = tuple(np.where(np.arange(n) == i, u, b) for u, b in zip(upd, blocks))
            heapq.heappush(heap, (cost + float(e[i] * e[i]), pushed, (child, seq + (i,))))
            pushed += 1
        if pushed > max_nodes:
            raise DeintError(f"tree search gave up after {max_nodes} nodes on {kappa} pulses; it is meant for "
                             "short trains (~20 pulses, <= 3 sources)")
    raise AssertionError("unreachable: the heap holds a path to every depth")


class TreeSearch:
    """Policy `tree`: waits for the whole (short) train, then labels it with the optimal sequence.
    Its lag is `max_pulses - 1`, so it refuses longer episodes."""

    PARAMS = declare(Param("max_pulses", int, 20, "the longest train it waits for (the lag is max_pulses - 1)", low=1,
                           high=200),
                     # a node holds its KF blocks and its sequence: 2e6 nodes of 200 pulses took 1.7 GB
                     Param("max_nodes", int, 2_000_000, "the most tree nodes the search expands", low=1,
                           high=2_000_000))

    def __init__(self, max_pulses: int = 20, max_nodes: int = 2_000_000):
        self.PARAMS.check(locals())
        self.max_pulses, self.max_nodes = max_pulses, max_nodes
        self.lag = max_pulses - 1

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if info.get("n_pulses", 0) > self.max_pulses:
            raise NotApplicable(f"tree labels trains of at most {self.max_pulses} pulses (max_pulses); this episode "
                             f"has {info['n_pulses']}")
        self.priors = priors
        self.ys: list[float] = []
        self.labels: list[int] | None = None
        self.steps = 0

    def act(self, obs: dict[str, Any]) -> int:
        if int(obs["valid"]):
            self.ys.append(float(obs["toa"][0]))
        pulse = self.steps - self.lag
        self.steps += 1
        if pulse < 0:
            return 0
        if self.labels is None:  # all pulses have arrived by the first labelling step
            self.labels = tree_search(np.array(self.ys), self.priors, self.max_nodes)[0].tolist()
        return self.labels[pulse]

"""Scenario spec fields: `Range` (a value drawn once per episode) and the checks every spec class
uses to read a number, a parameter (number or Range) or a tuple of numbers, each failure one
`DeintError` line naming the field (deint_env.scenario)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from deint_env.errors import DeintError, check


@dataclass(frozen=True)
class Range:
    """A value drawn once per episode: uniform on [low, high], or log-uniform when `log`."""

    low: float
    high: float
    log: bool = False

    def __post_init__(self) -> None:
        for name in ("low", "high"):
            v = getattr(self, name)
            check(_is_number(v) and math.isfinite(v), f"Range.{name}", v, "must be a finite number")
            object.__setattr__(self, name, float(v))  # Range(10, 20) and Range(10.0, 20.0) must hash alike
        check(isinstance(self.log, bool), "Range.log", self.log, "must be true or false")
        check(self.low <= self.high, "Range", (self.low, self.high), "need low <= high")
        check(not self.log or self.low > 0, "Range.low", self.low, "a log-uniform range needs low > 0")

    def draw(self, rng: np.random.Generator) -> float:
        u = rng.random()
        if self.log:
            return float(math.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low))))
        return float(self.low + u * (self.high - self.low))

    @property
    def mean(self) -> float:
        if self.log:
            return (self.high - self.low) / math.log(self.high / self.low) if self.high > self.low else self.low
        return 0.5 * (self.low + self.high)


Param = Union[float, Range]


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(v: Any, what: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """A finite number in [lo, hi] (JSON gives ints, floats, strings, null: only numbers pass)."""
    check(_is_number(v) and math.isfinite(v) and lo <= v <= hi, what, v, f"a number in [{lo:g}, {hi:g}]")
    return float(v)


def _param(value: Any, what: str, *, positive: bool = False, nonneg: bool = False) -> Param:
    """Coerce a JSON value (number or {"low","high","log"}) into a float or a `Range`, validated."""
    if isinstance(value, dict):
        unknown = set(value) - {"low", "high", "log"}
        check(not unknown and {"low", "high"} <= set(value), what, value,
              'a range is {"low": a, "high": b, "log": false}')
        try:
            value = Range(value["low"], value["high"], value.get("log", False))
        except DeintError as e:
            raise DeintError(f"{what}: {e}") from None
    if isinstance(value, Range):
        lo = value.low
        check(not positive or lo > 0, what, value, "must be > 0")
        check(not nonneg or lo >= 0, what, value, "must be >= 0")
        return value
    check(isinstance(value, (int, float)) and not isinstance(value, bool), what, value,
          "must be a number or a range")
    v = float(value)
    check(math.isfinite(v), what, value, "must be finite")
    check(not positive or v > 0, what, value, "must be > 0")
    check(not nonneg or v >= 0, what, value, "must be >= 0")
    return v


def _param_mean(p: Param) -> float:
    return p.mean if isinstance(p, Range) else p


def _param_low(p: Param) -> float:
    return p.low if isinstance(p, Range) else p


def _param_high(p: Param) -> float:
    return p.high if isinstance(p, Range) else p


def _floats(value: Any, what: str) -> tuple[float, ...]:
    check(isinstance(value, (list, tuple)), what, value, "must be a list of numbers")
    out = []
    for v in value:
        check(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v), what, value,
              "must be a list of finite numbers")
        out.append(float(v))
    return tuple(out)

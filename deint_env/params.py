"""Declared policy parameters: each policy states its keyword parameters once, as `Param`s (name,
type, default, range or choices, a one-line meaning), and one helper validates them.

A policy class (or factory function) carries its declaration as the attribute `PARAMS` (a
`ParamSet`, made by `declare`); its constructor calls `PARAMS.check(locals())`, and
`deint_env.policies.make_policy` validates a spec's parameters through it before building the policy
(unknown names, wrong types, values out of range: one `DeintError` line each).  `deint policies NAME`
prints `ParamSet.table()`.

Types are strict: a bool is not a number, an int parameter refuses 2.0, a float parameter takes an
int (2 means 2.0) but never NaN, nor an infinity unless its range is closed at inf; None is allowed
only where the parameter is declared `optional`.  Cross-parameter rules (mht's nscan <= lag) stay
in the constructor, stated with `deint_env.errors.check`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Mapping

from deint_env.errors import DeintError

TYPES = (int, float, bool, str)


class _Required:
    """The default of a parameter every spec must give (an agent's checkpoint)."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()


def spelled(value: Any) -> str:
    """A value as a spec writes it (true, none, inf, 1e-06)."""
    if value is REQUIRED:
        return "(required)"
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return str(value)


def _bound(x: float) -> str:
    """A range's bound: 2^63 for a large power of two (a seed's), else as %g writes it (1e+05 as 100000)."""
    if float(x).is_integer() and abs(x) < 2**64:
        k = int(x)
        return f"2^{k.bit_length() - 1}" if k >= 2**16 and k & (k - 1) == 0 else str(k)
    return f"{x:g}"


@dataclass(frozen=True)
class Param:
    """One keyword parameter.  Numbers: the range [low, high] (None: unbounded on that side; `low_open` /
    `high_open` exclude the bound).  Strings: `choices` (empty: any string).  `optional`: None is allowed
    too (the meaning says what None does)."""

    name: str
    type: type
    default: Any
    meaning: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    optional: bool = False

    def __post_init__(self) -> None:
        if not self.name.isidentifier() or self.type not in TYPES or not self.meaning or "\n" in self.meaning:
            raise ValueError(f"parameter {self.name!r}: a name, a type in {TYPES} and a one-line meaning")
        if self.choices and self.type is not str:
            raise ValueError(f"parameter {self.name!r}: choices are for str parameters")
        if (self.low is not None or self.high is not None) and self.type not in (int, float):
            raise ValueError(f"parameter {self.name!r}: a range is for int and float parameters")
        if self.default is not REQUIRED:
            self.validate(self.default)  # the default obeys its own declaration

    @property
    def type_name(self) -> str:
        return self.type.__name__ + (" | None" if self.optional else "")

    @property
    def range(self) -> str:
        """The allowed values, as a table or an error message shows them."""
        if self.type is bool:
            return "true, false"
        if self.type is str:
            return ", ".join(self.choices) if self.choices else "any string"
        if self.low is None and self.high is None:
            return "any finite number" if self.type is float else "any integer"
        low = "-inf" if self.low is None else _bound(self.low)
        high = "inf" if self.high is None else _bound(self.high)
        lo = "(" if self.low_open or self.low is None else "["
        hi = ")" if self.high_open or self.high is None else "]"
        return f"{lo}{low}, {high}{hi}"

    def allowed(self) -> str:
        what = {bool: "true or false", str: "one of " + self.range if self.choices else "a string",
                int: "an integer in " + self.range, float: "a number in " + self.range}[self.type]
        if self.type in (int, float) and self.low is None and self.high is None:
            what = "an integer" if self.type is int else "a finite number"
        return what + (" or none" if self.optional else "")

    def validate(self, value: Any) -> Any:
        """`value` if allowed (a float parameter's int as a float), else one `DeintError` line."""
        if value is None and self.optional:
            return None
        t = self.type
        if t is bool:
            ok = isinstance(value, bool)
        elif t is str:
            ok = isinstance(value, str) and (not self.choices or value in self.choices)
        else:
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and \
                (t is float or isinstance(value, numbers.Integral)) and value == value  # not NaN
            if ok:  # an integer compared exactly: float(2**63 - 1) rounds up to 2^63, past an open bound
                v = int(value) if isinstance(value, numbers.Integral) else float(value)
                closed_inf = self.high is not None and math.isinf(self.high) and not self.high_open
                ok = (isinstance(v, int) or math.isfinite(v) or (v == math.inf and closed_inf)) and \
                    (self.low is None or (v > self.low if self.low_open else v >= self.low)) and \
                    (self.high is None or (v < self.high if self.high_open else v <= self.high))
        if not ok:
            raise DeintError(f"{self.name}={value!r} is invalid: {self.allowed()}")
        return float(value) if t is float else value


@dataclass(frozen=True)
class ParamSet:
    """A policy's declared parameters, in signature order.  `internal`: keyword arguments for Python
    callers only (an object, e.g. mht's `scorer`), not settable from a spec."""

    params: tuple[Param, ...]
    internal: tuple[str, ...] = ()
    _by_name: dict[str, Param] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        by_name = {p.name: p for p in self.params}
        if len(by_name) != len(self.params) or set(by_name) & set(self.internal):
            raise ValueError(f"parameters declared twice: {[p.name for p in self.params]} {self.internal}")
        object.__setattr__(self, "_by_name", by_name)

    def __getitem__(self, name: str) -> Param:
        return self._by_name[name]

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __iter__(self):
        return iter(self.params)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._by_name)

    def defaults(self) -> dict[str, Any]:
        return {p.name: p.default for p in self.params}

    def validate(self, kwargs: Mapping[str, Any]) -> dict[str, Any]:
        """Every given parameter checked (a float parameter's int as a float); an unknown name or a bad
        value is one `DeintError` line."""
        out = {}
        for key, value in kwargs.items():
            if key not in self._by_name:
                raise DeintError(f"there is no parameter {key!r}; the parameters: {', '.join(self.names) or 'none'}")
            out[key] = self._by_name[key].validate(value)
        return out

    def check(self, arguments: Mapping[str, Any]) -> None:
        """A constructor's check of its arguments (`PARAMS.check(locals())`): every declared name found in
        `arguments` is validated; other names (self, internal ones, **kw) are left alone."""
        for p in self.params:
            if p.name in arguments:
                p.validate(arguments[p.name])

    def plus(self, *params: Param, internal: Iterable[str] = ()) -> ParamSet:
        """These parameters followed by `params` (a subclass's own)."""
        return ParamSet(self.params + params, self.internal + tuple(internal))

    def only(self, *names: str) -> ParamSet:
        """The declared parameters `names`, in that order (a subclass exposing a subset)."""
        return ParamSet(tuple(self._by_name[n] for n in names))

    def changed(self, **defaults: Any) -> ParamSet:
        """The same parameters with other defaults (a subclass or factory whose signature differs; a default
        of None makes the parameter optional)."""
        unknown = set(defaults) - set(self._by_name)
        if unknown:
            raise ValueError(f"no parameters {sorted(unknown)}")
        return ParamSet(tuple(replace(p, default=defaults[p.name], optional=p.optional or defaults[p.name] is None)
                              if p.name in defaults else p for p in self.params), self.internal)

    def table(self) -> list[tuple[str, str, str, str, str]]:
        """(parameter, type, default, range or choices, meaning) rows."""
        return [(p.name, p.type_name, spelled(p.default), p.range, p.meaning) for p in self.params]


# a stochastic policy's own seed (deint_env.policies.policy_rng)
SEED = Param("seed", int, None, "the policy's own seed (none: the runner's policy seed)", low=0, high=2**63,
             high_open=True, optional=True)


def declare(*params: Param, internal: Iterable[str] = ()) -> ParamSet:
    """A policy's parameters: `PARAMS = declare(Param("gate", float, 4.0, "...", low=0, low_open=True), ...)`."""
    return ParamSet(tuple(params), tuple(internal))

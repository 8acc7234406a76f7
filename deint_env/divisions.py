"""Latency divisions: leaderboards rank policies only against others that decide as early.

A policy declares its `lag`: how many later pulses it sees before it must label a pulse (design.md
section 5).  A decision delay is a real cost for a receiver, so, as MLPerf separates its Server and
Offline scenarios, every board ranks within three divisions by declared lag:

- `online`: lag <= 3, the look-ahead Delta of Mardia & Kumar's forward dynamic programme (MK94);
- `low-latency`: lag <= 64;
- `offline`: any lag, whole-episode batch methods included.

A row belongs to the tightest division its lag fits; the same policy with other parameters (e.g.
`mht:lag=3,nscan=3`) plays the other divisions as rows of its own.
"""

from __future__ import annotations

from deint_env.errors import DeintError

# name -> the largest lag it admits (None: any), tightest first
DIVISIONS: dict[str, int | None] = {"online": 3, "low-latency": 64, "offline": None}


def division_of(lag: int | None) -> str:
    """The tightest division whose bound admits `lag` (an unknown lag is offline: nothing is promised)."""
    if lag is None:
        return "offline"
    if isinstance(lag, bool) or not isinstance(lag, int) or lag < 0:
        raise DeintError(f"lag={lag!r} is invalid: an integer >= 0")
    return next(name for name, bound in DIVISIONS.items() if bound is None or lag <= bound)


def check_division(name: str) -> str:
    if name not in DIVISIONS:
        raise DeintError(f"division {name!r} is unknown; one of {', '.join(DIVISIONS)}")
    return name


def admits(division: str, lag: int | None) -> bool:
    """Whether a policy of `lag` may play in `division` (its bound, or any lag offline)."""
    bound = DIVISIONS[check_division(division)]
    return bound is None or (lag is not None and lag <= bound)

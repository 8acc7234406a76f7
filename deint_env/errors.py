"""The one exception type users see: every bad input becomes a one-line `DeintError`."""

from __future__ import annotations

import re


class DeintError(ValueError):
    """Bad user input (a field, a file, a name): the message says what is wrong and what is allowed."""


class NotApplicable(DeintError):
    """A policy cannot play this scenario (e.g. a prior-based policy on a blind scenario, an agent
    trained for another number of sources).  The runner records such episodes as not applicable and
    leaderboards report the policy's coverage instead of a score for them."""


MAX_SHOWN = 200  # characters of a bad value an error line repeats (a 10^4-entry list is not a message)


def shown(value: object) -> str:
    """`repr(value)` on one line (a numpy array's repr breaks lines), cut to MAX_SHOWN characters."""
    text = re.sub(r"\n\s*", " ", repr(value))  # a str's repr escapes its newlines: only containers' are joined
    return text if len(text) <= MAX_SHOWN else text[:MAX_SHOWN] + "..."


def check(ok: bool, what: str, value: object, allowed: str) -> None:
    """Raise `DeintError("<what>=<value> is invalid: <allowed>")` unless `ok`."""
    if not ok:
        raise DeintError(f"{what}={shown(value)} is invalid: {allowed}")

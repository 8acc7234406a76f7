"""The one exception type users see: every bad input becomes a one-line `DeintError`."""

from __future__ import annotations


class DeintError(ValueError):
    """Bad user input (a field, a file, a name): the message says what is wrong and what is allowed."""


def check(ok: bool, what: str, value: object, allowed: str) -> None:
    """Raise `DeintError("<what>=<value> is invalid: <allowed>")` unless `ok`."""
    if not ok:
        raise DeintError(f"{what}={value!r} is invalid: {allowed}")

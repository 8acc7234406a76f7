"""JSON files: priors files and scenario files, and the limits every JSON input is parsed within.

Priors file: JSON, `{"period": [...], "phase": [...], "jitter_std": s, ...}` (see
`Priors.from_json_dict`); an emitter library adds per-track `frequency`, `pulse_width`, `aoa` (MHz, us,
degrees) with their `frequency_std`, `pulse_width_std`, `aoa_std`.  NaN and Infinity are refused (they are not JSON).

Limits, checked before Python builds anything from the text: nesting at most `MAX_DEPTH` deep
(Python's parser recurses, so a deeper document would raise RecursionError), integers of at most
`MAX_INT_DIGITS` digits, and floats that are finite in float64 (1e400 is refused, not read as inf).
A key repeated in one object is refused (json would keep its last value).
"""

from __future__ import annotations

import json
import re
from typing import Any

from deint_env.episode import SCALARS, Episode, Priors
from deint_env.errors import DeintError
from deint_env.formats.files import PathLike, read_text, write_text

MAX_DEPTH = 64  # our files nest 4 deep (a scenario's sources' modulation)
MAX_INT_DIGITS = 19  # 2^63 has 19 digits: seeds and counts fit
_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_OPEN = re.compile(r"[\[{]")


def check_depth(text: str, where: str) -> None:
    """Refuse JSON text nested deeper than MAX_DEPTH, before parsing it (strings skipped)."""
    bare = _STRING.sub("", text)
    if len(_OPEN.findall(bare)) <= MAX_DEPTH:
        return
    depth = 0
    for m in re.finditer(r"[\[{\]}]", bare):
        depth += 1 if m.group() in "[{" else -1
        if depth > MAX_DEPTH:
            raise DeintError(f"{where}: JSON nested more than {MAX_DEPTH} deep; the limit is {MAX_DEPTH} levels")


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number JSON allows")


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"the integer {text[:12]}... has {len(text.lstrip('-'))} digits; the limit is "
                         f"{MAX_INT_DIGITS} digits")
    return int(text)


def _parse_float(text: str) -> float:
    value = float(text)
    if value in (float("inf"), float("-inf")):
        raise ValueError(f"the number {text[:24]} is out of range; numbers must be finite float64 values "
                         f"(|x| < 1.8e308)")
    return value


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    # json keeps the last of a repeated key: a file saying two things would be read as one silently
    out = dict(pairs)
    if len(out) < len(pairs):
        seen: set[str] = set()
        key = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise ValueError(f"key {key!r} appears twice in an object; give each key once")
    return out


def loads(text: str, where: str, parse_constant=_reject_constant) -> Any:
    """Parse JSON text within the module's limits; every problem is one `DeintError` line naming `where`."""
    check_depth(text, where)
    try:
        return json.loads(text, parse_constant=parse_constant, parse_int=_parse_int, parse_float=_parse_float,
                          object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as e:
        raise DeintError(f"{where}: line {e.lineno} column {e.colno}: not valid JSON ({e.msg})") from None
    except (ValueError, RecursionError) as e:
        raise DeintError(f"{where}: {e}") from None


def read_json(path: PathLike) -> Any:
    """A JSON file, within the module's limits; NaN and Infinity are rejected (they are not JSON)."""
    return loads(read_text(path, "JSON"), str(path))


def format_json(obj: Any) -> str:
    try:
        return json.dumps(obj, indent=1, allow_nan=False) + "\n"
    except ValueError:
        raise DeintError("cannot write NaN or infinite numbers to a JSON file") from None


def read_priors(path: PathLike) -> Priors:
    return Priors.from_json_dict(read_json(path), where=str(path))


def format_priors(priors: Priors | dict[str, Any], where: str = "priors") -> str:
    """A priors file's text; it is checked to read back before anything is written."""
    d = priors.to_json_dict() if isinstance(priors, Priors) else priors
    Priors.from_json_dict(d, where=where)
    return format_json(d)


def write_priors(path: PathLike, priors: Priors | dict[str, Any]) -> None:
    write_text(path, format_priors(priors, where=str(path)))


def true_priors(episode: Episode) -> dict[str, Any]:
    """A priors dict holding a simulated episode's true periods and phases and its channel statistics:
    what `genie` needs to label a pulse file (exact for constant-PRI, always-on sources)."""
    if episode.truth is None:
        raise DeintError("true priors need a simulated episode (its truth)")
    return {"period": episode.truth.period.tolist(), "phase": episode.truth.phase.tolist(),
            **{k: float(getattr(episode.priors, k)) for k in SCALARS}}

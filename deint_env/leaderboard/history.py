"""Test looks: every policy version a board has scored on its test seeds, in the order it was scored.

Each look at the test seeds is a chance to choose on them; a reader should know how many versions of a
policy were tried before the one shown.  `history.json` beside a board lists (family, version) pairs
in first-scored order: the family is the registry name (`mht`, `mht-tuned`, `lmht`; parameters do not
make a new family), the version what its results are keyed on (the registry version; a learned agent's
checkpoint hash; a tuned entry's preset hash).  Every board write appends the versions it has not seen
(`update`), and never removes one; a row's `test_looks` is the number of its family's versions scored
before its own.  `python -m deint_env.leaderboard.history FOLDER...` rebuilds the file from the
git history of the folder's results.jsonl (the looks taken before this file existed).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any, NamedTuple

from deint_env.errors import DeintError, shown
from deint_env.formats.files import write_all

HISTORY = "history.json"


class Look(NamedTuple):
    family: str
    version: str


def family(spec: str) -> str:
    return spec.split(":", 1)[0]


def read(folder: Path) -> list[Look]:
    path = folder / HISTORY
    if not path.exists():
        return []
    rebuild = f"rebuild it with python -m deint_env.leaderboard.history {folder}"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        looks = [Look(d["family"], d["version"]) for d in data["looks"]]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError):
        raise DeintError(f"{path}: is not a test-look history (JSON with a list 'looks' of family and version); "
                         f"{rebuild}") from None
    if data.get("format") != "deint-test-looks":
        raise DeintError(f"{path}: field format is {shown(data.get('format'))}, not 'deint-test-looks'; {rebuild}")
    # `text` writes strings only: a number or object here (once read as its str) is a tampered file
    for i, look in enumerate(looks):
        for key, value in look._asdict().items():
            if not isinstance(value, str) or not value:
                raise DeintError(f"{path}: field looks[{i}].{key} is {shown(value)}, not a non-empty string; "
                                 f"{rebuild}")
    return list(dict.fromkeys(looks))


def text(looks: list[Look]) -> str:
    return json.dumps({"format": "deint-test-looks", "looks": [l._asdict() for l in looks]}, indent=1) + "\n"


def update(looks: list[Look], rows: list[dict[str, Any]]) -> list[Look]:
    """`looks` with the versions of `rows` not yet in it appended (submissions are not looks: they are
    scored once, as sent), in row order."""
    seen = set(looks)
    out = list(looks)
    for r in rows:
        if r["submitted"] or r["oracle"] or r.get("policy_version") is None:
            continue
        look = Look(family(r["policy"]), str(r["policy_version"]))
        if look not in seen:
            seen.add(look)
            out.append(look)
    return out


def test_looks(looks: list[Look], row: dict[str, Any]) -> int | None:
    """How many versions of the row's family were scored on test before its own."""
    if row["submitted"] or row["oracle"] or row.get("policy_version") is None:
        return None
    mine = Look(family(row["policy"]), str(row["policy_version"]))
    earlier = [l for l in looks if l.family == mine.family]
    return earlier.index(mine) if mine in earlier else len(earlier)


def from_git(folder: Path) -> list[Look]:
    """The looks recorded in every committed version of `folder`/results.jsonl, oldest first."""
    path = folder / "results.jsonl"
    git = ["git", "-C", str(folder)]
    commits = subprocess.run(git + ["log", "--reverse", "--format=%H", "--", "results.jsonl"], check=True,
                             capture_output=True, text=True).stdout.split()
    looks: list[Look] = []
    for commit in commits:
        blob = subprocess.run(git + ["show", f"{commit}:./results.jsonl"], capture_output=True, text=True)
        if blob.returncode:
            continue  # removed in that commit
        for line in blob.stdout.splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if rec.get("split", "test") != "test" or rec.get("submitted") or rec.get("oracle"):
                continue
            look = Look(family(rec["policy"]), str(rec.get("policy_version", 1)))
            if look not in looks:
                looks.append(look)
    if not commits and path.exists():
        raise DeintError(f"{path}: has no git history")
    return looks


def main(argv: list[str] | None = None) -> int:
    folders = [Path(a) for a in (sys.argv[1:] if argv is None else argv)]
    for folder in folders:
        looks = list(dict.fromkeys(from_git(folder) + read(folder)))
        write_all([(folder / HISTORY, text(looks))])
        print(f"{folder / HISTORY}: {len(looks)} versions of {len({l.family for l in looks})} families")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

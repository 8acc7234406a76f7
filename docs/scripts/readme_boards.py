"""The README's leaderboard leaders, generated from the published boards (never typed by hand).

Reads every `leaderboards/<suite>/leaderboard.json` and writes, between the README's markers
`<!-- boards:start -->` and `<!-- boards:end -->`, one table row per board and latency division: the
entry ranked first (every entry ranked "1=" when tied) with its mean normalised score and lag, and beside
it the best entry left unranked for playing only part of the board (coverage below 100 %), if it scores more.

    python docs/scripts/readme_boards.py            # rewrite README.md's block
    python docs/scripts/readme_boards.py --check    # exit 1 if README.md's block is not up to date
    python docs/scripts/readme_boards.py --print    # print the block

Boards written before latency divisions existed have no `division` per row: a row's division is then
the tightest that admits its lag (online: lag <= 3; low-latency: <= 64; offline: any) and rows are
ranked within it by score mean, among those the board ranked at all (`rank` not None).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
START, END = "<!-- boards:start -->", "<!-- boards:end -->"
DIVISIONS = ("online", "low-latency", "offline")
BOUNDS = {"online": 3, "low-latency": 64}


def division_of(lag: float | None) -> str:
    if lag is None:
        return "offline"
    return next((d for d, bound in BOUNDS.items() if lag <= bound), "offline")


def leaders(board: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """division -> its first-ranked rows (several when tied), in the board's order."""
    rows = [r for r in board.get("rows", []) if r.get("rank") is not None and r.get("score_mean") is not None]
    out: dict[str, list[dict[str, Any]]] = {}
    for division in DIVISIONS:
        if any("division" in r for r in rows):  # the divisions format: the board's own ranks
            mine = [r for r in rows if r.get("division") == division]
            top = [r for r in mine if r["rank"] == 1 or str(r.get("rank_label") or "").startswith("1=")]
        else:  # an older board: divisions derived from lag, ranked by score mean
            mine = sorted((r for r in rows if division_of(r.get("lag")) == division),
                          key=lambda r: -r["score_mean"])
            top = mine[:1]
        if top:
            out[division] = top
    return out


def partial_leader(board: dict[str, Any], division: str, above: float) -> dict[str, Any] | None:
    """The best-scoring entry of `division` the board leaves unranked because it cannot play every episode
    (coverage below 1: an anchored-only or blind-only policy), when it outscores `above` (the ranked
    leader's mean): shown beside the leader, with its coverage, so that a board whose methods each play
    part of it does not read as led by `random`."""
    rows = [r for r in board.get("rows", []) if r.get("rank") is None and not r.get("oracle")
            and r.get("division") == division and r.get("score_mean") is not None
            and (r.get("coverage") or 0) < 1 and r["score_mean"] > above]
    return max(rows, key=lambda r: r["score_mean"], default=None)


def _lag(value: float | None) -> str:
    if value is None:
        return "-"
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def _entry(row: dict[str, Any], tied: bool) -> str:
    label = " (1=)" if tied else ""
    marker = f" {row['marker']}" if row.get("marker") else ""
    return f"`{row['policy']}`{marker}{label}: {row['score_mean']:.3f}, lag {_lag(row.get('lag'))}"


def block(root: Path = ROOT) -> str:
    """The markdown between the README's markers (without them)."""
    lines = ["| board | division | leader: score mean, lag |", "|---|---|---|"]
    derived = []
    for path in sorted((root / "leaderboards").glob("*/leaderboard.json")):
        board = json.loads(path.read_text())
        suite = board.get("suite", path.parent.name)
        if not any("division" in r for r in board.get("rows", [])):
            derived.append(suite)
        ranked = leaders(board)
        for division in DIVISIONS:
            top = ranked.get(division, [])
            partial = partial_leader(board, division, max((r["score_mean"] for r in top), default=-float("inf")))
            if not top and partial is None:
                continue
            entries = "; ".join([_entry(r, len(top) > 1) for r in top] + (
                [f"unranked, over {partial['coverage']:.0%} of the episodes: {_entry(partial, False)}"]
                if partial is not None else []))
            lines.append(f"| [{suite}](leaderboards/{path.parent.name}/README.md) | {division} | {entries} |")
    if derived:
        lines += ["", f"Built before latency divisions (each entry's division derived from its lag, ranked by score "
                      f"mean): {', '.join(derived)}."]
    return "\n".join(lines) + "\n"


def render(readme: str, content: str) -> str:
    """`readme` with the text between the markers replaced by `content`."""
    try:
        head, rest = readme.split(START, 1)
        _, tail = rest.split(END, 1)
    except ValueError:
        raise SystemExit(f"README.md lacks the markers {START} ... {END}") from None
    return f"{head}{START}\n{content}{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="exit 1 if README.md's block is not up to date")
    p.add_argument("--print", action="store_true", help="print the block instead of writing README.md")
    p.add_argument("--readme", type=Path, default=ROOT / "README.md")
    args = p.parse_args(argv)
    content = block()
    if args.print:
        print(content, end="")
        return 0
    old = args.readme.read_text()
    new = render(old, content)
    if args.check:
        if new != old:
            print(f"{args.readme}: the leaderboard block is out of date; run python docs/scripts/readme_boards.py",
                  file=sys.stderr)
            return 1
        return 0
    if new != old:
        args.readme.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())

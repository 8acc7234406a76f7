"""The one table formatter: aligned text (the terminal) and Markdown (READMEs), and the columns of an
entry table (`deint run`'s summary, the leaderboard) built from the metric table `metrics.METRICS`
(read when a table is made, so an entry added there shows everywhere)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

from deint_env import metrics
from deint_env.metrics import SCORE, Metric


def text_table(head: Sequence[str], body: Sequence[Sequence[str]]) -> str:
    """Columns left-aligned, two spaces apart, a dashed rule under the header."""
    widths = [max([len(h)] + [len(r[i]) for r in body]) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)).rstrip(), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in body]
    return "\n".join(lines)


def markdown_table(head: Sequence[str], body: Sequence[Sequence[str]]) -> list[str]:
    esc = lambda s: s.replace("|", "\\|")  # noqa: E731
    return ["| " + " | ".join(map(esc, head)) + " |", "|" + "---|" * len(head)] + [
        "| " + " | ".join(map(esc, row)) + " |" for row in body]


# ---------------------------------------------------------------------------------------------------
# entry tables
# ---------------------------------------------------------------------------------------------------
def num(v: Any, spec: str = ".3f") -> str:
    return "-" if v is None or v != v else format(v, spec)


def interval(d: dict[str, Any], name: str) -> str:
    if d.get(name) is None or d[name] != d[name]:
        return "-"
    return f"{num(d[name])} [{num(d[name + '_low'])}, {num(d[name + '_high'])}]"


def display_name(row: dict[str, Any]) -> str:
    """The entry's name with what it is when that matters for reading its score."""
    tag = " (oracle)" if row["oracle"] else " (learned)" if row.get("kind") == "learned" else ""
    return row["policy"] + tag


@dataclass(frozen=True)
class Column:
    head: str
    cell: Callable[[dict[str, Any]], str]
    value: Callable[[dict[str, Any]], Any]  # the sort value (None = missing)


def _metric_column(m: Metric) -> Column:
    return Column(m.label, lambda r: m.cell(r[m.key]), lambda r: r[m.key])


def entry_columns(summary: bool = False) -> list[Column]:
    """The leaderboard's columns, or with `summary` those of `deint run` (no rank; the metrics marked
    `summary`; the score intervals, which may be missing, and the episode count)."""
    cols = [] if summary else [Column("rank", lambda r: num(r["rank"], "d"), lambda r: r["rank"])]
    cols += [Column("policy", display_name, lambda r: r["policy"])]
    if summary:
        cols += [Column("episodes", lambda r: str(r["episodes"]), lambda r: r["episodes"])]
    cols += [Column(f"{SCORE} {label} [95% CI]", lambda r, k=f"{SCORE}_{name}": interval(r, k),
                    lambda r, k=f"{SCORE}_{name}": r[k]) for label, name in (("IQM", "iqm"), ("mean", "mean"))]
    cols += [_metric_column(m) for m in metrics.METRICS if m.summary or not summary]
    cols += [Column("coverage", lambda r: f"{r['coverage']:.0%}", lambda r: r["coverage"]),
             Column("faults", lambda r: str(len(r["faults"])), lambda r: len(r["faults"]))]
    return cols


def entry_body(rows: Sequence[dict[str, Any]], summary: bool = False) -> tuple[list[str], list[list[str]]]:
    cols = entry_columns(summary)
    return [c.head for c in cols], [[c.cell(r) for c in cols] for r in rows]


def fault_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """One line per faulted episode: the entry is incomplete until a rerun plays it."""
    return [f"{r['policy']}, scenario {f['scenario']}, seed {f['seed']}: {f['error']}"
            for r in rows for f in r["faults"]]


def entry_table(rows: Sequence[dict[str, Any]], summary: bool = False) -> str:
    """The entry table as text, then the faulted episodes, if any."""
    out = text_table(*entry_body(rows, summary))
    faults = fault_lines(rows)
    if faults:
        out += (f"\nincomplete: {len(faults)} faulted episode(s), not scored (rerun to retry):\n  "
                + "\n  ".join(faults))
    return out

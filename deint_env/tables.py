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


# parameters naming a file: an entry is shown by its registry name and version, never by a path
_PATH_PARAMS = ("checkpoint=", "model=")


def display_name(row: dict[str, Any]) -> str:
    """The entry's name with what it is when that matters for reading its score: oracle, ablation, and
    for a learned entry its marker ("learned" only when its learned share is shown to be above 0)."""
    name, _, params = row["policy"].partition(":")
    items = [p for p in params.split(",") if p]
    kept = [p for p in items if not p.startswith(_PATH_PARAMS)]
    text = name + (":" + ",".join(kept) if kept else "")
    if len(kept) < len(items):
        text += f" @{str(row.get('policy_version'))[:12]}"
    if row["oracle"]:
        return text + " (oracle)"
    if row.get("ablation_of"):
        return text + " (ablation)"
    if row.get("kind") == "learned":
        return text + f" ({row.get('marker') or 'learned'})"
    return text


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
    cols = [] if summary else [Column("rank", lambda r: r.get("rank_label") or "-", lambda r: r["rank"])]
    cols += [Column("policy", display_name, lambda r: r["policy"])]
    if not summary:  # what its results are keyed on: the registry version, a checkpoint's or a preset's hash
        cols += [Column("version", lambda r: _short(r.get("policy_version")), lambda r: str(r.get("policy_version")))]
    if summary:
        cols += [Column("episodes", lambda r: str(r["episodes"]), lambda r: r["episodes"])]
    cols += [Column(f"{SCORE} {label} [95% CI]", lambda r, k=f"{SCORE}_{name}": interval(r, k),
                    lambda r, k=f"{SCORE}_{name}": r[k]) for label, name in (("mean", "mean"), ("IQM", "iqm"))]
    cols += [_metric_column(m) for m in metrics.METRICS if m.summary or not summary]
    cols += [Column("coverage", lambda r: f"{r['coverage']:.0%}", lambda r: r["coverage"]),
             Column("faults", lambda r: str(len(r["faults"])), lambda r: len(r["faults"]))]
    if not summary:
        cols += [Column("x fdp", lambda r: num(r.get("vs_fdp"), ".2f"), lambda r: r.get("vs_fdp")),
                 Column("learned share [95% CI]", _share, lambda r: r.get("learned_share")),
                 Column("test looks", lambda r: num(r.get("test_looks"), "d"), lambda r: r.get("test_looks"))]
    return cols


def _short(version: Any) -> str:
    if version is None:
        return "-"
    text = str(version)
    return text if len(text) <= 14 else text.replace("sha256:", "")[:12] + "..."


def _share(row: dict[str, Any]) -> str:
    if row.get("learned_share") is None:
        return "-"
    if row.get("learned_share_low") is None or row["learned_share_low"] != row["learned_share_low"]:
        return f"{row['learned_share']:+.4f}"
    return f"{row['learned_share']:+.4f} [{row['learned_share_low']:+.4f}, {row['learned_share_high']:+.4f}]"


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

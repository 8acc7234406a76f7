"""Paper experiments for `deint reproduce NAME`: each runs one published experiment, writes its figure
(PNG) and a table of our numbers beside the paper's, and returns that table.

An experiment is a function `run(out_dir: Path, quick: bool) -> Report`, registered with
`@experiment("name", "what it reproduces")` in a module listed in `MODULES`; `quick` shrinks seeds and
pulse counts for tests.  Figures need matplotlib (the `[plot]` or `[dev]` extra).
"""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from deint_env.errors import DeintError

MODULES = ("baselines.reproduce.mk94", "baselines.reproduce.mk94_pt", "baselines.reproduce.cm00",
           "baselines.reproduce.dm89", "baselines.reproduce.nk00")


@dataclass
class Report:
    """One experiment's outcome: rows of (quantity, ours, paper, note) and the files written."""

    name: str
    title: str
    rows: list[dict[str, Any]] = field(default_factory=list)
    files: list[str] = field(default_factory=list)

    def add(self, quantity: str, ours: Any, paper: Any = "", note: str = "") -> None:
        self.rows.append({"quantity": quantity, "ours": ours, "paper": paper, "note": note})

    def table(self) -> str:
        head = ["quantity", "ours", "paper", "note"]
        cells = [[str(r[h]) for h in head] for r in self.rows]
        widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, h in enumerate(head)]
        lines = [f"{self.name}: {self.title}", "  ".join(h.ljust(w) for h, w in zip(head, widths)),
                 "  ".join("-" * w for w in widths)]
        lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in cells]
        return "\n".join(lines)

    def write(self, out_dir: Path) -> None:
        """The table as text and JSON beside the figures."""
        (out_dir / f"{self.name}.txt").write_text(self.table() + "\n")
        (out_dir / f"{self.name}.json").write_text(json.dumps(
            {"name": self.name, "title": self.title, "rows": self.rows, "files": self.files}, indent=1) + "\n")


_EXPERIMENTS: dict[str, tuple[str, Callable[[Path, bool], Report]]] = {}


def experiment(name: str, title: str):
    def register(fn: Callable[[Path, bool], Report]):
        _EXPERIMENTS[name] = (title, fn)
        return fn

    return register


def _load() -> None:
    for module in MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name != module:  # a missing dependency, not a missing module
                raise


def list_experiments() -> dict[str, str]:
    _load()
    return {name: title for name, (title, _) in sorted(_EXPERIMENTS.items())}


def run_experiment(name: str, out_dir: str | Path, quick: bool = False) -> Report:
    _load()
    if name not in _EXPERIMENTS:
        raise DeintError(f"experiment {name!r} is unknown; known: {', '.join(sorted(_EXPERIMENTS))}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report = _EXPERIMENTS[name][1](out, quick)
    report.write(out)
    return report


def figure():
    """A fresh matplotlib figure on the Agg backend (no display needed)."""
    try:
        import matplotlib
    except ImportError:
        raise DeintError("figures need matplotlib: pip install 'deint-bench[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt

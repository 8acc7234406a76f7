"""Progress bars: tqdm on stderr, redrawn in place on a terminal and at most every 10 s in logs."""

from __future__ import annotations

import sys

from tqdm import tqdm


def progress_bar(total: int, desc: str = "", enabled: bool = True) -> tqdm:
    """A tqdm bar of `total` steps (`update(n)`, `close()`); disabled with `enabled=False` or nothing to do."""
    tty = sys.stderr.isatty()
    return tqdm(total=total, desc=desc, disable=not enabled or total <= 0, file=sys.stderr,
                mininterval=0.1 if tty else 10.0, dynamic_ncols=tty, leave=True)

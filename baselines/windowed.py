"""Windowed batch decisions behind the per-pulse policy protocol (the blind deinterleavers, the TDC
model adapter): a policy buffers one row per received pulse, labels a whole window of `window` pulses
when its last pulse arrives (the last, shorter window at the first padding step), and emits those
labels one per step, at lag window - 1."""

from __future__ import annotations

from collections import deque
from typing import Any

MAX_WINDOW = 10_001  # the env's largest lag is 10000


class WindowedPolicy:
    """Subclasses give `_row(obs)` (what to keep of a received pulse; `self._seen` is its index) and
    `_label_rows(rows)` (one label per row of a full window), and call `_start()` in `reset`."""

    def __init__(self, window: int):
        self.window = window
        self.lag = window - 1

    def _row(self, obs: dict[str, Any]) -> Any:
        raise NotImplementedError

    def _label_rows(self, rows: list[Any]) -> list[int]:
        raise NotImplementedError

    def _start(self) -> None:
        self._rows: list[Any] = []
        self._ready: deque[int] = deque()
        self._seen = 0  # pulses received so far
        self._step = 0

    def act(self, obs: dict[str, Any]) -> int:
        if int(obs["valid"]):
            self._rows.append(self._row(obs))
            self._seen += 1
            if len(self._rows) == self.window:
                self._flush()
        else:
            self._flush()
        due = self._step - self.lag
        self._step += 1
        if due < 0:
            return 0  # before the first decision: the env ignores it
        return self._ready.popleft()

    def _flush(self) -> None:
        if self._rows:
            rows, self._rows = self._rows, []
            self._ready.extend(self._label_rows(rows))

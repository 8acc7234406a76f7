"""The viewer, kept apart from the env's step logic: the analyst's pulse picture as an RGB array (and as
PNG bytes), a window that shows it (render_mode="human"), or a text table.

The picture draws each pulse at its TOA (x, linear) against its ΔTOA, the time since the previous
received pulse (y, log scale: sources' PRIs a decade apart stay visible together), in one panel per
colouring (the agent's labels, the true sources), beside a PRI histogram on the same ΔTOA axis: grey
bars count the ΔTOAs, coloured bars stacked on them the intervals between consecutive pulses given
the same label, which a right deinterleaving turns into one spike per source at its PRI.

Pure numpy (the core needs no plotting library); only the window imports matplotlib.  The env passes
only pulses already labelled, so rendering never shows the truth of a pending pulse.
"""

from __future__ import annotations

import struct
import time
import zlib
from typing import Sequence

import numpy as np

from deint_env.errors import DeintError

# Ten distinguishable colours (Tableau 10); label/source i takes colour i mod 9, "spurious" grey.
PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                    [140, 86, 75], [227, 119, 194], [188, 189, 34], [23, 190, 207], [127, 127, 127]], np.uint8)
SPURIOUS = np.array([170, 170, 170], np.uint8)
FRAME, GRID, MINOR, HIST = 60, 225, 242, 205  # grey levels: panel frames, decade and 2-5 lines, ΔTOA bars
PAD, GAP, DOT = 14, 14, 1  # margins, space between panels, dot half-width (3x3 px dots)

Colouring = tuple[np.ndarray, np.ndarray]  # (ids >= 0 per pulse, spurious mask)


def _colours(ids: np.ndarray, spurious: np.ndarray) -> np.ndarray:
    out = PALETTE[np.asarray(ids) % (len(PALETTE) - 1)]  # grey (the last) is kept for "spurious"
    out[spurious] = SPURIOUS
    return out


def label_intervals(toa: np.ndarray, ids: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The intervals between consecutive kept pulses of the same id, and that id (time order kept by a
    stable sort on the id)."""
    idx = np.flatnonzero(keep)
    order = idx[np.argsort(ids[idx], kind="stable")]
    same = ids[order][1:] == ids[order][:-1]
    return np.diff(toa[order])[same], ids[order][1:][same]


class LogAxis:
    """ΔTOA -> pixel row of a panel spanning rows [top, bottom], on a log scale over the positive values
    given (widened to at least a factor 4, so one tight band does not fill the panel)."""

    def __init__(self, values: np.ndarray, top: int, bottom: int):
        pos = values[values > 0]
        lo, hi = (float(pos.min()), float(pos.max())) if pos.size else (1.0, 10.0)
        mid, half = np.log10(lo * hi) / 2, max(np.log10(hi / lo) / 2, np.log10(4) / 2) * 1.1
        self.lo, self.hi, self.top, self.bottom = mid - half, mid + half, top, bottom

    def row(self, v: np.ndarray) -> np.ndarray:
        # a zero ΔTOA (coincident pulses) sits on the bottom edge rather than at log(0)
        frac = (np.log10(np.maximum(v, 10.0 ** self.lo)) - self.lo) / (self.hi - self.lo)
        return np.clip(np.round(self.bottom - frac * (self.bottom - self.top)), self.top, self.bottom).astype(int)

    def grid(self) -> list[tuple[int, bool]]:
        """(row, is a decade) of the 1-2-5 values inside the axis."""
        out = []
        for e in range(int(np.floor(self.lo)), int(np.ceil(self.hi)) + 1):
            for m in (1, 2, 5):
                v = m * 10.0 ** e
                if self.lo <= np.log10(v) <= self.hi:
                    out.append((int(self.row(np.array([v]))[0]), m == 1))
        return out


def draw(toa: np.ndarray, colourings: Sequence[Colouring], width: int = 720, height: int = 480) -> np.ndarray:
    """The pulse picture of `toa` (sorted) as an RGB array: one ΔTOA-against-TOA panel per colouring,
    then the PRI histogram with the intervals per id of the first colouring (its spurious pulses left out)."""
    img = np.full((height, width, 3), 255, np.uint8)
    n = toa.size
    dtoa = np.diff(toa)  # the first pulse has no predecessor: drawn from the second on
    ids0, spur0 = colourings[0]
    ivals, ival_ids = label_intervals(toa, np.asarray(ids0), ~np.asarray(spur0))
    top, bottom = PAD, height - PAD - 1
    axis = LogAxis(np.concatenate([dtoa, ivals]), top + DOT + 1, bottom - DOT - 1)
    hist_w = max(width // 5, 40)
    panel_w = (width - 2 * PAD - len(colourings) * GAP - hist_w) // len(colourings)
    lefts = [PAD + p * (panel_w + GAP) for p in range(len(colourings) + 1)]
    for x0, w in zip(lefts, [panel_w] * len(colourings) + [hist_w]):
        for row, decade in axis.grid():
            img[row, x0:x0 + w] = GRID if decade else MINOR
            img[row, x0 - (5 if decade else 3):x0] = FRAME  # tick marks left of the panel
    if n > 1:
        span = max(float(toa[-1] - toa[1]), 1e-300)
        x = np.round((toa[1:] - toa[1]) / span * (panel_w - 2 * DOT - 3)).astype(int) + DOT + 1
        y = axis.row(dtoa)
        for x0, (ids, spur) in zip(lefts, colourings):
            colours = _colours(np.maximum(np.asarray(ids)[1:], 0), np.asarray(spur)[1:])
            for dy in range(-DOT, DOT + 1):
                for dx in range(-DOT, DOT + 1):
                    img[y + dy, x0 + x + dx] = colours
        _histogram(img, axis, dtoa, ivals, ival_ids, lefts[-1], hist_w)
    for x0, w in zip(lefts, [panel_w] * len(colourings) + [hist_w]):
        img[[top, bottom], x0:x0 + w] = FRAME
        img[top:bottom + 1, [x0, x0 + w - 1]] = FRAME
    return img


def _histogram(img: np.ndarray, axis: LogAxis, dtoa: np.ndarray, ivals: np.ndarray, ival_ids: np.ndarray,
               x0: int, w: int, bin_rows: int = 3) -> None:
    """Horizontal bars on the panel at x0 (rows shared with the scatter panels): the ΔTOA count per
    `bin_rows` rows in grey, each id's interval count in its colour, stacked from the left over it."""
    nbins = (axis.bottom - axis.top) // bin_rows + 1
    grey = np.bincount((axis.row(dtoa) - axis.top) // bin_rows, minlength=nbins)
    ids = np.unique(ival_ids)
    per_id = np.zeros((nbins, ids.size), np.int64)
    np.add.at(per_id, ((axis.row(ivals) - axis.top) // bin_rows, np.searchsorted(ids, ival_ids)), 1)
    # Each kind scaled to its own peak: the interval spikes would otherwise flatten the spread ΔTOAs.
    grey_scale = (w - 4) / max(int(grey.max()), 1)
    scale = (w - 4) / max(int(per_id.sum(1).max(initial=0)), 1)
    rows = axis.top + np.arange(nbins)[:, None] * bin_rows + np.arange(bin_rows - 1)  # a blank row between bins
    rows, cols = rows.clip(max=axis.bottom), np.arange(w - 4) + x0 + 2
    ends = np.round(np.cumsum(per_id, 1) * scale).astype(int)
    starts = np.concatenate([np.zeros((nbins, 1), int), ends[:, :-1]], 1)
    bars = [(np.zeros(nbins, int), np.round(grey * grey_scale).astype(int), np.full(3, HIST, np.uint8))]
    bars += [(starts[:, k], ends[:, k], PALETTE[ids[k] % (len(PALETTE) - 1)]) for k in range(ids.size)]
    for lo, hi, colour in bars:
        on = (np.arange(w - 4) >= lo[:, None]) & (np.arange(w - 4) < hi[:, None])  # (bin, column)
        b, c = np.nonzero(on)
        img[rows[b], cols[c][:, None]] = colour


def render_rgb(toa: np.ndarray, labels: np.ndarray, source: np.ndarray, n_labels: int,
               width: int = 720, height: int = 480) -> np.ndarray:
    """The env's frame: ΔTOA against TOA coloured by the agent's labels (left) and by the true sources
    (middle; a merged pulse by its primary source, spurious grey), and the PRI histogram of the labels."""
    return draw(toa, [(labels, labels == n_labels), (source, source < 0)], width, height)


def png(img: np.ndarray) -> bytes:
    """An RGB array as PNG bytes, with no metadata (equal arrays give equal bytes): indexed colour when
    it has at most 256 colours (a picture's few flat colours: a third of the bytes or less), else RGB."""
    h, w, _ = img.shape
    codes = (img.astype(np.uint32) << np.array([16, 8, 0], np.uint32)).sum(2, dtype=np.uint32)
    colours, index = np.unique(codes, return_inverse=True)
    if colours.size <= 256:
        rows, head, extra = index.reshape(h, w).astype(np.uint8), (8, 3), [(b"PLTE", _rgb_bytes(colours))]
    else:
        rows, head, extra = img.reshape(h, w * 3), (8, 2), []
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], 1)  # filter type 0 on every row

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return b"".join([b"\x89PNG\r\n\x1a\n", chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, *head, 0, 0, 0)),
                     *(chunk(k, d) for k, d in extra), chunk(b"IDAT", zlib.compress(raw.tobytes(), 9)),
                     chunk(b"IEND", b"")])


def _rgb_bytes(codes: np.ndarray) -> bytes:
    return np.stack([codes >> 16, codes >> 8, codes], 1).astype(np.uint8).tobytes()


class Window:
    """A matplotlib window showing frames (render_mode="human"), refreshed at most `fps` times a second
    as Gymnasium's pygame clock paces its envs.  With a file-only backend (MPLBACKEND=Agg) each frame is
    still drawn, at the same pace, and nothing is shown."""

    def __init__(self, fps: float, title: str = "deint-bench"):
        try:
            import matplotlib.pyplot as plt
        except ImportError:
            raise DeintError("render_mode='human' needs matplotlib: pip install 'deint-bench[plot]'") from None
        self._plt, self.fps, self.title = plt, fps, title
        self._fig = self._image = None
        self._due = 0.0

    def show(self, frame: np.ndarray) -> None:
        plt = self._plt
        if self._fig is None or not plt.fignum_exists(self._fig.number):  # first frame, or the user closed it
            h, w, _ = frame.shape
            self._fig = plt.figure(figsize=(w / 100, h / 100), dpi=100)  # numbered: each env its own window
            self._fig.canvas.manager.set_window_title(self.title)
            ax = self._fig.add_axes((0, 0, 1, 1))
            ax.set_axis_off()
            self._image = ax.imshow(frame, interpolation="nearest")
            if self._gui:
                self._fig.show()
        else:
            self._image.set_data(frame)
        canvas = self._fig.canvas
        canvas.draw_idle()
        wait = max(self._due - time.monotonic(), 0.0)
        if self._gui:
            canvas.start_event_loop(max(wait, 1e-3))  # the window stays responsive while it waits
        else:
            time.sleep(wait)
        self._due = time.monotonic() + 1.0 / self.fps

    @property
    def _gui(self) -> bool:
        return self._fig.canvas.required_interactive_framework is not None

    def close(self) -> None:
        if self._fig is not None:
            self._plt.close(self._fig)
            self._fig = self._image = None


def render_ansi(toa: np.ndarray, labels: np.ndarray, source: np.ndarray, n_labels: int, rows: int = 12) -> str:
    """The last `rows` labelled pulses with the truth beside them, and the running label agreement."""
    n = toa.size
    lines = [f"{'pulse':>7} {'toa':>14} {'label':>6} {'truth':>6}"]
    for j in range(max(0, n - rows), n):
        lab = "spur" if labels[j] == n_labels else str(int(labels[j]))
        tru = "spur" if source[j] < 0 else str(int(source[j]))
        lines.append(f"{j:>7} {toa[j]:>14.6g} {lab:>6} {tru:>6}")
    agree = float(np.mean(np.where(labels == n_labels, source < 0, labels == source))) if n else float("nan")
    lines.append(f"{n} pulses labelled; labels equal to the primary source: {agree:.3f}")
    return "\n".join(lines) + "\n"

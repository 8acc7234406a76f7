"""The viewer, kept apart from the env's step logic: a pulse raster as an RGB array, or a text table.

Both show only pulses already labelled, so rendering never shows the truth of a pending pulse.
"""

from __future__ import annotations

import numpy as np

# Ten distinguishable colours (Tableau 10); label/source i takes colour i mod 10, "spurious" grey.
PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                    [140, 86, 75], [227, 119, 194], [188, 189, 34], [23, 190, 207], [127, 127, 127]], np.uint8)
SPURIOUS = np.array([170, 170, 170], np.uint8)


def _colours(ids: np.ndarray, spurious: np.ndarray) -> np.ndarray:
    out = PALETTE[np.asarray(ids) % (len(PALETTE) - 1)]  # grey (the last) is kept for "spurious"
    out[spurious] = SPURIOUS
    return out


def render_rgb(toa: np.ndarray, labels: np.ndarray, source: np.ndarray, n_labels: int,
               width: int = 640, height: int = 320) -> np.ndarray:
    """Two panels, TOA (up) against pulse index (right): left coloured by the agent's labels, right by
    the true sources (a merged pulse by its primary source)."""
    img = np.full((height, width, 3), 255, np.uint8)
    pad, gap = 12, 16
    pw, ph = (width - 2 * pad - gap) // 2, height - 2 * pad
    n = toa.size
    for p, (ids, spur) in enumerate(((labels, labels == n_labels), (source, source < 0))):
        x0 = pad + p * (pw + gap)
        img[pad - 1, x0 - 1:x0 + pw + 1] = img[pad + ph, x0 - 1:x0 + pw + 1] = 60  # frame
        img[pad - 1:pad + ph + 1, x0 - 1] = img[pad - 1:pad + ph + 1, x0 + pw] = 60
        if n == 0:
            continue
        span = max(float(toa[-1] - toa[0]), 1e-12)
        px = x0 + 1 + np.round(np.arange(n) / max(n - 1, 1) * (pw - 3)).astype(int)
        py = pad + ph - 2 - np.round((toa - toa[0]) / span * (ph - 3)).astype(int)
        colours = _colours(np.maximum(ids, 0), spur)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                img[py + dy, px + dx] = colours
    return img


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

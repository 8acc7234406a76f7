"""`deint plot`: a pulse file as an EW analyst reads it, drawn with matplotlib (the `plot` extra).

    deint plot PULSES.csv [--labels LABELS.csv] -o OUT.png [--first N]

Each pulse is a dot at its TOA (x) against its ΔTOA, the time since the previous received pulse (y, log
scale), in one panel per colouring the file allows: by LABELS (a label file as `deint label` writes)
and by the file's own source column (the truth); one uncoloured panel when it has neither.  Beside
them, on the same ΔTOA axis, the PRI histogram: the ΔTOAs (a grey outline) and, per label (or per source
without labels), the intervals between consecutive pulses given that label, which a right
deinterleaving turns into one spike per source at its PRI.  The same view as the env's rgb_array
frame (`deint_env.envs.render`), with axes, ticks and a legend.
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import numpy as np

from deint_env import formats
from deint_env.cli_util import _check_paths, _status, read_label_file
from deint_env.errors import DeintError
from deint_env.formats import tdc

INCH = 100  # dots per inch: the figure size in inches is the picture's size in hundreds of pixels
NO_MATPLOTLIB = "deint plot needs matplotlib: pip install 'deint-bench[plot]'"
MAX_DRAWN_TOA = 1e300  # near float64's limit the ΔTOAs and the axes' margins overflow to inf in matplotlib


def _add_plot(sub) -> None:
    p = sub.add_parser(
        "plot", help="draw a pulse file: ΔTOA against TOA and the PRI histogram (PNG)",
        description="Draw PULSES.csv as ΔTOA (time since the previous pulse, log scale) against TOA, coloured by "
                    "LABELS (a label file, as `deint label` writes) and by the file's source column (its "
                    "truth), one panel each (both when both exist), beside the PRI histogram: the ΔTOAs "
                    "(an outline) and the intervals between consecutive pulses of each label (of each source "
                    "without labels) in colour.  A .h5/.hdf5 file is a Turing Deinterleaving Challenge file "
                    "(its emitter ids are the truth).  Needs matplotlib (pip install 'deint-bench[plot]').")
    p.add_argument("pulses", metavar="PULSES.csv")
    p.add_argument("--labels", metavar="LABELS.csv", help="a label file of PULSES.csv to colour by")
    p.add_argument("-o", "--output", required=True, metavar="OUT.png", help="the PNG file to write")
    p.add_argument("--first", type=int, metavar="N", help="draw only the first N pulses")
    p.set_defaults(func=cmd_plot)


def _read(args: argparse.Namespace) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The file's TOAs, its truth (source ids, -1 = spurious; None without) and the labels (file labels,
    -1 = spurious; None without --labels)."""
    if tdc.is_tdc_path(args.pulses):
        train = tdc.read_tdc(args.pulses)
        toa, source = train.toa, (train.source() if train.labels is not None else None)
    else:
        table = formats.read_pulse_table(args.pulses)
        toa, source = table.toa, table.source
    labels = None if args.labels is None else read_label_file(args.labels, toa, args.pulses)
    return toa, source, labels


def cmd_plot(args: argparse.Namespace) -> int:
    _check_paths({"PULSES": args.pulses, "--labels": args.labels}, {"-o": args.output})
    if Path(args.output).suffix.lower() != ".png":
        raise DeintError(f"-o {args.output}: deint plot writes PNG; name the output *.png")
    if args.first is not None and args.first < 2:
        raise DeintError(f"--first={args.first} is invalid: at least 2 pulses (a ΔTOA needs two)")
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise DeintError(NO_MATPLOTLIB) from None
    toa, source, labels = _read(args)
    n = toa.size if args.first is None else min(args.first, toa.size)
    if n < 2:
        raise DeintError(f"{args.pulses}: has {toa.size} pulse(s); a ΔTOA plot needs at least 2")
    big = np.flatnonzero(np.abs(toa[:n]) > MAX_DRAWN_TOA)
    if big.size:
        raise DeintError(f"{args.pulses}: pulse {int(big[0]) + 1} has toa={float(toa[big[0]])!r}, too large to draw; "
                         f"deint plot draws TOAs in [-{MAX_DRAWN_TOA:g}, {MAX_DRAWN_TOA:g}]")
    panels = [("by label (--labels)", "label", labels), ("by true source (the file's)", "source", source)]
    panels = [(title, kind, ids[:n]) for title, kind, ids in panels if ids is not None]
    if not panels:
        panels = [("no labels, no truth", "pulse", np.zeros(n, np.int64))]
    buf = io.BytesIO()
    try:
        with np.errstate(over="ignore"):  # no metadata (below): reruns give equal bytes
            fig = _figure(Figure, toa[:n], panels, f"{Path(args.pulses).name}: {n} of {toa.size} pulses")
            fig.savefig(buf, format="png", dpi=INCH, metadata={"Software": None})
    except OverflowError:  # a log axis over ~280 decades: matplotlib's tick positions overflow to inf
        dtoa = np.diff(toa[:n])
        raise DeintError(f"{args.pulses}: its ΔTOAs run from {dtoa[dtoa > 0].min():g} to {dtoa.max():g}, too wide "
                         f"a range for a log axis; draw fewer pulses (--first N) or rescale the TOAs") from None
    formats.write_bytes(args.output, buf.getvalue())
    coloured = " and ".join(f"{kind}s" for _, kind, _ in panels if kind != "pulse") or "nothing (no labels or truth)"
    _status(f"deint: plotted {n} pulses coloured by {coloured} -> {args.output}")
    return 0


def _colour(i: int) -> str:
    return "0.55" if i < 0 else f"C{i % 10}"


def _figure(Figure, toa: np.ndarray, panels: list[tuple[str, str, np.ndarray]], title: str):
    from deint_env.envs.render import label_intervals  # lazily: `deint --help` loads no env

    dtoa = np.diff(toa)
    kind0, ids0 = panels[0][1], panels[0][2]
    ivals, ival_ids = label_intervals(toa, ids0, ids0 >= 0)
    pos = np.concatenate([dtoa[dtoa > 0], ivals[ivals > 0]])
    lo, hi = (pos.min(), pos.max()) if pos.size else (1.0, 10.0)
    shown = np.maximum(dtoa, lo)  # a zero ΔTOA (coincident pulses) on the bottom edge, not lost to the log axis
    fig = Figure(figsize=(4 * len(panels) + 3, 5), dpi=INCH, layout="constrained")
    axes = fig.subplots(1, len(panels) + 1, sharey=True, width_ratios=[4] * len(panels) + [2.2])
    for ax, (name, kind, ids) in zip(axes, panels):
        for i in np.unique(ids):
            sel = ids[1:] == i
            what = "pulses" if kind == "pulse" else "spurious" if i < 0 else f"{kind} {i}"
            ax.scatter(toa[1:][sel], shown[sel], s=6, linewidths=0, color="0.2" if kind == "pulse" else _colour(i),
                       label=f"{what} ({int(sel.sum())})", rasterized=True)
        ax.set_yscale("log")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("TOA")
        if len(np.unique(ids)) <= 12:
            ax.legend(fontsize=7, loc="lower right", markerscale=2, framealpha=0.85)
    axes[0].set_ylabel("ΔTOA: time since the previous pulse")
    axes[0].set_ylim(lo / 1.25, hi * 1.25)
    h = axes[-1]
    edges = np.geomspace(lo / 1.25, hi * 1.25, 90)
    if kind0 != "pulse" and ivals.size:
        keys = np.unique(ival_ids)
        h.hist([ivals[ival_ids == k] for k in keys], bins=edges, orientation="horizontal", stacked=True,
               color=[_colour(int(k)) for k in keys],
               label=[f"{kind0} {k} intervals" for k in keys] if keys.size <= 12 else None)
    # the ΔTOAs as an outline over the bars, so neither hides the other
    h.hist(shown, bins=edges, orientation="horizontal", histtype="step", color="0.3", label="ΔTOA")
    h.set_xscale("log")  # the interval spikes and the spread ΔTOAs differ by orders of magnitude
    h.set_xlabel("count")
    h.set_title("PRI histogram", fontsize=9)
    h.legend(fontsize=7, loc="lower right", framealpha=0.85)
    fig.suptitle(title, fontsize=10)
    return fig

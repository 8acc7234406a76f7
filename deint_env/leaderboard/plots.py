"""The leaderboard's plots (PNG, matplotlib): rliable's interval-estimate and performance-profile
plots, and the mean score against each varying scenario setting.  PNGs carry no software or time
metadata, so equal numbers give byte-identical files."""

from __future__ import annotations

import io
import math
import sys
from typing import Any

import numpy as np

from deint_env.leaderboard.render import tidy
from deint_env.stats import TAUS
from deint_env.tables import display_name


def _pyplot():
    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")  # files only: no display needed
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight", metadata={"Software": None})
    _pyplot().close(fig)
    return buf.getvalue()


def _colors(names: list[str]) -> dict[str, Any]:
    import matplotlib

    palette = matplotlib.colormaps["tab10" if len(names) <= 10 else "tab20"].colors
    return {n: palette[i % len(palette)] for i, n in enumerate(names)}


def _ok(v: Any) -> bool:
    return v is not None and math.isfinite(v)


def render_all(board: dict[str, Any], profiles: dict[str, tuple[np.ndarray, ...]]) -> dict[str, bytes]:
    """{file name: PNG bytes}: the plots `render.plot_files` lists."""
    board = tidy(board)
    rows = [r for r in board["rows"] if _ok(r["score_iqm"])]
    if not rows:
        return {}
    names = [display_name(r) for r in rows]
    colors = _colors(names)
    out = {"profiles.png": profile_plot(rows, names, colors, profiles), "pareto.png": pareto(board["suite"], rows)}
    if board["intervals"]:
        out["intervals.png"] = intervals(rows, names, colors)
    for key in board["rows"][0]["by_setting"]:
        out[f"score_vs_{key}.png"] = setting_plot(board["suite"], key, rows, names, colors)
    return out


def intervals(rows: list[dict[str, Any]], names: list[str], colors: dict[str, Any]) -> bytes:
    from rliable import plot_utils

    _pyplot()
    points = {n: [r["score_iqm"], r["score_mean"]] for n, r in zip(names, rows)}
    cis = {n: np.array([[r["score_iqm_low"], r["score_mean_low"]], [r["score_iqm_high"], r["score_mean_high"]]])
           for n, r in zip(names, rows)}
    height = 0.45 * len(names)  # inches; the axis label goes below the tick labels
    fig, _ = plot_utils.plot_interval_estimates(points, cis, ["IQM", "Mean"], algorithms=names[::-1], colors=colors,
                                                xlabel="normalised score (0 = random, 1 = genie)", row_height=0.45,
                                                subfigure_width=4.0, xlabel_y_coordinate=-0.75 / height, wspace=0.3)
    return _png(fig)


def profile_plot(rows: list[dict[str, Any]], names: list[str], colors: dict[str, Any],
                 profiles: dict[str, tuple[np.ndarray, ...]]) -> bytes:
    from rliable import plot_utils

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    curves = {n: profiles[r["policy"]][0] for n, r in zip(names, rows)}
    bands = {n: (profiles[r["policy"]][1], profiles[r["policy"]][2]) for n, r in zip(names, rows)}
    plot_utils.plot_performance_profiles(curves, TAUS, bands, ax=ax, colors=colors, xlabel=r"normalised score $\tau$",
                                         ylabel=r"fraction of episodes with score $> \tau$", labelsize="large",
                                         ticklabelsize="large")
    ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    return _png(fig)


def setting_plot(suite: str, key: str, rows: list[dict[str, Any]], names: list[str], colors: dict[str, Any]) -> bytes:
    plt = _pyplot()
    values = [p["value"] for p in rows[0]["by_setting"][key]]
    numeric = not any(isinstance(v, str) for v in values)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for k, (name, r) in enumerate(zip(names, rows)):
        pts = [(i, p) for i, p in enumerate(r["by_setting"][key]) if _ok(p["mean"])]
        if not pts:
            continue
        if numeric:
            x = np.array([values[i] for i, _ in pts], dtype=float)
        else:  # categories side by side, entries spread a little around each
            x = np.array([i for i, _ in pts], dtype=float) + 0.5 * ((k + 0.5) / len(rows) - 0.5)
        y = np.array([p["mean"] for _, p in pts])
        err = np.array([[p["mean"] - p["mean_low"], p["mean_high"] - p["mean"]] if _ok(p["mean_low"]) else [0.0, 0.0]
                        for _, p in pts]).T  # no intervals on a board with too few seeds
        ax.errorbar(x, y, yerr=err, color=colors[name], label=name, marker="o", markersize=4, capsize=3,
                    linestyle="-" if numeric else "none", linewidth=1.5)
    if numeric:
        pos = [v for v in values if v > 0]
        if len(pos) == len(values) and max(values) / min(values) >= 20:
            ax.set_xscale("log")
        if len(values) <= 6:  # few values: tick each; more would crowd the axis
            ax.set_xticks(values, [f"{v:g}" for v in values], minor=False)
    else:
        ax.set_xticks(range(len(values)), values)
    ax.set_xlabel(key)
    ax.set_ylabel("mean normalised score")
    ax.set_title(f"{suite}: score against {key} (95 % intervals)")
    ax.grid(True, alpha=0.25)
    ax.spines[["top", "right"]].set_visible(False)
    ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    return _png(fig)


def _front(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The Pareto front of (cost, score) points: each point no other beats on both, by cost."""
    front, best = [], -math.inf
    for cost, score in sorted(points, key=lambda p: (p[0], -p[1])):
        if score > best:
            front.append((cost, score))
            best = score
    return front


def pareto(suite: str, rows: list[dict[str, Any]]) -> bytes:
    """Mean score against lag and against us/pulse, one colour per division, each division's front drawn."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    divisions = list(dict.fromkeys(r["division"] for r in rows))
    colors = _colors(divisions)
    ranked = [r for r in rows if not r["oracle"] and not r.get("ablation_of") and r["coverage"] >= 1]
    for ax, key, label in ((axes[0], "lag", "lag (pulses; log scale, 0 drawn at 0.5)"),
                           (axes[1], "us_per_pulse", "us/pulse (one timing run; log scale)")):
        for d in divisions:
            pts = [(max(float(r[key]), 0.5), r["score_mean"], display_name(r)) for r in ranked
                   if r["division"] == d and _ok(r.get(key)) and _ok(r["score_mean"])]
            if not pts:
                continue
            ax.scatter([p[0] for p in pts], [p[1] for p in pts], color=colors[d], label=d, s=18)
            front = _front([(p[0], p[1]) for p in pts])
            ax.step([p[0] for p in front], [p[1] for p in front], where="post", color=colors[d], alpha=0.6)
            for x, y, name in pts:
                if (x, y) in front:
                    ax.annotate(name, (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("mean normalised score")
        ax.grid(True, alpha=0.25)
        ax.spines[["top", "right"]].set_visible(False)
    if axes[0].get_legend_handles_labels()[0]:  # a board of submitted entries alone has no lags to draw
        axes[0].legend(title="division", frameon=False)
    fig.suptitle(f"{suite}: score against decision lag and cost (each division's Pareto front)")
    return _png(fig)

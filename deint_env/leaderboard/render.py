"""The leaderboard as files: leaderboard.json, leaderboard.csv, README.md (GitHub) and index.html (both
with a scenario table linking each scenario's example-episode picture, `episodes`).

Floats are rounded to 6 significant digits and keys sorted, and nothing depends on the clock: only
the measured `us_per_pulse` can change between two builds from the same results.  index.html is one
self-contained page (inline CSS and a few lines of JavaScript: click a column header to sort, tabs
for the per-tag scores) that works opened from the file system.
"""

from __future__ import annotations

import contextlib
import csv
import html
import io
import json
import math
import re
from pathlib import Path
from typing import Any

from deint_env.errors import DeintError
from deint_env.formats.files import write_all
from deint_env import metrics
from deint_env.tables import display_name, entry_columns, fault_lines, interval, markdown_table, num

PLOTS_DOC = {
    "intervals.png": "interval estimates: score IQM and mean per entry with 95 % stratified-bootstrap intervals",
    "pareto.png": "mean score against lag and against us/pulse per division: the Pareto front of each",
    "profiles.png": "performance profiles: the share of test episodes scoring above tau, with 95 % bands",
}


def publish(folder: Path, files: dict[str, str | bytes], obsolete: list[str] = ()) -> None:
    """Publish `files` into `folder` all together or not at all (`write_all`: every file is written
    beside its target before any is renamed into place, so a full disk or any other failure leaves
    the folder as it was), then remove the `obsolete` files.  Call with the folder's results lock held."""
    try:
        write_all([(folder / name, data) for name, data in files.items()])
    except DeintError as e:
        raise DeintError(f"{e}; nothing was published") from None
    for name in obsolete:
        with contextlib.suppress(FileNotFoundError):
            (folder / name).unlink()


def tidy(x: Any) -> Any:
    """Floats rounded to 6 significant digits (NaN -> None), recursively."""
    if isinstance(x, dict):
        return {k: tidy(v) for k, v in x.items()}
    if isinstance(x, list):
        return [tidy(v) for v in x]
    if isinstance(x, float):
        return float(f"{x:.6g}") if math.isfinite(x) else None
    return x


def render_all(board: dict[str, Any]) -> dict[str, str]:
    board = tidy(board)
    return {"leaderboard.json": json.dumps(board, indent=1, sort_keys=True, allow_nan=False) + "\n",
            "leaderboard.csv": render_csv(board), "README.md": render_readme(board),
            "index.html": render_html(board)}


# ---------------------------------------------------------------------------------------------------
# cells
# ---------------------------------------------------------------------------------------------------
def csv_fields() -> list[str]:
    return (["division", "rank", "rank_label", "policy", "kind", "marker", "ablation_of", "learned_share",
             "learned_share_low", "learned_share_high", "test_looks", "vs_fdp", "score_iqm", "score_iqm_low", "score_iqm_high", "score_mean", "score_mean_low",
             "score_mean_high"] + [m.key for m in metrics.METRICS]
            + ["coverage", "played", "scored", "episodes", "faults", "oracle", "submitted", "version",
               "policy_version"])


TAG_FIELDS = ["iqm", "iqm_low", "iqm_high", "mean", "mean_low", "mean_high", "scored"]


def render_csv(board: dict[str, Any]) -> str:
    fields = csv_fields()
    head = fields + ["suite", "suite_version", "suite_hash"]
    head += [f"tag_{t}_{f}" for t in board["tags"] for f in TAG_FIELDS]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(head)
    for r in board["rows"]:
        cells = [len(r[k]) if k == "faults" else r.get(k) for k in fields]
        cells += [board["suite"], board["suite_version"], board["suite_hash"]]
        cells += [r["tags"][t][f] for t in board["tags"] for f in TAG_FIELDS]
        w.writerow(["" if c is None else str(c).lower() if isinstance(c, bool) else c for c in cells])
    return out.getvalue()


# ---------------------------------------------------------------------------------------------------
# README.md
# ---------------------------------------------------------------------------------------------------
def _scope_text(b: dict[str, Any]) -> str:
    scope = b["scope"]
    if scope["scenarios"] is None and scope["max_seeds"] is None:
        return f"every test seed of its {b['scenarios']} scenarios"
    which = "all" if scope["scenarios"] is None else ", ".join(scope["scenarios"])
    seeds = "every test seed" if scope["max_seeds"] is None else f"the first {scope['max_seeds']} test seeds"
    return f"a partial run ({seeds} of {b['scenarios']} scenarios: {which}), not the published scope"


def plot_files(board: dict[str, Any]) -> dict[str, str]:
    """Every plot of the folder and what it shows."""
    if not any(r["score_iqm"] is not None for r in board["rows"]):
        return {}
    out = {k: v for k, v in PLOTS_DOC.items() if k != "intervals.png" or board["intervals"]}
    for key in board["rows"][0]["by_setting"]:
        out[f"score_vs_{key}.png"] = f"mean score against the scenario setting {key}, with 95 % intervals"
    return out


IMPROVEMENT_HEAD = ["division", "X", "Y (next below)", "P(X > Y) [95% CI]", "scenarios", "rank"]


def _improvement_body(b: dict[str, Any]) -> list[list[str]]:
    return [[p["division"], p["x"], p["y"], f"{num(p['p'])} [{num(p['low'])}, {num(p['high'])}]", str(p["scenarios"]),
             "shared (interval includes 0.5)" if p["tied"] else "apart"] for p in b["probability_of_improvement"]]


def division_title(name: str, bound: int | None) -> str:
    return f"{name} (lag <= {bound})" if bound is not None else f"{name} (any lag)"


def division_rows(b: dict[str, Any]) -> list[tuple[str, list[dict[str, Any]]]]:
    """(title, rows) per division, in the board's order; entries that play no episode of the suite are
    left to `board_notes`."""
    return [(division_title(d, bound), [r for r in b["rows"] if r["division"] == d and _plays(r)])
            for d, bound in b["divisions"].items()]


def _plays(row: dict[str, Any]) -> bool:
    return row["played"] > 0 or bool(row["faults"])


def board_notes(b: dict[str, Any]) -> list[str]:
    """What a reader must know before reading the ranks: the seeds behind them, where the times come from,
    which learned entries are not shown to learn."""
    out = []
    if not b["intervals"]:
        out.append(f"**Only {b['seeds_per_scenario']} test seed(s) per scenario** (fewer than 3): no intervals are "
                   "shown and ranks follow the means untested; read them as provisional.")
    t = b.get("timing")
    if t is None:
        out.append("**Speed:** not timed (run `deint leaderboard --time`); times from the scoring runs are not shown.")
    else:
        m = t["machine"]
        out.append(f"**Speed** (us/pulse, x fdp) comes from one timing run on {t['date']} ({m['processor']}, "
                   f"{m['cpus']} CPUs, Python {m['python']}): {t['method']}; fdp took "
                   f"{num(t['reference']['us_per_pulse'], '.1f')} us/pulse on {t['reference']['suite']}'s episodes.")
        stale = [display_name(r) for r in b["rows"] if r["policy"] in (t.get("stale") or ())]
        if stale:
            out.append("**Not timed at the version scored** (changed since the timing run; no speed shown): "
                       + ", ".join(stale) + ".")
        batched = [f"{display_name(r)} ({r['timing_batch']})" for r in b["rows"] if r.get("timing_batch")]
        if batched:
            out.append("**Batched K episodes:** timed playing K episodes in lock-step, one network call per step for "
                       "all K (as the runner plays them), each at the batch's time per pulse: " + ", ".join(batched)
                       + ".")
    idle = [display_name(r) for r in b["rows"] if not _plays(r)]
    if idle:
        out.append("**Not applicable** to any scenario of this suite (not shown): " + ", ".join(idle) + ".")
    marked = [r for r in b["rows"] if r.get("kind") == "learned" and r.get("ablation") and not r.get("ablation_of")
              and _plays(r)]
    if marked:
        out.append("**Learned entries** against their ablation (the same entry with its network's output zeroed, "
                   "played on the same episodes): " + "; ".join(
                       f"{display_name(r)}: {r['marker_reason']} (ablation {r['ablation']})" for r in marked) + ".")
    return out


def explanation(b: dict[str, Any]) -> list[str]:
    reps = b["bootstrap"]["reps"]
    return [
        "**Score.** Each test episode's label accuracy a (the environment's reward rule: the right source "
        "label, or the right link to the predecessor in blind scenarios) is normalised between a floor and a "
        "ceiling measured on that same episode: score = (a - a_random) / (a_genie - a_random), where `random` "
        "labels uniformly at random (seeded by the episode) and `genie` is the oracle that labels from the "
        "true parameters (the order-preserving MAP alignment of the received pulses to the true emission "
        "schedule). 0 is chance, 1 is the oracle. A policy can beat it on an episode by luck, and where the "
        "TOA jitter is comparable to the spacing of pulses (so the received order is not the emission order) "
        "genie is no longer a ceiling: scores above 1 there mean a policy did better than it.",
        "",
        "**Method.** Every policy plays every test episode through the environment, seeing only the "
        "observations and the public priors. Rows are ranked within latency divisions by their declared lag "
        "(online: lag <= 3, the look-ahead of MK94's forward DP; low-latency: lag <= 64; offline: any lag), by "
        "score mean; an entry shares the rank of the one above it (\"1=\") when their probability of "
        "improvement's interval includes 0.5. Over the episodes we report the mean and the interquartile mean "
        f"(IQM: the mean of the middle 50 % of scores, robust to a few failed episodes), each with a 95 % "
        f"stratified-bootstrap percentile interval ({reps} replicates, scenarios as "
        "strata, seeded so that reruns reproduce the numbers), computed with "
        f"[rliable](https://github.com/google-research/rliable) {b['rliable_version']} (Agarwal et al., "
        "\"Deep RL at the edge of the statistical precipice\", NeurIPS 2021). P(X > Y) is rliable's "
        "probability of improvement: the chance that X outscores Y on a random test episode of a scenario, "
        "averaged over scenarios. Coverage is the share of episodes a policy can play (a prior-based policy "
        "cannot play a blind scenario, say): its scores are over those only. Oracles see the truth; they are "
        "ceilings, not methods, and get no rank; so do entries that cannot play every episode (coverage "
        "below 100 %), listed after the ranked ones because their scores are over a subset. Faults are "
        "episodes where a policy failed (an exception, a label that is not an integer in range, a dead worker "
        "process): they are not scored, lower its coverage and are listed under the table. The period "
        "errors are medians over episodes of the final "
        "period estimates' mean relative error and of their RMS error over the Cramer-Rao bound (1 = "
        "efficient), for policies that report estimates. us/pulse is the policy's own compute time in the "
        "board's one timing run, and x fdp its ratio to fdp's in that run. A learned entry's learned share is "
        "its mean score minus that of its ablation (its network's output zeroed) on the same episodes; it is "
        "marked learned only when that interval lies above 0, else search. Test looks counts the versions of "
        "the entry's family scored on these test seeds before its own (history.json): each look is a chance "
        "to have chosen on the test seeds.",
    ]


def notes(b: dict[str, Any]) -> list[str]:
    """What the table leaves out or scores on fewer episodes: incomplete and stale entries, faults."""
    out = []
    if b["incomplete"]:
        out.append("Not shown, incomplete (rerun `deint leaderboard` to finish): " + ", ".join(
            f"{p} ({n} of {b['episodes']} episodes)" for p, n in sorted(b["incomplete"].items())))
    if b["stale"]:
        out.append("Not shown, stale (recorded with another version of the policy; rerun `deint leaderboard` "
                   "to replay): " + ", ".join(f"{p} ({n} episodes)" for p, n in sorted(b["stale"].items())))
    faults = fault_lines(b["rows"])
    if faults:
        out.append(f"Faults: {len(faults)} episode(s) where a policy failed, not scored (its coverage is lower "
                   "and it is not ranked; rerun `deint leaderboard` to retry): " + "; ".join(faults))
    return out


def render_readme(b: dict[str, Any]) -> str:
    title = f"# Leaderboard: {b['suite']}"
    lines = [title, "",
             f"Suite `{b['suite']}` version {b['suite_version']} (content hash `{b['suite_hash']}`), "
             f"{b['episodes']} test episodes per entry: {_scope_text(b)}. deint-bench {b['package_version']}. "
             "Generated by `deint leaderboard`; the same numbers are in [leaderboard.json](leaderboard.json) "
             "and [leaderboard.csv](leaderboard.csv), the episodes in [results.jsonl](results.jsonl), and a "
             "sortable page in [index.html](index.html).", ""]
    lines += [line for note in board_notes(b) for line in (note, "")]
    cols = entry_columns()
    for title, rows in division_rows(b):
        lines += [f"## Division: {title}", ""]
        lines += (markdown_table([c.head for c in cols], [[c.cell(r) for c in cols] for r in rows]) if rows
                  else ["No entry plays this division."]) + [""]
    lines.pop()
    lines += [line for note in notes(b) for line in ("", note)]
    if b["tags"]:
        lines += ["", "## Scores per tag", "", "Score IQM [95 % CI] over the scenarios carrying each tag.", ""]
        lines += markdown_table(["policy"] + b["tags"],
                           [[display_name(r)] + [interval(r["tags"][t], "iqm") for t in b["tags"]] for r in b["rows"]])
    if b["probability_of_improvement"]:
        lines += ["", "## Probability of improvement", "", "Between each ranked entry and the next below it in "
                  "its division; where the interval includes 0.5 they share a rank:", ""]
        lines += markdown_table(IMPROVEMENT_HEAD, _improvement_body(b))
    lines += ["", "## Scenarios", "", EXAMPLES_TEXT, ""]
    lines += markdown_table(["scenario (example episode)", "tags", "validation seed", "pulses drawn"],
                            [[f"[{x['scenario']}]({x['picture']})", ", ".join(x["tags"]), str(x["seed"]), _drawn(x)]
                             for x in b["examples"]])
    lines += ["", "## How to read it", ""] + explanation(b)
    plots = plot_files(b)
    if plots:
        lines += ["", "## Plots", ""]
        for name, what in plots.items():
            lines += [f"[{name}]({name}): {what}.", "", f"![{what}]({name})", ""]
        lines.pop()
    lines += ["", "## Submitting", "",
              "Labels from outside (any method, any language) are scored the same way: see the submission "
              "format in the [project README](../../README.md#leaderboards) and run "
              f"`deint leaderboard submit FILE --suite {b['suite']} --name NAME`."]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------------
# index.html
# ---------------------------------------------------------------------------------------------------
STYLE = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:84em;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0}
th,td{padding:.3em .6em;white-space:nowrap;border-bottom:1px solid #ddd;text-align:right}
td.t{text-align:left}th{cursor:pointer;background:#f4f4f4;user-select:none}
th[aria-sort=ascending]::after{content:" \\25B2"}th[aria-sort=descending]::after{content:" \\25BC"}
.tabs button{font:inherit;padding:.3em .8em;border:1px solid #bbb;background:#f8f8f8;cursor:pointer}
.tabs button.on{background:#333;color:#fff}img{max-width:100%;display:block;margin:1em 0}"""

# Click a header: sort its table's rows by that column (ascending, then descending); a cell's data-v
# holds its sort value, numbers compare as numbers, an empty value always sorts last.
SCRIPT = """document.querySelectorAll("table.sortable th").forEach((th, i) => th.addEventListener("click", () => {
  const body = th.closest("table").tBodies[0], up = th.getAttribute("aria-sort") !== "ascending";
  th.closest("tr").querySelectorAll("th").forEach(h => h.removeAttribute("aria-sort"));
  th.setAttribute("aria-sort", up ? "ascending" : "descending");
  const v = r => r.cells[i].dataset.v, cmp = (a, b) => isNaN(a) || isNaN(b) ? a.localeCompare(b) : a - b;
  [...body.rows].sort((a, b) => v(a) === "" ? 1 : v(b) === "" ? -1 : (up ? 1 : -1) * cmp(v(a), v(b)))
    .forEach(r => body.appendChild(r));
}));
document.querySelectorAll(".tabs button").forEach(b => b.addEventListener("click", () => {
  document.querySelectorAll(".tab").forEach(s => s.hidden = s.id !== b.dataset.tab);
  document.querySelectorAll(".tabs button").forEach(x => x.classList.toggle("on", x === b));
}));"""


EXAMPLES_TEXT = ("Each scenario's name links a picture of an example episode, its first validation seed (not a "
                 "test seed the board scores): every received pulse at its TOA (x) against the time since the "
                 "previous pulse (ΔTOA, y, log scale), coloured by the source that sent it (spurious grey), "
                 "beside the PRI histogram on the same ΔTOA axis (grey: the ΔTOAs; colours: the intervals "
                 "between consecutive pulses of each source, a spike at its PRI).")


def _drawn(x: dict[str, Any]) -> str:
    return str(x["pulses"]) if x["pulses"] == x["episode_pulses"] else f"first {x['pulses']} of {x['episode_pulses']}"


def _html_table(table_id: str, head: list[str], rows: list[list[tuple[str, Any]]]) -> str:
    """A sortable table; each cell is (text, sort value)."""
    def cell(text: str, value: Any) -> str:
        if isinstance(value, str):
            return f'<td class="t" data-v="{html.escape(value)}">{html.escape(text)}</td>'
        return f'<td data-v="{"" if value is None else repr(value)}">{html.escape(text)}</td>'

    out = [f'<table class="sortable" id="{table_id}"><thead><tr>'
           + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr></thead><tbody>"]
    out += ["<tr>" + "".join(cell(t, v) for t, v in row) + "</tr>" for row in rows]
    return "\n".join(out) + "\n</tbody></table>"


def _md_inline(text: str) -> str:
    """The markdown of `explanation` (bold, code, links) as HTML."""
    text = html.escape(text, quote=False)
    text = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", text)
    text = re.sub(r"`(.+?)`", r"<code>\1</code>", text)
    return re.sub(r"\[(.+?)\]\((.+?)\)", r'<a href="\2">\1</a>', text)


def render_html(b: dict[str, Any]) -> str:
    e = html.escape
    cols = entry_columns()
    tabs = [("tab-all", "all scenarios")] + [(f"tab-tag-{t}", t) for t in b["tags"]]
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             f"<title>deint-bench leaderboard: {e(b['suite'])}</title>", f"<style>{STYLE}</style></head><body>",
             f"<h1>Leaderboard: {e(b['suite'])}</h1>",
             f"<p>Suite <code>{e(b['suite'])}</code> version {b['suite_version']} (content hash "
             f"<code>{e(b['suite_hash'])}</code>), {b['episodes']} test episodes per entry: {e(_scope_text(b))}. "
             f"deint-bench {e(b['package_version'])}. Click a column header to sort.</p>",
             '<nav class="tabs">' + "".join(
                 f'<button data-tab="{tid}"{" class=on" if k == 0 else ""}>{e(name)}</button>'
                 for k, (tid, name) in enumerate(tabs)) + "</nav>",
             '<section class="tab" id="tab-all">']
    parts += [f"<p>{_md_inline(note)}</p>" for note in board_notes(b)]
    for k, (title, rows) in enumerate(division_rows(b)):
        parts += [f"<h2>Division: {e(title)}</h2>",
                  _html_table(f"board-{k}", [c.head for c in cols], [[(c.cell(r), c.value(r)) for c in cols] for r in rows])
                  if rows else "<p>No entry plays this division.</p>"]
    parts += ["</section>"]
    for t in b["tags"]:
        rows = []
        for r in b["rows"]:
            d = r["tags"][t]
            rows.append([(display_name(r), r["policy"]), (interval(d, "iqm"), d["iqm"]),
                         (interval(d, "mean"), d["mean"]), (str(d["scored"]), d["scored"])])
        parts += [f'<section class="tab" id="tab-tag-{e(t)}" hidden>',
                  f"<p>Scores over the scenarios tagged <code>{e(t)}</code>.</p>",
                  _html_table(f"tag-{e(t)}", ["policy", "score IQM [95% CI]", "score mean [95% CI]", "episodes"],
                              rows), "</section>"]
    parts += [f"<p>{e(note)}</p>" for note in notes(b)]
    if b["probability_of_improvement"]:
        rows = [[(d, d), (x, x), (y, y), (ci, p["p"]), (n, p["scenarios"]), (t, t)]
                for (d, x, y, ci, n, t), p in zip(_improvement_body(b), b["probability_of_improvement"])]
        parts += ["<h2>Probability of improvement</h2>",
                  "<p>Between each ranked entry and the next below it in its division.</p>",
                  _html_table("improvement", IMPROVEMENT_HEAD, rows)]
    parts += ["<h2>Scenarios</h2>", f"<p>{e(EXAMPLES_TEXT)}</p>",
              '<table id="scenarios"><thead><tr><th>scenario (example episode)</th><th>tags</th>'
              "<th>validation seed</th><th>pulses drawn</th></tr></thead><tbody>"]
    parts += [f'<tr><td class="t"><a href="{e(x["picture"])}">{e(x["scenario"])}</a></td><td class="t">'
              f'{e(", ".join(x["tags"]))}</td><td>{x["seed"]}</td><td>{e(_drawn(x))}</td></tr>' for x in b["examples"]]
    parts += ["</tbody></table>"]
    parts += ["<h2>How to read it</h2>"] + [f"<p>{_md_inline(p)}</p>" for p in explanation(b) if p]
    plots = plot_files(b)
    if plots:
        parts.append("<h2>Plots</h2>")
        parts += [f'<figure><img src="{e(name)}" alt="{e(what)}"><figcaption>{e(what)}</figcaption></figure>'
                  for name, what in plots.items()]
    parts += [f"<script>\n{SCRIPT}\n</script>", "</body></html>"]
    return "\n".join(parts) + "\n"

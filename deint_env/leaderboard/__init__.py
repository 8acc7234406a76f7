"""Leaderboards: every policy on a suite's test episodes, scored with honest statistics.

`deint leaderboard --suite SUITE` (or `build`) writes `leaderboards/<suite>/`; `deint leaderboard --all`
rebuilds every such folder with the policy specs and scope its leaderboard.json records:

- `results.jsonl`: one runner record per (entry, test episode), in canonical order; the run resumes
  from it and never replays a finished episode;
- `leaderboard.json`, `leaderboard.csv`: per entry the normalised score's IQM and mean with 95 %
  stratified-bootstrap intervals (rliable), accuracy, mean P_e, V-measure, ARI, per-tag scores, period
  error against the CRLB, us per pulse, lag, coverage, versions and the suite's hash; plus the
  probability of improvement between the top entries (JSON);
- `README.md` (the tables for GitHub, one per latency division), `index.html` (sortable, per-tag tabs,
  no server needed) and the plots (`intervals.png`, `profiles.png`, `pareto.png`, `score_vs_<setting>.png`);
- `episode-<scenario>.png`: an example episode per scenario (its first validation seed, coloured by the
  truth), linked from the scenario table of README.md and index.html (`episodes`);
- `history.json`: every policy version scored on the test seeds (`history`: each row's test looks);
- `timings.json`: the one timing run the speed columns come from (`timing`, `deint leaderboard --time`).

Rows are ranked within latency divisions by score mean, with shared ranks where the data cannot
separate two entries, and learned entries are measured against their ablation (`ranking`).

Bootstraps are seeded and files hold no timestamps but timings.json's: rebuilding from the same
results and timings gives the same bytes.  Outside labels enter through `submit` (format in
`deint_env.leaderboard.submit`).  Modules: `build` (running, aggregating through
`deint_env.aggregate`, the path `deint run`'s summary takes too, with `deint_env.stats`' rliable
estimates), `render` (JSON, CSV, README, HTML, and publishing every file together), `plots` (PNG),
`episodes` (the example-episode pictures), `submit` (submissions and `export`).  Columns come from the
metric table `deint_env.metrics.METRICS`.
"""

from deint_env.leaderboard import timing
from deint_env.leaderboard.build import (Scope, board_entries, board_policies, build, default_policies, published_suites,
                                         write)
from deint_env.leaderboard.submit import export, score_submission, submit

__all__ = ["Scope", "board_entries", "board_policies", "build", "default_policies", "published_suites", "export",
           "score_submission", "submit", "timing", "write"]

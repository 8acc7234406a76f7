"""An example episode per scenario for the board's pages: the scenario's first validation seed (never a
test seed the board scores), drawn as the env's picture coloured by the true sources
(`deint_env.envs.render`: ΔTOA against TOA, log scale, beside the PRI histogram of each source's
intervals), as a small indexed-colour PNG.  Simulation and drawing are deterministic, so a rebuild
writes the same bytes."""

from __future__ import annotations

from typing import Any

from deint_env.envs.render import draw, png
from deint_env.simulate import simulate
from deint_env.suites import SuiteEntry

WIDTH, HEIGHT = 480, 300
MAX_PULSES = 1000  # the first pulses only: a long episode (scale-v0's 10^6) would be a blot at this size


def file_name(scenario: str) -> str:
    # beside the board's other files: the folder stays flat, and a dropped scenario's picture is
    # removed with the other obsolete PNGs
    return f"episode-{scenario}.png"


def examples(entries: list[SuiteEntry]) -> tuple[list[dict[str, Any]], dict[str, bytes]]:
    """Per scenario (suite order) its row for the pages (scenario, tags, seed, pulses drawn, picture)
    and the pictures as {file name: PNG bytes}."""
    rows, files = [], {}
    for e in entries:
        seed = e.seeds("validation")[0]
        ep = simulate(e.spec, seed)
        toa, source = ep.toa[:MAX_PULSES], ep.source[:MAX_PULSES]
        name = file_name(e.name)
        files[name] = png(draw(toa, [(source, source < 0)], WIDTH, HEIGHT))
        rows.append({"scenario": e.name, "tags": list(e.tags), "seed": seed, "pulses": int(toa.size),
                     "episode_pulses": len(ep), "picture": name})
    return rows, files

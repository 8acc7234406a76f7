"""The front door: the README's size and generated block, the generated reference pages, the docs site."""

from __future__ import annotations

import importlib
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(f"docs_scripts_{name}", ROOT / "docs" / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_readme_is_at_most_200_lines():
    n = len((ROOT / "README.md").read_text().splitlines())
    assert n <= 200, f"README.md has {n} lines; move detail to docs/"


def test_readme_leaderboard_block_is_generated_from_the_boards():
    boards = _script("readme_boards")
    readme = (ROOT / "README.md").read_text()
    assert boards.render(readme, boards.block()) == readme, \
        "README.md's leaderboard block is out of date: run python docs/scripts/readme_boards.py"


def test_readme_block_reads_boards_without_divisions():
    boards = _script("readme_boards")
    board = {"rows": [
        {"policy": "genie", "rank": None, "score_mean": 1.0, "lag": 0.0},
        {"policy": "a", "rank": 2, "score_mean": 0.5, "lag": 0.0},
        {"policy": "b", "rank": 1, "score_mean": 0.6, "lag": 3.0},
        {"policy": "c", "rank": 3, "score_mean": 0.9, "lag": 16.0},
        {"policy": "d", "rank": 4, "score_mean": 0.8, "lag": 1024.0},
        {"policy": "e", "rank": None, "score_mean": None, "lag": None}]}
    got = {d: [r["policy"] for r in rows] for d, rows in boards.leaders(board).items()}
    assert got == {"online": ["b"], "low-latency": ["c"], "offline": ["d"]}


def test_readme_block_shows_every_tied_leader():
    boards = _script("readme_boards")
    board = {"rows": [
        {"policy": "a", "division": "online", "rank": 1, "rank_label": "1=", "score_mean": 0.9, "lag": 0},
        {"policy": "b", "division": "online", "rank": 1, "rank_label": "1=", "score_mean": 0.89, "lag": 3},
        {"policy": "c", "division": "online", "rank": 3, "rank_label": "3", "score_mean": 0.5, "lag": 3},
        {"policy": "d", "division": "offline", "rank": 1, "rank_label": "1", "score_mean": 0.95, "lag": 999}]}
    got = {d: [r["policy"] for r in rows] for d, rows in boards.leaders(board).items()}
    assert got == {"online": ["a", "b"], "offline": ["d"]}


def test_readme_block_names_a_better_entry_that_plays_part_of_the_board():
    """An entry left unranked for covering only part of the board (anchored-only on a board with blind
    scenarios) is named beside the ranked leader when it scores more, with its coverage; an oracle never is."""
    boards = _script("readme_boards")
    board = {"rows": [
        {"policy": "genie", "division": "online", "rank": None, "oracle": True, "coverage": 0.5, "score_mean": 1.0},
        {"policy": "random", "division": "online", "rank": 1, "rank_label": "1", "score_mean": 0.0, "coverage": 1.0},
        {"policy": "anchored", "division": "online", "rank": None, "score_mean": 0.4, "coverage": 0.5},
        {"policy": "weak", "division": "online", "rank": None, "score_mean": 0.3, "coverage": 0.5},
        {"policy": "mht", "division": "offline", "rank": None, "score_mean": 0.9, "coverage": 0.46}]}
    assert boards.partial_leader(board, "online", 0.0)["policy"] == "anchored"
    assert boards.partial_leader(board, "online", 0.5) is None
    assert boards.partial_leader(board, "offline", -1.0)["policy"] == "mht"


def test_generated_reference_pages_are_up_to_date():
    pages = _script("gen_pages")
    assert pages.stale() == [], "docs/generated/ is out of date: run python docs/scripts/gen_pages.py"


def test_docs_site_builds_strict(tmp_path):
    # mkdocs-material and mkdocstrings-python are in the [dev] extra; a missing one fails here, saying so.
    # (no -q: mkdocs counts warnings for --strict only when it logs them)
    for module in ("mkdocs", "material", "mkdocstrings_handlers.python"):
        try:
            importlib.import_module(module)
        except ImportError:
            pytest.fail(f"the docs site needs {module}: pip install mkdocs-material mkdocstrings-python "
                        "(the [dev] extra)")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
                       cwd=ROOT, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stdout}\n{r.stderr}"
    assert (tmp_path / "site" / "api" / "index.html").read_text().count("deint_env.envs.deinterleave.DeinterleaveEnv")

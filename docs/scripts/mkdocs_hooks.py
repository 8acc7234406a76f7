"""mkdocs hook (mkdocs.yml `hooks:`): the published leaderboards on the site, and links out of docs/ checked.

The docs pages are also read on GitHub, where a board is linked as `../leaderboards/SUITE/README.md`.
On the site that file does not exist, so:

- `on_files` adds each published board's `index.html` (its sortable page), plots, `leaderboard.json`
  and `leaderboard.csv` to the site under `leaderboards/SUITE/`;
- `on_page_markdown` rewrites a link that leaves docs/ to its copy on the site (a board's README.md to
  its index.html) and fails the build for a link to a file that does not exist or that the site does not
  carry, so broken links fail `mkdocs build --strict` here too.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]
BOARD_FILES = ("index.html", "leaderboard.json", "leaderboard.csv", "*.png")
LINK = re.compile(r"(\]\()([^)\s#]+)(#[^)\s]*)?(\))")


def _boards() -> list[Path]:
    return sorted(p.parent for p in (ROOT / "leaderboards").glob("*/leaderboard.json"))


def on_files(files: Files, config, **kwargs) -> Files:
    for board in _boards():
        for pattern in BOARD_FILES:
            for path in sorted(board.glob(pattern)):
                rel = path.relative_to(ROOT).as_posix()
                if files.get_file_from_path(rel) is None:
                    files.append(File(rel, str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown: str, page, config, files: Files, **kwargs) -> str:
    docs = Path(config["docs_dir"]).resolve()
    page_dir = posixpath.dirname(page.file.src_uri)

    def fix(m: re.Match) -> str:
        url = m.group(2)
        if "://" in url or url.startswith(("mailto:", "/")):
            return m.group(0)
        target = (docs / page_dir / url).resolve()
        try:
            target.relative_to(docs)
            return m.group(0)  # inside docs/: mkdocs checks it
        except ValueError:
            pass
        if not target.exists():
            raise PluginError(f"{page.file.src_uri}: link to {url}, which does not exist")
        rel = target.relative_to(ROOT).as_posix()
        if target.name == "README.md" and target.parent in _boards():
            rel = posixpath.join(posixpath.dirname(rel), "index.html")
        if files.get_file_from_path(rel) is None:
            raise PluginError(f"{page.file.src_uri}: link to {url}, a file outside docs/ that the site does not carry")
        new = posixpath.relpath(rel, page_dir or ".")
        return f"{m.group(1)}{new}{m.group(3) or ''}{m.group(4)}"

    return LINK.sub(fix, markdown)

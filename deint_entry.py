"""The `deint` console script's entry point (pyproject.toml, [project.scripts]).

A top-level module, outside `deint_env`, so that it runs before the package is imported: Ctrl-C during
that import (about 0.3 s of every command) is then one line and exit status 130, as it is once
`deint_env.cli.main` runs, and not a KeyboardInterrupt traceback.  It imports nothing else of the
project until its handler is in place.
"""

from __future__ import annotations

import signal
import sys

EXIT_INTERRUPTED = 130  # deint_env.cli_util's; importing it from there would import the package first


def _interrupted(signum: int, frame: object) -> None:
    print("deint: interrupted", file=sys.stderr)
    raise SystemExit(EXIT_INTERRUPTED)  # unwinds the import without a traceback


def main() -> int:
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.default_int_handler:  # an inherited SIG_IGN (nohup, `cmd &`) stays ignored
        signal.signal(signal.SIGINT, _interrupted)
    from deint_env.cli import main as cli_main

    try:
        signal.signal(signal.SIGINT, previous)  # main's own handling: a KeyboardInterrupt, one line and 130
        return cli_main()
    except KeyboardInterrupt:  # one that lands before main's own `except` is in place
        print("deint: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED

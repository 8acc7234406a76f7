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


_fired = []  # the SIGINTs `_interrupted` has handled


def _interrupted(signum: int, frame: object) -> None:
    _fired.append(signum)
    print("deint: interrupted", file=sys.stderr)
    raise SystemExit(EXIT_INTERRUPTED)  # unwinds the import without a traceback


def main() -> int:
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.default_int_handler:  # an inherited SIG_IGN (nohup, `cmd &`) stays ignored
        signal.signal(signal.SIGINT, _interrupted)
    try:
        from deint_env.cli import main as cli_main
    except Exception:
        signal.signal(signal.SIGINT, previous)
        if _fired:  # numpy's loader turns the exit raised while it loads a compiled module into an ImportError
            return EXIT_INTERRUPTED
        raise
    try:
        signal.signal(signal.SIGINT, previous)  # main's own handling: a KeyboardInterrupt, one line and 130
        if _fired:  # an optional import that caught it (`except ImportError`) let the import end: still Ctrl-C
            return EXIT_INTERRUPTED
        return cli_main()
    except KeyboardInterrupt:  # one that lands before main's own `except` is in place
        print("deint: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED

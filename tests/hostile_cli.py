"""What the CLI tests ask of `deint`: a refused command is one line; the installed console script."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from deint_env.cli import main


def one_line(capsys, *argv, says: str) -> str:
    """`deint ARGV` exits 2 with one error line (its last) holding `says`."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and err.count("deint: error: ") == 1 and err.endswith("\n") and says in err, err
    assert err.splitlines()[-1].startswith("deint: error: "), err
    return err


def deint_script() -> str:
    """The installed `deint` console script: the venv's, even when PATH lacks the venv."""
    beside = Path(sys.executable).with_name("deint")
    script = str(beside) if beside.exists() else shutil.which("deint")
    assert script, "the deint console script is not installed (pip install -e .)"
    return script

"""What the hostile-input tests (rounds six and seven) ask of `deint`: a refused command is one line."""

from __future__ import annotations

from deint_env.cli import main


def one_line(capsys, *argv, says: str) -> str:
    """`deint ARGV` exits 2 with one error line (its last) holding `says`."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and err.count("deint: error: ") == 1 and err.endswith("\n") and says in err, err
    assert err.splitlines()[-1].startswith("deint: error: "), err
    return err

"""Reading and writing whole files safely: the one atomic writer every output goes through (pulse,
label, priors, TDC and leaderboard files), and whole-file reads that fail with one line.

Every output is written to a temporary file in the target's directory and renamed over the target
only when complete: an error, a full disk or an interrupt never leaves a half-written file nor
clobbers a good one, and the error names the file.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator, TextIO

from deint_env.errors import DeintError

PathLike = str | os.PathLike


@contextlib.contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """A temporary path beside `path` to write to; it replaces `path` (synced, with the mode a plain
    open() gives) only if the block succeeds, and is removed otherwise."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise DeintError(f"cannot write {path}: {e.strerror or e}") from None
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, _file_mode(path))  # mkstemp makes 0600 files
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise DeintError(f"cannot write {path}: {e.strerror or e}") from None
        raise


@contextlib.contextmanager
def atomic_write(path: PathLike) -> Iterator[TextIO]:
    """Open a temporary file beside `path` for writing; it replaces `path` only if the block succeeds."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as f:
        yield f


def _file_mode(path: Path) -> int:
    try:
        return os.stat(path).st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def write_text(path: PathLike, text: str) -> None:
    with atomic_write(path) as f:
        f.write(text)


def write_bytes(path: PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data)


def read_bytes(path: PathLike, kind: str) -> bytes:
    """A file's bytes, every failure one line naming the file (`kind`: what the file should be)."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise DeintError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise DeintError(f"{path}: is a directory, not a {kind} file") from None
    except OSError as e:
        raise DeintError(f"{path}: cannot read ({e.strerror or e})") from None


def read_text(path: PathLike, kind: str) -> str:
    """A UTF-8 text file's content, every failure one line naming the file."""
    try:
        return read_bytes(path, kind).decode("utf-8-sig")  # -sig: drop a spreadsheet's byte-order mark
    except UnicodeDecodeError:
        raise DeintError(f"{path}: is not a UTF-8 text ({kind}) file") from None



"""Reading and writing whole files safely: the one atomic writer every output goes through (pulse,
label, priors, TDC and leaderboard files), and whole-file reads that fail with one line.

Every output is written to a temporary file in the target's directory, synced, and renamed over the
target only when complete: an error, a full disk or an interrupt never leaves a half-written file nor
clobbers a good one, and the error names the file (`cannot write out.csv: No space left on device`).
`write_all` publishes several files together: all are written before any is renamed, so a failure
changes none of them.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path
from typing import Iterator, Sequence, TextIO

from deint_env.errors import DeintError

PathLike = str | os.PathLike
# The largest array an input file may declare (checked against its declared shape and item size before
# anything is allocated): a few-kilobyte compressed file can otherwise ask for tens of GiB.
MAX_ARRAY_BYTES = 1 << 30


def check_array_size(shape: tuple[int, ...], itemsize: int, what: str) -> None:
    """Refuse an array whose declared size exceeds MAX_ARRAY_BYTES (one line saying the limit)."""
    n = 1
    for d in shape:
        n *= int(d)
    if n * itemsize > MAX_ARRAY_BYTES:
        raise DeintError(f"{what} declares shape {tuple(int(d) for d in shape)} ({n * itemsize / 2**30:.3g} GiB); "
                         f"the limit is {MAX_ARRAY_BYTES / 2**30:g} GiB per array")


def _cannot_write(path: PathLike, e: OSError) -> DeintError:
    return DeintError(f"cannot write {path}: {e.strerror or e}")


def short_name(name: str, limit: int = 200) -> str:
    """`name` cut to at most `limit` bytes, for the names of files kept beside it (a temporary file, a
    lock): with their prefix and suffix they must stay within the file system's 255 bytes a name."""
    raw = os.fsencode(name)
    return name if len(raw) <= limit else os.fsdecode(raw[:limit])


def _temporary(path: Path) -> Path:
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{short_name(path.name)}.", suffix=".tmp")
    except OSError as e:
        raise _cannot_write(path, e) from None
    os.close(fd)
    return Path(tmp)


def _finish(tmp: Path, path: Path) -> None:
    """Sync a written temporary file and give it the mode a plain open() would (mkstemp makes 0600)."""
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    os.chmod(tmp, _file_mode(path))


def check_output(path: PathLike) -> None:
    """Refuse an output path that exists as anything but a regular file: renaming over a device node,
    a FIFO or a symbolic link would replace it (as root, `-o /dev/null` would replace /dev/null)."""
    if not os.fspath(path):  # pathlib reads '' as '.', the current directory
        raise DeintError("cannot write '': the path is empty; give a file name")
    if os.fspath(path).endswith(os.sep):  # pathlib would drop the slash and write `out.csv` for `out.csv/`
        raise DeintError(f"cannot write {path}: it names a directory (a trailing {os.sep}); give a file name")
    if os.sep in os.fspath(path) and os.path.basename(os.fspath(path)) in (".", ".."):  # `out.csv/.` too
        raise DeintError(f"cannot write {path}: it names a directory (a last part . or ..); give a file name")
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise _cannot_write(path, e) from None
    if not stat.S_ISREG(mode):
        kind = ("a symbolic link" if stat.S_ISLNK(mode) else "a directory" if stat.S_ISDIR(mode) else
                "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else
                "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
        raise DeintError(f"cannot write {path}: it is {kind}; outputs are written only to regular files (new or "
                         f"existing)")
    if not mode & 0o222:  # renaming over it would replace a file its owner made read-only (as root, too)
        raise DeintError(f"cannot write {path}: it is read-only (mode {stat.S_IMODE(mode):04o}); make it writable "
                         f"or write elsewhere")


@contextlib.contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """A temporary path beside `path` to write to (for writers that open files themselves, e.g. h5py);
    it replaces `path` only if the block succeeds, and is removed otherwise."""
    path = Path(path)
    check_output(path)
    tmp = _temporary(path)
    try:
        yield tmp
        _finish(tmp, path)
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise _cannot_write(path, e) from None
        raise


def write_all(files: Sequence[tuple[PathLike, str | bytes]]) -> None:
    """Write every (path, text or bytes) together: each to a temporary file beside its target, then all
    renamed over their targets; if any write fails, no target changes and the error names its file."""
    for current, _ in files:  # every target checked before anything is written
        check_output(current)
    temps: list[tuple[Path, Path]] = []
    current: PathLike = ""
    try:
        for current, data in files:
            path = Path(current)
            temps.append((_temporary(path), path))
            if isinstance(data, str):
                with open(temps[-1][0], "w", encoding="utf-8", newline="") as f:
                    f.write(data)
            else:
                temps[-1][0].write_bytes(data)
            _finish(*temps[-1])
        while temps:
            tmp, current = temps[0]
            os.replace(tmp, current)
            temps.pop(0)
    except BaseException as e:
        for tmp, _ in temps:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if isinstance(e, OSError):
            raise _cannot_write(current, e) from None
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
    write_all([(path, text)])


def write_bytes(path: PathLike, data: bytes) -> None:
    write_all([(path, data)])


def read_bytes(path: PathLike, kind: str) -> bytes:
    """A file's bytes, every failure one line naming the file (`kind`: what the file should be)."""
    path = Path(path)
    try:
        # A device or FIFO (/dev/zero, a pipe) has no end to read to (and opening a FIFO waits for a
        # writer), so it is refused before it is opened: only regular files are inputs.
        if not stat.S_ISREG(os.stat(path).st_mode) and not path.is_dir():
            raise DeintError(f"{path}: is not a regular file; a {kind} file is read only from a regular file")
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



"""Pulse files and label files (CSV; docs/design.md section 7).

Pulse file: CSV with a header naming its columns, one pulse per line, sorted by TOA::

    toa,amplitude,source,sources
    12.5,1.02,0,0
    13.25,2.1,1,1|2

`toa` is required; `amplitude` is optional; `source` (the truth: the pulse's source, -1 = spurious)
makes it a truth file; `sources` (optional, written only when some pulse is merged) lists every
source merged into a pulse, joined by '|' (an empty cell means just `source`).

Label file: CSV `toa,label`, one line per pulse of the pulse file and in its order; label -1 means
spurious.  Inside the package the spurious label is `n_labels` (the env's action), so `write_labels`
takes env labels and `read_labels` returns file labels; `from_file_labels` maps them back.

Floats are written with `repr` (the shortest string that reads back to the same float64), so round
trips are exact.  Files are written through `files.write_text` (atomic).  Every problem with an input is one
`DeintError` line naming the file, the line and what is allowed.
"""

from __future__ import annotations

import csv
import io
import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deint_env.episode import Episode, Priors
from deint_env.errors import MAX_SHOWN, DeintError, shown
from deint_env.formats.files import PathLike, read_text, write_text
from deint_env.labels import source_bits
from deint_env.scenario import MAX_MERGING_SOURCES, MAX_SOURCES

PULSE_COLUMNS = ("toa", "amplitude", "source", "sources")
LABEL_COLUMNS = ("toa", "label")
MAX_LABEL = 4095  # a sanity bound for label files read without a known label count


def _split(path: Path, text: str) -> tuple[list[str], list[str], list[int]]:
    """(header cells, every data cell row after row, each data row's cell count).

    Plain files are split with str methods, several times faster than the csv module on 10^6 rows;
    files with quotes go through the csv module, which unquotes them.
    """
    if '"' in text:
        reader = csv.reader(io.StringIO(text, newline=""), strict=True)
        rows = []
        try:
            for row in reader:
                rows.append(row)
                if reader.line_num > len(rows):  # a quoted cell ran over a line break ('"1\n5"' would read as 15)
                    raise DeintError(f"{path}: line {len(rows)}: a quoted cell spans several lines; each line of "
                                     f"the file is one row")
        except csv.Error as e:
            raise DeintError(f"{path}: line {reader.line_num}: {e}") from None
        while rows and not any(c.strip() for c in rows[-1]):  # trailing blank lines
            rows.pop()
        if not rows:
            return [], [], []
        return rows[0], list(itertools.chain.from_iterable(rows[1:])), list(map(len, rows[1:]))
    lines = (text.replace("\r\n", "\n") if "\r" in text else text).split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        return [], [], []
    data = lines[1:]
    widths = [c + 1 for c in map(str.count, data, itertools.repeat(","))]
    return lines[0].split(","), ",".join(data).split(",") if data else [], widths


def _table(path: Path, allowed: tuple[str, ...], what: str) -> tuple[list[str], list[list[str]], int]:
    """(column names, the cells of each column, number of data rows), the header checked.
    Data row i is on line i + 2."""
    header, cells, widths = _split(path, read_text(path, "CSV"))
    header = [h.strip() for h in header]
    example = ",".join(allowed)
    if not header:
        raise DeintError(f"{path}: the file is empty; a {what} starts with a header line such as '{example}'")
    if not any(header):
        raise DeintError(f"{path}: line 1: is empty; the first line must be the header ('{example}')")
    if "toa" not in header:
        if _is_number(header[0]):
            raise DeintError(f"{path}: line 1: the header is missing; the first line must name the columns "
                             f"(allowed: {', '.join(allowed)}; 'toa' is required)")
        raise DeintError(f"{path}: line 1: no 'toa' column (columns found: {shown(header)}); "
                         f"allowed: {', '.join(allowed)}")
    for name in header:
        if name not in allowed:
            raise DeintError(f"{path}: line 1: column {shown(name)} is unknown; allowed: {', '.join(allowed)}")
        if header.count(name) > 1:
            raise DeintError(f"{path}: line 1: column {name!r} appears twice")
    n, width = len(widths), len(header)
    if not n:
        raise DeintError(f"{path}: has a header but no {'pulses' if what == 'pulse file' else 'labels'}")
    bad = np.flatnonzero(np.array(widths) != width)
    if bad.size:
        i, off = int(bad[0]), sum(widths[:int(bad[0])])
        k = widths[i]
        got = "is empty" if k == 0 or (k == 1 and not cells[off].strip()) else f"has {k} field{'s' * (k != 1)}"
        raise DeintError(f"{path}: line {i + 2}: {got}; every line needs the header's {width} fields "
                         f"({','.join(header)})")
    return header, [cells[j::width] for j in range(width)], n


def _is_number(text: str) -> bool:
    """Whether numpy parses `text` as a float (the rule the fast column parse applies)."""
    try:
        np.array([text], dtype=np.float64)
    except ValueError:
        return False
    return True


def _check_plain(path: Path, name: str, cells: list[str], allowed: str) -> None:
    """Refuse cells that numpy reads as numbers but no decimal number spells: digit separators ('1_0'
    reads as 10) and non-ASCII digits ('١')."""
    joined = "".join(cells)
    if joined.isascii() and "_" not in joined:
        return
    i = next(i for i, c in enumerate(cells) if not c.isascii() or "_" in c)
    raise DeintError(f"{path}: line {i + 2}: {name}={shown(cells[i].strip())} is not a decimal number; {allowed}")


def _floats(path: Path, name: str, cells: list[str]) -> np.ndarray:
    """A column of finite floats."""
    _check_plain(path, name, cells, f"{name} must be a finite decimal number")
    try:
        values = np.array(cells, dtype=np.float64)
    except ValueError:
        i = next(i for i, c in enumerate(cells) if not _is_number(c))
        got = f"{name}={shown(cells[i].strip())} is not a number" if cells[i].strip() else f"{name} is empty"
        raise DeintError(f"{path}: line {i + 2}: {got}; {name} must be a finite decimal number") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        raise DeintError(f"{path}: line {i + 2}: {name}={cells[i].strip()[:MAX_SHOWN]} is not finite; "
                         f"{name} must be a finite decimal number")
    return values


def _ints(path: Path, name: str, cells: list[str], lo: int, hi: int, meaning: str) -> np.ndarray:
    """A column of integers in [lo, hi] ('2.0' is accepted as 2)."""
    allowed = f"{name} must be an integer in [{lo}, {hi}]{meaning}"
    _check_plain(path, name, cells, allowed)
    try:
        values = np.array(cells, dtype=np.float64)
    except ValueError:
        values = None
    ok = None if values is None else (np.isfinite(values) & (values == np.round(values))
                                      & (values >= lo) & (values <= hi))
    if ok is None or not ok.all():
        i = next(i for i, c in enumerate(cells) if not _is_number(c)) if ok is None else int(np.flatnonzero(~ok)[0])
        raise DeintError(f"{path}: line {i + 2}: {name}={shown(cells[i].strip())} is invalid; {allowed}")
    return values.astype(np.int64)


def _check_sorted(path: Path, toa: np.ndarray) -> None:
    bad = np.flatnonzero(toa[1:] < toa[:-1])  # not np.diff: -1.7e308 to 1.7e308 overflows with a warning
    if bad.size:
        i = int(bad[0]) + 1
        raise DeintError(f"{path}: line {i + 2}: toa={float(toa[i])!r} is smaller than the previous line's toa="
                         f"{float(toa[i - 1])!r}; pulses must be sorted by increasing toa")


# ---------------------------------------------------------------------------------------------------
# pulse files
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PulseTable:
    """The columns of a pulse file.  source (int32, -1 = spurious) and mask (uint64 bits of every
    merged source) are None unless the file has a `source` column.  frequency, pulse_width, aoa: the
    pulse descriptors of a challenge file that has them (CSV pulse files hold none)."""

    toa: np.ndarray
    amplitude: np.ndarray | None
    source: np.ndarray | None
    mask: np.ndarray | None
    frequency: np.ndarray | None = None
    pulse_width: np.ndarray | None = None
    aoa: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.toa.size)

    @property
    def n_sources(self) -> int:
        """The number of true sources the truth names (0 without truth)."""
        if self.mask is None or not self.mask.size:
            return 0
        return max(int(np.bitwise_or.reduce(self.mask)).bit_length(), int(self.source.max()) + 1)


def format_pulses(episode: Episode, truth: bool = True) -> str:
    """The text of a pulse file for `episode` (with the `source` truth columns when `truth`)."""
    if not isinstance(episode, Episode):
        raise DeintError(f"episode={shown(episode)} is invalid: an Episode (deint_env.simulate gives one)")
    cols, header = [list(map(repr, episode.toa.tolist()))], ["toa"]
    if episode.amplitude is not None:
        cols.append(list(map(repr, episode.amplitude.tolist())))
        header.append("amplitude")
    if truth:
        source = episode.source.tolist()
        cols.append(list(map(str, source)))
        header.append("source")
        mask = episode.mask
        merged = np.flatnonzero(np.bitwise_and(mask, mask - np.uint64(1)) != 0)
        if merged.size:
            cells = list(cols[-1])
            for j in merged.tolist():
                bits = int(mask[j])
                cells[j] = "|".join(str(i) for i in range(bits.bit_length()) if bits >> i & 1)
            cols.append(cells)
            header.append("sources")
    return ",".join(header) + "\n" + "".join(f"{row}\n" for row in map(",".join, zip(*cols)))


def write_pulses(path: PathLike, episode: Episode, truth: bool = True) -> None:
    write_text(path, format_pulses(episode, truth))


def read_pulse_table(path: PathLike) -> PulseTable:
    path = Path(path)
    header, cols, n = _table(path, PULSE_COLUMNS, "pulse file")
    col = dict(zip(header, cols))
    toa = _floats(path, "toa", col["toa"])
    _check_sorted(path, toa)
    amplitude = _floats(path, "amplitude", col["amplitude"]) if "amplitude" in col else None
    if "source" not in col:
        if "sources" in col:
            raise DeintError(f"{path}: line 1: a 'sources' column needs a 'source' column (the primary source)")
        return PulseTable(toa, amplitude, None, None)
    source = _ints(path, "source", col["source"], -1, MAX_SOURCES - 1, " (-1 = spurious)")
    mask = source_bits(source)
    if "sources" in col:
        _merge_sources(path, col["sources"], col["source"], source, mask)
    return PulseTable(toa, amplitude, source.astype(np.int32), mask)


def _merge_sources(path: Path, cells: list[str], source_cells: list[str], source: np.ndarray,
                   mask: np.ndarray) -> None:
    """Fill `mask` from the `sources` column ('0|2'; empty = just `source`)."""
    # Most cells repeat the source cell; only the others (merged pulses, say) need parsing.
    same = np.fromiter(map(str.__eq__, cells, source_cells), dtype=bool, count=len(cells))
    src = source.tolist()
    for i in np.flatnonzero(~same).tolist():
        cell = cells[i].strip()
        if not cell:
            continue
        try:  # int() would also read '1_0' as 10 and non-ASCII digits
            members = [int(m) for m in cell.split("|")] if cell.isascii() and "_" not in cell else None
        except ValueError:
            members = None
        if members == [src[i]]:
            continue
        where = f"{path}: line {i + 2}: sources={shown(cell)}"
        if members is None or any(not 0 <= m < MAX_MERGING_SOURCES for m in members):
            raise DeintError(f"{where} is invalid; allowed: source numbers in [0, {MAX_MERGING_SOURCES - 1}] "
                             f"joined by '|' (e.g. 0|2), -1 for a spurious pulse, or empty")
        if len(set(members)) < len(members):  # '0|0': a source merged with itself is a typo, not a merge
            raise DeintError(f"{where} names a source twice; sources lists each merged source once")
        if src[i] not in members:
            raise DeintError(f"{where} does not include the line's source={src[i]}; sources lists every source "
                             f"merged into the pulse, the primary one included")
        bits = 0
        for m in members:
            bits |= 1 << m
        mask[i] = bits


def read_pulses(path: PathLike, priors: Priors) -> Episode:
    """A pulse file as an `Episode` for `priors` (truth None; source/mask zero without a source column)."""
    if not isinstance(priors, Priors):
        raise DeintError(f"priors={shown(priors)} is invalid: a Priors (formats.read_priors(PATH) reads one)")
    t = read_pulse_table(path)
    n = len(t)
    return Episode(scenario=Path(path).name, seed=0, toa=t.toa, amplitude=t.amplitude,
                   source=t.source if t.source is not None else np.zeros(n, dtype=np.int32),
                   mask=t.mask if t.mask is not None else np.zeros(n, dtype=np.uint64),
                   truth=None, priors=priors)


# ---------------------------------------------------------------------------------------------------
# label files
# ---------------------------------------------------------------------------------------------------
def to_file_labels(labels: np.ndarray, n_labels: int) -> np.ndarray:
    """Env labels (spurious = n_labels) -> file labels (spurious = -1)."""
    labels = np.asarray(labels, dtype=np.int64)
    return np.where(labels == n_labels, -1, labels)


def from_file_labels(labels: np.ndarray, n_labels: int) -> np.ndarray:
    """File labels (spurious = -1) -> env labels (spurious = n_labels)."""
    labels = np.asarray(labels, dtype=np.int64)
    return np.where(labels < 0, n_labels, labels)


def format_labels(toa: np.ndarray, labels: np.ndarray, n_labels: int) -> str:
    toa = np.asarray(toa, dtype=np.float64)
    if not np.isfinite(toa).all():  # the reader refuses such a file: never write one
        bad = toa[~np.isfinite(toa)][0]
        raise DeintError(f"toa={float(bad)!r} is not finite; a label file's TOAs are finite numbers")
    labels = np.asarray(labels, dtype=np.int64)
    if labels.shape != toa.shape or (labels.size and not 0 <= labels.min() <= labels.max() <= n_labels):
        raise DeintError(f"{labels.size} labels for {toa.size} pulses, or a label outside [0, {n_labels}]")
    rows = zip(map(repr, toa.tolist()), map(str, to_file_labels(labels, n_labels).tolist()))
    return "toa,label\n" + "".join(f"{t},{lab}\n" for t, lab in rows)


def write_labels(path: PathLike, toa: np.ndarray, labels: np.ndarray, n_labels: int) -> None:
    """Write env labels (0..n_labels, n_labels = spurious) as a `toa,label` file (-1 = spurious)."""
    write_text(path, format_labels(toa, labels, n_labels))


def read_labels(path: PathLike, toa: np.ndarray | None = None, n_labels: int | None = None,
                pulses: PathLike = "the pulse file") -> np.ndarray:
    """The labels of a `toa,label` file, as in the file (-1 = spurious).

    With `toa` (the pulse file's, named `pulses` in messages) the file must have one line per pulse
    with the same TOAs; with `n_labels` every label must lie in [-1, n_labels - 1].
    """
    path = Path(path)
    if n_labels is not None and (isinstance(n_labels, bool) or not isinstance(n_labels, (int, np.integer))):
        raise DeintError(f"n_labels={n_labels!r} is invalid: an integer, the labels other than spurious (or None)")
    header, cols, n = _table(path, LABEL_COLUMNS, "label file")
    col = dict(zip(header, cols))
    if "label" not in col:
        raise DeintError(f"{path}: line 1: no 'label' column; a label file has the columns toa,label")
    hi = MAX_LABEL if n_labels is None else n_labels - 1
    labels = _ints(path, "label", col["label"], -1, hi, " (-1 = spurious)")
    file_toa = _floats(path, "toa", col["toa"])
    if toa is not None:
        if n != toa.size:
            raise DeintError(f"{path}: has {n} labels but {pulses} has {toa.size} pulses; "
                             f"a label file needs one line per pulse")
        # TOAs are written with repr, so they match exactly; the tolerance forgives other writers' rounding.
        tol = 1e-12 * max(1.0, float(np.max(np.abs(toa))))
        bad = np.flatnonzero(np.abs(file_toa - toa) > tol)
        if bad.size:
            i = int(bad[0])
            raise DeintError(f"{path}: line {i + 2}: toa={float(file_toa[i])!r} differs from the toa on line {i + 2} of {pulses} "
                             f"({float(toa[i])!r}); labels must follow the pulse file line by line")
    else:
        _check_sorted(path, file_toa)
    return labels

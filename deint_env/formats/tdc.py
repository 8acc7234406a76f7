"""Turing Deinterleaving Challenge (TDC) HDF5 pulse-train files: reading, writing and converting
them to and from our CSV pulse files.  The challenge's scores are in `deint_env.tdc_scores`, its
models run as policies through `baselines.tdc_adapter` (policy `tdc`).

The file format
---------------
As the challenge's own package saves and loads a `PulseTrain` (alan-turing-institute/
turing-deinterleaving-challenge, `data/structure.py`; read through `data/dataset.py`), one pulse train
is one HDF5 file holding:

=========================  ==============================================================================
``data``                   dataset, shape (seq_len, n_features), float32 (gzip level 9): one row per
                           pulse (a pulse descriptor word), one column per feature
``labels``                 dataset, shape (seq_len,), int8 (gzip level 9): the emitter id of each pulse;
                           optional (their loader expects it; their slicing and scoring code squeezes
                           and flattens it, so (seq_len, 1) is read too)
``metadata/``              group: the `PulseTrainMetadata` fields
``metadata/feature_names`` dataset of fixed-length byte strings (numpy ``S``): the name of each column
``metadata`` attributes    ``type`` ("real", "synthetic" or "hybrid"), and when set ``description``,
                           ``collection_time_s``, ``num_pulses``, ``date_created`` (ISO 8601); receiver and
                           transmitter parameters are sub-groups (``transmitters/item_0``, ...)
=========================  ==============================================================================

The TSRD pulse descriptor words are time of arrival (microseconds), centre frequency, pulse width, angle
of arrival and amplitude, in that column order (their plotting helpers index them 0..4).  Which spelling
of a feature name a file uses is not fixed by their code, so names are matched after normalising
(case, spaces/hyphens -> '_', a trailing unit such as "(us)" dropped) against these aliases (their
plotting helper's spellings included):

===================  ===========================================================================
``toa``              toa, time_of_arrival, t  -> our ``toa`` (required)
``frequency``        f, cf, freq, frequency, centre_frequency, center_frequency, rf
``pulse_width``      pw, pulse_width, pulsewidth
``angle_of_arrival`` aoa, angle_of_arrival, doa, direction_of_arrival
``amplitude``        a, amp, amplitude, power, pulse_amplitude -> our ``amplitude``
===================  ===========================================================================

Any other name is rejected (one line naming it), as are a missing dataset, a shape mismatch, an empty
train, non-finite values in any column and TOAs that decrease.  TOAs keep the file's units (TDC: us).

Labels and noise.  TDC labels are emitter ids with no order and no priors, so TDC files are scored as
blind (clustering) problems; the challenge's primary metric is the V-measure.  A negative label (the
TDC models' ``default_label`` convention, -1 as HDBSCAN writes it) is read as "belongs to no emitter",
which is our spurious label (-1 in our files).  `TDCTrain.pulse_table` numbers the emitters 0..K-1 in
increasing id order (at most 128, `scenario.MAX_SOURCES`; more is still scored by the clustering
metrics, see `score_labels`).  Its frequency, pulse_width and angle_of_arrival columns become the
episode's `frequency`, `pulse_width` and `aoa` arrays (`TDCTrain.episode`), and an episode's arrays
are written back under those names (`train_from_episode`); a file's other units are kept as they are.
`gym.make("deint_env/Deinterleave-v0", scenario="tdc:PATH")` plays a labelled file as one blind episode.

Choices where the TDC format leaves room (all documented here):
- we write ``data`` as float32 (their dtype) by default; ``dtype="float64"`` keeps float64 TOAs exact
  (their loader reads either);
- we write ``labels`` as int8 of shape (seq_len,) with -1 for spurious pulses; an id outside int8 is an
  error;
- feature names we write: time_of_arrival, frequency, pulse_width, angle_of_arrival, amplitude (the
  ones present, in that order); metadata attributes ``type`` ("synthetic"), ``num_pulses`` and
  ``description``; no ``date_created`` and no HDF5 timestamps, so the same content gives the same bytes;
- a merged pulse keeps only its primary source (TDC has one label per pulse).
"""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError
from deint_env.formats import pulse_csv
from deint_env.formats.files import PathLike, atomic_path, check_array_size, write_text
from deint_env.labels import source_bits
from deint_env.scenario import MAX_SOURCES

SUFFIXES = (".h5", ".hdf5")

# Our canonical feature names, in the TDC column order, with the spellings read for each.
FEATURES: dict[str, tuple[str, ...]] = {
    "toa": ("toa", "time_of_arrival", "t"),
    "frequency": ("f", "cf", "freq", "frequency", "centre_frequency", "center_frequency", "rf"),
    "pulse_width": ("pw", "pulse_width", "pulsewidth"),
    "angle_of_arrival": ("aoa", "angle_of_arrival", "doa", "direction_of_arrival"),
    "amplitude": ("a", "amp", "amplitude", "power", "pulse_amplitude"),
}
WRITTEN_NAMES = {"toa": "time_of_arrival", "frequency": "frequency", "pulse_width": "pulse_width",
                 "angle_of_arrival": "angle_of_arrival", "amplitude": "amplitude"}
_ALIAS = {alias: canon for canon, aliases in FEATURES.items() for alias in aliases}
# Our feature columns beside toa and amplitude, by the `Episode` array that holds each.
EPISODE_DESCRIPTORS = {"frequency": "frequency", "pulse_width": "pulse_width", "angle_of_arrival": "aoa"}
INT8 = (-128, 127)


def is_tdc_path(path: PathLike | None) -> bool:
    """Whether a path names an HDF5 (TDC) file, by its suffix."""
    return path is not None and Path(path).suffix.lower() in SUFFIXES


def _h5py():
    try:
        import h5py
    except ImportError:
        raise DeintError("TDC (HDF5) files need h5py: pip install 'deint-bench[tdc]'") from None
    return h5py


def canonical_feature(name: str) -> str | None:
    """Our name for a TDC feature name ('Time of Arrival (us)' -> 'toa'), or None if unknown."""
    key = re.sub(r"[\s\-]+", "_", _without_unit(str(name)).strip().lower())
    return _ALIAS.get(key)


def _without_unit(name: str) -> str:
    """`name` less a trailing bracketed unit ('Time of Arrival (us)' -> 'Time of Arrival'): the group
    from the first opening bracket after the last earlier closing one.  In linear time: the regex it
    replaces (any space, an opening bracket, no closing one, a closing bracket, the end) retried every
    opening bracket to the end of the name (a 40 KB name: 24 s)."""
    s = name.rstrip()
    if not s.endswith((")", "]")):
        return name
    body = s[:-1]
    after = max(body.rfind(")"), body.rfind("]")) + 1
    opens = [i for i in (body.find("(", after), body.find("[", after)) if i >= 0]
    return s[:min(opens)] if opens else name


def _allowed_names() -> str:
    return "; ".join(f"{canon}: {', '.join(a)}" for canon, a in FEATURES.items())


# ---------------------------------------------------------------------------------------------------
# one pulse train
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class TDCTrain:
    """One TDC pulse train: the ``data`` matrix with its feature names, the ``labels`` (emitter ids as
    in the file, int64; None without labels) and the ``metadata`` attributes."""

    data: np.ndarray
    feature_names: tuple[str, ...]
    labels: np.ndarray | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    columns: tuple[str, ...] = ()  # our name of each column (filled by `validated`)

    def __len__(self) -> int:
        return int(self.data.shape[0])

    def column(self, name: str) -> np.ndarray | None:
        """A feature column as float64 by our name, or None if the train has no such column."""
        return self.data[:, self.columns.index(name)].astype(np.float64) if name in self.columns else None

    @property
    def toa(self) -> np.ndarray:
        return self.column("toa")

    @property
    def amplitude(self) -> np.ndarray | None:
        return self.column("amplitude")

    @property
    def features(self) -> dict[str, np.ndarray]:
        """The columns other than toa and amplitude (frequency, pulse_width, angle_of_arrival)."""
        return {c: self.column(c) for c in self.columns if c not in ("toa", "amplitude")}

    @property
    def emitters(self) -> np.ndarray:
        """The distinct emitter ids (noise, any negative id, excluded), increasing."""
        if self.labels is None:
            return np.zeros(0, dtype=np.int64)
        return np.unique(self.labels[self.labels >= 0])

    def source(self) -> np.ndarray:
        """Our source column: emitters numbered 0..K-1 in increasing id order, -1 for noise."""
        if self.labels is None:
            raise DeintError("this TDC train has no labels")
        out = np.full(len(self), -1, dtype=np.int32)
        real = self.labels >= 0
        out[real] = np.searchsorted(self.emitters, self.labels[real])
        return out

    def descriptors(self) -> dict[str, np.ndarray]:
        """The pulse descriptor columns it has, by `Episode` array name (frequency, pulse_width, aoa)."""
        return {ours: self.column(col) for col, ours in EPISODE_DESCRIPTORS.items() if col in self.columns}

    def pulse_table(self, where: str = "the TDC file") -> pulse_csv.PulseTable:
        """The train as our `PulseTable` (with truth when it has labels, and its descriptor columns)."""
        if self.labels is None:
            return pulse_csv.PulseTable(self.toa, self.amplitude, None, None, **self.descriptors())
        k = self.emitters.size
        if k > MAX_SOURCES:
            raise DeintError(f"{where}: has {k} emitters; a truth table holds at most {MAX_SOURCES} sources")
        source = self.source()
        return pulse_csv.PulseTable(self.toa, self.amplitude, source, source_bits(source), **self.descriptors())

    def episode(self, priors: Priors, name: str = "tdc") -> Episode:
        """The train as an `Episode` to play with `priors` (truth None; the source columns are the
        labels when the file has them, else zeros, as `pulse_csv.read_pulses` does; its descriptor
        columns as the episode's)."""
        n = len(self)
        if self.labels is not None and self.emitters.size <= MAX_SOURCES:
            t = self.pulse_table()
            source, mask = t.source, t.mask
        else:
            source, mask = np.zeros(n, dtype=np.int32), np.zeros(n, dtype=np.uint64)
        return Episode(scenario=name, seed=0, toa=self.toa, amplitude=self.amplitude, source=source, mask=mask,
                       truth=None, priors=priors, **self.descriptors())

    def model_input(self) -> np.ndarray:
        """What a TDC model is given for this train: the data matrix as float32, columns as in the file."""
        return np.asarray(self.data, dtype=np.float32)

    # ---- construction and checks ---------------------------------------------------------------
    @classmethod
    def from_columns(cls, toa: np.ndarray, amplitude: np.ndarray | None = None, labels: np.ndarray | None = None,
                     features: dict[str, np.ndarray] | None = None, description: str | None = None) -> TDCTrain:
        """A train from our columns: toa, optional amplitude, emitter labels (-1 = spurious) and other
        features by name (any alias of frequency, pulse_width, angle_of_arrival)."""
        cols: dict[str, np.ndarray] = {"toa": np.asarray(toa, dtype=np.float64)}
        if amplitude is not None:
            cols["amplitude"] = np.asarray(amplitude, dtype=np.float64)
        for name, values in (features or {}).items():
            canon = canonical_feature(name)
            if canon is None:
                raise DeintError(f"feature {name!r} is unknown; TDC features are {_allowed_names()}")
            if canon in cols:
                raise DeintError(f"feature {name!r} is given twice (as {canon})")
            cols[canon] = np.asarray(values, dtype=np.float64)
        order = [c for c in FEATURES if c in cols]
        n = cols["toa"].size
        for c in order:
            if cols[c].shape != (n,):
                raise DeintError(f"feature {c} has shape {cols[c].shape}; every column needs ({n},) like toa")
        data = np.stack([cols[c] for c in order], axis=1) if n else np.zeros((0, len(order)))
        meta: dict[str, Any] = {"type": "synthetic", "num_pulses": int(n)}
        if description:
            meta["description"] = description
        lab = None if labels is None else np.asarray(labels)
        return cls(data, tuple(WRITTEN_NAMES[c] for c in order), lab, meta).validated("the TDC train")

    def validated(self, where: str) -> TDCTrain:
        """This train checked (shapes, names, finite sorted TOAs, integer labels), columns filled in."""
        data = self.data
        if data.ndim != 2:
            raise DeintError(f"{where}: data has shape {data.shape}; TDC data is 2-D (seq_len, n_features)")
        if data.dtype.kind not in "fiu":
            raise DeintError(f"{where}: data has dtype {data.dtype}; TDC data is numeric (float32)")
        n, width = data.shape
        names = tuple(self.feature_names)
        if len(names) != width:
            raise DeintError(f"{where}: metadata/feature_names has {len(names)} names but data has {width} columns")
        columns = []
        for i, name in enumerate(names):
            canon = canonical_feature(name)
            if canon is None:
                raise DeintError(f"{where}: feature name {name!r} (column {i}) is unknown; allowed: {_allowed_names()}")
            if canon in columns:
                raise DeintError(f"{where}: feature name {name!r} (column {i}) names {canon} a second time")
            columns.append(canon)
        if "toa" not in columns:
            raise DeintError(f"{where}: no time-of-arrival column among the feature names {list(names)}; "
                             f"one must be named {' or '.join(FEATURES['toa'])}")
        if n == 0:
            raise DeintError(f"{where}: data has no pulses")
        bad = np.argwhere(~np.isfinite(data))
        if bad.size:
            i, j = map(int, bad[0])
            raise DeintError(f"{where}: data[{i}, {j}] ({names[j]}) = {data[i, j]} is not finite; "
                             f"TDC data must be finite numbers")
        t = columns.index("toa")
        down = np.flatnonzero(np.diff(data[:, t]) < 0)
        if down.size:
            i = int(down[0]) + 1
            raise DeintError(f"{where}: data[{i}, {t}] ({names[t]}) = {float(data[i, t])!r} is smaller than "
                             f"data[{i - 1}, {t}] = {float(data[i - 1, t])!r}; pulses must be sorted by increasing "
                             f"time of arrival")
        labels = self.labels
        if labels is not None:
            labels = np.asarray(labels)
            if labels.shape not in ((n,), (n, 1)):
                raise DeintError(f"{where}: labels has shape {labels.shape} but data has {n} rows; "
                                 f"labels needs shape ({n},)")
            labels = labels.reshape(n)
            if labels.dtype.kind == "f":
                ok = np.isfinite(labels) & (labels == np.round(labels))
                if not ok.all():
                    i = int(np.flatnonzero(~ok)[0])
                    raise DeintError(f"{where}: labels[{i}] = {labels[i]} is not an integer emitter id")
            elif labels.dtype.kind not in "iu":
                raise DeintError(f"{where}: labels has dtype {labels.dtype}; TDC labels are integers (int8)")
            big = np.flatnonzero(labels > np.iinfo(np.int64).max if labels.dtype.kind == "u" else
                                 (labels >= 2.0**63) | (labels < -2.0**63) if labels.dtype.kind == "f" else 0)
            if big.size:  # as int64 it would wrap round, a real emitter read as noise (a negative id)
                i = int(big[0])
                raise DeintError(f"{where}: labels[{i}] = {labels[i]} is invalid; emitter ids are integers in "
                                 f"[-2^63, 2^63) (TDC's are int8; negative: noise)")
            labels = labels.astype(np.int64)
        return TDCTrain(data, names, labels, dict(self.metadata), tuple(columns))

    # ---- writing -----------------------------------------------------------------------------------
    def write(self, path: PathLike, dtype: str = "float32") -> None:
        """Write the train as a TDC file (atomically: a temporary file renamed over `path`)."""
        _atomic_h5(Path(path), self._filler(str(path), dtype))

    def to_bytes(self, dtype: str = "float32", where: str = "the TDC train") -> bytes:
        """The TDC file's bytes (for `files.write_all`, which writes several outputs all or none)."""
        fill = self._filler(where, dtype)
        buffer = io.BytesIO()
        with _h5py().File(buffer, "w") as f:
            fill(f)
        return buffer.getvalue()

    def _filler(self, path: str, dtype: str) -> Callable[[Any], None]:
        """The train checked for writing as `dtype`, and the function that fills an open HDF5 file."""
        if dtype not in ("float32", "float64"):
            raise DeintError(f"dtype={dtype!r} is invalid: float32 (the TDC's) or float64")
        train = self.validated(str(path))
        data = np.asarray(train.data, dtype=dtype)
        recheck = TDCTrain(data, train.feature_names, train.labels, train.metadata)
        recheck.validated(f"{path} (as {dtype})")  # float32 rounding may not break the rules either
        labels = train.labels
        if labels is not None and labels.size and (labels.min() < INT8[0] or labels.max() > INT8[1]):
            bad = int(labels[(labels < INT8[0]) | (labels > INT8[1])][0])
            raise DeintError(f"{path}: label {bad} does not fit TDC's int8 labels (ids in [{INT8[0]}, {INT8[1]}])")
        names = np.array([n.encode("utf-8") for n in train.feature_names], dtype="S")
        meta = {**train.metadata, "num_pulses": len(train)}

        def fill(f) -> None:
            g = f.create_group("metadata", track_order=True)
            g.create_dataset("feature_names", data=names, track_times=False)
            for key in sorted(meta):
                g.attrs[key] = meta[key]
            f.create_dataset("data", data=data, dtype=dtype, compression="gzip", compression_opts=9,
                             track_times=False)
            if labels is not None:
                f.create_dataset("labels", data=labels.astype(np.int8), dtype=np.int8, compression="gzip",
                                 compression_opts=9, track_times=False)

        return fill


@contextlib.contextmanager
def _hdf5(path: Path) -> Iterator[Any]:
    h5py = _h5py()
    if not path.exists():
        raise DeintError(f"{path}: no such file")
    if path.is_dir():
        raise DeintError(f"{path}: is a directory, not a TDC (HDF5) file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise DeintError(f"{path}: is not a readable HDF5 file ({str(e).splitlines()[0]})") from None
    with f:
        yield f


def read_tdc(path: PathLike) -> TDCTrain:
    """Read and check a TDC pulse-train file; every problem is one `DeintError` line.  Only the objects
    a TDC file holds are opened, each through a hard link (external and soft links are refused, so no
    other file is opened and no link loop is followed), and every dataset's declared size is checked
    against `files.MAX_ARRAY_BYTES` before it is read."""
    h5py = _h5py()
    path = Path(path)
    with _hdf5(path) as f:
        data = _dataset(h5py, path, f, "data", "a TDC file holds data (seq_len x features), labels and "
                                               "metadata/feature_names")
        meta = _member(h5py, path, f, "metadata")
        if not isinstance(meta, h5py.Group):
            raise DeintError(f"{path}: no 'metadata' group; a TDC file names its data columns in "
                             f"metadata/feature_names")
        feature_names = _dataset(h5py, path, meta, "feature_names", "it names the data columns")
        raw = np.atleast_1d(_read(path, feature_names, "metadata/feature_names"))
        names = tuple(x.decode("utf-8", "replace") if isinstance(x, bytes) else str(x) for x in raw.tolist())
        values = _read(path, data, "data")
        labels = None
        if _member(h5py, path, f, "labels") is not None:
            labels = _read(path, _dataset(h5py, path, f, "labels", "it holds the emitter ids"), "labels")
        attrs = {k: _attribute(path, k, v) for k, v in meta.attrs.items()}
    if not isinstance(values, np.ndarray):
        raise DeintError(f"{path}: data is a scalar; TDC data is 2-D (seq_len, n_features)")
    return TDCTrain(values, names, labels, attrs).validated(str(path))


def _member(h5py, path: Path, group: Any, name: str) -> Any:
    """`group[name]` if it is there through a hard link, None if it is absent; other links are refused."""
    link = group.get(name, getlink=True)
    if link is None:
        return None
    where = f"{group.name.rstrip('/')}/{name}".lstrip("/")
    if isinstance(link, h5py.ExternalLink):
        raise DeintError(f"{path}: '{where}' is an external link (to {link.filename}:{link.path}); a TDC file "
                         f"must hold its data itself")
    if isinstance(link, h5py.SoftLink):
        raise DeintError(f"{path}: '{where}' is a soft link (to {link.path}); a TDC file's objects are "
                         f"stored under their own names")
    return group[name]


def _dataset(h5py, path: Path, group: Any, name: str, hint: str) -> Any:
    obj = _member(h5py, path, group, name)
    where = f"{group.name.rstrip('/')}/{name}".lstrip("/")
    if obj is None:
        raise DeintError(f"{path}: no '{where}' dataset; {hint}")
    if not isinstance(obj, h5py.Dataset):
        raise DeintError(f"{path}: '{where}' is a group; it must be a dataset ({hint})")
    if obj.is_virtual or obj.external:
        raise DeintError(f"{path}: '{where}' stores its data in other files (a virtual or external dataset); "
                         f"a TDC file must hold its data itself")
    return obj


# A compressed dataset may unpack to at most this many times its file's size (beyond a floor that any
# real train's labels fit in): gzip unpacks a run of zeros about 1000-fold, so a 9 KB file could declare
# 1 GiB (within MAX_ARRAY_BYTES) and cost 10 GB once converted and sorted, while pulse descriptors
# (float64 TOAs, frequencies, widths) compress at most a few-fold.
MAX_EXPANSION, EXPANSION_FLOOR = 64, 64 * 2**20


def _read(path: Path, dataset: Any, where: str) -> Any:
    """A dataset's values, its declared size checked first (against the limit per array, and against
    the file's own size for the expansion a compression bomb needs)."""
    check_array_size(dataset.shape or (), dataset.dtype.itemsize, f"{path}: '{where}'")
    declared = int(np.prod(dataset.shape or (), dtype=np.float64)) * dataset.dtype.itemsize
    size = path.stat().st_size
    if declared > max(EXPANSION_FLOOR, MAX_EXPANSION * size):
        raise DeintError(f"{path}: '{where}' declares {declared} bytes from a {size}-byte file; a dataset unpacks to "
                         f"at most {MAX_EXPANSION} times its file's size (beyond {EXPANSION_FLOOR >> 20} MiB)")
    try:
        return dataset[()]
    except (OSError, ValueError) as e:
        raise DeintError(f"{path}: '{where}' cannot be read ({str(e).splitlines()[0]})") from None


def _attribute(path: Path, key: str, v: Any) -> Any:
    """A metadata attribute as plain data, refused now if it could not be written back with the labels
    (a variable-length integer attribute failed only when the labels were written, after the work)."""
    if isinstance(v, np.ndarray) and v.dtype.kind == "O" and not all(isinstance(x, (str, bytes)) for x in v.flat):
        raise DeintError(f"{path}: metadata attribute {key!r} holds variable-length or object values; TDC metadata "
                         f"attributes are strings, numbers or arrays of them")
    return _plain(v)


def _plain(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def write_tdc(path: PathLike, toa: np.ndarray, amplitude: np.ndarray | None = None,
              labels: np.ndarray | None = None, features: dict[str, np.ndarray] | None = None, *,
              dtype: str = "float32", description: str | None = None) -> TDCTrain:
    """Write a TDC file from our columns (labels: emitter ids, -1 = spurious); returns what it wrote
    (read it back with `read_tdc`: equal data, names and labels)."""
    train = TDCTrain.from_columns(toa, amplitude, labels, features, description)
    train.write(path, dtype)
    return train


def _atomic_h5(path: Path, fill: Callable[[Any], None]) -> None:
    h5py = _h5py()
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        fill(f)


def episode_features(episode: Episode) -> dict[str, np.ndarray]:
    """An episode's descriptor arrays by TDC feature name (frequency, pulse_width, angle_of_arrival)."""
    return {col: getattr(episode, ours) for col, ours in EPISODE_DESCRIPTORS.items()
            if getattr(episode, ours) is not None}


def train_from_episode(episode: Episode, truth: bool = True) -> TDCTrain:
    """A simulated or loaded episode as a TDC train (every column it has; labels = primary source,
    -1 = spurious)."""
    return TDCTrain.from_columns(episode.toa, episode.amplitude, episode.source if truth else None,
                                 episode_features(episode),
                                 description=f"deint-bench episode {episode.scenario} seed {episode.seed}")


def read_label_ids(path: PathLike, toa: np.ndarray, pulses: PathLike) -> np.ndarray:
    """Predicted labels of a TDC file (its labels dataset), checked against the truth's TOAs."""
    train = read_tdc(path)
    if train.labels is None:
        raise DeintError(f"{path}: has no 'labels' dataset; a TDC label file holds the predicted emitter ids")
    if len(train) != toa.size:
        raise DeintError(f"{path}: has {len(train)} labels but {pulses} has {toa.size} pulses; a label file "
                         f"needs one label per pulse")
    own = train.toa
    tol = 1e-6 * max(1.0, float(np.max(np.abs(toa))))  # float32 files: a relative float32 tolerance
    bad = np.flatnonzero(np.abs(own - toa) > tol)
    if bad.size:
        i = int(bad[0])
        raise DeintError(f"{path}: pulse {i} has toa {float(own[i])!r} but {pulses} has {float(toa[i])!r}; "
                         f"labels must follow the pulse file pulse by pulse")
    return train.labels


def write_labels(path: PathLike, pulses: TDCTrain | Episode, labels: np.ndarray, n_labels: int,
                 description: str | None = None) -> None:
    """Predicted env labels (n_labels = spurious) as a TDC file: the pulses' own rows (a TDC train's
    data as read, or an episode's toa/amplitude in float64) with the labels (-1 = spurious)."""
    file_labels = pulse_csv.to_file_labels(labels, n_labels)
    if isinstance(pulses, TDCTrain):
        meta = {**pulses.metadata, **({"description": description} if description else {})}
        out = TDCTrain(pulses.data, pulses.feature_names, file_labels, meta)
        out.write(path, "float64" if pulses.data.dtype == np.float64 else "float32")
    else:
        TDCTrain.from_columns(pulses.toa, pulses.amplitude, file_labels, episode_features(pulses),
                              description=description).write(path, "float64")


def convert(src: PathLike, dst: PathLike, dtype: str = "float32") -> str:
    """Convert a pulse file between our CSV and a TDC HDF5 file (by suffix); returns a status line."""
    src, dst = Path(src), Path(dst)
    if is_tdc_path(src) == is_tdc_path(dst):
        raise DeintError(f"convert goes between a CSV pulse file and a TDC file (.h5/.hdf5): got {src} -> {dst}")
    if is_tdc_path(dst):
        t = pulse_csv.read_pulse_table(src)
        merged = 0 if t.mask is None else int(np.count_nonzero(np.bitwise_and(t.mask, t.mask - np.uint64(1))))
        train = TDCTrain.from_columns(t.toa, t.amplitude, t.source, description=f"converted from {src.name}")
        train.write(dst, dtype)
        moved = float(np.max(np.abs(train.toa.astype(dtype).astype(np.float64) - t.toa)))
        notes = [f"{len(train)} pulses, columns {', '.join(train.feature_names)}"
                 + (", labels" if t.source is not None else "")]
        if merged:
            notes.append(f"{merged} merged pulses keep their primary source only")
        if moved > 0:
            notes.append(f"TOAs rounded to {dtype} (by up to {moved:.3g}; --float64 keeps them exact)")
        return f"{src} -> {dst}: " + "; ".join(notes)
    train = read_tdc(src)
    if train.labels is not None and train.emitters.size > MAX_SOURCES:
        raise DeintError(f"{src}: has {train.emitters.size} emitters; a pulse file holds at most {MAX_SOURCES}")
    cols, header = [list(map(repr, train.toa.tolist()))], ["toa"]
    if train.amplitude is not None:
        cols.append(list(map(repr, train.amplitude.tolist())))
        header.append("amplitude")
    if train.labels is not None:
        cols.append(list(map(str, train.source().tolist())))
        header.append("source")
    write_text(dst, ",".join(header) + "\n" + "".join(f"{r}\n" for r in map(",".join, zip(*cols))))
    dropped = [n for n, c in zip(train.feature_names, train.columns) if c not in ("toa", "amplitude")]
    note = f"; dropped {', '.join(dropped)} (pulse files hold toa and amplitude)" if dropped else ""
    ids = f"; emitter ids {train.emitters.tolist()[:8]}{'...' if train.emitters.size > 8 else ''} -> sources 0.." \
          f"{train.emitters.size - 1}" if train.labels is not None and train.emitters.size else ""
    return f"{src} -> {dst}: {len(train)} pulses{ids}{note}"

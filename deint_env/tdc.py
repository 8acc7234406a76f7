"""Turing Deinterleaving Challenge (TDC) interoperability: its HDF5 pulse-train files, its
`Deinterleaver` models as blind-mode policies, and its metric set.

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
increasing id order (at most 64, the bit-mask limit of our truth tables; more is still scored by the
clustering metrics, see `score_labels`).

Choices where the TDC format leaves room (all documented here):
- we write ``data`` as float32 (their dtype) by default; ``dtype="float64"`` keeps float64 TOAs exact
  (their loader reads either);
- we write ``labels`` as int8 of shape (seq_len,) with -1 for spurious pulses; an id outside int8 is an
  error;
- feature names we write: time_of_arrival, frequency, pulse_width, angle_of_arrival, amplitude (the
  ones present, in that order); metadata attributes ``type`` ("synthetic"), ``num_pulses`` and
  ``description``; no ``date_created`` and no HDF5 timestamps, so the same content gives the same bytes;
- a merged pulse keeps only its primary source (TDC has one label per pulse).

Models
------
A TDC `Deinterleaver` (`models/model.py`) is a callable: an older version documents
``model(batch)`` with a (batch, seq_len, n_features) array returning (batch, seq_len) emitter ids; the
current one has a ``default_label`` attribute (the id it gives pulses it cannot associate, ignored in
scoring when it is a true label) and its evaluation calls ``model(train)`` on one (seq_len,
n_features) train.  `predict` supports both, duck-typed (this package never imports theirs): it calls
the model with a batch of one, and if that raises or gives the wrong shape, with the bare train.
`TDCDeinterleaver` (registered as policy ``tdc``, e.g. ``tdc:model=my.module:MyModel,window=500``)
runs such a model in our online protocol; see its docstring.

Metrics
-------
`tdc_scores` reproduces the challenge's `evaluate_labels` (`models/evaluate.py`): homogeneity,
completeness, V-measure, ARI and AMI from scikit-learn, the cluster-wise MCC and F1 (for each true
emitter the best score over predicted clusters, then the worst emitter), and the discount: with a
``default_label``, pulses whose *true* label is it are dropped and every score is multiplied by the
fraction kept.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import math
import os
import re
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.scenario import MAX_SOURCES

PathLike = str | os.PathLike
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
INT8 = (-128, 127)
MAX_WINDOW = 10_001  # the env's largest lag is 10000


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
    key = re.sub(r"\s*[(\[][^)\]]*[)\]]\s*$", "", str(name)).strip().lower()
    key = re.sub(r"[\s\-]+", "_", key)
    return _ALIAS.get(key)


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

    def pulse_table(self, where: str = "the TDC file"):
        """The train as our `io.PulseTable` (with truth when it has labels)."""
        from deint_env.io import PulseTable

        if self.labels is None:
            return PulseTable(self.toa, self.amplitude, None, None)
        k = self.emitters.size
        if k > MAX_SOURCES:
            raise DeintError(f"{where}: has {k} emitters; a truth table holds at most {MAX_SOURCES} sources")
        source = self.source()
        mask = np.zeros(len(self), dtype=np.uint64)
        real = source >= 0
        mask[real] = np.left_shift(np.uint64(1), source[real].astype(np.uint64))
        return PulseTable(self.toa, self.amplitude, source, mask)

    def episode(self, priors: Priors, name: str = "tdc") -> Episode:
        """The train as an `Episode` to play with `priors` (truth None; the source columns are the
        labels when the file has them, else zeros, as `io.read_pulses` does)."""
        n = len(self)
        if self.labels is not None and self.emitters.size <= MAX_SOURCES:
            t = self.pulse_table()
            source, mask = t.source, t.mask
        else:
            source, mask = np.zeros(n, dtype=np.int32), np.zeros(n, dtype=np.uint64)
        return Episode(scenario=name, seed=0, toa=self.toa, amplitude=self.amplitude, source=source, mask=mask,
                       truth=None, priors=priors)

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
            labels = labels.astype(np.int64)
        return TDCTrain(data, names, labels, dict(self.metadata), tuple(columns))

    # ---- writing -----------------------------------------------------------------------------------
    def write(self, path: PathLike, dtype: str = "float32") -> None:
        """Write the train as a TDC file (atomically: a temporary file renamed over `path`)."""
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

        _atomic_h5(Path(path), fill)


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
    """Read and check a TDC pulse-train file; every problem is one `DeintError` line."""
    h5py = _h5py()
    path = Path(path)
    with _hdf5(path) as f:
        if "data" not in f or not isinstance(f["data"], h5py.Dataset):
            raise DeintError(f"{path}: no 'data' dataset; a TDC file holds data (seq_len x features), "
                             f"labels and metadata/feature_names")
        meta = f.get("metadata")
        if not isinstance(meta, h5py.Group):
            raise DeintError(f"{path}: no 'metadata' group; a TDC file names its data columns in "
                             f"metadata/feature_names")
        if "feature_names" not in meta or not isinstance(meta["feature_names"], h5py.Dataset):
            raise DeintError(f"{path}: no 'metadata/feature_names' dataset; it names the data columns")
        raw = np.atleast_1d(meta["feature_names"][()])
        names = tuple(x.decode("utf-8", "replace") if isinstance(x, bytes) else str(x) for x in raw.tolist())
        data = f["data"][()]
        labels = None
        if "labels" in f:
            if not isinstance(f["labels"], h5py.Dataset):
                raise DeintError(f"{path}: 'labels' is a group; it must be a dataset of emitter ids")
            labels = f["labels"][()]
        attrs = {k: _plain(v) for k, v in meta.attrs.items()}
    if not isinstance(data, np.ndarray):
        raise DeintError(f"{path}: data is a scalar; TDC data is 2-D (seq_len, n_features)")
    return TDCTrain(data, names, labels, attrs).validated(str(path))


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
    from deint_env.io import atomic_path

    h5py = _h5py()
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        fill(f)


def train_from_episode(episode: Episode, truth: bool = True) -> TDCTrain:
    """A simulated or loaded episode as a TDC train (labels = primary source, -1 = spurious)."""
    return TDCTrain.from_columns(episode.toa, episode.amplitude, episode.source if truth else None,
                                 description=f"deint-bench episode {episode.scenario} seed {episode.seed}")


# ---------------------------------------------------------------------------------------------------
# the challenge's metrics
# ---------------------------------------------------------------------------------------------------
def tdc_scores(labels_true: np.ndarray, labels_pred: np.ndarray, default_label: int | None = None) -> dict[str, float]:
    """The challenge's `evaluate_labels` for one train: homogeneity, completeness, v_measure, ari,
    ami (scikit-learn), cluster-wise mcc and f1, and the discount.  With `default_label` (the model's
    "no emitter" id) pulses whose true label is it are left out and every score is multiplied by the
    share of pulses kept (the discount)."""
    from sklearn import metrics as skm

    from deint_env.metrics import clusterwise_mcc_f1

    true = np.asarray(labels_true).ravel()
    pred = np.asarray(labels_pred).ravel()
    if true.shape != pred.shape:
        raise DeintError(f"{pred.size} predicted labels for {true.size} true labels")
    discount = 1.0
    if default_label is not None and true.size:
        keep = true != default_label
        discount = float(keep.mean())
        true, pred = true[keep], pred[keep]
    if true.size == 0:
        return dict.fromkeys(("homogeneity", "completeness", "v_measure", "ari", "ami", "mcc", "f1"), math.nan) | {
            "discount": discount}
    out = {"homogeneity": skm.homogeneity_score(true, pred), "completeness": skm.completeness_score(true, pred),
           "v_measure": skm.v_measure_score(true, pred), "ari": skm.adjusted_rand_score(true, pred),
           "ami": skm.adjusted_mutual_info_score(true, pred)}
    cw = clusterwise_mcc_f1(true, pred)
    out.update(mcc=cw["cluster_mcc"], f1=cw["cluster_f1"])
    return {k: discount * float(v) for k, v in out.items()} | {"discount": discount}


def score_labels(pred: np.ndarray, truth: np.ndarray, n_labels: int | None = None) -> dict[str, Any]:
    """Score predicted ids against TDC truth ids (negative = spurious / noise, both sides) in blind
    mode: our label metrics when the truth has at most 64 emitters (else the clustering metrics
    alone); the cluster-wise MCC/F1 there are the TDC's own (`metrics.clusterwise_mcc_f1`)."""
    from deint_env.metrics import clustering_metrics, label_metrics

    pred = np.asarray(pred, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    ids = np.unique(pred[pred >= 0])
    if n_labels is None:
        n_labels = max(int(ids.size), 1)
        env = np.where(pred >= 0, np.searchsorted(ids, pred), n_labels)
    else:
        env = np.where(pred >= 0, pred, n_labels)
    emitters = np.unique(truth[truth >= 0])
    source = np.where(truth >= 0, np.searchsorted(emitters, truth), -1).astype(np.int32)
    out: dict[str, Any] = {"n_labels": int(n_labels), "blind": True, "n_emitters": int(emitters.size)}
    if emitters.size <= MAX_SOURCES:
        mask = np.zeros(source.size, dtype=np.uint64)
        real = source >= 0
        mask[real] = np.left_shift(np.uint64(1), source[real].astype(np.uint64))
        out.update(label_metrics(env, source, mask, int(n_labels), True, clustering=True))
    else:  # our truth tables stop at 64 sources; the clustering metrics do not
        out.update(n_pulses=int(pred.size), **clustering_metrics(source, env))
    return out


# ---------------------------------------------------------------------------------------------------
# TDC models
# ---------------------------------------------------------------------------------------------------
def load_model(spec: str) -> Any:
    """'package.module:Name' -> a model: a class is instantiated without arguments, any other
    callable (a model instance, a plain function) is used as it is."""
    module, colon, attr = str(spec).partition(":")
    if not colon or not module or not attr:
        raise DeintError(f"model={spec!r} is invalid: write package.module:Name (a Deinterleaver class or instance)")
    try:
        obj: Any = importlib.import_module(module)
    except ImportError as e:
        raise DeintError(f"model={spec!r}: cannot import {module} ({e}); the module must be installed or on "
                         f"PYTHONPATH") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise DeintError(f"model={spec!r}: {module} has no attribute {attr!r}")
        obj = getattr(obj, part)
    if inspect.isclass(obj):
        try:
            obj = obj()
        except Exception as e:  # noqa: BLE001 - the user's constructor: say what failed, in one line
            raise DeintError(f"model={spec!r}: {attr}() failed ({type(e).__name__}: {e})") from None
    if not callable(obj):
        raise DeintError(f"model={spec!r}: {attr} is not callable; a TDC Deinterleaver is called on pulse trains")
    return obj


def _ids(out: Any, n: int) -> np.ndarray | None:
    """The model's output as n integer ids, or None if it has another shape."""
    try:
        arr = np.asarray(out)
    except Exception:  # noqa: BLE001
        return None
    if arr.shape not in ((n,), (1, n), (n, 1), (1, n, 1)):
        return None
    arr = arr.reshape(n)
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr) & (arr == np.round(arr))):
            raise DeintError("the TDC model returned non-integer emitter ids")
    elif arr.dtype.kind not in "iub":
        raise DeintError(f"the TDC model returned {arr.dtype} labels; emitter ids are integers")
    return arr.astype(np.int64)


def predict(model: Callable[[np.ndarray], Any], data: np.ndarray, batched: bool | None = None) -> np.ndarray:
    """A TDC model's emitter ids (int64, one per row) for one train (seq_len, n_features).

    batched=True calls ``model(data[None])`` (the documented batch interface), False calls
    ``model(data)`` (what the current TDC evaluation does), None tries the batch first and falls back
    to the bare train when that raises or returns the wrong shape.  The model gets float32 rows, as
    TDC files hold them.
    """
    return _predict(model, data, batched)[0]


def _predict(model: Callable[[np.ndarray], Any], data: np.ndarray, batched: bool | None) -> tuple[np.ndarray, bool]:
    data = np.asarray(data, dtype=np.float32)
    n = data.shape[0]
    failures = []
    for batch in ([True, False] if batched is None else [bool(batched)]):
        try:
            out = model(data[None] if batch else data)
        except Exception as e:  # noqa: BLE001 - a model's own error: fall back, or report it in one line
            failures.append(f"raised {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}".rstrip(": "))
            continue
        ids = _ids(out, n)
        if ids is not None:
            return ids, batch
        failures.append(f"returned shape {np.shape(out)}")
    how = " and ".join(f"{'on a batch of one' if b else 'on the bare train'} {f}" for b, f in
                       zip([True, False] if batched is None else [bool(batched)], failures))
    raise DeintError(f"the TDC model {how} ({n} pulses); it must return {n} emitter ids, shape (1, {n}) "
                     f"for a batch of one or ({n},) for one train")


def noise_label_of(model: Any, noise_label: int | None = None) -> int | None:
    """The id a model gives pulses it associates with no emitter: `noise_label` if given, else the
    model's ``default_label`` attribute (the TDC convention), else None."""
    if noise_label is not None:
        return int(noise_label)
    value = getattr(model, "default_label", None)
    if value is None:
        return None
    try:
        return int(value)
    except (TypeError, ValueError):
        return None


def to_blind_labels(ids: np.ndarray, n_labels: int, noise_label: int | None = None,
                    overflow: str = "spurious") -> np.ndarray:
    """Emitter ids -> our blind labels: ids numbered 0, 1, ... in first-seen order, the noise id ->
    spurious (n_labels).  Ids beyond the label budget become spurious (overflow="spurious") or raise
    NotApplicable (overflow="raise")."""
    ids = np.asarray(ids, dtype=np.int64)
    out = np.full(ids.size, n_labels, dtype=np.int64)
    real = ids != noise_label if noise_label is not None else np.ones(ids.size, dtype=bool)
    uniq, first = np.unique(ids[real], return_index=True)
    if uniq.size > n_labels and overflow == "raise":
        raise NotApplicable(f"the TDC model found {uniq.size} emitters in a window; the label budget is {n_labels}")
    rank = np.empty(uniq.size, dtype=np.int64)  # each id's first-seen rank, capped at spurious
    rank[np.argsort(first)] = np.minimum(np.arange(uniq.size), n_labels)
    out[real] = rank[np.searchsorted(uniq, ids[real])]
    return out


class TDCDeinterleaver:
    """A TDC `Deinterleaver` model run as a blind-mode policy (registered as ``tdc``).

    A TDC model labels whole trains, so the policy buffers pulses and labels them in consecutive
    windows of `window` pulses: its lag is window - 1, so when the last pulse of a window arrives,
    the window's first pulse is due and the model runs once on the window (the last, shorter window
    runs at the first padding step).  Each window is clustered on its own: its emitter ids are
    numbered 0, 1, ... in first-seen order (the model's noise id -> spurious; ids past the label
    budget -> spurious, or NotApplicable with overflow="raise"), so clusters are not associated
    across windows.  With window >= the episode length the model sees the whole train at once, as
    in the challenge; windows are at most 10001 pulses (the env's largest lag is 10000), and
    `label_train` / `label_episode` label a train of any length in one call, without the protocol.

    The model is given rows of (toa, amplitude) as float32 - amplitude only when the episode has it -
    or, after `attach_data`, the rows of a full PDW matrix (a TDC file's data), row k being read only
    once pulse k has been observed.  Anchored scenarios are not applicable: a clustering model has no
    notion of prior tracks.
    """

    def __init__(self, model: Any, window: int = 1000, batched: bool | None = None, overflow: str = "spurious",
                 noise_label: int | None = None):
        if isinstance(window, bool) or not isinstance(window, int) or not 1 <= window <= MAX_WINDOW:
            raise ValueError(f"window={window!r} is invalid: an integer in [1, {MAX_WINDOW}] (pulses per model "
                             f"call; the lag, window - 1, is at most 10000)")
        if overflow not in ("spurious", "raise"):
            raise ValueError(f"overflow={overflow!r} is invalid: spurious or raise")
        if batched not in (None, True, False):
            raise ValueError(f"batched={batched!r} is invalid: true, false or none (try both)")
        self.model = load_model(model) if isinstance(model, str) else model
        if not callable(self.model):
            raise ValueError("model must be callable (a TDC Deinterleaver)")
        self.window = window
        self.lag = window - 1
        self.batched = batched
        self.overflow = overflow
        self.noise_label = noise_label_of(self.model, noise_label)
        self._data: np.ndarray | None = None

    def attach_data(self, data: np.ndarray | None) -> None:
        """Give the model these PDW rows (one per pulse of the next episodes) instead of (toa, amplitude)."""
        self._data = None if data is None else np.asarray(data, dtype=np.float32)

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if not priors.blind:
            raise NotApplicable("tdc models cluster pulses into emitters: blind scenarios only (no prior tracks)")
        self.n_labels = priors.n_labels
        self._amp = bool(info.get("has_amplitude", True))
        n = info.get("n_pulses")
        if self._data is not None and n is not None and self._data.shape[0] != n:
            raise DeintError(f"attached data has {self._data.shape[0]} rows for an episode of {n} pulses")
        self._rows: list[Any] = []
        self._ready: deque[int] = deque()
        self._seen = 0
        self._step = 0

    def _flush(self) -> None:
        if not self._rows:
            return
        block = np.asarray(self._rows, dtype=np.float32)
        ids, self.batched = _predict(self.model, block, self.batched)  # the convention found is kept
        self._ready.extend(to_blind_labels(ids, self.n_labels, self.noise_label, self.overflow).tolist())
        self._rows = []

    def act(self, obs: dict[str, Any]) -> int:
        if int(obs["valid"]):
            k = self._seen
            if self._data is not None:
                self._rows.append(self._data[k])
            else:
                toa = float(obs["toa"][0])
                self._rows.append((toa, float(obs["amplitude"][0])) if self._amp else (toa,))
            self._seen += 1
            if len(self._rows) == self.window:
                self._flush()
        else:
            self._flush()
        due = self._step - self.lag
        self._step += 1
        if due < 0:
            return 0  # before the first decision: the env ignores it
        return self._ready.popleft()


def from_deinterleaver(model: Any, window: int = 1000, **kwargs: Any) -> TDCDeinterleaver:
    """Wrap a TDC Deinterleaver instance (or any callable with its interface) as a policy."""
    return TDCDeinterleaver(model, window=window, **kwargs)


def label_train(model: Any, data: np.ndarray, n_labels: int | None = None, *, batched: bool | None = None,
                noise_label: int | None = None, overflow: str = "spurious") -> np.ndarray:
    """Label a whole train at once, as the challenge does.  Without `n_labels`: the model's emitter ids;
    with it: our blind labels (see `to_blind_labels`)."""
    ids = predict(model, data, batched)
    if n_labels is None:
        return ids
    return to_blind_labels(ids, n_labels, noise_label_of(model, noise_label), overflow)


def episode_input(episode: Episode) -> np.ndarray:
    """The (toa[, amplitude]) rows a model is given for an episode without PDW data."""
    cols = [episode.toa] + ([episode.amplitude] if episode.amplitude is not None else [])
    return np.stack(cols, axis=1).astype(np.float32)


def label_episode(model: Any, episode: Episode, **kwargs: Any) -> np.ndarray:
    """Our blind labels for a whole episode in one model call (the episode's label budget)."""
    return label_train(model, episode_input(episode), episode.n_labels, **kwargs)


# ---------------------------------------------------------------------------------------------------
# the command line's file handling
# ---------------------------------------------------------------------------------------------------
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
    from deint_env.io import to_file_labels

    file_labels = to_file_labels(labels, n_labels)
    if isinstance(pulses, TDCTrain):
        meta = {**pulses.metadata, **({"description": description} if description else {})}
        out = TDCTrain(pulses.data, pulses.feature_names, file_labels, meta)
        out.write(path, "float64" if pulses.data.dtype == np.float64 else "float32")
    else:
        TDCTrain.from_columns(pulses.toa, pulses.amplitude, file_labels, description=description).write(path, "float64")


def convert(src: PathLike, dst: PathLike, dtype: str = "float32") -> str:
    """Convert a pulse file between our CSV and a TDC HDF5 file (by suffix); returns a status line."""
    from deint_env import io

    src, dst = Path(src), Path(dst)
    if is_tdc_path(src) == is_tdc_path(dst):
        raise DeintError(f"convert goes between a CSV pulse file and a TDC file (.h5/.hdf5): got {src} -> {dst}")
    if is_tdc_path(dst):
        t = io.read_pulse_table(src)
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
    io.write_text(dst, ",".join(header) + "\n" + "".join(f"{r}\n" for r in map(",".join, zip(*cols))))
    dropped = [n for n, c in zip(train.feature_names, train.columns) if c not in ("toa", "amplitude")]
    note = f"; dropped {', '.join(dropped)} (pulse files hold toa and amplitude)" if dropped else ""
    ids = f"; emitter ids {train.emitters.tolist()[:8]}{'...' if train.emitters.size > 8 else ''} -> sources 0.." \
          f"{train.emitters.size - 1}" if train.labels is not None and train.emitters.size else ""
    return f"{src} -> {dst}: {len(train)} pulses{ids}{note}"


def _register() -> None:
    from deint_env.policies import register_policy

    register_policy("tdc", "deint_env.tdc:TDCDeinterleaver",
                    description="a Turing Deinterleaving Challenge Deinterleaver model (model=module:Name), "
                                "labelling windows of `window` pulses (blind only)")


_register()

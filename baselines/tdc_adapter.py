"""A Turing Deinterleaving Challenge `Deinterleaver` model as a blind-mode policy (registered as
``tdc``, kind "adapter"; it runs the user's code named by ``model=``).

A TDC `Deinterleaver` (`models/model.py`) is a callable: an older version documents
``model(batch)`` with a (batch, seq_len, n_features) array returning (batch, seq_len) emitter ids; the
current one has a ``default_label`` attribute (the id it gives pulses it cannot associate, ignored in
scoring when it is a true label) and its evaluation calls ``model(train)`` on one (seq_len,
n_features) train.  `predict` supports both, duck-typed (this package never imports theirs): it calls
the model with a batch of one, and if that raises or gives the wrong shape, with the bare train.
`TDCDeinterleaver` (registered as policy ``tdc``, e.g. ``tdc:model=my.module:MyModel,window=500``)
runs such a model in our online protocol; see its docstring.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any, Callable

import numpy as np

from baselines.windowed import MAX_WINDOW, WindowedPolicy
from deint_env.episode import Episode, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.params import REQUIRED, Param, declare


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


class TDCDeinterleaver(WindowedPolicy):
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

    PARAMS = declare(
        Param("model", str, REQUIRED, "the Deinterleaver to run: module:Name (runs that code)"),
        Param("window", int, 1000, "pulses per model call (the lag is window - 1)", low=1, high=MAX_WINDOW),
        Param("batched", bool, None, "call the model on a batch of windows (none: try both)", optional=True),
        Param("overflow", str, "spurious", "more clusters than labels: the extra ones spurious, or raise",
              choices=("spurious", "raise")),
        Param("noise_label", int, None, "the id the model gives noise pulses (none: the model's own, if it states one)",
              optional=True),
    )

    def __init__(self, model: Any, window: int = 1000, batched: bool | None = None, overflow: str = "spurious",
                 noise_label: int | None = None):
        self.PARAMS.only("window", "batched", "overflow", "noise_label").check(locals())  # model: a name or an object
        self.model = load_model(model) if isinstance(model, str) else model
        if not callable(self.model):
            raise ValueError("model must be callable (a TDC Deinterleaver)")
        super().__init__(window)
        self.batched = batched
        self.overflow = overflow
        self.noise_label = noise_label_of(self.model, noise_label)
        self._data: np.ndarray | None = None

    def attach_data(self, data: np.ndarray | None) -> None:
        """Give the model these PDW rows (one per pulse of the next episodes) instead of (toa, amplitude)."""
        self._data = None if data is None else np.asarray(data, dtype=np.float32)

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self.n_labels = priors.n_labels
        self._amp = bool(info.get("has_amplitude", True))
        n = info.get("n_pulses")
        if self._data is not None and n is not None and self._data.shape[0] != n:
            raise DeintError(f"attached data has {self._data.shape[0]} rows for an episode of {n} pulses")
        self._start()

    def _label_rows(self, rows: list[Any]) -> list[int]:
        block = np.asarray(rows, dtype=np.float32)
        ids, self.batched = _predict(self.model, block, self.batched)  # the convention found is kept
        return to_blind_labels(ids, self.n_labels, self.noise_label, self.overflow).tolist()

    def _row(self, obs: dict[str, Any]) -> Any:
        if self._data is not None:
            return self._data[self._seen]
        toa = float(obs["toa"][0])
        return (toa, float(obs["amplitude"][0])) if self._amp else (toa,)


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

"""Safe, identified checkpoints: one safetensors file holding the weights and a JSON description.

A checkpoint is a single `.safetensors` file.  Its header metadata carries `format` and `meta`, the
JSON of a `CheckpointMeta` (architecture, feature layout and version, training scenarios and their
suite hashes, train seeds, steps, hyper-parameters, package versions), so the file alone rebuilds
and evaluates the agent.  Loading parses the header as JSON and the tensors with safetensors: it
never unpickles anything (no `torch.load`, no cloudpickle), so a crafted file cannot run code.  A
file that is not a safetensors checkpoint (a stable-baselines3 zip, a pickle, anything else) is
refused with one line.

A checkpoint is identified by its content: `key` is the SHA-256 of the file's bytes, so results
computed with a checkpoint stay tied to those exact weights even if another file replaces it later.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import tempfile
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from deint_env.errors import DeintError
from deint_env.formats.files import short_name

FORMAT = "deint-checkpoint/1"
MAX_BYTES = 256 * 2**20  # no agent of this benchmark comes near; a bigger file is refused unread
MAX_HEADER = 16 * 2**20
_SIGNATURES = (  # what people hand us instead of a safetensors file, named in the refusal
    (b"PK\x03\x04", "a zip archive (a stable-baselines3 or torch.save checkpoint?), which holds pickles"),
    (b"\x80", "a Python pickle"),
)


@dataclass(frozen=True)
class CheckpointMeta:
    """Everything needed to rebuild an agent and to know what it was trained on."""

    architecture: dict[str, Any]  # {"name": one of agents.networks.ARCHITECTURES, **its keyword arguments}
    features: dict[str, Any]  # {"layout": ..., "version": ..., plus the layout's own parameters}
    algorithm: str
    scenarios: list[str]  # training scenarios, suite-qualified
    suite_hashes: dict[str, str]  # suite -> content hash at training time
    train_seeds: list[int]  # [start, stop) of the seeds training drew from
    timesteps: int
    hyperparameters: dict[str, Any]
    versions: dict[str, str]
    seed: int = 0
    notes: dict[str, Any] = field(default_factory=dict)  # e.g. training seconds, evaluation scores

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str, where: str) -> CheckpointMeta:
        try:
            d = json.loads(text)
        except (ValueError, RecursionError):
            raise DeintError(f"{where}: its metadata is not valid JSON") from None
        if not isinstance(d, dict):
            raise DeintError(f"{where}: its metadata must be a JSON object")
        names = {f.name for f in fields(cls)}
        required = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING}
        missing, unknown = sorted(required - set(d)), sorted(set(d) - names)
        if missing or unknown:
            raise DeintError(f"{where}: metadata key {(missing or unknown)[0]!r} is "
                             f"{'missing' if missing else 'unknown'}; keys: {', '.join(sorted(names))}")
        for name in ("architecture", "features", "suite_hashes", "hyperparameters", "versions"):
            if not isinstance(d[name], dict):
                raise DeintError(f"{where}: metadata {name!r} must be a JSON object")
        for name in ("architecture", "features"):
            _check_sizes(d[name], f"{where}: {name}")
        return cls(**d)


# The sizes a checkpoint's architecture and feature layout may declare, checked before any network is
# built: a 151 KB file declaring d_model=30000 would otherwise allocate gigabytes before its tensors
# fail to fit.  Widths and lengths are at most MAX_SIZE, depths far less (a 16-layer, 1024-wide
# transformer is about 0.2 G parameters, under 1 GB); no shipped agent comes near (d_model <= 64).
MAX_SIZE = 4096
SIZE_BOUNDS = {"d_model": (1, 1024), "heads": (1, 64), "layers": (1, 16), "n_lstm_layers": (1, 8), "net_arch": (1, MAX_SIZE)}
MAX_LIST = 16


def _check_sizes(fields: dict[str, Any], where: str) -> None:
    for key, value in fields.items():
        items = value if isinstance(value, list) else [value]
        if isinstance(value, list) and len(value) > MAX_LIST and any(type(v) is int for v in value):
            raise DeintError(f"{where} {key!r} lists {len(value)} sizes; at most {MAX_LIST}")
        lo, hi = SIZE_BOUNDS.get(key, (0, MAX_SIZE))
        for v in items:
            if type(v) is int and not lo <= v <= hi:
                raise DeintError(f"{where} {key}={v} is out of range: an integer in [{lo}, {hi}]")


@dataclass(frozen=True)
class Checkpoint:
    path: Path
    meta: CheckpointMeta
    tensors: dict[str, Any]  # name -> torch.Tensor
    key: str  # "sha256:" + the first 16 hex digits of the file's SHA-256

    @property
    def version(self) -> str:
        """What a results file should key this agent's records on (the file's content hash)."""
        return self.key


def content_key(data: bytes) -> str:
    return "sha256:" + hashlib.sha256(data).hexdigest()[:16]


def save_checkpoint(path: str | os.PathLike, tensors: dict[str, Any], meta: CheckpointMeta) -> str:
    """Write `tensors` (name -> torch.Tensor) and `meta` to `path` atomically; returns the content key."""
    from safetensors.torch import save

    data = save({k: v.detach().contiguous().cpu() for k, v in tensors.items()},
                metadata={"format": FORMAT, "meta": meta.to_json()})
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Write beside the target, then rename: an interrupted save never leaves a half-written checkpoint.
    fd, tmp = tempfile.mkstemp(prefix=f".{short_name(path.name)}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)  # mkstemp makes the file private; a checkpoint is meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return content_key(data)


def read_header(data: bytes, where: str) -> dict[str, Any]:
    """The safetensors JSON header of `data`, or a one-line refusal naming what the file is."""
    # A safetensors file starts with its header length (u64, little-endian) and then "{": a length
    # whose low byte is 0x80 looks like a pickle's first byte, so name a signature only for files
    # that are not laid out as safetensors (they are never unpickled either way).
    laid_out = len(data) > 8 and data[8:9] == b"{" and struct.unpack("<Q", data[:8])[0] <= len(data) - 8
    for magic, what in _SIGNATURES:
        if data.startswith(magic) and not laid_out:
            raise DeintError(f"{where} is {what}; checkpoints are loaded only from safetensors files, "
                             "never unpickled")
    if len(data) < 8:
        raise DeintError(f"{where} is not a safetensors checkpoint (too short)")
    (size,) = struct.unpack("<Q", data[:8])
    if size > min(MAX_HEADER, len(data) - 8):
        raise DeintError(f"{where} is not a safetensors checkpoint (its header length {size} is impossible)")
    try:
        header = json.loads(data[8:8 + size])
    except (ValueError, RecursionError):
        raise DeintError(f"{where} is not a safetensors checkpoint (its header is not JSON)") from None
    if not isinstance(header, dict):
        raise DeintError(f"{where} is not a safetensors checkpoint (its header is not a JSON object)")
    return header


def load_checkpoint(path: str | os.PathLike) -> Checkpoint:
    """Read, check and identify a checkpoint; every problem is one `DeintError` line."""
    from safetensors import SafetensorError
    from safetensors.torch import load

    path = Path(path)
    where = f"checkpoint {path}"
    if not path.is_file():
        raise DeintError(f"{where} does not exist (train one with `deint train`)")
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise DeintError(f"{where} is {size} bytes; a checkpoint is at most {MAX_BYTES}")
    data = path.read_bytes()  # read once: the hash, the header and the tensors all come from these bytes
    header = read_header(data, where)
    metadata = header.get("__metadata__")
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT or "meta" not in metadata:
        found = metadata.get("format") if isinstance(metadata, dict) else None
        raise DeintError(f"{where} is a safetensors file but not a deint checkpoint (format {found!r}, "
                         f"expected {FORMAT!r})")
    meta = CheckpointMeta.from_json(metadata["meta"], where)
    try:
        tensors = load(data)
    except SafetensorError as e:
        raise DeintError(f"{where}: its tensors are unreadable ({str(e).splitlines()[0]})") from None
    return Checkpoint(path, meta, tensors, content_key(data))


def read_meta(path: str | os.PathLike) -> CheckpointMeta:
    return load_checkpoint(path).meta

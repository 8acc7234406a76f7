"""TensorBoard scalars of a training run (`OUT/tensorboard`), for the loops SB3 does not log itself
(behaviour cloning / DAgger) and for the validation accuracy of every algorithm.

`tensorboard` ships with the `[rl]` extra; without it (a bare install) `writer` returns None, and the
run says so once instead of failing: the logs are a convenience, the checkpoints and `eval.jsonl`
are the record.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path


def tensorboard_available() -> bool:
    return importlib.util.find_spec("tensorboard") is not None


def writer(log_dir: Path, progress: bool):
    """A `torch.utils.tensorboard.SummaryWriter` into `log_dir`, or None when tensorboard is missing."""
    if not tensorboard_available():
        if progress:
            print("deint: tensorboard is not installed, so no TensorBoard logs (pip install tensorboard)", flush=True)
        return None
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(log_dir=str(log_dir))


def next_run_dir(root: Path, name: str) -> Path:
    """`root/name_K` with K one more than the highest existing (SB3's naming), so a resumed run's
    scalars go beside the earlier ones'."""
    taken = [int(p.name.rpartition("_")[2]) for p in root.glob(f"{name}_*") if p.name.rpartition("_")[2].isdigit()]
    return root / f"{name}_{max(taken, default=0) + 1}"

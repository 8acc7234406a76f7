"""`deint import-sb3`: a stable-baselines3 model you trust -> a deint checkpoint (`agent:checkpoint=`).

A stable-baselines3 zip holds pickled Python objects (the policy class, the spaces, the schedules), so
loading it can run any code its author put there.  This module is the one code path of deint-bench
that unpickles, and only when asked to (`trust=True`, `--trust-this-file`): it loads the zip with
stable-baselines3, rebuilds the policy, checks that the `agent` policy's architectures
(`agents.networks.build_policy`) hold it on the token features of its observation space, and writes its
weights and a JSON description as a safetensors checkpoint, which loads without unpickling ever after.

The model must have been trained on `deint_env/DeinterleaveTokens-v0` (a Dict observation; the layout
and look-ahead are read from its space) with a track network of `agents.networks`: `MaskableTrackPolicy`
(MaskablePPO), `TrackPolicy` (PPO, A2C), `TrackDQNPolicy` (DQN) or `RecurrentTrackPolicy` (RecurrentPPO).
What it was trained on is not in the zip: the checkpoint's `scenarios` and `train_seeds` are empty and
its notes name the source file and its hash.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path
from typing import Any, NamedTuple

from agents.checkpoint import CheckpointMeta, save_checkpoint
from agents.networks import architecture_of, build_policy, load_weights, weights_of
from agents.train import _versions
from deint_env.errors import DeintError
from deint_env.features import TrackLayout

ALGORITHM = "sb3-import"
UNTRUSTED = ("loading a stable-baselines3 zip unpickles Python objects, which can run any code; pass "
             "--trust-this-file only for a model you made or trust")
NETWORKS = "MaskableTrackPolicy, TrackPolicy, TrackDQNPolicy or RecurrentTrackPolicy of agents.networks"


class Imported(NamedTuple):
    path: Path  # the checkpoint written
    key: str  # its content key (`agent:checkpoint=`'s version)
    architecture: dict[str, Any]
    layout: TrackLayout


def _constant(_: float) -> float:
    return 0.0


def _line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def import_sb3(model_path: str | os.PathLike, out: str | os.PathLike, *, trust: bool = False) -> Imported:
    """Convert the SB3 zip at `model_path` into the checkpoint `out` (written atomically); every
    refusal is one `DeintError` line, and nothing is unpickled unless `trust`."""
    src = Path(model_path)
    if not trust:
        raise DeintError(f"{src}: {UNTRUSTED}")
    if not src.is_file():
        raise DeintError(f"{src} does not exist" if not src.exists() else
                         f"{src} is not a regular file; a model zip is read only from a regular file")
    if not zipfile.is_zipfile(src):
        raise DeintError(f"{src} is not a stable-baselines3 model zip (not a zip archive)")
    with zipfile.ZipFile(src) as z:
        names = z.namelist()
    if "data" not in names:
        raise DeintError(f"{src} is not a stable-baselines3 model zip (no 'data' entry)")
    from stable_baselines3.common.save_util import load_from_zip_file

    try:
        data, params, _ = load_from_zip_file(src, device="cpu")
    except Exception as e:  # noqa: BLE001 -- whatever the unpickling raises, said in one line
        raise DeintError(f"{src}: stable-baselines3 cannot load it ({type(e).__name__}: {_line(e)})") from None
    policy_class = data.get("policy_class")
    if not isinstance(policy_class, type) or "policy" not in params:
        raise DeintError(f"{src}: its policy could not be restored (is the package defining its class installed?)")
    where = f"{src} ({policy_class.__name__})"
    layout = TrackLayout.from_space(data.get("observation_space"))
    if layout is None:
        raise DeintError(f"{where}: its observation space is not a token layout of DeinterleaveTokens-v0; the agent "
                         f"policy plays models trained on that env with a {NETWORKS}")
    kwargs = dict(data.get("policy_kwargs") or {})
    try:
        policy = policy_class(data["observation_space"], data["action_space"], _constant, **kwargs)
        policy.load_state_dict(params["policy"])
        architecture = architecture_of(policy)
        net = build_policy(architecture, layout.to_dict())  # what `agent:checkpoint=` will rebuild
        load_weights(net, weights_of(policy), where)
    except Exception as e:  # noqa: BLE001 -- a foreign class fails in its own ways; one line either way
        raise DeintError(f"{where}: the agent policy cannot load this network, only a {NETWORKS} "
                         f"({_line(e)})") from None
    meta = CheckpointMeta(
        architecture=architecture, features=layout.to_dict(), algorithm=ALGORITHM, scenarios=[], suite_hashes={},
        train_seeds=[], timesteps=int(data.get("num_timesteps") or 0),
        hyperparameters={"policy_class": f"{policy_class.__module__}.{policy_class.__qualname__}",
                         "policy_kwargs": json.loads(json.dumps(kwargs, default=str))},
        versions=_versions(), seed=int(data.get("seed") or 0),
        notes={"imported_from": src.name, "source_sha256": hashlib.sha256(src.read_bytes()).hexdigest()})
    key = save_checkpoint(out, weights_of(net), meta)
    return Imported(Path(out), key, architecture, layout)

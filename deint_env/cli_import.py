"""`deint import-sb3`: convert a stable-baselines3 model you trust into a deint checkpoint.

    deint import-sb3 MODEL.zip --trust-this-file -o agent.safetensors
    deint run --suite core-v0 --split validation --policy agent:checkpoint=agent.safetensors

The conversion (`agents.sb3_import`) is the only code path that unpickles, and only with
`--trust-this-file`; without it the command refuses with one line before reading the file.  Like
`deint train` and `deint dataset`, this command sits on top of the packages and imports `agents` when run.
"""

from __future__ import annotations

import argparse

from deint_env.cli_util import _check_paths, _status
from deint_env.errors import DeintError


def _add_import_sb3(sub) -> None:
    p = sub.add_parser(
        "import-sb3", help="convert a stable-baselines3 model you trust into a safe checkpoint (unpickles it)",
        description="Load a stable-baselines3 / sb3-contrib model zip trained on DeinterleaveTokens-v0 with a "
                    "track network of agents.networks (MaskableTrackPolicy, TrackPolicy, TrackDQNPolicy, "
                    "RecurrentTrackPolicy) and write it as a safetensors checkpoint that `--policy "
                    "agent:checkpoint=OUT` plays.  Loading the zip unpickles Python objects, which can run any "
                    "code: this is the one command that does so, and only with --trust-this-file.")
    p.add_argument("model", metavar="MODEL.zip", help="the stable-baselines3 model file")
    p.add_argument("--trust-this-file", action="store_true",
                   help="you made this file or trust its author: loading it runs whatever its pickles hold")
    p.add_argument("-o", "--out", required=True, metavar="OUT.safetensors", help="the checkpoint to write")
    p.set_defaults(func=cmd_import_sb3)


def cmd_import_sb3(args: argparse.Namespace) -> int:
    if not args.trust_this_file:  # before the import below: a refusal needs no [rl] extra
        raise DeintError(f"{args.model}: loading a stable-baselines3 zip unpickles Python objects, which can run any "
                         "code; pass --trust-this-file only for a model you made or trust")
    _check_paths({"MODEL": args.model}, {"-o": args.out})
    try:
        from agents.sb3_import import import_sb3
    except ImportError as e:
        raise DeintError(f"import-sb3 needs {e.name}: pip install 'deint-bench[rl]'") from None
    done = import_sb3(args.model, args.out, trust=True)
    _status(f"deint: wrote {done.path} ({done.architecture['name']}, {done.layout.max_tracks} tracks, look-ahead "
            f"{done.layout.lookahead}, {done.key}); play it with --policy agent:checkpoint={done.path}")
    return 0

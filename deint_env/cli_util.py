"""What every `deint` subcommand shares: exit codes, the one-line-error parser, status lines, the
check of output paths against every input, and the policies a command is given."""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

from deint_env.errors import MAX_SHOWN, DeintError
from deint_env.formats.files import check_output


EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def _decimal_int(text: str) -> int:
    """int() of ASCII decimal digits only: int() also reads '1_0' as 10 and non-ASCII digits ('٣' as 3)."""
    if not re.fullmatch(r"\s*[+-]?[0-9]+\s*", text):
        raise ValueError(text)
    return int(text)


def _decimal_float(text: str) -> float:
    """float() of an ASCII decimal number (or inf, nan): float() also reads '1_0' as 10 and non-ASCII digits."""
    if not re.fullmatch(r"\s*[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?\s*|\s*[+-]?(inf|infinity|nan)\s*",
                        text, re.IGNORECASE):
        raise ValueError(text)
    return float(text)


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line, like every other error of `deint`; `type=int` and
    `type=float` arguments take ASCII decimal numbers only (argparse's message still says "invalid int
    value" or "invalid float value")."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register("type", int, _decimal_int)
        self.register("type", float, _decimal_float)

    def error(self, message: str):
        if len(message) > 2 * MAX_SHOWN:  # "unrecognized arguments: " and 10^4 of them is not a message
            message = message[:2 * MAX_SHOWN] + "..."
        self.exit(EXIT_ERROR, f"deint: error: {message} (see '{self.prog} --help')\n")


def _status(text: str) -> None:
    print(text, file=sys.stderr)


def _check_paths(inputs: dict[str, str | None], outputs: dict[str, str | None]) -> None:
    """Fail before anything is read or written when an output is not a regular file (`check_output`), its
    directory is missing, or it is the same file as an input or another output: by resolved path (symlinks,
    '..', './'), and for existing files by device and inode (hard links).  Keys are the options that name the
    paths."""
    named_in = [(k, p) for k, p in inputs.items() if p]
    named_out = [(k, p) for k, p in outputs.items() if p]
    for opt, path in named_out:
        if not Path(path).resolve().parent.is_dir():
            raise DeintError(f"{path}: cannot write: directory {Path(path).parent} does not exist")
    for i, (opt, path) in enumerate(named_out):
        for other_opt, other in named_in + named_out[:i]:
            if _same_file(path, other):
                role = "output" if (other_opt, other) in named_out else "input"
                raise DeintError(f"{opt} {path} is the same file as the {role} {other_opt} {other}; "
                                 f"name a different file for each input and output")
    for _, path in named_out:  # a directory or a FIFO refused now, not after the policy has played
        check_output(path)


def _check_folders(folders: dict[str, str | None]) -> None:
    """Refuse an empty folder option: pathlib reads '' as '.', so the files would land in the current
    directory.  Keys are the options that name the folders (None: not given)."""
    for opt, folder in folders.items():
        if folder == "":
            raise DeintError(f"{opt} {folder!r}: the path is empty; give a folder name")


def _policy_inputs(specs: list[str]) -> dict[str, str]:
    """The files a policy spec reads, as inputs for `_check_paths`: a parameter naming an existing file
    (`checkpoint=ck.safetensors`), and the source of a top-level module a parameter names
    (`model=mymodel:Name`; found without importing it).  `-o ck.safetensors` would replace them."""
    import importlib.util

    from deint_env.policies import parse_policy_spec

    found: dict[str, str] = {}
    for spec in specs:
        try:
            _, kwargs = parse_policy_spec(spec)
        except DeintError:
            continue  # a bad spec is refused, with its own line, where it is built
        for key, value in kwargs.items():
            if not isinstance(value, str):
                continue
            if os.path.isfile(value):
                found[f"--policy {key}="] = value
            module = value.split(":", 1)[0]
            if ":" in value and module.isidentifier():  # undotted: find_spec imports no parent package
                origin = getattr(importlib.util.find_spec(module), "origin", None)
                if origin and os.path.isfile(origin):
                    found[f"--policy {key}="] = origin
    return found


def _same_file(a: str, b: str) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): not the same file
        return False



def _run_policies(args: argparse.Namespace) -> list[str]:
    from deint_env.policies import canonical_spec, parse_policy_spec

    specs = list(args.policy)
    if args.policies is not None:
        names = [s.strip() for s in args.policies.split(",")]
        bad = next((s for s in names if not s or ":" in s or "=" in s), None)
        if bad is not None:
            raise DeintError(f"--policies={args.policies!r} is invalid: plain policy names separated by commas; "
                             f"give a policy with parameters as --policy NAME:key=value,...")
        specs += names
    if not specs:
        raise DeintError("name at least one policy: --policy SPEC (repeatable) or --policies A,B,...")
    out, seen = [], set()
    for s in specs:
        canon = canonical_spec(*parse_policy_spec(s))
        if canon not in seen:
            seen.add(canon)
            out.append(s)
    return out


def read_label_file(path: str, toa, pulses: str, n_labels: int | None = None):
    """File labels (-1 = spurious) of a label CSV, or of a TDC file's labels (negative ids -> -1), for the
    pulses `toa` of the file `pulses`; a label at or past `n_labels` (when given) is refused."""
    import numpy as np

    from deint_env import formats
    from deint_env.formats import tdc

    if not tdc.is_tdc_path(path):
        return formats.read_labels(path, toa, n_labels, pulses=pulses)
    labels = np.maximum(tdc.read_label_ids(path, toa, pulses), -1)
    if n_labels is not None and labels.max() >= n_labels:
        raise DeintError(f"{path}: label {int(labels.max())} is outside --n-labels={n_labels} "
                         f"(labels 0..{n_labels - 1}, -1 = spurious)")
    return labels

"""Hostile checkpoints (issue 26): every size a checkpoint declares is bounded before a network is built."""

from __future__ import annotations

import dataclasses
import resource

import pytest

pytest.importorskip("torch")

from agents.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from deint_env.cli import main  # noqa: E402

DAGGER = "agents/checkpoints/dagger-all-lag3.safetensors"
SEQ = "agents/checkpoints/seq-blind-v0.safetensors"


def _tampered(tmp_path, source: str, **change) -> str:
    ck = load_checkpoint(source)
    arch = {**ck.meta.architecture, **{k: v for k, v in change.items() if k in ck.meta.architecture}}
    feats = {**ck.meta.features, **{k: v for k, v in change.items() if k in ck.meta.features}}
    out = tmp_path / "tampered.safetensors"
    save_checkpoint(out, ck.tensors, dataclasses.replace(ck.meta, architecture=arch, features=feats))
    return str(out)


@pytest.mark.parametrize("source,change,says", [
    (DAGGER, {"d_model": 30000}, "architecture d_model=30000 is out of range: an integer in [1, 1024]"),
    (DAGGER, {"d_model": 10**6}, "architecture d_model=1000000 is out of range: an integer in [1, 1024]"),
    (DAGGER, {"d_model": -64}, "architecture d_model=-64 is out of range: an integer in [1, 1024]"),
    (DAGGER, {"max_tracks": 10**7}, "features max_tracks=10000000 is out of range: an integer in [0, 4096]"),
    (SEQ, {"layers": 4096}, "architecture layers=4096 is out of range: an integer in [1, 16]"),
    (SEQ, {"ff": 10**8}, "architecture ff=100000000 is out of range: an integer in [0, 4096]"),
])
def test_declared_sizes_are_bounded_before_building(capsys, tmp_path, source, change, says):
    path = _tampered(tmp_path, source, **change)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(Exception, match="out of range") as err:
        load_checkpoint(path)
    assert str(err.value) == f"checkpoint {path}: {says}"
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # KiB: nothing big allocated


def test_a_size_bomb_through_the_cli_is_one_line(capsys, tmp_path):
    path = _tampered(tmp_path, DAGGER, d_model=30000)
    assert main(["simulate", "paper-v0/mk94-two-var1", "--seed", "1", "-o", str(tmp_path / "p.csv"), "--priors-out",
                 str(tmp_path / "p.json")]) == 0
    capsys.readouterr()
    code = main(["label", str(tmp_path / "p.csv"), "--priors", str(tmp_path / "p.json"), "--policy",
                 f"agent:checkpoint={path}", "-o", str(tmp_path / "l.csv")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "d_model=30000 is out of range" in err
    assert not (tmp_path / "l.csv").exists()

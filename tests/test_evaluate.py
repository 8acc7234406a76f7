"""Your own model (issue 25): `deint_env.evaluate` on an in-memory stable-baselines3 model, `deint
import-sb3` (the one unpickling path, refused without --trust-this-file), and the torch thread count our
SB3 env sets.  Nothing is trained: an untrained MaskablePPO labels deterministically all the same."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("sb3_contrib")  # the [rl] extra

from sb3_contrib import MaskablePPO  # noqa: E402

import deint_env  # noqa: E402
from agents.checkpoint import read_meta  # noqa: E402
from agents.networks import MaskableTrackPolicy  # noqa: E402
from agents.vec_env import TokenVecEnv  # noqa: E402
from deint_env.cli import main  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.evaluation import SB3Policy  # noqa: E402
from deint_env.policies import make_policy  # noqa: E402
from deint_env.runner import play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

SCENARIO = "core-v0/core-n3-spread4-jitter0.05"
LAG = 2


@pytest.fixture(scope="module")
def model() -> MaskablePPO:
    venv = TokenVecEnv.make(2, scenarios=[SCENARIO], lag=LAG, max_tracks=4)
    return MaskablePPO(MaskableTrackPolicy, venv, n_steps=64, batch_size=64, seed=0, device="cpu")


@pytest.fixture(scope="module")
def converted(model, tmp_path_factory) -> str:
    d = tmp_path_factory.mktemp("sb3")
    model.save(d / "model.zip")
    out = d / "agent.safetensors"
    assert main(["import-sb3", str(d / "model.zip"), "--trust-this-file", "-o", str(out)]) == 0
    return str(out)


def test_evaluate_an_sb3_model_as_its_converted_checkpoint_plays(model, converted):
    res = deint_env.evaluate(model, scenarios=[SCENARIO], max_seeds=2, progress=False)
    agent = deint_env.evaluate(f"agent:checkpoint={converted}", scenarios=[SCENARIO], max_seeds=2, progress=False)
    assert res.policy == "MaskablePPO" and res.split == "validation"
    assert [r.seed for r in res.records] == list(find_entry(SCENARIO).seeds("validation")[:2])
    assert all(r.played and r.lag == LAG for r in res.records)
    by_seed = {r.seed: r for r in agent.records}
    for r in res.records:  # the same labels, hence the same metrics (the time aside)
        for key in ("accuracy", "score", "v_measure", "genie_accuracy"):
            assert r.get(key) == by_seed[r.seed].get(key), key
    # the summary is the board's row of these records: means, and no interval below 3 seeds a scenario
    assert res.summary["episodes"] == 2 and res.summary["coverage"] == 1.0
    assert res.accuracy == pytest.approx(np.mean([r.get("accuracy") for r in res.records]))
    mean, low, high = res.score
    assert mean == pytest.approx(np.mean([r.get("score") for r in res.records])) and math.isnan(low)
    assert mean == agent.score[0] and "MaskablePPO" in res.table()


def test_the_converted_agent_labels_as_the_model_does(model, converted):
    meta = read_meta(converted)
    assert meta.algorithm == "sb3-import" and meta.architecture["name"] == "track-net"
    assert meta.features["lookahead"] == LAG and meta.features["max_tracks"] == 4
    episode = simulate(find_entry(SCENARIO).spec, 5)
    ours = play(SB3Policy(model), episode, clustering=False).labels
    theirs = play(make_policy(f"agent:checkpoint={converted}"), episode, clustering=False).labels
    np.testing.assert_array_equal(ours, theirs)
    assert len(set(ours.tolist())) > 1  # a real labelling, not a constant one
    # and on the token env's own observations, the model's masked predictions are the agent network's
    from agents.networks import action_scores
    from agents.policy import load_agent

    _, net = load_agent(converted)
    venv = TokenVecEnv.make(3, scenarios=[SCENARIO], lag=LAG, max_tracks=4)
    venv.seed(1)
    obs = venv.reset()
    for _ in range(50):
        masks = venv.action_masks()
        actions, _ = model.predict(obs, action_masks=masks, deterministic=True)
        np.testing.assert_array_equal(actions, np.where(masks, action_scores(net, obs).numpy(), -np.inf).argmax(1))
        obs, *_ = venv.step(actions)


def test_evaluate_refusals_and_the_test_split_warning(model):
    with pytest.raises(DeintError, match="not both"):
        deint_env.evaluate(model, suite="core-v0", scenarios=[SCENARIO])
    with pytest.raises(DeintError, match="workers=2"):
        deint_env.evaluate(model, scenarios=[SCENARIO], workers=2)
    with pytest.raises(DeintError, match="neither a policy"):
        deint_env.evaluate(object(), scenarios=[SCENARIO])
    with pytest.warns(UserWarning, match="test seeds"):
        res = deint_env.evaluate("nearest-prior", scenarios=[SCENARIO], split="test", max_seeds=1, progress=False)
    assert res.records[0].split == "test" and res.records[0].seed == find_entry(SCENARIO).test.start


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return err


def test_import_sb3_is_refused_without_the_flag_and_for_foreign_networks(model, tmp_path, capsys):
    zip_path = tmp_path / "model.zip"
    model.save(zip_path)
    out = tmp_path / "agent.safetensors"
    assert main(["import-sb3", str(zip_path), "-o", str(out)]) == 2
    err = _one_line(capsys)
    assert "unpickles" in err and "--trust-this-file" in err and not out.exists()
    assert main(["import-sb3", str(zip_path), "--trust-this-file", "-o", str(zip_path)]) == 2
    assert "same file" in _one_line(capsys)
    (tmp_path / "notes.zip").write_bytes(b"not a zip")
    assert main(["import-sb3", str(tmp_path / "notes.zip"), "--trust-this-file", "-o", str(out)]) == 2
    assert "not a stable-baselines3 model zip" in _one_line(capsys)
    venv = TokenVecEnv.make(1, scenarios=[SCENARIO], lag=LAG, max_tracks=4)
    MaskablePPO("MultiInputPolicy", venv, n_steps=64, batch_size=64, seed=0, device="cpu").save(tmp_path / "mlp.zip")
    assert main(["import-sb3", str(tmp_path / "mlp.zip"), "--trust-this-file", "-o", str(out)]) == 2
    assert "the agent policy cannot load this network" in _one_line(capsys) and not out.exists()


THREADS = ("import torch; torch.set_num_threads(2)\n"
           "from agents.vec_env import TokenVecEnv\n"
           f"TokenVecEnv.make(1, scenario={SCENARIO!r}); TokenVecEnv.make(1, scenario={SCENARIO!r})\n"
           "print(torch.get_num_threads())")


@pytest.mark.parametrize("omp", [None, "2"])
def test_the_sb3_env_sets_one_torch_thread_unless_the_user_chose(omp):
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    if omp is not None:
        env["OMP_NUM_THREADS"] = omp
    out = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    said = [line for line in out.stderr.splitlines() if "torch set to 1 thread" in line]
    assert (out.stdout.split(), len(said)) == ((["1"], 1) if omp is None else (["2"], 0))

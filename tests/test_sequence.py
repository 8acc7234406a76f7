"""The pointer sequence labeller `seq` (agents/sequence.py): shapes, causality (a pulse's label never
depends on pulses beyond its lag), checkpoint round trip, training entry, and the shipped checkpoint
labelling a pulse file from an independent generator through `deint label`."""

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.checkpoint import CheckpointMeta, load_checkpoint, save_checkpoint  # noqa: E402
from agents.sequence import (CHECKPOINT, N_FEATURES, ChainDecoder, PointerNet, SeqLayout,  # noqa: E402
                             SequencePolicy, chain_features, chain_truth, encode, label_episode,
                             pair_features, pointer_targets)
from deint_env.cli import main  # noqa: E402
from deint_env.errors import DeintError, NotApplicable  # noqa: E402
from deint_env.labels import correct_link  # noqa: E402
from deint_env.runner import play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

LAYOUT = SeqLayout(window=8, context=16, lag=4)


def tiny_net(seed=0):
    torch.manual_seed(seed)
    return PointerNet(LAYOUT.window, d_model=8, heads=2, layers=1, ff=16).eval()


def stream(n=200, seed=0, amplitude=False):
    rng = np.random.default_rng(seed)
    toa = np.sort(np.concatenate([np.arange(0, 800, p) + rng.normal(0, 0.1, np.arange(0, 800, p).size)
                                  for p in (11.0, 17.0, 29.0)]))[:n]
    return toa, (rng.uniform(1, 2, toa.size) if amplitude else None)


@pytest.mark.parametrize("amplitude", [False, True])
def test_feature_and_logit_shapes(amplitude):
    toa, amp = stream(amplitude=amplitude)
    f = pair_features(toa, amp, np.arange(toa.size), LAYOUT, toa.size)
    assert f.x.shape == (toa.size, LAYOUT.window, N_FEATURES) and f.x.dtype == np.float32
    assert np.isfinite(f.x).all()
    assert f.valid[0].sum() == 0 and f.valid[3].sum() == 3 and f.valid[50].all()
    assert (f.x[~f.valid] == 0).all()  # absent candidates carry nothing
    net = tiny_net()
    h, logits = encode(net, f)
    assert h.shape == (toa.size, LAYOUT.window, 8) and logits.shape == (toa.size, LAYOUT.window + 2)
    chain = chain_features(toa, np.arange(toa.size) - 3, f)  # any chains: pulse i follows i - 3
    assert chain.shape == (toa.size, LAYOUT.window, 6) and np.isfinite(chain).all()
    with torch.no_grad():
        full = net(torch.from_numpy(f.x), torch.from_numpy(f.valid), torch.from_numpy(chain)).numpy()
    assert np.array_equal(np.isneginf(full), np.isneginf(logits))
    assert np.isneginf(logits[3, 3:LAYOUT.window]).all() and np.isfinite(logits[3, :3]).all()
    assert np.isfinite(logits[:, LAYOUT.window:]).all()  # "new" and "spurious" are always offered


def test_a_label_never_depends_on_pulses_beyond_its_lag():
    """Streams that agree on their first m pulses give the same labels to pulses 0..m-1-lag, however
    the rest differs (features and decoder alike); so does the policy, pulse by pulse."""
    net = tiny_net()
    toa, _ = stream(seed=1)
    full, _ = label_episode(net, LAYOUT, toa, None, 8)
    for m in (20, 57, 120):
        other = toa.copy()
        other[m:] = np.sort(toa[m - 1] + np.random.default_rng(m).uniform(0.1, 300, toa.size - m))
        alt, _ = label_episode(net, LAYOUT, other, None, 8)
        cut = m - LAYOUT.lag
        assert (alt[:cut] == full[:cut]).all()
        f1 = pair_features(toa, None, np.arange(cut), LAYOUT, toa.size)
        f2 = pair_features(other, None, np.arange(cut), LAYOUT, other.size)
        assert np.array_equal(f1.x, f2.x)
    # the look-ahead is used: the last pulse before the cut sees the changed pulses
    f1 = pair_features(toa, None, np.array([m - LAYOUT.lag]), LAYOUT, toa.size)
    f2 = pair_features(other, None, np.array([m - LAYOUT.lag]), LAYOUT, other.size)
    assert not np.array_equal(f1.x, f2.x)


def save_tiny(path, net=None, layout=LAYOUT):
    net = net or tiny_net()
    meta = CheckpointMeta(architecture=net.architecture(), features=layout.to_dict(), algorithm="seq",
                          scenarios=["blind-v0/blind-n2to2-jitter0.1"], suite_hashes={}, train_seeds=[0, 99000],
                          timesteps=0, hyperparameters={}, versions={})
    return save_checkpoint(path, net.state_dict(), meta)


@pytest.mark.parametrize("batch", [1, 5])
def test_checkpoint_round_trip_and_policy_matches_batch_labelling(tmp_path, batch):
    """The policy rebuilt from the file labels an env episode exactly as the in-memory network labels
    the whole stream at once; batching changes the lag, not the labels."""
    net = tiny_net(3)
    key = save_tiny(tmp_path / "s.safetensors", net)
    ck = load_checkpoint(tmp_path / "s.safetensors")
    assert ck.key == key and ck.meta.architecture["name"] == "seq-pointer"
    pol = SequencePolicy(str(tmp_path / "s.safetensors"), batch=batch)
    from deint_env.policies import make_policy
    assert isinstance(make_policy(f"agent:checkpoint={tmp_path / 's.safetensors'}"), SequencePolicy)
    assert pol.lag == LAYOUT.lag + batch - 1 and pol.version.startswith(key)
    for k, v in net.state_dict().items():
        assert torch.equal(pol.net.state_dict()[k], v)
    ep = simulate(find_entry("blind-v0/blind-n3to3-jitter0.1").spec, 5)
    res = play(pol, ep)
    want, chains = label_episode(net, LAYOUT, ep.toa, ep.amplitude, ep.n_labels)
    assert np.array_equal(res.labels, want) and pol.decoder.chains == chains
    assert sum(pol.decoder.lengths) == int(np.sum(res.labels < ep.n_labels))


def test_refusals(tmp_path):
    save_tiny(tmp_path / "s.safetensors")
    pol = SequencePolicy(str(tmp_path / "s.safetensors"))
    ep = simulate(find_entry("core-v0/core-n2-spread4-jitter0.05").spec, 0)
    with pytest.raises(NotApplicable, match="blind scenarios only"):
        play(pol, ep)
    with pytest.raises(ValueError, match="batch=0 is invalid"):
        SequencePolicy(str(tmp_path / "s.safetensors"), batch=0)
    (tmp_path / "bad.safetensors").write_bytes(b"\x80\x04junk")
    with pytest.raises(DeintError, match="never unpickled"):
        SequencePolicy(str(tmp_path / "bad.safetensors"))
    with pytest.raises(DeintError, match="context=4 must be >= window=8"):
        SeqLayout(window=8, context=4)


def test_pointer_targets_name_true_predecessors():
    ep = simulate(find_entry("blind-v0/blind-n3to3-jitter0.1").spec, 1)
    y = pointer_targets(ep, np.arange(len(ep)), 32)
    pred = np.arange(len(ep)) - 1 - y
    linked = y < 32
    assert linked.mean() > 0.95
    assert (ep.source[pred[linked]] == ep.source[linked]).all()
    # decoding the true pointers gives (almost) every link right
    dec = ChainDecoder(ep.n_labels, 32)
    onehot = np.full((len(ep), 34), -1.0)
    onehot[np.arange(len(ep)), y] = 1.0
    labels = np.array([dec.decode(r) for r in onehot])
    assert np.mean(correct_link(labels, ep.source, ep.mask, ep.n_labels)) > 0.99
    assert np.array_equal(np.array(dec.pred)[linked], chain_truth(ep)[linked])  # the chains are the truth's


def test_train_entry_writes_a_resumable_checkpoint(tmp_path):
    from agents.config import TrainConfig
    from agents.train import train

    hp = tmp_path / "seq.yml"
    hp.write_text("default:\n  window: 8\n  context: 16\n  episodes_per_step: 1\n  pulses_per_episode: 16\n"
                  "  validation_episodes: 1\n  d_model: 8\n  heads: 2\n  layers: 1\n  ff: 16\n  own_chains: 1.0\n")
    cfg = TrainConfig(out=tmp_path / "run", algo="seq", scenarios=("blind-v0/blind-n2to2-jitter0.1",), lag=2,
                      timesteps=32, eval_every=16, hyperparams_file=hp, progress=False)
    res = train(cfg)
    meta = load_checkpoint(res.last).meta
    assert res.timesteps == 32 and len(res.evaluations) == 2
    assert meta.algorithm == "seq" and meta.features["lag"] == 2 and meta.train_seeds == [0, 99000]
    assert meta.suite_hashes.keys() == {"blind-v0"} and meta.hyperparameters["window"] == 8
    again = train(TrainConfig(**{**cfg.__dict__, "timesteps": 48}))
    assert again.timesteps == 48 and len(again.evaluations) == 1  # resumed at 32
    with pytest.raises(DeintError, match="blind scenarios only"):
        train(TrainConfig(out=tmp_path / "r2", algo="seq", scenarios=("core-v0/core-n2-spread4-jitter0.05",),
                          hyperparams_file=hp, progress=False))


TINY_SEQ = ("  window: 8\n  context: 16\n  episodes_per_step: 1\n  pulses_per_episode: 16\n  validation_episodes: 1\n"
            "  d_model: 8\n  heads: 2\n  layers: 1\n  ff: 16\n  chain_dropout: 0.1\n")


def deint_train(*args: str) -> None:
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", "from deint_env.cli import main; raise SystemExit(main())", "train",
                          "--algo", "seq", "--scenario", "blind-v0/blind-n2to2-jitter0.1", "--lag", "2",
                          "--no-progress", *args], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr


def test_phases_in_the_yaml_are_the_two_commands_run_by_hand(tmp_path):
    """One `deint train` of a YAML entry with phases gives bitwise the weights of its phases run as
    separate `deint train` commands, each a fresh process, the second resuming from the first's
    last.safetensors."""
    from agents.config import TrainConfig
    from agents.train import train

    recipe = tmp_path / "recipe.yml"
    recipe.write_text("default:\n" + TINY_SEQ + "  own_chains: 0.5\n  phases:\n"
                      "    - {n_timesteps: 40, own_chains: 0.0, seed: 0, eval_every: 16}\n"
                      "    - {n_timesteps: 72, own_chains: 1.0, seed: 1, eval_every: 24}\n")
    first, second = tmp_path / "first.yml", tmp_path / "second.yml"
    first.write_text("default:\n" + TINY_SEQ + "  own_chains: 0.0\n")
    second.write_text("default:\n" + TINY_SEQ + "  own_chains: 1.0\n")
    config = TrainConfig(out=tmp_path / "one", algo="seq", scenarios=("blind-v0/blind-n2to2-jitter0.1",), lag=2,
                         hyperparams_file=recipe, progress=False)
    assert train(config).timesteps == 80  # the one command (in this process: the phases share it)
    deint_train("--hyperparams", str(first), "--timesteps", "40", "--eval-every", "16", "--seed", "0",
                "-o", str(tmp_path / "two"))
    after_first = load_checkpoint(tmp_path / "two" / "last.safetensors")
    deint_train("--hyperparams", str(second), "--timesteps", "72", "--eval-every", "24", "--seed", "1",
                "-o", str(tmp_path / "two"))
    for name in ("last", "best"):
        one, two = (load_checkpoint(tmp_path / d / f"{name}.safetensors") for d in ("one", "two"))
        assert one.meta.timesteps == two.meta.timesteps and one.tensors.keys() == two.tensors.keys()
        assert all(torch.equal(one.tensors[k], two.tensors[k]) for k in one.tensors), name
    one = load_checkpoint(tmp_path / "one" / "last.safetensors")
    assert one.meta.timesteps == 80 and after_first.meta.timesteps == 48  # 16 pulses a step: 3 + 2 steps
    assert one.meta.notes["phase"] == "2/2" and one.meta.hyperparameters["own_chains"] == 1.0
    assert not all(torch.equal(one.tensors[k], after_first.tensors[k]) for k in one.tensors)  # phase 2 trained
    evals = [json.loads(x)["timesteps"] for x in (tmp_path / "one" / "eval.jsonl").read_text().splitlines()]
    assert evals == [16, 32, 48, 80]  # phase 2 validates first at 48 + 24 -> 80
    assert train(config).timesteps == 80 and len((tmp_path / "one" / "eval.jsonl").read_text().splitlines()) == 4
    # (a rerun finds both phases done)
    with pytest.raises(DeintError, match="--timesteps does not apply"):
        train(TrainConfig(out=tmp_path / "x", algo="seq", scenarios=("blind-v0/blind-n2to2-jitter0.1",),
                          timesteps=10, hyperparams_file=recipe, progress=False))


def independent_pulses(periods, n, sigma, rng):
    """Pulse trains made here, not by the simulator: random phases, white TOA noise."""
    toa, src = [], []
    for i, p in enumerate(periods):
        t = rng.uniform(0, p) + p * np.arange(int(4 * n * max(periods) / p / len(periods)) + 2)
        toa.append(t + rng.normal(0, sigma, t.size)), src.append(np.full(t.size, i))
    toa, src = np.concatenate(toa), np.concatenate(src)
    order = np.argsort(toa, kind="stable")[:n]
    return toa[order], src[order]


def true_links(src):
    last, out = {}, []
    for k, s in enumerate(src.tolist()):
        out.append(last.get(s, -1))
        last[s] = k
    return np.array(out)


def label_links(labels):
    last, out = {}, []
    for k, lab in enumerate(labels.tolist()):
        out.append(last.get(lab, -1) if lab >= 0 else -2)
        if lab >= 0:
            last[lab] = k
    return np.array(out)


def test_shipped_checkpoint_labels_an_independent_pulse_file(tmp_path, capsys):
    toa, src = independent_pulses([13.0, 31.0, 57.0], 600, 0.1, np.random.default_rng(11))
    (tmp_path / "p.csv").write_text("toa\n" + "\n".join(repr(float(t)) for t in toa) + "\n")
    acc = {}
    for policy in ("seq", "random"):
        code = main(["label", str(tmp_path / "p.csv"), "--policy", policy, "--n-sources", "8",
                     "-o", str(tmp_path / "out.csv")])
        assert code == 0, capsys.readouterr().err
        labels = np.array([int(r.split(",")[1]) for r in (tmp_path / "out.csv").read_text().split()[1:]])
        assert labels.size == toa.size
        acc[policy] = float(np.mean(label_links(labels) == true_links(src)))
    assert acc["seq"] > 0.9 and acc["random"] < 0.3, acc
    meta = load_checkpoint(CHECKPOINT).meta
    assert meta.algorithm == "seq" and all(s.startswith("blind-v0/") for s in meta.scenarios)
    assert meta.train_seeds[1] <= 100_000 and meta.features["lag"] == SequencePolicy().lag

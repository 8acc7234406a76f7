"""Turing Deinterleaving Challenge interoperability: its HDF5 files, its Deinterleaver models as
policies, and its metric set (deint_env.formats.tdc, baselines.tdc_adapter, deint_env.tdc_scores)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from sklearn import metrics as skm

from baselines import tdc_adapter
from deint_env import tdc_scores
from deint_env.formats import tdc
from deint_env.cli import main
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.metrics import clustering_metrics
from deint_env.policies import make_policy
from deint_env.runner import play


# ---- tiny stand-ins for TDC Deinterleaver models (their interface, duck-typed) -------------------
class ColumnModel:
    """New-style: called on one (seq_len, n_features) train; clusters by the rounded value of one
    column; pulses whose value is below `floor` get the default label -1."""

    default_label = -1

    def __init__(self, column: int = -1, floor: float = -np.inf):
        self.column, self.floor = column, floor
        self.calls: list[tuple[int, ...]] = []

    def __call__(self, data):
        self.calls.append(np.shape(data))
        if np.ndim(data) != 2:
            raise ValueError("one train (seq_len, n_features) at a time")
        x = np.asarray(data)[:, self.column]
        return np.where(x < self.floor, -1, np.round(x)).astype(int)


class BatchModel:
    """Old-style: called on a (batch, seq_len, n_features) batch; returns (batch, seq_len) float ids."""

    def __init__(self):
        self.calls: list[tuple[int, ...]] = []

    def __call__(self, data):
        self.calls.append(np.shape(data))
        return np.round(np.asarray(data)[:, :, -1]).astype(np.float64)


class FrequencyModel(ColumnModel):
    """For `deint label` on a TDC file: clusters by the frequency column (column 1 of TDC's order)."""

    def __init__(self):
        super().__init__(column=1)


def synthetic(n_per: int = 60, seed: int = 0, noise: int = 5):
    """Three emitters (emitter ids 3, 7, 11) with distinct frequency and amplitude, plus noise pulses."""
    rng = np.random.default_rng(seed)
    toa, labels, freq, amp = [], [], [], []
    for k, (eid, period, f, a) in enumerate([(3, 7.0, 9100.0, 2.0), (7, 11.0, 9400.0, 5.0), (11, 13.0, 9700.0, 8.0)]):
        t = 0.3 * k + period * np.arange(n_per) + rng.normal(0, 0.05, n_per)
        toa.append(t), labels.append(np.full(n_per, eid)), freq.append(np.full(n_per, f)), amp.append(np.full(n_per, a))
    toa.append(rng.uniform(0, 7.0 * n_per, noise)), labels.append(np.full(noise, -1))
    freq.append(np.full(noise, 9999.0)), amp.append(np.full(noise, 0.0))
    toa, labels, freq, amp = map(np.concatenate, (toa, labels, freq, amp))
    order = np.argsort(toa, kind="stable")
    pw = np.round(rng.uniform(0.5, 2.0, toa.size), 2)
    return toa[order], amp[order], labels[order], {"frequency": freq[order], "pulse_width": pw[order]}


def deint(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# ---- files ---------------------------------------------------------------------------------------
def test_written_file_reads_back_identically(tmp_path):
    toa, amp, labels, feats = synthetic()
    for dtype in ("float64", "float32"):
        path = tmp_path / f"train-{dtype}.h5"
        wrote = tdc.write_tdc(path, toa, amp, labels, feats, dtype=dtype)
        got = tdc.read_tdc(path)
        cast = lambda x: np.asarray(x).astype(dtype).astype(np.float64)  # noqa: E731
        assert got.data.dtype == np.dtype(dtype)
        assert got.feature_names == ("time_of_arrival", "frequency", "pulse_width", "amplitude")
        assert got.columns == ("toa", "frequency", "pulse_width", "amplitude") == wrote.columns
        assert np.array_equal(got.toa, cast(toa)) and np.array_equal(got.amplitude, cast(amp))
        assert all(np.array_equal(got.features[k], cast(v)) for k, v in feats.items())
        assert np.array_equal(got.labels, labels) and got.labels.dtype == np.int64
        assert got.metadata == {"type": "synthetic", "num_pulses": toa.size}
        # a second generation is the same file, byte for byte
        again = tmp_path / f"again-{dtype}.h5"
        got.write(again, dtype)
        assert again.read_bytes() == path.read_bytes()
    # float32-representable inputs survive the TDC's own dtype exactly
    t32 = toa.astype(np.float32).astype(np.float64)
    tdc.write_tdc(tmp_path / "exact.h5", t32, None, labels)
    assert np.array_equal(tdc.read_tdc(tmp_path / "exact.h5").toa, t32)


def test_on_disk_layout_is_the_tdc_one(tmp_path):
    toa, amp, labels, feats = synthetic()
    tdc.write_tdc(tmp_path / "t.h5", toa, amp, labels, feats, description="layout")
    with h5py.File(tmp_path / "t.h5", "r") as f:
        assert set(f) == {"data", "labels", "metadata"}
        assert f["data"].dtype == np.float32 and f["data"].shape == (toa.size, 4)
        assert f["data"].compression == "gzip" and f["data"].compression_opts == 9
        assert f["labels"].dtype == np.int8 and f["labels"].shape == (toa.size,)
        names = f["metadata/feature_names"]
        assert names.dtype.kind == "S" and [n.decode() for n in names[()]][0] == "time_of_arrival"
        assert dict(f["metadata"].attrs) == {"type": "synthetic", "num_pulses": toa.size, "description": "layout"}


def write_like_the_tdc(path: Path, data, labels, names, labels_column=False):
    """A file laid out as the challenge's PulseTrain.save lays it out (an independent writer)."""
    with h5py.File(path, "w") as f:
        meta = f.create_group("metadata")
        meta.create_dataset("feature_names", data=np.array(names, dtype="S"))
        meta.attrs["type"] = "synthetic"
        meta.attrs["num_pulses"] = len(data)
        meta.attrs["date_created"] = "2025-05-15T10:00:00"
        tx = meta.create_group("transmitters").create_group("item_0")
        tx.attrs["pri_us"] = 100.0
        f.create_dataset("data", data=np.asarray(data), dtype=np.float32, compression="gzip", compression_opts=9)
        lab = np.asarray(labels).reshape(-1, 1) if labels_column else np.asarray(labels)
        f.create_dataset("labels", data=lab, dtype=np.int8, compression="gzip", compression_opts=9)


def test_reads_tdc_written_files_with_their_spellings(tmp_path):
    toa, amp, labels, feats = synthetic()
    aoa = np.linspace(0, 90, toa.size)
    data = np.stack([toa, feats["frequency"], feats["pulse_width"], aoa, amp], axis=1)
    names = ["ToA (us)", "Frequency (MHz)", "Pulse Width (us)", "Angle of Arrival (deg)", "Amplitude (dBm)"]
    write_like_the_tdc(tmp_path / "theirs.h5", data, labels, names, labels_column=True)
    got = tdc.read_tdc(tmp_path / "theirs.h5")
    assert got.columns == ("toa", "frequency", "pulse_width", "angle_of_arrival", "amplitude")
    assert got.feature_names == tuple(names)
    assert np.array_equal(got.toa, toa.astype(np.float32)) and np.array_equal(got.labels, labels)
    assert got.metadata["date_created"] == "2025-05-15T10:00:00"
    table = got.pulse_table()
    assert table.n_sources == 3 and np.array_equal(table.source, np.searchsorted([3, 7, 11], labels) * (labels >= 0)
                                                   - (labels < 0))
    for short in (["toa", "f", "pw", "aoa", "a"], ["ToA", "F", "PW", "AoA", "A"],
                  ["time_of_arrival", "frequency", "pulse_width", "angle_of_arrival", "amplitude"]):
        write_like_the_tdc(tmp_path / "s.h5", data, labels, short)
        assert tdc.read_tdc(tmp_path / "s.h5").columns == got.columns


def bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    good = np.array([[1.0, 9.0], [2.0, 9.5], [3.0, 9.0]])
    cases = {}

    def make(name, data=good, labels=(0, 1, 0), names=("toa", "f"), drop=(), expected=""):
        path = tmp_path / f"{name}.h5"
        with h5py.File(path, "w") as f:
            if "metadata" not in drop:
                g = f.create_group("metadata")
                if "names" not in drop:
                    g.create_dataset("feature_names", data=np.array(names, dtype="S"))
            if "data" not in drop:
                f.create_dataset("data", data=np.asarray(data))
            if labels is not None:
                f.create_dataset("labels", data=np.asarray(labels))
        cases[name] = (path, expected)

    make("nodata", drop=("data",), expected="no 'data' dataset")
    make("nometa", drop=("metadata",), expected="no 'metadata' group")
    make("nonames", drop=("names",), expected="no 'metadata/feature_names' dataset")
    make("width", names=("toa",), expected="metadata/feature_names has 1 names but data has 2 columns")
    make("unknown", names=("toa", "chirp"), expected="feature name 'chirp' (column 1) is unknown")
    make("twice", names=("toa", "ToA"), expected="feature name 'ToA' (column 1) names toa a second time")
    make("notoa", names=("f", "pw"), expected="no time-of-arrival column")
    make("unsorted", data=[[1.0, 9.0], [3.0, 9.5], [2.0, 9.0]],
         expected="data[2, 0] (toa) = 2.0 is smaller than data[1, 0] = 3.0")
    make("nan", data=[[1.0, 9.0], [2.0, np.nan], [3.0, 9.0]], expected="data[1, 1] (f) = nan is not finite")
    make("empty", data=np.zeros((0, 2)), labels=np.zeros(0), expected="data has no pulses")
    make("onedim", data=[1.0, 2.0], names=("toa",), expected="data has shape (2,); TDC data is 2-D")
    make("labels", labels=(0, 1), expected="labels has shape (2,) but data has 3 rows")
    make("fraction", labels=(0.0, 1.5, 0.0), expected="labels[1] = 1.5 is not an integer emitter id")
    (tmp_path / "text.h5").write_text("toa\n1\n")
    cases["text"] = (tmp_path / "text.h5", "is not a readable HDF5 file")
    cases["missing"] = (tmp_path / "missing.h5", "missing.h5: no such file")
    return cases


def test_bad_files_are_one_line_errors(tmp_path, capsys):
    for name, (path, expected) in bad_files(tmp_path).items():
        with pytest.raises(DeintError) as e:
            tdc.read_tdc(path)
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith(str(path)) and expected in msg, (name, msg)
        code, out, err = deint(capsys, "label", path, "--policy", "random", "--n-sources", 2, "-o", tmp_path / "l.csv")
        assert code == 2 and out == "" and err.count("\n") == 1 and expected in err, (name, err)
    assert not (tmp_path / "l.csv").exists()


def test_writes_are_checked_and_atomic(tmp_path):
    path = tmp_path / "t.h5"
    tdc.write_tdc(path, [1.0, 2.0], None, [0, 1])
    before = path.read_bytes()
    for args, kw, expected in [
        (([1.0, 2.0], None, [0, 300]), {}, "label 300 does not fit TDC's int8 labels"),
        (([2.0, 1.0],), {}, "is smaller than"),
        (([1.0, np.inf],), {}, "is not finite"),
        (([1.0, 2.0],), {"features": {"chirp": [1, 2]}}, "feature 'chirp' is unknown"),
        (([1.0, 2.0],), {"features": {"f": [1, 2], "cf": [1, 2]}}, "is given twice"),
        (([1.0, 2.0], [1.0]), {}, "feature amplitude has shape (1,)"),
        (([1.0, 2.0],), {"dtype": "float16"}, "dtype='float16' is invalid"),
    ]:
        with pytest.raises(DeintError) as e:
            tdc.write_tdc(path, *args, **kw)
        assert expected in str(e.value), str(e.value)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["t.h5"]


def test_h5py_stays_optional():
    code = ("import sys, deint_env, deint_env.cli, deint_env.runner; from deint_env.policies import list_policies; "
            "names = [p.name for p in list_policies()]; assert 'tdc' in names, names; "
            "assert 'h5py' not in sys.modules and 'ray' not in sys.modules, 'imported too early'")
    subprocess.run([sys.executable, "-c", code], check=True)


# ---- metrics ---------------------------------------------------------------------------------------
def reference_cluster_wise(true, pred, score):
    """The challenge's definition, straight from scikit-learn: best cluster per emitter, worst emitter."""
    fn = {"mcc": skm.matthews_corrcoef, "f1": skm.f1_score}[score]
    return min(max(fn((pred == c).astype(int), (true == t).astype(int)) for c in np.unique(pred))
               for t in np.unique(true))


@pytest.mark.parametrize("seed", range(4))
def test_tdc_scores_equal_scikit_learn(seed):
    rng = np.random.default_rng(seed)
    true = rng.choice([-1, 3, 7, 11, 20], size=300, p=[0.1, 0.3, 0.3, 0.2, 0.1])
    pred = np.where(rng.random(300) < 0.7, true, rng.integers(-1, 6, 300))
    got = tdc_scores.tdc_scores(true, pred)
    want = {"homogeneity": skm.homogeneity_score(true, pred), "completeness": skm.completeness_score(true, pred),
            "v_measure": skm.v_measure_score(true, pred), "ari": skm.adjusted_rand_score(true, pred),
            "ami": skm.adjusted_mutual_info_score(true, pred), "mcc": reference_cluster_wise(true, pred, "mcc"),
            "f1": reference_cluster_wise(true, pred, "f1"), "discount": 1.0}
    assert got == pytest.approx(want, abs=1e-12)
    # their noise convention: pulses whose true label is the model's default label are left out and
    # every score is discounted by the share kept
    keep = true != -1
    masked = tdc_scores.tdc_scores(true, pred, default_label=-1)
    ratio = keep.mean()
    assert masked["discount"] == pytest.approx(ratio)
    assert masked["v_measure"] == pytest.approx(ratio * skm.v_measure_score(true[keep], pred[keep]))
    assert masked["mcc"] == pytest.approx(ratio * reference_cluster_wise(true[keep], pred[keep], "mcc"))
    # our clustering metrics on the same labels (noise -1 as one more class, as TDC scores it
    # without a default label) are scikit-learn's
    ours = clustering_metrics(true, pred)
    for key in ("v_measure", "homogeneity", "completeness", "ari", "ami"):
        assert ours[key] == pytest.approx(want[key], abs=1e-12), key


def test_scored_file_equals_scikit_learn(tmp_path, capsys):
    """The acceptance check: a TDC file written by our writer reads back identically, and `deint
    score` on it equals scikit-learn on the same labels."""
    toa, amp, labels, feats = synthetic(seed=3)
    rng = np.random.default_rng(1)
    pred = np.where(rng.random(toa.size) < 0.8, labels, rng.integers(0, 4, toa.size))
    tdc.write_tdc(tmp_path / "truth.h5", toa, amp, labels, feats)
    tdc.write_tdc(tmp_path / "pred.h5", toa, amp, pred, feats)
    truth, guess = tdc.read_tdc(tmp_path / "truth.h5"), tdc.read_tdc(tmp_path / "pred.h5")
    assert np.array_equal(truth.labels, labels) and np.array_equal(guess.labels, pred)
    code, out, err = deint(capsys, "score", tmp_path / "pred.h5", "--truth", tmp_path / "truth.h5", "--json")
    assert code == 0, err
    got = json.loads(out)
    assert got["blind"] is True and got["n_emitters"] == 3 and got["n_pulses"] == toa.size
    assert got["v_measure"] == pytest.approx(skm.v_measure_score(labels, pred), abs=1e-12)
    assert got["ari"] == pytest.approx(skm.adjusted_rand_score(labels, pred), abs=1e-12)
    assert got["ami"] == pytest.approx(skm.adjusted_mutual_info_score(labels, pred), abs=1e-12)
    assert got["homogeneity"] == pytest.approx(skm.homogeneity_score(labels, pred), abs=1e-12)
    assert got["completeness"] == pytest.approx(skm.completeness_score(labels, pred), abs=1e-12)
    assert got["cluster_mcc"] == pytest.approx(reference_cluster_wise(labels, pred, "mcc"), abs=1e-12)
    assert got["cluster_f1"] == pytest.approx(reference_cluster_wise(labels, pred, "f1"), abs=1e-12)
    # the same labels as a CSV label file score the same
    (tmp_path / "pred.csv").write_text("toa,label\n" + "".join(
        f"{t!r},{p}\n" for t, p in zip(truth.toa.tolist(), pred.tolist())))
    code, out, err = deint(capsys, "score", tmp_path / "pred.csv", "--truth", tmp_path / "truth.h5", "--json")
    assert code == 0, err
    assert json.loads(out)["v_measure"] == pytest.approx(got["v_measure"], abs=1e-12)


def test_many_emitters_score_by_clustering_alone():
    rng = np.random.default_rng(0)
    true = rng.integers(0, 200, 4000)  # beyond a truth table's 128 sources
    pred = np.where(rng.random(4000) < 0.9, true, 0)
    got = tdc_scores.score_labels(pred, true)
    assert got["n_emitters"] == 200 and "accuracy" not in got
    assert got["v_measure"] == pytest.approx(skm.v_measure_score(true, pred), abs=1e-12)


def test_ninety_emitters_get_the_label_metrics_too():
    rng = np.random.default_rng(0)
    true = rng.integers(0, 90, 2000)  # TSRD trains have up to 90 emitters: beyond a 64-bit mask, within 128
    got = tdc_scores.score_labels(true, true)
    assert got["n_emitters"] == 90 and got["accuracy"] == 1.0 and got["matched_accuracy"] == 1.0
    assert len(got["pe"]) == 90 and max(got["pe"]) == 0.0


# ---- models as policies ------------------------------------------------------------------------------
def blind_episode(n_labels: int = 6, **kw):
    toa, amp, labels, feats = synthetic(**kw)
    train = tdc.TDCTrain.from_columns(toa, amp, labels, feats)
    return train, train.episode(Priors(n_labels=n_labels, blind=True))


def test_whole_window_policy_equals_labelling_the_train():
    train, episode = blind_episode()
    model = ColumnModel(floor=0.5)  # the amplitude column; the noise pulses (amplitude 0) get -1
    policy = tdc_adapter.from_deinterleaver(model, window=len(episode))
    assert policy.lag == len(episode) - 1 and policy.noise_label == -1
    res = play(policy, episode)
    direct = tdc_adapter.label_episode(ColumnModel(floor=0.5), episode)
    assert np.array_equal(res.labels, direct)
    assert model.calls == [(1, len(episode), 2), (len(episode), 2)]  # batch of one refused, bare train taken
    spur = episode.n_labels
    assert set(res.labels[episode.source < 0].tolist()) == {spur} and res.metrics["v_measure"] == pytest.approx(1.0)
    assert res.metrics["accuracy"] == pytest.approx(1.0)  # every link right, spurious pulses included


@pytest.mark.parametrize("window", [1, 7, 50, 10_000])
def test_windows_label_each_block_on_its_own(window):
    train, episode = blind_episode(n_labels=3)
    model = BatchModel()
    res = play(tdc_adapter.from_deinterleaver(model, window=window), episode)
    rows = tdc_adapter.episode_input(episode)
    want = np.concatenate([tdc_adapter.to_blind_labels(np.round(rows[i:i + window, -1]).astype(int), 3)
                           for i in range(0, len(episode), window)])
    assert np.array_equal(res.labels, want)
    assert all(len(c) == 3 and c[0] == 1 for c in model.calls)  # always the batch convention


def test_label_budget_overflow():
    ids = np.array([5, 5, 9, 2, -1, 9, 4, 2])
    assert tdc_adapter.to_blind_labels(ids, 2).tolist() == [0, 0, 1, 2, 2, 1, 2, 2]  # first-seen; -1 a cluster too
    assert tdc_adapter.to_blind_labels(ids, 3, noise_label=-1).tolist() == [0, 0, 1, 2, 3, 1, 3, 2]
    with pytest.raises(NotApplicable, match="found 4 emitters in a window; the label budget is 3"):
        tdc_adapter.to_blind_labels(ids, 3, noise_label=-1, overflow="raise")


def test_registered_policy_and_its_errors():
    policy = make_policy("tdc:model=test_tdc:FrequencyModel,window=20,batched=false")
    assert policy.lag == 19 and policy.batched is False and isinstance(policy.model, FrequencyModel)
    _, episode = blind_episode()
    with pytest.raises(NotApplicable, match="blind scenarios only"):
        policy.reset(Priors.from_json_dict({"period": [1.0, 2.0]}), {})
    for spec, expected in [("tdc", "model"), ("tdc:model=nomodule", "write package.module:Name"),
                           ("tdc:model=no_such_module_xyz:M", "cannot import no_such_module_xyz"),
                           ("tdc:model=test_tdc:Nope", "has no attribute 'Nope'"),
                           ("tdc:model=test_tdc:FrequencyModel,window=0", "window=0 is invalid"),
                           ("tdc:model=test_tdc:FrequencyModel,window=10002", r"window=10002 is invalid: an integer in \[1, 10001\]")]:
        with pytest.raises(DeintError, match=expected):
            make_policy(spec)

    class Broken:
        def __call__(self, data):
            return np.zeros(3)

    with pytest.raises(DeintError, match="returned shape"):
        play(tdc_adapter.from_deinterleaver(Broken(), window=10), episode)


def test_label_and_score_a_tdc_file_with_a_model(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    toa, amp, labels, feats = synthetic(seed=2)
    tdc.write_tdc("truth.h5", toa, amp, labels, feats)
    spec = "tdc:model=test_tdc:FrequencyModel,window=10001"
    code, _, err = deint(capsys, "label", "truth.h5", "--policy", spec, "--n-sources", 8, "-o", "pred.h5")
    assert code == 0, err
    pred = tdc.read_tdc("pred.h5")
    truth = tdc.read_tdc("truth.h5")
    assert pred.feature_names == truth.feature_names and np.array_equal(pred.data, truth.data)
    # the model saw the frequency column of the file: a perfect clustering (noise is one more cluster)
    assert skm.v_measure_score(labels, pred.labels) == pytest.approx(1.0)
    code, out, err = deint(capsys, "score", "pred.h5", "--truth", "truth.h5", "--json")
    assert code == 0 and json.loads(out)["v_measure"] == pytest.approx(1.0)
    # CSV output, and anchored priors are refused in one line
    code, _, err = deint(capsys, "label", "truth.h5", "--policy", spec, "--n-sources", 8, "-o", "pred.csv")
    assert code == 0 and Path("pred.csv").read_text().startswith("toa,label\n")
    code, _, err = deint(capsys, "label", "truth.h5", "--policy", spec, "--prior-periods", "7,11,13", "-o", "x.csv")
    assert code == 2 and "blind scenarios only" in err and err.count("\n") == 1 and not Path("x.csv").exists()


def test_convert_round_trip(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert deint(capsys, "simulate", "robust-v0/robust-merged1", "--seed", 3, "-o", "p.csv")[0] == 0
    code, _, err = deint(capsys, "tdc", "convert", "p.csv", "p.h5", "--float64")
    assert code == 0 and "merged pulses keep their primary source only" in err, err
    code, _, err = deint(capsys, "tdc", "convert", "p.h5", "back.csv")
    assert code == 0, err
    from deint_env.formats import read_pulse_table

    a, b = read_pulse_table("p.csv"), read_pulse_table("back.csv")
    assert np.array_equal(a.toa, b.toa) and np.array_equal(a.source, b.source)
    assert (a.amplitude is None) == (b.amplitude is None)
    code, _, err = deint(capsys, "tdc", "convert", "p.csv", "q.csv")
    assert code == 2 and "between a CSV pulse file and a TDC file" in err

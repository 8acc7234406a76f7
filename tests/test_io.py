"""Pulse, label and priors files: exact round trips, strict one-line validation, atomic writes."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from deint_env import formats as io
from deint_env.episode import Priors
from deint_env.errors import DeintError
from deint_env.scenario import PriorSpec, ScenarioSpec, SourceSpec
from deint_env.simulate import simulate
from deint_env.suites import resolve_scenario

# amplitudes, merged pulses (including three-way merges) and spurious pulses in one short episode
RICH = ScenarioSpec(
    name="io-rich", n_pulses=600, toa_jitter_std=0.1, coincidence_resolution=0.6, spurious_rate=0.1,
    amplitudes=True, amplitude_noise_std=0.05,
    sources=(SourceSpec(period=10.0, amplitude=1.0), SourceSpec(period=13.0, amplitude=2.0),
             SourceSpec(period=17.0, amplitude=3.0)),
    priors=PriorSpec(period_error=0.01, phase_error=0.1))


def merged(mask: np.ndarray) -> np.ndarray:
    return np.bitwise_and(mask, mask - np.uint64(1)) != 0


def write(path, text: str):
    path.write_text(text)
    return path


def error_of(fn, *args, **kwargs) -> str:
    with pytest.raises(DeintError) as e:
        fn(*args, **kwargs)
    msg = str(e.value)
    assert "\n" not in msg
    return msg


# ---- round trips ----------------------------------------------------------------------------------
def test_pulse_file_round_trip_is_exact(tmp_path):
    ep = simulate(RICH, 7)
    assert merged(ep.mask).any() and (ep.source < 0).any()
    path = tmp_path / "p.csv"
    io.write_pulses(path, ep)
    assert path.read_text().splitlines()[0] == "toa,amplitude,source,sources"
    t = io.read_pulse_table(path)
    for name in ("toa", "amplitude", "source", "mask"):
        assert getattr(t, name).dtype == getattr(ep, name).dtype and np.array_equal(getattr(t, name), getattr(ep, name))
    assert t.n_sources == 3
    back = io.read_pulses(path, ep.priors)
    assert back.truth is None and back.priors is ep.priors and np.array_equal(back.mask, ep.mask)


def test_pulse_file_without_truth_or_merges(tmp_path):
    ep = simulate(resolve_scenario("paper-v0/mk94-two-var1"), 3)
    io.write_pulses(tmp_path / "t.csv", ep)
    assert (tmp_path / "t.csv").read_text().startswith("toa,source\n")  # no merges: no sources column
    io.write_pulses(tmp_path / "n.csv", ep, truth=False)
    t = io.read_pulse_table(tmp_path / "n.csv")
    assert t.source is None and t.mask is None and t.amplitude is None and np.array_equal(t.toa, ep.toa)
    e = io.read_pulses(tmp_path / "n.csv", ep.priors)  # a policy's episode: placeholder truth columns
    assert not e.source.any() and not e.mask.any() and e.source.dtype == np.int32 and e.mask.dtype == np.uint64


def test_label_file_round_trip(tmp_path):
    toa = np.cumsum(np.random.default_rng(0).random(200)) * 1e3 + 1e-7
    labels = np.random.default_rng(1).integers(0, 4, 200)  # 3 = spurious
    io.write_labels(tmp_path / "l.csv", toa, labels, 3)
    lines = (tmp_path / "l.csv").read_text().splitlines()
    assert lines[0] == "toa,label"
    assert {ln.rsplit(",", 1)[1] for ln in lines[1:]} == {"-1", "0", "1", "2"}
    got = io.read_labels(tmp_path / "l.csv", toa, 3)
    assert np.array_equal(io.from_file_labels(got, 3), labels)
    assert np.array_equal(io.to_file_labels(labels, 3), got)


def test_priors_round_trip(tmp_path):
    for priors in (simulate(RICH, 1).priors, simulate(resolve_scenario("paper-v0/cm00-five-jitter0"), 2).priors,
                   simulate(resolve_scenario("blind-v0/blind-n2to5-jitter0.1"), 3).priors):
        io.write_priors(tmp_path / "pr.json", priors)
        a, b = priors.as_info(), io.read_priors(tmp_path / "pr.json").as_info()
        assert a.keys() == b.keys()
        for k in a:
            assert np.array_equal(a[k], b[k], equal_nan=True), k


def test_true_priors_hold_the_truth(tmp_path):
    ep = simulate(RICH, 4)
    io.write_priors(tmp_path / "t.json", io.true_priors(ep))
    p = io.read_priors(tmp_path / "t.json")
    assert np.array_equal(p.period, ep.truth.period) and np.array_equal(p.phase, ep.truth.phase)
    assert (p.jitter_std, p.spurious_rate, p.coincidence_resolution) == (0.1, 0.1, 0.6)


def test_quoted_fields_crlf_and_bom_are_read(tmp_path):
    p = tmp_path / "q.csv"
    p.write_bytes(b'\xef\xbb\xbf"toa","amplitude"\r\n"1.5",2\r\n3,4\r\n\r\n')
    t = io.read_pulse_table(p)
    assert t.toa.tolist() == [1.5, 3.0] and t.amplitude.tolist() == [2.0, 4.0]


# ---- validation -------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, expected", [
    ("", "the file is empty"),
    ("toa\n", "has a header but no pulses"),
    ("1.0\n2.0\n", "line 1: the header is missing"),
    ("amplitude\n1\n", "line 1: no 'toa' column"),
    ("toa,foo\n1,2\n", "line 1: column 'foo' is unknown; allowed: toa, amplitude, source, sources"),
    ("toa,toa\n1,2\n", "column 'toa' appears twice"),
    ("toa\n1\n3\n2\n", "line 4: toa=2.0 is smaller than the previous line's toa=3.0"),
    ("toa\n1\nnan\n", "line 3: toa=nan is not finite"),
    ("toa\n1\ninf\n", "line 3: toa=inf is not finite"),
    ("toa\n1\nabc\n", "line 3: toa='abc' is not a number"),
    ("toa,amplitude\n1,2\n2\n", "line 3: has 1 field; every line needs the header's 2 fields"),
    ("toa,amplitude\n1,2\n\n3,4\n", "line 3: is empty"),
    ("toa,source\n1,-2\n", "line 2: source='-2' is invalid; source must be an integer in [-1, 127]"),
    ("toa,source\n1,0.5\n", "source='0.5' is invalid"),
    ("toa,source,sources\n1,0,1|2\n", "line 2: sources='1|2' does not include the line's source=0"),
    ("toa,source,sources\n1,0,0|x\n", "sources='0|x' is invalid"),
    ("toa,sources\n1,0\n", "a 'sources' column needs a 'source' column"),
])
def test_bad_pulse_files(tmp_path, text, expected):
    path = write(tmp_path / "bad.csv", text)
    msg = error_of(io.read_pulse_table, path)
    assert msg.startswith(f"{path}: ") and expected in msg


def test_missing_file_and_directory(tmp_path):
    assert "no such file" in error_of(io.read_pulse_table, tmp_path / "nope.csv")
    assert "is a directory" in error_of(io.read_pulse_table, tmp_path)
    assert "no such file" in error_of(io.read_priors, tmp_path / "nope.json")


@pytest.mark.parametrize("text, n_labels, expected", [
    ("toa,label\n1,0\n2,1\n", None, "has 2 labels but the pulse file has 3 pulses"),
    ("toa,label\n1,0\n2,1\n3,5\n", 3, "line 4: label='5' is invalid; label must be an integer in [-1, 2] (-1 = spurious)"),
    ("toa,label\n1,0\n2,-2\n3,0\n", None, "label='-2' is invalid"),
    ("toa,label\n1,0\n2,0.5\n3,0\n", None, "label='0.5' is invalid"),
    ("toa,label\n1,0\n2.5,0\n3,0\n", None, "line 3: toa=2.5 differs from the toa on line 3 of the pulse file (2.0)"),
    ("toa\n1\n2\n3\n", None, "no 'label' column"),
    ("toa,label,source\n1,0,0\n", None, "column 'source' is unknown; allowed: toa, label"),
])
def test_bad_label_files(tmp_path, text, n_labels, expected):
    path = write(tmp_path / "l.csv", text)
    msg = error_of(io.read_labels, path, np.array([1.0, 2.0, 3.0]), n_labels)
    assert msg.startswith(f"{path}: ") and expected in msg


def test_label_toas_match_within_a_tiny_tolerance(tmp_path):
    toa = np.array([0.1, 0.2 + 1e-9, 1e6 / 3])
    path = write(tmp_path / "l.csv", "toa,label\n0.1,0\n0.200000001,1\n333333.33333333331,-1\n")
    assert io.read_labels(path, toa, 2).tolist() == [0, 1, -1]


@pytest.mark.parametrize("text, expected", [
    ('{"period": [1, 2', "line 1 column 17: not valid JSON"),
    ('{"period": [1, 2], "bogus": 1}', "key 'bogus' is unknown"),
    ('{"period": [NaN]}', "NaN is not a number JSON allows"),
    ('{"phase": [1]}', "'period' (a list of the sources' periods) is required"),
    ('[1, 2]', "must be a JSON object"),
])
def test_bad_priors_files(tmp_path, text, expected):
    path = write(tmp_path / "pr.json", text)
    msg = error_of(io.read_priors, path)
    assert str(path) in msg and expected in msg


def test_unreadable_priors_are_never_written(tmp_path):
    with pytest.raises(DeintError):
        io.write_priors(tmp_path / "pr.json", {"period": [-1.0]})
    assert not list(tmp_path.iterdir())


# ---- atomic writes ----------------------------------------------------------------------------------
@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_atomic_write_keeps_the_old_file_on_failure(tmp_path, exc):
    path = write(tmp_path / "out.csv", "good\n")
    with pytest.raises(exc):
        with io.atomic_write(path) as f:
            f.write("half")
            raise exc()
    assert path.read_text() == "good\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]  # no temporary file left behind


def test_atomic_write_replaces_and_gives_a_normal_mode(tmp_path):
    path = tmp_path / "new.csv"
    io.write_text(path, "a\n")
    umask = os.umask(0)
    os.umask(umask)
    assert path.read_text() == "a\n" and stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    os.chmod(path, 0o640)
    io.write_text(path, "b\n")
    assert path.read_text() == "b\n" and stat.S_IMODE(path.stat().st_mode) == 0o640
    assert "cannot write" in error_of(io.write_text, tmp_path / "no-dir" / "x.csv", "x")


def test_label_writer_rejects_bad_labels():
    with pytest.raises(DeintError):
        io.format_labels(np.array([1.0, 2.0]), np.array([0, 3]), 2)


def test_priors_from_simulation_are_public(tmp_path):
    spec = resolve_scenario("paper-v0/mk94-two-var1")
    ep = simulate(spec, 0)
    io.write_priors(tmp_path / "pr.json", ep.priors)
    p = io.read_priors(tmp_path / "pr.json")
    assert isinstance(p, Priors) and p.period.tolist() == [10.0, 22.0]  # the paper's x_{1|0}, not the truth

"""Pulse descriptor words (issue 28): the simulator's frequency, pulse width, AoA and scan-shaped
amplitudes follow their spec; descriptors are deterministic and leave a scenario's TOAs alone; the
envs observe them exactly when a scenario has them; challenge files keep them and play as scenarios;
bad descriptor fields are one-line errors.  (tests/test_episode_hashes.py pins the TOA-only suites.)"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import deint_env  # noqa: F401  (registers the env ids)
from deint_env.cli import main as deint_main
from deint_env.envs.deinterleave import TDC_LABELS
from deint_env.envs.vector import DeinterleaveVectorEnv
from deint_env.episode import Priors
from deint_env.errors import DeintError
from deint_env.formats import tdc
from deint_env.metrics import label_metrics
from deint_env.scenario import DescriptorSpec, PriorSpec, Range, ReceiverSpec, ScenarioSpec, SourceSpec
from deint_env.simulate import simulate, simulate_many
from deint_env.suites import resolve_scenario

BLIND = dict(blind=True, label_budget=16, priors=PriorSpec(kind="none"))


def one_emitter(d: DescriptorSpec, receiver: ReceiverSpec | None = None, n: int = 1000, **kw) -> ScenarioSpec:
    """One emitter, PRI 10 from t = 0, no noise unless asked: pulse k at TOA 10 k."""
    return ScenarioSpec(name="pdw-test", sources=(SourceSpec(period=10.0, phase=0.0, descriptors=d),), n_pulses=n,
                        amplitudes=True, receiver=receiver, **{**BLIND, **kw})


def test_frequencies_hop_within_their_set_and_widths_take_their_levels():
    d = DescriptorSpec(frequency=9000.0, frequency_hops=(0.0, 50.0, 100.0), pulse_width=2.0,
                       pulse_width_levels=(1.0, 3.0))
    ep = simulate(one_emitter(d), 0)
    assert set(np.unique(ep.frequency)) == {9000.0, 9050.0, 9100.0}
    assert set(np.unique(ep.pulse_width)) == {2.0, 6.0}
    for name in ("frequency", "pulse_width", "aoa"):
        x = getattr(ep, name)
        assert x.dtype == np.float64 and x.shape == ep.toa.shape


def test_drawn_centre_jitter_and_receiver_noise():
    d = DescriptorSpec(frequency=Range(8000.0, 12000.0), frequency_std=3.0, aoa=100.0)
    ep = simulate(one_emitter(d, ReceiverSpec(frequency_noise_std=4.0, aoa_noise_std=2.0), n=4000), 1)
    assert 8000 - 50 < ep.frequency.mean() < 12000 + 50
    assert ep.frequency.std() == pytest.approx(5.0, rel=0.1)  # hypot(3, 4)
    assert ep.aoa.mean() == pytest.approx(100.0, abs=0.2) and ep.aoa.std() == pytest.approx(2.0, rel=0.1)


def test_aoa_drifts_and_wraps_into_0_360():
    d = DescriptorSpec(aoa=359.0, aoa_rate=0.001)  # one degree per 1000 TOA units: 10 degrees over the episode
    ep = simulate(one_emitter(d, ReceiverSpec(aoa_noise_std=0.5)), 0)
    assert ep.aoa.min() >= 0 and ep.aoa.max() < 360
    unwrapped = np.unwrap(np.radians(ep.aoa))
    slope = np.polyfit(ep.toa, np.degrees(unwrapped), 1)[0]
    assert slope == pytest.approx(0.001, rel=0.05)


@pytest.mark.parametrize("beam", ["gaussian", "sinc2"])
def test_circular_scan_gives_bursts_periodic_with_the_scan_period(beam):
    d = DescriptorSpec(scan="circular", scan_period=1000.0, beamwidth=10.0, beam=beam, sidelobe_db=-30.0)
    ep = simulate(one_emitter(d), 3)  # 100 pulses a revolution
    a = ep.amplitude
    np.testing.assert_allclose(a[100:], a[:-100], rtol=1e-9)
    assert a.max() > 10 ** (-0.5 / 20)  # the main beam sweeps past (peak within half a pulse's turn)
    assert a.min() == pytest.approx(10 ** (-30 / 20))  # the sidelobe floor between bursts
    # with a threshold the quiet pulses are missing: every heard pulse is above it, the TOAs a subset
    heard = simulate(one_emitter(d, ReceiverSpec(threshold=0.1)), 3)
    assert heard.amplitude.min() >= 0.1
    k = np.round(heard.toa / 10).astype(int)
    np.testing.assert_array_equal(heard.toa, 10.0 * k)  # scheduled pulses only (pulse k at 10 k)
    np.testing.assert_allclose(heard.amplitude, a[k % 100], rtol=1e-9)  # each where the scan puts it
    per_turn = np.bincount((heard.toa // 1000).astype(int))[:-1]
    expected = int(np.sum(a[:100] >= 0.1))
    assert set(per_turn.tolist()) <= {expected - 1, expected, expected + 1}  # a burst each revolution


def test_sector_scan_and_scanning_receiver_shape_the_amplitude():
    sector = DescriptorSpec(scan="sector", scan_period=2000.0, sector=60.0, beamwidth=5.0)
    a = simulate(one_emitter(sector, n=2000), 0).amplitude
    np.testing.assert_allclose(a[200:], a[:-200], rtol=1e-6)  # out and back every 200 pulses
    assert a.max() > 0.9 and a.min() < 0.1
    rx = ReceiverSpec(mode="scanning", scan_period=500.0, beamwidth=40.0, sidelobe_db=-20.0)
    b = simulate(one_emitter(DescriptorSpec(), rx, n=2000), 0).amplitude  # the receiver's look turns
    np.testing.assert_allclose(b[50:], b[:-50], rtol=1e-9)
    assert b.max() > 0.9 and b.min() == pytest.approx(0.1)


def test_same_seed_same_descriptors_alone_or_batched():
    spec = ScenarioSpec(name="pdw-det", n_pulses=300, amplitudes=True, toa_jitter_std=0.1, spurious_rate=0.1,
                        missing_prob=0.1, receiver=ReceiverSpec(threshold=0.05, aoa_noise_std=1.0),
                        sources=tuple(SourceSpec(period=Range(10.0, 40.0), amplitude=Range(0.5, 5.0),
                                                 descriptors=DescriptorSpec(frequency=Range(8000.0, 9000.0),
                                                                            frequency_hops=(0.0, 30.0),
                                                                            scan="circular", scan_period=500.0))
                                      for _ in range(4)), **BLIND)
    seeds = list(range(40))  # past the batched seeding's threshold
    batch = simulate_many(spec, seeds)
    for s in (0, 17, 39):
        a, b = simulate(spec, s), batch[s]
        for name in ("toa", "amplitude", "source", "frequency", "pulse_width", "aoa"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(batch[0].frequency, batch[1].frequency)


@pytest.mark.parametrize("merge", ["received", "emission"])
def test_merged_pulses_keep_their_leading_pulses_descriptors(merge):
    srcs = tuple(SourceSpec(period=p, phase=0.0, descriptors=DescriptorSpec(frequency=f, aoa=a))
                 for p, f, a in ((10.0, 9000.0, 10.0), (15.0, 9500.0, 200.0)))
    ep = simulate(ScenarioSpec(name="pdw-merge", n_pulses=300, amplitudes=True, coincidence_resolution=1.0,
                               merge=merge, sources=srcs, **BLIND), 0)
    merged = np.bitwise_and(ep.mask, ep.mask - np.uint64(1)) != 0
    assert merged.any()  # every 30 time units both sources arrive together; source 0 leads the run
    assert (ep.frequency[merged] == 9000.0).all() and (ep.aoa[merged] == 10.0).all()
    assert (ep.frequency[ep.source == 1] == 9500.0).all()


def test_descriptors_leave_the_toas_alone():
    base = dict(name="pdw-same", n_pulses=500, amplitudes=True, toa_jitter_std=0.2, missing_prob=0.1,
                spurious_rate=0.2, priors=PriorSpec(period_error=0.01))
    periods = (Range(10.0, 20.0), Range(15.0, 30.0), 17.0)
    plain = ScenarioSpec(sources=tuple(SourceSpec(period=p, amplitude=2.0) for p in periods), **base)
    rich = ScenarioSpec(sources=tuple(SourceSpec(period=p, amplitude=2.0, descriptors=DescriptorSpec(
        frequency_std=2.0, pulse_width_levels=(1.0, 2.0))) for p in periods),
        receiver=ReceiverSpec(aoa_noise_std=3.0), **base)
    for seed in (0, 5):
        a, b = simulate(plain, seed), simulate(rich, seed)
        assert a.frequency is None and b.frequency is not None
        for name in ("toa", "amplitude", "source", "mask"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(a.priors.period, b.priors.period)


def test_env_observes_descriptors_exactly_when_the_scenario_has_them():
    plain = gym.make("deint_env/Deinterleave-v0", scenario="core-v0/core-n2-spread1.5-jitter0.05")
    assert set(plain.observation_space.spaces) == {"toa", "amplitude", "valid"}
    obs, info = plain.reset(seed=0)
    assert set(obs) == {"toa", "amplitude", "valid"} and info["has_descriptors"] is False
    env = gym.make("deint_env/Deinterleave-v0", scenario="pdw-v0/pdw-staring-n5", lag=1)
    keys = {"toa", "amplitude", "valid", "frequency", "pulse_width", "aoa"}
    assert set(env.observation_space.spaces) == keys
    obs, info = env.reset(seed=7)
    assert info["has_descriptors"] is True
    ep = env.unwrapped.episode
    assert set(obs) == keys and obs["frequency"].dtype == np.float64 and obs["aoa"].shape == (1,)
    assert obs["frequency"][0] == ep.frequency[0] and obs["pulse_width"][0] == ep.pulse_width[0]
    obs, *_ = env.step(0)
    assert obs["aoa"][0] == ep.aoa[1] and env.observation_space.contains(obs)
    check_env(gym.make("deint_env/Deinterleave-v0", scenario="pdw-v0/pdw-scanning-n5-blind").unwrapped,
              skip_render_check=True)


def test_vector_env_observes_the_single_envs_descriptors():
    venv = DeinterleaveVectorEnv(num_envs=2, scenario="pdw-v0/pdw-staring-n10")
    obs, _ = venv.reset(seed=[3, 4])
    assert obs["frequency"].shape == (2, 1) and venv.single_observation_space.contains(
        {k: v[0] for k, v in obs.items()})
    for i, seed in enumerate((3, 4)):
        ep = simulate(venv.spec_scenario, seed)
        assert obs["pulse_width"][i, 0] == ep.pulse_width[0] and obs["aoa"][i, 0] == ep.aoa[0]


def test_ninety_emitters_are_scored_past_the_64_bit_mask():
    """Anchored 90 sources: the true labels earn every reward, in the env, the vector env and the metrics."""
    spec = ScenarioSpec(name="pdw-90", n_pulses=600, amplitudes=True, spurious_rate=0.05,
                        sources=tuple(SourceSpec(period=Range(50.0, 500.0), descriptors=DescriptorSpec())
                                      for _ in range(90)), priors=PriorSpec())
    ep = simulate(spec, 0)
    assert ep.source.max() >= 64 and np.all(ep.mask[ep.source >= 64] == 0)
    truth = np.where(ep.source >= 0, ep.source, spec.spurious_label)
    m = label_metrics(truth, ep.source, ep.mask, spec.n_labels, False)
    assert m["accuracy"] == 1.0 and len(m["pe"]) == 90
    env = gym.make("deint_env/Deinterleave-v0", scenario=spec)
    env.reset(seed=0)
    assert sum(env.step(int(a))[1] for a in truth) == len(ep)
    venv = DeinterleaveVectorEnv(num_envs=1, scenario=spec)
    venv.reset(seed=[0])
    assert sum(float(venv.step(np.array([a]))[1][0]) for a in truth.tolist()) == len(ep)


def test_tdc_round_trip_keeps_the_descriptors(tmp_path):
    ep = simulate(ScenarioSpec.from_dict(simulate_spec_dict()), 2)
    path = tmp_path / "ep.h5"
    tdc.train_from_episode(ep).write(path, "float64")
    train = tdc.read_tdc(path)
    assert train.feature_names == ("time_of_arrival", "frequency", "pulse_width", "angle_of_arrival", "amplitude")
    back = train.episode(ep.priors)
    for name in ("toa", "amplitude", "source", "frequency", "pulse_width", "aoa"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ep, name))
    table = train.pulse_table()
    np.testing.assert_array_equal(table.aoa, ep.aoa)


def simulate_spec_dict() -> dict:
    """A descriptor scenario as JSON, receiver included (also checks the dict form)."""
    return {"name": "pdw-json", "n_pulses": 400, "amplitudes": True, "blind": True, "label_budget": 8,
            "priors": {"kind": "none"}, "spurious_rate": 0.1,
            "receiver": {"mode": "scanning", "scan_period": 300.0, "beamwidth": 60.0, "threshold": 0.02},
            "sources": [{"period": 7.0, "descriptors": {"frequency": {"low": 9000, "high": 9500},
                                                        "scan": "circular", "scan_period": 900.0}},
                        {"period": 11.0, "descriptors": {"frequency_hops": [0, 20], "aoa": 45.0}}]}


def test_spec_json_round_trip():
    spec = ScenarioSpec.from_dict(simulate_spec_dict())
    assert isinstance(spec.sources[0].descriptors, DescriptorSpec) and isinstance(spec.receiver, ReceiverSpec)
    again = ScenarioSpec.from_dict(spec.to_dict())
    assert again == spec and again.content_hash == spec.content_hash
    plain = ScenarioSpec(name="p", sources=(SourceSpec(period=1.0),), n_pulses=5)
    assert "descriptors" not in plain.to_dict()["sources"][0] and "receiver" not in plain.to_dict()


def test_cli_simulate_writes_every_column_to_a_tdc_file(tmp_path, capsys):
    ep = simulate(resolve_scenario("pdw-v0/pdw-staring-n5"), 3)
    for out, extra in ((tmp_path / "a.h5", []), (tmp_path / "b.dat", ["--format", "tdc"])):
        assert deint_main(["simulate", "pdw-v0/pdw-staring-n5", "--seed", "3", "-o", str(out), *extra]) == 0
        train = tdc.read_tdc(out)
        assert set(train.columns) == {"toa", "frequency", "pulse_width", "angle_of_arrival", "amplitude"}
        np.testing.assert_array_equal(train.toa, ep.toa)  # float64 data: exact
        np.testing.assert_array_equal(train.episode(ep.priors).frequency, ep.frequency)
        np.testing.assert_array_equal(train.source(), ep.source)
    csv = tmp_path / "c.csv"  # a CSV pulse file holds toa and amplitude, and says what it leaves out
    assert deint_main(["simulate", "pdw-v0/pdw-staring-n5", "--seed", "3", "-o", str(csv)]) == 0
    assert "frequency, pulse_width, aoa left out" in capsys.readouterr().err
    assert csv.read_text().startswith("toa,amplitude,source\n")


def test_a_challenge_file_plays_as_a_scenario(tmp_path):
    ep = simulate(ScenarioSpec.from_dict(simulate_spec_dict()), 0)
    path = tmp_path / "train.h5"
    tdc.train_from_episode(ep).write(path, "float64")
    env = gym.make("deint_env/Deinterleave-v0", scenario=f"tdc:{path}")
    assert env.action_space.n == TDC_LABELS + 1
    assert set(env.observation_space.spaces) == {"toa", "amplitude", "valid", "frequency", "pulse_width", "aoa"}
    obs, info = env.reset(seed=5)
    assert obs["toa"][0] == ep.toa[0] and obs["frequency"][0] == ep.frequency[0] and info["priors"]["blind"]
    labels = np.where(ep.source >= 0, ep.source, TDC_LABELS)  # one label per source: every link right
    rewards = [env.step(int(a))[1] for a in labels]
    assert sum(rewards) == len(ep)
    again, _ = env.reset(seed=99)  # the seed picks nothing: the same file
    assert again["toa"][0] == ep.toa[0]
    check_env(env.unwrapped, skip_render_check=True)


def test_a_challenge_file_without_labels_or_path_is_one_line(tmp_path):
    ep = simulate(ScenarioSpec.from_dict(simulate_spec_dict()), 0)
    bare = tmp_path / "bare.h5"
    tdc.train_from_episode(ep, truth=False).write(bare)
    for scenario, words in ((f"tdc:{bare}", "no 'labels'"), (f"tdc:{tmp_path / 'none.h5'}", "no such file"),
                            ("tdc:", "names no file")):
        with pytest.raises(DeintError) as e:
            gym.make("deint_env/Deinterleave-v0", scenario=scenario)
        assert words in str(e.value) and "\n" not in str(e.value)


def test_priors_carry_the_emitter_library():
    spec = ScenarioSpec(name="pdw-lib", n_pulses=3000, amplitudes=True, receiver=ReceiverSpec(aoa_noise_std=2.0),
                        sources=tuple(SourceSpec(period=Range(10.0, 20.0), descriptors=DescriptorSpec(
                            frequency=Range(8000.0, 12000.0), frequency_hops=(0.0, 100.0), pulse_width=Range(1.0, 9.0),
                            pulse_width_levels=(1.0, 3.0))) for _ in range(3)), priors=PriorSpec(descriptors=True))
    ep = simulate(spec, 4)
    info = ep.priors.as_info()
    for i in range(3):
        mine = ep.source == i
        assert abs(ep.frequency[mine].mean() - info["frequency"][i]) < 3 * info["frequency_std"][i] / 10
        assert info["frequency_std"][i] == pytest.approx(50.0)  # two hops 100 MHz apart
        assert ep.pulse_width[mine].mean() == pytest.approx(info["pulse_width"][i], rel=0.05)
        assert abs(ep.aoa[mine].mean() - info["aoa"][i]) < 0.5 and info["aoa_std"][i] == pytest.approx(2.0)
    back = Priors.from_json_dict(json.loads(json.dumps(ep.priors.to_json_dict())))
    np.testing.assert_array_equal(back.aoa_std, ep.priors.aoa_std)
    assert "frequency" not in simulate(spec.replace(priors=PriorSpec()), 4).priors.as_info()  # opt-in
    with pytest.raises(DeintError, match="frequency and frequency_std go together"):
        Priors.from_json_dict({"period": [10.0], "frequency": [9000.0]})


BAD = {
    "one hop": (lambda: DescriptorSpec(frequency_hops=(5.0,)), "descriptors.frequency_hops"),
    "negative width level": (lambda: DescriptorSpec(pulse_width_levels=(1.0, -2.0)), "descriptors.pulse_width_levels"),
    "zero width": (lambda: DescriptorSpec(pulse_width=0.0), "descriptors.pulse_width"),
    "aoa 400": (lambda: DescriptorSpec(aoa=400.0), "descriptors.aoa"),
    "negative frequency": (lambda: DescriptorSpec(frequency=-1.0), "descriptors.frequency"),
    "circular without period": (lambda: DescriptorSpec(scan="circular"), "descriptors.scan_period"),
    "period without scan": (lambda: DescriptorSpec(scan_period=5.0), "descriptors.scan_period"),
    "sector without width": (lambda: DescriptorSpec(scan="sector", scan_period=5.0), "descriptors.sector"),
    "unknown scan": (lambda: DescriptorSpec(scan="raster"), "descriptors.scan"),
    "zero beamwidth": (lambda: DescriptorSpec(beamwidth=0.0), "descriptors.beamwidth"),
    "unknown beam": (lambda: DescriptorSpec(beam="cosine"), "descriptors.beam"),
    "positive sidelobes": (lambda: DescriptorSpec(sidelobe_db=3.0), "descriptors.sidelobe_db"),
    "string frequency": (lambda: DescriptorSpec(frequency="9 GHz"), "descriptors.frequency"),
    "unknown receiver": (lambda: ReceiverSpec(mode="rotating"), "receiver.mode"),
    "scanning without period": (lambda: ReceiverSpec(mode="scanning", beamwidth=10.0), "receiver.scan_period"),
    "staring with a beam": (lambda: ReceiverSpec(beamwidth=10.0), "receiver.scan_period"),
    "negative threshold": (lambda: ReceiverSpec(threshold=-1.0), "receiver.threshold"),
    "descriptors on some sources": (lambda: ScenarioSpec(
        name="x", n_pulses=5, amplitudes=True,
        sources=(SourceSpec(period=1.0, descriptors=DescriptorSpec()), SourceSpec(period=2.0))), "source.descriptors"),
    "descriptors without amplitudes": (lambda: ScenarioSpec(
        name="x", n_pulses=5, sources=(SourceSpec(period=1.0, descriptors=DescriptorSpec()),)), "amplitudes"),
    "receiver without descriptors": (lambda: ScenarioSpec(
        name="x", n_pulses=5, sources=(SourceSpec(period=1.0),), receiver=ReceiverSpec()), "receiver"),
    "unknown descriptor field": (lambda: SourceSpec(period=1.0, descriptors={"freq": 1.0}), "'freq'"),
    "library of explicit priors": (lambda: PriorSpec(kind="explicit", period=(1.0,), period_std=(1.0,),
                                                     phase_std=(1.0,), descriptors=True), "priors.descriptors"),
    "library without descriptors": (lambda: ScenarioSpec(name="x", n_pulses=5, sources=(SourceSpec(period=1.0),),
                                                         priors=PriorSpec(descriptors=True)), "priors.descriptors"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_descriptor_fields_are_one_line_errors(case):
    make, field_name = BAD[case]
    with pytest.raises(DeintError) as e:
        make()
    msg = str(e.value)
    assert field_name in msg and "\n" not in msg

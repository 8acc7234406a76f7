"""The beam decoder of learned track agents (agents/beam.py) and its numpy network (agents/fast_net.py)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("stable_baselines3")

from gymnasium import spaces  # noqa: E402

from agents.beam import BeamDecoder  # noqa: E402
from agents.fast_net import NumpyTrackNet  # noqa: E402
from agents.networks import TrackPolicy, action_scores, weights_of  # noqa: E402
from agents.policy import ZOO_CHECKPOINT, AgentPolicy, BeamPolicy  # noqa: E402
from deint_env.episode import Priors  # noqa: E402
from deint_env.features import TrackFeatures, TrackLayout  # noqa: E402
from deint_env.runner import play  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402


def _random_policy(layout: TrackLayout, attention: bool, seed: int = 0) -> TrackPolicy:
    torch.manual_seed(seed)
    policy = TrackPolicy(layout.observation_space(), spaces.Discrete(layout.n_actions), lambda _: 0.0, d_model=16,
                         attention=attention, heads=4)
    with torch.no_grad():  # larger weights than the init: log-probabilities far from uniform
        for p in policy.parameters():
            p.mul_(3.0)
    return policy.eval()


@pytest.mark.parametrize("attention", [True, False])
def test_numpy_forward_equals_torch(attention):
    layout = TrackLayout(max_tracks=6, lookahead=2)
    policy = _random_policy(layout, attention)
    net = NumpyTrackNet(weights_of(policy), heads=4)
    rng = np.random.default_rng(1)
    n, b = 4, 7
    tracks = rng.normal(size=(b, 6, len(layout.token_names))).astype(np.float32)
    tracks[:, n:] = 0.0
    pulse = rng.normal(size=(b, len(layout.pulse_names))).astype(np.float32)
    mask = (np.arange(6) < n).astype(np.float32)[None].repeat(b, 0)
    logits = action_scores(policy, {"tracks": tracks, "mask": mask, "pulse": pulse}).numpy()
    want = torch.log_softmax(torch.from_numpy(np.concatenate([logits[:, :n], logits[:, 6:]], 1)), 1).numpy()
    got = net.log_probs(tracks[:, :n], pulse)
    assert got.shape == (b, n + 1) and np.abs(got - want).max() < 1e-5


def _decode(decoder: BeamDecoder, priors: Priors, toa: np.ndarray) -> list[int]:
    decoder.start(priors, has_amplitude=False)
    out = []
    for k in range(len(toa) + decoder.layout.lookahead + decoder.decision_lag):
        label = decoder.step(toa[k] if k < len(toa) else 0.0, 0.0, k < len(toa))
        if label is not None:
            out.append(label)
    return out


def _sequence_log_prob(net, layout: TrackLayout, priors: Priors, toa: np.ndarray, labels) -> float:
    """The network's log-probability of one labelling, replayed on a single feature row."""
    f = TrackFeatures(1, layout)
    f.reset_rows([0], [priors], [False])
    n, total, j = priors.n_labels, 0.0, 0
    for k in range(len(toa) + layout.lookahead):
        f.observe(np.array([toa[k] if k < len(toa) else 0.0]), np.zeros(1), np.array([k < len(toa)]))
        if f.ready[0]:
            tracks, pulse = f.arrays()
            total += float(net.log_probs(tracks[:, :n], pulse)[0, labels[j]])
            f.label(np.array([labels[j] if labels[j] < n else layout.max_tracks]))
            j += 1
    return total


def test_exhaustive_beam_finds_the_most_likely_labelling_and_greedy_may_not():
    layout = TrackLayout(max_tracks=4, lookahead=1)
    priors = Priors.from_json_dict({"period": [10.0, 13.0], "phase": [2.0, 3.0], "jitter_std": 0.5})
    toa = np.array([2.3, 3.4, 11.6, 16.2, 21.9])
    best_gap = []
    for seed in (4, 11):  # random networks on which greedy decoding misses the best labelling
        net = NumpyTrackNet(weights_of(_random_policy(layout, True, seed)), heads=4)
        scores = {seq: _sequence_log_prob(net, layout, priors, toa, seq)
                  for seq in itertools.product(range(3), repeat=len(toa))}
        best = max(scores, key=scores.get)
        exhaustive = _decode(BeamDecoder(net, layout, beam=3 ** len(toa), decision_lag=len(toa), merge=False),
                             priors, toa)
        assert tuple(exhaustive) == best
        greedy = _decode(BeamDecoder(net, layout, beam=1, decision_lag=0), priors, toa)
        assert scores[tuple(greedy)] <= scores[best]
        best_gap.append(scores[best] - scores[tuple(greedy)])
        merged = _decode(BeamDecoder(net, layout, beam=9, decision_lag=len(toa)), priors, toa)
        assert tuple(merged) == best  # 5 pulses, 2 tracks: few distinct futures, a beam of 9 holds them
    assert max(best_gap) > 0  # the test can tell a beam from greedy decoding


def test_beam_of_one_is_the_greedy_agent():
    episode = simulate(find_entry("core-v0/core-n4-spread4-jitter0.2").spec.replace(n_pulses=150), 5)
    greedy = play(AgentPolicy(str(ZOO_CHECKPOINT)), episode, clustering=False)
    beam1 = BeamPolicy(str(ZOO_CHECKPOINT), beam=1, decision_lag=4)
    assert beam1.lag == AgentPolicy(str(ZOO_CHECKPOINT)).lag + 4
    assert np.array_equal(play(beam1, episode, clustering=False).labels, greedy.labels)


def _independent_pulses(n: int, rng: np.random.Generator, n_pulses: int = 300):
    """Periodic trains with Gaussian TOA jitter, made here (not by deint_env's simulator)."""
    period = 10.0 * 4.0 ** rng.random(n)
    phase = rng.random(n) * period
    jitter = 0.002 * period.min()
    toa, src = [], []
    for s in range(n):
        k = np.arange(int(n_pulses * 1.2 * period.min() / period[s]) + 2)
        toa.append(phase[s] + k * period[s] + rng.normal(0.0, jitter, k.size))
        src.append(np.full(k.size, s))
    toa, src = np.concatenate(toa), np.concatenate(src)
    order = np.argsort(toa, kind="stable")[:n_pulses]
    return toa[order], src[order], {"period": period.tolist(), "phase": phase.tolist(), "jitter_std": jitter,
                                    "spurious_rate": 0.0, "missing_prob": 0.0}


@pytest.mark.parametrize("policy", ["dagger-beam", "lmht"])
@pytest.mark.parametrize("n", [2, 3, 8])
def test_zoo_agent_labels_an_outside_pulse_file(tmp_path, n, policy):
    import json

    from deint_env.cli import main

    toa, src, priors = _independent_pulses(n, np.random.default_rng(n))
    (tmp_path / "p.csv").write_text("toa\n" + "".join(f"{float(t)!r}\n" for t in toa))
    (tmp_path / "pr.json").write_text(json.dumps(priors))
    assert main(["label", str(tmp_path / "p.csv"), "--policy", policy, "--priors", str(tmp_path / "pr.json"),
                 "-o", str(tmp_path / "l.csv")]) == 0
    labels = np.loadtxt(tmp_path / "l.csv", delimiter=",", skiprows=1, usecols=1).astype(int)
    assert labels.shape == src.shape and np.mean(labels == src) > 0.95


def test_kernels_compute_what_track_features_compute():
    """The beam's numba kernels against `TrackFeatures` (arrays and label) on hypotheses of a real episode."""
    from agents.beam_kernels import extend, token_arrays

    episode = simulate(find_entry("robust-v0/robust-combined").spec.replace(n_pulses=60), 2)
    for version in (2, 3):
        layout = TrackLayout(max_tracks=5, lookahead=2, version=version)
        b, n = 4, episode.n_labels
        ref, mine = TrackFeatures(b, layout), TrackFeatures(b, layout)
        for f in (ref, mine):
            f.reset_rows(np.arange(b), [episode.priors] * b, [False] * b)
        rng = np.random.default_rng(version)
        toa = episode.toa
        for k in range(len(toa) + 2):
            for f in (ref, mine):
                f.observe(np.full(b, toa[k] if k < len(toa) else 0.0), np.zeros(b), np.full(b, k < len(toa)))
            if not ref.ready[0]:
                continue
            tracks, pulse = ref.arrays()
            got, got_pulse = token_arrays(mine.period, mine.anchor, mine.count, mine.amp_mean, mine.amp_scale,
                                          mine.prior_period, b, n, mine.win_toa[0], mine.win_amp[0],
                                          mine.first_toa[0], int(mine.labelled[0]), mine.scalars[0], False,
                                          version, 5, 2)
            assert np.array_equal(got, tracks[:, :n]) and np.array_equal(np.broadcast_to(got_pulse, pulse.shape), pulse)
            labels = rng.integers(0, n + 1, b)  # a random labelling per row: rows drift apart
            ref.label(np.where(labels < n, labels, 5))
            extend(np.arange(b), labels, n, mine.win_toa[0, 1], 0.0, mine.period, mine.anchor, mine.count,
                   mine.span_time, mine.span_periods, mine.amp_mean, mine.prior_period)
            mine.labelled += 1
            mine.win_toa[:, 0], mine.win_toa[:, 1] = mine.win_toa[:, 1], np.nan


def test_compiled_beam_scores_equal_the_numpy_network():
    for attention in (True, False):
        layout = TrackLayout(max_tracks=8, lookahead=3)
        net = NumpyTrackNet(weights_of(_random_policy(layout, attention)), heads=4)
        rng = np.random.default_rng(2)
        for k, n in ((1, 2), (8, 3), (5, 8)):
            tracks = rng.normal(size=(k, n, len(layout.token_names))).astype(np.float32)
            pulse = rng.normal(size=len(layout.pulse_names)).astype(np.float32)
            want, want_v = net.scores(tracks, pulse[None])
            got, got_v = net.beam_scores(tracks, pulse)
            assert np.abs(got - want).max() < 1e-5 and np.abs(got_v - want_v).max() < 1e-5

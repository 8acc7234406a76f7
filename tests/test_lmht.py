"""`lmht` (agents/lmht.py, the scorer in baselines/mht/scorer.py): the numba scorer against the torch one, a zero
scorer against mht, the training rows against the truth and a checkpoint's round trip (the checked-in
agent on pulse files from an independent generator through `deint label`: tests/test_agents_beam.py)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.lmht import SEARCH, SEARCH_VERSION, LMHT, TorchScorer, candidates, group_loss, train  # noqa: E402
from baselines.mht import MHT  # noqa: E402
from baselines.mht import FEATURE_VERSION, N_FEATURES, Scorer, mlp  # noqa: E402
from deint_env.errors import DeintError  # noqa: E402
from deint_env.policies import make_policy, policy_info  # noqa: E402
from deint_env.runner import play  # noqa: E402
from deint_env.simulate import simulate  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402


def _random_scorer(seed: int, hidden: int = 8) -> TorchScorer:
    net = TorchScorer(hidden, seed)
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(torch.randn(p.shape, generator=g, dtype=p.dtype))
    return net


def test_numba_scorer_equals_torch_scorer():
    """Random weights and features, some outside the feature range (clipped by both)."""
    net = _random_scorer(3)
    x = np.random.default_rng(0).normal(0.0, 2.0, (200, N_FEATURES))
    net.fit_range(torch.from_numpy(x[:50]))
    want = net(torch.from_numpy(x)).detach().numpy()
    fast = net.numba()
    got = np.array([mlp(fast, row, np.empty(8)) for row in x])
    assert np.any(want != want[0])  # the ReLUs do not all sit on one side
    assert np.any((x[50:] < fast.lo) | (x[50:] > fast.hi))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_a_zero_scorer_is_mht_and_a_random_one_is_not():
    """f = 0 adds exactly 0.0 to every score: mht's labels; a random f changes them (the hook is live)."""
    episode = simulate(find_entry("core-v0/core-n6-spread1.5-jitter0.5").spec.replace(n_pulses=300), 4)
    zero = TorchScorer(4, 0).numba()
    ref = play(MHT(), episode, clustering=False).labels
    assert np.array_equal(play(MHT(scorer=zero), episode, clustering=False).labels, ref)
    assert not np.array_equal(play(MHT(scorer=_random_scorer(5).numba()), episode, clustering=False).labels, ref)


def test_lmht_plays_with_its_search_and_its_version_names_what_its_labels_depend_on():
    agent = make_policy("lmht")
    assert agent.beam == SEARCH["beam"] != agent.meta.hyperparameters["mht"]["beam"]  # SEARCH over training
    assert all(getattr(agent, k) == v for k, v in SEARCH.items())
    assert agent.version.endswith(f"/lmht-{FEATURE_VERSION}.{SEARCH_VERSION}/mht-{policy_info('mht').version}")
    assert make_policy("lmht:margin=1000000").margin == 1e6
    assert make_policy("lmht:misfit=0").misfit == 0.0


def test_training_rows_follow_the_truth():
    """Behaviour-cloning rows: one group per pulse with a right candidate, whose right label matches the
    truth; mht's logits already put most of the mass on it (a small loss), and the spurious candidate
    is in every group."""
    episode = simulate(find_entry("robust-v0/robust-combined").spec.replace(n_pulses=200), 1)
    zero = TorchScorer(4, 0).numba()
    feat, base, right, group = candidates(episode, zero, 0.0, np.random.default_rng(0))
    assert feat.shape == (base.size, N_FEATURES) and np.all(np.diff(group) >= 0)
    pulses = np.unique(group)
    assert pulses.size > 0.95 * len(episode)
    for k in pulses[:50]:
        rows = group == k
        assert feat[rows, 2].sum() == 1  # one spurious candidate
        assert right[rows].any()
    _, inv = np.unique(group, return_inverse=True)
    loss = float(group_loss(torch.from_numpy(base), torch.from_numpy(right.astype(float)), torch.from_numpy(inv),
                            pulses.size))
    assert 0.0 < loss < 0.3


def test_a_trained_checkpoint_round_trips(tmp_path):
    out = train(["core-v0/core-n3-spread4-jitter0.2"], tmp_path / "s.safetensors", seeds=1, iterations=2, epochs=3,
                hidden=4, log=lambda _: None)
    agent = LMHT(checkpoint=str(out), beam=4)
    assert agent.beam == 4 and agent.net.w1.shape == (N_FEATURES, 4) and np.all(agent.net.lo <= agent.net.hi)
    assert np.any(agent.net.w2 != 0)  # trained: f is no longer 0
    again = LMHT(checkpoint=str(out), beam=4)
    assert agent.version == again.version and agent.version.startswith("sha256:")
    for a, b in zip(agent.net, again.net):
        assert np.array_equal(a, b)
    (tmp_path / "bad.safetensors").write_bytes(b"\x80\x04junk")
    with pytest.raises(DeintError, match="never unpickled"):
        LMHT(checkpoint=str(tmp_path / "bad.safetensors"))


def test_deint_train_algo_lmht(tmp_path, capsys):
    """`deint train --algo lmht` with a tiny YAML: a checkpoint the policy spec plays."""
    from deint_env.cli import main

    (tmp_path / "hp.yml").write_text("default:\n  seeds: 1\n  iterations: 1\n  epochs: 2\n  hidden: 4\n  beam: 4\n")
    assert main(["train", "--algo", "lmht", "--scenario", "core-v0/core-n2-spread4-jitter0.2", "--hyperparams",
                 str(tmp_path / "hp.yml"), "-o", str(tmp_path / "run"), "--no-progress"]) == 0
    agent = LMHT(checkpoint=str(tmp_path / "run" / "last.safetensors"))
    assert agent.meta.hyperparameters["mht"]["beam"] == 4 and agent.beam == SEARCH["beam"]  # play: SEARCH's
    assert agent.meta.timesteps == 2 and agent.meta.train_seeds == [10, 11]
    (tmp_path / "bad.yml").write_text("default:\n  sedes: 1\n")
    assert main(["train", "--algo", "lmht", "--scenario", "core-v0/core-n2-spread4-jitter0.2", "--hyperparams",
                 str(tmp_path / "bad.yml"), "-o", str(tmp_path / "run2"), "--no-progress"]) != 0
    assert "'sedes' is unknown" in capsys.readouterr().err


def _settings(scenario: str, **params):
    """An mht reset on the scenario's priors: its compiled settings (stated rates, misfit)."""
    agent = MHT(**params)
    agent.reset(simulate(find_entry(scenario).spec.replace(n_pulses=50), 0).priors, {})
    return agent.settings[0]  # the record the kernels take


def test_misfit_is_the_likelihood_ratio_of_the_decided_rates_against_the_stated_ones():
    """Binomial for misses per arrival, Poisson for spurious pulses per arrival (stated rates floored as mht
    floors them, a rate left to estimate held to 5 %); an observed rate at or below that adds nothing."""
    from scipy.stats import binom, poisson

    from baselines.mht.kernels import _misfit
    from baselines.mht.state import _Q_FLOOR, _R_FLOOR

    stated = _settings("robust-v0/robust-combined")  # q = 0.1, r = 0.1
    zero = _settings("core-v0/core-n6-spread1.5-jitter0.5")  # q = r = 0: the floors
    unknown = _settings("robust-v0/robust-combined", rates="estimate")
    for cfg, q0, r0 in ((stated, 0.1, 0.1), (zero, _Q_FLOOR, _R_FLOOR), (unknown, 0.05, 0.05)):
        for hits, misses, spurious in ((900, 100, 100), (800, 200, 30), (950, 50, 300), (990, 10, 2), (0, 0, 0)):
            a = hits + misses
            want = 0.0
            if misses > q0 * a:
                want += binom.logpmf(misses, a, misses / a) - binom.logpmf(misses, a, q0)
            if spurious > r0 * a:
                want += poisson.logpmf(spurious, spurious) - poisson.logpmf(spurious, r0 * a)
            got = _misfit(cfg, np.array([hits, misses, spurious, 0]))
            assert got == pytest.approx(want, rel=1e-9, abs=1e-9), (q0, hits, misses, spurious)
    assert _misfit(stated, np.array([800, 200, 300, 0])) > 100  # both rates far above the stated ones
    assert _misfit(stated, np.array([900, 100, 100, 0])) == 0.0
    assert _misfit(unknown, np.array([960, 40, 45, 0])) == 0.0


@pytest.mark.parametrize("scenario, learned", [("robust-v0/robust-spurious0.1", False),
                                               ("robust-v0/robust-merged0.5", True),
                                               ("agile-v0/agile-sliding", True)])
def test_the_learned_correction_waits_for_a_misfit_unless_the_priors_state_merging(scenario, learned):
    """lmht's labels are mht's search's alone (the scorer off) where mht's model fits; the scorer is on from
    the start where the priors state merging, and from a misfit on for agile sources; where it is on it
    changes labels.  The gate is decided per pulse, so the labels do not depend on `batch`."""
    episode = simulate(find_entry(scenario).spec.replace(n_pulses=400), 1)
    gated = LMHT()
    labels = play(gated, episode, clustering=False).labels
    off = LMHT()
    off.net = Scorer.off()
    assert gated.counts[3] == int(learned)
    assert np.array_equal(labels, play(off, episode, clustering=False).labels) != learned
    # a gate no misfit reaches changes only the scenes where a misfit opened it (stated merging opens it anyway)
    closed = play(LMHT(misfit=1e6), episode, clustering=False).labels
    assert np.array_equal(closed, labels) == (scenario != "agile-v0/agile-sliding")
    assert np.array_equal(play(LMHT(batch=1), episode, clustering=False).labels, labels)


def test_from_six_sources_the_search_before_the_gate_opens_is_mhts_own_at_its_beam():
    """SEARCH's `wide_from`: where the gate stays closed on six sources lmht's labels are those of mht with
    lmht's beam (64) and N-scan depth; without it they are the narrower search's; below six sources it
    changes nothing."""
    assert SEARCH["wide_from"] == 6 and SEARCH["beam"] == 64
    six = simulate(find_entry("core-v0/core-n6-spread1.5-jitter0.5").spec.replace(n_pulses=400), 1)
    gated = LMHT()
    labels = play(gated, six, clustering=False).labels
    assert gated.counts[3] == 0
    assert np.array_equal(labels, play(MHT(beam=64, nscan=SEARCH["nscan"]), six, clustering=False).labels)
    assert not np.array_equal(labels, play(LMHT(wide_from=0), six, clustering=False).labels)
    four = simulate(find_entry("core-v0/core-n4-spread1.5-jitter0.5").spec.replace(n_pulses=400), 1)
    assert np.array_equal(play(LMHT(), four, clustering=False).labels,
                          play(LMHT(wide_from=0), four, clustering=False).labels)


def test_the_gate_opens_on_priors_that_leave_the_rates_unknown():
    """Priors without rates (a pulse file's JSON may omit them): the decided labels are held to the weak
    prior's 5 %, so agile sources that shed spurious labels still open the gate."""
    import dataclasses
    import math

    episode = simulate(find_entry("agile-v0/agile-sliding").spec.replace(n_pulses=400), 1)
    episode = dataclasses.replace(episode, priors=dataclasses.replace(episode.priors, missing_prob=math.nan,
                                                                      spurious_rate=math.nan))
    gated, closed = LMHT(), LMHT(misfit=1e6)
    labels = play(gated, episode, clustering=False).labels
    assert not np.array_equal(play(closed, episode, clustering=False).labels, labels)
    assert gated.counts[3] == 1 and closed.counts[3] == 0

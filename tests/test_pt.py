"""The probabilistic teacher (MK94 IV) and the `dokf` tracker: convergence, reproducibility, labels,
the spurious test inside pt-post, and the MK94 PT experiments in quick mode."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.pt import PTPost, PTPrior
from baselines.reproduce import run_experiment
from baselines.reproduce.mk94_pt import classify, predicted_rms
from deint_env import ScenarioSpec, SourceSpec, make_policy, simulate
from deint_env.errors import DeintError
from deint_env.runner import play, reference_accuracies
from deint_env.scenario import PriorSpec
from deint_env.suites import find_entry

CLEAN_TWO = ScenarioSpec(name="clean-two", n_pulses=300, toa_jitter_std=0.1,
                         sources=(SourceSpec(period=11.0, phase=3.0), SourceSpec(period=17.0, phase=4.0)),
                         priors=PriorSpec(kind="perturbed", period_error=0.01, phase_error=0.02))


def _run(policy, episode, seed):
    policy.reset(episode.priors, {"policy_seed": seed})
    labels = [policy.act({"toa": (y,), "valid": 1}) for y in episode.toa]
    return np.array(labels), policy.estimates()


def test_pt_prior_converges_at_the_binomial_rate():
    """MK94 Fig. 9's case cut to 3000 pulses: the a-priori teacher's period errors shrink like
    sqrt(1.2 (1 - pi) / (K pi)) (baselines.reproduce.mk94_pt); measured over 8 seeds the rms is
    0.6-1.0 times that prediction, i.e. (1.4%, 3.5%, 6.3%) for T = (11, 30, 80)."""
    spec = find_entry("paper-v0/mk94-pt-three").spec.replace(n_pulses=3000)
    errors = []
    for seed in range(8):
        ep = simulate(spec, seed)
        _, est = _run(PTPrior(), ep, seed)
        errors.append(est["period"] / ep.truth.period - 1.0)
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    ratio = rms / predicted_rms(ep.priors.source_prob, 3000)
    assert np.all(ratio < 1.5) and np.all(ratio > 0.4), ratio
    assert rms[0] < 0.02  # the frequent source: within 2 % rms after 3000 pulses


def test_pt_prior_is_seeded_and_map_labels_do_not_change_learning():
    ep = simulate(find_entry("paper-v0/mk94-pt-three").spec.replace(n_pulses=400), 3)
    a = play(make_policy("pt-prior"), ep, policy_seed=7)
    b = play(make_policy("pt-prior"), ep, policy_seed=7)
    c = play(make_policy("pt-prior"), ep, policy_seed=8)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.estimates["period"], b.estimates["period"])
    assert not np.array_equal(a.labels, c.labels)
    d = play(make_policy("pt-prior:seed=7"), ep, policy_seed=99)  # its own seed wins over the runner's
    np.testing.assert_array_equal(a.labels, d.labels)
    m = play(make_policy("pt-prior:label=map"), ep, policy_seed=7)
    np.testing.assert_array_equal(a.estimates["period"], m.estimates["period"])
    assert not np.array_equal(a.labels, m.labels)


@pytest.mark.parametrize("name", ["pt-post", "pt-post:label=map", "dokf"])
def test_posterior_trackers_label_a_clean_two_source_train_like_the_genie(name):
    for seed in range(3):
        ep = simulate(CLEAN_TWO, seed)
        res = play(make_policy(name), ep, policy_seed=seed)
        genie, _ = reference_accuracies(ep)  # coincident pulses cost the genie too
        assert res.metrics["accuracy"] >= genie - 0.02, (seed, res.metrics["accuracy"], genie)
        np.testing.assert_allclose(res.estimates["period"], ep.truth.period, rtol=1e-3)
        np.testing.assert_allclose(res.estimates["phase"], ep.truth.phase, atol=0.1)


def test_pt_post_is_reproducible_and_dokf_deterministic():
    ep = simulate(find_entry("paper-v0/mk94-pt-post").spec.replace(n_pulses=300), 1)
    a, b = (_run(PTPost(), ep, 5)[0] for _ in range(2))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, _run(PTPost(), ep, 6)[0])
    d1, d2 = (play(make_policy("dokf"), ep, policy_seed=s).labels for s in (1, 2))
    np.testing.assert_array_equal(d1, d2)


def test_spurious_test_only_with_spurious_priors():
    base = CLEAN_TWO.replace(n_pulses=400, toa_jitter_std=0.05)
    clean = simulate(base, 0)
    assert np.all(_run(PTPost(), clean, 0)[0] < clean.n_labels)
    found, thrown = [], []
    for seed in range(4):
        spur = simulate(base.replace(spurious_rate=0.1), seed)
        called = play(make_policy("dokf"), spur, policy_seed=seed).labels == spur.n_labels
        truly = spur.source < 0
        found.append(np.mean(called[truly]))
        thrown.append(np.mean(called[~truly]))
    assert min(found) > 0.8  # the spurious pulses are found ...
    assert max(thrown) < 0.05  # ... and few source pulses are thrown away


def test_coasting_and_resets_keep_tracks_alive():
    """A wrongly taken spurious pulse biases a track so that the Theorem 1 test then rejects all its
    source's pulses (seed 33 below, without the remedies); coasting plus the dropout reset recovers.
    (On seed 0, where a wrong take in the start showed it, the start beam of dokf version 3 and
    pt-post version 3 avoids that take.)  pt-post version 4's particles recover without them too: the
    particle that took the spurious pulse loses weight."""
    spur = simulate(CLEAN_TWO.replace(n_pulses=400, toa_jitter_std=0.05, spurious_rate=0.1), 33)
    truly = spur.source < 0
    thrown = {}
    one = "particles=1"
    for name in (f"pt-post:coast=false,{one}", f"pt-post:coast=true,reset_after=4,{one}", "pt-post:coast=false",
                 "pt-post", "dokf"):
        called = play(make_policy(name), spur, policy_seed=33).labels == spur.n_labels
        thrown[name] = np.mean(called[~truly])
    assert thrown[f"pt-post:coast=false,{one}"] > 0.3
    # pt-post takes the remedies by itself when the priors state a spurious (or missing) rate
    assert max(thrown[f"pt-post:coast=true,reset_after=4,{one}"], thrown["pt-post"], thrown["dokf"]) < 0.05, thrown
    assert thrown["pt-post:coast=false"] < 0.05, thrown


def test_dokf_beam_margin_keeps_only_close_labellings():
    """On a clear two-source train the whole-episode beam without a margin keeps its 8 places after the start
    full, dokf's default margin (10 nats) leaves one labelling (every rival is a wrong take, far behind), and
    the labels are the same."""
    ep = simulate(CLEAN_TWO, 0)
    full, pruned = make_policy("dokf:beam_margin=none"), make_policy("dokf")
    labels = {}
    for name, policy in (("full", full), ("pruned", pruned)):
        labels[name] = _run(policy, ep, 0)[0]
    assert len(full._beam) == 8 and len(pruned._beam) == 1
    np.testing.assert_array_equal(labels["full"], labels["pruned"])
    with pytest.raises(DeintError, match="beam_margin"):
        make_policy("dokf:beam_margin=0")


def test_dokf_beam_ends_with_the_start_where_the_priors_are_vague():
    """MK94 V-C's PT scenes state period 1 +- 1000: every rival labelling stays within the margin there (7-20
    ms a pulse), so the beam ends after two longest prior periods, as in dokf version 5; priors that locate
    the periods keep it the whole episode."""
    vague = find_entry("paper-v0/mk94-pt-three")
    policy = make_policy("dokf")
    play(policy, simulate(vague.spec, vague.seeds("validation")[0]))
    assert policy._beam is None
    policy = make_policy("dokf")
    play(policy, simulate(CLEAN_TWO, 0))
    assert policy._beam is not None


def test_dokf_beam_prices_the_arrivals_it_coasts_through():
    """robust-onset, first validation seed: the third source starts at 40 % of the episode, its prior period
    (12.08) beside the first's (12.02).  While the beam's skipped arrivals were free, a labelling in which
    the idle track took some of the first source's pulses (that track coasting) scored as the true one, and
    the beam's lag-0 labels mixed them (0.39 of the labels right at margin 5, one decision after the start
    0.96)."""
    entry = find_entry("robust-v0/robust-onset")
    ep = simulate(entry.spec, entry.seeds("validation")[0])
    specs = ("dokf:beam_span=2", "dokf:beam_margin=5", "dokf")
    acc = {spec: play(make_policy(spec), ep).metrics["accuracy"] for spec in specs}
    assert min(acc["dokf:beam_margin=5"], acc["dokf"]) >= max(0.9, acc["dokf:beam_span=2"] - 0.02), acc


def test_pt_post_particles_where_the_priors_are_vague_or_located():
    """Particles run after the start beam where the priors locate the periods, and from the priors where
    they are vague only when asked for (by default the published PT there); each is reproducible from its
    seed, and `particles=1` is the one-teacher PT."""
    vague = find_entry("paper-v0/mk94-pt-three")
    ep = simulate(vague.spec.replace(n_pulses=300), vague.seeds("validation")[0])
    policy = make_policy("pt-post")
    play(policy, ep)
    assert policy._particles is None
    runs = [play(make_policy("pt-post:particles=4"), ep, policy_seed=3).labels for _ in range(2)]
    np.testing.assert_array_equal(*runs)
    policy = make_policy("pt-post")
    labels = play(policy, simulate(CLEAN_TWO, 0), policy_seed=3).labels
    assert policy._particles is not None and len(policy._particles) == 32
    one = make_policy("pt-post:particles=1")
    play(one, simulate(CLEAN_TWO, 0), policy_seed=3)
    assert one._particles is None
    assert labels.size == 300


def test_pt_post_particles_coast_only_where_a_miss_is_told_from_jitter():
    """mk94-two-var3 (clean channel, jitter std 1.73 against periods 11 and 17, priors 10 and 22): 5 jitter
    deviations pass half a period, so a pulse past the midpoint of two arrivals may be a late one.  Version 5's
    particles took VI-C-3's remedies there, drew misses for late pulses, reset their tracks and gave the trains
    to each other (accuracy 0.416 on this validation episode); version 6's do not coast there (0.602), and do
    on CLEAN_TWO (jitter 0.1)."""
    entry = find_entry("paper-v0/mk94-two-var3")
    seed = entry.seeds("validation")[0]
    policy = make_policy("pt-post")
    res = play(policy, simulate(entry.spec, seed), policy_seed=seed)
    assert policy._particles is not None and not policy.coast
    assert res.metrics["accuracy"] >= 0.55, res.metrics["accuracy"]
    policy = make_policy("pt-post")
    play(policy, simulate(CLEAN_TWO, 0), policy_seed=3)
    assert policy.coast


@pytest.mark.parametrize("name", ["cm00-random4-jitter0", "cm00-random5-jitter0"])
def test_pt_post_start_gives_unknown_phases_their_prior_identities(name):
    """CM00's clean scenes state no phases and every period 11 % high.  Version 6's start charged a first pulse
    of unknown phase the diffuse prior's normaliser, -log(10^6 T), so it deferred starting tracks and put the
    0.232 train of random5 on the track of prior period 0.403 +- 0.045; and it dropped a swap of two one-pulse
    tracks as alike (their next arrivals within the prior period's deviation), so on random4 the order of the
    first pulses gave the trains of periods 0.232 and 0.245 to the priors 0.272 and 0.258.  Of these validation
    episodes' pulses 26-60 (the start, two longest periods, is over by the 22nd) version 6 labelled 24 and 35 of
    35 wrong; now none."""
    entry = find_entry("paper-v0/" + name)
    seed = entry.seeds("validation")[0]
    ep = simulate(entry.spec.replace(n_pulses=60), seed)
    labels = play(make_policy("pt-post"), ep, policy_seed=seed).labels
    np.testing.assert_array_equal(labels[25:], ep.source[25:])


def test_policy_parameters_are_checked():
    with pytest.raises(DeintError, match="label"):
        make_policy("pt-post:label=mode")
    with pytest.raises(DeintError, match="no parameter"):
        make_policy("dokf:seed=1")
    with pytest.raises(DeintError, match="coast"):
        make_policy("pt-prior:coast=true")
    with pytest.raises(DeintError, match="reset_after"):
        make_policy("pt-post:coast=true,reset_after=0")
    for bad in (0, 1025):
        with pytest.raises(DeintError, match="particles"):
            make_policy(f"pt-post:particles={bad}")
    blind = simulate(find_entry("blind-v0/" + _first_blind()).spec, 0)
    with pytest.raises(DeintError, match="needs priors"):
        make_policy("pt-prior").reset(blind.priors, {})


def _first_blind() -> str:
    from deint_env.suites import load_suite

    return next(iter(load_suite("blind-v0"))).name


def test_classify_tracks():
    truth = np.array([11.0, 30.0, 80.0])
    assert classify(30.2, truth) == "true"
    assert classify(22.1, truth) == "x2 of 11"
    assert classify(14.6, truth) == "other"


@pytest.mark.parametrize("name", ["mk94-fig9", "mk94-fig10", "mk94-fig11", "mk94-fig13"])
def test_pt_experiments_run_quick(name, tmp_path):
    report = run_experiment(name, tmp_path, quick=True)
    assert (tmp_path / f"{name}.png").stat().st_size > 1000
    assert name in (tmp_path / f"{name}.txt").read_text()
    rows = json.loads((tmp_path / f"{name}.json").read_text())["rows"]
    assert rows and all(r["ours"] != "" for r in rows)
    assert report.files == [f"{name}.png"]


@pytest.mark.parametrize("scenario", ["robust-spurious0.2", "robust-combined"])
def test_pt_post_off_a_clean_channel_does_not_collapse(scenario):
    """Told a spurious (or missing) rate, the published PT calls nearly every pulse spurious once a
    track slips (coast=false: 0.35-0.66 of 400 pulses right on seeds 0-3); with VI-C-3's coasting,
    resets and the scored missed arrivals, which pt-post takes by itself off a clean channel, >= 0.85
    (measured 0.88-0.99), and with the rates unknown too (estimated online) >= 0.7 (measured 0.75-0.99).
    (pt-post version 4's particles alone often hold the tracks too: with coast=false, 0.86 on
    robust-spurious0.2's seed 0 and 0.875 on robust-combined's seed 2; here the PT is one teacher.)"""
    spec = find_entry("robust-v0/" + scenario).spec.replace(n_pulses=400)
    for seed in range(4):
        ep = simulate(spec, seed)
        told, bare, guessed = (play(make_policy(name), ep, policy_seed=seed).metrics["accuracy"]
                               for name in ("pt-post", "pt-post:coast=false,particles=1", "pt-post:rates=estimate"))
        assert bare < 0.7 and told >= 0.85 and guessed >= 0.7, (seed, bare, told, guessed)

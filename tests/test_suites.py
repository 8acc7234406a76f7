"""Suites: load, names, seed splits, tags, every scenario simulates, lookup by name, and the files
agree with the builder that wrote them."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import deint_env.suites as suites_mod
from deint_env import simulate
from deint_env.errors import DeintError
from deint_env.registration import PAPER_IDS
from deint_env.scenario import ScenarioSpec
from deint_env.suites import TAGS, Suite, find_entry, list_suites, load_suite, resolve_scenario
from deint_env.suites.build import BUILDERS

SUITES = list_suites()
ENTRIES = [pytest.param(s, e, id=f"{s}/{e.name}") for s in SUITES for e in load_suite(s)]


def test_expected_suites():
    assert set(SUITES) == set(BUILDERS)
    assert {"paper-v0", "paper-v1", "core-v0", "robust-v0", "agile-v0", "scale-v0", "blind-v0"} <= set(SUITES)


@pytest.mark.parametrize("name", SUITES)
def test_suite_loads(name):
    suite = load_suite(name)
    assert suite.name == name and isinstance(suite.version, int) and len(suite) > 0
    assert name.endswith(f"-v{suite.version}")
    names = [e.name for e in suite]
    assert len(names) == len(set(names))
    for e in suite:
        assert isinstance(e.spec, ScenarioSpec)
        assert set(e.tags) <= set(TAGS) and len(e.tags) == len(set(e.tags))
        assert not e.train.overlaps(e.test)
        assert max(e.train.start, e.test.start) >= min(e.train.stop, e.test.stop)  # disjoint half-open ranges
        assert len(e.test) >= 1 and len(e.train) >= 1


@pytest.mark.parametrize("name", SUITES)
def test_suite_file_matches_its_builder(name):
    built = BUILDERS[name]()
    loaded = load_suite(name)
    assert built.content() == loaded.content()
    assert built.content_hash == loaded.content_hash


def test_suites_match_their_published_hashes():
    hist = suites_mod.history()
    for name in SUITES:
        assert hist[name][-1]["hash"] == load_suite(name).content_hash, name


def test_content_hash_moves_with_content():
    suite = load_suite("robust-v0")
    d = suite.to_json_dict()
    assert Suite.from_json_dict(d).content_hash == suite.content_hash
    d2 = copy.deepcopy(d)
    d2["description"] = "other words"  # the description cannot move a score
    assert Suite.from_json_dict(d2).content_hash == suite.content_hash
    d2["scenarios"][0]["test"] = [d2["scenarios"][0]["test"][0], d2["scenarios"][0]["test"][1] + 1]
    assert Suite.from_json_dict(d2).content_hash != suite.content_hash
    d3 = copy.deepcopy(d)
    d3["scenarios"][0]["spec"]["n_pulses"] += 1
    assert Suite.from_json_dict(d3).content_hash != suite.content_hash


def test_tags_describe_the_scenario():
    """Where a tag names a feature, the tag is there exactly when the feature is."""
    for s in SUITES:
        for e in load_suite(s):
            sp = e.spec
            assert ("blind" in e.tags) == sp.blind, e.name
            assert ("spurious" in e.tags) == (sp.spurious_rate > 0), e.name
            assert ("agile" in e.tags) == any(x.modulation.kind != "constant" for x in sp.sources), e.name
            lossy = sp.missing_prob > 0 or sp.coincidence_resolution > 0 or any(x.active for x in sp.sources) \
                or (sp.receiver is not None and sp.receiver.threshold > 0)  # the threshold drops pulses
            assert ("missing" in e.tags) == lossy, e.name
            assert ("paper" in e.tags) == (s.startswith("paper-")), e.name
            assert ("pdw" in e.tags) == sp.has_descriptors, e.name
            assert ("scale" in e.tags) == (s.startswith("scale-")), e.name
            if "jitter" in e.tags:
                assert sp.toa_jitter_std > 0 or sp.pri_jitter_std > 0, e.name


@pytest.mark.parametrize("suite_name, entry", ENTRIES)
def test_every_scenario_simulates_its_first_test_seed(suite_name, entry):
    spec = entry.spec
    if spec.n_pulses > 100_000:
        pytest.skip("the 10^6-pulse scale scenarios are simulated in test_largest_scale_scenario (slow)")
    ep = simulate(spec, entry.test.start)
    assert len(ep) == spec.n_pulses
    assert np.all(np.isfinite(ep.toa)) and np.all(np.diff(ep.toa) >= 0)
    assert ep.n_labels == spec.n_labels and ep.blind == spec.blind
    assert ep.truth.n_sources <= len(spec.sources)
    assert ep.source.max() < ep.truth.n_sources
    assert (ep.amplitude is not None) == spec.amplitudes


@pytest.mark.slow
def test_largest_scale_scenario():
    for e in load_suite("scale-v0"):
        if e.spec.n_pulses > 100_000:
            ep = simulate(e.spec, e.test.start)
            assert len(ep) == e.spec.n_pulses and np.all(np.diff(ep.toa) >= 0)


# ---- lookup ---------------------------------------------------------------------------------------------
def test_find_entry_qualified_and_bare():
    q = find_entry("paper-v0/mk94-three")
    b = find_entry("mk94-three")
    assert q.spec == b.spec and q.name == "mk94-three"
    assert resolve_scenario("paper-v0/mk94-three") == q.spec
    assert resolve_scenario("core-n2-spread1.5-jitter0.05").name == "core-n2-spread1.5-jitter0.05"


@pytest.mark.parametrize("env_suffix, scenario", sorted(PAPER_IDS.items()))
def test_paper_ids_name_paper_scenarios(env_suffix, scenario):
    assert find_entry(scenario).spec.name == scenario.split("/")[1]
    assert "paper" in find_entry(scenario).tags


@pytest.mark.parametrize("name, words", [
    ("no-such-scenario", ["no-such-scenario", "SUITE/SCENARIO"]),
    ("paper-v0/no-such-scenario", ["no-such-scenario", "paper-v0"]),
    ("no-such-suite-v0/mk94-three", ["no-such-suite-v0", "known suites"]),
])
def test_unknown_names_are_clear_errors(name, words):
    with pytest.raises(DeintError) as info:
        find_entry(name)
    for w in words:
        assert w in str(info.value)
    with pytest.raises(DeintError):
        resolve_scenario(name)


def test_ambiguous_bare_name():
    """paper-v1 repeats paper-v0's scenarios: a bare name resolves where both agree (to paper-v0's
    entry), and is an error where they differ (the merging scenarios)."""
    assert find_entry("mk94-three") == find_entry("paper-v0/mk94-three") == find_entry("paper-v1/mk94-three")
    with pytest.raises(DeintError, match=r"several suites \(paper-v0, paper-v1\) and differs"):
        find_entry("mk94-missing-two")
    assert find_entry("paper-v1/mk94-missing-two").spec.merge == "emission"


def test_resolve_scenario_kinds():
    spec = load_suite("agile-v0").entries[0].spec
    assert resolve_scenario(spec) is spec
    assert resolve_scenario(spec.to_dict()) == spec
    with pytest.raises(DeintError, match="scenario"):
        resolve_scenario(42)


# ---- malformed suite files -------------------------------------------------------------------------------
def _one_scenario_suite(**changes) -> dict:
    d = load_suite("robust-v0").to_json_dict()
    d = copy.deepcopy(d)
    d["scenarios"] = d["scenarios"][:2]
    for k, v in changes.items():
        d["scenarios"][0][k] = v
    return d


def test_suite_file_validation():
    with pytest.raises(DeintError, match="overlap"):
        Suite.from_json_dict(_one_scenario_suite(train=[0, 100], test=[50, 60]))
    with pytest.raises(DeintError, match="'shiny'"):
        Suite.from_json_dict(_one_scenario_suite(tags=["shiny"]))
    with pytest.raises(DeintError, match="seed range"):
        Suite.from_json_dict(_one_scenario_suite(test=[10, 10]))
    d = _one_scenario_suite()
    d["scenarios"][1]["spec"]["name"] = d["scenarios"][0]["spec"]["name"]
    with pytest.raises(DeintError, match="twice"):
        Suite.from_json_dict(d)
    d = _one_scenario_suite()
    del d["scenarios"][0]["train"]
    with pytest.raises(DeintError, match="'train'"):
        Suite.from_json_dict(d)
    with pytest.raises(DeintError, match="unknown"):
        load_suite("no-such-v0")

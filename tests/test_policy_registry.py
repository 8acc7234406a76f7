"""The policy registry (issue 8): entry points, metadata, the one modes check, spec parsing limits."""

from __future__ import annotations

import gc
import sys
import tomllib
import weakref
from pathlib import Path

import pytest

from baselines.fdp import FDP
from deint_env import policies
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.policies import PolicyInfo, default_policies, list_policies, make_policy, parse_policy_spec
from deint_env.runner import play
from deint_env.simulate import simulate
from deint_env.suites import find_entry

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = '''
from deint_env.policies import PolicyInfo


class Constant:
    lag = 0

    def __init__(self, label=0):
        self.label = label

    def reset(self, priors, info):
        pass

    def act(self, obs):
        return self.label


POLICIES = (PolicyInfo("x-const", "x_policies:Constant", kind="learned", version=3, description="a plugin's"),)
'''


@pytest.fixture
def fresh_registry(monkeypatch):
    """An empty registry that loads its providers again on first use."""
    monkeypatch.setattr(policies, "_REGISTRY", {})
    monkeypatch.setattr(policies, "_loaded", False)
    monkeypatch.setattr(policies, "_builtins_loaded", False)


def fake_distribution(root: Path, entry: str, module: str = PLUGIN) -> None:
    """A third-party distribution as an installer leaves it: a module and its dist-info metadata."""
    info = root / "x_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: x-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[deint_bench.policies]\n{entry}\n")
    (root / "x_policies.py").write_text(module)


def test_pyproject_declares_the_builtin_providers():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["entry-points"][policies.GROUP] == policies.BUILTIN_PROVIDERS


def test_a_third_party_distribution_registers_through_the_entry_point_group(tmp_path, monkeypatch, fresh_registry):
    fake_distribution(tmp_path, "x = x_policies:POLICIES")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "x_policies", raising=False)
    assert policies.providers()["x"] == "x_policies:POLICIES"
    names = {p.name: p for p in list_policies()}
    assert names["x-const"].provider == "x" and names["x-const"].kind == "learned" and names["x-const"].version == 3
    assert {"fdp", "genie", "ppo", "tdc"} <= set(names)  # the built-ins are still there
    assert "x-const" not in default_policies()  # a third party's policy joins a board only when named
    episode = simulate(find_entry("paper-v0/mk94-two-var1").spec.replace(n_pulses=30), 0)
    assert play(make_policy("x-const:label=1"), episode).labels.tolist() == [1] * 30


def test_a_plugin_cannot_take_a_builtin_name(tmp_path, monkeypatch, fresh_registry):
    fake_distribution(tmp_path, "x = x_policies:POLICIES", PLUGIN.replace('"x-const", "x_policies:Constant"',
                                                                          '"fdp", "x_policies:Constant"'))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "x_policies", raising=False)
    with pytest.raises(DeintError, match="policy name 'fdp' is registered twice: by baselines .* and by x"):
        list_policies()


def test_a_shipped_policy_is_found_without_reading_the_entry_points(monkeypatch, fresh_registry):
    """Reading the installed metadata costs every `deint` start-up: a shipped name needs only the built-in
    providers."""
    def no_metadata():
        raise AssertionError("entry points read for a shipped policy")

    monkeypatch.setattr(policies, "providers", no_metadata)
    assert policies.policy_info("fdp").provider == "baselines"


def test_another_name_reads_the_entry_points(tmp_path, monkeypatch, fresh_registry):
    fake_distribution(tmp_path, "x = x_policies:POLICIES")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "x_policies", raising=False)
    assert policies.policy_info("x-const").provider == "x"


@pytest.mark.parametrize("entry, module, expected", [
    ("x = x_policies:NOPE", PLUGIN, "x_policies has no attribute 'NOPE'"),
    ("x = x_missing_module:POLICIES", PLUGIN, "cannot import x_missing_module"),
    ("x = x_policies:POLICIES", "POLICIES = ['fdp']", "must be a sequence of deint_env.policies.PolicyInfo"),
])
def test_a_broken_provider_is_one_line(tmp_path, monkeypatch, fresh_registry, entry, module, expected):
    fake_distribution(tmp_path, entry, module)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "x_policies", raising=False)
    with pytest.raises(DeintError, match=expected) as e:
        list_policies()
    assert "\n" not in str(e.value)


def test_metadata_is_checked():
    for bad in (dict(kind="ceiling"), dict(modes=()), dict(modes=("online",)), dict(version=0)):
        with pytest.raises(ValueError):
            PolicyInfo("x", "m:f", **bad)
    info = policies.policy_info("genie")
    assert info.oracle and info.kind == "oracle" and policies.policy_info("ppo").learned
    assert policies.policy_info("tree").limits.max_pulses == 20 and policies.policy_info("tdc").modes == ("blind",)


def test_default_set_leaves_out_policies_needing_a_parameter_and_pulse_limited_ones():
    names = default_policies()
    assert "tdc" not in names and "tree" not in names and {"genie", "ppo", "fdp", "random"} <= set(names)
    tuned = [p.name for p in list_policies() if p.required == ("suite",)]  # a tuned entry names its suite's preset
    assert names == [p.name for p in list_policies() if p.name not in ("agent", "agent-beam", "tdc", "tree", *tuned)]


def test_modes_are_checked_once_from_the_registry():
    blind = Priors(n_labels=3, blind=True)
    for name in ("fdp", "fdp-ll", "nearest-prior", "pt-prior", "pt-post", "dokf", "ekf-bank", "ekf-coupled", "tree"):
        with pytest.raises(NotApplicable, match=f"policy '{name}' needs priors"):
            make_policy(name).reset(blind, {})
    tdc = make_policy("tdc:model=test_tdc:FrequencyModel")
    with pytest.raises(NotApplicable, match="'tdc' plays blind scenarios only"):
        tdc.reset(Priors.from_json_dict({"period": [1.0, 2.0]}), {})
    fdp = make_policy("fdp")
    assert type(fdp) is FDP  # the policy stays itself
    make_policy("random").reset(blind, {"policy_seed": 0})  # plays both modes


def test_the_modes_check_leaves_no_reference_cycle():
    """A policy is freed when its last reference goes (its work arrays with it), not only when the cyclic
    garbage collector runs: the check's wrapper does not hold the policy."""
    gc.disable()
    try:
        policy = make_policy("fdp")
        policy.reset(Priors.from_json_dict({"period": [1.0, 2.0]}), {})
        ref = weakref.ref(policy)
        del policy
        assert ref() is None
    finally:
        gc.enable()


@pytest.mark.parametrize("spec, expected", [
    ("fdp:lookahead=3,lookahead=4", "'lookahead' is given twice"),
    ("fdp:lookahead=1e400", "numbers in policy parameters are finite"),
    ("fdp:lookahead=" + "9" * 400, "below 2^63"),
    ("random:seed=-1", "seed=-1 is invalid: an integer in [0, 2^63)"),
    ("random:seed=1e400", "numbers in policy parameters are finite"),
    ("random:seed=9223372036854775808", "below 2^63"),
    ("random:seed=0.5", "seed=0.5 is invalid"),
])
def test_bad_specs_are_one_line(spec, expected):
    with pytest.raises(DeintError) as e:
        make_policy(spec)
    assert expected in str(e.value) and "\n" not in str(e.value)


def test_spec_values_parse():
    assert parse_policy_spec("random:seed=9223372036854775807")[1] == {"seed": 2**63 - 1}
    assert parse_policy_spec("x:a=-2,b=1e-3,c=true,d=none,e=word") == ("x", dict(a=-2, b=1e-3, c=True, d=None,
                                                                                 e="word"))


def test_required_parameters_are_named_or_refused_and_keep_a_policy_out_of_the_defaults():
    from deint_env.policies import default_policies, policy_info

    assert policy_info("agent").required == ("checkpoint",) and policy_info("tdc").required == ("model",)
    for name, needed in (("agent", "checkpoint"), ("tdc", "model")):
        with pytest.raises(DeintError, match=f"policy '{name}' needs {needed}=...: write {name}:{needed}=VALUE"):
            make_policy(name)
        assert name not in default_policies()
    assert {"dagger", "ppo", "mht", "fdp"} <= set(default_policies())

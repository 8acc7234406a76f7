"""Declared policy parameters (issue #24, item 3): every shipped policy declares each keyword parameter
(type, default, range, meaning) and one helper validates them; `deint policies NAME` prints them."""

from __future__ import annotations

import inspect
import math

import pytest

from deint_env.cli import main
from deint_env.errors import DeintError
from deint_env.params import REQUIRED, Param, declare
from deint_env.policies import BUILTIN_PROVIDERS, list_policies, make_policy, policy_info

BUILTIN = [p for p in list_policies() if p.provider in BUILTIN_PROVIDERS]


@pytest.mark.parametrize("info", BUILTIN, ids=lambda p: p.name)
def test_every_builtin_policy_declares_its_signature(info):
    """Each keyword parameter of the factory is declared, with the signature's default (REQUIRED where the
    signature has none); a **kwargs factory (lmht, cdif, fdp-ll) declares the parameters it passes on."""
    declared = info.declaration()
    assert declared is not None, f"{info.name} declares no parameters"
    sig = inspect.signature(info.load()).parameters
    for name, p in sig.items():
        if p.kind in (p.VAR_KEYWORD, p.VAR_POSITIONAL) or name in declared.internal:
            continue
        assert name in declared, f"{info.name}: {name} is not declared"
        want = REQUIRED if p.default is p.empty else p.default
        got = declared[name].default
        assert got is want or (type(got) is type(want) and got == want), (info.name, name, got, want)
    if not any(p.kind is p.VAR_KEYWORD for p in sig.values()):
        assert set(declared.names) <= set(sig), f"{info.name} declares parameters its factory does not take"
    for k in info.required:
        assert declared[k].default is REQUIRED
    for row in declared.table():
        assert len(row) == 5 and all(row) and "\n" not in row[4]


def test_kwargs_policies_declare_what_they_pass_on():
    mht = policy_info("mht").declaration()
    lmht = policy_info("lmht").declaration()
    assert set(mht.names) < set(lmht.names) and {"checkpoint", "network"} <= set(lmht.names)
    hist = {"window", "align", "pri_min", "pri_max", "min_pulses", "min_fill", "max_miss", "presort_eps"}
    assert hist | {"x"} == set(policy_info("cdif").declaration().names)
    assert hist | {"x", "k"} == set(policy_info("sdif").declaration().names)
    assert set(policy_info("fdp-ll").declaration().names) == set(policy_info("fdp").declaration().names) - {"cost"}


def test_deint_policies_mht_lists_every_parameter(capsys):
    assert main(["policies", "mht"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("mht (reference")
    head = lines[1].split()
    assert head == ["parameter", "type", "default", "range", "meaning"]
    rule, starts, i = lines[2], [0], 0  # the columns start where the dashed rule's runs do
    while (i := rule.find("  -", i)) >= 0:
        starts.append(i + 2)
        i += 2
    assert len(starts) == 5
    rows = {}
    for line in lines[3:]:
        cells = [line[a:b].strip() for a, b in zip(starts, starts[1:] + [None])]
        rows[cells[0]] = cells[1:]
    from baselines.mht import MHT

    sig = [k for k in inspect.signature(MHT).parameters if k != "scorer"]
    assert list(rows) == sig and len(sig) == 24
    for name, (typ, default, rng, meaning) in rows.items():
        assert typ.split(" | ")[0] in ("int", "float", "str", "bool") and default and rng and len(meaning) > 10
    assert rows["beam"][:3] == ["int", "32", "[1, 100000]"]
    assert rows["p_gap"][:3] == ["float", "1e-06", "(0, 1)"]
    assert rows["rates"][:3] == ["str", "priors", "priors, estimate"]
    assert rows["margin"][:3] == ["float", "inf", "(0, inf]"]
    assert rows["look_restart"][:3] == ["int | None", "none", "[0, 100000]"]


def test_deint_policies_without_a_name_is_the_list(capsys):
    assert main(["policies"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].split()[:3] == ["policy", "kind", "modes"] and "mht" in out


@pytest.mark.parametrize("spec, message", [
    ("mht:beam=0", "beam=0 is invalid: an integer in [1, 100000]"),
    ("mht:beam=1.5", "beam=1.5 is invalid: an integer in [1, 100000]"),
    ("mht:beam=true", "beam=True is invalid: an integer"),
    ("mht:nscan=30,lag=20", "nscan=30 is invalid: at most lag=20"),
    ("mht:rates=maybe", "rates='maybe' is invalid: one of priors, estimate"),
    ("mht:beem=3", "policy 'mht' has no parameter 'beem'; its parameters: beam, start_beam"),
    ("fdp:lookahead=true", "lookahead=True is invalid: an integer in [1, 30]"),
    ("fdp:missing=1", "missing=1 is invalid: true or false"),
    ("fdp-ll:cost=raw", "policy 'fdp-ll' has no parameter 'cost'"),
    ("dokf:gate=-1", "gate=-1 is invalid: a number in (0, inf)"),
    ("dokf:reset_after=0", "reset_after=0 is invalid: an integer in [1, "),
    ("renewal-ml:lag=-2", "lag=-2 is invalid: an integer in [0, 256]"),
    ("agile-kf:switch=1", "switch=1 is invalid: a number in [0, 1)"),
    ("ekf-bank:label_scale=x", "label_scale='x' is invalid: one of period, time"),
    ("ekf-coupled:asym=1", "asym=1 is invalid: a number in [0, 1)"),
    ("cdif:x=-1", "x=-1 is invalid: a number in (0, 100]"),
    ("cdif:window=1", "window=1 is invalid: an integer in [2, 10001]"),
    ("dbscan:eps=0", "eps=0 is invalid: a number in (0, inf)"),
    ("hdbscan:min_cluster_size=1", "min_cluster_size=1 is invalid: an integer in [2, "),
    ("tree:max_pulses=500", "max_pulses=500 is invalid: an integer in [1, 200]"),
    ("nearest-prior:gate=0", "gate=0 is invalid: a number in (0, inf)"),
    ("lmht:beam=0", "beam=0 is invalid: an integer in [1, 100000]"),
    ("lmht:network=maybe", "network='maybe' is invalid: one of on, off"),
    ("seq:batch=0", "batch=0 is invalid: an integer in [1, 4096]"),
    ("dagger-beam:decision_lag=-1", "decision_lag=-1 is invalid: an integer in [0, 1000]"),
    ("mht-tuned:suite=core-v0,division=later", "division='later' is invalid: one of online, low-latency, offline"),
])
def test_bad_values_are_one_line_errors(capsys, spec, message):
    with pytest.raises(DeintError) as e:
        make_policy(spec)
    assert message in str(e.value) and "\n" not in str(e.value)
    code = main(["run", "--scenario", "core-v0/core-n4-spread4-jitter0.2", "--policy", spec, "--max-seeds", "1",
                 "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0]


def test_constructors_validate_through_the_declaration():
    from baselines.fdp import FDP
    from baselines.mht import MHT
    from baselines.pt import DOKFTracker

    for make, message in ((lambda: MHT(beam=0), "beam=0 is invalid"), (lambda: MHT(gate=math.nan), "gate=nan"),
                          (lambda: FDP(tree_gate=2.0, engine="numpy"), "tree_gate=2.0 is invalid"),
                          (lambda: FDP(lookahead=4, start_lag=4), "start_lag=4 is invalid: at least lookahead + 1"),
                          (lambda: DOKFTracker(coast="yes"), "coast='yes' is invalid: true or false or none")):
        with pytest.raises(ValueError, match=message.replace("+", r"\+")):
            make()
    assert MHT(gate=4).gate == 4.0 and MHT(look_restart=2, look_start=6).look_restart == 2


def test_param_validate():
    p = Param("gate", float, 4.0, "the gate", low=0, low_open=True)
    assert p.validate(3) == 3.0 and isinstance(p.validate(3), float) and p.validate(2.5) == 2.5
    for bad in (0, -1, math.inf, math.nan, True, "4", None):
        with pytest.raises(DeintError, match=r"^gate=.* is invalid: a number in \(0, inf\)$"):
            p.validate(bad)
    n = Param("beam", int, 8, "hypotheses", low=1, high=64)
    assert n.validate(64) == 64
    for bad in (0, 65, 2.0, False, None):
        with pytest.raises(DeintError, match=r"is invalid: an integer in \[1, 64\]$"):
            n.validate(bad)
    m = Param("margin", float, math.inf, "nats", low=0, high=math.inf, low_open=True)
    assert m.validate(math.inf) == math.inf and m.range == "(0, inf]"
    o = Param("look", int, None, "arrivals (none: look_start)", low=0, optional=True)
    assert o.validate(None) is None and o.type_name == "int | None" and o.range == "[0, inf)"
    with pytest.raises(DeintError, match="an integer in \\[0, inf\\) or none"):
        o.validate(-1)
    c = Param("rates", str, "priors", "rates", choices=("priors", "estimate"))
    with pytest.raises(DeintError, match="one of priors, estimate"):
        c.validate("Priors")
    b = Param("coast", bool, True, "coast")
    for bad in (1, 0, "true", None):
        with pytest.raises(DeintError, match="true or false$"):
            b.validate(bad)
    with pytest.raises(ValueError):
        Param("gate", float, -1.0, "a default outside its own range", low=0)
    with pytest.raises(ValueError):
        Param("gate", float, 1.0, "two\nlines")
    s = declare(p, n, internal=("scorer",))
    assert s.validate({"gate": 1, "beam": 2}) == {"gate": 1.0, "beam": 2}
    with pytest.raises(DeintError, match="no parameter 'scorer'"):
        s.validate({"scorer": object()})
    s.check({"self": object(), "gate": 1.0, "scorer": object(), "other": 1})
    assert s.changed(beam=None)["beam"].optional and s.only("beam").names == ("beam",)
    assert s.table()[0] == ("gate", "float", "4.0", "(0, inf)", "the gate")

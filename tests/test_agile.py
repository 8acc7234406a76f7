"""Agile PRIs: the PRI state models on the Kalman core, priors naming modulations, `agile-kf` and
`renewal-ml`.  The pulse trains here come from a small generator written in this file (not the
project's simulator), so a shared mistake in the simulator's modulation formulas would show."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from baselines import pri_models
from baselines.kalman import (DLMModel, LinearBlock, initial_block, innovation, linear_innovation, linear_predict,
                              linear_update, predict, update)
from deint_env.cli import main
from deint_env.episode import Priors
from deint_env.errors import DeintError
from deint_env.scenario import Modulation
from deint_env.simulate import simulate
from deint_env.suites import load_suite

SIGMA = 0.1


# ---- an independent pulse generator -------------------------------------------------------------------
def pri_sequence(kind: str, period: float, n: int, rng: np.random.Generator, **p) -> np.ndarray:
    """n PRIs straight from the textbook definitions (stagger cycle, saw-tooth, sine, dwells, AR(1))."""
    k = np.arange(n)
    if kind == "constant":
        return np.full(n, period)
    if kind == "stagger":
        levels = np.array(p["pattern"]) * period / np.mean(p["pattern"])
        return levels[k % len(levels)]
    if kind == "dwell_switch":
        levels = np.array(p["pattern"]) * period / np.mean(p["pattern"])
        return levels[(k // p["cycle"]) % len(levels)]
    if kind == "sliding":
        return period * (1 + p["depth"] * ((k % p["cycle"]) / (p["cycle"] - 1) - 0.5))
    if kind == "sinusoidal":
        return period * (1 + p["depth"] * np.sin(2 * math.pi * k / p["cycle"] + p["psi"]))
    if kind == "drifting":
        out = [period]
        for _ in range(n - 1):
            out.append(p["alpha"] * out[-1] + p["drift_std"] * rng.standard_normal())
        return np.array(out)
    raise AssertionError(kind)


def pulse_train(sources, duration: float, rng: np.random.Generator, missing: float = 0.0, spurious: float = 0.0):
    """sources: (phase, period, kind, params) each; returns sorted toa and true labels (-1 spurious)."""
    toas, labels = [], []
    for i, (phase, period, kind, params) in enumerate(sources):
        pri = pri_sequence(kind, period, int(3 * duration / period) + 2, rng, **params)
        t = phase + np.concatenate([[0.0], np.cumsum(pri[:-1])])
        t = t[t < duration]
        t = t[rng.random(t.size) >= missing]
        toas.append(t + SIGMA * rng.standard_normal(t.size))
        labels.append(np.full(t.size, i))
    if spurious:
        rate = spurious * sum(1 / s[1] for s in sources)
        c = rng.poisson(rate * duration)
        toas.append(np.sort(rng.random(c) * duration))
        labels.append(np.full(c, -1))
    toa, lab = np.concatenate(toas), np.concatenate(labels)
    order = np.argsort(toa, kind="stable")
    return toa[order], lab[order]


def write_files(tmp_path, toa, sources, modulation=True, **scalars):
    (tmp_path / "p.csv").write_text("toa\n" + "\n".join(repr(float(t)) for t in toa) + "\n")
    priors = {"period": [s[1] * 1.003 for s in sources], "phase": [s[0] + 0.05 for s in sources],
              "period_std": [0.01 * s[1] for s in sources], "phase_std": [0.05 * s[1] for s in sources],
              "jitter_std": SIGMA, **scalars}
    if modulation:
        priors["modulation"] = [None if kind == "constant" else
                                {"kind": kind, **{k: v for k, v in params.items() if k not in ("psi",)}}
                                for _, _, kind, params in sources]
    (tmp_path / "pr.json").write_text(json.dumps(priors))


def label_file(tmp_path, capsys, policy: str) -> np.ndarray:
    code = main(["label", str(tmp_path / "p.csv"), "--policy", policy, "--priors", str(tmp_path / "pr.json"),
                 "-o", str(tmp_path / "out.csv")])
    assert code == 0, capsys.readouterr().err
    rows = (tmp_path / "out.csv").read_text().split()[1:]
    return np.array([int(r.split(",")[1]) for r in rows])


AGILE = {
    "stagger": (0.0, 13.0, "stagger", {"pattern": [1.0, 1.4, 1.9]}),
    "sliding": (1.0, 12.0, "sliding", {"depth": 0.3, "cycle": 24}),
    "sinusoidal": (2.0, 14.0, "sinusoidal", {"depth": 0.25, "cycle": 40, "psi": 1.1}),
    "dwell_switch": (0.5, 12.5, "dwell_switch", {"pattern": [1.0, 1.5, 0.7], "cycle": 15}),
    "drifting": (3.0, 13.5, "drifting", {"alpha": 0.9997, "drift_std": 0.02}),
}
STEADY = [(4.0, 17.3, "constant", {}), (7.0, 23.9, "constant", {})]


# ---- the Kalman core ----------------------------------------------------------------------------------
def test_linear_block_is_the_dlm_block_for_a_constant_pri():
    """The general block with the constant model reproduces the 2x2 DLM core, pulse by pulse.  (The
    DLM block reaches the first pulse through one interval's noise, the general one starts at the
    first pulse: the DLM's phase variance is lowered by that interval's variance to match.)"""
    rng = np.random.default_rng(0)
    m = DLMModel(jitter_var=0.04, interval_var=0.01)
    b = initial_block(np.array([10.0]), np.array([3.0]), np.array([0.5]), np.array([math.sqrt(1.0 - 0.01)]))
    arrays = pri_models.build_bank([(pri_models.constant(),)], np.array([10.0]), np.array([0.5]), np.array([3.0]),
                                   np.array([1.0]), 0.01)
    lin = LinearBlock(arrays.x0, arrays.p0)
    y = 3.0 + 10.2 * np.arange(30) + rng.normal(0, 0.2, 30)
    for n, yk in enumerate(y):
        pb = predict(b, m)
        e, s = innovation(pb, yk, m)
        le, ls = linear_innovation(lin, yk, pri_models.TAU, m.jitter_var)
        assert le[0, 0] == pytest.approx(float(e[0]), abs=1e-9) and ls[0, 0] == pytest.approx(float(s[0]), rel=1e-9)
        b = update(pb, e, s, m)
        lin = linear_update(lin, le, ls, pri_models.TAU, m.jitter_var)
        lin = linear_predict(lin, arrays.transition_of(np.array([0]), np.array([n])), arrays.q)
    assert lin.x[0, 0, 1] == pytest.approx(float(b.period[0]), abs=1e-9)


def test_linear_update_is_joseph_form_bit_for_bit():
    """`linear_update` builds I - K H by subtracting K from one column of I; the written-out product
    I - K e_index' (computed here) must give the same bits, also for states of infinite variance (K not
    finite: the product's path) and for gains of either sign (-0.0 terms)."""
    rng = np.random.default_rng(3)
    for trial in range(50):
        d = int(rng.integers(2, 6))
        a = rng.normal(size=(4, 3, d, d))
        p = a @ np.swapaxes(a, -1, -2) * rng.uniform(0.01, 100.0)
        if trial % 5 == 0:
            p[0, 1, :, :] = np.inf
        b = LinearBlock(rng.normal(size=(4, 3, d)), p)
        index = int(rng.integers(d))
        e, s = rng.normal(size=(4, 3)), p[..., index, index] + 0.3
        with np.errstate(invalid="ignore"):  # inf / inf: the non-finite gains
            got = linear_update(b, e, s, index, 0.3)
            k = p[..., :, index] / s[..., None]
            i_kh = np.eye(d) - k[..., :, None] * np.eye(d)[index]
            want_p = i_kh @ p @ np.swapaxes(i_kh, -1, -2) + 0.3 * k[..., :, None] * k[..., None, :]
        assert got.x.tobytes() == (b.x + k * e[..., None]).tobytes()
        assert got.p.tobytes() == want_p.tobytes()


def test_imm_mixing_is_blom_and_bar_shaloms_interaction_step():
    """`PathSearch._mix`, all pairs at once, against IMM's interaction step written out one model j at a
    time: w_ij = p_ij mu_i / sum_i p_ij mu_i within a family, x0_j = sum_i w_ij x_i, P0_j = sum_i w_ij (P_i
    + (x_i - x0_j)(x_i - x0_j)')."""
    from baselines.agile import RenewalML

    rng = np.random.default_rng(5)
    policy = RenewalML()
    policy.reset(Priors(n_labels=2, period=np.array([10.0, 23.0]), phase=np.array([1.0, 4.0]), jitter_std=0.1,
                        period_std=np.array([0.1, 0.2]), phase_std=np.array([0.5, 0.5])), {})
    m, d = policy.arrays.valid.shape[1], policy.arrays.f.shape[-1]
    same = policy.arrays.same_family
    assert (same & ~np.eye(m, dtype=bool)).any()  # the default bank mixes (its PRI family)
    src = rng.integers(0, 2, 7)
    alive = rng.random((7, m)) < 0.8
    alive[:, 0] = True
    logw = np.where(alive, np.log(rng.dirichlet(np.ones(m), 7)), -np.inf)
    a = rng.normal(size=(7, m, d, d))
    b = LinearBlock(rng.normal(size=(7, m, d)) * 10, a @ np.swapaxes(a, -1, -2))
    got = policy._mix(src, logw, alive, b)
    for r in range(7):
        mu = np.exp(logw[r])
        trans = (1 - policy.switch) * np.eye(m) + policy.switch * alive[r][None, :] / alive[r].sum()
        for j in range(m):
            w = np.array([trans[i, j] * mu[i] if same[src[r], i, j] else 0.0 for i in range(m)])
            w = w / w.sum() if w.sum() > 0 else np.eye(m)[j]  # a model no family member reaches keeps its state
            x0 = sum(w[i] * b.x[r, i] for i in range(m))
            p0 = sum(w[i] * (b.p[r, i] + np.outer(b.x[r, i] - x0, b.x[r, i] - x0)) for i in range(m))
            np.testing.assert_allclose(got.x[r, j], x0, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(got.p[r, j], p0, rtol=1e-12, atol=1e-10)


@pytest.mark.parametrize("kind", sorted(AGILE))
def test_each_pri_model_predicts_its_own_modulation(kind):
    """One source, the model its modulation names: after a few cycles every arrival is predicted
    within 4 sigma, where the constant-PRI DLM misses most of them by far."""
    phase, period, _, params = AGILE[kind]
    rng = np.random.default_rng(1)
    pri = pri_sequence(kind, period, 400, rng, **params)
    y = phase + np.concatenate([[0.0], np.cumsum(pri[:-1])]) + SIGMA * rng.standard_normal(400)
    mod = Modulation(kind, **{k: (tuple(v) if isinstance(v, list) else v) for k, v in params.items() if k != "psi"})
    errors = {}
    for name, model in (("named", pri_models.from_modulation(mod, period)), ("constant", pri_models.constant())):
        a = pri_models.build_bank([(model,)], np.array([period]), np.array([0.01 * period]), np.array([phase]),
                                  np.array([0.5]), 0.0)
        state, z = LinearBlock(a.x0, a.p0), []
        for n, yk in enumerate(y):
            e, s = linear_innovation(state, yk, pri_models.TAU, SIGMA ** 2)
            z.append(float(e[0, 0] / np.sqrt(s[0, 0])))
            state = linear_predict(linear_update(state, e, s, pri_models.TAU, SIGMA ** 2),
                                   a.transition_of(np.array([0]), np.array([n])), a.q)
        errors[name] = np.abs(np.array(z[200:]))
    assert errors["named"].max() < 4.0, errors["named"].max()
    assert np.mean(errors["constant"] > 4.0) > 0.3 or kind == "drifting"


def test_drifting_model_estimates_the_shrinking_period():
    """MK94 II-C-2 with alpha < 1: the filtered T follows alpha^n T within 1 %."""
    rng = np.random.default_rng(2)
    pri = pri_sequence("drifting", 20.0, 600, rng, alpha=0.999, drift_std=0.0)
    y = np.concatenate([[0.0], np.cumsum(pri[:-1])]) + SIGMA * rng.standard_normal(600)
    a = pri_models.build_bank([(pri_models.drifting(0.999, 1e-4),)], np.array([20.0]), np.array([0.2]),
                              np.array([0.0]), np.array([0.5]), 0.0)
    state = LinearBlock(a.x0, a.p0)
    for n, yk in enumerate(y):
        e, s = linear_innovation(state, yk, pri_models.TAU, SIGMA ** 2)
        state = linear_predict(linear_update(state, e, s, pri_models.TAU, SIGMA ** 2),
                               a.transition_of(np.array([0]), np.array([n])), a.q)
    assert state.x[0, 0, 1] == pytest.approx(pri[-1] * 0.999, rel=0.01)
    assert abs(pri[-1] / 20.0 - 0.999 ** 599) < 1e-9  # the train did shrink (by 45 %)


# ---- priors naming modulations ------------------------------------------------------------------------
def test_priors_modulation_round_trips_and_rejects_bad_entries():
    d = {"period": [10.0, 20.0], "modulation": [{"kind": "stagger", "pattern": [1, 1.5]}, None]}
    p = Priors.from_json_dict(d)
    assert p.modulation == (Modulation("stagger", pattern=(1.0, 1.5)), None)
    assert Priors.from_json_dict(p.to_json_dict()).modulation == p.modulation
    assert Priors.from_info(p.as_info()).modulation == p.modulation
    for bad, what in (([{"kind": "stagger"}], "2 entries"), ([{"kind": "wiggle"}, None], "modulation.kind"),
                      ([{"kind": "sliding", "depth": 2.0, "cycle": 8}, None], "modulation.depth")):
        with pytest.raises(DeintError, match=what):
            Priors.from_json_dict({"period": [10.0, 20.0], "modulation": bad})


def test_agile_v1_is_agile_v0_with_named_modulations():
    """Same pulses and same numeric priors; the priors add each source's modulation, with the
    spec's parameters only (the sinusoid's drawn phase is nowhere in them)."""
    v0, v1 = load_suite("agile-v0"), load_suite("agile-v1")
    assert [e.name for e in v0] == [e.name for e in v1]
    for e0, e1 in zip(v0, v1):
        a, b = simulate(e0.spec, e0.test.start), simulate(e1.spec, e1.test.start)
        assert np.array_equal(a.toa, b.toa) and np.array_equal(a.source, b.source)
        assert np.array_equal(a.priors.period, b.priors.period) and a.priors.modulation is None
        assert b.priors.modulation == tuple(s.modulation for s in e1.spec.sources)
        assert "psi" not in json.dumps(b.priors.to_json_dict())


# ---- the trackers, through the command line -------------------------------------------------------
@pytest.mark.parametrize("kind", sorted(AGILE))
def test_trackers_label_a_generated_file(tmp_path, capsys, kind):
    """An agile source among two steady ones, labelled through `deint label`: with its modulation named
    both trackers label > 95 % right (the rest: pulses of two sources closer than the jitter), where
    the constant-PRI `dokf` falls under 90 %."""
    sources = [AGILE[kind], *STEADY]
    toa, truth = pulse_train(sources, 2500.0, np.random.default_rng(3))
    write_files(tmp_path, toa, sources)
    acc = {}
    for policy in ("agile-kf", "renewal-ml", "dokf"):
        labels = label_file(tmp_path, capsys, policy)
        assert labels.size == toa.size
        acc[policy] = np.mean(labels == truth)
    assert acc["agile-kf"] > 0.95 and acc["renewal-ml"] > 0.96 and acc["dokf"] < 0.9, acc


def test_renewal_ml_with_missing_and_spurious_pulses(tmp_path, capsys):
    """Young et al.'s setting: a staggered and a wobulated source plus a steady one, 10 % missed, 0.1
    spurious pulses per source pulse; the path search labels at least 90 % right."""
    sources = [AGILE["stagger"], AGILE["sinusoidal"], STEADY[1]]
    rng = np.random.default_rng(5)
    toa, truth = pulse_train(sources, 2500.0, rng, missing=0.1, spurious=0.1)
    write_files(tmp_path, toa, sources, missing_prob=0.1, spurious_rate=0.1)
    labels = label_file(tmp_path, capsys, "renewal-ml")
    truth = np.where(truth < 0, len(sources), truth)
    labels = np.where(labels < 0, len(sources), labels)
    assert np.mean(labels == truth) > 0.9, np.mean(labels == truth)
    assert np.mean(labels[truth == len(sources)] == len(sources)) > 0.5  # spurious pulses are found


def test_bad_modulation_in_a_priors_file_is_one_line(tmp_path, capsys):
    sources = [AGILE["stagger"], *STEADY]
    toa, _ = pulse_train(sources, 300.0, np.random.default_rng(6))
    write_files(tmp_path, toa, sources)
    d = json.loads((tmp_path / "pr.json").read_text())
    d["modulation"][0] = {"kind": "stagger", "pattern": [1.0]}
    (tmp_path / "pr.json").write_text(json.dumps(d))
    code = main(["label", str(tmp_path / "p.csv"), "--policy", "agile-kf", "--priors", str(tmp_path / "pr.json"),
                 "-o", str(tmp_path / "out.csv")])
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1 and "modulation.pattern" in err[0]
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.slow
def test_renewal_ml_on_agile_v1_first_test_seeds():
    """The acceptance target on the suite's own episodes: normalised score >= 0.9 on the first test
    seed of every agile-v1 scenario (about a minute)."""
    from deint_env.runner import make_jobs, run_job

    scores = {job.scenario["name"]: run_job(job).metrics["score"] for job in make_jobs(["renewal-ml"], "agile-v1", max_seeds=1)}
    assert len(scores) == 9 and min(scores.values()) >= 0.9, scores


def test_simulated_agile_v1_priors_file_names_the_modulations(tmp_path, capsys):
    """`deint simulate --priors-out` writes the modulation key, and `deint label` reads it back: with it
    agile-kf labels the stagger scenario's episode as well as its suite runs do."""
    out = tmp_path / "p.csv"
    assert main(["simulate", "agile-v1/agile-stagger3", "--seed", "1000001", "-o", str(out), "--priors-out",
                 str(tmp_path / "pr.json")]) == 0
    priors = json.loads((tmp_path / "pr.json").read_text())
    assert priors["modulation"][0] == {"kind": "stagger", "pattern": [1.0, 1.3, 1.7]}
    assert priors["modulation"][1:] == [{"kind": "constant"}, {"kind": "constant"}]
    labels = label_file(tmp_path, capsys, "agile-kf")
    truth = np.array([int(r.split(",")[-1]) for r in out.read_text().split()[1:]])
    assert np.mean(labels == truth) > 0.95


def links(labels: np.ndarray) -> np.ndarray:
    """Each pulse's predecessor under a labelling (-1: none; spurious labels link nowhere)."""
    last, out = {}, np.full(labels.size, -1)
    for k, lab in enumerate(labels.tolist()):
        if lab >= 0:
            out[k] = last.get(lab, -1)
            last[lab] = k
    return out


def test_renewal_ml_blind_links_a_generated_file(tmp_path, capsys):
    """Blind mode (a blind priors file: a label budget and the channel's jitter, no periods): tracks
    are born from the pulses; on three steady sources more than 95 % of the pulses are linked to their
    true predecessor, against under 40 % for `random`.  Without the jitter (--n-sources alone) it
    measures the noise from the pulses and links as well."""
    sources = [(0.0, 13.0, "constant", {}), *STEADY]
    toa, truth = pulse_train(sources, 2000.0, np.random.default_rng(7))
    (tmp_path / "p.csv").write_text("toa\n" + "\n".join(repr(float(t)) for t in toa) + "\n")
    (tmp_path / "pr.json").write_text(json.dumps({"blind": True, "label_budget": 6, "jitter_std": SIGMA}))
    code = main(["label", str(tmp_path / "p.csv"), "--policy", "renewal-ml", "--n-sources", "6",
                 "-o", str(tmp_path / "out.csv")])
    assert code == 0, capsys.readouterr().err
    labels = np.array([int(r.split(",")[1]) for r in (tmp_path / "out.csv").read_text().split()[1:]])
    acc = {"measured": np.mean(links(labels) == links(truth))}
    for policy in ("renewal-ml", "random"):
        code = main(["label", str(tmp_path / "p.csv"), "--policy", policy, "--priors", str(tmp_path / "pr.json"),
                     "-o", str(tmp_path / "out.csv")])
        assert code == 0, capsys.readouterr().err
        labels = np.array([int(r.split(",")[1]) for r in (tmp_path / "out.csv").read_text().split()[1:]])
        acc[policy] = np.mean(links(labels) == links(truth))
    assert acc["renewal-ml"] > 0.95 and acc["measured"] > 0.95 and acc["random"] < 0.4, acc


def test_unknown_phases_are_placed_by_the_first_pulse(tmp_path, capsys):
    """`--prior-periods` alone (phases unknown): each track's first arrival is taken to lie within a
    period of the first pulse; the path search then labels a staggered and two steady sources at least
    90 % right, far better than the greedy constant-PRI `dokf`."""
    sources = [AGILE["stagger"], *STEADY]
    toa, truth = pulse_train(sources, 2000.0, np.random.default_rng(8))
    (tmp_path / "p.csv").write_text("toa\n" + "\n".join(repr(float(t)) for t in toa) + "\n")
    periods = ",".join(str(s[1] * 1.003) for s in sources)
    acc = {}
    for policy in ("renewal-ml", "dokf"):
        code = main(["label", str(tmp_path / "p.csv"), "--policy", policy, "--prior-periods", periods,
                     "-o", str(tmp_path / "out.csv")])
        assert code == 0, capsys.readouterr().err
        labels = np.array([int(r.split(",")[1]) for r in (tmp_path / "out.csv").read_text().split()[1:]])
        acc[policy] = np.mean(labels == truth)
    assert acc["renewal-ml"] > 0.9 and acc["dokf"] < acc["renewal-ml"] - 0.2, acc


@pytest.mark.parametrize("kind", ["drifting", "sinusoidal", "sliding", "stagger"])
def test_default_bank_without_named_modulations(tmp_path, capsys, kind):
    """Priors that name no modulation: renewal-ml's default bank (constant, PRI rate, 2-/3-stagger,
    switch, pruned after 100 pulses) still labels > 95 % right.  (The test's dwell-and-switch, +-40 %
    every 15 pulses, is not among them: 0.79 without its pattern named.)"""
    sources = [AGILE[kind], *STEADY]
    toa, truth = pulse_train(sources, 2500.0, np.random.default_rng(3))
    write_files(tmp_path, toa, sources, modulation=False)
    acc = np.mean(label_file(tmp_path, capsys, "renewal-ml") == truth)
    assert acc > 0.95, acc

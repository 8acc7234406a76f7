"""PRI models real emitters use (random-level stagger, deep sliding, non-integer wobulation, dwells of
their own lengths): the spec's validation, the simulator's statistics, and the anchored agile trackers
on files from a generator written here in plain numpy (not `deint_env.sim`), labelled through
`deint label` as a user would.

The generator mimics the renewal-process deinterleaving data sets (Young et al. 2019 style): 3 radars,
about 1000 received pulses, 0-30 % of the emissions missing, 10-20 % spurious pulses; each radar's
model stated in its own convention (random levels in PRI units with their probabilities or a Markov
matrix; a sliding ramp's depth relative to its first PRI; a wobulation's frequency in cycles per
pulse) and translated into the priors format as a user would.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from deint_env.cli import main as deint
from deint_env.errors import DeintError
from deint_env.scenario import Modulation, PriorSpec, ScenarioSpec, SourceSpec
from deint_env.simulate import simulate

JITTER = 0.05  # TOA noise std; PRIs are 10 to 30
PHASE_STD = 0.05  # the priors' phase std, relative to the period
MARKOV = ((0.1, 0.8, 0.1), (0.1, 0.1, 0.8), (0.8, 0.1, 0.1))


def radar(kind: str, rng: np.random.Generator, n: int) -> tuple[np.ndarray, dict, float]:
    """n successive PRIs of one radar, its priors' modulation entry and its mean PRI."""
    if kind in ("random_stagger", "markov_stagger"):  # levels in PRI units, drawn per pulse
        levels = rng.uniform(10, 30) * np.array([0.8, 1.0, 1.3])
        if kind == "random_stagger":
            probs = np.array([0.5, 0.3, 0.2])
            s = rng.choice(3, size=n, p=probs)
            mod = {"kind": "random_stagger", "pattern": levels.tolist(), "probs": probs.tolist()}
        else:
            probs = np.full(3, 1 / 3)  # MARKOV is doubly stochastic: uniform stationary distribution
            s = np.empty(n, dtype=int)
            s[0] = rng.integers(3)
            for j in range(1, n):
                s[j] = rng.choice(3, p=MARKOV[s[j - 1]])
            mod = {"kind": "random_stagger", "pattern": levels.tolist(), "transition": [list(r) for r in MARKOV]}
        return levels[s], mod, float(probs @ levels)
    if kind == "sliding":  # base PRI B = the ramp's first, depth relative to it (> 1: the ramp spans more)
        base, depth, cycle = rng.uniform(8, 18), rng.uniform(1.0, 1.3), int(rng.integers(24, 49))
        pri = base * (1 + depth * (np.arange(n) % cycle) / (cycle - 1))
        return pri, {"kind": "sliding", "depth": depth, "cycle": cycle, "relative_to": "start"}, base * (1 + depth / 2)
    if kind == "sinusoidal":  # wobulation of 0.015 cycles per pulse: 66.7 pulses a cycle
        mean, depth, freq = rng.uniform(10, 30), rng.uniform(0.1, 0.2), 0.015
        pri = mean * (1 + depth * np.sin(2 * math.pi * freq * np.arange(n) + rng.uniform(0, 2 * math.pi)))
        return pri, {"kind": "sinusoidal", "depth": depth, "cycle": 1 / freq}, mean
    raise ValueError(kind)


def write_file(folder, kinds: tuple[str, ...], seed: int, missing: float, spurious: float, n_pulses: int = 1000):
    """A pulse CSV (toa,source) and its priors JSON; returns their paths and the true sources."""
    rng = np.random.default_rng(seed)
    toa, src, mods, means, phases = [], [], [], [], []
    horizon = n_pulses / ((1 - missing) * (1 + spurious) * 3 / 20)  # mean PRI about 20
    for i, kind in enumerate(kinds):
        pri, mod, mean = radar(kind, rng, int(horizon / 5))
        phase = rng.uniform(0, pri[0])
        t = phase + np.r_[0.0, np.cumsum(pri[:-1])]
        keep = (t < horizon) & (rng.random(t.size) >= missing)
        toa.append(t[keep] + JITTER * rng.standard_normal(keep.sum()))
        src.append(np.full(keep.sum(), i))
        mods.append(mod), means.append(mean), phases.append(phase)
    rate = spurious * float(np.sum(1 / np.array(means)))  # spurious pulses per emitted radar pulse
    n_spur = rng.poisson(rate * horizon)
    toa.append(rng.uniform(0, horizon, n_spur)), src.append(np.full(n_spur, -1))
    toa, src = np.concatenate(toa), np.concatenate(src)
    order = np.argsort(toa)
    toa, src = toa[order][:n_pulses], src[order][:n_pulses]
    pulses, priors = folder / f"pulses{seed}.csv", folder / f"priors{seed}.json"
    pulses.write_text("toa,source\n" + "".join(f"{t!r},{s}\n" for t, s in zip(toa.tolist(), src.tolist())))
    priors.write_text(json.dumps({
        "period": means, "phase": phases, "period_std": [0.01 * m for m in means],
        "phase_std": [PHASE_STD * m for m in means], "jitter_std": JITTER, "missing_prob": missing,
        "spurious_rate": spurious, "modulation": mods}))
    return pulses, priors, src


def label_accuracy(folder, pulses, priors, truth: np.ndarray, policy: str) -> float:
    out = folder / f"{pulses.stem}-{policy}.csv"
    assert deint(["label", str(pulses), "--policy", policy, "--priors", str(priors), "-o", str(out)]) == 0
    labels = np.array([int(line.split(",")[1]) for line in out.read_text().splitlines()[1:]])
    return float(np.mean(labels == truth))


ANCHORED = ("agile-kf", "renewal-ml")
MIXES = (("random_stagger", "sliding", "sinusoidal"), ("markov_stagger", "random_stagger", "sinusoidal"),
         ("sliding", "markov_stagger", "sliding"))
FAST = [(MIXES[0], 0, 0.3, 0.2), (MIXES[2], 1, 0.3, 0.2)]
# The grid's last file below the target, (MIXES[1], 11, 0.3, 0.2), had renewal-ml at 0.881 when the grid was
# written (its wobulated train held by the two random-level ones); version 3 labels 0.973 of it, version 4 0.976.
GRID = [(mix, seed, q, s) for mix in MIXES for seed in (10, 11) for q in (0.0, 0.15, 0.3) for s in (0.1, 0.2)]


def check_file(tmp_path, kinds, seed, missing, spurious) -> None:
    pulses, priors, truth = write_file(tmp_path, kinds, seed, missing, spurious)
    acc = {p: label_accuracy(tmp_path, pulses, priors, truth, p) for p in ANCHORED}
    assert max(acc.values()) >= 0.90, (kinds, seed, missing, spurious, acc)


@pytest.mark.parametrize("kinds,seed,missing,spurious", FAST)
def test_outside_agile_files_are_labelled_well(tmp_path, kinds, seed, missing, spurious):
    check_file(tmp_path, kinds, seed, missing, spurious)


@pytest.mark.slow
@pytest.mark.parametrize("kinds,seed,missing,spurious", GRID)
def test_outside_agile_grid(tmp_path, kinds, seed, missing, spurious):
    check_file(tmp_path, kinds, seed, missing, spurious)


# ---- the spec: every bad value is one line naming the field and what is allowed -----------------
BAD = {
    "transition not row-stochastic": (dict(kind="random_stagger", pattern=(1, 2), transition=((0.5, 0.4), (0, 1))),
                                      "modulation.transition", "row-stochastic"),
    "transition reducible": (dict(kind="random_stagger", pattern=(1, 2), transition=((1, 0), (0, 1))),
                             "modulation.transition", "irreducible"),
    "transition of the wrong size": (dict(kind="random_stagger", pattern=(1, 2, 3),
                                          transition=((0.5, 0.5), (0.5, 0.5))), "modulation.transition", "3x3"),
    "probs not summing to 1": (dict(kind="random_stagger", pattern=(1, 2), probs=(0.3, 0.3)), "modulation.probs",
                               "summing to 1"),
    "probs and transition": (dict(kind="random_stagger", pattern=(1, 2), probs=(0.5, 0.5),
                                  transition=((0.5, 0.5), (0.5, 0.5))), "modulation.transition", "not both"),
    "probs on a stagger": (dict(kind="stagger", pattern=(1, 2), probs=(0.5, 0.5)), "modulation.probs",
                           "kind='random_stagger' only"),
    "one level": (dict(kind="random_stagger", pattern=(1.0,)), "modulation.pattern", "at least two"),
    "deep ramp relative to the mean": (dict(kind="sliding", depth=1.0231, cycle=8), "modulation.depth",
                                       "relative_to='start'"),
    "ramp start depth 0": (dict(kind="sliding", depth=0.0, cycle=8, relative_to="start"), "modulation.depth",
                           "0 < depth"),
    "relative_to on a sinusoid": (dict(kind="sinusoidal", depth=0.1, cycle=8, relative_to="start"),
                                  "modulation.relative_to", "sliding only"),
    "unknown relative_to": (dict(kind="sliding", depth=0.1, cycle=8, relative_to="end"), "modulation.relative_to",
                            "mean, start"),
    "wobulation cycle below 2": (dict(kind="sinusoidal", depth=0.1, cycle=1.5), "modulation.cycle", ">= 2"),
    "fractional sliding cycle": (dict(kind="sliding", depth=0.1, cycle=8.5), "modulation.cycle", "integer"),
    "dwells of the wrong count": (dict(kind="dwell_switch", pattern=(1, 2), dwells=(3,)), "modulation.dwells",
                                  "one dwell per pattern level"),
    "dwells and cycle": (dict(kind="dwell_switch", pattern=(1, 2), dwells=(3, 4), cycle=5), "modulation.dwells",
                         "cycle left 0"),
    "zero dwell": (dict(kind="dwell_switch", pattern=(1, 2), dwells=(3, 0)), "modulation.dwells", ">= 1"),
    "random start of a sinusoid": (dict(kind="sinusoidal", depth=0.1, cycle=8, random_start=True),
                                   "modulation.random_start", "true only for"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_modulation_is_one_clear_line(case):
    kwargs, field, allowed = BAD[case]
    with pytest.raises(DeintError) as e:
        Modulation(**kwargs)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(field + "=") and allowed in msg, msg


def test_bad_modulation_in_a_priors_file_is_one_line(tmp_path, capsys):
    pulses, priors, _ = write_file(tmp_path, MIXES[1], 0, 0.0, 0.1, n_pulses=50)
    d = json.loads(priors.read_text())
    d["modulation"][0]["transition"] = [[0.5, 0.5, 0.0]] * 2
    priors.write_text(json.dumps(d))
    assert deint(["label", str(pulses), "--policy", "agile-kf", "--priors", str(priors),
                  "-o", str(tmp_path / "l.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "modulation.transition" in err and "row-stochastic" in err, err


def test_new_fields_keep_old_serialisations():
    old = Modulation("sinusoidal", depth=0.1, cycle=50)
    assert Modulation("sinusoidal", depth=0.1, cycle=50.0) == old
    assert ScenarioSpec(name="s", sources=(SourceSpec(period=10.0, modulation=old),), n_pulses=10).to_dict()[
        "sources"][0]["modulation"] == {"kind": "sinusoidal", "depth": 0.1, "cycle": 50}
    rs = Modulation("random_stagger", pattern=(1.0, 2.0), transition=((0.5, 0.5), (0.2, 0.8)))
    spec = ScenarioSpec(name="s", sources=(SourceSpec(period=10.0, modulation=rs),), n_pulses=10)
    assert ScenarioSpec.from_dict(json.loads(spec.to_json())) == spec


# ---- the simulator: the generated PRIs follow each model's definition -----------------------------
def one_source(mod: Modulation, n: int = 4000, period: float = 10.0) -> ScenarioSpec:
    return ScenarioSpec(name="one", sources=(SourceSpec(period=period, phase=0.0, modulation=mod),), n_pulses=n,
                        priors=PriorSpec(modulation=True))


def levels_of(mod: Modulation, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    ep = simulate(one_source(mod), seed)
    pri = ep.truth.source_pri(0)[:-1]
    ratio = mod.level_ratios() * ep.truth.period[0]
    level = np.argmin(np.abs(pri[:, None] - ratio[None]), axis=1)
    assert np.allclose(pri, ratio[level])  # every PRI is one of the levels
    return level, pri


def test_random_levels_follow_their_probabilities():
    probs = (0.5, 0.3, 0.2)
    level, pri = levels_of(Modulation("random_stagger", pattern=(1.0, 1.3, 1.7), probs=probs))
    freq = np.bincount(level, minlength=3) / level.size
    assert np.allclose(freq, probs, atol=4 * math.sqrt(0.25 / level.size))
    assert abs(pri.mean() / 10.0 - 1) < 0.02  # T is the mean PRI
    # i.i.d.: the level after a level has the same distribution
    after0 = np.bincount(level[1:][level[:-1] == 0], minlength=3) / (level[:-1] == 0).sum()
    assert np.allclose(after0, probs, atol=0.05)


def test_markov_levels_follow_their_transition_matrix():
    trans = ((0.1, 0.9, 0.0), (0.0, 0.2, 0.8), (0.7, 0.0, 0.3))
    mod = Modulation("random_stagger", pattern=(1.0, 1.3, 1.7), transition=trans)
    level, pri = levels_of(mod)
    counts = np.zeros((3, 3))
    np.add.at(counts, (level[:-1], level[1:]), 1)
    assert np.allclose(counts / counts.sum(axis=1, keepdims=True), trans, atol=0.04)
    pi = mod.level_probs()
    assert np.allclose(pi @ np.array(trans), pi)  # stationary
    assert np.allclose(np.bincount(level, minlength=3) / level.size, pi, atol=0.04)
    assert abs(pri.mean() / 10.0 - 1) < 0.02


def test_random_levels_differ_between_episodes_and_repeat_within_one():
    mod = Modulation("random_stagger", pattern=(1.0, 2.0))
    a, b = levels_of(mod, 1)[0], levels_of(mod, 2)[0]
    assert not np.array_equal(a[:100], b[:100])
    assert np.array_equal(a, levels_of(mod, 1)[0])


def test_deep_sliding_ramp_spans_more_than_its_first_pri():
    depth, cycle = 1.5, 20
    ep = simulate(one_source(Modulation("sliding", depth=depth, cycle=cycle, relative_to="start")), 0)
    pri = ep.truth.source_pri(0)[:-1]
    first = 10.0 / (1 + depth / 2)
    assert np.allclose(pri[:cycle], first * (1 + depth * np.arange(cycle) / (cycle - 1)))
    assert pri.max() - pri.min() > first and pri.min() > 0
    assert abs(pri[: cycle * (pri.size // cycle)].mean() - 10.0) < 1e-9


def test_random_start_draws_the_ramp_position():
    mod = Modulation("sliding", depth=0.5, cycle=16, random_start=True)
    starts = {int(np.argmin(simulate(one_source(mod, 200), seed).truth.source_pri(0)[:16])) for seed in range(12)}
    assert len(starts) > 3


def test_wobulation_of_a_non_integer_cycle():
    cycle, depth = 1 / 0.015, 0.2
    pri = simulate(one_source(Modulation("sinusoidal", depth=depth, cycle=cycle)), 0).truth.source_pri(0)[:-1]
    n = np.arange(pri.size)

    def misfit(c: float) -> float:
        x = np.stack([np.sin(2 * np.pi * n / c), np.cos(2 * np.pi * n / c)], axis=1)
        coef, *_ = np.linalg.lstsq(x, pri / 10.0 - 1, rcond=None)
        return float(np.abs(x @ coef - (pri / 10.0 - 1)).max())

    assert misfit(cycle) < 1e-9 and misfit(round(cycle)) > 0.05


def test_dwells_of_their_own_lengths():
    dwells, pattern = (20, 35, 10), (1.0, 1.4, 0.8)
    pri = simulate(one_source(Modulation("dwell_switch", pattern=pattern, dwells=dwells)), 0).truth.source_pri(0)
    run_starts = np.r_[0, np.nonzero(np.diff(pri))[0] + 1]
    runs = np.diff(run_starts)[:6]
    assert runs.tolist() == [20, 35, 10, 20, 35, 10]
    assert abs(pri[:sum(dwells)].mean() - 10.0) < 1e-9  # T is the pulse-weighted mean


# ---- the trackers' model pieces ---------------------------------------------------------------------
def test_level_runs_are_the_chains_distribution():
    """`JumpLevels.sequences`: from every last level, the runs of each length r are a distribution, and
    a run's length S is its level counts times the level ratios (r = 2: every pair's sum)."""
    from baselines import pri_models

    mod = Modulation("random_stagger", pattern=(1.0, 1.3, 1.7), transition=((0.1, 0.9, 0.0), (0.0, 0.2, 0.8),
                                                                            (0.7, 0.0, 0.3)))
    lv = pri_models.random_stagger(mod).jumps
    s, runs, last, logp = lv.sequences(3)
    p = np.exp(logp)
    for r in range(4):
        assert np.allclose(p[:, runs == r].sum(axis=1), 1.0)
    ratio, trans = mod.level_ratios(), np.array(mod.transition)
    for a in range(3):  # r = 2 from level a: P(i then j) = trans[a, i] trans[i, j], S = ratio_i + ratio_j
        for i in range(3):
            for j in range(3):
                col = (runs == 2) & (last == j) & np.isclose(s, ratio[i] + ratio[j])
                want = sum(trans[a, i2] * trans[i2, j] for i2 in range(3) if np.isclose(ratio[i2] + ratio[j],
                                                                                        ratio[i] + ratio[j]))
                assert np.isclose(p[a, col].sum(), want)


def test_fractional_wobulation_model_rotates_to_the_definition():
    """theta = (T, s, c) advanced by the model's transition gives PRI_n = phi . theta_n =
    T (1 + depth sin(2 pi n / L + psi)) for a cycle L that is not whole."""
    from baselines import pri_models

    cycle, depth, t, psi = 1 / 0.015, 0.2, 12.0, 0.7
    model = pri_models.sinusoidal(cycle, depth)
    theta = np.array([t, t * depth * np.sin(psi), t * depth * np.cos(psi)])
    pri = []
    for _ in range(200):
        pri.append(float(model.table[0] @ theta))
        theta = model.transition @ theta
    n = np.arange(200)
    assert np.allclose(pri, t * (1 + depth * np.sin(2 * np.pi * n / cycle + psi)))


def test_a_random_cycle_position_gets_one_model_per_position():
    from baselines import pri_models

    mod = Modulation("sliding", depth=1.2, cycle=10, relative_to="start", random_start=True)
    bank = pri_models.bank_from_modulation(mod, 10.0)
    assert len(bank) == 10
    n = np.arange(25)
    for o, model in enumerate(bank):  # model o at emission n: the ramp at position n + o
        ratio = model.table[n % 10] @ model.unit
        assert np.allclose(ratio, (1 + 1.2 * ((n + o) % 10) / 9) / 1.6)


@pytest.mark.parametrize("levels,q", [(3, 0.2), (3, 0.001), (8, 0.1), (16, 0.1), (64, 0.1)])
def test_random_level_mixtures_take_the_longest_runs_that_fit(levels, q):
    """A random-level source's mixture scores runs of up to `runs` intervals, fewer where their (level
    counts, last level) groups pass `_JUMP_COLUMNS`: the longest that fit.  They were found by building
    the longest first and shortening, which for 64 levels meant ~10^10 groups (hours) before the first
    check; now they are built from one run up."""
    from baselines import agile, pri_models

    mod = Modulation("random_stagger", pattern=tuple(float(x) for x in range(1, levels + 1)))
    lv = pri_models.from_modulation(mod, 10.0).jumps
    runs = max(1, min(agile._JUMP_RUNS, math.ceil(math.log(agile._JUMP_TAIL) / math.log(q)) + 1))
    got = agile._Jumps([(pri_models.from_modulation(mod, 10.0),)], q).columns[0]
    r = max(got[1])  # the longest run scored
    assert r == runs or (lv.sequences(r + 1)[0].size > agile._JUMP_COLUMNS >= got[0].size)
    assert all(np.array_equal(a, b) for a, b in zip(got, lv.sequences(r)))


def test_a_random_level_search_too_large_to_run_is_refused_up_front(tmp_path, capsys):
    """Three random-level sources of 64 levels each: renewal-ml's default beam (64 x 4) scores 3.2e6
    terms a pulse (over 60 s for 1000 pulses); it is refused in one line before any pulse, not run."""
    pulses, priors, _ = write_file(tmp_path, MIXES[1], 0, 0.0, 0.1, n_pulses=50)
    d = json.loads(priors.read_text())
    d["modulation"] = [{"kind": "random_stagger", "pattern": [1.0 + 0.01 * k for k in range(64)]}] * 3
    priors.write_text(json.dumps(d))
    assert deint(["label", str(pulses), "--policy", "renewal-ml", "--priors", str(priors),
                  "-o", str(tmp_path / "l.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "terms a pulse, at most" in err and not (tmp_path / "l.csv").exists(), err

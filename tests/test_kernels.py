"""Every numba kernel against Python.  The compiled modules are found by their `@njit` decorators and each
must have a check here (`CHECKS`); the kernels of a module are found as its objects with `py_func` (numba
dispatchers), so a new kernel is checked without listing it.  Trackers are played with every kernel of
their modules swapped for its Python source (`.py_func`, callers included) and give the labels of the
compiled run, and each such check fails when one of its modules' kernels was never called by it.  The blind
deinterleavers' kernels are held to small plain-Python references of their own, on random inputs."""

from __future__ import annotations

import ast
import functools
import importlib
import math
from collections import Counter
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from baselines.jit_cache import kernels
from deint_env import PriorSpec, Range, ScenarioSpec, SourceSpec, make_policy, simulate
from deint_env.episode import Priors
from deint_env.runner import play

ROOT = Path(__file__).resolve().parents[1]

# compiled module -> the test here (or elsewhere) that checks its kernels
CHECKS = {
    "baselines.kalman_jit": "tests/test_kalman_compiled.py",
    "baselines.survivor": "test_mht_kernels_label_as_their_python_source",
    "baselines.mht.kernels": "test_mht_kernels_label_as_their_python_source",
    "baselines.mht.start": "test_mht_kernels_label_as_their_python_source",
    "baselines.mht.scorer": "test_mht_kernels_label_as_their_python_source",
    "agents.lmht": "test_mht_kernels_label_as_their_python_source",
    "baselines.fdp": "test_fdp_kernels_label_as_their_python_source",
    "baselines.fdp_start": "test_fdp_kernels_label_as_their_python_source",
    "agents.beam_kernels": "test_beam_kernels_label_as_their_python_source",
    "agents.fast_net": "test_beam_kernels_label_as_their_python_source (the beam's), "
                       "test_agent_kernels_label_as_their_python_source (the agent policy's)",
    "deint_env.features_kernels": "test_agent_kernels_label_as_their_python_source",
    "baselines.blind.search": "test_walk_equals_a_python_reference",
    "baselines.blind.pri_transform": "test_pri_transforms_equal_python_references",
}


def _is_jit(decorator: ast.expr) -> bool:
    f = decorator.func if isinstance(decorator, ast.Call) else decorator
    return (f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")) in ("njit", "jit")


def compiled_modules() -> set[str]:
    """The project modules with a function decorated by numba (`njit`, `numba.njit`, `jit`, ...)."""
    out = set()
    for package in ("deint_env", "baselines", "agents"):
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef) and any(_is_jit(d) for d in node.decorator_list):
                    parts = path.relative_to(ROOT).with_suffix("").parts
                    out.add(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
                    break
    return out


def test_every_compiled_module_has_a_check():
    assert compiled_modules() == set(CHECKS)


def defined(*modules: ModuleType) -> set[str]:
    """The kernels the modules define, as `module.name`."""
    return {f"{m.__name__}.{k.py_func.__name__}" for m in modules for k in kernels(vars(m))}


def interpreted(monkeypatch, *modules: ModuleType) -> Counter:
    """Every kernel in the modules' namespaces (their own and those they import) replaced by its Python
    source; returns the calls per kernel (`module.name`), counted as they happen."""
    calls: Counter = Counter()

    def counted(f):
        key = f"{f.__module__}.{f.__name__}"

        @functools.wraps(f)
        def run(*args, **kwargs):
            calls[key] += 1
            return f(*args, **kwargs)

        return run

    for module in modules:
        for name, obj in list(vars(module).items()):
            if hasattr(obj, "py_func"):
                monkeypatch.setattr(module, name, counted(obj.py_func))
    return calls


def _modules(*names: str) -> list[ModuleType]:
    return [importlib.import_module(n) for n in names]


SMALL = ScenarioSpec(name="kernels-small", n_pulses=150, toa_jitter_std=0.2, missing_prob=0.1, spurious_rate=0.1,
                     sources=tuple(SourceSpec(period=Range(10.0, 30.0, log=True)) for _ in range(3)),
                     priors=PriorSpec(period_error=0.01, phase_error=0.05))
MHT_SMALL = "beam=8,start_beam=16,nscan=6,lag=120"
MHT_PLAYS = [  # (policy, priors): every path of the beam, the start, the learned scorer
    (f"mht:{MHT_SMALL},dense=0", None),
    (f"mht:{MHT_SMALL},dense=0,margin=8", None),
    (f"mht:{MHT_SMALL},dense=0,margin=8,dead=1,look_restart=2,jump=0.04,jump_z=1,drift=0.001", None),
    (f"mht:{MHT_SMALL}", PriorSpec(period_error=0.01, phase_error=None)),  # the multi-start (`_loglik`)
    (f"lmht:{MHT_SMALL},misfit=0", None),  # the learned scorer from the first pulse
]


def _crowded_start():
    """Two sources of near-equal period and phase (each first pulse in the other's first gate: the pair
    re-start of `initiate`) and a third, each prior 1 % off."""
    rng = np.random.default_rng(0)
    trains = [(10.0, 3.0), (10.07, 3.25), (23.0, 7.0)]
    toa = np.sort(np.concatenate([ph + t * np.arange(int(400 / t)) + 0.05 * rng.standard_normal(int(400 / t))
                                  for t, ph in trains]))
    priors = Priors(n_labels=3, period=np.array([t * 1.01 for t, _ in trains]),
                    phase=np.array([ph for _, ph in trains]), period_std=np.full(3, 0.1), phase_std=np.full(3, 0.4),
                    jitter_std=0.05)
    return toa, priors


def _initiated(toa, priors):
    from baselines.mht import MHT
    from baselines.mht.kernels import rates
    from baselines.mht.start import initiate

    policy = MHT(dense=0)
    policy.reset(priors, {})
    blk = policy.cur.blk[0].copy()
    log_q, log_1mq, _ = rates(policy.settings[0], np.zeros(3, np.int64))
    initiate(toa, toa.size, blk, policy.settings[0], log_q, log_1mq)
    return blk


def test_mht_kernels_label_as_their_python_source(monkeypatch):
    """mht's package, lmht's walk (`_follow`) and the survivor rule: the same labels, joint start and
    training rows interpreted as compiled."""
    from agents.lmht import TorchScorer, candidates

    mods = _modules("baselines.mht.kernels", "baselines.mht.start", "baselines.mht.scorer", "baselines.mht.policy",
                    "baselines.survivor", "agents.lmht")
    want = defined(*mods)
    episodes = [simulate(SMALL if pri is None else SMALL.replace(priors=pri), 5) for _, pri in MHT_PLAYS]
    compiled = [play(make_policy(p), ep).labels for (p, _), ep in zip(MHT_PLAYS, episodes)]
    start = _crowded_start()
    blk = _initiated(*start)
    short = simulate(SMALL.replace(n_pulses=40), 1)
    scorer = TorchScorer(4, 0).numba()
    rows = candidates(short, scorer, 0.5, np.random.default_rng(0), beam=4, start_beam=4, nscan=4, lag=40)

    calls = interpreted(monkeypatch, *mods)
    for (p, _), ep, labels in zip(MHT_PLAYS, episodes, compiled):
        np.testing.assert_array_equal(play(make_policy(p), ep).labels, labels, err_msg=p)
    np.testing.assert_array_equal(_initiated(*start), blk)
    for a, b in zip(candidates(short, scorer, 0.5, np.random.default_rng(0), beam=4, start_beam=4, nscan=4, lag=40),
                    rows):
        np.testing.assert_array_equal(a, b)
    assert not want - set(calls), sorted(want - set(calls))


def test_fdp_kernels_label_as_their_python_source(monkeypatch):
    """fdp's core (tree, look-ahead, commit, the robust start's chains), pulse by pulse and a window in one
    call (`decide_all`, mht's FDP start)."""
    from baselines.fdp import CompiledFDPCore

    mods = _modules("baselines.fdp", "baselines.fdp_start")
    want = defined(*mods)
    spec = ScenarioSpec(name="dense", n_pulses=150, toa_jitter_std=0.1,
                        sources=tuple(SourceSpec(period=Range(10.0, 60.0, log=True)) for _ in range(6)),
                        priors=PriorSpec(period_error=0.01, phase_error=0.05))
    ep = simulate(spec, 7)
    pols = ("fdp", "fdp:tree_gate=4,start=lookahead,start_lag=200", "fdp-ll:missing=true")
    compiled = [play(make_policy(p), ep).labels for p in pols]
    toa = np.ascontiguousarray(ep.toa[:60])

    def window():
        return CompiledFDPCore(ep.priors, "lookahead", False, "phase", math.inf).decide_all(toa, 3)

    whole = window()
    calls = interpreted(monkeypatch, *mods)
    for p, labels in zip(pols, compiled):
        np.testing.assert_array_equal(play(make_policy(p), ep).labels, labels, err_msg=p)
    np.testing.assert_array_equal(window(), whole)
    assert not want - set(calls), sorted(want - set(calls))


AGENT_KERNELS = {"agents.fast_net._dense", "agents.fast_net._track_logits"}  # the `agent` policy's network


def test_beam_kernels_label_as_their_python_source(monkeypatch):
    """The beam decoder's feature, selection and update kernels and its compiled network (dagger-beam)."""
    mods = _modules("agents.beam_kernels", "agents.fast_net", "agents.beam")
    want = defined(*mods) - AGENT_KERNELS
    ep = simulate(SMALL.replace(n_pulses=60), 2)
    compiled = play(make_policy("dagger-beam"), ep).labels
    calls = interpreted(monkeypatch, *mods)
    np.testing.assert_array_equal(play(make_policy("dagger-beam"), ep).labels, compiled)
    assert not want - set(calls), sorted(want - set(calls))


def test_agent_kernels_label_as_their_python_source(monkeypatch):
    """The `agent` policy's compiled networks (the track network: dagger; SB3's MLP: ppo) and the token
    features, played alone and in lock-step."""
    from deint_env.runner import play_batch

    mods = _modules("agents.fast_net", "deint_env.features_kernels")
    want = AGENT_KERNELS | defined(mods[1])
    eps = [simulate(SMALL.replace(n_pulses=40), 3), simulate(SMALL.replace(n_pulses=25, sources=SMALL.sources[:2]), 4)]
    compiled = [play(make_policy("dagger"), eps[0]).labels, play(make_policy("ppo"), eps[1]).labels]
    calls = interpreted(monkeypatch, *mods)
    np.testing.assert_array_equal(play(make_policy("dagger"), eps[0]).labels, compiled[0])
    np.testing.assert_array_equal(play_batch(make_policy("ppo"), eps[1:])[0].labels, compiled[1])
    assert not want - set(calls), sorted(want - set(calls))


# ---- the blind kernels against plain-Python references -------------------------------------------------
def _ref_walk(t, free, seed, pri, pri_unc, sigma, max_miss, memory, slack, curve):
    """The sequence search's walk, as its docstring says: predict the next arrival from a least-squares
    line (a parabola with `curve`, from 6 pulses) through the last `memory` pulses of the train, take the
    nearest free later pulse within the gate 3 sigma + (uncertainty + slack) * steps, stop after
    `max_miss` empty gates in a row or past the end."""
    idx, ks = [seed], [0]
    k = miss = 0
    while True:
        k += 1
        kk = np.array(ks[-memory:], float)
        tt = t[idx[-memory:]]
        if kk.size >= 2:
            deg = 2 if curve and kk.size >= 6 else 1
            coef = np.polyfit(kk - kk.mean(), tt - tt.mean(), deg)
            pred = tt.mean() + np.polyval(coef, k - kk.mean())
            unc = min(pri_unc, 4.0 * sigma / (kk[-1] - kk[0]))
        else:
            pred, unc = t[seed] + pri * k, pri_unc
        gate = 3.0 * sigma + (unc + slack) * (k - ks[-1])
        if pred - gate > t[-1]:
            break
        inside = [j for j in range(t.size) if abs(t[j] - pred) <= gate and free[j] and j != idx[-1]]
        best = max(inside, key=lambda j: (-abs(t[j] - pred), j)) if inside else -1
        if best > idx[-1]:
            idx.append(best)
            ks.append(k)
            miss = 0
        else:
            miss += 1
            if miss > max_miss:
                break
    return np.array(idx), np.array(ks)


def _ref_accept(n, slots, min_pulses, min_fill, chance):
    return n >= min_pulses and n >= max(min_fill, chance + 3.0 * math.sqrt(chance * (1.0 - chance) / slots)) * slots


def _trains(seed: int):
    """Two jittered trains, a few missing, and spurious pulses: the walk's decisions are clear-cut."""
    rng = np.random.default_rng(seed)
    parts = []
    for period in rng.uniform(8.0, 20.0, 2):
        n = int(300 / period)
        tr = rng.uniform(0, period) + period * np.arange(n) + 0.05 * rng.standard_normal(n)
        parts.append(tr[rng.random(n) > 0.1])
    parts.append(rng.uniform(0, 300, 8))
    t = np.sort(np.concatenate(parts))
    return t, rng.random(t.size) > 0.1


@pytest.mark.parametrize("seed", range(4))
def test_walk_equals_a_python_reference(seed):
    from baselines.blind import search

    want = defined(search)
    t, free = _trains(seed)
    rng = np.random.default_rng(seed)
    seeds = np.flatnonzero(free)[:6]
    for curve, memory, slack in ((False, 16, 0.0), (False, 5, 0.3), (True, 8, 0.3)):
        pri = float(rng.uniform(8.0, 20.0))
        for s in seeds:
            idx, ks = search._walk(t, free, s, pri, 0.5, 0.05, 3, memory, slack, curve)
            ri, rk = _ref_walk(t, free, s, pri, 0.5, 0.05, 3, memory, slack, curve)
            np.testing.assert_array_equal(idx, ri)
            np.testing.assert_array_equal(ks, rk)
        best = search._best_walk(t, free, seeds, pri, 0.5, 0.05, 3, memory, slack, curve, 4, 0.6, 0.1)
        walks = [_ref_walk(t, free, s, pri, 0.5, 0.05, 3, memory, slack, curve) for s in seeds]
        ok = [w for w in walks if _ref_accept(w[0].size, w[1][-1] - w[1][0] + 1, 4, 0.6, 0.1)]
        ref = max(ok, key=lambda w: w[0].size) if ok else (np.empty(0, np.int64),) * 2  # the first of the longest
        np.testing.assert_array_equal(best[0], ref[0])
    for n, slots, chance in ((10, 12, 0.0), (10, 12, 0.3), (3, 3, 0.0), (50, 80, 0.2)):
        assert search._accept(n, slots, 6, 0.8, chance) == _ref_accept(n, slots, 6, 0.8, chance)
    assert want == {f"{search.__name__}.{k}" for k in ("_walk", "_best_walk", "_accept")}


def _ref_transform(t, centres, half, pri_min, pri_max, shift):
    """The jitter-robust PRI transform's sums, pair by pair (later pulse j ascending, earlier pulse m from
    j - 1 down), over every bin whose acceptance interval holds the difference, differences within
    [pri_min, pri_max] widened by the widest half-width (so the last bin, centred past pri_max, misses
    the top of its interval): with `shift`, a bin's origin is its first pair's earlier pulse, moved by
    whole bin periods up to each pair's earlier pulse; else 0.  Returns |D_k| and the pair counts."""
    d = np.zeros(centres.size, complex)
    count = np.zeros(centres.size)
    origin = [None] * centres.size
    for j in range(1, t.size):
        for m in range(j - 1, -1, -1):
            tau = t[j] - t[m]
            if not pri_min - half.max() <= tau <= pri_max + half.max():
                continue
            for k in np.flatnonzero(np.abs(tau - centres) <= half):
                o = 0.0
                if shift:
                    if origin[k] is None:
                        origin[k] = t[m]
                    elif t[m] - origin[k] >= centres[k]:
                        origin[k] += centres[k] * math.floor((t[m] - origin[k]) / centres[k])
                    o = origin[k]
                d[k] += np.exp(2j * math.pi * (t[j] - o) / tau)
                count[k] += 1
    return np.abs(d), count


def _ref_transform_nk(t, centres, eps, zeta0):
    """The paper's origin rule: bin k takes a difference within eps tau_k of tau_k; its origin starts at the
    first such pair's later pulse and moves to t_j when t_j is one bin period after it from a pair starting
    there, or nu >= 2 periods within relative error zeta0."""
    d = np.zeros(centres.size, complex)
    count = np.zeros(centres.size)
    origin = [None] * centres.size
    for j in range(1, t.size):
        for m in range(j - 1, -1, -1):
            tau = t[j] - t[m]
            for k in np.flatnonzero(((1 - eps) * centres <= tau) & (tau <= (1 + eps) * centres)):
                if origin[k] is None:
                    origin[k] = t[j]
                eta = (t[j] - origin[k]) / centres[k]
                nu = math.floor(eta + 0.5)
                if (nu == 1 and t[m] == origin[k]) or (nu >= 2 and abs(eta / nu - 1.0) <= zeta0):
                    origin[k] = t[j]
                d[k] += np.exp(2j * math.pi * (t[j] - origin[k]) / centres[k])
                count[k] += 1
    return np.abs(d), count


@pytest.mark.parametrize("seed", range(3))
def test_pri_transforms_equal_python_references(seed):
    from baselines.blind import pri_transform as pt

    want = defined(pt)
    t, _ = _trains(seed)
    t = t[:60]
    for improved in (True, False):
        centres, mag, count, half = pt.pri_transform(t, 5.0, 40.0, 0.5, 0.02, 0.05, improved=improved)
        ref_mag, ref_count = _ref_transform(t, centres, half, 5.0, 40.0, improved)
        np.testing.assert_array_equal(count, ref_count)
        np.testing.assert_allclose(mag, ref_mag, rtol=1e-9, atol=1e-9)
    centres, mag, count, _ = pt.pri_transform_nk(t, 5.0, 40.0, 70, 0.03)
    ref_mag, ref_count = _ref_transform_nk(t, centres, 0.03, 0.03)
    np.testing.assert_array_equal(count, ref_count)
    np.testing.assert_allclose(mag, ref_mag, rtol=1e-9, atol=1e-9)
    assert want == {f"{pt.__name__}._transform", f"{pt.__name__}._transform_nk"}

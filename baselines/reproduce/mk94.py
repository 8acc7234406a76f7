"""MK94's KF and FDP experiments (section V-A, V-B, VI-A): Figs. 3-8 and 12, on the paper-v1 scenarios
(MK94's merging; the others are paper-v0's) and their test seeds.  `fdp` runs with its defaults: the
published accumulation (3.2) and the first pulse predicted at its phase."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from baselines.fdp import FDP
from baselines.genie import Genie
from baselines.reproduce import Report, experiment, figure
from deint_env.envs.deinterleave import DeinterleaveEnv
from deint_env.episode import Episode, Priors
from deint_env.labels import correct_anchored
from deint_env.metrics import per_source_error
from deint_env.runner import play
from deint_env.scenario import ScenarioSpec
from deint_env.simulate import simulate
from deint_env.suites import find_entry

SUITE = "paper-v1"
SWEEP = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0)  # Figs. 4-5, the mk94-two-var* scenarios
PRIOR_VARS = (1.0, 10.0, 100.0)  # Sigma_{1|0} = v I for the Fig. 4/5 sensitivity rows (the paper: I)
MK94_FIG12_PERIODS = (10.01, 29.98)  # the paper's final estimates in VI-A-2 (true: 11, 30)
STARTUP_VARS, STARTUP_SEEDS = (1.5, 2.0), 100  # Fig. 4/5 start-up losses counted on this many train seeds


def _seeds(name: str, quick: bool, n: int = 10) -> list[int]:
    entry = find_entry(f"{SUITE}/{name}")
    return list(entry.test)[: (2 if quick else n)]


def _episode(name: str, seed: int, quick: bool, quick_pulses: int | None = None) -> Episode:
    spec = find_entry(f"{SUITE}/{name}").spec
    if quick and quick_pulses:
        spec = spec.replace(n_pulses=min(spec.n_pulses, quick_pulses))
    return simulate(spec, seed)


def fig4_spec(var: float, prior_var: float = 1.0, n_pulses: int | None = None) -> ScenarioSpec:
    """The Fig. 4/5 scenario of jitter variance `var`, with Sigma_{1|0} = prior_var I."""
    spec = find_entry(f"{SUITE}/mk94-two-var{var:g}").spec
    sd = (math.sqrt(prior_var),)
    spec = spec.replace(priors=dataclasses.replace(spec.priors, period_std=sd, phase_std=sd))
    return spec.replace(n_pulses=min(spec.n_pulses, n_pulses)) if n_pulses else spec


def lost_source(pe: np.ndarray) -> np.ndarray:
    """Per seed of P_e (seed, source): whether a source was lost (P_e > 0.3; the genie's, measured on
    the Fig. 4/5 scenarios, stays below 0.23 per seed and source up to sigma_w^2 = 2)."""
    return np.any(pe > 0.3, axis=-1)


def pe_runs(spec: ScenarioSpec, seeds: list[int], policy: Callable[[], Any]) -> np.ndarray:
    """P_e (MK94 eq. 5.1) per (seed, source) of a fresh `policy()` on each seed's episode."""
    rows = []
    for seed in seeds:
        pol = policy()
        rows.append(play(pol, simulate(spec, seed), oracle=getattr(pol, "oracle", False)).metrics["pe"])
    return np.array(rows, dtype=float)


def startup_failure(labels: np.ndarray, ep: Episode, first: int = 100) -> bool:
    """Whether some source lost the start: most of its pulses among the first `first` mislabelled."""
    head = slice(0, first)
    correct = correct_anchored(labels[head], ep.source[head], ep.mask[head], ep.n_labels)
    return bool(np.nanmax(per_source_error(correct, ep.mask[head])) > 0.5)


def trace_periods(policy: Any, episode: Episode) -> np.ndarray:
    """Play `policy` through the env and record its period estimates after every step."""
    env = DeinterleaveEnv.for_episode(episode, lag=policy.lag, clustering_metrics=False)
    obs, info = env.load_episode(episode)
    policy.reset(Priors.from_info(info["priors"]), info)
    rows = []
    while True:
        obs, _, done, _, _ = env.step(policy.act(obs))
        rows.append(policy.estimates()["period"])
        if done:
            return np.array(rows)


def _evolution_figure(out: Path, name: str, title: str, traces: np.ndarray, truth: np.ndarray) -> str:
    plt = figure()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for i in range(traces.shape[1]):
        ax.plot(traces[:, i], lw=1, label=f"T{i + 1} estimate")
        ax.axhline(truth[i], color="k", lw=0.6, ls=":")
    ax.set_xlabel("pulse instant k")
    ax.set_ylabel("period estimate")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    path = out / f"{name}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def _fmt(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in np.atleast_1d(v)) + ")"


@experiment("mk94-fig3", "MK94 V-A, Fig. 3: KF period estimate of one source, sigma_w = 3 and 100")
def fig3(out: Path, quick: bool) -> Report:
    rep = Report("mk94-fig3", "KF period estimate of a single source (T=11, phi=50), x_1|0=(1,1), Sigma=1e3 I")
    plt = figure()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for name, label, paper in (("mk94-single-var9", "sigma_w=3", "converges in < 30 pulses"),
                               ("mk94-single-var10000", "sigma_w=100", "close after 80 pulses; 11.04 after 100")):
        finals, settle = [], []
        for k, seed in enumerate(_seeds(name, quick)):
            tr = trace_periods(FDP(lookahead=1), _episode(name, seed, quick))[:, 0]
            finals.append(tr[-1])
            outside = np.flatnonzero(np.abs(tr - 11.0) >= 0.5)
            settle.append(0 if outside.size == 0 else outside[-1] + 1)  # within 0.5 of T from here on
            if k == 0:
                ax.plot(tr, lw=1, label=label)
        rep.add(f"{label}: period estimate after 100 pulses (mean over seeds)", f"{np.mean(finals):.2f}", paper)
        rep.add(f"{label}: pulses until within 0.5 of T for good (median)", f"{np.median(settle):.0f}", paper)
    ax.axhline(11.0, color="k", lw=0.6, ls=":")
    ax.set_ylim(0, 25)
    ax.set_xlabel("pulse instant k")
    ax.set_ylabel("period estimate")
    ax.legend()
    ax.set_title("MK94 Fig. 3 (ours): KF period estimate, T=11", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "mk94-fig3.png", dpi=110)
    plt.close(fig)
    rep.files.append("mk94-fig3.png")
    rep.add("note", "TOAs are received sorted", "", "with sigma_w=100 >> T the received order is not the emission "
            "order the paper's model assumes; our episodes are in arrival order (docs/design.md section 3)")
    return rep


def _pe_sweep(sweep, seeds, quick: bool, policy: Callable[[], Any], prior_var: float = 1.0) -> np.ndarray:
    """P_e (variance, seed, source)."""
    return np.array([pe_runs(fig4_spec(var, prior_var, 150 if quick else None), seeds, policy) for var in sweep])


@experiment("mk94-fig4-5", "MK94 V-B-1, Figs. 4-5: P_e of two sources against sigma_w^2 for Delta = 1..5")
def fig4_5(out: Path, quick: bool) -> Report:
    rep = Report("mk94-fig4-5", "FDP error probabilities, T=(11,17), phi=(3,4), x_1|0=(10,22,1,2), Sigma=I")
    sweep = SWEEP[::4] if quick else SWEEP
    deltas = (1, 3) if quick else (1, 2, 3, 4, 5)
    seeds = _seeds("mk94-two-var1", quick)
    genie = _pe_sweep(sweep, seeds, quick, Genie).mean(axis=1)
    seq = _pe_sweep(sweep, seeds, quick, lambda: FDP(lookahead=3, accumulate="sequence")).mean(axis=1)
    plt = figure()
    fig, axes = plt.subplots(2, 3, figsize=(11, 6), sharex=True, sharey=True)
    pe3 = None
    for row, (init, what) in enumerate((("phase", "first pulse predicted at its phase (ours, design section 8)"),
                                        ("mk94", "literal (2.3): first pulse of a source at phi + T"))):
        pe = np.array([_pe_sweep(sweep, seeds, quick, lambda: FDP(lookahead=d, init=init)).mean(axis=1)
                       for d in deltas])
        if init == "phase":
            pe3 = pe[deltas.index(3)]
        for a, delta in enumerate(deltas):
            for col in range(2):
                axes[row, col].plot(sweep, pe[a, :, col], marker="o", ms=3, label=f"Delta={delta}")
            axes[row, 2].plot(sweep, pe[a].mean(axis=1), marker="o", ms=3, label=f"Delta={delta}")
            for b in (0, len(sweep) - 1):
                rep.add(f"init={init} Delta={delta} sigma^2={sweep[b]:g}: (P_e1, P_e2)", _fmt(pe[a, b]),
                        _paper_fig4(delta, sweep[b]))
        for col, t in enumerate(("P_e source 1", "P_e source 2", "mean P_e (Fig. 5)")):
            g = genie[:, col] if col < 2 else genie.mean(axis=1)
            axes[row, col].plot(sweep, g, color="k", ls="--", lw=1, label="genie")
            axes[row, col].set_title(f"{t}\n{what}", fontsize=8)
        axes[row, 0].set_ylabel("error probability")
    for ax in axes[1]:
        ax.set_xlabel("sigma_w^2")
    axes[0, 2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "mk94-fig4-5.png", dpi=110)
    plt.close(fig)
    rep.files.append("mk94-fig4-5.png")
    for b, var in enumerate(sweep):
        rep.add(f"sigma^2={var:g}: (P_e1, P_e2) genie / Delta=3 (3.2) / Delta=3 accumulate=sequence",
                f"{_fmt(genie[b])} / {_fmt(pe3[b])} / {_fmt(seq[b])}", "", "the genie knows the true schedule")
    # Sigma_{1|0} sensitivity of Delta = 3: how often a source is lost at the start, and the gap to the genie
    low = [b for b, var in enumerate(sweep) if var <= 2.0]
    for v in PRIOR_VARS:
        runs = _pe_sweep(sweep, seeds, quick, lambda: FDP(lookahead=3), prior_var=v)  # (var, seed, source)
        gap = np.abs(runs.mean(axis=1) - genie)[low].max()
        lost = ", ".join(f"{int(n)}" for n in np.sum(lost_source(runs), axis=1))
        rep.add(f"Delta=3, Sigma={v:g} I: max |P_e - P_e(genie)| over sigma^2 <= 2", f"{gap:.3f}",
                "no gain beyond Delta=3 ('optimal')" if v == 1 else "",
                f"seeds losing a source (P_e > 0.3) at sigma^2 = {', '.join(f'{x:g}' for x in sweep)}: {lost} "
                f"of {len(seeds)}")
    # ten test seeds are too few for a rate: count the start-ups lost on train seeds
    train_seeds = list(find_entry(f"{SUITE}/mk94-two-var1").train)[: (4 if quick else STARTUP_SEEDS)]
    for v in PRIOR_VARS[:2]:
        lost = [int(lost_source(pe_runs(fig4_spec(var, v), train_seeds, lambda: FDP(lookahead=3))).sum())
                for var in STARTUP_VARS]
        rep.add(f"Delta=3, Sigma={v:g} I: train seeds losing a source at sigma^2 = "
                f"{', '.join(f'{x:g}' for x in STARTUP_VARS)}", ", ".join(f"{n} of {len(train_seeds)}" for n in lost),
                "both tracked" if v == 1 else "", "a start-up failure: the prior T2 = 22 (true 17) lets the "
                "first pulses fit the swapped sources (tests: seed 1000004)")
    rep.add("why the rows differ", "", "", "the paper's Delta=1 failure comes from (2.3)'s initialisation: with "
            "tau_1 = phi a source's first pulse is predicted a period late; predicting it at its phase (docs/design.md "
            "section 8) lets even Delta=1 track both sources at low jitter")
    return rep


def _paper_fig4(delta: int, var: float) -> str:
    if delta == 1:
        return "(~0, ~1): source 2 never tracked"
    if delta == 2:
        return "both tracked" if var < 0.5 else "(~0, ~1): source 2 lost"
    return "both tracked, P_e grows with sigma^2; no gain beyond Delta=3"


def _evolution(exp: str, scen: str, title: str, paper: str, kw: dict[str, Any], quick: bool, out: Path,
               quick_pulses: int) -> Report:
    rep = Report(exp, title)
    truth = find_entry(f"{SUITE}/{scen}").spec
    true_t = np.array([s.period for s in truth.sources])
    finals, accs = [], []
    for k, seed in enumerate(_seeds(scen, quick, 5)):
        ep = _episode(scen, seed, quick, quick_pulses)
        tr = trace_periods(FDP(**kw), ep)
        finals.append(tr[-1])
        accs.append(play(FDP(**kw), ep).metrics["accuracy"])
        if k == 0:
            rep.files.append(_evolution_figure(out, rep.name, f"{title} (ours, seed {seed})", tr, true_t))
    rep.add("true periods", _fmt(true_t), _fmt(true_t))
    rep.add("final period estimates (median over seeds)", _fmt(np.median(finals, axis=0)), paper)
    rep.add("label accuracy (mean)", f"{np.mean(accs):.3f}", "")
    return rep


@experiment("mk94-fig6", "MK94 V-B-2, Fig. 6: FDP period estimates, T=(11,80), sigma_w^2=9")
def fig6(out: Path, quick: bool) -> Report:
    return _evolution("mk94-fig6", "mk94-two-wide", "MK94 Fig. 6: FDP Delta=3, T=(11,80), x_1|0=(60,96,2,1)",
                      "accurate after ~300 pulses", {"lookahead": 3}, quick, out, 200)


@experiment("mk94-fig7", "MK94 V-B-3, Fig. 7: FDP period estimates, T=(11,30,80), sigma_w^2=9")
def fig7(out: Path, quick: bool) -> Report:
    return _evolution("mk94-fig7", "mk94-three", "MK94 Fig. 7: FDP Delta=3, T=(11,30,80), x_1|0=(39,40,90,3,4,2)",
                      "approach the true values after ~300 pulses", {"lookahead": 3}, quick, out, 200)


@experiment("mk94-fig8", "MK94 V-B-4, Fig. 8: FDP tracks eight sources, sigma_w^2=1")
def fig8(out: Path, quick: bool) -> Report:
    return _evolution("mk94-fig8", "mk94-eight", "MK94 Fig. 8: FDP Delta=3, eight sources", "all eight tracked",
                      {"lookahead": 3}, quick, out, 150)


def fig12_runs(suite: str, kw: dict[str, Any], seeds: list[int], quick: bool) -> tuple[np.ndarray, np.ndarray,
                                                                                   np.ndarray]:
    """FDP(**kw) on the Fig. 12 scenario of `suite`: P_e (seed, source), final period estimates (seed,
    source) and start-up failures (seed,)."""
    spec = find_entry(f"{suite}/mk94-missing-two").spec
    if quick:
        spec = spec.replace(n_pulses=150)
    pes, finals, failed = [], [], []
    for seed in seeds:
        ep = simulate(spec, seed)
        res = play(FDP(**kw), ep)
        pes.append(res.metrics["pe"])
        finals.append(res.estimates["period"])
        failed.append(startup_failure(res.labels, ep))
    return np.array(pes, dtype=float), np.array(finals), np.array(failed)


def _near(finals: np.ndarray, target, tol: float = 0.3) -> float:
    """The share of seeds whose every final period is within tol of target."""
    return float(np.mean(np.all(np.abs(finals - np.asarray(target)) <= tol, axis=1)))


@experiment("mk94-fig12", "MK94 VI-A-2, Fig. 12: standard vs modified FDP with merged pulses, T=(11,30)")
def fig12(out: Path, quick: bool) -> Report:
    rep = Report("mk94-fig12", "FDP Delta=3, exactly simultaneous arrivals merged (paper-v1), T=(11,30), "
                 "x_1|0=(4,27,3,4), Sigma=1e6 I")
    variants: dict[str, dict[str, Any]] = {"standard": {}, "modified (VI-A)": {"missing": True},
                                           "coasting (VI-C-3)": {"dropout": True}}
    seeds = _seeds("mk94-missing-two", quick)
    paper = {"standard": "loses source 2 after 12 pulses", "modified (VI-A)": "tracks both; T -> (10.01, 29.98)",
             "coasting (VI-C-3)": "(not in the paper)"}
    startup = {"standard": "fails (1 run shown)", "modified (VI-A)": "succeeds (1 run shown)", "coasting (VI-C-3)": ""}
    plt = figure()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for (label, kw), color in zip(variants.items(), ("C0", "C1", "C2")):
        pes, finals, failed = fig12_runs(SUITE, kw, seeds, quick)
        for k, seed in enumerate(seeds):  # every seed's estimates, one colour per variant
            tr = trace_periods(FDP(**kw), _episode("mk94-missing-two", seed, quick, 150))
            for i, ax in enumerate(axes):
                ax.plot(tr[:, i], lw=0.7, color=color, alpha=0.6, label=label if k == 0 else None)
        rep.add(f"{label}: (P_e1, P_e2)", _fmt(np.mean(pes, axis=0)), paper[label])
        rep.add(f"{label}: final periods (median)", _fmt(np.median(finals, axis=0)), paper[label])
        rep.add(f"{label}: seeds ending within 0.3 of the paper's {_fmt(np.array(MK94_FIG12_PERIODS))}",
                f"{_near(finals, MK94_FIG12_PERIODS):.2f}", "1 run shown",
                f"within 0.3 of the truth (11, 30): {_near(finals, (11.0, 30.0)):.2f}; {len(seeds)} seeds")
        rep.add(f"{label}: start-up failure rate", f"{np.mean(failed):.2f}", startup[label],
                "a source's P_e over the first 100 pulses above 0.5")
    _, finals, failed = fig12_runs("paper-v0", variants["modified (VI-A)"], seeds, quick)
    rep.add("modified (VI-A) on paper-v0 (merging after the jitter): within 0.3 of the paper's / start-up failures",
            f"{_near(finals, MK94_FIG12_PERIODS):.2f} / {np.mean(failed):.2f}", "",
            "paper-v0 merges jittered arrivals closer than 1, not the simultaneous ones")
    for i, ax in enumerate(axes):
        ax.axhline((11.0, 30.0)[i], color="k", lw=0.6, ls=":")
        ax.axhline(MK94_FIG12_PERIODS[i], color="k", lw=0.6, ls="--")
        ax.set_xlabel("pulse instant k")
        ax.set_ylabel(f"period estimate of source {i + 1}")
        ax.set_title(f"MK94 Fig. 12 (ours, {len(seeds)} seeds): T{i + 1}; dotted: true, dashed: the paper's end",
                     fontsize=8)
    axes[0].set_ylim(0, 16)
    axes[1].set_ylim(20, 40)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "mk94-fig12.png", dpi=110)
    plt.close(fig)
    rep.files.append("mk94-fig12.png")
    return rep

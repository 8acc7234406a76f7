"""MK94's probabilistic-teacher experiments (section V-C, VI-B): Figs. 9, 10, 11 and 13, on the paper-v1
scenarios (MK94's merging) and their test seeds (policy seed = episode seed, as the runner plays them).

What to expect from PT with a-priori probabilities.  Its source choice ignores the data, so source i
is handed each pulse with probability pi_i and its KF fits a line through a *binomially thinned*
pulse stream: the period estimate is the mean interval of that stream, which is T_i when pi is right,
with the error of a least-squares slope through a random walk whose steps have mean T_i and variance
T_i^2 (1 - pi_i): relative rms ~ sqrt(1.2 (1 - pi_i) / (K pi_i)) after K pulses.  The tables print
this prediction beside the measurement.  Missing or merged pulses thin the stream further, so the
estimate becomes T_i / (1 - f) for a fraction f of lost pulses.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from baselines.pt import PTPost, PTPrior
from baselines.reproduce import Report, experiment, figure
from baselines.reproduce.mk94 import SUITE, trace_periods
from deint_env.episode import Episode
from deint_env.runner import play
from deint_env.simulate import simulate
from deint_env.suites import find_entry


def _runs(scen: str, policy, quick: bool, quick_pulses: int, n_seeds: int = 10):
    """(episodes, period traces (seeds, K, N), label accuracies) over the scenario's test seeds."""
    entry = find_entry(f"{SUITE}/{scen}")
    spec = entry.spec.replace(n_pulses=quick_pulses) if quick else entry.spec
    eps, traces, accs = [], [], []
    for seed in list(entry.test)[: 2 if quick else n_seeds]:
        ep = simulate(spec, seed)
        eps.append(ep)
        traces.append(trace_periods(policy(seed=seed), ep))
        accs.append(play(policy(seed=seed), ep, policy_seed=seed).metrics["accuracy"])
    return eps, np.array(traces), np.array(accs)


def _fmt(v, digits: int = 2) -> str:
    return "(" + ", ".join(f"{x:.{digits}f}" for x in np.atleast_1d(v)) + ")"


def _pct(v) -> str:
    return "(" + ", ".join(f"{100 * x:.1f}%" for x in np.atleast_1d(v)) + ")"


def predicted_rms(pi: np.ndarray, k: int | np.ndarray) -> np.ndarray:
    """PT-prior's relative rms period error after k pulses (module doc)."""
    return np.sqrt(1.2 * (1.0 - pi) / (np.multiply.outer(k, pi)))


def _prior_figure(out: Path, name: str, title: str, traces: np.ndarray, truth: np.ndarray, pi: np.ndarray,
                  seed: int) -> str:
    plt = figure()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    for i in range(traces.shape[2]):
        line, = ax.plot(traces[0, :, i], lw=1, label=f"T{i + 1} = {truth[i]:g}")
        ax.axhline(truth[i], color=line.get_color(), lw=0.6, ls=":")
        rms = np.sqrt(np.mean((traces[:, :, i] / truth[i] - 1.0) ** 2, axis=0))
        k = np.arange(1, rms.size + 1)
        bx.loglog(k, rms, color=line.get_color(), lw=1, label=f"T{i + 1} measured")
        bx.loglog(k, predicted_rms(pi[i], k), color=line.get_color(), lw=0.8, ls="--")
    ax.set_xlabel("pulse instant k")
    ax.set_ylabel("period estimate")
    ax.set_title(f"{title} (ours, seed {seed})", fontsize=8)
    ax.legend(fontsize=7)
    bx.axhline(0.01, color="k", lw=0.6, ls=":")
    bx.set_ylim(1e-3, 10)
    bx.set_xlabel("pulse instant k")
    bx.set_ylabel("relative rms period error over seeds")
    bx.set_title(f"rms over {traces.shape[0]} seeds; dashed: sqrt(1.2 (1 - pi) / (k pi)); dotted: 1 %", fontsize=8)
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=110)
    plt.close(fig)
    return f"{name}.png"


def _pt_prior(name: str, scen: str, title: str, at: int, paper: str, quick: bool, out: Path) -> Report:
    rep = Report(name, title)
    eps, traces, accs = _runs(scen, PTPrior, quick, 600)
    at = min(at, traces.shape[1])
    truth, pi = eps[0].truth.period, eps[0].priors.source_prob
    rel = traces[:, at - 1] / truth - 1.0
    rep.files.append(_prior_figure(out, name, title, traces, truth, pi, eps[0].seed))
    rep.add("true periods", _fmt(truth, 0), _fmt(truth, 0))
    rep.add("a-priori probabilities pi_i", _fmt(pi, 3), "pi_i = T_i / sum T",
            "the pulse rates, pi_i proportional to 1/T_i: the paper's T_i / sum T (a typo) would hand the slowest "
            "source the most pulses")
    rep.add(f"period estimates after {at} pulses, mean over {len(eps)} seeds", _fmt(traces[:, at - 1].mean(0)), paper)
    rep.add(f"relative rms period error after {at} pulses", _pct(np.sqrt(np.mean(rel ** 2, axis=0))), "",
            f"predicted {_pct(predicted_rms(pi, at))} (module doc)")
    rep.add("seeds with every period within 1 %", f"{np.mean(np.all(np.abs(rel) < 0.01, axis=1)):.2f}", "",
            f"per source {_fmt(np.mean(np.abs(rel) < 0.01, axis=0))}")
    rep.add("pulses for a 1 % rms error (predicted)", _fmt(np.ceil(1.2 * (1 - pi) / pi / 1e-4), 0), "",
            "the a-priori teacher learns from assignment counts only")
    rep.add("label accuracy (mean)", f"{accs.mean():.3f}", "", f"sampled labels: sum pi_i^2 = {np.sum(pi ** 2):.3f}")
    return rep


@experiment("mk94-fig9", "MK94 V-C-2, Fig. 9: PT with known a-priori probabilities, T=(11,30,80), sigma_w^2=36")
def fig9(out: Path, quick: bool) -> Report:
    return _pt_prior("mk94-fig9", "mk94-pt-three", "MK94 Fig. 9: PT-prior, T=(11,30,80), x_1|0=1, Sigma=I", 3000,
                     "close to the true values after 3000 pulses", quick, out)


@experiment("mk94-fig10", "MK94 V-C-3, Fig. 10: PT with known a-priori probabilities, five sources, sigma_w^2=64")
def fig10(out: Path, quick: bool) -> Report:
    return _pt_prior("mk94-fig10", "mk94-pt-five", "MK94 Fig. 10: PT-prior, T=(11,19,39,83,120), x_1|0=1, Sigma=I",
                     5000, "converge; larger periods converge slowly", quick, out)


def classify(estimate: float, truth: np.ndarray, tol: float = 0.02) -> str:
    """'true' (within tol of a true period), 'xM' (of M times one, M >= 2) or 'other'."""
    ratio = estimate / truth
    if np.any(np.abs(ratio - 1.0) < tol):
        return "true"
    m = np.round(ratio)
    hit = (m >= 2) & (np.abs(ratio / np.maximum(m, 1) - 1.0) < tol)
    if hit.any():
        i = int(np.flatnonzero(hit)[0])
        return f"x{int(m[i])} of {truth[i]:g}"
    return "other"


@experiment("mk94-fig11", "MK94 V-C-4, Fig. 11: PT with a-posteriori probabilities, N=4 assumed for 3 sources")
def fig11(out: Path, quick: bool) -> Report:
    rep = Report("mk94-fig11", "PT-post, T=(11,30,80), sigma_w^2=1, N=4 assumed, x_1|0=1, Sigma=1e6 I, pi=1/4")
    eps, traces, accs = _runs("mk94-pt-post", PTPost, quick, 500)
    truth = eps[0].truth.period
    kinds = [[classify(t, truth) for t in tr[-1]] for tr in traces]
    counts = Counter(k for row in kinds for k in row)
    found = [len({int(np.argmin(np.abs(t / truth - 1))) for t, k in zip(tr[-1], row) if k == "true"})
             for tr, row in zip(traces, kinds)]
    plt = figure()
    n_show = min(4, len(eps))
    fig, axes = plt.subplots(1, n_show, figsize=(3.3 * n_show, 3.6), squeeze=False)
    for ax, tr, ep, row in zip(axes[0], traces, eps, kinds):
        for i in range(tr.shape[1]):
            ax.plot(tr[:, i], lw=1, label=f"track {i + 1}: {row[i]}")
        for t in (*truth, 2 * truth[0]):
            ax.axhline(t, color="k", lw=0.5, ls=":" if t in truth else "--")
        ax.set_yscale("log")
        ax.set_ylim(0.5, 500)
        ax.set_xlabel("pulse instant k")
        ax.set_title(f"seed {ep.seed}", fontsize=8)
        ax.legend(fontsize=6)
    axes[0, 0].set_ylabel("period estimate (dotted: 11, 30, 80; dashed: 22)")
    fig.suptitle("MK94 Fig. 11 (ours): PT with a-posteriori probabilities, N=4 for three sources", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "mk94-fig11.png", dpi=110)
    plt.close(fig)
    rep.files.append("mk94-fig11.png")
    rep.add("final estimates, first seed", _fmt(traces[0, -1]), "two at 22 (= 2 x 11), two at true values")
    rep.add(f"tracks by final estimate ({len(eps)} seeds x 4 tracks)",
            ", ".join(f"{k}: {v}" for k, v in counts.most_common()), "2 true, 2 at x2 of 11",
            "true/multiple: within 2 %")
    rep.add("true sources found per seed (0-3)", " ".join(map(str, found)), "2",
            f"seeds finding all three: {sum(f == 3 for f in found)}")
    rep.add("label accuracy (mean)", f"{accs.mean():.3f}", "", "label 4 (a phantom track) is always wrong")
    return rep


def lost_fraction(ep: Episode) -> float:
    """The fraction of the pulses emitted up to the last arrival that never arrive on their own."""
    return 1.0 - len(ep) / np.count_nonzero(ep.truth.schedule_toa <= ep.toa[-1])


@experiment("mk94-fig13", "MK94 VI-B, Fig. 13: PT with known a-priori probabilities and merged pulses")
def fig13(out: Path, quick: bool) -> Report:
    rep = Report("mk94-fig13", "PT-prior, T=(11,30,80), sigma_w^2=36, simultaneous arrivals merged, x_1|0=1, "
                 "Sigma=1e6 I")
    eps, traces, accs = _runs("mk94-pt-missing-three", PTPrior, quick, 600)
    truth, pi = eps[0].truth.period, eps[0].priors.source_prob
    f = np.array([lost_fraction(ep) for ep in eps])
    k = traces.shape[1]
    final = traces[:, -1]
    rep.files.append(_prior_figure(out, "mk94-fig13", "MK94 Fig. 13: PT-prior with merged pulses", traces, truth, pi,
                                   eps[0].seed))
    rep.add("true periods", _fmt(truth, 0), _fmt(truth, 0))
    rep.add(f"period estimates after {k} pulses, mean over {len(eps)} seeds", _fmt(final.mean(0)),
            "extremely robust to missing pulses")
    rep.add("relative bias of the estimates", _pct(np.mean(final / truth - 1, axis=0)), "",
            f"predicted 1/(1-f) - 1 = {100 * np.mean(1 / (1 - f) - 1):.1f}% for f lost")
    rep.add("fraction f of emitted pulses lost to merging (mean)", f"{100 * f.mean():.1f}%", "",
            "paper-v1: exactly simultaneous noise-free arrivals merge, as in MK94")
    rep.add("label accuracy (mean)", f"{accs.mean():.3f}", "")
    return rep

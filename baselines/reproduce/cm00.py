"""CM00's experiments (Conroy & Moore 2000, section IV) on the paper-v0 scenarios (times in ms, PRFs
in kHz): Tables I-II / Fig. 5, Fig. 6 / Table III, and the failure case of Tables IV-V with LP's
coupled EKFs beside the bank.

As in the paper: sampling at 100 kHz (Ts = 0.01 ms), PRF priors 10 % low, phases unknown, R = 10 (20
at 51 and 72 % jitter), Q = 0, 2000 pulses.  Errors as the paper's tables: PRF error |f_hat - f| / f
in %, phase error |theta_hat - theta| (circular) in % of 2 pi, with theta = 2 pi (first arrival mod T)
/ T.  Our runs vary the bank's random phase initialisations (policy seeds) and, for the random sets
and jittered trains, the episode (test seeds).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from baselines.coupled import EKFCoupled
from baselines.ekf import EKFBank, SampledBank
from baselines.reproduce import Report, experiment, figure
from deint_env.episode import Episode
from deint_env.runner import accuracy_of
from deint_env.simulate import simulate
from deint_env.suites import find_entry

PAPER_TS = 0.01  # 100 kHz, in ms
JITTER = (0, 23, 32, 51, 72)  # % of the smallest PRI (0.138 ms)
SUCCESS_PHASE = 10.0  # CM00 IV-B: "successfully estimated if the average phase error is within 10 %"
RIGHT_PRF = 0.1  # % : a filter has every train right (the failure of Table IV is at 6 %, successes at ~0.01 %)
# Tables I-II: per train (actual PRF kHz, est. PRF kHz, error %, actual phase rad, est. phase rad, error %)
TABLE_1_2 = ((1.3238, 1.3237, 4.8e-3, 4.50, 4.46, 0.6), (1.7364, 1.7363, 6.3e-3, 5.31, 5.25, 1.0),
             (2.0830, 2.0828, 5.8e-3, 4.90, 4.82, 1.3), (2.7595, 2.7595, 1.5e-3, 2.04, 1.98, 1.0),
             (7.2244, 7.2245, 2.5e-3, 2.33, 2.41, 1.4))
# Table III: noise % -> (trains, average PRF error %, average phase error %)
TABLE_3 = {0: (7, 12.7e-3, 2.1), 23: (6, 20.1e-3, 4.0), 32: (4, 37.3e-3, 8.2), 51: (2, 7.7e-3, 7.6),
           72: (0, None, None)}
# Tables IV-V (the failure): per train (actual PRF, est. PRF, error %, actual phase, est. phase, error %)
TABLE_4_5 = ((1.1268, 1.1990, 6.41, 0.21, 1.44, 19.5), (1.2715, 1.1992, 5.69, 5.92, 4.64, 20.3),
             (3.9194, 3.9199, 2.6e-3, 6.10, 6.23, 2.1), (5.0299, 5.0300, 1.4e-3, 0.61, 0.73, 1.9))


# ---------------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------------
def _episode(name: str, seed: int, pulses: int | None = None) -> Episode:
    spec = find_entry(f"paper-v0/{name}").spec
    if pulses is not None:
        spec = spec.replace(n_pulses=min(spec.n_pulses, pulses))
    return simulate(spec, seed)


def _r(pct: int) -> float:
    return 20.0 if pct >= 51 else 10.0  # CM00 IV-B


def run(policy: SampledBank, episode: Episode, policy_seed: int, every: int = 0) -> dict[str, Any]:
    """Feed the episode's pulses to `policy` (online, as the env does); record estimates every
    `every` pulses.  Returns labels, trace [(pulse, period, phase)], seconds and the policy."""
    policy.reset(episode.priors, {"policy_seed": policy_seed})
    labels = np.empty(len(episode), dtype=np.int64)
    trace = []
    t0 = time.perf_counter()
    for j, t in enumerate(episode.toa):
        labels[j] = policy.act({"toa": episode.toa[j:j + 1], "valid": 1})
        if every and (j % every == 0 or j == len(episode) - 1):
            est = policy.estimates()
            trace.append((j + 1, est["period"], est["phase"]))
    return {"labels": labels, "trace": trace, "seconds": time.perf_counter() - t0, "policy": policy}


def theta(phase: np.ndarray, period: np.ndarray) -> np.ndarray:
    """CM00's phase in [0, 2 pi) of a train whose first arrival is `phase` (time origin 0)."""
    return 2 * math.pi * np.mod(phase, period) / period


def paper_errors(period_hat: np.ndarray, phase_hat: np.ndarray, episode: Episode) -> tuple[np.ndarray, np.ndarray]:
    """(PRF error %, phase error % of 2 pi) per train, as CM00's tables."""
    tr = episode.truth
    prf = 100 * np.abs(tr.period / period_hat - 1)
    d = (theta(phase_hat, period_hat) - theta(tr.phase, tr.period)) / (2 * math.pi)
    return prf, 100 * np.abs(d - np.round(d))


def member_errors(policy: SampledBank, episode: Episode) -> tuple[np.ndarray, np.ndarray]:
    """paper_errors of every bank member: (K, M) arrays."""
    per = policy.Ts / policy.f
    ph = policy._t0 + np.mod(policy.u, 1.0) * per
    tr = episode.truth
    prf = 100 * np.abs(tr.period / per - 1)
    d = (theta(ph, per) - theta(tr.phase, tr.period)) / (2 * math.pi)
    return prf, 100 * np.abs(d - np.round(d))


def _save(fig: Any, out: Path, name: str, plt: Any) -> str:
    path = out / f"{name}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def _evolution(ax_f: Any, ax_p: Any, trace: list, episode: Episode, trains: range | list) -> None:
    """CM00 Fig. 5 panels: PRF (kHz) and phase (rad) estimates against the pulse count."""
    n = np.array([r[0] for r in trace])
    per = np.array([r[1] for r in trace])
    ph = np.array([r[2] for r in trace])
    tr = episode.truth
    for i in trains:
        line = ax_f.plot(n, 1 / per[:, i], lw=1, label=f"train {i + 1}")[0]
        ax_f.axhline(1 / tr.period[i], color=line.get_color(), lw=0.6, ls=":")
        ax_p.plot(n, theta(ph[:, i], per[:, i]), lw=1, color=line.get_color())
        ax_p.axhline(theta(tr.phase[i], tr.period[i]), color=line.get_color(), lw=0.6, ls=":")
    ax_f.set_ylabel("PRF estimate (kHz)")
    ax_p.set_ylabel("phase estimate (rad)")
    ax_p.set_xlabel("pulses processed")
    ax_f.legend(fontsize=7, ncol=3)


# ---------------------------------------------------------------------------------------------------
# Tables I-II / Fig. 5: five trains, no noise
# ---------------------------------------------------------------------------------------------------
@experiment("cm00-tables-1-2", "CM00 IV, Tables I-II / Fig. 5: ekf-bank on five noise-free trains from 10 % PRF error")
def tables_1_2(out: Path, quick: bool) -> Report:
    rep = Report("cm00-tables-1-2", "ekf-bank (K=16, 100 kHz, R=10) on the five trains of Table I, phases unknown, "
                 "PRFs 10 % low")
    pulses = 500 if quick else None
    seeds = range(2 if quick else 10)
    ep = _episode("cm00-five-jitter0", 1_000_000, pulses)
    runs = [run(EKFBank(ts=PAPER_TS, r=10.0), ep, s, every=10 if s == 0 else 0) for s in seeds]
    errs = []
    for r in runs:
        est = r["policy"].estimates()
        errs.append(paper_errors(est["period"], est["phase"], ep) + (est,))
    prf0, ph0, est0 = errs[0]
    for i, row in enumerate(TABLE_1_2):
        rep.add(f"train {i + 1} PRF kHz (error %)", f"{1 / est0['period'][i]:.4f} ({prf0[i]:.1e})",
                f"{row[1]:.4f} ({row[2]:.1e})", f"actual {row[0]:.4f}; our policy seed 0")
    for i, row in enumerate(TABLE_1_2):
        rep.add(f"train {i + 1} phase rad (error %)", f"{theta(est0['phase'], est0['period'])[i]:.2f} ({ph0[i]:.1f})",
                f"{row[4]:.2f} ({row[5]:.1f})", f"actual {row[3]:.2f}")
    prf = np.array([e[0] for e in errs])
    ph = np.array([e[1] for e in errs])
    ok = ph.mean(axis=1) < SUCCESS_PHASE
    rep.add("runs with average phase error < 10 %", f"{ok.sum()}/{len(ok)}", "", "bank phase seeds")
    if ok.any():
        rep.add("mean PRF error % (successful runs)", f"{prf[ok].mean():.1e}",
                f"{np.mean([r[2] for r in TABLE_1_2]):.1e}")
        rep.add("max PRF error % (successful runs)", f"{prf[ok].max():.1e}", f"{max(r[2] for r in TABLE_1_2):.1e}",
                "acceptance: < 0.05 %")
        rep.add("mean phase error % (successful runs)", f"{ph[ok].mean():.2f}",
                f"{np.mean([r[5] for r in TABLE_1_2]):.2f}")
        rep.add("max phase error % (successful runs)", f"{ph[ok].max():.2f}", f"{max(r[5] for r in TABLE_1_2):.1f}")
    acc = [accuracy_of(r["labels"], ep) for r in runs]
    rep.add("label accuracy (online, all pulses)", f"{np.mean(acc):.3f}", "-", "CM00 does not label")
    rep.add("pulses / s (policy time)", f"{len(ep) * len(runs) / sum(r['seconds'] for r in runs):.0f}", "-",
            f"{len(ep)} pulses, {runs[0]['policy']._k} samples")
    plt = figure()
    fig, (ax_f, ax_p) = plt.subplots(2, 1, figsize=(6.5, 6), sharex=True)
    _evolution(ax_f, ax_p, runs[0]["trace"], ep, range(5))
    ax_f.set_title("CM00 Fig. 5: ekf-bank on five noise-free trains (dotted: truth)", fontsize=9)
    rep.files.append(_save(fig, out, "cm00-fig5", plt))
    return rep


# ---------------------------------------------------------------------------------------------------
# Fig. 6 / Table III: degradation with jitter
# ---------------------------------------------------------------------------------------------------
@experiment("cm00-fig6-table3", "CM00 IV-B, Fig. 6 / Table III: trains estimated successfully vs TOA jitter")
def fig6_table3(out: Path, quick: bool) -> Report:
    rep = Report("cm00-fig6-table3", "ekf-bank on 2-7 trains with random PRFs (1-8 kHz) under TOA jitter of 0-72 % "
                 "of 0.138 ms; success = average phase error < 10 %")
    levels = (0, 51) if quick else JITTER
    sizes = (2, 3) if quick else tuple(range(2, 8))
    n_seeds = 1 if quick else 10
    pulses = 300 if quick else None
    cell: dict[tuple[int, int], dict[str, Any]] = {}
    for pct in levels:
        for m in sizes:
            name = f"cm00-random{m}-jitter{pct}"
            seeds = list(find_entry(f"paper-v0/{name}").test)[:n_seeds]
            res = []
            for s in seeds:
                ep = _episode(name, s, pulses)
                r = run(EKFBank(ts=PAPER_TS, r=_r(pct)), ep, s)
                est = r["policy"].estimates()
                prf, ph = paper_errors(est["period"], est["phase"], ep)
                res.append((prf.mean(), ph.mean(), prf.max()))
            a = np.array(res)
            ok = a[:, 1] < SUCCESS_PHASE
            cell[pct, m] = {"rate": ok.mean(), "tight": int(np.sum(ok & (a[:, 2] < RIGHT_PRF))), "n_ok": int(ok.sum()),
                            "prf": a[ok, 0].mean() if ok.any() else math.nan,
                            "prf_median": np.median(a[ok, 0]) if ok.any() else math.nan,
                            "phase": a[ok, 1].mean() if ok.any() else math.nan}
    for pct in levels:
        good = [m for m in sizes if cell[pct, m]["rate"] >= 0.5]
        best = max(good) if good else 0
        paper = TABLE_3[pct]
        c = cell.get((pct, best))
        ours = f"{best} trains" + (f", PRF {c['prf']:.1e} % (median {c['prf_median']:.1e}), phase {c['phase']:.1f} %"
                                   if best else "")
        ref = f"{paper[0]} trains" + (f", PRF {paper[1]:.1e} %, phase {paper[2]:.1f} %" if paper[0] else "")
        if pct == 0:
            ref += " (text: 8 of 10 sets, 13.8e-3 %, 2.0 %)"
        rates = ", ".join(f"{m}:{cell[pct, m]['rate']:.1f}" for m in sizes)
        tight = f"; {c['tight']} of its {c['n_ok']} successes have every PRF error < {RIGHT_PRF} %" if best else ""
        rep.add(f"jitter {pct} %: most trains with >= half the sets successful; errors of those", ours, ref,
                f"success rate by trains {rates} ({n_seeds} sets each){tight}")
    five = [(pct, _five_train_errors(pct, pulses, 1 if quick else 5)) for pct in levels]
    for pct, (prf, ph, rate) in five:
        rep.add(f"five trains of Table I, jitter {pct} %: PRF / phase error %", f"{prf:.1e} / {ph:.1f}",
                "Fig. 7: plot only" if pct == 23 else "-", f"average phase error < 10 % in {rate}")
    plt = figure()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for pct in levels:
        ax1.plot(sizes, [cell[pct, m]["rate"] for m in sizes], marker="o", lw=1, label=f"jitter {pct} %")
    ax1.set_xlabel("number of trains")
    ax1.set_ylabel("fraction of sets with average phase error < 10 %")
    ax1.legend(fontsize=7)
    ax1.set_title("ekf-bank: success vs number of trains", fontsize=9)
    ours = [max([m for m in sizes if cell[pct, m]["rate"] >= 0.5], default=0) for pct in levels]
    ax2.plot(levels, ours, marker="o", label="ours (>= half the sets)")
    ax2.plot(list(TABLE_3), [v[0] for v in TABLE_3.values()], marker="s", ls="--", label="CM00 Table III")
    ax2.set_xlabel("TOA jitter, % of 0.138 ms")
    ax2.set_ylabel("trains estimated successfully")
    ax2.legend(fontsize=7)
    ax2.set_title("CM00 Fig. 6: degradation with jitter", fontsize=9)
    rep.files.append(_save(fig, out, "cm00-fig6", plt))
    return rep


def _five_train_errors(pct: int, pulses: int | None, n_seeds: int) -> tuple[float, float, str]:
    """Mean PRF / phase error of the five-train set at a jitter level over episode (and bank) seeds."""
    name = f"cm00-five-jitter{pct}"
    rows = []
    for s in list(find_entry(f"paper-v0/{name}").test)[:n_seeds]:
        ep = _episode(name, s, pulses)
        est = run(EKFBank(ts=PAPER_TS, r=_r(pct)), ep, s)["policy"].estimates()
        prf, ph = paper_errors(est["period"], est["phase"], ep)
        rows.append((prf.mean(), ph.mean()))
    a = np.array(rows)
    return float(a[:, 0].mean()), float(a[:, 1].mean()), f"{int((a[:, 1] < SUCCESS_PHASE).sum())}/{len(a)} runs"


# ---------------------------------------------------------------------------------------------------
# Tables IV-V: two trains of near-equal PRF and phase
# ---------------------------------------------------------------------------------------------------
VARIANTS = (
    ("ekf-bank", lambda: EKFBank(ts=PAPER_TS, r=10.0)),
    ("ekf-coupled (LP (12), mu=1, asym=0.2, c0=0)", lambda: EKFCoupled(ts=PAPER_TS, r=10.0)),
    ("coupled, c fixed at 0 (others' sawtooth left in)", lambda: EKFCoupled(ts=PAPER_TS, r=10.0, mu=0.0, c0=0.0)),
    ("coupled, c fixed at 1 (joint innovation, block P)", lambda: EKFCoupled(ts=PAPER_TS, r=10.0, mu=0.0, c0=1.0)),
    ("ekf-bank with K=64", lambda: EKFBank(n_filters=64, ts=PAPER_TS, r=10.0)),
)


@experiment("cm00-tables-4-5", "CM00 IV-C, Tables IV-V: the near-equal failure case, ekf-bank vs ekf-coupled")
def tables_4_5(out: Path, quick: bool) -> Report:
    rep = Report("cm00-tables-4-5", "trains 1-2 of near-equal PRF and phase (Table IV): ekf-bank vs LP-coupled EKFs "
                 "(banks of K=16 unless stated)")
    pulses = 500 if quick else None
    seeds = list(range(2 if quick else 10))
    variants = VARIANTS[:2] if quick else VARIANTS
    ep = _episode("cm00-near-equal", 1_000_000, pulses)
    traces, fail_run = {}, None
    for vi, (label, make) in enumerate(variants):
        all_ok, pair_ok, member_ok, acc, e12, p12 = [], [], [], [], [], []
        for s in seeds:
            r = run(make(), ep, s, every=10)
            pol = r["policy"]
            mprf, mph = member_errors(pol, ep)
            right = (mprf < RIGHT_PRF) & (mph < SUCCESS_PHASE)  # (K, 4): member, train
            b = pol.best
            all_ok.append(right[b].all())
            pair_ok.append(right[b, :2].all())
            member_ok.append(right.all(axis=1).mean())
            acc.append(accuracy_of(r["labels"], ep))
            e12.append(mprf[b, :2].mean())
            p12.append(mph[b, :2].mean())
            if s == seeds[0]:
                traces[label] = r["trace"]
            if vi == 0 and not pair_ok[-1] and fail_run is None:
                fail_run = r
        n = len(all_ok)
        rep.add(f"{label}: chosen filter has trains 1-2 right (PRF < 0.1 %, phase < 10 %)",
                f"{np.sum(pair_ok)}/{n}", "0/1" if vi == 0 else "-",
                f"all four right: {np.sum(all_ok)}/{n}; bank members with all four right: "
                f"{100 * np.mean(member_ok):.1f} %")
        rep.add(f"{label}: trains 1-2 PRF / phase error % (median)", f"{np.median(e12):.2g} / {np.median(p12):.1f}",
                "6.05 / 19.9" if vi == 0 else "-", f"label accuracy {np.mean(acc):.3f}")
    if fail_run is not None:
        fail = fail_run["policy"].estimates()
        prf, ph = paper_errors(fail["period"], fail["phase"], ep)
        for i, row in enumerate(TABLE_4_5):
            rep.add(f"an ekf-bank run failing on trains 1-2: train {i + 1} PRF kHz (error %) / phase rad (error %)",
                    f"{1 / fail['period'][i]:.4f} ({prf[i]:.2g}) / {theta(fail['phase'], fail['period'])[i]:.2f} "
                    f"({ph[i]:.1f})", f"{row[1]:.4f} ({row[2]:.2g}) / {row[4]:.2f} ({row[5]:.1f})",
                    f"actual {row[0]:.4f} / {row[3]:.2f}")
    plt = figure()
    panels = [(label, traces[label]) for label, _ in variants[:2]]
    if fail_run is not None:
        panels.append(("ekf-bank, a run failing on trains 1-2", fail_run["trace"]))
    fig, axes = plt.subplots(2, len(panels), figsize=(4.2 * len(panels), 6), sharex=True, squeeze=False)
    for col, (label, trace) in enumerate(panels):
        _evolution(axes[0, col], axes[1, col], trace, ep, [0, 1])
        axes[0, col].set_title(label[:40], fontsize=8)
    rep.files.append(_save(fig, out, "cm00-tables-4-5", plt))
    return rep

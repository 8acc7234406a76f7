"""DM89's simulation (section 4, Fig. 1): the detection-oriented Kalman filter on a Bernoulli-Gaussian
spike train (lambda = 0.1, sigma_r = 0.25, N = 150) through the fourth-order ARMA V(z) with white
noise sigma_n = 0.03; the paper shows one realisation with five missed detections and one false alarm.
DM89 has no suite entry: run r uses np.random.default_rng(r), r = 0..99, drawing q, then r, then n.

A second table part runs the waveform front end (`detect_pulses`) on a paper pulse train.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from deint_env.receiver import DM89_CHANNEL, detect_pulses, match_detections, realize, run_dokf
from baselines.reproduce import Report, experiment, figure
from deint_env.simulate import simulate
from deint_env.suites import find_entry

LAM, SIGMA_R, N_SAMPLES, SIGMA_N = 0.1, 0.25, 150, 0.03


def bernoulli_gaussian_runs(seeds, n: int = N_SAMPLES, lam: float = LAM, sigma_r: float = SIGMA_R,
                            sigma_n: float = SIGMA_N) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """DM89 (1)-(3) for each seed: spikes q (bool), mu = q r and observations z, each (runs, n)."""
    q, mu, z = [], [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        qs = rng.random(n) < lam
        ms = qs * (sigma_r * rng.standard_normal(n))
        q.append(qs)
        mu.append(ms)
        z.append(lfilter(*DM89_CHANNEL, ms) + sigma_n * rng.standard_normal(n))
    return np.array(q), np.array(mu), np.array(z)


def _ms(x: np.ndarray) -> str:
    return f"{np.mean(x):.2f} +- {np.std(x):.2f}"


@experiment("dm89", "DM89 section 4, Fig. 1: DOKF detection of a Bernoulli-Gaussian spike train through V(z)")
def dm89(out: Path, quick: bool) -> Report:
    rep = Report("dm89", "DOKF on lambda=0.1, sigma_r=0.25, N=150 spikes through DM89's V(z), sigma_n=0.03")
    seeds = range(10 if quick else 100)
    q, mu, z = bernoulli_gaussian_runs(seeds)
    q_hat, mu_hat = run_dokf(z, realize(*DM89_CHANNEL), LAM, SIGMA_R, SIGMA_N)
    miss = np.sum(q & ~q_hat, axis=1)
    false = np.sum(~q & q_hat, axis=1)
    rep.add(f"spikes per run (mean over {len(seeds)} runs)", f"{q.sum(axis=1).mean():.1f}", "",
            f"expected lambda N = {LAM * N_SAMPLES:g}")
    rep.add("missed detections per run (mean +- sd)", _ms(miss), "5", "one realisation in the paper")
    rep.add("false alarms per run (mean +- sd)", _ms(false), "1", "one realisation in the paper")
    rep.add("runs with <= 5 misses and <= 1 false alarm", f"{np.mean((miss <= 5) & (false <= 1)):.2f}", "")
    near = [match_detections(np.flatnonzero(qh), np.flatnonzero(qq), 1) for qh, qq in zip(q_hat, q)]
    rep.add("false alarms per run when +-1 sample counts as a hit", _ms([np.sum(m < 0) for m in near]), "")
    hit = q & q_hat
    rep.add("|r| of missed vs detected spikes (median)",
            f"{np.median(np.abs(mu[q & ~q_hat])):.3f} vs {np.median(np.abs(mu[hit])):.3f}", "",
            "the misses are the small spikes")
    rep.add("amplitude estimate (25)-(26): rms error / sigma_r on hits",
            f"{np.sqrt(np.mean((mu_hat[hit] - mu[hit]) ** 2)) / SIGMA_R:.3f}", "")

    plt = figure()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    k = np.arange(N_SAMPLES)
    ax.plot(k[q[0]], mu[0][q[0]], "o", mfc="none", color="k", label="true spikes")
    ax.vlines(k, 0, mu_hat[0], color="tab:red", lw=2, label="DOKF estimates")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("k")
    ax.set_ylabel("amplitude")
    ax.set_title(f"DM89 Fig. 1 (ours, run 0): {miss[0]} missed, {false[0]} false alarm(s)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "dm89.png", dpi=110)
    plt.close(fig)
    rep.files.append("dm89.png")

    # the front end on a pulse train: unit amplitudes at the TOAs of an MK94 episode, sample period 1
    entry = find_entry("paper-v0/mk94-three")
    ep = simulate(entry.spec.replace(n_pulses=150) if quick else entry.spec, next(iter(entry.test)))
    toa = ep.toa - ep.toa.min()
    rate = (len(toa) - 1) / (toa[-1] or 1.0)
    for noise in (0.03, 0.25):
        det = detect_pulses(toa, 1.0, 1.0, DM89_CHANNEL, noise, rate, 1.0, np.random.default_rng(0))
        rep.add(f"front end on mk94-three ({len(toa)} pulses, Ts=1, sigma_n={noise:g}): missed / false alarms",
                f"{det.n_missed} / {det.n_false_alarms}", "", "pulses on one sample merge; +-1 sample is a hit")
    return rep

"""Nishiguchi & Kobayashi 2000 (IEEE T-AES 36(2)), the improved PRI transform, on the worked example its
simulations use: three interleaved trains of mean PRIs 1, sqrt(2) and sqrt(5) (first pulses at 0, 0.1, 0.2;
334 + 333 + 333 = 1000 pulses), the PRI range [0, 10] in K = 201 bins, each TOA moved by a uniform jitter
in [-a, a] (a = 0.1: 10 % of the shortest PRI), eps = a, zeta0 = 0.03, thresholds alpha = 0.3, beta = 0.15,
gamma = 4.

Source of the example: only the paper's first page (abstract, introduction) is readable in the stored
copies (hobbydocbox.com, moam.info); the simulation parameters above are those of a public MATLAB
re-implementation of the paper's figures (github.com/eclipseljp/Rader, folder PRI_transform), not read
from the paper itself.  The paper's stated outcomes (abstract): the original transform's PRI spectrum
peaks at the PRIs (subharmonics suppressed) but is vulnerable to jitter; the improved transform keeps
the peaks of jittered trains, so thresholding detects the mean PRIs.

Seeds: run r draws the jitter with np.random.default_rng(r), r = 0..99.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from baselines.blind.pri_transform import (nk_thresholds, original_pri_transform, pri_transform_candidates,
                                           pri_transform_nk, threshold_peaks)
from baselines.reproduce import Report, experiment, figure

PRIS = (1.0, math.sqrt(2.0), math.sqrt(5.0))
FIRST = (0.0, 0.1, 0.2)
COUNTS = (334, 333, 333)
TAU_MAX, N_BINS, JITTER, ZETA0 = 10.0, 201, 0.1, 0.03
SUBHARMONICS = (2.0, 3.0, 2 * math.sqrt(2.0))


def example_toas(a: float, seed: int) -> np.ndarray:
    """The example's 1000 TOAs, each moved by U(-a, a), sorted."""
    t = np.concatenate([f + p * np.arange(n) for p, f, n in zip(PRIS, FIRST, COUNTS)])
    return np.sort(t + np.random.default_rng(seed).uniform(-a, a, t.size))


def detect(t: np.ndarray, eps: float) -> np.ndarray:
    """The PRIs the improved transform detects (K = 201 bins, the paper's thresholds)."""
    centres, mag, count, widths = pri_transform_nk(t, 0.0, TAU_MAX, N_BINS, eps, ZETA0)
    return threshold_peaks(centres, mag, nk_thresholds(t, centres, count, widths))


def matches(found: np.ndarray, step: float) -> tuple[int, int]:
    """(true PRIs with a detection within one bin step and eps, detections near no true PRI)."""
    tol = step + JITTER * np.asarray(PRIS)
    hit = sum(bool(np.any(np.abs(found - p) <= tl)) for p, tl in zip(PRIS, tol))
    extra = sum(not np.any(np.abs(f - np.asarray(PRIS)) <= tol) for f in found)
    return hit, extra


def _peak(centres: np.ndarray, mag: np.ndarray, tau: float) -> float:
    return float(mag[np.argmin(np.abs(centres - tau))])


@experiment("nk00", "Nishiguchi & Kobayashi 2000: PRI spectra of three trains (PRIs 1, sqrt 2, sqrt 5), original vs improved")
def nk00(out: Path, quick: bool) -> Report:
    rep = Report("nk00", "PRI transform on 1000 pulses of PRIs 1, sqrt 2, sqrt 5; K = 201 bins on [0, 10]")
    seeds = range(10 if quick else 100)
    step = TAU_MAX / N_BINS

    clean = example_toas(0.0, 0)
    c0, m0 = original_pri_transform(clean, 0.0, TAU_MAX, N_BINS)
    at_pri = [_peak(c0, m0, p) for p in PRIS]
    at_sub = [_peak(c0, m0, s) for s in SUBHARMONICS]
    rep.add("original, no jitter: |D| at 1, sqrt 2, sqrt 5", ", ".join(f"{v:.0f}" for v in at_pri),
            "peaks at the PRIs", "a train of n pulses adds n - 1 at its PRI")
    rep.add("original, no jitter: |D| at 2, 3, 2 sqrt 2 (subharmonics)", ", ".join(f"{v:.0f}" for v in at_sub),
            "suppressed", f"largest off-PRI bin {np.max(np.delete(m0, [np.argmin(np.abs(c0 - p)) for p in PRIS])):.0f}")

    orig_j, imp_j, hits, extras, exact, ours_hits, ours_extra = [], [], [], [], 0, [], []
    for s in seeds:
        t = example_toas(JITTER, s)
        c1, m1 = original_pri_transform(t, 0.0, TAU_MAX, N_BINS)
        orig_j.append([_peak(c1, m1, p) for p in PRIS])
        centres, mag, count, widths = pri_transform_nk(t, 0.0, TAU_MAX, N_BINS, JITTER, ZETA0)
        imp_j.append([_peak(centres, mag, p) for p in PRIS])
        found = threshold_peaks(centres, mag, nk_thresholds(t, centres, count, widths))
        h, e = matches(found, step)
        hits.append(h)
        extras.append(e)
        exact += (h == 3 and e == 0)
        # the policy's transform (bins tau^2 / (8 D) apart, origins moved in whole bin periods)
        cand = np.array([c.pri for c in pri_transform_candidates(t, 0.5, TAU_MAX, 0.002, eps=0.02,
                                                                  sigma=JITTER / math.sqrt(3))])
        h2, e2 = matches(cand, 0.0)
        ours_hits.append(h2)
        ours_extra.append(e2)
    n = len(seeds)
    rep.add(f"original, a = {JITTER:g}: |D| at the PRIs (mean over {n} runs)",
            ", ".join(f"{v:.0f}" for v in np.mean(orig_j, axis=0)), "peaks lost (vulnerable to jitter)")
    rep.add(f"improved, a = {JITTER:g}: |D| at the PRIs (mean)", ", ".join(f"{v:.0f}" for v in np.mean(imp_j, axis=0)),
            "peaks kept")
    rep.add("improved: true PRIs detected by the thresholds (mean of 3)", f"{np.mean(hits):.2f}",
            "the mean PRIs detected by thresholding")
    rep.add("improved: runs with exactly the three PRIs and nothing else", f"{exact}/{n}", "")
    rep.add("improved: spurious detections per run", f"{np.mean(extras):.2f}", "")
    rep.add("policy's transform (fine bins, whole-period origin steps): PRIs found / spurious per run",
            f"{np.mean(ours_hits):.2f} / {np.mean(ours_extra):.2f}", "", "pri-transform's detector on the same TOAs")

    plt = figure()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    t = example_toas(JITTER, 0)
    c1, m1 = original_pri_transform(t, 0.0, TAU_MAX, N_BINS)
    centres, mag, count, widths = pri_transform_nk(t, 0.0, TAU_MAX, N_BINS, JITTER, ZETA0)
    for ax, (x, y, title) in zip(axes, [(c0, m0, "original, no jitter"), (c1, m1, f"original, jitter a = {JITTER:g}"),
                                        (centres, mag, f"improved, jitter a = {JITTER:g}")]):
        ax.plot(x, y, lw=1)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("tau")
    axes[2].plot(centres, nk_thresholds(t, centres, count, widths), "r--", lw=1, label="threshold")
    axes[2].legend(fontsize=7)
    axes[0].set_ylabel("|D(tau)|")
    fig.tight_layout()
    fig.savefig(out / "nk00.png", dpi=110)
    plt.close(fig)
    rep.files.append("nk00.png")
    return rep

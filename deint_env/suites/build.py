"""Writes the suite files (`python -m deint_env.suites.build`).  The JSON files are the source of truth:
a published suite never changes, and tests check each file against its hash in HISTORY.json.  To
change a suite, add a new version here (e.g. `core-v1`) and publish it with `--publish "note"`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
from pathlib import Path
from typing import Any

from deint_env.scenario import DescriptorSpec, Modulation, PriorSpec, Range, ReceiverSpec, ScenarioSpec, SourceSpec
from deint_env.suites import Suite, SuiteEntry, SeedRange

HERE = Path(__file__).parent
TRAIN = SeedRange(0, 100_000)


def test_seeds(n: int) -> SeedRange:
    return SeedRange(1_000_000, 1_000_000 + n)


def entry(spec: ScenarioSpec, tags, settings, n_test: int = 10) -> SuiteEntry:
    return SuiteEntry(spec, tuple(tags), settings, TRAIN, test_seeds(n_test))


def explicit(period, phase, std) -> PriorSpec:
    """MK94's x_{1|0} = (T..., phi...) with Sigma_{1|0} = std^2 I."""
    return PriorSpec(kind="explicit", period=tuple(period), phase=tuple(phase), period_std=(std,), phase_std=(std,))


def sources(periods, phases) -> tuple[SourceSpec, ...]:
    return tuple(SourceSpec(period=float(t), phase=float(p)) for t, p in zip(periods, phases))


# ------------------------------------------------------------------------------------------------
# paper-v0: every simulation of MK94 sections V-VI and CM00 section IV
# ------------------------------------------------------------------------------------------------
MK94_FIG4_VARIANCES = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0)
CM00_FIVE_PRF_KHZ = (1.3238, 1.7364, 2.0830, 2.7595, 7.2244)  # Table I
CM00_FIVE_PHASE_RAD = (4.50, 5.31, 4.90, 2.04, 2.33)  # Table II
CM00_NEAR_PRF_KHZ = (1.1268, 1.2715, 3.9194, 5.0299)  # Table IV
CM00_NEAR_PHASE_RAD = (0.21, 5.92, 6.10, 0.61)  # Table V
# Section IV-B: sigma^2 = 1, 2, 5, 10 (x 1e-9 s^2), i.e. 23, 32, 51, 72 % of the smallest PRI (0.138 ms).
CM00_JITTER = {0: 0.0, 23: math.sqrt(1e-3), 32: math.sqrt(2e-3), 51: math.sqrt(5e-3), 72: math.sqrt(10e-3)}


def cm00_trains(prf_khz, phase_rad) -> tuple[SourceSpec, ...]:
    """CM00's trains in milliseconds: pulse n of train i at (2 pi n + theta_i) / (2 pi f_i)."""
    return tuple(SourceSpec(period=1.0 / f, phase=th / (2 * math.pi * f)) for f, th in zip(prf_khz, phase_rad))


CM00_PRIORS = PriorSpec(kind="perturbed", period_bias=1 / 0.9, phase_error=None)  # PRF 10 % low, phase unknown


def paper_v0() -> Suite:
    e = []
    for var, desc in ((9.0, "sigma_w = 3"), (1e4, "sigma_w = 100")):
        e.append(entry(ScenarioSpec(
            name=f"mk94-single-var{var:g}", sources=sources([11], [50]), n_pulses=100, toa_jitter_std=math.sqrt(var),
            priors=explicit([1], [1], math.sqrt(1e3)),
            description=f"MK94 V-A, Fig. 3: one source T=11, phi=50, {desc}; x_1|0=(1,1), Sigma=1e3 I"),
            ["paper"] + (["jitter"] if var > 10 else []), {"paper": "MK94 Fig. 3", "n_sources": 1, "jitter_var": var}))
    for var in MK94_FIG4_VARIANCES:
        e.append(entry(ScenarioSpec(
            name=f"mk94-two-var{var:g}", sources=sources([11, 17], [3, 4]), n_pulses=500,
            toa_jitter_std=math.sqrt(var), priors=explicit([10, 22], [1, 2], 1.0),
            description=f"MK94 V-B-1, Figs. 4-5: T=(11,17), phi=(3,4), sigma_w^2={var:g}; x_1|0=(10,22,1,2), Sigma=I"),
            ["paper"] + (["jitter"] if var >= 1.5 else []), {"paper": "MK94 Figs. 4-5", "n_sources": 2,
                                                             "jitter_var": var}))
    e.append(entry(ScenarioSpec(
        name="mk94-two-wide", sources=sources([11, 80], [3, 4]), n_pulses=600, toa_jitter_std=3.0,
        priors=explicit([60, 96], [2, 1], 1.0),
        description="MK94 V-B-2, Fig. 6: T=(11,80), phi=(3,4), sigma_w^2=9; x_1|0=(60,96,2,1), Sigma=I"),
        ["paper", "jitter"], {"paper": "MK94 Fig. 6", "n_sources": 2, "jitter_var": 9.0}))
    e.append(entry(ScenarioSpec(
        name="mk94-three", sources=sources([11, 30, 80], [3, 4, 6]), n_pulses=600, toa_jitter_std=3.0,
        priors=explicit([39, 40, 90], [3, 4, 2], 1.0),
        description="MK94 V-B-3, Fig. 7: T=(11,30,80), phi=(3,4,6), sigma_w^2=9; x_1|0=(39,40,90,3,4,2), Sigma=I"),
        ["paper", "jitter"], {"paper": "MK94 Fig. 7", "n_sources": 3, "jitter_var": 9.0}))
    eight_t, eight_phi = [11, 19, 39, 53, 83, 113, 139, 160], [3, 4, 6, 7, 4, 10, 3, 1]
    e.append(entry(ScenarioSpec(
        name="mk94-eight", sources=sources(eight_t, eight_phi), n_pulses=1000, toa_jitter_std=1.0,
        priors=explicit([7, 14, 38, 49, 83, 113, 140, 160], eight_phi, 10.0),
        description="MK94 V-B-4, Fig. 8: eight sources, sigma_w^2=1; x_1|0 as published, Sigma=1e2 I"),
        ["paper"], {"paper": "MK94 Fig. 8", "n_sources": 8, "jitter_var": 1.0}))
    e.append(entry(ScenarioSpec(
        name="mk94-pt-three", sources=sources([11, 30, 80], [3, 4, 6]), n_pulses=4000, toa_jitter_std=6.0,
        priors=explicit([1, 1, 1], [1, 1, 1], 1.0),
        description="MK94 V-C-2, Fig. 9: PT with known priors, T=(11,30,80), sigma_w^2=36; x_1|0=1, Sigma=I"),
        ["paper", "jitter"], {"paper": "MK94 Fig. 9", "n_sources": 3, "jitter_var": 36.0}))
    five_t, five_phi = [11, 19, 39, 83, 120], [3, 4, 6, 7, 4]
    e.append(entry(ScenarioSpec(
        name="mk94-pt-five", sources=sources(five_t, five_phi), n_pulses=5000, toa_jitter_std=8.0,
        priors=explicit([1] * 5, [1] * 5, 1.0),
        description="MK94 V-C-3, Fig. 10: PT with known priors, five sources, sigma_w^2=64; x_1|0=1, Sigma=I"),
        ["paper", "jitter"], {"paper": "MK94 Fig. 10", "n_sources": 5, "jitter_var": 64.0}))
    e.append(entry(ScenarioSpec(
        name="mk94-pt-post", sources=sources([11, 30, 80], [3, 4, 6]), n_pulses=3000, toa_jitter_std=1.0,
        priors=PriorSpec(kind="explicit", period=(1, 1, 1, 1), phase=(1, 1, 1, 1), period_std=(1e3,),
                         phase_std=(1e3,), source_prob=(0.25, 0.25, 0.25, 0.25)),
        description="MK94 V-C-4, Fig. 11: PT with a-posteriori probabilities, three sources but N=4 assumed, "
                    "sigma_w^2=1; x_1|0=1, Sigma=1e6 I, pi_i=1/4"),
        ["paper"], {"paper": "MK94 Fig. 11", "n_sources": 3, "jitter_var": 1.0}))
    e.append(entry(ScenarioSpec(
        name="mk94-missing-two", sources=sources([11, 30], [3, 4]), n_pulses=400, toa_jitter_std=1.0,
        coincidence_resolution=1.0, priors=explicit([4, 27], [3, 4], 1e3),
        description="MK94 VI-A-2, Fig. 12: T=(11,30), sigma_w^2=1, coincident pulses merge (only one is "
                    "received); x_1|0=(4,27,3,4), Sigma=1e6 I"),
        ["paper", "missing"], {"paper": "MK94 Fig. 12", "n_sources": 2, "jitter_var": 1.0}))
    e.append(entry(ScenarioSpec(
        name="mk94-pt-missing-three", sources=sources([11, 30, 80], [3, 4, 6]), n_pulses=4000, toa_jitter_std=6.0,
        coincidence_resolution=1.0, priors=explicit([1, 1, 1], [1, 1, 1], 1e3),
        description="MK94 VI-B, Fig. 13: PT with known priors and merged coincident pulses, T=(11,30,80), "
                    "sigma_w^2=36; x_1|0=1, Sigma=1e6 I"),
        ["paper", "missing", "jitter"], {"paper": "MK94 Fig. 13", "n_sources": 3, "jitter_var": 36.0}))
    # --- CM00 (times in ms, PRFs in kHz) ---
    for pct, sd in CM00_JITTER.items():
        e.append(entry(ScenarioSpec(
            name=f"cm00-five-jitter{pct}", sources=cm00_trains(CM00_FIVE_PRF_KHZ, CM00_FIVE_PHASE_RAD),
            n_pulses=2000, toa_jitter_std=sd, priors=CM00_PRIORS,
            description=f"CM00 IV, Tables I-II / Figs. 5-7: the five trains of Table I, TOA jitter {pct} % of the "
                        "smallest PRI; priors: PRFs 10 % low, phases unknown"),
            ["paper"] + (["jitter"] if pct else []), {"paper": "CM00 Tables I-III", "n_sources": 5,
                                                      "jitter_pct_min_pri": pct}))
    for m in range(2, 8):
        for pct in CM00_JITTER:
            e.append(entry(ScenarioSpec(
                name=f"cm00-random{m}-jitter{pct}",
                sources=tuple(SourceSpec(period=Range(0.125, 1.0)) for _ in range(m)), n_pulses=2000,
                toa_jitter_std=CM00_JITTER[pct], priors=CM00_PRIORS,
                description=f"CM00 IV, Table III / Fig. 6: {m} trains with random PRFs in 1-8 kHz (periods "
                            f"uniform in 0.125-1 ms), jitter {pct} % of 0.138 ms; priors: PRFs 10 % low, phases unknown"),
                ["paper"] + (["jitter"] if pct else []), {"paper": "CM00 Table III", "n_sources": m,
                                                          "jitter_pct_min_pri": pct}))
    e.append(entry(ScenarioSpec(
        name="cm00-near-equal", sources=cm00_trains(CM00_NEAR_PRF_KHZ, CM00_NEAR_PHASE_RAD), n_pulses=2000,
        priors=CM00_PRIORS,
        description="CM00 IV-C, Tables IV-V: trains 1 and 2 of near-equal PRF and phase (the EKF's failure case)"),
        ["paper"], {"paper": "CM00 Tables IV-V", "n_sources": 4}))
    return Suite("paper-v0", 0, "Every simulation of Moore & Krishnamurthy 1994 (sections V-VI) and Conroy & "
                 "Moore 2000 (section IV), with the papers' own initial estimates as priors.", tuple(e))


# The merging scenarios of paper-v0 as MK94 simulates them (the other scenarios are paper-v0's).
MK94_SIMULTANEOUS = {
    "mk94-missing-two": "MK94 VI-A-2, Fig. 12: T=(11,30), sigma_w^2=1, exactly simultaneous noise-free arrivals "
                        "merge (only one is received); x_1|0=(4,27,3,4), Sigma=1e6 I",
    "mk94-pt-missing-three": "MK94 VI-B, Fig. 13: PT with known priors, exactly simultaneous noise-free arrivals "
                             "merged, T=(11,30,80), sigma_w^2=36; x_1|0=1, Sigma=1e6 I",
}


def paper_v1() -> Suite:
    """paper-v0 with MK94's merging model (sections VI-A-2, VI-B): pulses merge when their noise-free
    arrivals coincide, not when their jittered TOAs land within the resolution.  On the integer
    schedules of Figs. 12-13 paper-v0's resolution of 1 then merges exactly the simultaneous arrivals."""
    e = []
    for x in paper_v0():
        if x.name in MK94_SIMULTANEOUS:
            x = dataclasses.replace(x, spec=x.spec.replace(merge="emission", description=MK94_SIMULTANEOUS[x.name]),
                                    settings={**x.settings, "merge": "emission"})
        e.append(x)
    return Suite("paper-v1", 1, "paper-v0 with MK94's merging: exactly simultaneous noise-free arrivals merge "
                 "(Figs. 12-13); every other scenario as in paper-v0.", tuple(e))


# ------------------------------------------------------------------------------------------------
# core-v0, robust-v0, agile-v0, scale-v0, blind-v0
# ------------------------------------------------------------------------------------------------
T_MIN = 10.0
STD_PRIORS = PriorSpec(kind="perturbed", period_error=0.01, phase_error=0.05)


def random_sources(n: int, spread: float, **kw: Any) -> tuple[SourceSpec, ...]:
    return tuple(SourceSpec(period=Range(T_MIN, T_MIN * spread, log=True), **kw) for _ in range(n))


def core_v0() -> Suite:
    e = []
    for n in (2, 3, 4, 6, 8):
        for spread in (1.5, 4.0, 16.0):
            for jitter in (0.05, 0.2, 0.5):
                e.append(entry(ScenarioSpec(
                    name=f"core-n{n}-spread{spread:g}-jitter{jitter:g}", sources=random_sources(n, spread),
                    n_pulses=1000, toa_jitter_std=jitter, priors=STD_PRIORS,
                    description=f"{n} constant-PRI sources, periods log-uniform in [{T_MIN:g}, {T_MIN * spread:g}], "
                                f"sigma_w={jitter:g}; priors: periods 1 % off, phases 5 % of a period off"),
                    ["jitter"] if jitter >= 0.2 else [], {"n_sources": n, "period_spread": spread,
                                                          "jitter_rel": jitter / T_MIN}))
    return Suite("core-v0", 0, "Constant-PRI sources: 2-8 sources x 3 period spreads x 3 TOA jitter levels.", tuple(e))


def robust_v0() -> Suite:
    base = dict(sources=random_sources(3, 4.0), n_pulses=1000, toa_jitter_std=0.2, priors=STD_PRIORS)
    e = []

    def add(name, tags, settings, desc, **kw):
        e.append(entry(ScenarioSpec(name=name, description=desc, **{**base, **kw}), tags, settings))

    for p in (0.05, 0.1, 0.2):
        add(f"robust-missing{p:g}", ["missing"], {"missing_prob": p}, f"each pulse missed with probability {p:g}",
            missing_prob=p)
    for r in (0.5, 1.0):
        add(f"robust-merged{r:g}", ["missing"], {"coincidence_resolution": r},
            f"pulses closer than {r:g} merge into one", coincidence_resolution=r)
    for s in (0.05, 0.1, 0.2):
        add(f"robust-spurious{s:g}", ["spurious"], {"spurious_rate": s}, f"{s:g} spurious pulses per source pulse",
            spurious_rate=s)
    srcs = list(base["sources"])
    add("robust-dropout", ["missing"], {"event": "dropout"}, "source 3 stops halfway through",
        sources=tuple(srcs[:2] + [SourceSpec(period=srcs[2].period, active=((0.0, 0.5),))]))
    add("robust-onset", ["missing"], {"event": "onset"}, "source 3 starts 40 % into the episode",
        sources=tuple(srcs[:2] + [SourceSpec(period=srcs[2].period, active=((0.4, 1.0),))]))
    for c in (0.1, 0.3):
        add(f"robust-cumjitter{c:g}", ["jitter"], {"pri_jitter_std": c}, f"cumulative PRI jitter {c:g} per interval",
            pri_jitter_std=c)
    add("robust-combined", ["missing", "spurious"], {"missing_prob": 0.1, "spurious_rate": 0.1,
                                                     "coincidence_resolution": 0.5},
        "10 % missed, 0.1 spurious per pulse, merging within 0.5", missing_prob=0.1, spurious_rate=0.1,
        coincidence_resolution=0.5)
    return Suite("robust-v0", 0, "Three sources under missing, merged and spurious pulses, dropout, onset and "
                 "cumulative jitter.", tuple(e))


def agile_v0(priors: PriorSpec = STD_PRIORS) -> Suite:
    steady = random_sources(2, 4.0)
    agile = Range(T_MIN, 2 * T_MIN, log=True)
    e = []

    def add(name, mod, desc, all_agile=False):
        srcs = (tuple(SourceSpec(period=agile, modulation=mod) for _ in range(3)) if all_agile
                else (SourceSpec(period=agile, modulation=mod), *steady))
        e.append(entry(ScenarioSpec(name=name, sources=srcs, n_pulses=1000, toa_jitter_std=0.1, priors=priors,
                                    description=desc), ["agile"], {"modulation": mod.kind, "all_agile": all_agile}))

    add("agile-stagger2", Modulation("stagger", pattern=(1.0, 1.5)), "one source with a 2-position stagger")
    add("agile-stagger3", Modulation("stagger", pattern=(1.0, 1.3, 1.7)), "one source with a 3-position stagger")
    add("agile-sliding", Modulation("sliding", depth=0.3, cycle=32), "one source sliding +-15 % over 32 pulses")
    add("agile-wobulated", Modulation("sinusoidal", depth=0.1, cycle=50), "one source wobulated +-10 %, 50 pulses")
    add("agile-wobulated-deep", Modulation("sinusoidal", depth=0.3, cycle=50), "one source wobulated +-30 %")
    add("agile-dwell-switch", Modulation("dwell_switch", pattern=(1.0, 1.4, 0.8), cycle=20),
        "one source switching between 3 PRIs every 20 pulses")
    add("agile-drifting", Modulation("drifting", alpha=1.0, drift_std=0.02),
        "one source whose period random-walks (MK94 II-C-2, alpha=1)")
    add("agile-drifting-alpha", Modulation("drifting", alpha=0.9995, drift_std=0.01),
        "one source whose period shrinks (MK94 II-C-2, alpha=0.9995)")
    add("agile-all-stagger", Modulation("stagger", pattern=(1.0, 1.3, 1.7)), "three 3-position staggered sources",
        all_agile=True)
    return Suite("agile-v0", 0, "Agile PRIs: stagger, sliding, wobulated, dwell-and-switch, drifting.", tuple(e))


def agile_v1() -> Suite:
    """agile-v0's scenarios (the same episodes, pulse for pulse) with priors that also name each source's
    modulation (`PriorSpec.modulation`): what an emitter library tells a tracker."""
    v0 = agile_v0(dataclasses.replace(STD_PRIORS, modulation=True))
    return Suite("agile-v1", 1, "agile-v0 with priors naming each source's PRI modulation and its parameters.",
                 v0.entries)


AGILE_V2_MISSING, AGILE_V2_SPURIOUS = 0.1, 0.1  # the channel of agile-v2's scenarios but the last two


def agile_v2() -> Suite:
    """The PRI models real emitters use (issue #22): random-level stagger (i.i.d. and Markov), deep
    saw-tooth ramps, wobulation of a non-integer cycle and dwells of their own lengths, under missing
    and spurious pulses, with priors naming each source's modulation (an emitter library's entry)."""
    steady = random_sources(2, 4.0)
    agile = Range(T_MIN, 2 * T_MIN, log=True)
    priors = dataclasses.replace(STD_PRIORS, modulation=True)
    rs = Modulation("random_stagger", pattern=(1.0, 1.3, 1.7), probs=(0.5, 0.3, 0.2))
    markov = Modulation("random_stagger", pattern=(0.8, 1.0, 1.25),
                        transition=((0.1, 0.8, 0.1), (0.1, 0.1, 0.8), (0.8, 0.1, 0.1)))
    deep = Modulation("sliding", depth=1.2, cycle=32, relative_to="start")
    wob = Modulation("sinusoidal", depth=0.2, cycle=1 / 0.015)
    dwells = Modulation("dwell_switch", pattern=(1.0, 1.4, 0.8), dwells=(20, 35, 10))
    e = []

    def add(name, mods, desc, missing=AGILE_V2_MISSING, spurious=AGILE_V2_SPURIOUS):
        srcs = tuple(SourceSpec(period=agile, modulation=m) for m in mods) + steady[:3 - len(mods)]
        e.append(entry(ScenarioSpec(name=name, sources=srcs, n_pulses=1000, toa_jitter_std=0.1, priors=priors,
                                    missing_prob=missing, spurious_rate=spurious,
                                    description=f"{desc}; {missing:.0%} missing, {spurious:g} spurious per pulse"),
                       ["agile", "missing", "spurious"],
                       {"modulation": "+".join(sorted({m.kind for m in mods})), "n_agile": len(mods),
                        "missing_prob": missing, "spurious_rate": spurious}))

    add("agile2-random-stagger", (rs,), "one source switching at random among 3 PRI levels (probabilities 0.5/0.3/0.2)")
    add("agile2-markov-stagger", (markov,), "one source switching among 3 PRI levels by a Markov chain")
    add("agile2-deep-sliding", (deep,), "one source sliding over a ramp 1.2 times its first PRI, 32 pulses")
    add("agile2-wobulated-fractional", (wob,), "one source wobulated +-20 % over 66.7 pulses (not a whole number)")
    add("agile2-dwells", (dwells,), "one source holding 3 PRIs for 20, 35 and 10 pulses in turn")
    add("agile2-mixed", (rs, deep, wob), "a random-level, a deep sliding and a wobulated source")
    add("agile2-mixed-heavy", (rs, deep, wob), "agile2-mixed on a worse channel", missing=0.3, spurious=0.2)
    add("agile2-all-random", (rs, markov, rs), "three random-level sources", missing=0.2, spurious=0.15)
    return Suite("agile-v2", 2, "Random-level stagger, deep sliding, non-integer wobulation and dwells of their own "
                 "lengths, with missing and spurious pulses; priors name each modulation.", tuple(e))


def scale_v0() -> Suite:
    e = []
    for n_pulses, n in ((10_000, 4), (10_000, 16), (100_000, 8), (100_000, 32), (1_000_000, 8), (1_000_000, 32)):
        e.append(entry(ScenarioSpec(
            name=f"scale-{n_pulses}p-{n}s", sources=random_sources(n, n / 2), n_pulses=n_pulses, toa_jitter_std=0.1,
            priors=STD_PRIORS, description=f"{n} sources, {n_pulses} pulses"), ["scale"],
            {"n_sources": n, "n_pulses": n_pulses}, n_test=2))
    return Suite("scale-v0", 0, "Long episodes (10^4-10^6 pulses) with up to 32 sources.", tuple(e))


def blind_v0() -> Suite:
    e = []
    for lo, hi in ((2, 2), (3, 3), (2, 5), (4, 6)):
        for jitter in (0.1, 0.5):
            e.append(entry(ScenarioSpec(
                name=f"blind-n{lo}to{hi}-jitter{jitter:g}", sources=random_sources(hi, 8.0), n_pulses=1000,
                toa_jitter_std=jitter, blind=True, label_budget=8, n_active=(lo, hi), priors=PriorSpec(kind="none"),
                description=f"{lo}-{hi} sources (unknown), no priors, 8 labels, sigma_w={jitter:g}"),
                ["blind"] + (["jitter"] if jitter >= 0.5 else []), {"n_sources_low": lo, "n_sources_high": hi,
                                                                    "jitter_rel": jitter / T_MIN}))
    return Suite("blind-v0", 0, "Unknown number of sources and no priors: link-rewarded labels.", tuple(e))


# ------------------------------------------------------------------------------------------------
# pdw-v0: pulse descriptor words, as the Turing Synthetic Radar Dataset's scenes (Gunn et al. 2026)
# ------------------------------------------------------------------------------------------------
# Every emitter draws from the same wide ranges, so they overlap in every descriptor: X band, the TDC's
# microsecond TOAs.  Antenna scans are compressed to 10-100 ms (real search radars: seconds) so that an
# episode of 10^4 pulses holds whole scans, bursts and gaps alike.
PDW_PRI = Range(50.0, 5000.0, log=True)  # us
# Emitters share a few parameter modes (bands, pulse-width classes) rather than spreading uniformly, so
# several emitters of a scene overlap in frequency and pulse width as the TSRD's do.
PDW_BANDS = (8600.0, 9100.0, 9400.0, 9900.0)  # MHz: band centres, each emitter +-40 MHz about one
PDW_PULSE_WIDTHS = (Range(0.8, 1.2), Range(4.0, 6.0), Range(15.0, 25.0))  # us: short, medium, long
PDW_ERP = Range(0.5, 50.0, log=True)  # received amplitude on the main beam (ERP less range loss)
PDW_SCAN = Range(1e4, 1e5, log=True)  # us
PDW_AOA_DRIFT = Range(-1e-5, 1e-5)  # degrees per us: up to 10 degrees a second
_PDW_NOISE = dict(threshold=0.05, frequency_noise_std=5.0, pulse_width_noise_std=0.2)
PDW_RECEIVERS = {
    "staring": ReceiverSpec(aoa_noise_std=3.0, **_PDW_NOISE),
    # a 30-degree beam turning every 20 ms: an emitter is in its main beam for ~1.7 ms a turn (a burst),
    # heard between only when strong enough for the -30 dB sidelobes; its directional antenna measures
    # the AoA better than the staring receiver's
    "scanning": ReceiverSpec(mode="scanning", scan_period=2e4, beamwidth=30.0, sidelobe_db=-30.0, aoa_noise_std=1.0,
                             **_PDW_NOISE),
}
PDW_PRIORS = PriorSpec(kind="perturbed", period_error=0.01, phase_error=0.05, descriptors=True)  # an emitter library
# PRI agility, cycling over the emitters: constant, jittered (+-10 %, i.i.d. levels), 3-position
# stagger, wobulated (+-20 %), dwell-and-switch, sliding (+-15 % over 32 pulses)
PDW_MODULATIONS = (
    Modulation(),
    Modulation("random_stagger", pattern=(0.9, 0.95, 1.0, 1.05, 1.1)),
    Modulation("stagger", pattern=(1.0, 1.3, 1.7), random_start=True),
    Modulation("sinusoidal", depth=0.2, cycle=1 / 0.015),
    Modulation("dwell_switch", pattern=(1.0, 1.4, 0.8), dwells=(20, 35, 10), random_start=True),
    Modulation("sliding", depth=0.3, cycle=32, random_start=True),
)


def pdw_emitter(i: int) -> SourceSpec:
    """Emitter i of a pdw-v0 scene: a mix cycling through the kinds of emitters a receiver meets, its
    band and pulse-width class shared with others (band (3i // 2) mod 4, class i mod 3)."""
    kind = i % 4
    band = PDW_BANDS[(3 * i // 2) % len(PDW_BANDS)]
    common = dict(frequency=Range(band - 40.0, band + 40.0), pulse_width=PDW_PULSE_WIDTHS[i % 3],
                  aoa_rate=PDW_AOA_DRIFT, beamwidth=(2.0, 3.0, 5.0)[i % 3], beam=("gaussian", "sinc2")[i % 2],
                  sidelobe_db=-25.0)
    d = (DescriptorSpec(frequency_std=2.0, scan="circular", scan_period=PDW_SCAN, **common),  # search radar
         DescriptorSpec(frequency_hops=(0.0, 150.0, 300.0, 450.0, 600.0), pulse_width_levels=(1.0, 2.0, 4.0),
                        scan="circular", scan_period=PDW_SCAN, **common),  # frequency- and PW-agile
         DescriptorSpec(frequency_std=20.0, scan="sector", scan_period=PDW_SCAN, sector=90.0, **common),
         DescriptorSpec(frequency_std=2.0, **common))[kind]  # the last: a tracker, its beam on the receiver
    return SourceSpec(period=PDW_PRI, modulation=PDW_MODULATIONS[i % len(PDW_MODULATIONS)], amplitude=PDW_ERP,
                      descriptors=d)


def pdw_v0() -> Suite:
    e = []
    for rx, receiver in PDW_RECEIVERS.items():
        scenes = [(n, 10_000, blind) for n in (5, 10, 30, 90) for blind in (False, True)] + [(90, 100_000, True)]
        for n, n_pulses, blind in scenes:
            budget = min(256, max(16, 2 ** math.ceil(math.log2(1.5 * n))))
            name = f"pdw-{rx}-n{n}" + ("-blind" if blind else "") + ("-100k" if n_pulses > 10_000 else "")
            e.append(entry(ScenarioSpec(
                name=name, sources=tuple(pdw_emitter(i) for i in range(n)), n_pulses=n_pulses, toa_jitter_std=0.05,
                spurious_rate=0.02, amplitudes=True, amplitude_noise_std=0.01, receiver=receiver,
                blind=blind, label_budget=budget if blind else 0,
                priors=PriorSpec(kind="none") if blind else PDW_PRIORS,
                description=f"{n} emitters (PRI 50 us-5 ms, mostly agile: jittered, staggered, wobulated, "
                            "dwell-and-switch, sliding; four shared 80 MHz bands in 8.6-9.9 GHz, three PW classes, "
                            f"any AoA; circular, sector and no scans), {rx} receiver, threshold 0.05, "
                            f"{n_pulses} pulses; "
                            + (f"blind, {budget} labels" if blind else "priors: periods 1 % off, phases 5 %, "
                               "the emitter library's descriptor means and spreads")),
                ["pdw", "agile", "missing", "spurious"] + (["blind"] if blind else []),
                {"receiver": rx, "n_sources": n, "n_pulses": n_pulses, "blind": blind},
                n_test=2 if n_pulses > 10_000 else 10))
    return Suite("pdw-v0", 0, "Pulse descriptor words (frequency, pulse width, AoA, scan-shaped amplitude) as in the "
                 "Turing Synthetic Radar Dataset: 5-90 emitters with agile PRIs sharing a few frequency bands and "
                 "pulse-width classes, staring and scanning receivers, anchored and blind.", tuple(e))


BUILDERS = {"paper-v0": paper_v0, "paper-v1": paper_v1, "core-v0": core_v0, "robust-v0": robust_v0, "agile-v0": agile_v0,
            "agile-v1": agile_v1, "agile-v2": agile_v2, "scale-v0": scale_v0, "blind-v0": blind_v0,
            "pdw-v0": pdw_v0}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("suites", nargs="*", default=list(BUILDERS))
    ap.add_argument("--publish", metavar="NOTE", help="record the written suites' hashes in HISTORY.json")
    args = ap.parse_args(argv)
    hist_path = HERE / "HISTORY.json"
    hist = json.loads(hist_path.read_text()) if hist_path.exists() else {}
    for name in args.suites:
        suite = BUILDERS[name]()
        published = hist.get(name)
        if published and published[-1]["hash"] != suite.content_hash:
            raise SystemExit(f"{name} is published with hash {published[-1]['hash']}; its content would change "
                             f"to {suite.content_hash}. Make a new version instead.")
        (HERE / f"{name}.json").write_text(json.dumps(suite.to_json_dict(), indent=1) + "\n")
        if args.publish and not published:
            hist[name] = [{"hash": suite.content_hash, "date": datetime.date.today().isoformat(),
                           "note": args.publish}]
        print(f"{name}: {len(suite)} scenarios, hash {suite.content_hash}")
    if args.publish:
        hist_path.write_text(json.dumps(hist, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()

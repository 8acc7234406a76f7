"""Same spec + seed => same episode, bit for bit, across refactors of the simulator.

`tests/data/episode_hashes.json` holds a sha256 over every array of the episode (pulses, truth and
priors) for every scenario of every published suite (scale-v0: the 10^4-pulse scenarios only) at
three seeds each (the first test seed, the first train seed, 12345), and for a few extra specs below
that reach the paths no suite uses (amplitudes, windows, merges, modulations, the horizon retry,
ties).  A published suite never changes, so neither may these hashes.

Regenerate the file only when an intended simulator change comes with new suite versions (a change
that moves any episode moves scores, see docs/design.md section 3):

    python tests/test_episode_hashes.py --write
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from deint_env.episode import Episode
from deint_env.scenario import Modulation, PriorSpec, Range, ScenarioSpec, SourceSpec
from deint_env.simulate import simulate, simulate_many
from deint_env.suites import list_suites, load_suite

FIXTURE = Path(__file__).parent / "data" / "episode_hashes.json"
EXTRA_SEEDS = (0, 1, 2, 3, 12345)
_SPREAD = Range(10.0, 40.0, log=True)

# Specs no suite covers; each comment says which path it reaches.
EXTRA = (
    # amplitudes with per-source fluctuation and measurement noise; merges sum amplitudes, spurious
    # pulses draw theirs; cumulative jitter; missing pulses
    ScenarioSpec(name="x-amplitudes-merged", n_pulses=600, toa_jitter_std=0.3, pri_jitter_std=0.5, missing_prob=0.1,
                 coincidence_resolution=1.0, spurious_rate=0.3, amplitudes=True, amplitude_noise_std=0.05,
                 sources=(SourceSpec(period=_SPREAD, amplitude=Range(1.0, 2.0), amplitude_std=0.1),
                          SourceSpec(period=_SPREAD, amplitude=3.0),
                          SourceSpec(period=_SPREAD, phase=Range(0.0, 5.0), amplitude_std=0.2)),
                 priors=PriorSpec(period_error=0.02, period_bias=1.05, phase_error=0.1, source_prob=(0.5, 0.3, 0.2))),
    # every modulation, one per source (> 3 sources: the default sort), a dropout and an onset window
    ScenarioSpec(name="x-modulations-windows", n_pulses=800, toa_jitter_std=0.1,
                 sources=(SourceSpec(period=_SPREAD, modulation=Modulation("stagger", pattern=(1.0, 1.3, 1.7))),
                          SourceSpec(period=_SPREAD, modulation=Modulation("sliding", depth=0.3, cycle=16)),
                          SourceSpec(period=_SPREAD, modulation=Modulation("sinusoidal", depth=0.2, cycle=25)),
                          SourceSpec(period=_SPREAD, modulation=Modulation("drifting", alpha=0.9995, drift_std=0.05)),
                          SourceSpec(period=_SPREAD, modulation=Modulation("dwell_switch", pattern=(1.0, 1.5),
                                                                           cycle=20), active=((0.0, 0.4),)),
                          SourceSpec(period=_SPREAD, active=((0.3, 0.6), (0.8, 1.0)))),
                 priors=PriorSpec(phase_error=None)),
    # the models of agile-v2 and the ones it leaves out: random levels (i.i.d., Markov), random cycle
    # positions (stagger, dwells of their own lengths, a deep ramp), a wobulation of a fractional cycle
    ScenarioSpec(name="x-agile-models", n_pulses=800, toa_jitter_std=0.1, missing_prob=0.1, spurious_rate=0.1,
                 sources=(SourceSpec(period=_SPREAD, modulation=Modulation("random_stagger", pattern=(1.0, 1.5),
                                                                           probs=(0.3, 0.7))),
                          SourceSpec(period=_SPREAD, modulation=Modulation(
                              "random_stagger", pattern=(1.0, 1.3, 1.7),
                              transition=((0.0, 1.0, 0.0), (0.5, 0.0, 0.5), (0.2, 0.3, 0.5)))),
                          SourceSpec(period=_SPREAD, modulation=Modulation("stagger", pattern=(1.0, 1.3, 1.7),
                                                                           random_start=True)),
                          SourceSpec(period=_SPREAD, modulation=Modulation("dwell_switch", pattern=(1.0, 1.4, 0.8),
                                                                           dwells=(5, 9, 3), random_start=True)),
                          SourceSpec(period=_SPREAD, modulation=Modulation("sliding", depth=1.5, cycle=12,
                                                                           relative_to="start", random_start=True)),
                          SourceSpec(period=_SPREAD, modulation=Modulation("sinusoidal", depth=0.2, cycle=17.3))),
                 priors=PriorSpec(modulation=True)),
    # one source on for a tenth of the nominal duration: the first horizon falls short and is doubled
    ScenarioSpec(name="x-horizon-retry", n_pulses=300, toa_jitter_std=0.2, spurious_rate=0.2,
                 coincidence_resolution=0.5,
                 sources=(SourceSpec(period=50.0), SourceSpec(period=5.0, active=((0.0, 0.1),)))),
    # noise-free commensurate periods: exact ties, with <= 3 and with > 3 sources (the stable re-sort)
    ScenarioSpec(name="x-ties-3", n_pulses=500,
                 sources=tuple(SourceSpec(period=t, phase=0.0) for t in (10.0, 15.0, 6.0))),
    ScenarioSpec(name="x-ties-5", n_pulses=500,
                 sources=tuple(SourceSpec(period=t, phase=0.0) for t in (10.0, 15.0, 6.0, 12.0, 20.0))),
    # blind, varying source count, windowed optional sources, spurious pulses merging into real ones
    ScenarioSpec(name="x-blind-windows", n_pulses=400, toa_jitter_std=0.3, spurious_rate=0.5,
                 coincidence_resolution=1.5, blind=True, label_budget=8, n_active=(1, 4),
                 priors=PriorSpec(kind="none"),
                 sources=(SourceSpec(period=Range(10.0, 80.0, log=True)), SourceSpec(period=_SPREAD),
                          SourceSpec(period=_SPREAD, active=((0.2, 0.7),)), SourceSpec(period=_SPREAD))),
    # explicit priors with more tracks than sources, with amplitudes (phantom tracks)
    ScenarioSpec(name="x-explicit-phantom", n_pulses=300, toa_jitter_std=1.0, amplitudes=True,
                 sources=(SourceSpec(period=11.0, phase=3.0, amplitude=2.0), SourceSpec(period=17.0, amplitude=1.0)),
                 priors=PriorSpec(kind="explicit", period=(10.0, 18.0, 30.0), phase=(2.0, 4.0, 5.0),
                                  period_std=(1.0,), phase_std=(1.0, 2.0, 3.0))),
    # MK94's merging (merge="emission"): exactly simultaneous noise-free arrivals of > 3 sources (the
    # default sort and the stable re-sort of ties), amplitudes summed, spurious pulses, missed pulses
    ScenarioSpec(name="x-emission-merged", n_pulses=600, toa_jitter_std=0.5, missing_prob=0.05,
                 coincidence_resolution=0.5, merge="emission", spurious_rate=0.1, amplitudes=True,
                 sources=tuple(SourceSpec(period=t, phase=0.0, amplitude=a)
                               for t, a in ((10.0, 1.0), (15.0, 2.0), (6.0, 1.5), (12.0, 1.0)))),
    # explicit priors without phases and with given source probabilities
    ScenarioSpec(name="x-explicit-no-phase", n_pulses=200, toa_jitter_std=0.5,
                 sources=(SourceSpec(period=Range(9.0, 12.0)), SourceSpec(period=Range(15.0, 20.0))),
                 priors=PriorSpec(kind="explicit", period=(10.0, 18.0), period_std=(1.0, 2.0), phase_std=(5.0,),
                                  source_prob=(0.6, 0.4))),
)


def cases() -> list[tuple[str, ScenarioSpec, tuple[int, ...]]]:
    """(key, spec, seeds) for every pinned scenario."""
    out = []
    for suite in list_suites():
        for e in load_suite(suite):
            if suite == "scale-v0" and e.spec.n_pulses != 10_000:
                continue
            out.append((f"{suite}/{e.name}", e.spec, (e.test.start, e.train.start, 12345)))
    out += [(f"extra/{s.name}", s, EXTRA_SEEDS) for s in EXTRA]
    return out


def episode_digest(ep: Episode) -> str:
    """sha256 over the raw bytes (with dtype and shape) of every array, in a fixed order."""
    h = hashlib.sha256()

    def add(name: str, value) -> None:
        h.update(name.encode())
        if value is None:
            h.update(b"None")
        elif isinstance(value, np.ndarray):
            h.update(f"{value.dtype.str}{value.shape}".encode())
            h.update(np.ascontiguousarray(value).tobytes())
        else:
            h.update(repr(value).encode())

    for name in ("toa", "amplitude", "source", "mask"):
        add(name, getattr(ep, name))
    for name in ("period", "phase", "final_period", "n_received", "schedule_toa", "schedule_pri",
                 "schedule_offsets"):
        add(f"truth.{name}", getattr(ep.truth, name))
    info = ep.priors.as_info()
    for name in sorted(info):
        add(f"priors.{name}", info[name])
    return h.hexdigest()


def compute(batched: bool = False) -> dict:
    """The fixture's content: episode by episode with `simulate`, or each scenario's seeds together."""
    out = {}
    for key, spec, seeds in cases():
        episodes = simulate_many(spec, seeds) if batched else [simulate(spec, s) for s in seeds]
        out[key] = {"spec": spec.content_hash, "seeds": {str(s): episode_digest(e) for s, e in zip(seeds, episodes)}}
    return out


@pytest.mark.parametrize("batched", [False, True], ids=["simulate", "simulate_many"])
def test_episodes_are_bit_identical_to_the_fixture(batched):
    expected = json.loads(FIXTURE.read_text())
    actual = compute(batched)
    assert actual.keys() == expected.keys(), "scenario list changed: see the module docstring"
    stale = [k for k in actual if actual[k]["spec"] != expected[k]["spec"]]
    assert not stale, f"specs changed (not the simulator): {stale}"
    moved = [f"{k} seed {s}" for k in actual for s, digest in actual[k]["seeds"].items()
             if digest != expected[k]["seeds"][s]]
    assert not moved, f"{len(moved)} episodes changed, e.g. {moved[:5]}"


@pytest.mark.parametrize("spec", EXTRA, ids=[s.name for s in EXTRA])
def test_extra_specs_reach_their_paths(spec):
    """Guard the fixture's coverage: the extra specs do produce what their comments promise."""
    eps = [simulate(spec, s) for s in EXTRA_SEEDS]
    if spec.coincidence_resolution > 0:
        assert any(np.any(np.bitwise_and(e.mask, e.mask - np.uint64(1)) != 0) for e in eps)  # merged pulses
    if spec.name.startswith("x-ties"):
        assert all(np.any(np.diff(e.toa) == 0) for e in eps)
    if spec.name == "x-horizon-retry":  # pulses past the first horizon: it was doubled
        for e in eps:
            rate = np.sum(1 / e.truth.period)
            received = rate * (1 + spec.spurious_rate) * np.exp(-rate * (1 + spec.spurious_rate)
                                                                * spec.coincidence_resolution)
            assert e.toa[-1] > e.truth.phase.max() + (1.15 * spec.n_pulses + 20) / received
    if spec.n_active is not None:
        assert len({e.truth.n_sources for e in eps}) > 1


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit(__doc__)
    FIXTURE.parent.mkdir(exist_ok=True)
    FIXTURE.write_text(json.dumps(compute(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {FIXTURE}")

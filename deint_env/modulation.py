"""PRI modulation identification: the model a policy found for each train, and its score.

A blind policy reports, per label track, a `PRIModel`: the kind (constant, stagger, sliding,
sinusoidal, dwell_switch, drifting) and its parameters, in the conventions of
`deint_env.scenario.Modulation` (period = the mean PRI T; stagger levels = the sub-PRIs in emission
order, T * pattern / mean(pattern); dwell_switch: the dwell PRIs in that convention as levels and the
pulses per dwell as cycle (their mean for dwells of their own lengths); random_stagger: its level PRIs;
sliding and sinusoidal: depth (relative peak-to-peak sweep over T / relative amplitude) and cycle
(pulses); drifting: the period alone).
`modulation_scores` compares them with the episode's truth: the share of sources whose model kind is
right, and the relative errors of the parameters where it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from deint_env.scenario import ScenarioSpec

KINDS = ("constant", "stagger", "sliding", "sinusoidal", "dwell_switch", "drifting", "random_stagger")


@dataclass(frozen=True)
class PRIModel:
    """One train's PRI model.  `levels`: stagger sub-PRIs or dwell PRIs (empty otherwise); `depth`:
    sliding / sinusoidal only; `cycle`: sliding / sinusoidal / dwell_switch only (0 otherwise)."""

    kind: str
    period: float
    levels: tuple[float, ...] = ()
    depth: float = 0.0
    cycle: float = 0.0

    def as_dict(self) -> dict[str, object]:
        return {"kind": self.kind, "period": self.period, "levels": list(self.levels), "depth": self.depth,
                "cycle": self.cycle}


def true_models(spec: ScenarioSpec, period: np.ndarray) -> list[PRIModel]:
    """The true PRI model of every source of an episode (period: the episode's drawn T_i)."""
    out = []
    for src, t in zip(spec.sources, np.asarray(period, dtype=np.float64).tolist()):
        m = src.modulation
        if m.kind in ("stagger", "dwell_switch", "random_stagger"):
            dwell = (float(np.mean(m.dwells)) if m.dwells else float(m.cycle)) if m.kind == "dwell_switch" else 0.0
            pat = np.asarray(m.pattern)
            levels = t * m.level_ratios() if m.kind == "random_stagger" or m.dwells else t * pat / pat.mean()
            out.append(PRIModel(m.kind, t, tuple(levels.tolist()), 0.0, dwell))
        elif m.kind == "sliding":
            out.append(PRIModel(m.kind, t, (), float(m.sliding_depth()), float(m.cycle)))
        elif m.kind == "sinusoidal":
            out.append(PRIModel(m.kind, t, (), float(m.depth), float(m.cycle)))
        else:
            out.append(PRIModel(m.kind, t))
    return out


def _cyclic_level_error(found: Sequence[float], true: Sequence[float]) -> float:
    """Mean relative error of stagger levels under the best cyclic rotation (NaN if counts differ)."""
    f, t = np.asarray(found, dtype=np.float64), np.asarray(true, dtype=np.float64)
    if f.size != t.size or f.size == 0:
        return math.nan
    return float(min(np.mean(np.abs(np.roll(f, r) - t) / t) for r in range(f.size)))


@dataclass(frozen=True)
class ModulationScore:
    """kind_accuracy: share of sources (with a track) whose model kind is right; n_scored: how many
    sources had a track; the parameter errors are means over the rightly identified sources of their
    kind (NaN when there is none): period (all kinds), stagger and dwell levels (under the best
    rotation, NaN if the level count is wrong), depth (sliding, sinusoidal) and cycle (those and
    dwell_switch), relative."""

    kind_accuracy: float
    n_scored: int
    period_rel_error: float
    level_rel_error: float
    depth_rel_error: float
    cycle_rel_error: float

    def as_dict(self) -> dict[str, float]:
        return {"modulation_kind_accuracy": self.kind_accuracy, "modulation_n_scored": self.n_scored,
                "modulation_period_rel_error": self.period_rel_error,
                "modulation_level_rel_error": self.level_rel_error,
                "modulation_depth_rel_error": self.depth_rel_error,
                "modulation_cycle_rel_error": self.cycle_rel_error}


def modulation_scores(found: Sequence[PRIModel | None], truth: Sequence[PRIModel],
                      label_of_source: np.ndarray) -> ModulationScore:
    """Score the models a policy reported per label (`found[label]`) against the true models of the
    sources; `label_of_source[i]` is the label matched to source i (-1: none, e.g. from the Hungarian
    matching of `deint_env.metrics.matched_labels`)."""
    right, period, levels, depth, cycle = [], [], [], [], []
    for i, true in enumerate(truth):
        lab = int(label_of_source[i]) if i < len(label_of_source) else -1
        model = found[lab] if 0 <= lab < len(found) else None
        if model is None:
            continue
        ok = model.kind == true.kind
        right.append(ok)
        if not ok:
            continue
        period.append(abs(model.period - true.period) / true.period)
        if true.kind in ("stagger", "dwell_switch", "random_stagger"):
            levels.append(_cyclic_level_error(model.levels, true.levels))
        if true.kind in ("sliding", "sinusoidal"):
            depth.append(abs(model.depth - true.depth) / true.depth)
        if true.kind in ("sliding", "sinusoidal", "dwell_switch"):
            cycle.append(abs(model.cycle - true.cycle) / true.cycle)

    def avg(x: list[float]) -> float:
        return float(np.mean(x)) if x else math.nan

    return ModulationScore(avg([float(r) for r in right]), len(right), avg(period), avg(levels), avg(depth),
                           avg(cycle))


def episode_modulation_scores(found: Sequence[PRIModel | None], spec: ScenarioSpec, period: np.ndarray,
                              labels: np.ndarray, source: np.ndarray, n_labels: int,
                              modulated_only: bool = False) -> ModulationScore:
    """`modulation_scores` for one played episode: a policy's models per label (`modulations()`),
    the scenario and its drawn periods (`truth.period`), and the labels it gave, matched to the
    sources by the Hungarian matching of the blind metrics.  `modulated_only` scores the sources whose
    PRI is not constant alone."""
    from deint_env.metrics import matched_labels

    truth = true_models(spec, period)
    mapped = matched_labels(np.asarray(labels), np.asarray(source), n_labels)
    label_of_source = np.full(len(truth), -1)
    for lab, src in zip(np.asarray(labels).tolist(), mapped.tolist()):
        if src < len(truth) and lab < n_labels:
            label_of_source[src] = lab
    keep = [i for i, t in enumerate(truth) if not modulated_only or t.kind != "constant"]
    return modulation_scores(found, [truth[i] for i in keep], label_of_source[keep])

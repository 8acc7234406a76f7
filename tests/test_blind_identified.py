"""`cdif-renewal` (baselines/blind/identified.py): cdif's trains and PRI models made anchored priors, then
the anchored renewal-ml, on files of the independent agile generator (tests/independent_agile.py)
labelled through `deint label` with --n-sources 3 and no priors file."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.blind.identified import IdentifiedRenewal, as_modulation, repeating_cycle
from deint_env.cli import main
from deint_env.episode import Priors
from deint_env.errors import NotApplicable
from deint_env.modulation import PRIModel
from independent_agile import agile_file, grid, matched_accuracy, read_labels, write_pulses

K = 3


def label(tmp_path, policy: str, f) -> np.ndarray | None:
    write_pulses(tmp_path / "p.csv", f)
    code = main(["label", str(tmp_path / "p.csv"), "--policy", policy, "--n-sources", str(K),
                 "-o", str(tmp_path / "l.csv")])
    return read_labels(tmp_path / "l.csv") if code == 0 else None


@pytest.mark.parametrize("seed", [0, 2])
def test_jittered_trains_beat_cdif(tmp_path, seed):
    """Three jittered (renewal) trains, 500 pulses, clean channel: cdif's own labels lose most of them
    (0.73 and 0.39 when written), identified and tracked they reach 0.90 (0.96 and 0.92)."""
    f = agile_file(("jittered",) * K, seed, n_pulses=500)
    ours = matched_accuracy(label(tmp_path, "cdif-renewal", f), f.source)
    theirs = matched_accuracy(label(tmp_path, "cdif", f), f.source)
    assert ours >= 0.90 and ours >= theirs + 0.1, (ours, theirs)


def test_identified_models_become_modulations():
    """A stagger found at twice its frame keeps one cycle; a one-level stagger is a constant PRI; a
    drifting train has no modulation (the default bank)."""
    assert repeating_cycle(np.array([9.0, 11.0, 9.0, 11.0]), 0.1).tolist() == [9.0, 11.0]
    period, mod = as_modulation(PRIModel("stagger", 20.0, (9.0, 11.0, 9.0, 11.0)))
    assert period == pytest.approx(10.0) and mod.kind == "stagger" and mod.pattern == pytest.approx((0.9, 1.1))
    period, mod = as_modulation(PRIModel("stagger", 24.0, (12.0, 12.0)))
    assert period == pytest.approx(12.0) and mod.kind == "constant"
    assert as_modulation(PRIModel("drifting", 15.0))[1] is None
    mod = as_modulation(PRIModel("sliding", 15.0, depth=0.4, cycle=31.6))[1]
    assert (mod.kind, mod.cycle, mod.random_start) == ("sliding", 32, True)


def test_no_train_is_not_applicable():
    """Pulses with no periodic train (a Poisson process) leave nothing to identify: NotApplicable."""
    toa = np.sort(np.random.default_rng(0).uniform(0, 1000, 300))
    policy = IdentifiedRenewal()
    policy.reset(Priors(n_labels=K, blind=True), {"n_pulses": toa.size})
    with pytest.raises(NotApplicable, match="no train"):
        for y in toa:
            policy.act({"valid": 1, "toa": np.array([y])})
        policy.act({"valid": 0, "toa": np.zeros(1)})


def test_anchored_priors_are_not_applicable():
    with pytest.raises(NotApplicable, match="blind"):
        IdentifiedRenewal().reset(Priors(n_labels=1, period=np.array([10.0])), {})


@pytest.mark.slow
def test_jittered_scene_of_the_grid_beats_cdif_on_average(tmp_path):
    """The jittered scene of seed 0, every channel (full size): higher mean accuracy than cdif (0.57 against
    0.48 when written; cdif-renewal is below cdif on the clean file, 0.56 against 0.76)."""
    ours, theirs = [], []
    for name, kinds, miss, spur, seed in grid():
        if name.startswith("jittered"):
            f = agile_file(kinds, seed, missing=miss, spurious=spur)
            ours.append(matched_accuracy(label(tmp_path, "cdif-renewal", f), f.source))
            theirs.append(matched_accuracy(label(tmp_path, "cdif", f), f.source))
    assert np.mean(ours) >= np.mean(theirs) + 0.05, (ours, theirs)

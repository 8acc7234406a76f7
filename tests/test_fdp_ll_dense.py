"""fdp-ll when the priors state no widths (`FDPLikelihood`): files from the independent generator
(tests/independent_gen.py) whose priors give periods, phases and jitter but no period or phase deviations,
labelled through `deint label`, so the parser's 5 % guess applies.  Counted in full, those guessed
deviations make the young sources' predictions several time units wide in a dense file (a pulse every 2
units): which of them takes a pulse is decided by log S rather than by the error, a long-period source
learns a wrong period and every track is lost within ~80 pulses (on the file below, fdp-ll 0.15 with the
full likelihood, 0.92 now, fdp 0.91).  fdp-ll therefore counts S as at most 2.5 R while the widths are
guessed.  Stated widths keep the full likelihood (where they are true, as in core-v0's 8-source
spread-16 scenes, its weighting is what lets fdp-ll start where fdp does not): the switch is checked on
its own, and the capped cost keeps the compiled core labelling as the numpy form."""

from __future__ import annotations

import numpy as np

from baselines.fdp import _widths_guessed
from deint_env import simulate
from deint_env.episode import Priors
from deint_env.suites import find_entry
from independent_gen import label_cli, make_cell, priors_json, run_cell, write_cell


def test_fdp_ll_keeps_its_tracks_on_a_dense_start(tmp_path):
    """16 sources, jitter 0.01 of the shortest period, rates unknown, 800 pulses (generator seed 101):
    fdp-ll labels as well as fdp (within 0.02)."""
    acc = run_cell(tmp_path, 16, 0.01, "unknown", 800, 101, ("fdp", "fdp-ll"))
    assert acc["fdp-ll"] >= acc["fdp"] - 0.02, acc


def test_only_a_file_stating_no_widths_has_guessed_widths():
    """The cap applies to the parser's 5 % guess only: a file stating either deviation, and a
    simulated episode's priors (which state their widths), keep the full likelihood."""
    base = {"period": [12.0, 30.0], "phase": [1.0, 5.0], "jitter_std": 0.1}
    assert _widths_guessed(Priors.from_json_dict(base))
    assert _widths_guessed(Priors.from_json_dict({"period": [12.0, 30.0]}))  # phases unknown
    assert not _widths_guessed(Priors.from_json_dict(base | {"period_std": [0.1, 0.3]}))
    assert not _widths_guessed(Priors.from_json_dict(base | {"phase_std": [0.2, 0.2]}))
    ep = simulate(find_entry("core-v0/core-n8-spread16-jitter0.2").spec.replace(n_pulses=50), 99000)
    assert not _widths_guessed(ep.priors)


def test_capped_likelihood_labels_as_the_numpy_form(tmp_path):
    """With guessed widths (the cap in force) the compiled core still labels as the numpy form, bit for bit."""
    cell = make_cell(5, 0.01, "unknown", 300, 102)
    pulses, priors = write_cell(tmp_path, cell, priors_json(cell, "unknown", 102))
    compiled = label_cli(tmp_path, pulses, priors, "fdp-ll")
    np.testing.assert_array_equal(label_cli(tmp_path, pulses, priors, "fdp-ll:engine=numpy"), compiled)

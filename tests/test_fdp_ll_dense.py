"""fdp-ll on a dense 16-source file from the independent generator (tests/independent_gen.py), labelled
through `deint label`.  Its likelihood cost e^2/S + log S loses every track in the first ~60 pulses: the
young sources' predictions are several time units wide (the priors' 5 % default deviations, with a pulse
every 2 units), so which of them takes which pulse is decided by their log S rather than their errors, a
long-period source learns a wrong period, and its pulses go to others.  Counting S as at most 9 R fixes
this file (0.93) but costs core-v0's 8-source spread-16 scenes whole episodes (there the priors' widths are
true and the weighting is what lets fdp-ll start where fdp does not), so the cost is unchanged for now."""

from __future__ import annotations

import pytest

from independent_gen import run_cell


@pytest.mark.slow  # 11 s for a known failure: it runs with the slow checks
@pytest.mark.xfail(strict=True, reason="fdp-ll loses every track at the start of dense 16-source files (above)")
def test_fdp_ll_keeps_its_tracks_on_a_dense_start(tmp_path):
    """16 sources, jitter 0.01 of the shortest period, rates unknown, 800 pulses (generator seed 101)."""
    acc = run_cell(tmp_path, 16, 0.01, "unknown", 800, 101, ("fdp", "fdp-ll"))
    assert acc["fdp-ll"] >= acc["fdp"] - 0.02, acc

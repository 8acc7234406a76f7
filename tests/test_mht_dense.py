"""mht's start on dense scenes from the independent generator (tests/independent_gen.py, issue #22): 16
constant-PRI sources, periods log-uniform in [12, 160], white jitter 0.03 of the shortest period, the
rates left out of the priors.

The first arrivals' gates there hold 10-12 pulses on average, below the joint start's old threshold
(`dense` 12).  The beam's own start then let a slow track take every m-th pulse of a faster source
whose pulse fell in its first gate (generator seed 110: a track of prior period 32.8 on the second
harmonic of a 14.34 train, one of 43.1 on a 22.3 train's); the fast tracks were left without pulses,
never restarted, and their pulses went spurious.  Labels right, mht (dense=12) / mht / fdp / genie:
seed 108 0.349 / 0.809 / 0.768 / 0.826, seed 110 0.408 / 0.828 / 0.820 / 0.847.  Generator seeds
>= 100 (seeds 1-3 are the issue's acceptance check).
"""

from __future__ import annotations

import pytest

from independent_gen import run_cell


@pytest.mark.parametrize("seed", [108, 110])
def test_slow_tracks_do_not_take_a_fast_sources_harmonic_in_a_dense_start(tmp_path, seed):
    acc = run_cell(tmp_path, 16, 0.03, "unknown", 2000, seed, ("mht",))
    assert acc["mht"] >= acc["genie"] - 0.05, acc


def test_a_track_lost_in_a_dense_scene_is_picked_up_again_when_the_rates_are_estimated(tmp_path):
    """8 sources, jitter 0.06 of the shortest period, the rates left out of the priors (generator seed 105):
    a track (period 20.46) lost after its first 12 pulses stayed lost -- a hit after a long silence or a
    restart paid log p_gap (p_gap 1e-6) at once where a spurious call paid ~-7 nats, and its pulses went
    spurious: 0.671 of the labels right, fdp 0.811.  With a rate estimated p_gap is floored at 1e-2
    (`_GAP_ESTIMATED`): the track takes its source's pulses again four arrivals later (0.809 of the labels
    right).  mht must stay within 0.01 of fdp (issue #22's acceptance) on this file."""
    acc = run_cell(tmp_path, 8, 0.06, "unknown", 2000, 105, ("fdp", "mht"))
    assert acc["mht"] >= acc["fdp"] - 0.01, acc


@pytest.mark.parametrize("seed, rates", [(123, "unknown"), (107, "zero"), (128, "unknown")])
def test_a_joint_start_keeps_each_track_on_its_own_train(tmp_path, seed, rates):
    """16 sources, jitter 0.03, a clean channel (mht version 8 / 9 / fdp, labels right).  Seeds 123 and
    107: at the clean channel's estimated (or stated) miss probability, ~1e-3, a chain whose pulse an
    earlier track had taken hopped onto a neighbour's train rather than skip the arrival, and tracks
    started on each other's trains (seed 123: the tracks of 21.24 and 19.35 swapped, the 45.31 track took
    a 19.35 train's second harmonic): 0.557 / 0.797 / 0.787, seed 107 (rates stated 0) 0.522 / 0.802 /
    0.122.  `MHT._joint_start` starts them at that q and at 5 % and keeps the likelier labelling of the
    buffered start.  Seed 128: the 36.89 track's chain began on its source's first pulse and went on along
    the 34.17 train, the 34.17 track's along the 36.89 train, and their first pulses lay outside each
    other's gates, so the pair was never re-started: 0.746 / 0.850 / 0.817 (`start._crossed`)."""
    acc = run_cell(tmp_path, 16, 0.03, rates, 2000, seed, ("fdp", "mht"))
    assert acc["mht"] >= max(acc["fdp"] - 0.01, acc["genie"] - 0.05), acc


@pytest.mark.parametrize("seed", [119, 122])
def test_a_few_sources_first_pulses_do_not_start_a_slow_track_on_a_harmonic(tmp_path, seed):
    """8 sources, jitter 0.06 of the shortest period, rates left out (mht version 9 / 10 / fdp, labels
    right).  The first arrivals' gates hold ~5 pulses, below the old joint-start threshold (`dense` 8), so
    the beam's own start ran alone; seed 119: the track of prior period 99.1 took the 51.6 train's first
    pulse and then its every other pulse, and its own source's pulses went spurious (0.801 / 0.835 / 0.812);
    seed 122: the 125.7 track was lost at the start (0.778 / 0.806 / 0.797).  Joint starts are now tried
    from gates of 3 pulses, beside the beam's own start, and the likeliest window wins (`MHT._joint_start`)."""
    acc = run_cell(tmp_path, 8, 0.06, "unknown", 2000, seed, ("fdp", "mht"))
    assert acc["mht"] >= acc["fdp"] - 0.01, acc


def test_the_beams_own_start_stays_a_candidate_below_crowded(tmp_path):
    """8 sources, jitter 0.03, rates left out (generator seed 103): the joint starts alone label 0.561
    (`mht:crowded=0`), the beam's own start 0.892 (fdp 0.890); the window's likelihood picks the own start."""
    acc = run_cell(tmp_path, 8, 0.03, "unknown", 2000, 103, ("fdp", "mht", "mht:crowded=0"))
    assert acc["mht"] >= acc["fdp"] - 0.01, acc
    assert acc["mht:crowded=0"] < acc["mht"] - 0.1, acc  # the case is one where the choice matters

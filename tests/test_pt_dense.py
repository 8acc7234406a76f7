"""pt-post's start on a dense scene from the independent generator (tests/independent_gen.py, issue #22),
labelled through `deint label`: 8 constant-PRI sources, periods log-uniform in [12, 160], white jitter
0.01 of the shortest period, the true phases and the rates stated 0 (the published PT, no remedies).

With the priors' default phase deviation (5 % of the period) the first arrivals fall in each other's
gates: along the true labelling the true source is not the likeliest at 3 of the start's 62 pulses
(two longest periods), and the teacher draws all 62 right with probability 4e-4.  A wrong draw put the
tracks on other sources' pulses for good: 0.09 of these 800 labels right (fdp 0.98).  pt-post now
acquires by the start beam's MAP decisions, as `dokf` does, before the teacher takes over: 0.94.
Generator seeds >= 100 (seeds 1-3 are the issue's acceptance check).

At jitter 0.06 the start is acquired but single draws after it lose tracks for good (module doc of
baselines/pt.py, 'Particles'): 32 teachers resampled by how well they predict keep them, if each can
coast a track that another of its tracks robbed (version 5).
"""

from __future__ import annotations

from independent_gen import run_cell


def test_pt_post_acquires_8_dense_sources(tmp_path):
    acc = run_cell(tmp_path, 8, 0.01, "zero", 800, 101, ("fdp", "pt-post"))
    assert acc["fdp"] > 0.8, acc
    assert acc["pt-post"] >= 0.5, acc


def test_pt_post_particles_hold_8_jittery_sources(tmp_path):
    acc = run_cell(tmp_path, 8, 0.06, "zero", 800, 103, ("fdp", "pt-post", "pt-post:particles=1"))
    assert acc["pt-post:particles=1"] < 0.5, acc  # the published PT, one teacher, collapses on this file
    assert acc["pt-post"] >= 0.65, acc  # 0.70 measured (fdp 0.77)


def test_pt_post_particles_coast_robbed_tracks_on_a_clean_channel(tmp_path):
    """Validation file 122, rates stated 0: without coasting (version 4's particles on a clean channel) a
    track robbed of a pulse in a burst of near-coincident pulses predicts the lost pulse for good, every
    particle comes to carry one and the labels collapse (0.230, fdp 0.797); version 5's particles coast
    them, at log q (q floored at 0.001) an arrival: 0.694."""
    acc = run_cell(tmp_path, 8, 0.06, "zero", 2000, 122, ("pt-post:coast=false", "pt-post"))
    assert acc["pt-post:coast=false"] < 0.5, acc
    assert acc["pt-post"] >= 0.65, acc

"""The survivor rule of MK94's FDP (3.2), shared by the beam searches (baselines/mht, agents/beam_kernels.py):
two hypotheses whose tracks all last fired on the same pulses continue alike up to their estimates, so only
the better is kept."""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, inline="always")
def same_last(last_a, a, last_b, b, now):
    """Whether two children have every track's last pulse in common: child A is the parent with tracks'
    last pulses `last_a` whose track `a` took the pulse `now` (any other `a`: none did), child B likewise.
    Pulses are whatever the caller keys them by (an index, a time), compared exactly."""
    for i in range(last_a.shape[0]):
        x = now if i == a else last_a[i]
        y = now if i == b else last_b[i]
        if x != y:
            return False
    return True

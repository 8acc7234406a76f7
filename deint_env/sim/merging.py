"""Merging: pulses closer than the receiver's coincidence resolution to their predecessor become one
pulse (MK94 II-A): the earlier TOA, summed amplitude, every source in the bit mask."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class MergedRow(NamedTuple):
    """One episode's output rows that `merge` fills in place."""

    toa: np.ndarray
    source: np.ndarray
    mask: np.ndarray
    amplitude: np.ndarray | None


def merge(toa, src, bits, amp, starts, out: MergedRow) -> None:
    """Merge each run of pulses closer than the resolution to their predecessor (group `starts`)
    into the rows of `out`.

    Merged runs are rare, so the work is a gather at the run starts plus scatters of the few others.
    """
    out_toa, primary, mask, out_amp = out.toa, out.source, out.mask, out.amplitude
    is_start = np.zeros(toa.size, bool)
    is_start[starts] = True
    rest = np.flatnonzero(~is_start)
    group = np.searchsorted(starts, rest, side="right") - 1
    # (The run starts are valid indices; mode="clip" spares np.take the buffered copy of `out`.)
    np.take(toa, starts, out=out_toa, mode="clip")
    np.take(bits, starts, out=mask, mode="clip")
    np.bitwise_or.at(mask, group, bits[rest])
    if amp is not None:
        np.take(amp, starts, out=out_amp, mode="clip")
        np.add.at(out_amp, group, amp[rest])  # energies add (MK94 II-A)
    np.take(src, starts, out=primary, mode="clip")
    # A run led by a spurious pulse takes its first real member as its primary source.
    real = src[rest] >= 0
    led_by_spurious = primary[group[real]] < 0
    if led_by_spurious.any():
        g, members = group[real][led_by_spurious], rest[real][led_by_spurious]
        _, first = np.unique(g, return_index=True)
        primary[g[first]] = src[members[first]]

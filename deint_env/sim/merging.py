"""Merging: pulses closer than the receiver's coincidence resolution to their predecessor become one
pulse (MK94 II-A): the earlier TOA, summed amplitude, every source in the bit mask."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from deint_env.sim.rows import take_rows


class MergedRow(NamedTuple):
    """One episode's output rows that `merge` fills in place."""

    toa: np.ndarray
    source: np.ndarray
    mask: np.ndarray
    amplitude: np.ndarray | None
    descriptors: tuple[np.ndarray, ...] = ()


def merge(toa, src, bits, amp, starts, out: MergedRow, descriptors: tuple[np.ndarray, ...] = ()) -> None:
    """Merge each run of pulses closer than the resolution to their predecessor (group `starts`)
    into the rows of `out`; a merged pulse keeps its leading pulse's `descriptors` (frequency, ...),
    as it keeps its TOA.

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
    for values, kept in zip(descriptors, out.descriptors):
        np.take(values, starts, out=kept, mode="clip")
    np.take(src, starts, out=primary, mode="clip")
    # A run led by a spurious pulse takes its first real member as its primary source.
    real = src[rest] >= 0
    led_by_spurious = primary[group[real]] < 0
    if led_by_spurious.any():
        g, members = group[real][led_by_spurious], rest[real][led_by_spurious]
        _, first = np.unique(g, return_index=True)
        primary[g[first]] = src[members[first]]


def merge_at_emission(y: np.ndarray, noise_free: np.ndarray, resolution: float) -> None:
    """MK94's merging (`ScenarioSpec.merge == "emission"`): pulses whose noise-free arrival times are
    closer than `resolution` to their predecessor's arrive as one pulse, at the received TOA of the
    run's earliest arrival.  Every member of a run takes that TOA (in `y`, in place), so after the
    sort `merge` joins exactly the tied pulses (the lowest-numbered source leads a run)."""
    order = np.argsort(noise_free, axis=1, kind="stable")
    t = take_rows(noise_free, order)
    joins = np.zeros(t.shape, bool)
    with np.errstate(invalid="ignore"):  # inf - inf in the padding
        joins[:, 1:] = np.diff(t, axis=1) < resolution
    if joins.any():
        lead = np.where(joins, 0, np.arange(t.shape[1]))  # each pulse's run start, in sorted position
        np.maximum.accumulate(lead, axis=1, out=lead)
        rows = np.arange(y.shape[0])[:, None]
        y[rows, order] = y[rows, np.take_along_axis(order, lead, axis=1)]

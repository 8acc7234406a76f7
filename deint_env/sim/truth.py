"""What an episode's truth holds: each source's parameters and schedule trimmed to the episode, and
the pulses received from each."""

from __future__ import annotations

import numpy as np

from deint_env.episode import Truth


def truths(period, phase, sched_t, sched_pri, rows, t_end, source, mask, merged: bool) -> list[Truth]:
    """The truth of the finished `rows` (pulses `source`, `mask`; `merged`: whether any pulse merged):
    each source's schedule trimmed to the episode, plus the margin a late, jittered pulse needs
    (`t_end` per row of the batch)."""
    n_done, k = period.shape
    # A prefix of each source's time-ordered schedule; gathering the prefixes row by row copies only
    # what is kept (a vectorised gather would read the padding too, about as much again).
    counts = np.array([(t <= t_end[:, None]).sum(axis=1)[rows] for t in sched_t]).T  # (rows, sources)
    final = np.full((n_done, k), np.nan)
    for i, (p, c) in enumerate(zip(sched_pri, counts.T)):
        some = c.nonzero()[0]
        final[some, i] = p[rows[some], c[some] - 1]
    offsets = np.zeros((n_done, k + 1), np.int64)
    np.cumsum(counts, axis=1, out=offsets[:, 1:])

    # Received pulses per (row, source): one bincount over row-offset sources (-1, spurious, -> column 0).
    offset = (np.arange(n_done, dtype=np.int64) * (k + 1) + 1)[:, None]
    n_received = np.bincount((source + offset).ravel(), minlength=n_done * (k + 1)).reshape(n_done, k + 1)[:, 1:]
    n_received = np.ascontiguousarray(n_received, dtype=np.int64)
    multi = np.bitwise_and(mask, mask - np.uint64(1)) != 0 if merged else None  # more than one bit set
    if merged and multi.any():  # a merged pulse also counts for its other sources
        per_row = multi.sum(axis=1)
        some = per_row.nonzero()[0]
        first = (np.cumsum(per_row) - per_row)[some]  # where each row's merged pulses start, row-major
        m_mask, m_src = mask[multi], source[multi]
        for i in range(k):
            member = (np.right_shift(m_mask, np.uint64(i)) & np.uint64(1)).astype(bool) & (m_src != i)
            n_received[some, i] += np.add.reduceat(member, first, dtype=np.int64)
    return [Truth(period=per, phase=ph, final_period=fin, n_received=rec,
                  schedule_toa=np.concatenate([t[r, :c] for t, c in zip(sched_t, row)]),
                  schedule_pri=np.concatenate([p[r, :c] for p, c in zip(sched_pri, row)]), schedule_offsets=off)
            for per, ph, fin, rec, off, r, row in zip(period, phase, final, n_received, offsets, rows.tolist(),
                                                      counts.tolist())]

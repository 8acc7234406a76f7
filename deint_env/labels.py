"""When is a label right?  One set of rules for the envs (rewards) and the metrics (scores).

Anchored mode: label i < n_labels names prior track i, which is true source i; label n_labels means
"spurious".  A merged pulse is right under any of its sources; a spurious pulse only under "spurious".

Blind (link) mode: a label names the pulse's predecessor, the last earlier pulse given the same
label ("none" if the label is new).  It is right when that is the true predecessor of the pulse in
one of its sources (the last earlier pulse containing that source, or "none" for the source's first
pulse); a spurious pulse is right only when labelled spurious.  Permutation-free and dense.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NO_PRED = -1  # "no predecessor": the first pulse of a source, or a label's first use
SPURIOUS_PRED = -2  # the pulse was labelled spurious: it links to nothing


def source_bits(source: np.ndarray) -> np.ndarray:
    """The uint64 membership mask of unmerged pulses: bit i for source i < 64; 0 for a spurious pulse
    and for sources 64 and up (which never merge, so their `source` names them)."""
    s = np.asarray(source, dtype=np.int64)
    bit = (s >= 0) & (s < 64)
    return np.where(bit, np.left_shift(np.uint64(1), np.where(bit, s, 0).astype(np.uint64)), np.uint64(0))


def correct_anchored(labels: np.ndarray, source: np.ndarray, mask: np.ndarray, spurious_label: int) -> np.ndarray:
    """Boolean array: is each anchored label right?  (Sources 64 and up have no mask bit and never
    merge: their pulses are right under their primary source.)"""
    lab = np.asarray(labels, dtype=np.int64)
    bit = (lab >= 0) & (lab < min(spurious_label, 64))
    shift = np.where(bit, lab, 0).astype(np.uint64)
    has_bit = (np.right_shift(mask, shift) & np.uint64(1)).astype(bool)
    primary = (lab >= 64) & (lab < spurious_label) & (lab == source)
    return np.where(lab == spurious_label, source < 0, (bit & has_bit) | primary)


@dataclass(frozen=True, eq=False)
class TruePredecessors:
    """Each pulse's true predecessor(s); merged pulses may have one per member source.

    pred[j]: the predecessor of pulse j in its primary source (NO_PRED for a source's first pulse,
    SPURIOUS_PRED for a spurious pulse).  alt_pulse / alt_pred: further valid predecessors of merged
    pulses, one row per extra member source, sorted by pulse.
    """

    pred: np.ndarray
    alt_pulse: np.ndarray
    alt_pred: np.ndarray

    def alternatives(self) -> dict[int, set[int]]:
        out: dict[int, set[int]] = {}
        for j, p in zip(self.alt_pulse.tolist(), self.alt_pred.tolist()):
            out.setdefault(j, set()).add(p)
        return out


def true_predecessors(source: np.ndarray, mask: np.ndarray) -> TruePredecessors:
    n = source.size
    real = np.flatnonzero(source >= 0)
    pulse, src = real, source[real].astype(np.int64)
    multi = np.flatnonzero(np.bitwise_and(mask, mask - np.uint64(1)) != 0)
    extra_pulse, extra_src = [], []
    for i in range(64 if multi.size else 0):
        has = (np.right_shift(mask[multi], np.uint64(i)) & np.uint64(1)).astype(bool) & (source[multi] != i)
        extra_pulse.append(multi[has]), extra_src.append(np.full(int(has.sum()), i))
    n_primary = pulse.size
    if extra_pulse:
        pulse = np.concatenate([pulse, *extra_pulse])
        src = np.concatenate([src, *extra_src])
    # Within each source, pairs in time order: a pair's predecessor is the pair before it.
    order = np.lexsort((pulse, src))
    s_sorted, p_sorted = src[order], pulse[order]
    prev = np.full(pulse.size, NO_PRED, dtype=np.int64)
    same = s_sorted[1:] == s_sorted[:-1]
    prev[order[1:][same]] = p_sorted[:-1][same]
    pred = np.full(n, SPURIOUS_PRED, dtype=np.int64)
    pred[pulse[:n_primary]] = prev[:n_primary]
    alt_pulse, alt_pred = pulse[n_primary:], prev[n_primary:]
    srt = np.argsort(alt_pulse, kind="stable")
    return TruePredecessors(pred=pred, alt_pulse=alt_pulse[srt], alt_pred=alt_pred[srt])


def label_predecessors(labels: np.ndarray, spurious_label: int) -> np.ndarray:
    """The predecessor each label names: the last earlier pulse with the same label."""
    lab = np.asarray(labels, dtype=np.int64)
    order = np.argsort(lab, kind="stable")  # grouped by label, time order kept within a group
    sl = lab[order]
    prev = np.full(lab.size, NO_PRED, dtype=np.int64)
    same = sl[1:] == sl[:-1]
    prev[order[1:][same]] = order[:-1][same]
    prev[lab == spurious_label] = SPURIOUS_PRED
    return prev


def correct_link(labels: np.ndarray, source: np.ndarray, mask: np.ndarray, spurious_label: int,
                 truth: TruePredecessors | None = None) -> np.ndarray:
    """Boolean array: does each label name the right predecessor (blind-mode reward)?"""
    truth = truth or true_predecessors(source, mask)
    named = label_predecessors(labels, spurious_label)
    ok = named == truth.pred  # a spurious pulse is right iff named SPURIOUS_PRED, i.e. labelled spurious
    if truth.alt_pulse.size:  # .at: a pulse merged from 3+ sources has several alternatives
        np.logical_or.at(ok, truth.alt_pulse, named[truth.alt_pulse] == truth.alt_pred)
    return ok

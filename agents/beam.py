"""Beam decoding of a learned track agent: the network's log-probabilities summed over label
sequences, searched with a beam and fixed-lag decisions (as sequence models are decoded).

A hypothesis is one labelling of the pulses so far, held as one row of a `TrackFeatures` (its own
track anchors, period estimates, counts, amplitude means); its score is the sum of the network's
log-probabilities of its labels, each computed from that hypothesis's own features.  For every pulse
each of the (at most) B hypotheses is extended by every label the scenario has (its tracks and
spurious), and the B best distinct extensions survive.  Two extensions are the same hypothesis for
the future when every track last fired on the same pulse (equal anchors): only the better is kept.
The label of a pulse is decided `decision_lag` pulses after it is first scored (the best hypothesis's
label), and hypotheses that labelled it otherwise are dropped, so the policy's lag is the network's
look-ahead plus `decision_lag`.  `beam=1` is the greedy agent with its labels delayed.

Every score comes from the checkpoint's network (`agents.fast_net`, numpy); nothing here models
pulses by hand.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.features import TrackFeatures, TrackLayout

VERSION = 1  # bumped whenever the decoder's labels change for the same network
# The per-hypothesis state of TrackFeatures (everything else is the same in every row: priors and
# the pulse window), reordered when hypotheses are extended.
_HYPOTHESIS_STATE = ("period", "anchor", "count", "span_time", "span_periods", "amp_mean")


class BeamDecoder:
    """Beam search over one episode's labels (module doc).  `start(priors, has_amplitude)`, then per
    raw observation `step(toa, amp, valid)` -> the decided label (token index: a track < n, or n =
    spurious) of the oldest undecided pulse, or None while nothing is decided yet."""

    def __init__(self, net: Any, layout: TrackLayout, beam: int, decision_lag: int):
        if isinstance(beam, bool) or not isinstance(beam, (int, np.integer)) or not 1 <= beam <= 256:
            raise DeintError(f"beam={beam!r} is invalid: an integer in [1, 256]")
        if (isinstance(decision_lag, bool) or not isinstance(decision_lag, (int, np.integer))
                or not 0 <= decision_lag <= 1000):
            raise DeintError(f"decision_lag={decision_lag!r} is invalid: an integer in [0, 1000]")
        self.net, self.layout = net, layout
        self.beam, self.decision_lag = int(beam), int(decision_lag)
        self.feats = TrackFeatures(self.beam, layout)
        self.pending = np.zeros((self.beam, self.decision_lag + 1), np.int64)  # undecided labels per hypothesis
        self.n_pending = 0
        self.alive = 1
        self.score = np.zeros(self.beam)
        self.n = 0

    def start(self, priors: Priors, has_amplitude: bool) -> None:
        if priors.blind:
            raise NotApplicable("the beam decoder plays anchored scenarios (blind ones have no prior tracks)")
        if priors.n_labels > self.layout.max_tracks:
            raise NotApplicable(f"the agent holds at most {self.layout.max_tracks} tracks; this scenario has "
                                f"{priors.n_labels}")
        self.feats.reset_rows(np.arange(self.beam), [priors] * self.beam, [has_amplitude] * self.beam)
        self.n = priors.n_labels
        self.n_pending, self.alive = 0, 1
        self.score[:] = 0.0

    def step(self, toa: float, amp: float, valid: bool) -> int | None:
        f = self.feats
        f.observe(np.full(self.beam, toa), np.full(self.beam, amp), np.full(self.beam, bool(valid)))
        if f.ready[0]:
            self._extend()
            if self.n_pending > self.decision_lag:
                return self._decide()
            return None
        return self._decide() if self.n_pending else None

    def _extend(self) -> None:
        f, k, n = self.feats, self.alive, self.n
        tracks, pulse = f.arrays()
        logp = self.net.log_probs(tracks[:k, :n], pulse[:k])  # (k, n + 1), column n = spurious
        cand = (self.score[:k, None] + logp).ravel()
        order = np.argsort(-cand, kind="stable")
        parent, label = np.divmod(order, n + 1)
        if k * (n + 1) > 1 and self.beam > 1:
            # Dedup: an extension's future depends on when each of its tracks last fired.
            key = f.anchor[parent, :n].copy()
            hit = label < n
            key[hit, label[hit]] = f.win_toa[0, 1]
            _, first = np.unique(key, axis=0, return_index=True)
            keep = np.sort(first)[:self.beam]  # first occurrences in score order: the best of each group
            parent, label = parent[keep], label[keep]
            new_score = cand[order[keep]]
        else:
            parent, label = parent[:self.beam], label[:self.beam]
            new_score = cand[order[:self.beam]]
        m = len(parent)
        for name in _HYPOTHESIS_STATE:
            a = getattr(f, name)
            a[:m] = a[parent]
        self.pending[:m] = self.pending[parent]
        self.pending[:m, self.n_pending] = label
        self.n_pending += 1
        self.score[:m] = new_score - new_score[0]  # relative to the best, so sums never drift
        self.alive = m
        actions = np.full(self.beam, self.layout.max_tracks, np.int64)  # rows beyond the beam: no track
        actions[:m] = np.where(label < n, label, self.layout.max_tracks)
        f.label(actions)

    def _decide(self) -> int:
        """The best hypothesis's label of the oldest undecided pulse; hypotheses disagreeing are dropped."""
        k = self.alive
        decided = int(self.pending[0, 0])
        keep = np.flatnonzero(self.pending[:k, 0] == decided)
        if len(keep) < k:
            m = len(keep)
            for name in _HYPOTHESIS_STATE:
                a = getattr(self.feats, name)
                a[:m] = a[keep]
            self.pending[:m] = self.pending[keep]
            self.score[:m] = self.score[keep]
            self.alive = m
        self.pending[:, :-1] = self.pending[:, 1:]
        self.n_pending -= 1
        return decided

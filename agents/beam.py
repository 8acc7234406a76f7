"""Beam decoding of a learned track agent: the network's log-probabilities summed over label
sequences, searched with a beam and fixed-lag decisions (as sequence models are decoded).

A hypothesis is one labelling of the pulses so far, held as one row of a `TrackFeatures` (its own
track anchors, period estimates, counts, amplitude means); its score is the sum of the network's
log-probabilities of its labels, each computed from that hypothesis's own features.  For every pulse
each of the (at most) B hypotheses is extended by every label the scenario has (its tracks and
spurious), and the B best distinct extensions survive.  Two extensions are the same hypothesis for
the future when every track last fired on the same pulse (equal anchors): with `merge` (the default)
only the better is kept, which spends the beam on different futures rather than on relabellings of
spurious pulses or on period estimates that differ in the last digits.
The label of a pulse is decided `decision_lag` pulses after it is first scored (the best hypothesis's
label), and hypotheses that labelled it otherwise are dropped, so the policy's lag is the network's
look-ahead plus `decision_lag`.  `beam=1` is the greedy agent with its labels delayed.  With `consistency` = w > 0 a hypothesis is
ranked by its summed log-probabilities plus w times the log-probability, from the network's value
head, that its state is still consistent (what DAgger's consistency loss trains, agents.imitation):
a locally normalised score alone cannot tell a hypothesis that has gone wrong, since each step's
probabilities sum to one whatever the state.

Every score comes from the checkpoint's network (`agents.fast_net`, one numba call per pulse); nothing here models
pulses by hand.  The hypotheses' feature state lives in a `TrackFeatures` (its rows), updated by the
numba kernels of `agents.beam_kernels`, which compute what `TrackFeatures` does, pulse by pulse.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agents.beam_kernels import extend, keep_rows, select, token_arrays
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.features import TrackFeatures, TrackLayout

VERSION = 2  # bumped whenever the decoder's labels change for the same network


class BeamDecoder:
    """Beam search over one episode's labels (module doc).  `start(priors, has_amplitude)`, then per
    raw observation `step(toa, amp, valid)` -> the decided label (token index: a track < n, or n =
    spurious) of the oldest undecided pulse, or None while nothing is decided yet."""

    def __init__(self, net: Any, layout: TrackLayout, beam: int, decision_lag: int, merge: bool = True,
                 consistency: float = 0.0):
        if isinstance(beam, bool) or not isinstance(beam, (int, np.integer)) or not 1 <= beam <= 4096:
            raise DeintError(f"beam={beam!r} is invalid: an integer in [1, 4096]")
        if (isinstance(decision_lag, bool) or not isinstance(decision_lag, (int, np.integer))
                or not 0 <= decision_lag <= 1000):
            raise DeintError(f"decision_lag={decision_lag!r} is invalid: an integer in [0, 1000]")
        # every pulse copies the beam's undecided labels: beam=4096 with decision_lag=1000 (32 MB a pulse) ran 500
        # pulses for over 60 s; 2^20 labels take ~40 ms a pulse
        if beam * (decision_lag + 1) > 2**20:
            raise DeintError(f"beam={beam} with decision_lag={decision_lag} is invalid: beam * (decision_lag + 1) "
                             f"at most 2^20 (the undecided labels every pulse copies)")
        self.net, self.layout = net, layout
        self.beam, self.decision_lag, self.merge = int(beam), int(decision_lag), bool(merge)
        self.consistency = float(consistency)
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
        f, k, n, lay = self.feats, self.alive, self.n, self.layout
        tracks, pulse = token_arrays(f.period, f.anchor, f.count, f.amp_mean, f.amp_scale, f.prior_period, k, n,
                                     f.win_toa[0], f.win_amp[0], f.first_toa[0], int(f.labelled[0]), f.scalars[0],
                                     bool(f.has_amp[0]), lay.version, lay.max_tracks, lay.lookahead)
        logp, consistent = self.net.beam_scores(tracks, pulse)  # (k, n + 1), column n = spurious; (k,)
        t, amp = f.win_toa[0, 1], f.win_amp[0, 1]
        cum = self.score[:k, None] + logp
        rank = cum + self.consistency * consistent[:, None] if self.consistency else cum
        parent, label, _ = select(rank, f.anchor, t, self.beam, self.merge and self.beam > 1)
        new_score = cum[parent, label]
        m = len(parent)
        self.pending[:m] = self.pending[parent]
        self.pending[:m, self.n_pending] = label
        self.n_pending += 1
        self.score[:m] = new_score - new_score.max()  # relative, so sums never drift
        self.alive = m
        extend(parent, label, n, t, amp, f.period, f.anchor, f.count, f.span_time, f.span_periods, f.amp_mean,
               f.prior_period)
        # The labelled pulse becomes every row's "previous" one (as TrackFeatures.label does).
        f.labelled += 1
        f.win_toa[:, 0] = t
        f.win_toa[:, 1] = np.nan

    def _decide(self) -> int:
        """The best hypothesis's label of the oldest undecided pulse; hypotheses disagreeing are dropped."""
        k = self.alive
        decided = int(self.pending[0, 0])
        keep = np.flatnonzero(self.pending[:k, 0] == decided)
        if len(keep) < k:
            f = self.feats
            keep_rows(keep, self.pending, self.score, f.period, f.anchor, f.count, f.span_time, f.span_periods,
                      f.amp_mean)
            self.alive = len(keep)
        self.pending[:, :-1] = self.pending[:, 1:]
        self.n_pending -= 1
        return decided

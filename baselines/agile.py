"""Trackers for agile PRIs: `agile-kf` (a model-bank Kalman tracker with MAP assignment, DM89 style)
and `renewal-ml` (Young et al.'s maximum-likelihood path search over renewal-process PRI models).

Both run the same hypothesis search on the PRI models of `baselines.pri_models` (linear-Gaussian
states on the shared Kalman core).  Each source carries a bank of models: the one its priors name
(`Priors.modulation`), or `pri_models.default_bank()` when they name none; the bank's model
probabilities are updated by each model's predictive likelihood of the pulses the source takes
(multiple-model adaptive estimation), with a switching probability `switch` mixed in every pulse
(IMM's Markov model switching, without its state mixing) so a source can move between models, as a
dwell-and-switch emitter does.  A source's predictive density for the next pulse is the mixture of
its models' Gaussian predictions.

A hypothesis is an assignment of every pulse so far to a source or to "spurious"; its cost is the
negative log-likelihood of the pulses under a mixture of renewal processes, as Young et al. set the
problem (each source's arrivals a renewal process observed with missing pulses, the spurious pulses a
Poisson process): the product over sources of their inter-arrival densities, times p_miss per
emission that went unreceived and (1 - p_miss) per received one, times the Poisson density lambda per
spurious pulse.  The paper's full text is not among the project's papers: this follows its model and
its maximum-likelihood labelling, not its equations one by one (its inter-arrival densities are here
the Gaussian predictions of the PRI state models, which makes a modulated source's intervals a
Markov-modulated rather than an i.i.d. renewal sequence; a random-level stagger's is its renewal
density itself, a mixture over runs of levels: `_Jumps`).  A source whose next emission is overdue at a
pulse (`kalman.overdue`'s MK94 VI-C-3 test on its best model; a bank of cycle offsets, when every credible offset
is overdue or a missed emission explains the pulse better) coasts: its models predict through the missed
emission, which costs -log p_miss.  A source of a named modulation that coasts through a run of arrivals longer
than `reset_after` and rarer than `_RESTART_TAIL` at the stated miss rate forks a hypothesis in which it starts
afresh (`_restart`: its bank back at the prior, its next emission within a PRI, every cycle position open, as a
source of unknown phase starts) beside the one that keeps its track, and the pulses decide.  A wobulation or ramp
that locked early on a wrong phase or cycle position (deviation 0.03-0.09, its own pulses 0.3-8 away) otherwise
called its own pulses spurious to the end: the four such files of the independent generator's seeds 1-2 (phases
unknown) had 0.52-0.77 of their labels right, 0.96-0.99 with the restart.  Restarting in place, without the
fork, cost a staggered file whose source had just missed five pulses in a row 0.99 -> 0.69; pricing the restart
as a model switch (-log `switch`, 4.6 nats) cost a wobulated file 0.985 -> 0.904.

- `agile-kf`: beam 1, lag 0: each pulse goes to the source (or spurious) of least cost, i.e. the MAP
  decision under the model-aware predictions, then that source's KF update: DM89's detect-then-filter.
- `renewal-ml`: Young et al.'s maximum-likelihood path search, here a beam search: the `beam` least-cost
  hypotheses survive each pulse (of those whose tracks agree, only the cheapest: `PathSearch._select`), and
  pulse k is labelled from the best hypothesis when pulse k + `lag` has arrived.  In blind mode (no priors, a
  label budget) the tracks are born from the pulses: a pulse may start a track (cost `birth`), a track's second
  pulse comes after an interval with a log-uniform prior over `pri_range` and starts its constant-PRI state, and
  from its third pulse on a track is predicted as in the anchored mode.  Without a stated TOA jitter it measures
  the white TOA noise and the PRI jitter from the pulses (`RenewalML._remeasure`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from baselines import pri_models
from baselines.kalman import LinearBlock, linear_innovation, linear_predict, linear_update
from baselines.pri_models import TAU, BankArrays
from deint_env.episode import MAX_MAGNITUDE, Priors
from deint_env.errors import DeintError, NotApplicable
from deint_env.params import Param, ParamSet, declare

_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
_MISS_FLOOR = 1e-3  # p_miss used for coasting when the priors say nothing is missed (a track can slip)
_MAX_COAST = 64
# blind renewal-ml's missing rate where nothing states it: with the floor's price (6.9 nats an emission) a
# track that misses two pulses is dearer than a new one, and with 32 free labels every gap starts a track
_UNSTATED_MISSING = 0.1
_LOG_2PI = math.log(2 * math.pi)
_JUMP_TAIL = 1e-4  # random-level sources: runs of missed emissions less likely than this are not scored
_JUMP_RUNS = 8  # ... nor longer than this many intervals (beyond them the source is reacquired)
_JUMP_COLUMNS = 4096  # ... nor more (level counts, last level) groups than this
# ... nor a search scoring more (hypotheses x levels x runs) terms a pulse than this: agile-v2's three random-level
# sources at the default beam score 5.8e5 (~8 ms a pulse); three sources of 64 levels 3.2e6 (~0.1 s a pulse: 200
# pulses in 20 s, loaded machine), beam=4096 over three 3-level sources 1.1e6 (~40 ms a pulse)
_JUMP_WORK = 2**20
# an offset bank's models this many nats below its best one's weight do not hold back its coasting (`_coast`)
_FAINT = 12.0
# a track restarts (`PathSearch._restart`) after a run of coasted arrivals less likely than this under the stated
# miss rate (and longer than `reset_after`): at 30 % missing, restarts after 5 in a row (p = 2.4e-3) cost agile-v2's
# mixed-heavy validation episodes 0.914 -> 0.907 and 0.959 -> 0.955 of their labels; after 6 (7e-4) they were
# as before.  1e-4 (6 and 8 in a row at 20 and 30 %) moved the six independent-generator files (seeds 1-2) the
# restart changes by 0.002 at most
_RESTART_TAIL = 1e-3


def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(top, axis) + np.log(np.exp(a - top).sum(axis=axis))


class _Jumps:
    """The random-level (`random_stagger`) sources of a search.  Their state (tau, T) in bank slot 0 is
    the source's last emission and period, never advanced; the next received pulse is scored by the
    renewal density of the level process (`pri_models.JumpLevels`), a mixture over the runs of r
    intervals to it (m = r - 1 emissions missed, each priced q = p_miss; m = r before the first pulse,
    whose run may be empty: the emission at the stated phase itself):

        p(y) = sum_runs P(run | s_last) q^m N(y; tau + T S, P_tt + 2 S P_tT + S^2 P_TT + r sigma_c^2 + R),

    S the run's length over T (its level ratios summed).  The pulse then updates (tau, T) along its
    likeliest run, and the last level's distribution (H, K) to its posterior."""

    def __init__(self, banks: list[tuple[pri_models.PRIModel, ...]], q: float):
        self.index = [i for i, b in enumerate(banks) if b[0].jumps is not None]
        runs = max(1, min(_JUMP_RUNS, math.ceil(math.log(_JUMP_TAIL) / math.log(q)) + 1))
        self.levels = [banks[i][0].jumps for i in self.index]
        self.columns = []
        for lv in self.levels:
            # many levels: fewer runs, so the mixture stays small.  Longer runs are tried from 1 up: their groups
            # multiply by up to the level count a run, so starting long built ~10^10 groups for 64 levels (hours)
            r, cols = 1, lv.sequences(1)
            while r < runs:
                longer = lv.sequences(r + 1)
                if longer[0].size > _JUMP_COLUMNS:
                    break
                r, cols = r + 1, longer
            self.columns.append(cols)
        self.reach = [float(c[0].max()) for c in self.columns]  # the longest run scored, over T
        self.log_q = math.log(q)
        self.last = [np.log(lv.start)[None] for lv in self.levels]  # (H, K): log P(last interval's level)
        self.fresh = np.ones((1, len(self.index)), dtype=bool)  # no pulse taken: tau is the first emission

    def take(self, h: np.ndarray) -> None:
        self.last = [a[h] for a in self.last]
        self.fresh = self.fresh[h]

    def mixture(self, x: np.ndarray, p: np.ndarray, y: float, r: float, interval_var: float) -> list[np.ndarray]:
        """Per random-level source, log(P(run) q^m N(y; ...)) of each run (H, C), from the slot-0
        states x (H, J, D+1) and p (H, J, D+1, D+1)."""
        out = []
        for j, (s, runs, _, logp) in enumerate(self.columns):
            tau, t = x[:, j, TAU, None], x[:, j, 1, None]
            var = (p[:, j, TAU, TAU, None] + 2 * s * p[:, j, TAU, 1, None] + s * s * p[:, j, 1, 1, None]
                   + runs * interval_var + r)
            ll = -0.5 * (_LOG_2PI + np.log(var) + (y - tau - s * t) ** 2 / var)
            fresh = self.fresh[:, j, None]
            w = _logsumexp(self.last[j][:, :, None] + logp[None], axis=1) + (runs - 1 + fresh) * self.log_q
            out.append(ll + np.where((runs == 0) & ~fresh, -np.inf, w))
        return out

    def update(self, j: int, rows: np.ndarray, scores: np.ndarray, state: LinearBlock, y: float, r: float,
               interval_var: float) -> LinearBlock:
        """Source j takes the pulse y in hypotheses `rows` (scores: their runs' (R, C)); returns its
        updated slot-0 states (R, D+1[, D+1])."""
        s, runs, last, _ = self.columns[j]
        best = np.argmax(scores, axis=1)
        d = state.x.shape[-1]
        f = np.broadcast_to(np.eye(d), (rows.size, d, d)).copy()
        f[:, TAU, 1] = s[best]
        q = np.zeros((rows.size, d, d))
        q[:, TAU, TAU] = runs[best] * interval_var
        pred = linear_predict(state, f, q)
        e, var = linear_innovation(pred, y, TAU, r)
        upd = linear_update(pred, e, var, TAU, r)
        k = self.last[j].shape[1]
        post = np.stack([_logsumexp(np.where((last == b) & (runs > 0), scores, -np.inf), axis=1) for b in range(k)], 1)
        post -= _logsumexp(post, axis=1)[:, None]
        moved = runs[best] > 0  # an empty run (the first emission) leaves the level's distribution as it was
        self.last[j] = self.last[j].copy()
        self.last[j][rows[moved]] = post[moved]
        self.fresh = self.fresh.copy()
        self.fresh[rows, j] = False
        return upd


def _uniform_log(alive: np.ndarray) -> np.ndarray:
    """log of the uniform distribution over the alive models (last axis), -inf elsewhere."""
    return np.where(alive, -np.log(np.maximum(alive.sum(axis=-1, keepdims=True), 1)), -np.inf)


PARAMS = declare(
    Param("beam", int, 1, "hypotheses kept", low=1, high=4096),
    Param("lag", int, 0, "pulses of look-ahead before a label is final", low=0, high=256),
    Param("gate", float, 5.0, "the overdue test's width, in predicted standard deviations", low=0, low_open=True),
    Param("switch", float, 0.01, "the per-pulse model switching probability", low=0, high=1, high_open=True),
    Param("bank", str, "priors", "priors: the model the priors name (else the default bank); default: always the "
          "bank", choices=("priors", "default")),
    Param("identify", int, 100, "after a source's identify-th pulse its bank keeps the models within margin (0: "
          "never prune)", low=0),
    Param("margin", float, 20.0, "nats of evidence within the best model that a pruned bank keeps", low=0,
          low_open=True),
    Param("reset_after", int, 4, "coasted arrivals in a row after which the arrival variance is at least PRI^2/12",
          low=1),
    Param("birth", float, 10.0, "blind mode: the cost of a new track's first pulse (nats)"),
    Param("pri_range", float, 100.0, "blind mode: max/min PRI of the log-uniform prior on a new track's first "
          "interval", low=1, low_open=True),
    Param("merge", bool, True, "keep only the cheapest of hypotheses whose tracks agree (every source's last pulse, "
          "likeliest model and its state)"),
)


class PathSearch:
    """The hypothesis search shared by `agile-kf` and `renewal-ml` (see the module doc).

    beam: hypotheses kept; lag: pulses of look-ahead before a label is final; gate: the overdue test's
    width in predicted standard deviations; switch: the per-pulse model switching probability; bank:
    "priors" (the named model, the default bank where none is named) or "default" (always the bank);
    identify, margin: after a source's `identify`-th pulse its bank keeps only the models within
    `margin` nats of the best one's evidence (0: never prune); reset_after: a source coasted through
    more arrivals than this in a row gets an arrival variance of at least PRI^2 / 12 (dokf's dropout
    reset), so a source that stops and restarts, or starts late, is acquired again (and a named modulation's
    track may start afresh: `_restart`).  Blind mode (where `blind_ok`): birth: the cost of a new track's first
    pulse (nats); pri_range: max/min PRI of the log-uniform prior on a new track's first interval; merge: keep one
    hypothesis of each track state (`_select`).  Declared: `PARAMS`."""

    PARAMS = PARAMS
    blind_ok = False

    def __init__(self, beam: int = 1, lag: int = 0, gate: float = 5.0, switch: float = 0.01, bank: str = "priors",
                 identify: int = 100, margin: float = 20.0, reset_after: int = 4, birth: float = 10.0,
                 pri_range: float = 100.0, merge: bool = True):
        PARAMS.check(locals())
        self.beam, self.lag, self.gate, self.switch, self.bank_mode = beam, lag, float(gate), float(switch), bank
        self.base_beam, self.jump_beam = beam, None  # jump_beam: per random-level source and one more
        self.identify, self.margin, self.reset_after = identify, float(margin), reset_after
        self.birth, self.pri_range, self.merge = float(birth), float(pri_range), merge

    # ---- setup ---------------------------------------------------------------------------------
    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        n = self.n = priors.n_labels
        self.blind = priors.blind
        if self.blind:  # tracks are born from the pulses: constant PRIs, set by each track's first interval
            if not self.blind_ok:
                raise NotApplicable(f"{type(self).__name__} needs priors; blind scenarios have none")
            period = np.ones(n)
            banks = [(pri_models.constant(),)] * n
            self.named = np.zeros(n, dtype=bool)
            phase, phase_std = np.zeros(n), np.ones(n)
            if not priors.jitter_std > 0:  # nothing else sets the scale of a track's errors (RenewalML
                # measures it from the pulses when the priors leave it out: `RenewalML._remeasure`)
                raise DeintError("blind tracks need the TOA jitter: a priors file with jitter_std > 0")
            self.r = priors.jitter_std ** 2
        else:
            period = np.asarray(priors.period, dtype=np.float64)
            named = priors.modulation if self.bank_mode == "priors" else None
            self.named = np.array([named is not None and named[i] is not None for i in range(n)])
            banks = [pri_models.bank_from_modulation(named[i], float(period[i])) if named is not None
                     and named[i] is not None else pri_models.default_bank() for i in range(n)]
            self.unknown_phase = ~np.isfinite(priors.phase)  # placed by the first pulse (see `_step`)
            phase = np.where(self.unknown_phase, 0.0, priors.phase)
            phase_std = np.where(self.unknown_phase, period, priors.phase_std)
            self.r = max(priors.jitter_std, _MIN_JITTER_REL * float(period.min())) ** 2
        self.period = period
        self.arrays: BankArrays = pri_models.build_bank(banks, period, priors.period_std if not self.blind else period,
                                                        phase, phase_std, priors.pri_jitter_std ** 2)
        m = self.arrays.valid.shape[1]
        # These trackers do not estimate rates: one the priors leave unknown (NaN) is taken as 0 (a miss
        # then costs the floor's price, and no pulse is called spurious), which labels best in our tests
        # (renewal-ml 0.76 -> 0.9+ on test_unknown_phases_are_placed_by_the_first_pulse against 0.05).
        p_miss = float(np.nan_to_num(priors.missing_prob))
        self.miss_cost = -math.log(max(p_miss, _MISS_FLOOR))
        self.hit_cost = -math.log1p(-p_miss)
        self.miss_odds = self.hit_cost - self.miss_cost  # log((1 - q) / q), q = p_miss
        # the one-miss test: for a named model, whose next PRI is known (the default bank's vague models
        # coast too early by it: agile-v0 agile-kf 0.36 -> 0.17 on a wobulated episode), on a channel that
        # states misses (with none stated a vague wobulation waits: agile-v1 0.97 -> 0.78 on one otherwise)
        self.miss_test = self.named & (p_miss > 0)
        self.interval_var = priors.pri_jitter_std ** 2
        self.jumps = _Jumps(banks, max(p_miss, _MISS_FLOOR))
        self.jump_src = np.isin(np.arange(n), self.jumps.index)
        self.beam = self.jump_beam * (1 + len(self.jumps.index)) if self.jump_beam and self.jumps.index \
            else self.base_beam
        work = self.beam * sum(lv.ratio.size * c[0].size for lv, c in zip(self.jumps.levels, self.jumps.columns))
        if work > _JUMP_WORK:
            raise NotApplicable(f"{type(self).__name__}: {self.beam} hypotheses x the random-level sources' "
                                f"levels x runs scored = {work:,} terms a pulse, at most {_JUMP_WORK:,} (minutes per "
                                f"1000 pulses beyond); fewer levels or a smaller beam")
        # sources whose bank holds one model per cycle offset (`Modulation.random_start`): its models
        # predict arrivals a whole ramp apart, so the best one alone cannot tell a miss
        self.offset_bank = np.array([len(b) > 1 and len({m.kind for m in b}) == 1 for b in banks])
        # sources that may restart (`_restart`): a named modulation, whose phase or cycle position a track
        # can lock on wrongly; after a run of coasted arrivals past `reset_after` that the stated miss rate
        # makes rarer than _RESTART_TAIL
        self.restartable = self.named & ~self.jump_src & np.array([any(m.kind != "constant" for m in b) for b in banks])
        self.restart_after = max(self.reset_after + 1,
                                 math.ceil(math.log(_RESTART_TAIL) / math.log(max(p_miss, _MISS_FLOOR))))
        rate = float(np.sum(1.0 / period))
        self.spurious_rate = float(np.nan_to_num(priors.spurious_rate))
        self.spurious_cost = -math.log(self.spurious_rate * rate) if self.spurious_rate > 0 else None
        # hypotheses (H of them): states (H, N, M, D+1[, D+1]), emission counts, model log-weights, costs
        self.state = LinearBlock(self.arrays.x0[None].copy(), self.arrays.p0[None].copy())
        self.count = np.zeros((1, n), dtype=np.int64)  # emissions passed (received or coasted)
        self.alive = self.arrays.valid[None].copy()  # (H, N, M): the models still in each source's bank
        self.logw = _uniform_log(self.alive)
        self.evidence = np.zeros((1, n, m))  # each model's own log-likelihood of the source's pulses
        self.taken = np.zeros((1, n), dtype=np.int64)  # pulses each source took
        self.missed = np.zeros((1, n), dtype=np.int64)  # emissions coasted through since the last one taken
        self.misfit = np.zeros((1, n), dtype=bool)  # took a pulse its every model ruled out: may restart
        self.last = np.full((1, n), np.nan)  # the last pulse taken
        self.y0 = None
        self.cost = np.zeros(1)
        self.first = np.full((1, n), np.nan)  # first pulse taken (the phase estimate)
        self.history = np.zeros((1, self.lag + 1), dtype=np.int64)  # labels of pulses k - lag .. k
        self.k = -1  # last pulse seen
        self.steps = 0
        self._mixing = bool((self.arrays.same_family & ~np.eye(m, dtype=bool)).any())  # any IMM family
        self._stay = (1 - self.switch) * np.eye(m)  # `_mix`'s constant terms
        self._tiny = np.eye(m) * 1e-300

    # ---- the filter steps ---------------------------------------------------------------------------
    def _advance(self, mask: np.ndarray) -> None:
        """Every model of the (hypothesis, source) pairs in `mask` (H, N) predicts its next emission.  The
        search's arrays belong to it alone (each pulse's `take` makes fresh ones): updated in place."""
        if mask.any():
            h, i = np.nonzero(mask)
            self.state.x[h, i], self.state.p[h, i] = self._predict(h, i, LinearBlock(self.state.x[h, i],
                                                                                      self.state.p[h, i]))

    def _predict(self, h: np.ndarray, i: np.ndarray, b: LinearBlock) -> LinearBlock:
        """The next emission of every model of the distinct pairs (h[k], i[k]), whose states are b
        (K, M, ...); their emission counts advance."""
        a = self.arrays
        f = a.transition_of(i, self.count[h, i])
        self.count[h, i] += 1
        return linear_predict(b, f, a.q[i], a.c[i])

    def _best_model(self) -> np.ndarray:
        return np.argmax(self.logw, axis=2)  # (H, N)

    def _coast(self, y: float) -> None:
        """MK94 VI-C-3 (`kalman.overdue` on each source's most probable model): sources whose next
        emission is overdue at y predict through it without a measurement, at -log p_miss each."""
        for _ in range(_MAX_COAST):
            best = self._best_model()
            hh, nn = np.arange(best.shape[0])[:, None], np.arange(self.n)
            x = self.state.x[hh, nn, best]  # (H, N, D+1)
            var = self.state.p[hh, nn, best, TAU, TAU]
            phi = self.arrays.phi(nn, best, self.count)
            pri = np.einsum("hnd,hnd->hn", phi, x[..., 1:])
            late = y - x[..., TAU] > self.gate * np.sqrt(var + self.r) + 0.5 * pri
            if self.miss_test.any():  # or one missed emission explains y better than none (dokf's (4.1),
                # equal variances): a vague prediction (an unlocked wobulation) need not wait 5 sd
                late |= self.miss_test & (y - x[..., TAU] > 0.5 * pri + (var + self.r) * self.miss_odds
                                          / np.maximum(pri, 1e-300))
            if self.offset_bank.any():  # a bank of cycle offsets: overdue only when every credible offset is.
                # An offset the pulses have already ruled out still predicts arrivals (and a gate) of its own,
                # which held the source back from coasting through a real miss; it then lost the pulse after
                # the miss: three deep ramps with 20 % missing had 0.37 of their labels right on a file of the
                # independent generator (tests/independent_agile.py), 0.985 now.  3, 7 and 12 nats did alike.
                pri_all = np.einsum("hnmd,hnmd->hnm", self.arrays.regressor(self.count), self.state.x[..., 1:])
                ahead, var_all = y - self.state.x[..., TAU], self.state.p[..., TAU, TAU] + self.r
                each = ahead > self.gate * np.sqrt(var_all) + 0.5 * pri_all
                # and the one-miss test, per offset: a source whose arrival is known only to within a PRI (an
                # unknown phase, a reset) otherwise coasted one PRI a pulse while its 5-sd gate held it 3 PRIs
                # behind, and its pulses went spurious for good (a deep ramp on a validation file with 30 %
                # missing and phases unknown: 0.02 of its labels right, 0.98 now)
                each |= self.miss_test[..., None] & (ahead > 0.5 * pri_all + var_all * self.miss_odds
                                                     / np.maximum(pri_all, 1e-300))
                faint = self.logw < self.logw.max(axis=2, keepdims=True) - _FAINT
                late = np.where(self.offset_bank, (each | ~self.alive | faint).all(axis=2), late)
            if self.blind:  # a track with fewer than two pulses has no PRI yet: it waits
                late &= self.taken >= 2
            late &= ~self.jump_src  # random-level sources score their missed emissions (`_Jumps`)
            if not late.any():
                return
            self.cost = self.cost + self.miss_cost * late.sum(axis=1)
            self._advance(late)
            self.missed += late
            lost = late & (self.missed > self.reset_after)
            if lost.any():  # a dropout (or a late start): open the arrival up to a whole PRI (as dokf)
                floor = (pri[lost] ** 2 / 12.0)[:, None]
                self.state.p[lost, :, TAU, TAU] = np.maximum(self.state.p[lost, :, TAU, TAU], floor)
            # a track that locked early on a wrong phase or cycle position predicts a deviation of 0.03-0.09
            # while its own pulses are 0.3-8 away: it coasts through them, calls them spurious and, the tau
            # floor above opening its arrival but not its modulation, never re-locks (a wobulated file of the
            # independent generator: 0.53 of its labels right).  So it may start afresh
            restart = late & self.restartable & (self.missed == self.restart_after)
            if restart.any():
                self._restart(restart, y)

    def _restart(self, mask: np.ndarray, y: float) -> None:
        """Each (hypothesis, source) pair in `mask` forks a hypothesis in which that source starts afresh, as
        a source of unknown phase does at the first pulse: every model of its bank back at its prior (the
        period's, the modulation's spread), its next emission in [y, y + T), every cycle position alive and
        equally likely.  The hypothesis that keeps the track stays beside it: the pulses decide."""
        h, i = np.nonzero(mask)
        self._take(np.concatenate([np.arange(mask.shape[0]), h]))
        h = mask.shape[0] + np.arange(h.size)
        a, t = self.arrays, self.period[i][:, None]
        self.state.x[h, i], self.state.p[h, i] = a.x0[i], a.p0[i]
        self.state.x[h, i, :, TAU] = y + 0.5 * t
        self.state.p[h, i, :, TAU, TAU] = (0.5 * t) ** 2
        self.alive[h, i] = a.valid[i]
        self.logw[h, i] = _uniform_log(a.valid[i])
        self.evidence[h, i] = 0.0
        self.taken[h, i] = 0

    def _jump_lost(self, y: float) -> None:
        """A random-level source silent beyond its longest scored run (a dropout, or a late start) is
        reacquired: its next emission is placed anywhere within its longest PRI after y, priced as the
        emissions it missed."""
        for j, i in enumerate(self.jumps.index):
            x, p = self.state.x[:, i, 0], self.state.p[:, i, 0]
            gap = y - x[:, TAU]
            lost = gap > self.jumps.reach[j] * x[:, 1] + self.gate * np.sqrt(p[:, TAU, TAU] + self.r)
            if not lost.any():
                continue
            self.cost = self.cost + self.miss_cost * np.where(lost, np.floor(gap / x[:, 1]), 0.0)
            half = 0.5 * float(self.jumps.levels[j].ratio.max()) * x[lost, 1]
            xs, ps = self.state.x.copy(), self.state.p.copy()
            xs[lost, i, 0, TAU] = y + half
            ps[lost, i, 0, TAU, :] = 0.0
            ps[lost, i, 0, :, TAU] = 0.0
            ps[lost, i, 0, TAU, TAU] = half ** 2
            self.state = LinearBlock(xs, ps)
            self.jumps.last[j] = self.jumps.last[j].copy()
            self.jumps.last[j][lost] = np.log(self.jumps.levels[j].start)
            self.jumps.fresh = self.jumps.fresh.copy()
            self.jumps.fresh[lost, j] = True

    def _take(self, h: np.ndarray) -> None:
        """The hypotheses become rows h of the current ones.  Fancy indexing copies: from here on their
        arrays are the search's own, updated in place."""
        self.state, self.cost, self.history = self.state.take(h), self.cost[h], self.history[h]
        self.count, self.logw, self.first = self.count[h], self.logw[h], self.first[h]
        self.alive, self.evidence, self.taken = self.alive[h], self.evidence[h], self.taken[h]
        self.missed, self.last, self.misfit = self.missed[h], self.last[h], self.misfit[h]
        self.jumps.take(h)

    def _select(self, flat: np.ndarray, width: int, y: float) -> np.ndarray:
        """The candidates (hypothesis h, label j as h * width + j) that survive, cheapest first.  With `merge`,
        of the candidates whose tracks would agree after this pulse - every source's last pulse, likeliest
        model and that model's state (to half the TOA noise's std), a random-level source's last level - only
        the cheapest is kept: they predict alike from here on, so the rest are near-copies that would crowd
        the beam (Viterbi's rule, as an MHT merges hypotheses).  Independent agile files, validation seeds 3-4,
        renewal-ml: mean 0.963 -> 0.975, worst 0.520 -> 0.891, files >= 0.90 44 -> 47 of 50.  Merging on the
        last pulses alone cost wobulated files (0.994 -> 0.766): their tracks differ in the sine's phase."""
        if not self.merge or self.beam == 1:
            keep = min(self.beam, flat.size)
            pick = np.argpartition(flat, keep - 1)[:keep] if keep < flat.size else np.arange(flat.size)
            return pick[np.argsort(flat[pick], kind="stable")]
        order = np.argsort(flat, kind="stable")
        finite = np.isfinite(flat[order])
        order = order[finite] if finite[0] else order[:1]
        h, j = np.divmod(order, width)
        last = self.last[h]  # each source's last pulse once the candidate takes y
        took = np.nonzero(j < self.n)[0]
        last[took, j[took]] = y
        # per hypothesis, then per candidate: each source's likeliest model, its state, a random-level last level
        best = np.argmax(self.logw, axis=2)  # (H, N)
        x = np.take_along_axis(self.state.x, best[:, :, None, None], axis=2)[:, :, 0]  # (H, N, D+1)
        cells = np.round(np.nan_to_num(x) / (0.5 * math.sqrt(self.r))).reshape(x.shape[0], -1)
        track = np.concatenate([best, cells, *(np.argmax(a, axis=1)[:, None] for a in self.jumps.last)], axis=1)
        key = np.concatenate([np.nan_to_num(last, nan=-np.inf), track[h]], axis=1) + 0.0  # + 0.0: no -0.0
        first: dict[bytes, int] = {}  # each key's cheapest candidate (`order` is sorted)
        for c, row in enumerate(key):
            first.setdefault(row.tobytes(), c)
            if len(first) == self.beam:
                break
        return order[list(first.values())]

    def _step(self, y: float) -> None:
        if self.k == 0 and not self.blind and self.unknown_phase.any():
            # an unknown phase lies in [y0, y0 + T) (every source emits within a period of the first
            # pulse): a Gaussian over that window, mean y0 + T/2 and std T/2
            x, p = self.state.x.copy(), self.state.p.copy()
            u = np.nonzero(self.unknown_phase)[0]
            t = self.period[u][:, None]
            xu, pu = x[:, u], p[:, u]  # (H, n_u, M, D+1[, D+1])
            xu[..., TAU] = y + 0.5 * t
            pu[..., TAU, TAU] = (0.5 * t) ** 2
            x[:, u], p[:, u] = xu, pu
            self.state = LinearBlock(x, p)
        if self.misfit.any():
            restart, self.misfit = self.misfit, np.zeros_like(self.misfit)
            self._restart(restart, y)
        self._coast(y)
        self._jump_lost(y)
        e, s = linear_innovation(self.state, y, TAU, self.r)  # (H, N, M)
        with np.errstate(invalid="ignore", divide="ignore"):  # pruned models' states are left to drift
            ll = np.where(self.alive, -0.5 * (_LOG_2PI + np.log(s) + e * e / s), -np.inf)  # predictive log-density
        jump_scores = []
        if self.jumps.index:  # random-level sources: their renewal mixture (one model, slot 0)
            ji = self.jumps.index
            jump_scores = self.jumps.mixture(self.state.x[:, ji, 0], self.state.p[:, ji, 0], y, self.r,
                                             self.interval_var)
            for j, i in enumerate(ji):
                ll[:, i, 0] = _logsumexp(jump_scores[j], axis=1)
        joint = self.logw + np.where(self.alive, ll, -np.inf)
        top = joint.max(axis=2, keepdims=True)
        src_ll = (top + np.log(np.exp(joint - top).sum(axis=2, keepdims=True)))[..., 0]  # (H, N)
        ext = self.cost[:, None] - src_ll + self.hit_cost
        if self.blind:
            ext = self._blind_costs(ext, y)
        if self.spurious_cost is not None:
            ext = np.concatenate([ext, self.cost[:, None] + self.spurious_cost], axis=1)
        flat = ext.ravel()
        pick = self._select(flat, ext.shape[1], y)
        h, j = np.divmod(pick, ext.shape[1])
        self._take(h)
        self.cost = flat[pick]
        self.history = np.concatenate([self.history[:, 1:], j[:, None]], axis=1)
        took = j < self.n
        if self.blind and took.any():
            took = self._acquire(took, j, y)
        if took.any():
            rows, src = np.nonzero(took)[0], j[took]
            sub = LinearBlock(self.state.x[rows, src], self.state.p[rows, src])
            upd = linear_update(sub, e[h[rows], src], s[h[rows], src], TAU, self.r)
            for jj, i in enumerate(self.jumps.index):  # random-level sources: along the likeliest run
                at = src == i
                if at.any():
                    r_i = rows[at]
                    new = self.jumps.update(jj, r_i, jump_scores[jj][h[r_i]],
                                            LinearBlock(sub.x[at, 0], sub.p[at, 0]), y, self.r, self.interval_var)
                    upd.x[at, 0], upd.p[at, 0] = new.x, new.p
            # a pulse outside every live model's gate, taken because nothing else could (no spurious pulses
            # stated): the track's state is wrong, not the pulse (a deep ramp locked two cycle positions off
            # after a missed reset took the next ramp's pulses at 13-40 sd; 0.89 -> 0.99 of a file's labels
            # right).  Such a track forks a restart at the next pulse, as after a run of misses (`_coast`)
            z2 = e[h[rows], src] ** 2 / s[h[rows], src]
            outside = np.where(self.alive[rows, src], z2, np.inf).min(axis=1) > self.gate ** 2
            self.misfit[rows[outside], src[outside]] = self.restartable[src[outside]]
            # model probabilities: Bayes on the pulse, then the switching mix (IMM's Markov step)
            self._identify(rows, src, ll[h[rows], src])
            alive = self.alive[rows, src]
            w = np.where(alive, self.logw[rows, src] + ll[h[rows], src], -np.inf)
            w -= w.max(axis=1, keepdims=True)
            w -= np.log(np.exp(w).sum(axis=1, keepdims=True))
            if self.switch > 0 and self._mixing:
                upd = self._mix(src, w, alive, upd)
                w = np.logaddexp(math.log1p(-self.switch) + w, math.log(self.switch) + _uniform_log(alive))
            self.logw[rows, src] = w
            self.first[rows, src] = np.where(np.isnan(self.first[rows, src]), y, self.first[rows, src])
            self.missed[rows, src] = 0
            self.last[rows, src] = y
            # then each model predicts the source's next emission, but a random-level source's state
            # stays at its last emission; the pairs' states are written back once, at the end
            moves = ~self.jump_src[src]
            if moves.all():
                upd = self._predict(rows, src, upd)
            elif moves.any():
                pred = self._predict(rows[moves], src[moves], LinearBlock(upd.x[moves], upd.p[moves]))
                upd.x[moves], upd.p[moves] = pred
            self.state.x[rows, src], self.state.p[rows, src] = upd

    # ---- blind mode: tracks born from the pulses -----------------------------------------------------
    def _blind_costs(self, ext: np.ndarray, y: float) -> np.ndarray:
        """The renewal likelihood of a track's first two pulses, whose PRI nothing predicts: its first
        pulse is a birth (cost `birth`, offered in the first free slot only: the free slots are alike),
        its second comes after an interval drawn from a log-uniform PRI prior over `pri_range` (density
        1 / (d ln range)); tracks with two pulses or more are predicted by their models."""
        ext = np.where(self.taken >= 2, ext, np.inf)
        gap = y - self.last
        with np.errstate(invalid="ignore", divide="ignore"):
            second = self.cost[:, None] + np.log(gap) + math.log(math.log(self.pri_range)) + self.hit_cost
        ext = np.where((self.taken == 1) & (gap > 0), second, ext)
        free = self.taken == 0
        first = np.argmax(free, axis=1)
        rows = np.nonzero(free.any(axis=1))[0]
        ext[rows, first[rows]] = self.cost[rows] + self.birth
        if self.spurious_rate > 0:  # the Poisson density of spurious pulses from the rate seen so far
            if self.y0 is None:
                self.y0 = y
            rate = (self.k + 1) / max(y - self.y0, 1e-9) * self.spurious_rate / (1 + self.spurious_rate)
            self.spurious_cost = -math.log(max(rate, 1e-300))
        return ext

    def _acquire(self, took: np.ndarray, j: np.ndarray, y: float) -> np.ndarray:
        """Births and second pulses (blind mode): a born track records its pulse; a track's second pulse
        starts its constant-PRI state, T = the interval (var 2R), tau = y (var R), which then advances
        to its next emission.  Returns the rows whose pulse still needs the ordinary update."""
        rows = np.nonzero(took)[0]
        src = j[rows]
        n_taken = self.taken[rows, src]
        self.taken, self.last, self.first = self.taken.copy(), self.last.copy(), self.first.copy()
        born = n_taken == 0
        self.first[rows[born], src[born]] = y
        second = n_taken == 1
        if second.any():
            r, i = rows[second], src[second]
            x, p = self.state.x.copy(), self.state.p.copy()
            x[r, i] = 0.0
            x[r, i, :, TAU], x[r, i, :, 1] = y, y - self.last[r, i][:, None]
            p[r, i] = 0.0
            p[r, i, :, TAU, TAU], p[r, i, :, TAU, 1], p[r, i, :, 1, TAU] = self.r, self.r, self.r
            p[r, i, :, 1, 1] = 2 * self.r
            self.state = LinearBlock(x, p)
            mask = np.zeros(took.shape + (self.n,), dtype=bool)
            mask[r, i] = True
            self._advance(mask)
        fresh = born | second
        self.taken[rows[fresh], src[fresh]] += 1
        self.last[rows[fresh], src[fresh]] = y
        out = took.copy()
        out[rows[fresh]] = False
        return out

    def _identify(self, rows: np.ndarray, src: np.ndarray, ll: np.ndarray) -> None:
        """Modulation identification: each model's own evidence (its predictive log-likelihood of the
        pulses the source took, without switching) accumulates; when the source has taken `identify`
        pulses (several cycles of any simulated modulation) the models more than `margin` nats behind
        the best leave its bank for good.  A steady source then keeps no broad model with which it
        could take over an agile source's pulses (or hand its own over)."""
        self.evidence[rows, src] += np.where(self.alive[rows, src], ll, 0.0)
        self.taken[rows, src] += 1
        due = self.taken[rows, src] == self.identify
        if self.identify and due.any():
            r, i = rows[due], src[due]
            ev = np.where(self.alive[r, i], self.evidence[r, i], -np.inf)
            self.alive[r, i] &= ev >= ev.max(axis=1, keepdims=True) - self.margin
            self.logw[r, i] = np.where(self.alive[r, i], self.logw[r, i], -np.inf)

    def _mix(self, src: np.ndarray, logw: np.ndarray, alive: np.ndarray, b: LinearBlock) -> LinearBlock:
        """IMM's interaction step (Blom & Bar-Shalom) within each model family: model j restarts from
        the mix of the family's states weighted by p_ij mu_i, with p = (1 - switch) I + switch U.  b:
        the states (R, M, ...) of sources `src`; returns the mixed states."""
        mu = np.exp(logw)  # (R, M)
        trans = self._stay + self.switch * alive[:, None, :] / alive.sum(axis=1)[:, None, None]
        wij = np.where(self.arrays.same_family[src], trans * mu[:, :, None], 0.0)  # (R, i, j)
        total = wij.sum(axis=1, keepdims=True)
        if not (total > 0).all():
            wij = wij + self._tiny
            total = wij.sum(axis=1, keepdims=True)
        wij /= total
        x, p = b  # (R, M, D+1[, D+1])
        r, m, d = x.shape
        wt = np.swapaxes(wij, 1, 2)  # (R, j, i)
        x0 = wt @ x  # mixed means
        # sum_i w_ij (P_i + dx dx'), dx = x_i - x0_j: positive by construction.  Every j at once, each
        # j's product the same (1, M) @ (M, d^2) as one j at a time.  The outer products are single
        # products (the same bits however they are taken); einsum lays them out in place twice as fast as
        # a broadcast product of d-long rows.
        dx = (x[:, None, :, :] - x0[:, :, None, :]).reshape(-1, d)  # (R j i, D+1)
        spread = np.einsum("ki,kj->kij", dx, dx).reshape(r, m, m, d * d)
        spread += p.reshape(r, 1, m, d * d)
        p0 = (wt[:, :, None] @ spread).reshape(r, m, d, d)
        return LinearBlock(x0, p0)

    # ---- the policy protocol -----------------------------------------------------------------------
    def act(self, obs: dict[str, Any]) -> int:
        if int(obs["valid"]):
            self.k += 1
            self._step(float(obs["toa"][0]))
        want = self.steps - self.lag  # step t labels pulse t - lag
        self.steps += 1
        if want < 0:
            return 0
        col = want - (self.k - self.lag)  # the history holds pulses k - lag .. k
        return int(self.history[0, col])  # hypotheses are sorted: row 0 is the best

    def estimates(self) -> dict[str, np.ndarray] | None:
        """The best hypothesis's sources: each one's mean PRI under its most probable model, and the
        first pulse it took (its phase; the prior's where it took none).  Blind: None (free labels
        have no estimate)."""
        if self.blind:
            return None
        best = self._best_model()[0]
        period = np.empty(self.n)
        for i in range(self.n):
            model = self.arrays.models[i][best[i]]
            period[i] = model.mean_pri(self.state.x[0, i, best[i], 1:])
        phase = np.where(np.isnan(self.first[0]), self.arrays.x0[:, 0, TAU], self.first[0])
        return {"period": period, "phase": phase}


class AgileKF(PathSearch):
    """`agile-kf`: the model-bank tracker with MAP decisions (beam 1, lag 0)."""

    PARAMS = PARAMS.only("gate", "switch", "bank", "identify", "margin", "reset_after")

    def __init__(self, gate: float = 5.0, switch: float = 0.01, bank: str = "priors", identify: int = 100,
                 margin: float = 20.0, reset_after: int = 4):
        super().__init__(beam=1, lag=0, gate=gate, switch=switch, bank=bank, identify=identify, margin=margin,
                         reset_after=reset_after)


class RenewalML(PathSearch):
    """`renewal-ml`: Young et al.'s ML path search, a beam of `beam` hypotheses decided at lag `lag`;
    in blind mode tracks are born from the pulses (`birth`, `pri_range`: see `PathSearch`).  The
    default beam is 64, or `JUMP_BEAM` times (1 + the number of sources whose priors name a random-level
    stagger): such a renewal density fits many intervals, so until another train locks (a wobulation's
    phase, say) the hypothesis giving that train its own pulses can trail by several nats for tens of
    pulses, and each random-level train adds such rivals."""

    PARAMS = ParamSet((dataclasses.replace(PARAMS["beam"], default=None, optional=True, meaning="hypotheses "
                                           "kept (none: 64, or 64 times 1 + the random-level staggers)"),)
                      + PARAMS.params[1:]).changed(lag=16)
    blind_ok = True
    # on the random-level test files a wobulated train was lost to one random-level train at a beam of
    # 64 (kept at 128) and to two at 128 (kept at 256)
    JUMP_BEAM = 64

    def __init__(self, beam: int | None = None, lag: int = 16, gate: float = 5.0, switch: float = 0.01,
                 bank: str = "priors", identify: int = 100, margin: float = 20.0, reset_after: int = 4,
                 birth: float = 10.0, pri_range: float = 100.0, merge: bool = True):
        super().__init__(beam=64 if beam is None else beam, lag=lag, gate=gate, switch=switch, bank=bank,
                         identify=identify, margin=margin, reset_after=reset_after, birth=birth, pri_range=pri_range,
                         merge=merge)
        self.jump_beam = self.JUMP_BEAM if beam is None else None

    # ---- blind mode without a stated TOA noise ---------------------------------------------------------
    # The noise is measured from the pulses seen so far (`baselines.blind.noise.estimate_noise`: white TOA
    # noise and PRI jitter from the widths of the difference peaks) when the first label is due and again
    # at these counts; when it moves by more than a quarter the search restarts from the first pulse with
    # it (so a record costs at most twice its first 4096 pulses more), and its labels are mapped onto the
    # labels already given out, which cannot change.
    _CHECKPOINTS = (64, 128, 256, 512, 1024, 2048, 4096)
    # blind: about 2 ms a pulse (10^4 pulses of three trains: 20 s of CPU; the 10^5 it allowed ran for minutes),
    # so a larger record is refused rather than run past a minute
    MAX_PULSES = 20_000

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        self._measure = priors.blind and not priors.jitter_std > 0
        if priors.blind and (info.get("n_pulses") or 0) > self.MAX_PULSES:
            raise DeintError(f"renewal-ml in blind mode labels at most {self.MAX_PULSES} pulses (about 2 ms a "
                             f"pulse); this record has {info['n_pulses']}: split it into files of at most "
                             f"{self.MAX_PULSES} pulses, or use cdif or sdif (up to 100000)")
        if not self._measure:
            super().reset(priors, info)
            return
        self._blind_priors, self._info = priors, info
        self._toas: list[float] = []
        self._emitted: list[int] = []
        self._perm = np.arange(priors.n_labels + 1)  # search label -> label given out (spurious fixed)
        self._noise = (0.0, 0.0)
        # until the first estimate (made before any label is given out) any scale will do
        super().reset(dataclasses.replace(priors, jitter_std=1.0), info)

    def _remeasure(self) -> bool:
        """Measure the noise on the pulses seen; restart and replay them if it moved (module comment)."""
        from baselines.blind.noise import estimate_noise

        t = np.asarray(self._toas)
        est = estimate_noise(t)
        gaps = np.diff(t)
        # a thousandth of the spacing, and never below the TOAs' own precision (coincident pulses)
        spacing = float(np.median(gaps)) if gaps.size else 0.0
        floor = max(1e-3 * spacing, 1e-12 * (1.0 + float(np.abs(t).max(initial=0.0))))
        # no periodic peak (every train swept or wobulated): 1 % of the spacing, a walk's typical error
        white = max(est.toa, floor) if est.toa > 0 or est.pri > 0 else 10 * floor
        old_w, old_v = self._noise
        first = len(self._toas) == self.lag + 1
        if not first and abs(white - old_w) <= 0.25 * old_w and abs(est.pri - old_v) <= 0.25 * max(old_v, white):
            return False
        self._noise = (white, est.pri)
        steps = self.steps
        pr = self._blind_priors
        PathSearch.reset(self, dataclasses.replace(
            pr, jitter_std=white, pri_jitter_std=est.pri,
            missing_prob=_UNSTATED_MISSING if math.isnan(pr.missing_prob) else pr.missing_prob), self._info)
        replayed = np.full(max(len(self._toas) - self.lag, 0), -1)
        for y in self._toas:
            self.k += 1
            self._step(y)
            if self.k >= self.lag:
                replayed[self.k - self.lag] = self.history[0, 0]
        self.steps = steps
        self._map_labels(replayed[:len(self._emitted)])
        return True

    def _map_labels(self, replayed: np.ndarray) -> None:
        """The permutation of the restarted search's labels that agrees best with the labels given out."""
        from scipy.optimize import linear_sum_assignment

        n = self.n
        given = np.asarray(self._emitted, dtype=np.int64)
        agree = np.zeros((n, n))
        keep = (replayed < n) & (given < n)
        np.add.at(agree, (replayed[keep], given[keep]), 1.0)
        rows, cols = linear_sum_assignment(-agree)
        perm = np.empty(n + 1, dtype=np.int64)
        perm[rows] = cols
        perm[n] = n
        self._perm = perm

    def act(self, obs: dict[str, Any]) -> int:
        if not self._measure:
            return super().act(obs)
        if int(obs["valid"]):
            y = float(obs["toa"][0])
            if not abs(y) <= MAX_MAGNITUDE:  # its noise, measured on such TOAs, squares past float64
                raise NotApplicable(f"a TOA of {y:.3g}: blind {type(self).__name__} measures the TOA noise on TOAs "
                                    f"up to {MAX_MAGNITUDE:g} in size")
            self._toas.append(y)
            seen = len(self._toas)
            if not ((seen == self.lag + 1 or seen in self._CHECKPOINTS) and self._remeasure()):
                self.k += 1
                self._step(y)
        elif len(self._toas) <= self.lag and self.steps == len(self._toas):  # a record shorter than the lag
            self._remeasure()
        want = self.steps - self.lag
        self.steps += 1
        if want < 0:
            return 0
        label = int(self._perm[self.history[0, want - (self.k - self.lag)]])
        self._emitted.append(label)
        return label

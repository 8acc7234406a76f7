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
Markov-modulated rather than an i.i.d. renewal sequence).  A source whose next emission is overdue at a pulse
(`kalman.overdue`'s MK94 VI-C-3 test on its best model) coasts: its models predict through the missed
emission, which costs -log p_miss.

- `agile-kf`: beam 1, lag 0: each pulse goes to the source (or spurious) of least cost, i.e. the MAP
  decision under the model-aware predictions, then that source's KF update: DM89's detect-then-filter.
- `renewal-ml`: Young et al.'s maximum-likelihood path search, here a beam search: the `beam` least-cost hypotheses survive each pulse, and pulse k is labelled from the best
  hypothesis when pulse k + `lag` has arrived.  In blind mode (no priors, a label budget) the tracks
  are born from the pulses: a pulse may start a track (cost `birth`), a track's second pulse comes
  after an interval with a log-uniform prior over `pri_range` and starts its constant-PRI state, and
  from its third pulse on a track is predicted as in the anchored mode.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from baselines import pri_models
from baselines.kalman import LinearBlock, linear_innovation, linear_predict, linear_update
from baselines.pri_models import TAU, BankArrays
from deint_env.episode import Priors
from deint_env.errors import DeintError, NotApplicable

_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
_MISS_FLOOR = 1e-3  # p_miss used for coasting when the priors say nothing is missed (a track can slip)
_MAX_COAST = 64
_LOG_2PI = math.log(2 * math.pi)


def _uniform_log(alive: np.ndarray) -> np.ndarray:
    """log of the uniform distribution over the alive models (last axis), -inf elsewhere."""
    return np.where(alive, -np.log(np.maximum(alive.sum(axis=-1, keepdims=True), 1)), -np.inf)


class PathSearch:
    """The hypothesis search shared by `agile-kf` and `renewal-ml` (see the module doc).

    beam: hypotheses kept; lag: pulses of look-ahead before a label is final; gate: the overdue test's
    width in predicted standard deviations; switch: the per-pulse model switching probability; bank:
    "priors" (the named model, the default bank where none is named) or "default" (always the bank);
    identify, margin: after a source's `identify`-th pulse its bank keeps only the models within
    `margin` nats of the best one's evidence (0: never prune); reset_after: a source coasted through
    more arrivals than this in a row gets an arrival variance of at least PRI^2 / 12 (dokf's dropout
    reset), so a source that stops and restarts, or starts late, is acquired again.  Blind mode (where
    `blind_ok`): birth: the cost of a new track's first pulse (nats); pri_range: max/min PRI of the
    log-uniform prior on a new track's first interval."""

    blind_ok = False

    def __init__(self, beam: int = 1, lag: int = 0, gate: float = 5.0, switch: float = 0.01, bank: str = "priors",
                 identify: int = 100, margin: float = 20.0, reset_after: int = 4, birth: float = 10.0,
                 pri_range: float = 100.0):
        if not isinstance(beam, int) or isinstance(beam, bool) or not 1 <= beam <= 4096:
            raise ValueError(f"beam={beam!r} must be an integer in [1, 4096]")
        if not isinstance(lag, int) or isinstance(lag, bool) or not 0 <= lag <= 256:
            raise ValueError(f"lag={lag!r} must be an integer in [0, 256]")
        if not gate > 0:
            raise ValueError(f"gate={gate!r} must be > 0")
        if not 0 <= switch < 1:
            raise ValueError(f"switch={switch!r} must be in [0, 1)")
        if bank not in ("priors", "default"):
            raise ValueError(f"bank={bank!r} must be 'priors' or 'default'")
        if not isinstance(identify, int) or isinstance(identify, bool) or identify < 0:
            raise ValueError(f"identify={identify!r} must be an integer >= 0 (0: never prune the bank)")
        if not margin > 0:
            raise ValueError(f"margin={margin!r} must be > 0")
        self.beam, self.lag, self.gate, self.switch, self.bank_mode = beam, lag, float(gate), float(switch), bank
        if not isinstance(reset_after, int) or isinstance(reset_after, bool) or reset_after < 1:
            raise ValueError(f"reset_after={reset_after!r} must be an integer >= 1")
        self.identify, self.margin, self.reset_after = identify, float(margin), reset_after
        if not pri_range > 1:
            raise ValueError(f"pri_range={pri_range!r} must be > 1")
        self.birth, self.pri_range = float(birth), float(pri_range)

    # ---- setup ---------------------------------------------------------------------------------
    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        n = self.n = priors.n_labels
        self.blind = priors.blind
        if self.blind:  # tracks are born from the pulses: constant PRIs, set by each track's first interval
            if not self.blind_ok:
                raise NotApplicable(f"{type(self).__name__} needs priors; blind scenarios have none")
            period = np.ones(n)
            banks = [(pri_models.constant(),)] * n
            phase, phase_std = np.zeros(n), np.ones(n)
            if not priors.jitter_std > 0:  # nothing else sets the scale of a track's errors
                raise DeintError("renewal-ml in blind mode needs the TOA jitter: give a priors file "
                                 '{"blind": true, "label_budget": N, "jitter_std": S} (S > 0)')
            self.r = priors.jitter_std ** 2
        else:
            period = np.asarray(priors.period, dtype=np.float64)
            named = priors.modulation if self.bank_mode == "priors" else None
            banks = [(pri_models.from_modulation(named[i], float(period[i])),) if named is not None
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
        self.last = np.full((1, n), np.nan)  # the last pulse taken
        self.y0 = None
        self.cost = np.zeros(1)
        self.first = np.full((1, n), np.nan)  # first pulse taken (the phase estimate)
        self.history = np.zeros((1, self.lag + 1), dtype=np.int64)  # labels of pulses k - lag .. k
        self.k = -1  # last pulse seen
        self.steps = 0
        self._m = m
        self._mixing = bool((self.arrays.same_family & ~np.eye(m, dtype=bool)).any())  # any IMM family

    # ---- the filter steps ---------------------------------------------------------------------------
    def _advance(self, mask: np.ndarray) -> None:
        """Every model of the (hypothesis, source) pairs in `mask` (H, N) predicts its next emission."""
        if not mask.any():
            return
        a = self.arrays
        h, i = np.nonzero(mask)
        f = a.transition(self.count)[h, i]  # only the pairs that advance
        pred = linear_predict(LinearBlock(self.state.x[h, i], self.state.p[h, i]), f, a.q[i], a.c[i])
        x, p = self.state.x.copy(), self.state.p.copy()
        x[h, i], p[h, i] = pred.x, pred.p
        self.state = LinearBlock(x, p)
        self.count = self.count + mask

    def _best_model(self) -> np.ndarray:
        return np.argmax(self.logw, axis=2)  # (H, N)

    def _coast(self, y: float) -> None:
        """MK94 VI-C-3 (`kalman.overdue` on each source's most probable model): sources whose next
        emission is overdue at y predict through it without a measurement, at -log p_miss each."""
        for _ in range(_MAX_COAST):
            best = self._best_model()[..., None]
            x = np.take_along_axis(self.state.x, best[..., None], axis=2)[:, :, 0]  # (H, N, D+1)
            var = np.take_along_axis(self.state.p[..., TAU, TAU], best, axis=2)[:, :, 0]
            phi = np.take_along_axis(self.arrays.regressor(self.count), best[..., None], axis=2)[:, :, 0]
            pri = np.einsum("hnd,hnd->hn", phi, x[..., 1:])
            late = y - x[..., TAU] > self.gate * np.sqrt(var + self.r) + 0.5 * pri
            if self.blind:  # a track with fewer than two pulses has no PRI yet: it waits
                late &= self.taken >= 2
            if not late.any():
                return
            self.cost = self.cost + self.miss_cost * late.sum(axis=1)
            self._advance(late)
            self.missed = self.missed + late
            lost = late & (self.missed > self.reset_after)
            if lost.any():  # a dropout (or a late start): open the arrival up to a whole PRI (as dokf)
                p = self.state.p.copy()
                floor = (pri[lost] ** 2 / 12.0)[:, None]
                p[lost, :, TAU, TAU] = np.maximum(p[lost, :, TAU, TAU], floor)
                self.state = LinearBlock(self.state.x, p)

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
        self._coast(y)
        e, s = linear_innovation(self.state, y, TAU, self.r)  # (H, N, M)
        with np.errstate(invalid="ignore", divide="ignore"):  # pruned models' states are left to drift
            ll = np.where(self.alive, -0.5 * (_LOG_2PI + np.log(s) + e * e / s), -np.inf)  # predictive log-density
        joint = self.logw + np.where(self.alive, ll, -np.inf)
        top = joint.max(axis=2, keepdims=True)
        src_ll = (top + np.log(np.exp(joint - top).sum(axis=2, keepdims=True)))[..., 0]  # (H, N)
        ext = self.cost[:, None] - src_ll + self.hit_cost
        if self.blind:
            ext = self._blind_costs(ext, y)
        if self.spurious_cost is not None:
            ext = np.concatenate([ext, self.cost[:, None] + self.spurious_cost], axis=1)
        flat = ext.ravel()
        keep = min(self.beam, flat.size)
        pick = np.argpartition(flat, keep - 1)[:keep] if keep < flat.size else np.arange(flat.size)
        pick = pick[np.argsort(flat[pick], kind="stable")]
        h, j = np.divmod(pick, ext.shape[1])
        self.cost = flat[pick]
        self.state = self.state.take(h)
        self.count, self.logw, self.first = self.count[h], self.logw[h], self.first[h].copy()
        self.alive, self.evidence, self.taken = self.alive[h], self.evidence[h], self.taken[h]
        self.missed, self.last = self.missed[h].copy(), self.last[h].copy()
        self.history = np.concatenate([self.history[h, 1:], j[:, None]], axis=1)
        took = j < self.n
        if self.blind and took.any():
            took = self._acquire(took, j, y)
        if took.any():
            rows, src = np.nonzero(took)[0], j[took]
            sub = LinearBlock(self.state.x[rows, src], self.state.p[rows, src])
            upd = linear_update(sub, e[h[rows], src], s[h[rows], src], TAU, self.r)
            x, p = self.state.x.copy(), self.state.p.copy()
            x[rows, src], p[rows, src] = upd.x, upd.p
            self.state = LinearBlock(x, p)
            # model probabilities: Bayes on the pulse, then the switching mix (IMM's Markov step)
            self._identify(rows, src, ll[h[rows], src])
            alive = self.alive[rows, src]
            w = np.where(alive, self.logw[rows, src] + ll[h[rows], src], -np.inf)
            w -= w.max(axis=1, keepdims=True)
            w -= np.log(np.exp(w).sum(axis=1, keepdims=True))
            if self.switch > 0 and self._mixing:
                self._mix(rows, src, w, alive)
                w = np.logaddexp(math.log1p(-self.switch) + w, math.log(self.switch) + _uniform_log(alive))
            self.logw = self.logw.copy()
            self.logw[rows, src] = w
            self.first[rows, src] = np.where(np.isnan(self.first[rows, src]), y, self.first[rows, src])
            self.missed[rows, src] = 0
            self.last[rows, src] = y
            mask = np.zeros(took.shape + (self.n,), dtype=bool)
            mask[rows, src] = True
            self._advance(mask)

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
        self.evidence = self.evidence.copy()
        self.evidence[rows, src] += np.where(self.alive[rows, src], ll, 0.0)
        self.taken = self.taken.copy()
        self.taken[rows, src] += 1
        due = self.taken[rows, src] == self.identify
        if self.identify and due.any():
            r, i = rows[due], src[due]
            ev = np.where(self.alive[r, i], self.evidence[r, i], -np.inf)
            self.alive = self.alive.copy()
            self.alive[r, i] &= ev >= ev.max(axis=1, keepdims=True) - self.margin
            self.logw = self.logw.copy()
            self.logw[r, i] = np.where(self.alive[r, i], self.logw[r, i], -np.inf)

    def _mix(self, rows: np.ndarray, src: np.ndarray, logw: np.ndarray, alive: np.ndarray) -> None:
        """IMM's interaction step (Blom & Bar-Shalom) within each model family: model j restarts from
        the mix of the family's states weighted by p_ij mu_i, with p = (1 - switch) I + switch U."""
        mu = np.exp(logw)  # (R, M)
        valid = alive
        trans = (1 - self.switch) * np.eye(self._m) + self.switch * valid[:, None, :] / valid.sum(axis=1)[:, None, None]
        wij = np.where(self.arrays.same_family[src], trans * mu[:, :, None], 0.0)  # (R, i, j)
        if not (wij.sum(axis=1) > 0).all():
            wij = wij + np.eye(self._m) * 1e-300
        wij /= wij.sum(axis=1, keepdims=True)
        x, p = self.state.x[rows, src], self.state.p[rows, src]  # (R, M, D+1[, D+1])
        r, m, d = x.shape
        wt = np.swapaxes(wij, 1, 2)  # (R, j, i)
        x0 = wt @ x  # mixed means
        p0 = np.empty_like(p)
        for j in range(m):  # sum_i w_ij (P_i + dx dx'), dx = x_i - x0_j: positive by construction
            dx = x - x0[:, j:j + 1]
            spread = (p + dx[..., :, None] * dx[..., None, :]).reshape(r, m, d * d)
            p0[:, j] = (wt[:, j:j + 1] @ spread).reshape(r, d, d)
        self.state.x[rows, src], self.state.p[rows, src] = x0, p0

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

    def __init__(self, gate: float = 5.0, switch: float = 0.01, bank: str = "priors", identify: int = 100,
                 margin: float = 20.0, reset_after: int = 4):
        super().__init__(beam=1, lag=0, gate=gate, switch=switch, bank=bank, identify=identify, margin=margin,
                         reset_after=reset_after)


class RenewalML(PathSearch):
    """`renewal-ml`: Young et al.'s ML path search, a beam of `beam` hypotheses decided at lag `lag`;
    in blind mode tracks are born from the pulses (`birth`, `pri_range`: see `PathSearch`)."""

    blind_ok = True

    def __init__(self, beam: int = 64, lag: int = 16, gate: float = 5.0, switch: float = 0.01, bank: str = "priors",
                 identify: int = 100, margin: float = 20.0, reset_after: int = 4, birth: float = 10.0,
                 pri_range: float = 100.0):
        super().__init__(beam=beam, lag=lag, gate=gate, switch=switch, bank=bank, identify=identify, margin=margin,
                         reset_after=reset_after, birth=birth, pri_range=pri_range)

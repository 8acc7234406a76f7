"""Forward dynamic programming with look-ahead (MK94 section III), its missing- and supernumerary-pulse
modifications (section VI-A) and dropout/onset handling (section VI-C-3), run online with lag Delta.

State (section III): for each source i the best sequence ending in source i at pulse k, its cost
r_k^i and its KF state (the per-source blocks of `baselines.kalman`).  Step 1 evaluates the
prediction-error costs J (3.1) of all N^(Delta+1) continuations s_k..s_{k+Delta} over y_k..y_{k+Delta}
and keeps the minimum c_ij per (s_k, s_{k+1}) = (i, j); step 2 is the FDP recursion (3.2),
phi^j = argmin_i (c_ij + r_k^i); step 3 carries the KF of the chosen survivor (3.3).

Reading of (3.2).  By default (`accumulate="lookahead"`) the costs accumulate as published,
r_{k+1}^j = min_i (c_ij + r_k^i): each survivor's cost carries its best look-ahead cost, so every
look-ahead error is counted again at each later pulse.  On MK94's Fig. 4/5 sweep (Delta = 3, Sigma_{1|0}
= I) this is within 0.006 of the genie's P_e up to sigma_w^2 = 1 on the ten test seeds; from 1.5 on
some start-ups are lost for good (8 and 13 of 100 train seeds at 1.5 and 2; `deint reproduce
mk94-fig4-5`), where the prior T2 = 22 (true 17) lets the early pulses fit the swapped sources.
`accumulate="sequence"` is
the other reading of "the cost of the best sequence ending in source i": r accumulates the errors of
the sequence itself, r_{k+1}^j = r_k^phi + e_{k+1}^2, while c_ij only choose phi; under it a look-ahead
as long as the data *is* the optimal tree search (2.19) (tests check that).  The first pulse's own
error starts the costs (r_1^i = e_1^2 under source i, where the paper writes 0) for the same reason.

Initialisation (2.3).  By default a source's first pulse is predicted at its phase (blocks start at
tau = phi - T, docs/design.md section 8).  `init="mk94"` is the literal (2.3): tau_1 = phi, the first received
pulse predicted at the phase of its source and every other source's first pulse at phi + T.

Decisions are fixed-lag: pulse k is labelled when y_{k+Delta} arrives, with s_k of the best
(i, j) = argmin (r_k^i + c_ij).

Two engines compute the same recursion with the same arithmetic in the same order, so their labels
are identical bit for bit (tested on every option, and on 313 core-v0/paper-v0 runs against the
fdp published before the compiled core).  `engine="compiled"` (default): numba functions walk the
tree depth first on one node per level (each level's update undone on the way back), rebuilding it
at every pulse; the deepest level needs costs only.  A plain fdp step is one compiled call; the VI
options drive the same functions through `CompiledFDPCore.tree`/`commit`.  Its interpreted form
(`.py_func`) gives the same labels (tested).  numba is a core dependency (the blind deinterleavers
and `mht` need it too).  `engine="numpy"`: the batched-numpy form, the tree computed level by level
over all hypotheses at once; `reuse=True` keeps the subtrees of the chosen survivors (at pulse k+1
exactly the top Delta levels of the new tree) and computes only the new deepest level,
`reuse=False` rebuilds it.  It is kept as the reference the compiled engine is tested and
benchmarked against (`benchmarks/bench_fdp.py`).

Gating (`tree_gate=g`, compiled engine; default None: the full tree, as published).  A continuation
is kept only when its source predicts the pulse within g innovation deviations, e^2 <= g^2 S with
S from the KF (2.15), as `mht` gates its candidates; a node none of whose sources gates the pulse
keeps its nearest one (FDP labels every pulse), and only live survivors (finite cost) are
expanded.  Where the gate removes no continuation that matters, the labels are the full tree's
(tested); a pulse then costs O(gated continuations) instead of N^(Delta+1) block updates.  With
`dropout` the sources coast through missed arrivals before the tree is built, so the gate is the
k-step one.  Gating is not the default: the published MK94 start-ups (e.g. Fig. 4/5's prior T2 = 22
for a true 17 with Sigma_{1|0} = I) put early pulses far outside any narrow gate.

Robust start (`start="lookahead"`, issue 10; default "prior").  In a dense scene (16 sources, phase
priors 5 % of a period) many first arrivals fall within each other's phase gates, and an FDP started
from the priors' phases puts some source on a neighbour's pulse and never recovers: measured on
scale-10000p-16s, accuracy 0.06-0.10 (chance); started from the true first pulses, 0.93-0.94 (genie
0.944).  `initiate` picks each source's first pulse by look-ahead (a chain search over its next
`start_look` arrivals) and hands the FDP priors with those phases known to the jitter.  It waits for
that look-ahead to be buffered, so the policy's lag is `start_lag` pulses (labels come that much
later; the decisions are the FDP's).  Sources with an unknown phase keep their priors.

Section VI-A (`missing=True`): J-bar is also evaluated on {y_k, y_k, y_{k+1}, .., y_{k+Delta-1}}, i.e.
y_k received for two sources at once (coincident pulses merged); when min c-bar < min c the pulse is
taken twice (we allow at most one repeat per received pulse).  `supernumerary=True`: J-bar on
{y_{k+1}, .., y_{k+Delta+1}}; when it wins, y_k is labelled spurious and the decision is the one on the
shifted window (so y_{k+1} is decided too and the next step is k+2, as published).  As published the
test has no price for calling a pulse extra, and it cascades: once a genuine pulse is dropped, its
source's next prediction is a period off and dropping keeps winning (measured on robust-v0: accuracy
0.19-0.28 against 0.35-0.97 without it).  `spurious_penalty` (in units of R, default 0 = as
published) is added to c-bar, e.g. 2 ln((1 - lambda) / lambda) for a spurious probability lambda.  Section VI-C-3
(`dropout=True`): a source whose predicted arrival is overdue by more than `gate` standard deviations
is coasted: the KF predicts through the missed arrivals with no measurement (its covariance grows),
so a source that stops, starts late or misses pulses is picked up where it is.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from baselines.fdp_start import _START_GATE, initiate
from baselines.jit_cache import guard
from baselines.kalman import Block, DLMModel, innovation, overdue, predict, prior_block, update
from baselines.kalman_jit import kf_predict, kf_update
from deint_env.episode import DEFAULT_WIDTH_REL, Priors
from deint_env.errors import NotApplicable, check
from deint_env.params import Param, ParamSet, declare

# Node state: per hypothesis, per source, these fields (the block, then pulses assigned so far).
PERIOD, TAU, P_TT, P_TX, P_XX, COUNT = range(6)
_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
# The most S the likelihood cost counts while the widths are guessed, in R (`FDPLikelihood`): the spread of the
# prediction of a source's period and phase fitted to its first n = 4 pulses alone, R (1 + 1/n + 3 (n+1) / (n (n-1))).
_GUESSED_S_CAP = 2.5


def _widths_guessed(priors: Priors) -> bool:
    """The priors state neither deviation: both are the parser's guess, 5 % of each period (simulated
    episodes' priors state theirs, and no suite's equal that guess).  The priors carry no flag for it."""
    guess = DEFAULT_WIDTH_REL * priors.period
    known = np.isfinite(priors.phase)
    return bool(np.array_equal(priors.period_std, guess) and np.array_equal(priors.phase_std[known], guess[known]))


def _block(b: np.ndarray) -> Block:
    return Block(b[..., PERIOD], b[..., TAU], b[..., P_TT], b[..., P_TX], b[..., P_XX])


def _fire(nodes: np.ndarray, src: np.ndarray, y: float, model: DLMModel, likelihood: bool, s_cap: float,
          no_predict: bool = False) -> np.ndarray:
    """Each node's source `src` emits pulse y: predict, innovate, update (in place).  Returns the
    cost of the pulse: e^2 (MK94 (2.18)), or e^2 / S + log S with `likelihood` (S counted as at most
    `s_cap`)."""
    rows = np.arange(nodes.shape[0])
    b = nodes[rows, src]  # (M, fields): a copy of the firing blocks
    pred = _block(b) if no_predict else predict(_block(b), model)
    e, s = innovation(pred, y, model)
    b[:, PERIOD], b[:, TAU], b[:, P_TT], b[:, P_TX], b[:, P_XX] = update(pred, e, s, model)
    b[:, COUNT] += 1.0
    nodes[rows, src] = b
    if not likelihood:
        return e * e
    s = np.minimum(s, s_cap)
    return e * e / s + np.log(s)


class FDPCore:
    """The FDP recursion: survivors `surv` (N survivors, N sources, fields), costs `r` (N,), and
    (with reuse) the kept tree `levels` = [(nodes, cost)] for y_k .. y_{k+D}.  The likelihood cost counts
    S as at most `s_cap_r` R (`FDPLikelihood`)."""

    def __init__(self, priors: Priors, accumulate: str, reuse: bool, likelihood: bool, init: str,
                 s_cap_r: float = math.inf):
        self.n = priors.n_labels
        self.accumulate, self.reuse, self.likelihood = accumulate, reuse, likelihood
        self.model = DLMModel.from_priors(priors, min_jitter=_MIN_JITTER_REL * float(np.min(priors.period)))
        self.s_cap = s_cap_r * self.model.jitter_var
        b = prior_block(priors)
        one = np.stack([b.period, b.tau, b.p_tt, b.p_tx, b.p_xx, np.zeros(self.n)], axis=-1)
        if init == "mk94":  # (2.3) literally: tau_1 = phi with the phase's variance
            one[:, TAU] = b.tau + b.period
            one[:, P_TX] = 0.0
            one[:, P_XX] = b.p_xx - b.p_tt
        self.first_no_predict = init == "mk94"
        self.surv = np.repeat(one[None], self.n, axis=0)  # survivor i: every source at its prior
        self.r: np.ndarray | None = None  # set by the first pulse
        self.levels: list[tuple[np.ndarray, np.ndarray]] = []

    def tree(self, ys: list[float]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Levels 0..D of the continuation tree over ys = [y_k, .., y_{k+D}] (reused when kept)."""
        d = len(ys) - 1
        if self.reuse and len(self.levels) == d + 1:
            return self.levels
        if self.reuse and len(self.levels) == d and d > 0:  # the kept tree lacks only its deepest level
            self.levels.append(self._children(self.levels[-1][0], ys[-1]))
            return self.levels
        nodes = self.surv.copy()
        first = self.r is None and self.first_no_predict
        levels = [(nodes, _fire(nodes, np.arange(self.n), ys[0], self.model, self.likelihood, self.s_cap, first))]
        for y in ys[1:]:
            levels.append(self._children(levels[-1][0], y))
        return levels

    def _children(self, parent: np.ndarray, y: float) -> tuple[np.ndarray, np.ndarray]:
        n = self.n
        nodes = np.repeat(parent, n, axis=0)
        return nodes, _fire(nodes, np.tile(np.arange(n), parent.shape[0]), y, self.model, self.likelihood,
                            self.s_cap)

    def lookahead_costs(self, levels) -> np.ndarray:
        """c_ij: the least look-ahead cost J (3.1) of the continuations with s_k = i, s_{k+1} = j,
        summed level by level in a fixed order (a reused tree gives the same sums as a rebuilt one)."""
        n, d = self.n, len(levels) - 1
        total = levels[1][1].reshape((n, n) + (1,) * (d - 1))
        for lev in range(2, d + 1):
            total = total + levels[lev][1].reshape((n,) * (lev + 1) + (1,) * (d - lev))
        return total.reshape(n, n, -1).min(axis=2)

    def commit(self, levels, c: np.ndarray | None) -> int:
        """Step 2-3 with look-ahead costs c (None: the last pulse).  Returns the label of pulse k."""
        n = self.n
        level0, cost0 = levels[0]
        if self.r is None:
            self.r = cost0.copy()  # the first pulse's own error starts the costs
        if c is None:
            self.levels = []
            return int(np.argmin(self.r))
        tot = self.r[:, None] + c
        phi = np.argmin(tot, axis=0)  # (3.2)
        cols = np.arange(n)
        best = tot[phi, cols]
        label = int(phi[int(np.argmin(best))])
        self.r = best if self.accumulate == "lookahead" else self.r[phi] + levels[1][1].reshape(n, n)[phi, cols]
        self.surv = level0[phi]  # (3.3): survivor j continues the KF of survivor phi^j after y_k
        # survivor j's subtree (rooted at node (phi^j, j)) is the top of the next tree
        self.levels = [(nodes.reshape((n, n, -1) + nodes.shape[1:])[phi, cols].reshape((-1,) + nodes.shape[1:]),
                        cost.reshape(n, n, -1)[phi, cols].reshape(-1)) for nodes, cost in levels[1:]] \
            if self.reuse else []
        return label

    def coast(self, y: float, gate: float) -> None:
        """Section VI-C-3: predict every source overdue at y by more than `gate` sigmas through its
        missed arrivals, without measurements (its variance grows, so it can be picked up again)."""
        s = self.surv
        m = self.model
        for _ in range(64):  # each pass skips one more missed arrival of every still-overdue source
            nxt = predict(_block(s), m)
            late = overdue(nxt, y, m, gate)
            if not late.any():
                break
            for f, v in zip((PERIOD, TAU, P_TT, P_TX, P_XX), nxt):
                s[..., f] = np.where(late, v, s[..., f])
        self.levels = []  # the survivors changed: a kept tree no longer applies

    def best_state(self) -> np.ndarray:
        return self.surv[int(np.argmin(self.r))] if self.r is not None else self.surv[0]


# ---- the compiled core ---------------------------------------------------------------------------
# Model scalars for the compiled functions, packed in one float array (one argument for numba).
_JV, _ALPHA, _DRIFT, _IVAR, _GATE2, _LL, _SEQ, _SCAP = range(8)


@njit(cache=True, nogil=True)
def _predict(t, tau, ptt, ptx, pxx, par):
    """`kalman.predict` ((2.8) and II-C-2's noises) on one block (`kf_predict`), the model's scalars from `par`."""
    return kf_predict(t, tau, ptt, ptx, pxx, par[_ALPHA], par[_DRIFT], par[_IVAR])


@njit(cache=True, nogil=True)
def _emit(node, i, y, par, no_predict):
    """Source i of `node` (N, fields) emits y: predict, innovate, update (2.15) in place, as
    `kalman.update` writes it.  Returns the pulse's cost (MK94 (2.18) e^2, or e^2 / S + log S with S
    counted as at most par[_SCAP])."""
    t, tau, ptt, ptx, pxx = node[i, PERIOD], node[i, TAU], node[i, P_TT], node[i, P_TX], node[i, P_XX]
    if not no_predict:
        t, tau, ptt, ptx, pxx = _predict(t, tau, ptt, ptx, pxx, par)
    e = y - tau
    s = pxx + par[_JV]
    node[i, PERIOD], node[i, TAU], node[i, P_TT], node[i, P_TX], node[i, P_XX] = kf_update(t, tau, ptt, ptx, pxx, e,
                                                                                          s, par[_JV])
    node[i, COUNT] += 1.0
    if par[_LL] != 0.0:
        s = min(s, par[_SCAP])
        return e * e / s + math.log(s)
    return e * e


@njit(cache=True, nogil=True)
def _children(node, y, par, cand, lev):
    """The sources of `node` that may emit y (into cand[lev]): those within the gate (e^2 <= g^2 S),
    or, when none is, the nearest (FDP labels every pulse, so a node always has a child).  Returns
    how many."""
    n = node.shape[0]
    m = 0
    best, near = np.inf, 0
    for j in range(n):
        t, tau, ptt, ptx, pxx = _predict(node[j, PERIOD], node[j, TAU], node[j, P_TT], node[j, P_TX],
                                         node[j, P_XX], par)
        e = y - tau
        z = e * e / (pxx + par[_JV])
        if z <= par[_GATE2]:
            cand[lev, m] = j
            m += 1
        if z < best:
            best, near = z, j
    if m == 0:
        cand[lev, 0] = near
        m = 1
    return m


@njit(cache=True, nogil=True)
def _leaves(node, y, par, base, lev, c, cost1, i, j1):
    """The deepest level below `node`: each gated child's cost (`_emit`'s, without the update no
    later level needs) added to the path's `base`, the least into c[i, j1] (and cost1 at level 1)."""
    n = node.shape[0]
    best, near, near_cost = np.inf, 0, 0.0
    found = False
    for j in range(n):
        t, tau, ptt, ptx, pxx = _predict(node[j, PERIOD], node[j, TAU], node[j, P_TT], node[j, P_TX],
                                         node[j, P_XX], par)
        e = y - tau
        s = pxx + par[_JV]
        z = e * e / s
        if par[_LL] != 0.0:
            s = min(s, par[_SCAP])
            cost = e * e / s + math.log(s)
        else:
            cost = e * e
        if z < best:
            best, near, near_cost = z, j, cost
        if z <= par[_GATE2]:
            found = True
            _leaf(c, cost1, i, j1, j, lev, base, cost)
    if not found:
        _leaf(c, cost1, i, j1, near, lev, base, near_cost)


@njit(cache=True, nogil=True)
def _leaf(c, cost1, i, j1, j, lev, base, cost):
    if lev == 1:
        cost1[i, j] = cost
        j1 = j
        total = cost
    else:
        total = base + cost
    if total < c[i, j1]:
        c[i, j1] = total


@njit(cache=True, nogil=True)
def _lookahead(surv, r, started, ys, no_predict, par, level0, cost0, c, cost1):
    """Step 1 of MK94 III over the window ys = y_k .. y_{k+D}: level 0 (survivor i's source i emits y_k,
    into level0[i], its cost cost0[i]), and c[i, j] = the least look-ahead cost J (3.1) of the
    continuations with s_k = i, s_{k+1} = j (cost1[i, j]: the cost of y_{k+1} there).  The tree is
    walked depth first on one node, each level's firing undone on the way back, with the costs summed
    from level 1 down in the order `FDPCore.lookahead_costs` sums them.  Only live survivors (finite
    cost; all at the first pulse) are expanded, and only gated children (`_children`); with an
    infinite gate this is the full tree.  Unreached entries stay inf."""
    n = surv.shape[0]
    d = ys.size - 1
    c[:, :] = np.inf
    cost1[:, :] = np.inf
    cost0[:] = np.inf
    cand = np.empty((d + 1, n), np.int64)
    count = np.zeros(d + 1, np.int64)
    ptr = np.zeros(d + 1, np.int64)
    fired = np.zeros(d + 1, np.int64)
    total = np.zeros(d + 1)
    saved = np.empty((d + 1, 6))
    node = np.empty((n, 6))
    live = np.zeros(n, np.bool_)
    if started:
        for i in range(n):
            live[i] = r[i] < np.inf
    elif par[_GATE2] < np.inf:  # the first pulse: the survivors are identical, so gate y_k on one
        for q in range(_children(surv[0], ys[0], par, cand, 0)):
            live[cand[0, q]] = True
    else:
        live[:] = True
    for i in range(n):
        if not live[i]:
            continue
        for q in range(n):
            for f in range(6):
                level0[i, q, f] = surv[i, q, f]
        cost0[i] = _emit(level0[i], i, ys[0], par, no_predict)
        if d == 0:
            continue
        if d == 1:
            _leaves(level0[i], ys[1], par, 0.0, 1, c, cost1, i, 0)
            continue
        for q in range(n):
            for f in range(6):
                node[q, f] = level0[i, q, f]
        lev = 1
        count[1] = _children(node, ys[1], par, cand, 1)
        ptr[1] = 0
        while lev > 0:
            if ptr[lev] == count[lev]:  # this level is done: undo its parent's firing
                lev -= 1
                if lev > 0:
                    for f in range(6):
                        node[fired[lev], f] = saved[lev, f]
                continue
            j = cand[lev, ptr[lev]]
            ptr[lev] += 1
            fired[lev] = j
            for f in range(6):
                saved[lev, f] = node[j, f]
            cost = _emit(node, j, ys[lev], par, False)
            total[lev] = cost if lev == 1 else total[lev - 1] + cost
            if lev == 1:
                cost1[i, j] = cost
            if lev + 1 == d:  # the next level is the deepest: costs only
                _leaves(node, ys[d], par, total[lev], d, c, cost1, i, fired[1])
                for f in range(6):
                    node[j, f] = saved[lev, f]
            else:
                lev += 1
                count[lev] = _children(node, ys[lev], par, cand, lev)
                ptr[lev] = 0


@njit(cache=True, nogil=True)
def _commit(surv, r, level0, c, cost1, par):
    """Steps 2-3: phi^j = argmin_i (c_ij + r_k^i) (3.2), the new costs, survivor j = the KF of
    survivor phi^j after y_k (3.3).  Returns the label of pulse k: s_k of argmin_ij (r_k^i + c_ij).
    Ties go to the lowest index, as numpy's argmin."""
    n = surv.shape[0]
    best = np.empty(n)
    phi = np.empty(n, np.int64)
    for j in range(n):
        b, p = r[0] + c[0, j], 0
        for i in range(1, n):
            v = r[i] + c[i, j]
            if v < b:
                b, p = v, i
        best[j], phi[j] = b, p
    top = 0
    for j in range(1, n):
        if best[j] < best[top]:
            top = j
    label = phi[top]
    new_r = np.empty(n)
    for j in range(n):
        new_r[j] = best[j] if par[_SEQ] == 0.0 else r[phi[j]] + cost1[phi[j], j]
    for j in range(n):
        if new_r[j] < np.inf:
            surv[j] = level0[phi[j]]
    r[:] = new_r
    return label


class Lookahead(NamedTuple):
    """Step 1's results at pulse k: level 0 (N survivors' states after y_k, and its cost), c_ij (3.1)
    and the cost of y_{k+1} under each (i, j).  Entries of pruned or dead survivors are inf."""

    level0: np.ndarray
    cost0: np.ndarray
    c: np.ndarray
    cost1: np.ndarray


class CompiledFDPCore(FDPCore):
    """The FDP recursion compiled (`_lookahead`, `_commit`), the same arithmetic in the same order as
    `FDPCore` (the batched-numpy form), so the labels are the same bit for bit; `gate` (in innovation
    deviations, inf: the full tree) keeps only continuations whose source predicts the pulse within
    it, as `mht` gates its candidates, so a pulse costs O(gated continuations), not O(N^(Delta+1)).
    The tree is rebuilt at every pulse, depth first without being stored (keeping it, as the numpy
    form's `reuse` does, would save only its upper levels, a fraction of the N^(Delta+1) leaves)."""

    def __init__(self, priors: Priors, accumulate: str, likelihood: bool, init: str, gate: float,
                 s_cap_r: float = math.inf):
        super().__init__(priors, accumulate, False, likelihood, init, s_cap_r)
        m = self.model
        self.par = np.array([m.jitter_var, m.alpha, m.drift_var, m.interval_var, gate * gate, float(likelihood),
                             float(accumulate == "sequence"), self.s_cap])
        self.r = np.zeros(self.n)
        self.started = False
        self.work = self._empty()

    def _empty(self) -> Lookahead:
        n = self.n
        return Lookahead(np.empty_like(self.surv), np.empty(n), np.empty((n, n)), np.empty((n, n)))

    def _no_predict(self) -> bool:
        return not self.started and self.first_no_predict

    def tree(self, ys: list[float]) -> Lookahead:
        out = self._empty()
        _lookahead(self.surv, self.r, self.started, np.asarray(ys, dtype=np.float64), self._no_predict(), self.par,
                   *out)
        return out

    def lookahead_costs(self, levels: Lookahead) -> np.ndarray:
        return levels.c

    def commit(self, levels: Lookahead, c: np.ndarray | None) -> int:
        if not self.started:
            self.r[:] = levels.cost0  # the first pulse's own error starts the costs
            self.started = True
        if c is None:
            return int(np.argmin(self.r))
        return int(_commit(self.surv, self.r, levels.level0, c, levels.cost1, self.par))

    def decide(self, ys: np.ndarray) -> int:
        """tree + commit in one compiled call (the plain FDP's whole step)."""
        started = self.started
        self.started = True
        return _decide(self.surv, self.r, started, ys, not started and self.first_no_predict, self.par, *self.work)

    def decide_all(self, toa: np.ndarray, d: int) -> np.ndarray:
        """`decide` over every pulse of `toa` in turn, each with the next `d` pulses as its look-ahead (the
        labels pulse-by-pulse calls give), in one compiled call: a call's own cost is a few us."""
        labels = np.empty(toa.size, np.int64)
        _decide_all(self.surv, self.r, self.started, toa, d, self.first_no_predict, self.par, labels, *self.work)
        self.started = self.started or toa.size > 0
        return labels

    def best_state(self) -> np.ndarray:
        return self.surv[int(np.argmin(self.r))] if self.started else self.surv[0]


@njit(cache=True, nogil=True)
def _decide_all(surv, r, started, toa, d, first_no_predict, par, labels, level0, cost0, c, cost1):
    end = toa.size
    for k in range(end):
        labels[k] = _decide(surv, r, started, toa[k:min(k + d + 1, end)], not started and first_no_predict, par,
                            level0, cost0, c, cost1)
        started = True


@njit(cache=True, nogil=True)
def _decide(surv, r, started, ys, no_predict, par, level0, cost0, c, cost1):
    _lookahead(surv, r, started, ys, no_predict, par, level0, cost0, c, cost1)
    if not started:
        r[:] = cost0
    if ys.size == 1:
        return np.argmin(r)
    return _commit(surv, r, level0, c, cost1, par)


PARAMS = declare(
    Param("lookahead", int, 3, "the look-ahead Delta: pulses seen before a label is final", low=1, high=30),
    Param("accumulate", str, "lookahead", "the published (3.2) accumulation, or sequence",
          choices=("lookahead", "sequence")),
    Param("init", str, "phase", "the start: phase, or the literal mk94", choices=("phase", "mk94")),
    Param("cost", str, "raw", "raw squared errors (2.18), or likelihood: e^2/S + log S", choices=("raw", "likelihood")),
    Param("missing", bool, False, "VI-A: test for missing pulses"),
    Param("supernumerary", bool, False, "VI-A: test for supernumerary pulses (lag + 1)"),
    Param("spurious_penalty", float, 0.0, "VI-A: the cost of calling a pulse spurious", low=0),
    Param("dropout", bool, False, "VI-C-3: coast through missed arrivals"),
    Param("gate", float, 5.0, "VI-C-3: the coasting gate, in innovation standard deviations", low=0, low_open=True),
    Param("reuse", bool, True, "numpy engine: keep the tree between pulses (the same labels)"),
    Param("tree_gate", float, None, "only continuations predicting the pulse within this many deviations (none: "
          "the full tree; needs engine=compiled)", low=0, low_open=True, optional=True),
    Param("engine", str, "compiled", "compiled, or the batched-numpy reference numpy (the same labels)",
          choices=("compiled", "numpy")),
    Param("start", str, "prior", "prior, or lookahead: the robust start", choices=("prior", "lookahead")),
    # a tree search over the look-ahead (a hit or a miss per arrival), exponential in its depth: 30 ran 500 pulses
    # in 1 s, 50 and 10^5 did not end in 60 s; 20 as mht's look_start
    Param("start_look", int, 6, "arrivals the robust start looks ahead", low=1, high=20),
    Param("start_lag", int, 2048, "pulses the robust start may wait (at least lookahead + 1; the lag with "
          "start=lookahead)", low=2, high=100_000),
)


class FDP:
    """MK94 forward dynamic programming with look-ahead Delta (policies `fdp`, `fdp-ll`).

    Parameters: `lookahead` (Delta >= 1), `accumulate` (the published (3.2) "lookahead", or "sequence"),
    `init` ("phase" or the literal "mk94"), `cost` ("raw" squared errors (2.18), or "likelihood":
    e^2/S + log S, which weighs each error by its predicted spread; S capped while the priors' widths
    are guessed: `FDPLikelihood`), `missing` / `supernumerary` /
    `spurious_penalty` (section VI-A), `dropout` and `gate` (section VI-C-3: coasting through missed
    arrivals), `engine` ("compiled", or the batched-numpy reference "numpy"; the same labels), `reuse`
    (numpy engine: keep the tree; the same labels), `tree_gate` (None: the full tree; a number g: only
    continuations whose source predicts the pulse within g innovation deviations, what makes 16
    sources affordable), `start` ("prior", or "lookahead": the robust start), `start_look` (arrivals
    the start looks ahead), `start_lag` (pulses the start may wait: the lag with start="lookahead").
    The lag is Delta, or Delta + 1 with `supernumerary`, or `start_lag` with the robust start.
    For scale-v0's dense scenes: `fdp:tree_gate=4,start=lookahead`.  Declared: `PARAMS`.
    """

    PARAMS = PARAMS

    def __init__(self, lookahead: int = 3, accumulate: str = "lookahead", init: str = "phase", cost: str = "raw",
                 missing: bool = False, supernumerary: bool = False, spurious_penalty: float = 0.0,
                 dropout: bool = False, gate: float = 5.0, reuse: bool = True, tree_gate: float | None = None,
                 engine: str = "compiled", start: str = "prior", start_look: int = 6, start_lag: int = 2048):
        PARAMS.check(locals())
        check(tree_gate is None or engine == "compiled", "tree_gate", tree_gate,
              "none with engine=numpy (the numpy engine is the full tree)")
        check(start_lag >= lookahead + 1, "start_lag", start_lag, f"at least lookahead + 1 = {lookahead + 1}")
        self.tree_gate = None if tree_gate is None else float(tree_gate)
        self.spurious_penalty = float(spurious_penalty)
        self.lookahead, self.accumulate, self.init, self.cost = lookahead, accumulate, init, cost
        self.missing, self.supernumerary, self.dropout, self.gate = bool(missing), bool(supernumerary), \
            bool(dropout), float(gate)
        self.engine = engine
        self.start, self.start_look = start, start_look
        # the VI-A tests change the observation stream, which a kept tree cannot follow
        self.reuse = bool(reuse) and not (missing or supernumerary or dropout)
        self.plain = not (missing or supernumerary or dropout)
        self.lag = lookahead + (1 if supernumerary else 0)
        if start == "lookahead":  # the initiation waits for its look-ahead (at most start_lag pulses)
            self.lag = max(self.lag, start_lag)

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if self.tree_gate is None and float(priors.n_labels) ** (self.lookahead + 1) > 4e6:
            # refused before any work, as a scene outside the policy's reach (one line, not a traceback)
            raise NotApplicable(f"lookahead={self.lookahead} with {priors.n_labels} sources means "
                             f"{priors.n_labels}^{self.lookahead + 1} continuations a pulse; at most 4e6 "
                             f"(tree_gate keeps only the gated ones)")
        self.priors = priors
        # the likelihood's S cap (`FDPLikelihood`), judged on the priors as given: the robust start's
        # restart states the phases it found, not the periods' widths
        self.s_cap_r = _GUESSED_S_CAP if self.cost == "likelihood" and _widths_guessed(priors) else math.inf
        self.core = self._core(priors)
        self.initiated = self.start == "prior"
        # robust start: the pulses its look-ahead needs (`start_look` arrivals of every source after
        # its phase gate)
        t, s = priors.period, priors.period_std
        tail = np.where(np.isfinite(priors.phase), priors.phase + _START_GATE * priors.phase_std, -np.inf)
        self.start_horizon = float(np.max(tail + (self.start_look + 0.5) * (t + _START_GATE * s), initial=-np.inf))
        self.fast = self.plain and self.engine == "compiled"
        self.spurious = priors.n_labels
        self.ys: list[float] = []
        self.toa = np.zeros(1024)  # the received TOAs and the decided labels (the compiled plain path)
        self.decisions = np.zeros(1024, np.int64)
        self.n_seen = self.decided = 0
        self.stream: list[int] = []  # received index of each internal pulse (a merged pulse twice)
        self.pos = 0  # next internal pulse to decide
        self.labels: dict[int, int] = {}
        self.ended = False
        self.steps = 0

    def _core(self, priors: Priors) -> FDPCore:
        likelihood = self.cost == "likelihood"
        if self.engine == "numpy":
            return FDPCore(priors, self.accumulate, self.reuse, likelihood, self.init, self.s_cap_r)
        gate = math.inf if self.tree_gate is None else self.tree_gate
        return CompiledFDPCore(priors, self.accumulate, likelihood, self.init, gate, self.s_cap_r)

    def _initiate(self, toa: np.ndarray, newest_step: bool) -> None:
        """Robust start, once its look-ahead is buffered (or the lag or the stream's end forces it):
        the FDP restarts from the initiated priors (no pulse has been decided yet)."""
        if self.initiated or not (self.ended or newest_step or (toa.size and toa[-1] >= self.start_horizon)):
            return
        if toa.size:
            self.core = self._core(initiate(toa, self.priors, self.core.model, _START_GATE, self.start_look))
        self.initiated = True

    def act(self, obs: dict[str, Any]) -> int:
        if self.fast:
            return self._act_plain(obs)
        if int(obs["valid"]):
            self.ys.append(float(obs["toa"][0]))
            self.stream.append(len(self.ys) - 1)
        else:
            self.ended = True
        self._initiate(np.asarray(self.ys), self.steps >= self.lag)
        while self._ready():
            self._decide()
        self.steps += 1
        return self.labels.pop(self.steps - 1 - self.lag, 0)  # step t labels pulse t - lag

    def _act_plain(self, obs: dict[str, Any]) -> int:
        """Plain FDP (no VI options) on the compiled core: pulse k is decided over y_k .. y_{k+Delta}
        (fewer once the stream has ended) as soon as they are in, one compiled call a pulse."""
        if int(obs["valid"]):
            if self.n_seen == self.toa.size:
                self.toa = np.concatenate([self.toa, np.zeros(self.toa.size)])
                self.decisions = np.concatenate([self.decisions, np.zeros(self.decisions.size, np.int64)])
            self.toa[self.n_seen] = obs["toa"][0]
            self.n_seen += 1
        else:
            self.ended = True
        if not self.initiated:
            self._initiate(self.toa[:self.n_seen], self.steps >= self.lag)
        if self.initiated:
            d, n, decide = self.lookahead, self.n_seen, self.core.decide
            while self.decided < n and (self.ended or self.decided + d < n):
                k = self.decided
                self.decisions[k] = decide(self.toa[k:min(k + d + 1, n)])
                self.decided = k + 1
        t = self.steps - self.lag  # step t labels pulse t - lag
        self.steps += 1
        return int(self.decisions[t]) if 0 <= t < self.decided else 0

    def _ready(self) -> bool:
        """Enough look-ahead to decide the next internal pulse (all of it once the stream ended)."""
        need = self.lookahead + (1 if self.supernumerary else 0)
        return self.initiated and self.pos < len(self.stream) and (self.ended or self.pos + need < len(self.stream))

    def _window(self, start: int, length: int) -> list[float]:
        return [self.ys[j] for j in self.stream[start:start + length]]

    def _decide(self) -> None:
        core, p, d = self.core, self.pos, self.lookahead
        if self.dropout:
            core.coast(self.ys[self.stream[p]], self.gate)
        ys = self._window(p, d + 1)
        levels = core.tree(ys)
        c = core.lookahead_costs(levels) if len(ys) > 1 else None
        received = self.stream[p]
        if c is not None and self.missing and (p == 0 or self.stream[p - 1] != received):
            alt = self._window(p, 1) + self._window(p, d)  # {y_k, y_k, y_{k+1}, .., y_{k+D-1}}  (6.2)
            alt_levels = core.tree(alt)
            alt_c = core.lookahead_costs(alt_levels)
            if alt_c.min() < c.min():  # a missing (merged) pulse at k: take y_k twice
                self.stream.insert(p + 1, received)
                levels, c = alt_levels, alt_c
        if c is not None and self.supernumerary and len(ys) == d + 1 and p + d + 1 < len(self.stream):
            alt = self._window(p + 1, d + 1)  # {y_{k+1}, .., y_{k+D+1}}
            alt_levels = core.tree(alt)
            alt_c = core.lookahead_costs(alt_levels)
            if alt_c.min() + self.spurious_penalty * core.model.jitter_var < c.min():
                # y_k is supernumerary: spurious, and y_{k+1} is decided here
                self.labels[received] = self.spurious
                del self.stream[p]
                received = self.stream[p]
                levels, c = alt_levels, alt_c
        label = core.commit(levels, c)
        if received not in self.labels:  # a repeated (merged) pulse keeps its first label
            self.labels[received] = label
        self.pos = p + 1

    def estimates(self) -> dict[str, np.ndarray]:
        s = self.core.best_state()
        count = s[:, COUNT]
        return {"period": s[:, PERIOD].copy(), "phase": s[:, TAU] - (count - 1) * s[:, PERIOD]}


class FDPLikelihood(FDP):
    """`fdp-ll`: FDP whose costs weigh each error by its predicted spread, e^2 / S + log S (the
    Gaussian negative log-likelihood), instead of MK94's raw e^2.  Not in the paper.

    Guessed widths.  When the priors state no period or phase deviations (`_widths_guessed`: a priors
    file without them gets 5 % of each period), S is counted as at most 2.5 R (`_GUESSED_S_CAP`: the
    spread a source's own 4 pulses leave its prediction): a wider prediction owes its spread to the
    guess, not to the source's pulses, so it costs fdp's error (scaled: e^2 / 2.5R + log 2.5R) until
    its measurements have narrowed it.  Uncapped, the young sources of a dense file (a pulse every 2
    time units, predictions several units wide) take pulses by their log S rather than their errors; a
    long-period source learns a wrong period and every track is lost within ~80 pulses
    (tests/test_fdp_ll_dense.py; bench_dense 16 sources, jitter 0.01, seeds 101-110: 0.92 capped, as
    fdp).  A cap of 6-9 R still lets young sources' log S decide at jitter 0.03 (16 sources: 0.46-0.54
    against fdp's 0.60; 2.5 R: 0.61).  Stated widths keep the full likelihood: where they are true
    (core-v0's 8-source spread-16 scenes) the weighting is what lets fdp-ll start where fdp does not,
    and a cap costs whole episodes there."""

    PARAMS = ParamSet(tuple(p for p in PARAMS if p.name != "cost"))

    def __init__(self, lookahead: int = 3, **kwargs: Any):
        super().__init__(lookahead=lookahead, cost="likelihood", **kwargs)


guard(globals())

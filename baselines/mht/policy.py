"""Policy `mht` (docs/mht.md): the Python side -- parameters, the start's tests and restarts, batching of
the pulses into the compiled driver (baselines/mht/kernels.py)."""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import numpy as np

from baselines.kalman import DLMModel, prior_block
from baselines.mht.kernels import _run, decision_rates, rates
from baselines.mht.scorer import FlatScorer, Scorer
from baselines.mht.start import _explained, _loglik, initiate
from baselines.mht.state import (_DEAD, _HASH_BITS, _JUMP_P, _LOOK, _WINDOW, P_TT, P_TX, P_XX, PERIOD, TAU, Beam, Flat,
                                 Scratch, Settings, new_beam, new_scratch, pack)
from deint_env.episode import DESCRIPTORS, Priors
from deint_env.errors import NotApplicable, check
from deint_env.params import Param, declare

_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
# the prior-consistency test (`MHT._vet`)
_VET_MAX_SOURCES = 12  # FDP's full tree costs N^4 a pulse: larger scenes are not tested
_VET_SLACK = 0.1  # unexplained pulses allowed beyond the spurious rate, and the gain a restart must bring
_VET_LOOK = 256  # at most this many arrivals per chain
_RATE_REL = 0.1  # relative deviation of a period from the relative frequencies and the window's pulse rate
# p_gap's floor when a rate is estimated (the priors leave it unknown, or `rates` estimate): a track lost in a
# dense scene is then not read as a source that stopped (docs/mht.md, "Restart")
_GAP_ESTIMATED = 1e-2
_JOINT_MISS = 0.05  # the joint start's second candidate: its chains' miss probability (`MHT._joint_start`)
# descriptor likelihoods (docs/mht.md, "Descriptor likelihoods"): the background a pulse's descriptor is
# judged against spans the library's means +- _DESC_SPAN of their deviations (AoA: the whole circle); a
# deviation is floored at _DESC_STD_REL of that span
_DESC_SPAN, _DESC_STD_REL = 4.0, 1e-6
_NO_DLL = np.zeros((0, 0))  # descriptors off: the driver's dll has no columns


class Library(NamedTuple):
    """The descriptors an emitter library gives (`descriptor_library`): their observation keys, per
    descriptor and track the mean and deviation (D, N), per descriptor the background's log-density and
    whether it is an angle (degrees, differences wrapped to [-180, 180))."""

    names: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    log_bg: np.ndarray
    circular: np.ndarray


def descriptor_library(priors: Priors) -> Library | None:
    """The priors' emitter library as mht scores it (None: the priors give no descriptor).  A descriptor's
    background (a pulse no track explains: spurious, or another emitter's) is uniform over the span of
    the library's means +- 4 deviations, or 360 degrees for the AoA."""
    names = tuple(d for d in DESCRIPTORS if getattr(priors, d) is not None and getattr(priors, f"{d}_std") is not None)
    if not names:
        return None
    mean = np.array([np.asarray(getattr(priors, d), dtype=float) for d in names]).reshape(len(names), -1)
    std = np.array([np.asarray(getattr(priors, f"{d}_std"), dtype=float) for d in names]).reshape(mean.shape)
    circular = np.array([d == "aoa" for d in names])
    width = np.where(circular, 360.0, np.max(mean + _DESC_SPAN * std, axis=1) - np.min(mean - _DESC_SPAN * std, axis=1))
    width = np.maximum(width, np.finfo(float).tiny)
    std = np.maximum(std, _DESC_STD_REL * width[:, None])
    return Library(names, mean, std, -np.log(width), circular)


def descriptor_llr(x: np.ndarray, lib: Library) -> np.ndarray:
    """dll (M, N): for each of M pulses (x: (M, D), the library's descriptors in its order) and track, the
    sum over descriptors of log N(x; mean, std) less the background's log-density.  A descriptor not
    measured (not finite) adds 0."""
    d = x[:, :, None] - lib.mean[None]
    d = np.where(lib.circular[None, :, None], (d + 180.0) % 360.0 - 180.0, d)
    z = d / lib.std[None]
    term = -0.5 * (math.log(2.0 * math.pi) + z * z) - np.log(lib.std)[None] - lib.log_bg[None, :, None]
    return np.sum(np.where(np.isfinite(term), term, 0.0), axis=1)


# Work arrays of finished policies by shape, for the next reset: fresh ones cost their page faults anew
# every episode (~0.3 ms for a 256-hypothesis start beam of 3 sources: 0.3 us a pulse of a 1000-pulse
# episode, more than the act calls)
_Work = tuple[tuple[Flat, Beam], tuple[Flat, Beam], tuple[Flat, Scratch]]  # the beams and scratch: buffers, views
_SPARE: dict[tuple[int, ...], list[_Work]] = {}
_SPARE_MAX = 2


@functools.lru_cache(maxsize=64)
def _zobrist(n: int) -> np.ndarray:
    """The Zobrist keys (per source, 2^_HASH_BITS random words), the same for every episode: made once
    per number of sources (reset runs per episode; making them took 54 us)."""
    rng = np.random.default_rng(0x5EED)
    return rng.integers(0, np.iinfo(np.int64).max, size=(n, 1 << _HASH_BITS), dtype=np.int64).astype(np.uint64)


_N = 100_000  # the largest pulse or arrival count a parameter takes
# the most arrivals looked ahead: the look-ahead is a tree search (a hit or a miss per arrival), exponential in
# its depth (look_start=20 ran 500 pulses in 1 s, 30 in 28 s, 100 did not end)
_MAX_LOOK = 20


def _squared(z: float) -> float:
    """z^2 for a width in deviations: any z >= 1e150 already admits every pulse, and squaring a larger one (a legal
    gate=1e300) overflows float64."""
    return min(z, 1e150) ** 2


PARAMS = declare(
    Param("beam", int, 32, "hypotheses kept", low=1, high=_N),
    Param("start_beam", int, 256, "hypotheses kept during track initiation (at least beam)", low=1, high=_N),
    Param("nscan", int, 24, "pulses between a pulse and its decision: the N-scan depth (at most lag)", low=0, high=_N),
    Param("look_start", int, 6, "arrivals looked ahead to start a track", low=0, high=_MAX_LOOK),
    Param("look", int, _LOOK, "arrivals looked ahead to judge a hit", low=0, high=_MAX_LOOK),
    Param("lag", int, 1024, "the env lag: the start's buffer, at most lag - nscan pulses", low=0, high=_N),
    Param("gate", float, 4.0, "the gate, in innovation standard deviations", low=0, low_open=True),
    Param("p_gap", float, 1e-6, "a source switching off and on again: the most a run of misses costs (at least "
          "1e-2 where a rate is estimated)", low=0,
          high=1, low_open=True, high_open=True),
    Param("rates", str, "priors", "priors: the priors' miss/spurious rates (unknown ones estimated); estimate: both "
          "estimated online", choices=("priors", "estimate")),
    Param("batch", int, 64, "pulses buffered per call of the compiled driver (labels do not depend on it)", low=1,
          high=_N),
    Param("dead", int, _DEAD, "arrivals a track must have missed in a row before it may restart", low=1, high=_N),
    Param("dense", float, 3.0, "try joint starts when the first arrivals' gates hold this many pulses on average "
          "(0: whenever the phases are known)", low=0),
    Param("crowded", float, 8.0, "from this many pulses a gate on, the beam's own start is no longer a candidate",
          low=0),
    Param("look_init", int, 16, "periods of the longest source the joint start buffers (arrivals per chain it "
          "judges)", low=1, high=_N),
    Param("margin", float, math.inf, "children more than this many nats below the best are dropped (inf: the fixed "
          "beam only)", low=0, high=math.inf, low_open=True),
    Param("margin_per_source", float, 0.0, "the margin is at least this many nats per source (0: margin alone)",
          low=0),
    Param("per_source", float, math.inf, "at most this many hypotheses per source, within beam (inf: beam)", low=0,
          high=math.inf, low_open=True),
    Param("look_restart", int, None, "arrivals looked ahead to restart a silent track, at most look_start "
          "(none: look_start)", low=0, high=_N, optional=True),
    Param("drift", float, 0.0, "a period's random walk: relative deviation of its change per arrival (0: constant "
          "period)", low=0),
    Param("jump", float, 0.0, "relative deviation of a period jump after a hit (probability 0.01 a hit; 0: no "
          "jumps)", low=0),
    Param("jump_z", float, 0.0, "a jump only after a hit with |e| >= jump_z sqrt(S) (0: after every hit)", low=0),
    Param("misfit", float, 0.0, "nats by which the decided labels must reject the stated rates before the scorer, "
          "dead, look, look_restart, jump apply (0: from the start)", low=0),
    Param("wide_from", int, 0, "with misfit: from this many sources on, mht's own search before the gate opens "
          "(0: never)", low=0, high=_N),
    Param("descriptors", bool, False, "score each pulse's descriptors (frequency, pulse width, AoA) against the priors' "
          "emitter library too (needs one)"),
    internal=("scorer",),
)


class MHT:
    """Policy `mht` (docs/mht.md).  Parameters: `PARAMS` (one line each; `deint policies mht`).

    Notes beyond those lines.  `lag`: pulses are buffered so the initiation look-ahead sees `look`
    periods of the longest source, but never longer than lag - nscan pulses.  `dense`: joint starts
    (`initiate`) are tried when every track's phase is known to within a period and the first arrivals'
    gates hold this many pulses on average (32 sources of scale-v0 hold ~21, 16 sources 8-9, 16 sources
    of periods spread over [12, 160] (tests/independent_gen.py) 10-13, core-v0 at most ~6); below
    `crowded` the beam's own start competes with them (`_joint_start`), since neither alone is right on
    every file (tests/test_mht_dense.py; 3 and 8 chosen on core-v0's validation seeds and generator seeds
    101-130).  `margin`: an adaptive beam, cheaper
    where one hypothesis leads clearly; `margin_per_source`: a hypothesis's score sums over its tracks,
    so more sources spread the children's scores wider; `per_source` is rounded up: few sources leave
    fewer ambiguities to carry.  `drift` (`drift_terms`): 0 is MK94's DLM; it lets tracks of near-equal
    periods swap where their trains cross.  `jump`: each hit is then a candidate twice, with and
    without the jump, and the hypotheses choose -- agile PRIs are followed while a constant period
    stays constant.  `scorer` (Python only): a learned correction of the candidates' scores (`Scorer`,
    the `lmht` agent); None: the hand-written scores.  `misfit` (`_misfit`): before the decided labels
    reject the stated rates, where the model fits, mht's defaults apply (restarts after 3 silent
    arrivals judged `look_start` ahead, hits judged 2 ahead, no jumps); priors that state merging (a
    coincidence resolution, which the hand-written likelihood leaves out) have the scorer and those
    settings from the start.  `wide_from`: `per_source` and the margins then narrow only the open
    gate's search.  `descriptors` (docs/mht.md, "Descriptor likelihoods"): each pulse's frequency, pulse
    width and AoA scored against the priors' emitter library (`descriptor_llr`) as well as its TOA;
    priors without a library are not applicable.  Off, the labels are bit for bit those without it."""

    PARAMS = PARAMS

    def __init__(self, beam: int = 32, start_beam: int = 256, nscan: int = 24, look_start: int = 6, look: int = _LOOK,
                 lag: int = 1024, gate: float = 4.0, p_gap: float = 1e-6, rates: str = "priors", batch: int = 64,
                 dead: int = _DEAD, dense: float = 3.0, crowded: float = 8.0, look_init: int = 16,
                 margin: float = math.inf, margin_per_source: float = 0.0,
                 per_source: float = math.inf, look_restart: int | None = None, drift: float = 0.0,
                 jump: float = 0.0, jump_z: float = 0.0, misfit: float = 0.0, wide_from: int = 0,
                 descriptors: bool = False, scorer: Scorer | None = None):
        PARAMS.check(locals())
        check(nscan <= lag, "nscan", nscan, f"at most lag={lag}")
        check(look_restart is None or look_restart <= look_start, "look_restart", look_restart,
              f"at most look_start={look_start}")
        self.beam, self.start_beam, self.nscan, self.lag = beam, max(start_beam, beam), nscan, lag
        self.reserve = lag - nscan
        self.look_start, self.look, self.dead = look_start, look, dead
        self.look_restart = look_start if look_restart is None else look_restart
        self.gate, self.p_gap, self.rates, self.batch = float(gate), float(p_gap), rates, batch
        self.dense, self.crowded, self.look_init = float(dense), float(crowded), look_init
        self.margin = float(margin)
        self.margin_per_source = float(margin_per_source)
        self.per_source = float(per_source)
        self.drift = float(drift)
        self.jump = float(jump)
        self.jump_z = float(jump_z)
        self.misfit = float(misfit)
        self.wide_from = wide_from
        self.descriptors = descriptors
        self.net = Scorer.off() if scorer is None else scorer

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        if priors.blind:
            raise NotApplicable("mht needs priors (an anchored scenario)")
        n = self.n = priors.n_labels
        model = DLMModel.from_priors(priors, min_jitter=_MIN_JITTER_REL * float(np.min(priors.period)))
        # an unknown phase: the first arrival is somewhere in the first period
        known = np.isfinite(priors.phase)
        phase = np.where(known, priors.phase, 0.5 * priors.period)
        phase_std = np.where(known, priors.phase_std, priors.period / math.sqrt(12.0))
        b = prior_block(Priors(n_labels=n, period=priors.period, phase=phase, period_std=priors.period_std,
                               phase_std=phase_std))
        self.prior = np.ascontiguousarray(np.stack(list(b), axis=-1))
        self.look_max = max(self.look, self.look_start)  # the scratch's look-ahead depth
        (self.cur_flat, self.cur), (self.nxt_flat, self.nxt), (self.w_flat, self.scratch) = self._work_arrays()
        self.net_flat = FlatScorer.of(self.net)  # (here: a test may swap the scorer after construction)
        self.cur.blk[0] = self.prior
        self.size = 1
        self.zob = _zobrist(n)
        # the key of "no pulse yet": every source's entry for last = -1 (index mask)
        self.cur.key[0] = np.bitwise_xor.reduce(self.zob[:, -1])
        t_max = float(np.max(priors.period))
        stated = self.rates == "priors"
        # a dense start: the first arrivals' gates hold `dense` pulses or more on average (the sources'
        # pulse rate times the gate's width), so joint starts (`initiate`) are tried -- when every track
        # can take part (its first gate narrower than its period: a track whose phase is unknown would
        # compete for the pulses outside the joint assignment); below `crowded` the beam's own start is
        # one of the candidates (`_joint_start`)
        p = self.prior
        first_s = p[:, P_XX] + 2.0 * p[:, P_TX] + p[:, P_TT] + model.interval_var + model.jitter_var
        width = 2.0 * self.gate * np.sqrt(first_s)
        held = float(np.mean(width)) * float(np.sum(1.0 / priors.period))
        initiate = bool(np.all(width < p[:, PERIOD])) and held >= self.dense
        self.own_start = held < self.crowded
        known_q = float(priors.missing_prob) if stated else math.nan  # NaN: estimated online
        known_r = float(priors.spurious_rate) if stated else math.nan
        estimated = math.isnan(known_q) or math.isnan(known_r)
        self.cfg = Settings(
            gate2=_squared(self.gate), jitter_var=model.jitter_var, interval_var=model.interval_var,
            log_gap=math.log(max(self.p_gap, _GAP_ESTIMATED) if estimated else self.p_gap),
            pulse_rate=float(np.sum(1.0 / priors.period)), known_q=known_q, known_r=known_r,
            start_until=float(np.max(phase + 4.0 * phase_std)) + t_max,
            horizon_start=(max(self.look_start, self.look_init if initiate else 0) + 0.5) * t_max * 1.05
            + 4.0 * float(np.max(phase_std)),
            horizon=(max(self.look, self.look_start, _LOOK if self.misfit > 0 else 0) + 0.5) * t_max * 1.05,
            beam=self.beam if math.isinf(self.per_source) else min(self.beam, math.ceil(self.per_source * n)),
            start_beam=self.start_beam, nscan=self.nscan, look_start=self.look_start, look_restart=self.look_restart,
            look=self.look, dead=self.dead, reserve=self.reserve, initiate=initiate, look_init=self.look_init,
            margin=max(self.margin, self.margin_per_source * n), drift=self.drift, jump=self.jump,
            log_jump=math.log(_JUMP_P), log_stay=math.log1p(-_JUMP_P), jump_z2=_squared(self.jump_z),
            misfit=0.0 if priors.coincidence_resolution > 0 else self.misfit,
            # only priors that predict every first arrival (the gate narrower than a period) promise a start: a
            # vague period or an unknown phase promises a chain anywhere, harmonics and other sources' trains
            # included, that a track's own start need not match (noise-free CM00 scenes lost every track)
            prior_ahead=bool(np.all(0.5 * width < p[:, PERIOD])))
        # the search while the misfit gate is closed
        self.fit = self.cfg._replace(dead=_DEAD, look=_LOOK, look_restart=self.look_start, jump=0.0, jump_z2=0.0)
        if 0 < self.wide_from <= n:  # a wider search where the model fits: dense scenes lose fewer tracks
            self.fit = self.fit._replace(beam=self.beam, margin=math.inf)
        self.settings = pack(self.cfg, self.fit)  # what the kernels read (`state.SETTINGS`)
        self.priors, self.vetted = priors, False  # the prior-consistency test is still to run (`_vet`)
        # it runs when every track's first arrival is predicted to within a period (its gate's half-width; a
        # vague period or phase fails this): then the priors predict where each source's pulses are
        self.vettable = self.cfg.prior_ahead
        self.perm = np.arange(n + 1)  # the label each track reports (`_identities`); spurious stays n
        self.identify = None  # (periods, variances) the tracks' identities are to be settled by
        # decided hits, misses, spurious; whether the misfit gate is open (`_misfit`)
        self.counts = np.zeros(_WINDOW + 4, np.int64)
        self.toa = np.zeros(1024)
        self.labels = np.zeros(1024, np.int64)
        self.n_seen = self.n_labels = 0
        self.due: list[int] = []  # labels reported or ready to be (`_due`)
        self.wake = 1  # act calls `_wake` when n_seen reaches this
        self.k = 0  # next pulse to process
        self.called = 0  # pulses seen at the last driver call
        self.ended = False
        self.steps = 0
        self._library(priors, info)

    def _library(self, priors: Priors, info: dict[str, Any]) -> None:
        """`descriptors`: the emitter library, the pulses' descriptors (`desc`, grown with `toa`) and their
        log-likelihood ratios (`dll`: pulses, N; computed up to `dll_done` before each driver call)."""
        self.names: tuple[str, ...] = ()
        self.dll, self.dll_done = _NO_DLL, 0
        if not self.descriptors:
            return
        lib = descriptor_library(priors)
        if lib is None:
            raise NotApplicable("mht:descriptors=true needs priors with an emitter library (descriptor means and "
                                "spreads); these give none")
        if info.get("has_descriptors") is False:
            raise NotApplicable("mht:descriptors=true needs pulse descriptors; this scenario's observations carry none")
        self.lib, self.names = lib, lib.names
        self.desc = np.zeros((self.toa.size, len(lib.names)))
        self.dll = np.zeros((self.toa.size, self.n))

    def _work_arrays(self) -> _Work:
        """The two beams and the scratch for this episode: this policy's own or a finished one's of the same
        shape (`_SPARE`), cleared to what fresh ones hold, else fresh ones."""
        cap, n, ring = self.start_beam, self.n, self.nscan + 1
        look, hidden = self.look_max, self.net.b1.shape[0]
        key = (cap, n, ring, look, hidden)
        spare = _SPARE.get(key)
        if getattr(self, "work_key", None) == key:
            work = (self.cur_flat, self.cur), (self.nxt_flat, self.nxt), (self.w_flat, self.scratch)
        elif spare:
            work = spare.pop()
        else:
            self.work_key = key
            # per parent: up to two arrivals (each also with a period jump, `jump`) and a restart per source
            # (`step`), and the spurious hypothesis
            return new_beam(cap, n, ring), new_beam(cap, n, ring), new_scratch(cap * (5 * n + 1), n, look, hidden)
        self.work_key = key
        for flat, _ in work:
            flat.f.fill(0)
            flat.i.fill(0)
        work[0][1].last.fill(-1)
        work[1][1].last.fill(-1)
        return work

    def __del__(self) -> None:
        # its work arrays go to the next policy of this shape (at most _SPARE_MAX sets are kept per shape)
        key = getattr(self, "work_key", None)
        if key is not None:
            spare = _SPARE.setdefault(key, [])
            # (a shallow copy of a policy shares its arrays: they are handed on once)
            if len(spare) < _SPARE_MAX and not any(w[0][1] is self.cur for w in spare):
                spare.append(((self.cur_flat, self.cur), (self.nxt_flat, self.nxt), (self.w_flat, self.scratch)))

    def act(self, obs: dict[str, Any]) -> int:
        # runs once a step (twice a pulse at the default lag): kept lean, the work is in the driver
        if obs["valid"]:
            n = self.n_seen
            self.toa[n] = obs["toa"][0]
            if self.names:
                row = self.desc[n]
                for j, name in enumerate(self.names):
                    row[j] = obs[name][0]
            self.n_seen = n = n + 1
            if n >= self.wake:
                self._wake()
        elif not self.ended:
            self.ended = True
            if self.n_seen:
                self._run()
        t = self.steps - self.lag  # step t labels pulse t - lag
        self.steps += 1
        if t < 0:
            return 0
        if t < len(self.due):
            return self.due[t]
        return self._due(t)

    def _wake(self) -> None:
        """The buffer grown when full; the driver called every `batch` pulses (its call costs far more than
        a pulse) or when a decision is due; `wake` set to the next pulse count needing either."""
        n = self.n_seen
        if n == self.toa.size:
            self.toa = np.concatenate([self.toa, np.zeros(n)])
            self.labels = np.concatenate([self.labels, np.zeros(n, np.int64)])
            if self.names:
                self.desc = np.concatenate([self.desc, np.zeros_like(self.desc)])
                self.dll = np.concatenate([self.dll, np.zeros_like(self.dll)])
        if n - self.called >= self.batch or n - 1 - self.k >= self.reserve:
            self._run()
        self.wake = min(self.toa.size, self.called + self.batch, self.k + 1 + self.reserve)

    def _due(self, t: int) -> int:
        """Label t once `due` (the reported labels, Python ints: a list index is the cheapest step) lacks it:
        the labels decided since are appended, the tracks' identities settled first if they are pending."""
        if t >= self.n_labels:
            return 0
        if self.identify is not None:
            # the tracks' identities from all the beam has seen when the first label is due
            self.perm[:self.n] = self._identities(self.labels[:self.n_labels], self.cur.blk[0], *self.identify)
            self.identify = None
        self.due.extend(self.perm[self.labels[len(self.due):self.n_labels]].tolist())
        return self.due[t]

    def _run(self) -> None:
        self.called = self.n_seen
        if self.names and self.dll_done < self.n_seen:  # the new pulses' descriptor likelihoods
            self.dll[self.dll_done:self.n_seen] = descriptor_llr(self.desc[self.dll_done:self.n_seen], self.lib)
            self.dll_done = self.n_seen
        if not self.vetted:
            cfg, y0 = self.cfg, self.toa[0]
            ahead = cfg.horizon_start if y0 <= cfg.start_until else cfg.horizon
            # what the driver needs before it processes pulse 0 (`_run`): its look-ahead buffered, or the lag's
            # end, or the stream's
            if self.ended or self.n_seen - 1 >= cfg.reserve or self.toa[self.n_seen - 1] >= y0 + ahead:
                self.vetted = True
                end = min(cfg.reserve + 1, int(np.searchsorted(self.toa[:self.n_seen], y0 + ahead, side="right")))
                self._vet(end)
                if self.cfg.initiate:
                    self._joint_start(end)
        self.k, self.size, swapped, self.n_labels = _run(
            self.toa, self.n_seen, self.ended, self.k, self.size, *self.cur_flat, *self.nxt_flat, self.start_beam,
            self.zob, self.prior, *self.w_flat, self.look_max, self.settings, self.counts, self.labels, self.n_labels,
            *self.net_flat, self.dll)
        if swapped:
            self.cur, self.nxt = self.nxt, self.cur
            self.cur_flat, self.nxt_flat = self.nxt_flat, self.cur_flat

    def _vet(self, end: int) -> None:
        """The prior-consistency test and the data-driven restart, or for priors that predict no first
        arrival the multi-start (see the module docstring): the first `end` pulses (what the driver has
        buffered before it labels pulse 0) against the priors."""
        n, cfg = self.n, self.settings[0]  # (the record the kernels take)
        unknown = math.isnan(cfg.known_q) or math.isnan(cfg.known_r)
        if end < 2 * n or not (n <= _VET_MAX_SOURCES or (unknown and self.vettable)):
            return
        if not self.vettable:
            self._multistart(end)
            return
        toa = self.toa[:end]
        log_q, log_1mq, _ = rates(cfg, self.counts)
        fitted = np.empty_like(self.prior)
        dll = self.dll if self.names else None  # (None: compiled without the descriptor terms)
        explained, missed = _explained(toa, end, self.prior, cfg, log_q, log_1mq, self._looks(toa, self.prior), fitted,
                                       dll)
        self._window_rates(end, explained, missed)
        # the pulses the sources are not expected to explain: spurious ones, r per source pulse (an unknown
        # r the window's net excess of pulses: read as the weak prior's 5 %, it let a dense start's priors
        # pass that left a source unexplained -- 0.91 of 8 sources' labels right, 0.97 when told 0)
        r = cfg.known_r
        if math.isnan(r):
            r = self.counts[_WINDOW + 2] / max(self.counts[_WINDOW] + self.counts[_WINDOW + 1], 1)
        allowed = end * (r / (1.0 + r) + _VET_SLACK)
        if n > _VET_MAX_SOURCES or end - explained <= allowed:
            return
        blk = self._fdp_start(toa)
        again, missed = _explained(toa, end, blk, cfg, log_q, log_1mq, self._looks(toa, blk), fitted, dll)
        # the restart must explain 10 % more of the window and half of what the priors left unexplained; the
        # tracks start from their chains over the window from FDP's estimates (what the test has just found:
        # a period FDP learnt early from wrong pulses is polished by the chain's KF)
        if again - explained >= _VET_SLACK * end and end - again <= 0.5 * (end - explained):
            self.prior[:] = fitted
            self.cur.blk[0] = fitted
            self._window_rates(end, again, missed)

    def _window_rates(self, end: int, explained: int, missed: int) -> None:
        """Unknown rates are estimated from the buffered start until the decisions cover it: the weak prior
        alone (5 %) made spurious calls cheap while a dense start was searched, and its tracks lost their
        sources (8 sources, 800 pulses: 0.71 of the labels right, 0.78 with this, 0.80 told 0).  The
        chains of the start (`_explained`, one track at a time, greedy) bound the counts: the pulses they
        leave are at most the spurious ones, the arrivals they skip at most the misses.  In a dense start
        those come in pairs -- a chain takes a neighbour's near-coincident pulse, skips its own arrival and
        leaves its pulse -- which are no evidence of a missed or a spurious pulse; the pulse count is: pulses beyond
        the sources' arrivals (R span, plus half an arrival per source at the window's edges) are
        spurious, arrivals beyond the pulses missed.  So each count is the net one, within its bound."""
        if math.isnan(self.cfg.known_q) or math.isnan(self.cfg.known_r):
            arrivals = self.cfg.pulse_rate * (self.toa[end - 1] - self.toa[0]) + 0.5 * self.n
            spurious = min(end - explained, max(0, round(end - arrivals)))
            missed = min(missed, max(0, round(arrivals - end)))
            self.counts[_WINDOW:] = end - spurious, missed, spurious, end

    def _multistart(self, end: int) -> None:
        """Vague priors: the start chosen among whole initialisations by the likelihood of the buffered
        window (see the module docstring).  Each candidate's beam labels the window; the labellings are
        scored alike (`_loglik`, under the informed prior) and the likeliest candidate starts the beam.
        Its tracks are later given the labels whose informed periods fit them best (`_identities`)."""
        cfg = self.settings[0]  # (the record the kernels take)
        toa = np.ascontiguousarray(self.toa[:end])
        log_q, log_1mq, log_rho = rates(cfg, self.counts)
        rate, rate_var = self._rate_periods(toa)
        informed = self._rate_start(toa, rate, rate_var)
        cands = [informed, self._fdp_start(toa)]
        if not np.array_equal(informed, self.prior):  # the relative frequencies said something
            cands.append(self.prior.copy())
        best, best_ll = None, -np.inf
        for blk in cands:
            labels, fin = self._window(toa, blk)
            ll = _loglik(toa, labels, informed, cfg, log_q, log_1mq, log_rho)
            if ll > best_ll:
                best, best_ll = (blk, labels, fin), ll
        blk, labels, fin = best
        # a track the winning labelling gave fewer than 3 pulses of the window has learnt nothing from it, and
        # one whose period over the window left the informed prior's gate learnt a wrong period: they start
        # from the informed prior
        few = np.bincount(labels, minlength=self.n + 1)[:self.n] < 3
        far = (fin[:, PERIOD] - rate) ** 2 > cfg.gate2 * (rate_var + np.maximum(fin[:, P_TT], 0.0))
        blk = np.where((few | far)[:, None], informed, blk)
        self.prior[:] = informed
        self.cur.blk[0] = blk
        self.identify = rate, rate_var  # the tracks' identities are settled at the first label (`act`)

    def _joint_start(self, end: int) -> None:
        """A dense start (`cfg.initiate`): the tracks started jointly (`initiate`) on the first `end` pulses, at
        the chains' miss probability the driver would use and at least _JOINT_MISS, and (below `crowded`) the
        beam's own start from the priors; the start whose beam labels those pulses likeliest under the priors
        (`_window`, `_loglik`) begins the beam.  On a clean channel the estimated q is ~1e-3; a chain whose
        pulse a track started before it has taken then hops onto a neighbour's train rather than skip an
        arrival (16 sources, tests/independent_gen.py: tracks started on each other's trains), while at a q
        of 5 % a fast chain skips freely and others' trains are left to harmonics; the beam's own start, in
        turn, lets a slow track take a faster source's harmonic among a few sources' first pulses (8 sources:
        a period-99 track on a 51.6 train's every other pulse).  None is right on every file; the window's
        likelihood tells which is (docs/mht.md, "Track initiation").  In a crowded start the own start is
        left out: its window can be likelier while the episode goes worse (scale-v0, 16 sources)."""
        toa = np.ascontiguousarray(self.toa[:end])
        cfg = self.settings[0]
        log_q, log_1mq, log_rho = decision_rates(cfg, self.counts, toa, 0)  # what the driver uses for pulse 0
        dll = self.dll[:end] if self.names else None
        starts = [self.prior] if self.own_start else []
        for floor in (0.0, _JOINT_MISS):
            q = max(math.exp(log_q), floor)
            blk = self.prior.copy()
            initiate(toa, end, blk, cfg, math.log(q), math.log1p(-q), dll)
            if not any(np.array_equal(blk, b) for b in starts):
                starts.append(blk)
        ll = [_loglik(toa, self._window(toa, blk)[0], self.prior, cfg, log_q, log_1mq, log_rho)
              for blk in starts] if len(starts) > 1 else [0.0]
        self.cur.blk[0] = starts[int(np.argmax(ll))]  # the first of equals: the own start, then the lower q

    def _window(self, toa: np.ndarray, blk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The beam started from blocks `blk` run over the window `toa` (as if the stream ended there): its
        labels and its best hypothesis's final blocks."""
        n, ring, cap = self.n, self.nscan + 1, self.start_beam
        (cur_flat, cur), (nxt_flat, nxt) = new_beam(cap, n, ring), new_beam(cap, n, ring)
        cur.blk[0] = blk
        cur.key[0] = self.cur.key[0]
        labels = np.zeros(toa.size, np.int64)
        _, _, swapped, _ = _run(toa, toa.size, True, 0, 1, *cur_flat, *nxt_flat, cap, self.zob, blk, *self.w_flat,
                                self.look_max, self.settings, self.counts.copy(), labels, 0, *self.net_flat, self.dll)
        return labels, (nxt if swapped else cur).blk[0].copy()

    def _rate_periods(self, toa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each track's period and its variance from the stated priors combined with the known relative
        frequencies pi_i (MK94 IV-2, the priors' `source_prob`): source i's pulses arrive at pi_i times
        the window's pulse rate lambda (less the spurious share), and a source emits (1 - q) / T_i, so
        T_i = (1 - q) / (pi_i lambda (1 - r / (1 + r))), known to _RATE_REL (the window's rate and merged
        pulses); the two Gaussians are multiplied."""
        pri = self.priors
        t, var = pri.period.astype(float), pri.period_std.astype(float) ** 2
        pi = np.asarray(pri.source_prob, dtype=float)
        # uniform pi is MK94 VI-B's "no a priori information" (pi_i = 1/4 for a PT run that assumes N = 4):
        # it tells no track from another, and its rate-implied period only divides the pulse rate by a guessed N
        if pi.size != self.n or not np.all(pi > 0) or np.all(pi == pi[0]) or toa[-1] <= toa[0]:
            return t, var
        q = 0.05 if math.isnan(self.cfg.known_q) else self.cfg.known_q
        r = 0.05 if math.isnan(self.cfg.known_r) else self.cfg.known_r
        lam = (toa.size - 1) / (toa[-1] - toa[0]) / (1.0 + r)
        t_rate = (1.0 - q) / (pi * lam)
        var_rate = (_RATE_REL * t_rate) ** 2
        var_c = 1.0 / (1.0 / var + 1.0 / var_rate)
        return var_c * (t / var + t_rate / var_rate), var_c

    def _rate_start(self, toa: np.ndarray, t: np.ndarray, var: np.ndarray) -> np.ndarray:
        """Prior blocks with the periods of `_rate_periods`; a phase the priors do not know to within the
        period is uniform over the first period after the window's first pulse."""
        pri = self.priors
        known = np.isfinite(pri.phase) & (pri.phase_std < t / math.sqrt(12.0))
        phase = np.where(known, pri.phase, toa[0] + 0.5 * t)
        phase_std = np.where(known, pri.phase_std, t / math.sqrt(12.0))
        b = prior_block(Priors(n_labels=self.n, period=t, phase=phase, period_std=np.sqrt(var), phase_std=phase_std))
        return np.ascontiguousarray(np.stack(list(b), axis=-1))

    def _identities(self, labels: np.ndarray, fin: np.ndarray, t: np.ndarray, var: np.ndarray) -> np.ndarray:
        """Which label each track reports: the assignment of tracks to the priors' labels that maximises
        the priors' log-density of the tracks' periods (in log-period: a period's prior N(t_i, var_i) and
        the track's estimate with its variance).  A track given fewer than 2 of the labels decided so far
        says nothing.  Tracks started from exchangeable priors (MK94 VI-B's x_{1|0} = 1 for all) are so told
        apart by the relative frequencies; distinct confident priors keep their order."""
        n = self.n
        cost = np.zeros((n, n))
        counts = np.bincount(labels[labels < n], minlength=n)
        for j in range(n):
            tj = fin[j, PERIOD]
            if counts[j] < 2 or not tj > 0:
                continue
            v = var / t ** 2 + max(fin[j, P_TT], 0.0) / tj ** 2
            cost[j] = -0.5 * (np.log(v) + (math.log(tj) - np.log(t)) ** 2 / v)
        from scipy.optimize import linear_sum_assignment  # here: scipy.optimize costs 0.3 s of a warm call

        rows, cols = linear_sum_assignment(-cost)
        perm = np.arange(n)
        perm[rows] = cols
        return perm

    def _looks(self, toa: np.ndarray, blk: np.ndarray) -> np.ndarray:
        """Arrivals a track's chain needs to cover the buffered window (at most `_VET_LOOK`)."""
        span = toa[-1] - toa[0]
        return np.minimum(np.ceil(span / blk[:, PERIOD]) + 1, _VET_LOOK).astype(np.int64)

    def _fdp_start(self, toa: np.ndarray) -> np.ndarray:
        """New prior blocks from MK94's FDP (`baselines.fdp`, as published) run over the buffered pulses:
        FDP gives every pulse to some source, so its KF learns a period from a wrong prior.  A track's
        period is the FDP's final estimate (variance 4x its own), its phase the first pulse the FDP gave it
        that lies on that estimate's grid of arrivals; a track given fewer than 3 pulses keeps its prior."""
        from baselines.fdp import CompiledFDPCore  # here: only a rejected prior needs it
        core = CompiledFDPCore(self.priors, "lookahead", False, "phase", math.inf)
        labels = core.decide_all(np.ascontiguousarray(toa), 3)
        state = core.best_state()
        blk = self.prior.copy()
        jv, iv, g2 = self.cfg.jitter_var, self.cfg.interval_var, self.cfg.gate2
        for i in range(self.n):
            mine = np.flatnonzero(labels == i)
            if mine.size < 3:
                continue
            t, last, var_t = state[i, PERIOD], state[i, TAU], state[i, P_TT]
            if not (t > 0.0 and math.isfinite(last) and var_t >= 0.0):  # lost (e.g. jitter beyond the period)
                continue
            m = np.round((last - toa[mine]) / t)
            resid = toa[mine] - (last - m * t)
            on = np.flatnonzero(resid ** 2 <= g2 * (jv + m * iv + m * m * var_t))
            first = toa[mine[on[0]] if on.size else mine[0]]
            var_t = 4.0 * var_t
            blk[i] = (t, first - t, var_t, -var_t, jv + var_t)  # tau = phi - T, as `initiate` starts a track
        return blk

    def estimates(self) -> dict[str, np.ndarray]:
        blk, arr = self.cur.blk[0], self.cur.arrivals[0]
        period, phase = np.empty(self.n), np.empty(self.n)
        period[self.perm[:self.n]] = blk[:, PERIOD]
        phase[self.perm[:self.n]] = blk[:, TAU] - (np.maximum(arr, 1) - 1) * blk[:, PERIOD]
        return {"period": period, "phase": phase}

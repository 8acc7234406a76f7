"""The probabilistic teacher (MK94 section IV): policies `pt-prior` and `pt-post`; and `dokf`, the same
tracker taught by its own MAP decisions with DM89's spurious-pulse test.

At each pulse y_{k+1} the teacher picks the active source at random and then runs the KF update of
that source only, (4.4) (Agrawala's learning with a probabilistic teacher, MK94 ref. [6]):
- `pt-post`, Step 1 as published: the a-posteriori probabilities (4.1) with the Gaussian
  approximation (4.2), f(X_{k+1} = e_j | y_{k+1}, ...) ~ pi_j N[y_{k+1}; H x^j_{k+1|k}, Omega^j],
  x^j_{k+1|k} and Omega^j from (4.3), i.e. every source's one-step prediction;
- `pt-prior`, MK94 IV-2: the a-priori probabilities pi instead ("instead of using the a posteriori
  probabilities in Step 1, one can use the a priori probability estimate"), so only the chosen
  source is predicted: O(1) per pulse.
pi is the priors' `source_prob` (by default the known relative pulse rates, MK94 IV-2).

State: the per-source 2x2 blocks (T, tau) of `baselines.kalman` (MK94's (2.7)-(2.8) with a
block-diagonal Sigma_{1|0}, so (4.3) costs O(1) per source instead of the published O(N^3)), started
by `kalman.prior_block`: tau = phi - T, so a source's first pulse is predicted at its phase (an
unknown phase: a huge variance, MK94's Sigma_{1|0} = 10^6 I).

Labels.  The PT's decision is the sampled source (`label="sample"`, the paper).  `label="map"`
labels each pulse with the most probable source under the same model (the argmax of (4.1)) while
still learning from the sample (a variant, not published: `pt-post:label=map`).

`dokf` (teacher "decision"): DM89's detect-then-filter carried over to the DLM: each pulse is
assigned to the argmax of (4.1), or called spurious by Theorem 1 (below), and that decision, not a
sample, drives the update, as DM89's q_hat(k|k) drives (16)-(17) (Agrawala's decision-directed
learning, against which ref. [6] sets the PT).  Its (4.1) keeps pi: leaving it out (each source's
arrival density already says when it is due) helped dense scenes of sources with rates proportional to
1/period a little (independent generator, 8 sources at jitter 0.06 of the shortest period: 0.694
without pi, 0.678 with it, validation files 101-103) and cost MK94's and CM00's scenes of unequal
rates and unknown phases much more (paper-v0's validation seeds: 0.461 without, 0.579 with).

Missed pulses (MK94 VI-C-3).  The DLM has no missing-pulse state, so a true pulse lost, rejected or
taken by the wrong source desynchronises its track: it goes on predicting the lost pulse and every
later pulse of its source looks spurious.  Remedies:
- `coast=True` (the rule of `fdp`'s `dropout`) predicts a source overdue at y by more than `gate`
  standard deviations plus half a period through its missed arrivals, without measurements;
- when the channel may miss pulses (the priors' missing_prob q > 0, or unknown), (4.1) gets a second
  hypothesis per source: its arrival nearest to y after m more misses (k = m + 1 steps of (2.8) in
  closed form), scored log pi_j + log(1 - q) + m log q + log N(e; 0, S), so a pulse between the
  midpoint of two arrivals and the coasting gate (or any late pulse without coasting) is read as
  missed arrivals, at their price;
- `reset_after=k` resets a source missing more than k arrivals in a row (a detected dropout): its
  phase is unknown again (var tau = T^2/12, cov(T, tau) = 0, so its next pulse does not bend the
  period; the prior's period back when it has strayed by more than two prior deviations) and the
  misses cost nothing more.  A source of unknown phase that took one pulse and missed its next
  arrival is reset too (its first pulse was most likely another's).
`dokf` uses coast=True, reset_after=4 (chosen on robust-v0 train seeds: a smaller k loses sources
of near-equal period whose pulses merge several times in a row; coasting floors q at 0.001, so a
merged pulse stays explainable).  `pt-post` is the published PT on a channel the priors state clean
(missing_prob = spurious_rate = 0); otherwise (`coast=None`, the default) it takes coast=True,
reset_after=4 too: without them it calls nearly every pulse spurious once a track slips.  Its particles
(below) take them on any channel whose jitter lets a miss be told from a late pulse (`_resolved`): a particle's
track that another of its tracks robbed needs them.

Spurious pulses (when the priors' spurious_rate r > 0, or unknown): before deciding, the best
hypothesis goes through DM89's Theorem 1 test (`deint_env.receiver.is_spurious`, spread T_j^2 / 12: a
uniform arrival over one period) with prior odds lambda : (1 - lambda) P_D q^m, lambda = r / (1 + r)
the probability that a received pulse is spurious, P_D = 1 - q the detection probability and m the
hypothesis's misses; a pulse it calls spurious gets the spurious label and updates nothing.
pt-prior has no Step 1 (its choice ignores y), so no test.  A coasting tracker tests after its start
(two longest periods) even on a channel stated free of spurious pulses, with lambda 1e-6: a pulse far
outside every gate is then a slipped track's, and forced onto another track it would slip that one too.

Unknown rates (NaN in the priors, or `rates="estimate"`: both) are estimated online from the
tracker's own decisions with a weak Beta prior (mean 0.05, worth 20): q = (misses + 1) / (arrivals
+ 20) over the taken pulses and the misses before them (a dropout's are not misses), lambda =
(spurious called + 1) / (pulses + 20), so the test and the miss prices follow the channel.  While
unknown phases are being acquired (two longest periods) decisions are not counted: a wrong start
would otherwise feed itself back into lambda.

Start beam (`dokf`).  Which fresh track a first pulse starts is a guess that a single decision gets
wrong too often (then every track holds another source's pulses: 0.002 of the labels right on one
test file), so until two longest periods have passed (`beam_span`) `dokf` keeps the 32 best
labellings (each extended by every hypothesis above and by "spurious", scored as Theorem 1 weighs them),
labels each pulse by the best at once (lag 0), and where the beam ends (below) goes on from the best alone.
Known phases too: with the priors' default phase deviation (5 % of the period) the first arrivals of dense
sources fall in each other's gates, and a single decision lost 0.8 of core-v0's 8-source labels (issue #22).
A labelling is kept only if it predicts something the better ones kept do not: one whose next two
arrivals of every source lie within one deviation (the state's, var tau' without the jitter's R) of a
better kept labelling's is dropped.  In a dense start the ambiguities are independent (which of
several slow sources, each with a wide first-arrival gate, took a pulse; which of two fast sources
took which of two coincident pulses), so the labellings that differ only in them are a product that
fills the 32 places with variants of one wrong start, and the true labelling, worth ~10^4 nats more
by the start's end, falls out early (16 sources at jitter 0.01 of the shortest period, rates stated
0: the 83rd of 512 extensions at the 6th pulse; 0.34 of the labels right over validation seeds
101-103, 0.64 with 128 or 512 places, 0.91 with the rule and 32 in version 4, 0.90 with pi back in
version 5).  The deviation leaves out R, and is one, not two: with R, or at two, two sources of close
periods that swap coincident pulses (core-v0's 4-source scene, periods 14.04 and 14.64) look alike
until they cross, and the swapped labelling, a little better then, took the true one's place (0.88 ->
0.28 of that episode's labels right).
Whole-episode beam (`dokf` version 6).  After the start the beam runs on (`beam_span`, in longest periods:
by default the whole episode where the priors place every period within half of itself, `_LOCATED`, else
the start alone), a lag-0 beam search that still labels each pulse at once by its best labelling but no
longer goes on from one: on the independent generator's dense files (8 sources, jitter 0.06 of the shortest
period, clean channel, validation seeds 101-110) single decisions after the start lose the tracks one after
another on half the files (0.15-0.18 of the labels right with the rates stated 0; mean 0.43, 0.60 with them
unknown), the beam holds them (mean 0.76 both ways, worst file 0.67; fdp 0.69).  Kept whole (32 places, no
margin) it cost 16-37 times a decision's time, so after the start it keeps at most `_AFTER_BEAM` (8)
labellings within `beam_margin` (10) nats of the best: a clear pulse leaves one, and the beam costs a
decision's work plus its copies (2-4 times version 5's time on the suites).  Both chosen on the boards'
validation seeds and the generator's files 101-110 (docs/experiments.md, 'Dense scenes'): margin 5 cost
MK94's two-source scenes with wrong priors (mk94-two-var2 and var3: a wrong labelling likelier for the first
periods pruned the right one: score 0.87 -> 0.14 on one validation episode of var2), 20 kept no more right
and took up to 2.5 times as long on the dense files; 32 places gained 0.003 on core-v0 at 1.3 times the
time.  With vague priors (MK94 V-C's PT scenes, period 1 +- 1000) every rival labelling stays within any
margin (7-20 ms per pulse), so there the beam ends with the start.
The spurious floor (`_spurious_prob`) applies after the start's two longest periods however long the
beam runs, and from then on the beam prices the arrivals `_coast` skips as the candidates price misses
(log q each, a dropout's excepted): left free, a labelling in which an idle track took another source's
pulses while that source coasted scored as the true one, and the beam's lag-0 labels mixed the two
(robust-v0's robust-onset, a source starting late beside one of near-equal period: 0.39 -> 0.97).

Acquisition (`pt-post`).  The teacher's draw is as blind as a single decision to which fresh track a
first pulse starts.  On the independent generator's dense files (8 sources, jitter 0.01 of the shortest
period, true phases with the default 5 % deviation, validation seeds 101-105) the true source is not
the likeliest at 4-7 of the start's 49-93 pulses along the true labelling, and the teacher draws the
whole start right with probability 1e-9 to 5e-5: it drew 0.03-0.65 of it right, every track went on
with another source's pulses, and with unknown rates the estimated lambda (0.23-0.96 by the end) then
called most pulses spurious.  So pt-post acquires as `dokf` does: until two longest periods have
passed, the start beam's MAP decisions teach and label (`_START_BEAM` places), then the teacher draws
from the best labelling on (one uniform per pulse throughout, so the draws stay reproducible).  Only
when the priors place every period within half of itself (`_LOCATED`): MK94 V-C's PT scenes state
period 1 with deviation 1 or 1000 for periods 11, 30 and 80, where two prior periods acquire nothing
and the PT learns from scratch as published.  Labels right over validation seeds 101-110, rates
unknown / stated 0: 8 sources at jitter 0.01 0.40 / 0.15 -> 0.93 / 0.93, at 0.03 0.30 / 0.14 -> 0.82
/ 0.68; 16 sources at 0.01 0.18 / 0.06 -> 0.87 / 0.87.  128 places, not dokf's 32: with 32 the true
16-source start fell out at its 12th pulse on seeds 108-110, 3.5 nats behind the 32nd place (a slow
source's first pulse, in a gate of deviation 8, costs more than giving it to a fast source 1-2
deviations off), and a track that slipped there never recovers on a channel stated clean (16 sources:
0.83 / 0.65).  The boards' validation seeds gain too (mean score, 10 seeds per scenario): paper-v0
0.42 -> 0.59, core-v0 0.70 -> 0.86, robust-v0 0.77 -> 0.79, agile-v0 0.29 -> 0.31, agile-v2 0.24 -> 0.31.

Particles (`pt-post` version 4).  After the start one teacher's wrong draw is for good: the source it
robbed goes on predicting the pulse it lost, and on a channel stated clean nothing lets that track catch
up (8 sources at jitter 0.06 of the shortest period, rates stated 0: 0.17-0.65 of the labels right, fdp
0.78-0.86).  Where the start beam ran (`_LOCATED`), `particles` (`_PARTICLES`, 32) teachers go on side by
side, drawn from the start's labellings by their scores: each draws its own source from its own (4.1) and
updates its own tracks as the PT does, and is weighted by the probability it gave the pulse, its (4.1)'s
normaliser (1 - lambda) sum_j pi_j N(y; H x^j, Omega^j) plus lambda times Theorem 1's spread density, and
log q for each arrival it coasted past; when the effective number of particles falls below half they are
resampled (systematic, one uniform).  This is a Rao-Blackwellised particle filter whose proposal is the
teacher's posterior, the optimal one: the published PT is its one-particle case (`particles=1`).  Each
pulse is labelled at once (lag 0) by the draw of the particle then likeliest.  Validation files 101-105,
8 sources at jitter 0.06, rates stated 0: 0.401 -> 0.755 (worst 0.166 -> 0.705; 8 particles 0.688, 16
0.605, 64 as 32 on files 101-103).  Files 101-103: rates unknown 0.620 -> 0.767, stated (2 % missing and
spurious) 0.531 -> 0.739; jitter 0.03 rates 0 0.852 -> 0.882; 16 sources at jitter 0.03 rates 0 0.256 ->
0.555, at 0.01 rates unknown 0.882 -> 0.904; 3 sources at 0.06 stated 0.796 -> 0.895.  The boards'
validation seeds (2 a scenario): paper-v0 0.623 -> 0.650, core-v0 0.882 -> 0.922, at 8-12 times the time
(core-v0 290 -> 2,150 us a pulse: one PT's work per particle).
Version 5: coasting particles, labelled by their vote.  Version 4 still lost whole files on a clean channel (8
sources at jitter 0.06, rates stated 0, validation files 101-130: 7 of 30 below 0.5), not by degenerate weights
(effective number 25-32 of 32) nor by the model (on file 119 the truth's path log-likelihood -3,131, the particles'
log evidence -39,240).  In a burst of near-coincident pulses a particle's track takes another source's pulse, and
on a channel stated clean the robbed track has no missed-arrival hypothesis: it predicts the lost pulse for good
and hands its source's later pulses to other tracks, in every particle alike.  So the particles take VI-C-3's
remedies whatever the channel (`coast=None`: coasting, scored misses with q floored at 0.001, reset_after=4,
lambda floored at 1e-6), from the start's end (from the first pulse they cost MK94's two-source scene with wrong
priors, mk94-two-var2, 0.82 -> 0.48), and each pulse is labelled by the particles' weighted vote (the mode of the
filter's marginal posterior) instead of the likeliest particle's draw, a coin toss at every near-coincidence.
Files 101-130: mean 0.633 -> 0.739, worst 0.230 -> 0.385 (fdp 0.222 on that file); core-v0's validation seeds
0.922 -> 0.949.  The price is paid on CM00's scenes, whose priors state the periods 11 % off (paper-v0, one
validation seed: 0.630 -> 0.573): on the clean ones the trains are found but often under each other's prior
identities; the jittered ones are not diagnosed yet (docs/experiments.md, 'Dense scenes').
Version 6: on a clean channel the particles take the remedies only where `gate` (5) deviations of the priors' jitter
stay within half the shortest prior period (`_resolved`).  CM00's jittered scenes (jitter std 0.12-0.39 of the
shortest prior period) and MK94's mk94-two-var3 (1.73 against 11) lost version 5's score to them: a pulse past the
midpoint of two arrivals, where the miss hypothesis starts, is there often a late pulse of the next arrival; the
particles drew misses for it, runs of them reset tracks, and the reset tracks took their neighbours' trains.
paper-v0, one validation seed: 0.580 -> 0.637 (CM00's jittered scenes 0.509 -> 0.606, mk94-two-var3 0.112 -> 0.473);
the dense files and core-v0's validation episodes pass the test and are labelled as by version 5.  CM00's clean
scenes still lose: their start already holds wrong identities (docs/experiments.md, 'pt-post version 6').
Version 7: unknown phases in the start beam.  The first pulse of a source of unknown phase was scored by the diffuse
prior (MK94's Sigma_{1|0} = 10^6 I): -log(10^6 T), some 15 nats below a pulse that continues a track, so the beam
ranked first the labellings that start tracks late, their pulses on started tracks at any period (CM00's clean
scene of five trains, priors 11 % high: the true labelling 20 nats behind by the 5th pulse and out of the beam; the
0.232 train ended on the track of prior period 0.403 +- 0.045).  In pt-post's start such a pulse now has the
density of a phase uniform over one period, 1 / T (as `_reset` has it).  And two labellings that swap the first
pulses of two such sources tie exactly and predict their next arrivals within the prior period's deviation, so the
rule keeping only labellings that predict differently dropped one of them by the order of the rows: that order, not
the periods their second pulses measure, chose which prior each train was held to (every train found, under
swapped identities).  pt-post's rule compares such a source's last arrival too, to its state's deviation (R-sized
once it took a pulse).  Priors stating every phase (core-v0, the dense files) label as before; dokf is unchanged.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import Any, NamedTuple

import numpy as np

from deint_env.receiver import is_spurious
from baselines.kalman import Block, DLMModel, overdue, phase_estimate, predict, prior_block, update
from deint_env.episode import Priors
from deint_env.errors import NotApplicable, check
from deint_env.params import SEED, Param, declare
from deint_env.policies import policy_rng

_MIN_JITTER_REL = 1e-6  # R floor, relative to the shortest prior period, for noise-free channels
_CHUNK = 4096  # uniforms drawn per refill: one per pulse, so labels do not depend on the chunking
_PRIOR_MEAN, _PRIOR_WEIGHT = 0.05, 20.0  # the weak Beta prior of an unknown rate
_Q_FLOOR = 1e-3  # the least miss probability of a coasting tracker: a merged or lost pulse stays explainable
_LAM_FLOOR = 1e-6  # and its least spurious probability: a pulse no track can explain stays spurious (mht's _R_ZERO)
_MAX_COAST = 64  # missed arrivals coasted through per pulse at most
_MAX_STEPS = 2.0**53  # arrivals a pulse may lie past a track: float64 (and the int64 counts) stay exact below
# the widest prior period deviation, in periods: the 2x2 filter's first updates subtract variances of
# (std)^2 from each other, which cancel to negative ones (at 1e11 periods they did; MK94's vaguest is 1000)
_MAX_PERIOD_STD_REL = 1e6
_START_BEAM = {"decision": 32, "posterior": 128}  # labellings kept during the start, per teacher
_AFTER_BEAM = 8  # labellings kept after the start, when the beam runs on (32: +0.003 on core-v0, 1.3x the time)
_MARGIN = 10.0  # dokf's default `beam_margin`, nats
_START_SPAN = 2.0  # the start's length, in longest prior periods from the first pulse
_LOCATED = 0.5  # pt-post acquires by the start beam when every prior period deviation is below this fraction
_SAME_AHEAD = 1.0  # a start labelling predicting a better kept one's next two arrivals to this many deviations: dropped
_AHEAD_STEPS = np.array([[0.0], [1.0], [2.0]])  # the last arrival and those two, in steps of (2.8)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)  # the Gaussians' normaliser the scores leave out
_PARTICLES = 32  # pt-post's teachers after a located start (module doc, 'Particles')
# each costs one PT's work a pulse (about 0.08 ms on 8 sources): 256 label a 1000-pulse episode in about 22 s of CPU
# (1024, the bound before, took 86 s: past a minute on the suites' own episodes; docs/hostile-round9.md)
_MAX_PARTICLES = 256
_AUTO_RESET = 4  # reset_after of pt-post's remedies when the priors do not state a clean channel (as dokf)
RATES = ("priors", "estimate")
LABELS = ("sample", "map")
TEACHERS = ("prior", "posterior", "decision")


class Candidates(NamedTuple):
    """The hypotheses for one pulse: rows 0..N-1 "source j's next arrival", then (when misses are
    hypotheses) "source j's nearest arrival after `steps` - 1 misses" for every j whose nearest arrival
    is not its next.  pred: the k-step predictions (2.8), e and s their innovations (2.15); miss: the
    log prior of the arrival (detection and misses); score: the log posterior up to a constant."""

    source: np.ndarray
    steps: np.ndarray
    pred: Block
    e: np.ndarray
    s: np.ndarray
    miss: np.ndarray
    score: np.ndarray


class _TrackState(NamedTuple):
    """What one labelling of the start beam holds: the blocks and the per-source arrival counts."""

    blocks: Block
    arrivals: np.ndarray
    missed: np.ndarray
    taken: np.ndarray
    young: bool


PARAMS = declare(
    Param("label", str, "sample", "sample: draw the label from the teacher's probabilities; map: the likeliest",
          choices=LABELS),
    SEED,
    Param("coast", bool, False, "coast through missed arrivals (none: on, with reset_after=4, unless the priors "
          "state a clean channel and one teacher runs, or a clean channel whose jitter blurs a miss)", optional=True),
    Param("gate", float, 5.0, "the overdue test's width, in predicted standard deviations", low=0, low_open=True),
    Param("reset_after", int, None, "coasted arrivals in a row after which a track's arrival variance is reset "
          "(dropout; none: never, or 4 with coast=none)", low=1, optional=True),
    Param("rates", str, "priors", "priors: the priors' miss/spurious rates (unknown ones estimated); estimate: both "
          "estimated online", choices=RATES),
    Param("particles", int, None, "pt-post: teachers run side by side after the start, each drawing its own "
          f"source, weighted by how well it predicted each pulse and resampled (none: {_PARTICLES} when the priors "
          "place every period within half of itself, else 1, the published PT; module doc, 'Particles')", low=1,
          high=_MAX_PARTICLES, optional=True),
    Param("beam_span", float, _START_SPAN, "dokf: longest prior periods from the first pulse during which it decides "
          "by its beam of labellings (none: the whole episode when the priors place every period within half of "
          "itself, else 2; module doc, 'Start beam')", low=0, low_open=True, optional=True),
    Param("beam_margin", float, None, "dokf: after the start (two longest prior periods), the beam keeps only "
          f"labellings within this many nats of the best (none: its {_AFTER_BEAM} places alone bound it; module "
          "doc, 'Start beam')", low=0, low_open=True, optional=True),
)


def _systematic(logw: np.ndarray, n: int, u: float) -> np.ndarray:
    """Systematic resampling: n indices drawn with probabilities proportional to exp(logw), from one uniform."""
    w = np.exp(logw - np.max(logw))
    cum = np.cumsum(w / w.sum())
    cum[-1] = 1.0
    return np.searchsorted(cum, (u + np.arange(n)) / n, side="right")


def _draw(c: Candidates, best: int, u: float) -> int:
    """The teacher's draw: the hypothesis of (4.1)'s posterior where its cumulative probability passes u."""
    cum = np.cumsum(np.exp(c.score - c.score[best]))
    return min(int(np.searchsorted(cum, u * cum[-1], side="right")), c.score.size - 1)


class ProbabilisticTeacher:
    """MK94 IV's PT with `teacher` "prior" (IV-2), "posterior" (Step 1, (4.1)-(4.3)) or "decision"
    (the MAP decision teaches: `dokf`); `label`, `coast` (None: on, with reset_after=4, unless the
    priors state a clean channel), `gate`, `reset_after`, `rates`, `beam_span`, `beam_margin`, `particles`: see
    the module doc.  `seed`: the policy's own seed (default: the runner's policy_seed).  Declared: `PARAMS` (and each
    subclass's)."""

    lag = 0

    def __init__(self, teacher: str, label: str = "sample", seed: int | None = None, coast: bool | None = False,
                 gate: float = 5.0, reset_after: int | None = None, rates: str = "priors",
                 beam_span: float | None = _START_SPAN, beam_margin: float | None = None, particles: int | None = 1):
        check(teacher in TEACHERS, "teacher", teacher, f"one of {', '.join(TEACHERS)}")
        PARAMS.check(locals())
        check(not (coast and teacher == "prior"), "coast", coast,
              "false with the a-priori teacher (coasting needs a posterior: its sources are always overdue)")
        self.teacher, self.label, self.seed, self.rates = teacher, label, seed, rates
        self.gate, self.beam_span, self.beam_margin = float(gate), beam_span, beam_margin
        self._coast_param, self._reset_param = coast, reset_after
        check(particles == 1 or teacher == "posterior", "particles", particles, "1 unless the teacher is a-posteriori")
        self._particles_param = particles

    def reset(self, priors: Priors, info: dict[str, Any]) -> None:
        wide = np.flatnonzero(~(priors.period_std <= _MAX_PERIOD_STD_REL * priors.period))
        if wide.size:
            j = int(wide[0])
            raise NotApplicable(f"prior period_std[{j}]={priors.period_std[j]:g} is beyond what the PT's filter "
                                f"holds: at most {_MAX_PERIOD_STD_REL:g} times the period ({priors.period[j]:g})")
        self.n = priors.n_labels
        self.priors = priors
        self.model = DLMModel.from_priors(priors, min_jitter=_MIN_JITTER_REL * float(np.min(priors.period)))
        self.blocks = prior_block(priors)  # arrays of N: the filtered (T, tau) of every source
        self.arrivals = np.zeros(self.n, dtype=np.int64)  # pulses taken + arrivals coasted through, per source
        self.missed = np.zeros(self.n, dtype=np.int64)  # arrivals coasted through since the last update
        self._sources, self._ones, self._zeros = np.arange(self.n), np.ones(self.n), np.zeros(self.n)
        pi = np.asarray(priors.source_prob, dtype=np.float64)
        self.log_pi = np.log(pi)
        self._cum_pi = np.cumsum(pi / pi.sum()).tolist()
        self._cum_pi[-1] = math.inf  # u < 1 always lands on a source
        estimate = self.rates == "estimate"
        q, r = (math.nan, math.nan) if estimate else (priors.missing_prob, priors.spurious_rate)
        self._q_known, self._r_known = q, r
        self._n_particles = self._particles_param if self._particles_param is not None else (
            _PARTICLES if self._located() else 1)
        self.coast, self.reset_after = bool(self._coast_param), self._reset_param
        # auto: VI-C-3's remedies off a clean channel (on a clean one the particles take them: `_remedies`)
        self._auto = self._coast_param is None
        if self._auto and not (q == 0.0 and r == 0.0):
            self.coast = True
            self.reset_after = _AUTO_RESET if self._reset_param is None else self._reset_param
        # misses are hypotheses when coasting (its q is floored: a merged pulse, or one the tracker gave
        # another source, leaves a track a period behind whatever the channel), or when the channel may
        # miss pulses at all.  Only the latter was tested, so a dokf told "missing_prob": 0 could not read
        # a pulse it had given another track as its own source's miss (issue #22)
        self._misses = self.coast or not q == 0.0
        self._q = _PRIOR_MEAN if math.isnan(q) else q
        self._lam = _PRIOR_MEAN if math.isnan(r) else r / (1.0 + r)
        self._pulses = self._called = self._hits = self._missed = 0  # the decided labels, for estimated rates
        self._coasted = 0  # arrivals `_coast` skipped (not counting a dropout's), since `_start_beam` zeroed it
        self.taken = np.zeros(self.n, dtype=np.int64)  # pulses taken, per source
        self._guessed = ~np.isfinite(priors.phase)  # sources whose phase the priors leave unknown
        # pt-post's start weighs their first pulses by a phase uniform over one period (`_start_beam`)
        self._uniform_phase = self._guessed & (self.teacher == "posterior")
        self._young = bool(self._guessed.any())  # some of them may still hold a single, doubtful pulse
        self._settled = math.inf  # rates are learnt from pulses after this time (set at the first pulse)
        self._start_end = math.inf  # the start (two longest periods from the first pulse) ends then
        self._acquired = math.inf
        self._started = False
        self._beam: list[tuple[float, _TrackState]] | None = None  # the start's labellings (`_start_beam`)
        self._particles: list[tuple[float, _TrackState]] | None = None  # the teachers after it (`_particle_step`)
        self._rng = policy_rng(info, self.seed)
        self._u: list[float] = []
        self._posterior = self.teacher != "prior" or self.label == "map"

    def _start(self, y: float) -> None:
        """At the first pulse: with unknown phases (kalman.prior_block's huge variance, MK94's
        Sigma_{1|0} = 10^6 I), decisions are guesses until two longest periods have passed: they are
        not counted as evidence about the channel (a wrong start would feed itself back into lambda),
        and `dokf` and `pt-post` make them by the start beam (`_start_beam`)."""
        self._started = True
        longest = float(np.max(self.priors.period))
        # the beam runs on where the priors locate the periods; with vague ones (MK94 V-C's PT scenes, period
        # 1 +- 1000) every rival labelling stays within the margin and the beam costs 7-20 ms a pulse
        span = self.beam_span if self.beam_span is not None else math.inf if self._located() else _START_SPAN
        self._start_end = y + span * longest
        self._acquired = y + _START_SPAN * longest  # the acquisition's guesses are over: the beam's margin applies
        # rates are learnt after two longest periods whatever the beam's span: the acquisition's guesses are over
        self._settled = y + _START_SPAN * longest if self._guessed.any() else -math.inf
        if self.teacher == "decision" or (self.teacher == "posterior" and self._located()):
            self._beam = [(0.0, self._save())]
        elif self._n_particles > 1:  # no start beam to seed them: every particle starts from the priors
            self._particles = [(0.0, self._save())] * self._n_particles
            self._remedies()

    def _remedies(self) -> None:
        """When the particles start, VI-C-3's remedies (`coast=None`) on a clean channel too: a particle's track
        robbed of a pulse by another of its tracks misses its next arrival on a clean channel too (module doc,
        'Particles').  Not before: in the start a far pulse says a prior is wrong, and taking it is how the KF
        learns the period (as `_spurious_prob`'s floor waits for the start's end).  On a clean channel only
        where a miss is told from a late pulse (`_resolved`): else the particles draw misses for jittered
        pulses, their tracks reset and take their neighbours' trains (module doc, 'Version 6')."""
        if self._auto and not self.coast and self._resolved():
            self.coast, self._misses = True, True
            self.reset_after = _AUTO_RESET if self._reset_param is None else self._reset_param

    def _resolved(self) -> bool:
        """The priors' arrival jitter, `gate` deviations of it, stays within half the shortest prior period: a
        pulse past the midpoint of two arrivals, where a miss hypothesis starts (`candidates`), is then no
        jittered pulse of the track's next arrival."""
        sd = math.sqrt(self.model.jitter_var + self.model.interval_var)
        return self.gate * sd < 0.5 * float(np.min(self.priors.period))

    def _located(self) -> bool:
        """The priors place every period within `_LOCATED` of itself, so that two longest periods are a
        start that acquires them (MK94 V-C's PT scenes state period 1 +- 1 or +- 1000 for 11, 30, 80)."""
        return bool(np.all(self.priors.period_std < _LOCATED * self.priors.period))

    def _uniform(self) -> float:
        if not self._u:
            self._u = self._rng.random(_CHUNK).tolist()[::-1]
        return self._u.pop()

    def _rates(self) -> None:
        """The Beta-posterior means of the unknown rates from the decided labels so far: q = (misses + 1)
        / (arrivals + 20) and lambda = (spurious + 1) / (pulses + 20) (prior mean 0.05, worth 20)."""
        if self._q_known != self._q_known:  # NaN: unknown
            self._q = (self._missed + _PRIOR_MEAN * _PRIOR_WEIGHT) / (self._hits + self._missed + _PRIOR_WEIGHT)
        if self._r_known != self._r_known:
            self._lam = (self._called + _PRIOR_MEAN * _PRIOR_WEIGHT) / (self._pulses + _PRIOR_WEIGHT)

    def _spurious_prob(self, y: float) -> float:
        """lambda of Theorem 1's test, floored when coasting after the start: with "spurious_rate": 0 the
        test never ran, so a pulse of a source whose track had slipped was forced onto the nearest other
        track, which slipped in turn (dokf: 0.12 of the labels right on 16 dense sources, 0.78 with the
        rate unknown; issue #22).  The floor only lets a pulse far outside every gate (~6 deviations) be
        spurious.  Not during the start (two longest periods): there a far pulse says a prior is wrong,
        and taking it is how the KF learns the period (MK94 V-B-2's x_{1|0} = (60, 96) for periods
        (11, 80): 0.20 of the labels right with the floor from the first pulse, 0.84 without)."""
        return max(self._lam, _LAM_FLOOR) if self.coast and y > self._acquired else self._lam

    def _coast(self, y: float) -> None:
        """VI-C-3: skip the missed arrivals of every source overdue at y (`coast`), resetting a source
        coasted through more than `reset_after` arrivals in a row (a detected dropout)."""
        b, m = self.blocks, self.model
        for _ in range(_MAX_COAST):
            pred = predict(b, m)
            late = overdue(pred, y, m, self.gate)
            if not late.any():
                break
            b = Block(*(np.where(late, new, old) for new, old in zip(pred, b)))
            self.missed += late
            self.arrivals += late
            # the arrivals skipped before a dropout, for the scores of the beam's labellings and the particles
            self._coasted += int(np.count_nonzero(late if self.reset_after is None
                                                  else late & (self.missed <= self.reset_after)))
            if self.reset_after is not None:
                b = self._reset(b, self._lost(self.missed, slice(None)))
        self.blocks = b

    def _lost(self, run: np.ndarray, source: np.ndarray | slice) -> np.ndarray:
        """A dropout: more than `reset_after` misses in a row; or a source of unknown phase that took one
        pulse and missed its next arrival (that first pulse was most likely not its own)."""
        if not self._young:
            return run > self.reset_after
        young = self._guessed[source] & (self.taken[source] == 1)
        return (run > self.reset_after) | (young & (run >= 1))

    def _reset(self, b: Block, lost: np.ndarray, source: np.ndarray | slice = slice(None)) -> Block:
        """MK94 VI-C-3's reset of a source lost in a dropout: its phase is unknown again (uniform over
        one period: var tau = T^2/12, uncorrelated with T, so the error of its next pulse does not
        bend the period), its period kept, or the prior's when it has left the prior by more than two
        prior deviations (a track biased by wrongly taken pulses)."""
        if not lost.any():
            return b
        prior_t, prior_tt = self.priors.period[source], self.priors.period_std[source] ** 2
        astray = lost & ((b.period - prior_t) ** 2 > 4.0 * prior_tt)
        t = np.where(astray, prior_t, b.period)
        return Block(t, b.tau, np.where(astray, prior_tt, b.p_tt), np.where(lost, 0.0, b.p_tx),
                     np.where(lost, t * t / 12.0, b.p_xx))

    def candidates(self, y: float) -> Candidates:
        """(4.1)-(4.3) with missed arrivals: for every source its next arrival and, when the channel
        may miss pulses, its arrival nearest to y after m more misses (k = m + 1 steps of (2.8) in
        closed form), scored log pi_j + log(1 - q) + m log q + log N(e; 0, S).  Coasting (`coast`)
        first skips the arrivals that are plainly past (`_coast`); the nearest-arrival rows decide
        the rest (a pulse less than `gate` deviations beyond the midpoint of two arrivals, or any
        late pulse of a non-coasting teacher)."""
        if self.coast:
            self._coast(y)
        b, m = self.blocks, self.model
        q = max(self._q, _Q_FLOOR) if self.coast else self._q
        source, steps, more = self._sources, self._ones, None
        if self._misses and q > 0:
            near = np.floor((y - b.tau) / b.period + 0.5)
            more = np.flatnonzero(near > 1.0)
            if more.size and not near[more].max() < _MAX_STEPS:  # a TOA of 1e300, or a period of 1e-30
                j = int(more[np.argmax(near[more])])
                raise NotApplicable(f"the pulse at TOA {y:.6g} lies {near[j]:.3g} periods ({b.period[j]:.3g}) past "
                                    f"track {j}'s last arrival; at most 2^53 can be counted")
        if more is not None and more.size:
            source, steps = np.concatenate([source, more]), np.concatenate([steps, near[more]])
            bb = b.take(source)
            # (2.8) `steps` times: tau + k T, cov(T, tau) + k var T, var tau + 2k cov + k^2 var T + k Q
            pred = Block(bb.period, bb.tau + steps * bb.period, bb.p_tt, bb.p_tx + steps * bb.p_tt,
                         steps * steps * bb.p_tt + 2.0 * steps * bb.p_tx + bb.p_xx + steps * m.interval_var)
            missed = steps - 1.0
            run = missed + self.missed[source]
        else:  # every source's next arrival only: (4.3)
            pred, missed, run = predict(b, m), self._zeros, self.missed
        if self.reset_after is not None and (self._young or run.max() > self.reset_after):
            # a dropout, as in `_coast`: its phase is lost, its misses cost nothing
            lost = self._lost(run, source)
            if lost.any():
                pred = self._reset(pred, lost, source)
                missed = np.where(lost, 0.0, missed)
        e, s = y - pred.tau, pred.p_xx + m.jitter_var
        miss = np.full(source.size, math.log1p(-q))
        if source.size > self.n:
            miss += missed * math.log(q)
        fit = -0.5 * (np.log(s) + e * e / s)
        if self._young and self._beam is not None:
            # a first pulse of unknown phase in pt-post's start beam: density 1 / T (`_start_beam`)
            fresh = self._uniform_phase[source] & (self.taken[source] == 0)
            fit = np.where(fresh, _HALF_LOG_2PI - np.log(pred.period), fit)
        score = (self.log_pi if source.size == self.n else self.log_pi[source]) + miss + fit
        return Candidates(source, steps, pred, e, s, miss, score)

    def act(self, obs: dict[str, Any]) -> int:
        if not int(obs["valid"]):
            return 0
        y = float(obs["toa"][0])
        if not self._started:
            self._start(y)
        u = self._uniform() if self.teacher != "decision" else 0.0  # one draw per pulse: reproducible
        if not self._posterior:  # pt-prior, sampled labels: only the chosen block is touched
            j = bisect_right(self._cum_pi, u)
            b = self.blocks
            pred = predict(Block(float(b.period[j]), float(b.tau[j]), float(b.p_tt[j]), float(b.p_tx[j]),
                                 float(b.p_xx[j])), self.model)
            b.put(j, update(pred, y - pred.tau, pred.p_xx + self.model.jitter_var, self.model))
            self.arrivals[j] += 1
            return j
        self._rates()
        counted = y > self._settled
        if self._beam is not None:
            if y <= self._start_end:
                return self._start_beam(y)
            if self._n_particles > 1:  # the particles are drawn from the start's labellings, by their scores
                pick = _systematic(np.array([score for score, _ in self._beam]), self._n_particles, self._uniform())
                self._particles = [(0.0, self._beam[i][1]) for i in pick]
                self._remedies()
            self._beam = None  # the start is over: on from the best labelling alone (loaded)
        if self._particles is not None:
            return self._particle_step(y, counted)
        c = self.candidates(y)
        best = int(np.argmax(c.score))
        self._pulses += counted
        lam = self._spurious_prob(y)
        if lam > 0 and self.teacher != "prior" and self._called_spurious(c, best, lam):
            self._called += counted
            return self.n
        if self.teacher == "prior":
            pick = int(np.flatnonzero(c.source == bisect_right(self._cum_pi, u))[0])
        elif self.teacher == "decision":
            pick = best
        else:
            pick = _draw(c, best, u)
        self._apply(c, pick, counted)
        return int(c.source[best]) if self.label == "map" else int(c.source[pick])

    def _particle_step(self, y: float, counted: bool) -> int:
        """pt-post with `particles` > 1 after the start: every particle is a PT (its own tracks, its own draw
        from its own (4.1)), weighted by the probability it gave the pulse, (1 - lambda) sum_j exp(score_j)
        plus lambda times Theorem 1's spread density (and log q per arrival it coasted past), and resampled
        (systematic) when the effective number falls below half.  The pulse is labelled by the particles'
        weighted vote of their draws (or, `label="map"`, their MAPs).  A Rao-Blackwellised particle filter with
        the optimal proposal: the published PT is its one-particle case, whose wrong draw is for good."""
        lam = self._spurious_prob(y)
        log_pulse = math.log1p(-lam)
        log_skip = math.log(max(self._q, _Q_FLOOR)) if self.coast else 0.0
        drawn = [self._uniform() for _ in self._particles]  # as many draws every pulse, whatever happens
        u_resample = self._uniform()
        weights, states, labels, runs = [], [], [], []
        for (logw, state), u in zip(self._particles, drawn):
            self._load(state)
            self._coasted = 0
            c = self.candidates(y)
            best = int(np.argmax(c.score))
            top = float(c.score[best])
            fit = top + math.log(float(np.sum(np.exp(c.score - top)))) + log_pulse
            pick = run = None
            spurious = False
            if lam > 0:
                fit = np.logaddexp(fit, self._spurious_score(0.0, c, best, lam))
                spurious = self._called_spurious(c, best, lam)
            if not spurious:
                pick = _draw(c, best, u)
                run = self._apply(c, pick, False)
            labels.append(self.n if spurious else int(c.source[best if self.label == "map" else pick]))
            runs.append(run)
            weights.append(logw + float(fit) + self._coasted * log_skip)
            states.append(self._save())
        logw = np.array(weights)
        lead = int(np.argmax(logw))
        self._pulses += counted
        if runs[lead] is None:
            self._called += counted
        elif counted:
            self._count(runs[lead])
        w = np.exp(logw - logw[lead])
        votes = np.zeros(self.n + 1)
        np.add.at(votes, labels, w)  # the label most of the weight drew: the particles' marginal posterior mode
        if w.sum() ** 2 < 0.5 * len(w) * float(np.sum(w * w)):  # effective number (sum w)^2 / sum w^2 below half
            self._particles = [(0.0, states[i]) for i in _systematic(logw, len(w), u_resample)]
        else:
            self._particles = list(zip((logw - logw[lead]).tolist(), states))
        self._load(states[lead])
        return int(np.argmax(votes))

    def _called_spurious(self, c: Candidates, best: int, lam: float) -> bool:
        """Theorem 1 (21)-(24) on the best hypothesis, its prior odds against "spurious" being
        (1 - lambda) P_D q^m : lambda (P_D = 1 - q, the detection probability; m its misses)."""
        pulse = (1.0 - lam) * math.exp(float(c.miss[best]))
        spread = float(c.pred.period[best]) ** 2 / 12.0
        return is_spurious(float(c.e[best]), float(c.s[best]), lam / (lam + pulse), spread)

    def _spurious_score(self, score: float, c: Candidates, best: int, lam: float) -> float:
        """`score` plus the log probability of "spurious" at this pulse: log lambda and Theorem 1's spread density
        around the best hypothesis (its variance plus a uniform arrival's over one period)."""
        spread = float(c.s[best]) + float(c.pred.period[best]) ** 2 / 12.0
        e = float(c.e[best])
        return score + math.log(lam) + float(self.log_pi[c.source[best]]) - 0.5 * (math.log(spread) + e * e / spread)

    def _apply(self, c: Candidates, pick: int, counted: bool) -> int:
        """(4.4): the KF update of the source of hypothesis `pick`, and its arrival bookkeeping."""
        j, k = int(c.source[pick]), int(c.steps[pick])
        self.blocks.put(j, update(c.pred.take(pick), c.e[pick], c.s[pick], self.model))
        self.arrivals[j] += k
        self.taken[j] += 1
        if self._young and self.taken[j] == 2:
            self._young = bool(np.any(self._guessed & (self.taken < 2)))
        run = int(self.missed[j]) + k - 1  # the misses since the source's last pulse
        if counted:
            self._count(run)
        self.missed[j] = 0
        return run

    def _count(self, run: int) -> None:
        """A decided pulse taken after `run` misses of its source, for the estimated rates."""
        self._hits += 1
        if self.reset_after is None or run <= self.reset_after:  # a dropout is not a run of misses
            self._missed += run

    def _save(self) -> _TrackState:
        return _TrackState(self.blocks.copy(), self.arrivals.copy(), self.missed.copy(), self.taken.copy(), self._young)

    def _load(self, state: _TrackState) -> None:
        self.blocks, self.arrivals, self.missed, self.taken = (state.blocks.copy(), state.arrivals.copy(),
                                                               state.missed.copy(), state.taken.copy())
        self._young = state.young

    def _start_beam(self, y: float) -> int:
        """`dokf` and `pt-post` while unknown phases are acquired (until two longest periods have
        passed): which fresh track a first pulse starts is a guess a single decision gets wrong too
        often, so the decisions of the start are a beam search: every kept labelling is extended by each
        hypothesis of `candidates` (log(1 - lambda) + its score) and by "spurious" (log lambda + Theorem
        1's spread density around its best hypothesis), and the best `_START_BEAM[teacher]` kept,
        skipping any whose next two arrivals (`_ahead`; in pt-post the last one of a source of unknown phase
        too) a better kept one predicts within `_SAME_AHEAD` deviations; each pulse is labelled at once by the
        best.  After the start (`dokf`, `beam_span`) at most `_AFTER_BEAM` are kept, within `beam_margin` of the
        best; where the beam ends the tracker goes on from the best alone.  One kept labelling reproduces the
        single-decision rule exactly."""
        lam = self._spurious_prob(y)
        log_pulse = math.log1p(-lam)
        # after the start the labellings' skipped arrivals are priced as the candidates' misses are: free, a
        # labelling whose idle track takes another's pulses (the other coasting) scores as the true one
        log_skip = math.log(max(self._q, _Q_FLOOR)) if self.coast and y > self._acquired else 0.0
        scores, expanded = [], []  # each kept labelling's children's scores (its rows, then "spurious")
        for score, state in self._beam:
            self._load(state)
            self._coasted = 0
            c = self.candidates(y)  # coasts the loaded state
            score += self._coasted * log_skip
            expanded.append((self._save(), c))
            children = (score + log_pulse) + c.score
            if lam > 0:
                children = np.append(children, self._spurious_score(score, c, int(np.argmax(c.score)), lam))
            scores.append(children)
        flat = np.concatenate(scores)
        owner = np.repeat(np.arange(len(scores)), [ch.size for ch in scores])
        row = np.concatenate([np.arange(ch.size) for ch in scores])
        order = np.argsort(-flat, kind="stable").tolist()  # best first; ties in the labellings' and rows' order
        floor = flat[order[0]] - self.beam_margin if self.beam_margin is not None and y > self._acquired else -math.inf
        beam = []
        size = _START_BEAM[self.teacher] if y <= self._acquired else _AFTER_BEAM
        ahead = np.empty((size, 2, _AHEAD_STEPS.size, self.n))  # the kept labellings' `_ahead`
        for k in order:
            score = float(flat[k])
            if score < floor:
                break
            parent, c = expanded[owner[k]]
            self._load(parent)
            if row[k] < c.score.size:  # else "spurious": nothing updated
                self._apply(c, int(row[k]), False)
            mean, var = self._ahead()
            kept = ahead[:len(beam)]
            if np.any(np.all((kept[:, 0] - mean) ** 2 <= _SAME_AHEAD ** 2 * np.minimum(kept[:, 1], var), axis=(1, 2))):
                continue  # a better labelling already predicts what this one does
            ahead[len(beam)] = mean, var
            beam.append((score, self._save()))
            if len(beam) == size:
                break
        top = order[0]
        c = expanded[owner[top]][1]
        label = int(c.source[row[top]]) if row[top] < c.score.size else self.n
        self._beam = beam
        self._load(beam[0][1])  # the tracker's state is the best labelling's
        return label

    def _ahead(self) -> tuple[np.ndarray, np.ndarray]:
        """Every source's next two arrivals (2.8) and their variances, without the jitter's, and in pt-post the
        last arrival of a source of unknown phase (`_start_beam`; any other's is alike at any distance)."""
        b, k = self.blocks, _AHEAD_STEPS
        var = k * k * b.p_tt + 2.0 * k * b.p_tx + b.p_xx + k * self.model.interval_var
        var[0] = np.where(self._uniform_phase, var[0], np.inf)
        return b.tau + k * b.period, var

    def estimates(self) -> dict[str, np.ndarray]:
        return {"period": self.blocks.period.copy(), "phase": phase_estimate(self.blocks, self.arrivals)}


class PTPrior(ProbabilisticTeacher):
    """`pt-prior`: MK94 IV-2, the source drawn from the known a-priori probabilities pi."""

    PARAMS = PARAMS.only("label", "seed")

    def __init__(self, label: str = "sample", seed: int | None = None):
        super().__init__("prior", label, seed)


class PTPost(ProbabilisticTeacher):
    """`pt-post`: MK94 IV, the source drawn from the a-posteriori probabilities (4.1)-(4.3), after an
    acquisition by the start beam when the priors locate the periods (module doc)."""

    PARAMS = PARAMS.only("label", "seed", "coast", "gate", "reset_after", "rates", "particles").changed(coast=None)

    def __init__(self, label: str = "sample", seed: int | None = None, coast: bool | None = None, gate: float = 5.0,
                 reset_after: int | None = None, rates: str = "priors", particles: int | None = None):
        super().__init__("posterior", label, seed, coast, gate, reset_after, rates, particles=particles)


class DOKFTracker(ProbabilisticTeacher):
    """`dokf`: the PT's tracker taught by its own MAP decisions, with DM89's Theorem 1 spurious test,
    coasting through missed arrivals and dropout resets (deterministic: it draws nothing)."""

    PARAMS = PARAMS.only("coast", "gate", "reset_after", "rates", "beam_span", "beam_margin").changed(
        coast=True, reset_after=4, beam_span=None, beam_margin=_MARGIN)

    def __init__(self, coast: bool = True, gate: float = 5.0, reset_after: int | None = 4, rates: str = "priors",
                 beam_span: float | None = None, beam_margin: float | None = _MARGIN):
        super().__init__("decision", "map", None, coast, gate, reset_after, rates, beam_span, beam_margin)

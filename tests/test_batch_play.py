"""Batched play (`deint_env.runner.play_batch`, the `BatchPolicy` protocol) and the `agent` policy's
compiled path: a batch labels as each episode alone, the compiled network as torch, and the compiled
token features are the numpy formulas' bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

import torch  # noqa: E402

from agents.networks import action_scores  # noqa: E402
from agents.policy import ZOO_CHECKPOINT, AgentPolicy  # noqa: E402
from deint_env import BatchPolicy, Policy, PolicyInfo, make_policy, simulate  # noqa: E402
from deint_env import policies, runner  # noqa: E402
from deint_env.episode import Priors  # noqa: E402
from deint_env.errors import NotApplicable  # noqa: E402
from deint_env.features import (CLIP, PERIOD_GATE, PRIOR_WEIGHT, TOKEN_FEATURES, TrackFeatures,  # noqa: E402
                                TrackLayout, _resid)
from deint_env.runner import BATCH, batch_size, make_tasks, play, play_batch  # noqa: E402
from deint_env.scenario import PriorSpec, ScenarioSpec, SourceSpec  # noqa: E402
from deint_env.suites import find_entry  # noqa: E402

V3 = f"agent:checkpoint={ZOO_CHECKPOINT}"  # token layout 3 (dagger's checkpoint is layout 2)
AMPLITUDES = ScenarioSpec(name="amplitudes", n_pulses=120, toa_jitter_std=0.1, amplitudes=True,
                          sources=(SourceSpec(period=10.0, amplitude=1.0, amplitude_std=0.1),
                                   SourceSpec(period=13.0, amplitude=2.0, amplitude_std=0.1),
                                   SourceSpec(period=17.0, amplitude=3.0, amplitude_std=0.1)),
                          priors=PriorSpec(period_error=0.01, phase_error=0.05))


def core(name: str, n_pulses: int, seed: int = 99_000):
    return simulate(find_entry(f"core-v0/{name}").spec.replace(n_pulses=n_pulses), seed)


def episodes():
    """Validation episodes of 2 to 8 sources and of different lengths, and one with amplitudes."""
    return [core("core-n4-spread4-jitter0.2", 150), core("core-n2-spread4-jitter0.05", 260),
            core("core-n8-spread4-jitter0.2", 90), simulate(AMPLITUDES, 5),
            core("core-n2-spread4-jitter0.2", 40, 99_001)]


@pytest.mark.parametrize("spec", ["dagger", "dagger:deterministic=false", V3, "ppo"])
def test_a_batch_labels_as_each_episode_alone(spec):
    eps = episodes()
    seeds = [7 * i for i in range(len(eps))]
    batch = play_batch(make_policy(spec), eps, policy_seeds=seeds)
    for episode, seed, got in zip(eps, seeds, batch):
        try:
            alone = play(make_policy(spec), episode, policy_seed=seed)
        except NotApplicable as e:  # ppo: two sources only
            assert isinstance(got, NotApplicable) and str(got) == str(e)
            continue
        np.testing.assert_array_equal(got.labels, alone.labels, err_msg=f"{spec}, {len(episode)} pulses")
        assert got.metrics["accuracy"] == alone.metrics["accuracy"]
    played = [(r, e) for r, e in zip(batch, eps) if not isinstance(r, NotApplicable)]
    assert played and len({round(r.seconds / len(e), 15) for r, e in played}) == 1  # one time per pulse


def test_a_blind_batch_labels_as_each_episode_alone():
    eps = [simulate(find_entry(f"blind-v0/{n}").spec.replace(n_pulses=m), 99_000)
           for n, m in (("blind-n2to2-jitter0.1", 80), ("blind-n4to6-jitter0.1", 50))]
    for got, episode in zip(play_batch(make_policy(V3), eps), eps):
        np.testing.assert_array_equal(got.labels, play(make_policy(V3), episode).labels)


@pytest.mark.parametrize("spec", ["dagger", V3, "ppo"])
def test_the_compiled_network_labels_and_scores_as_torch(spec):
    """The compiled forward pass (agents.fast_net) against the checkpoint's torch network: the same
    labels, and log-probabilities within float32 rounding on every observation it scored."""
    eps = [core("core-n2-spread4-jitter0.05", 150), core("core-n2-spread4-jitter0.2", 120, 99_002)]
    if spec != "ppo":
        eps += [core("core-n6-spread4-jitter0.2", 120), simulate(AMPLITUDES, 6)]
    for episode in eps:
        fast, slow = make_policy(spec), make_policy(spec)
        seen = []
        compiled = fast._fast

        def recorded(*args, compiled=compiled):
            seen.append(args)
            return compiled(*args)

        fast._fast, slow._fast = recorded, None
        np.testing.assert_array_equal(play(fast, episode).labels, play(slow, episode).labels)
        assert seen
        for args in seen:
            if len(args) == 3:  # tracks, pulse, track counts
                tracks, pulse, n = args
                mask = (np.arange(tracks.shape[1]) < n[:, None]).astype(np.float32)
                ref = action_scores(slow._net, {"tracks": tracks, "mask": mask, "pulse": pulse})
            else:
                ref = action_scores(slow._net, args[0])
            ref = torch.log_softmax(ref, 1).numpy()
            got = torch.log_softmax(torch.from_numpy(compiled(*args)), 1).numpy()
            keep = ref > -1e6  # the tracks the scenario has, and spurious
            np.testing.assert_allclose(got[keep], ref[keep], atol=2e-5, rtol=1e-5)


def numpy_arrays(tf: TrackFeatures) -> tuple[np.ndarray, np.ndarray]:
    """The token features as numpy computed them before the kernel (deint_env.features_kernels): the
    reference the kernel is held to, bit for bit."""
    lay = tf.layout
    with np.errstate(invalid="ignore", divide="ignore"):
        ready = tf.ready
        t, prev = tf.win_toa[:, 1], tf.win_toa[:, 0]
        tt = t[:, None]
        unit = (t - tf.first_toa) / np.maximum(tf.labelled, 1)
        unit = np.where((tf.labelled > 0) & (unit > 0), unit, np.nan)
        u = unit[:, None]
        p = tf.period
        since = (tt - tf.anchor) / p
        n = np.maximum(np.rint(since), 1.0)
        tok = [tf.exists, tf.count > 0, np.log1p(tf.count), np.isfinite(p), np.isfinite(tf.anchor),
               since, since - n, n - 1, (t - prev)[:, None] / p, np.log(p / u), (tt - tf.anchor) / u,
               (tf.win_amp[:, 1:2] - tf.amp_mean) / np.where(tf.blind[:, None], np.abs(
                   tf.win_amp[:, 1:2]) + 1e-12, tf.amp_scale), p / tf.prior_period - 1.0]
        v3 = lay.version >= 3
        if v3:
            p_sigma = p / np.maximum(tf.scalars[:, 2:3], 1e-3 * p)
            tok.append((since - n) * p_sigma)
        pulse = [ready, ready & ~np.isfinite(prev), tf.blind, tf.n_labels / lay.max_tracks,
                 tf.scalars[:, 0], tf.scalars[:, 1], tf.scalars[:, 2] / unit, tf.has_amp]
        for j in range(1, lay.lookahead + 1):
            tj = tf.win_toa[:, 1 + j]
            ahead = _resid((tj[:, None] - tf.anchor) / p)
            ahead_self = _resid((tj - t)[:, None] / p)
            tok += [ahead, ahead_self] + ([ahead * p_sigma, ahead_self * p_sigma] if v3 else [])
            pulse += [np.isfinite(tj), (tj - t) / unit]
        tracks = np.stack(np.broadcast_arrays(*tok), axis=-1).astype(np.float64)
        tracks[~tf.has_amp, :, TOKEN_FEATURES.index("amp")] = 0.0
        keep = (tf.exists & ready[:, None])[:, :, None]
        tracks = np.where(keep & np.isfinite(tracks), np.clip(tracks, -CLIP, CLIP), 0.0)
        glob = np.stack([np.asarray(g, np.float64) for g in pulse], axis=-1)
        glob = np.where(ready[:, None] & np.isfinite(glob), np.clip(glob, -CLIP, CLIP), 0.0)
    return tracks.astype(np.float32), glob.astype(np.float32)


def numpy_label(tf: TrackFeatures, actions: np.ndarray) -> None:
    """`TrackFeatures.label` as numpy computed it before the kernel (`features_kernels.label_rows`)."""
    a = np.asarray(actions, np.int64)
    ready = tf.ready
    rows = np.flatnonzero(ready & (a >= 0) & (a < tf.n_labels))
    tf.labelled += ready
    if rows.size:
        i = a[rows]
        t, amp = tf.win_toa[rows, 1], tf.win_amp[rows, 1]
        count, period, anchor = tf.count[rows, i], tf.period[rows, i], tf.anchor[rows, i]
        d = t - anchor
        used = count > 0
        known = used & np.isfinite(period)
        n = np.maximum(np.rint(np.where(known, d / np.where(known, period, 1.0), 1.0)), 1.0)
        gate = known & (np.abs(d - n * period) <= PERIOD_GATE * period)
        span_t = tf.span_time[rows, i] + np.where(gate, d, 0.0)
        span_n = tf.span_periods[rows, i] + np.where(gate, n, 0.0)
        first_interval = used & ~np.isfinite(period) & (d > 0)
        span_t = np.where(first_interval, d, span_t)
        span_n = np.where(first_interval, 1.0, span_n)
        p0 = tf.prior_period[rows, i]
        anchored = np.isfinite(p0)
        new_period = np.where(anchored, (PRIOR_WEIGHT * np.where(anchored, p0, 0.0) + span_t)
                              / (PRIOR_WEIGHT + span_n), span_t / np.maximum(span_n, 1.0))
        tf.period[rows, i] = np.where(gate | first_interval, new_period, period)
        tf.span_time[rows, i], tf.span_periods[rows, i] = span_t, span_n
        tf.anchor[rows, i] = t
        tf.count[rows, i] = count + 1
        mean = tf.amp_mean[rows, i]
        tf.amp_mean[rows, i] = np.where(used & np.isfinite(mean), mean + (amp - mean) / (count + 1), amp)
    tf.win_toa[ready, 0] = tf.win_toa[ready, 1]
    tf.win_toa[ready, 1] = np.nan


STATE = ("labelled", "count", "period", "anchor", "span_time", "span_periods", "amp_mean", "win_toa")


@pytest.mark.parametrize("version,lookahead", [(2, 3), (3, 3), (3, 0), (2, 1)])
def test_the_feature_kernels_give_the_numpy_features_bit_for_bit(version, lookahead):
    """Every step of a batch of episodes (anchored, blind, amplitudes; random labels, some spurious or
    naming absent tracks), both layouts: the observation and, after each label, the whole state."""
    eps = [core("core-n4-spread4-jitter0.2", 150), simulate(AMPLITUDES, 3), core("core-n8-spread4-jitter0.05", 90),
           simulate(find_entry("blind-v0/blind-n3to3-jitter0.1").spec.replace(n_pulses=120), 99_000)]
    tf, ref = (TrackFeatures(len(eps), TrackLayout(8, lookahead, False, version)) for _ in range(2))
    for f in (tf, ref):
        f.reset_rows(range(len(eps)), [e.priors for e in eps], [e.amplitude is not None for e in eps])
    rng = np.random.default_rng(version + lookahead)
    steps = 0
    for k in range(max(len(e) for e in eps) + lookahead):
        valid = np.array([k < len(e) for e in eps])
        toa = np.array([e.toa[k] if k < len(e) else 0.0 for e in eps])
        amp = np.array([e.amplitude[k] if k < len(e) and e.amplitude is not None else 0.0 for e in eps])
        tf.observe(toa, amp, valid)
        ref.observe(toa, amp, valid)
        got, want = tf.arrays(), numpy_arrays(tf)
        assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes(), k
        steps += int(tf.ready.sum())
        actions = rng.integers(0, 9, len(eps))
        tf.label(actions)
        numpy_label(ref, actions)
        assert all(getattr(tf, a).tobytes() == getattr(ref, a).tobytes() for a in STATE), k
    assert steps > 300


def test_the_protocol_and_which_policies_the_runner_batches():
    dagger = make_policy("dagger")
    assert isinstance(dagger, BatchPolicy) and isinstance(dagger, Policy)
    assert not isinstance(make_policy("fdp"), BatchPolicy) and isinstance(make_policy("fdp"), Policy)
    assert batch_size("dagger") == batch_size("ppo") == BATCH
    assert batch_size("fdp") == batch_size("genie") == batch_size("dagger-beam") == 1
    # the registry's mode check guards a batch's rows as it guards `reset`
    blind = simulate(find_entry("blind-v0/blind-n3to3-jitter0.1").spec.replace(n_pulses=30), 99_000)
    dagger.reset_batch(2)
    with pytest.raises(NotApplicable, match="anchored scenarios only"):
        dagger.reset_row(1, blind.priors, {})
    jobs = runner.make_jobs(["dagger", "fdp"], "core-v0", split="validation", max_seeds=2)
    tasks = make_tasks(jobs, workers=2)
    batched = [t for t in tasks if t[0].policy == "dagger"]
    assert [len(t) for t in batched] == [45, 45]  # 90 jobs: two batches, one per worker
    assert [j for t in batched for j in t] == [j for j in jobs if j.policy == "dagger"]
    assert all(len(t) == 1 for t in tasks if t[0].policy == "fdp")
    few = [j for j in jobs if j.policy == "fdp"][:3] + [j for j in jobs if j.policy == "dagger"][:5]
    assert [len(t) for t in make_tasks(few)] == [1, 1, 1, 5]


class FailsOnSomeEpisodes(AgentPolicy):
    """dagger, but its `act_batch` raises in any batch holding the 8-source episode."""

    def reset_row(self, row: int, priors: Priors, info: dict) -> None:
        super().reset_row(row, priors, info)
        self._eight = getattr(self, "_eight", False) or priors.n_labels == 8

    def act_batch(self, rows, obs):
        if self._eight:
            raise ZeroDivisionError("the policy divided by zero")
        return super().act_batch(rows, obs)


def test_a_failing_batch_is_replayed_alone_and_records_as_solo_play(monkeypatch):
    from agents.policy import DAGGER_CHECKPOINT

    policies.list_policies()
    monkeypatch.setitem(policies._REGISTRY, "fails", PolicyInfo(
        "fails", lambda: FailsOnSomeEpisodes(str(DAGGER_CHECKPOINT)), kind="reference", modes=("anchored",)))
    scenarios = ["core-v0/core-n2-spread4-jitter0.05", "core-v0/core-n8-spread4-jitter0.2"]
    jobs = [j for s in scenarios for j in runner.make_jobs(["fails", "dagger"], s, split="validation", max_seeds=1)]
    for job in jobs:  # short episodes
        object.__setattr__(job, "scenario", {**job.scenario, "n_pulses": 60})
    fails = runner.run_batch([j for j in jobs if j.policy == "fails"])
    assert [r.fault for r in fails] == [None, "ZeroDivisionError: the policy divided by zero"]
    batched = runner.run_batch([j for j in jobs if j.policy == "dagger"])
    alone = [runner.run_job(j) for j in jobs if j.policy == "dagger"]
    for a, b, f in zip(batched, alone, fails):
        assert a.metrics["accuracy"] == b.metrics["accuracy"] and a.metrics["score"] == b.metrics["score"]
    assert fails[0].metrics["accuracy"] == alone[0].metrics["accuracy"]
    assert batched[0].metrics["us_per_pulse"] == pytest.approx(batched[1].metrics["us_per_pulse"])


def test_the_timing_run_times_a_batch_policy_in_lock_step_and_the_board_says_so():
    from deint_env.leaderboard import render, timing
    from deint_env.leaderboard.build import add_looks_and_timings

    eps = episodes()
    dagger, fdp, ppo = (timing.time_policy(s, eps) for s in ("dagger", "fdp", "ppo"))
    assert (dagger.episodes, dagger.batch) == (5, 5) and (fdp.episodes, fdp.batch) == (5, 1)
    assert (ppo.episodes, ppo.batch) == (2, 2)  # its two-source episodes only
    row = {"played": 1, "faults": [], "submitted": False, "oracle": False, "kind": "reference"}
    board = {"rows": [{**row, "policy": "dagger"}, {**row, "policy": "fdp"}], "intervals": True,
             "seeds_per_scenario": 3}
    timings = {"date": "d", "machine": {"processor": "p", "cpus": 2, "python": "3"}, "method": "m",
               "reference": {"us_per_pulse": 10.0, "suite": "core-v0"},
               "policies": {"dagger": {"us_per_pulse": 9.0, "vs_fdp": 0.9, "batch": 45},
                            "fdp": {"us_per_pulse": 10.0, "vs_fdp": 1.0, "batch": 1}}}
    add_looks_and_timings(board, [], timings)
    assert board["rows"][0]["timing_batch"] == 45 and "timing_batch" not in board["rows"][1]
    notes = [n for n in render.board_notes(board) if n.startswith("**Batched K episodes:**")]
    assert len(notes) == 1 and "dagger (45)" in notes[0] and "fdp" not in notes[0]

"""Extreme but valid inputs to the reference policies (issue 7): `genie` (from a priors file), `ekf-bank`
and `ekf-coupled` either label sensibly or refuse the episode as not applicable with one line saying
why -- never a traceback, a huge allocation or a run of minutes.

The pulse files come from a tiny generator of our own (three jittered constant-PRI trains), with one
hostile edit each: one TOA of 1e12 at the end of a 600-pulse file, every TOA near 1e300, one TOA of
1e300, a prior period of 1e-6.  Each case runs through the policy API and through `deint label`.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from baselines import ekf
from baselines.coupled import EKFCoupled
from baselines.ekf import EKFBank
from baselines.genie import Genie
from deint_env import formats
from deint_env.cli import main
from deint_env.episode import Priors
from deint_env.errors import NotApplicable
from deint_env.runner import play

PERIODS, PHASES, SIGMA = (11.0, 17.0, 29.0), (1.0, 3.0, 7.0), 0.3
POLICIES = {"genie": Genie, "ekf-bank": EKFBank, "ekf-coupled": EKFCoupled}


def pulses(n: int = 600, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The first n received pulses of three jittered constant-PRI trains (TOAs sorted)."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    toa = np.concatenate([ph + k * t + rng.normal(0, SIGMA, n) for t, ph in zip(PERIODS, PHASES)])
    src = np.repeat(np.arange(3), n)
    order = np.argsort(toa)[:n]
    return toa[order], src[order]


def write_case(tmp_path, case: str) -> tuple[str, str]:
    """(pulse file, priors file) of one hostile case."""
    toa, src = pulses()
    periods = list(PERIODS)
    if case == "outlier-1e12":
        toa[-1] = 1e12
    elif case == "all-near-1e300":
        toa = toa + 1e300
    elif case == "one-1e300":
        toa[-1] = 1e300
    elif case == "period-1e-6":
        periods[0] = 1e-6
    else:
        assert case == "clean"
    path, pri = tmp_path / f"{case}.csv", tmp_path / f"{case}.json"
    path.write_text("toa,source\n" + "".join(f"{float(t)!r},{int(s)}\n" for t, s in zip(toa, src)))
    pri.write_text(json.dumps({"period": periods, "phase": list(PHASES), "jitter_std": SIGMA}))
    return str(path), str(pri)


def episode_of(path: str, pri: str):
    priors = Priors.from_json_dict(json.loads(open(pri).read()))
    return formats.read_pulses(path, priors)


HOSTILE = {  # case -> the reason each policy gives
    "outlier-1e12": {"genie": r"span 1e\+12 time units, 1.84e\+11 emissions .* at most 1600000",
                     "ekf": r"pulse 599 \(TOA 1e\+12\) lies 9.09e\+11 sampling steps .* at most 250000 are allowed"},
    "all-near-1e300": {"genie": r"TOAs up to 1e\+300 are stored in float64 steps of 1.49e\+284, too coarse",
                       "ekf": r"pulse 0 has TOA 1e\+300, stored in float64 steps of 1.49e\+284, coarser than the "
                              r"sampling step Ts = 1.1"},
    "one-1e300": {"genie": r"TOAs up to 1e\+300 are stored in float64 steps",
                  "ekf": r"pulse 599 has TOA 1e\+300, stored in float64 steps"},
    "period-1e-6": {"genie": r"3.26e\+09 emissions of the true schedule \(periods down to 1e-06\)",
                    "ekf": r"pulse 0 \(TOA 1.03\d*\) lies 1.04e\+07 sampling steps \(Ts = 1e-07\)"},
}


@pytest.mark.parametrize("policy", sorted(POLICIES))
@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_episode_is_refused_as_not_applicable(tmp_path, policy, case):
    path, pri = write_case(tmp_path, case)
    reason = HOSTILE[case]["genie" if policy == "genie" else "ekf"]
    with pytest.raises(NotApplicable, match=reason):
        play(POLICIES[policy](), episode_of(path, pri), oracle=policy == "genie")


@pytest.mark.parametrize("policy", sorted(POLICIES))
@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_cli_label_says_why_in_one_line_and_exits_2(tmp_path, capsys, policy, case):
    path, pri = write_case(tmp_path, case)
    out = tmp_path / "labels.csv"
    assert main(["label", path, "--policy", policy, "--priors", pri, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"deint: error: {policy}: ") and "Traceback" not in err
    assert not out.exists()  # nothing written


@pytest.mark.parametrize("policy", sorted(POLICIES))
def test_clean_file_still_labels_well(tmp_path, capsys, policy):
    path, pri = write_case(tmp_path, "clean")
    out = tmp_path / "labels.csv"
    assert main(["label", path, "--policy", policy, "--priors", pri, "-o", str(out)]) == 0
    got = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1].astype(int)  # toa,label
    assert np.mean(got == pulses()[1]) > 0.9


@pytest.mark.parametrize("cls", [EKFBank, EKFCoupled])
def test_sampled_banks_process_samples_bounded_by_the_pulses_seen(monkeypatch, cls):
    """By construction: whatever the TOAs, the samples the filters run through stay within
    MAX_SAMPLES_PER_PULSE per pulse seen (+ MAX_SAMPLES_EXTRA); the first pulse beyond is refused."""
    processed = []

    def count(self, k_stop, y):
        processed.append(k_stop - self._k)
        self._k = k_stop

    monkeypatch.setattr(cls, "_advance", count)
    rng = np.random.default_rng(1)
    gaps = np.exp(rng.uniform(0, np.log(5e3), 400))  # gaps of 1 to 5000 time units, sampling step 1.1
    toa = np.cumsum(gaps)
    policy = cls()
    priors = Priors(n_labels=3, period=np.array(PERIODS), phase=np.full(3, np.nan), period_std=np.ones(3),
                    phase_std=np.full(3, np.inf), source_prob=np.full(3, 1 / 3), jitter_std=SIGMA)
    policy.reset(priors, {"policy_seed": 0})
    labelled = 0
    with pytest.raises(NotApplicable, match="sampling steps"):
        for t in toa:
            policy.act({"toa": np.array([t])})
            labelled += 1
            assert sum(processed) <= ekf.MAX_SAMPLES_PER_PULSE * labelled + ekf.MAX_SAMPLES_EXTRA
    assert 0 < labelled < toa.size and math.ceil(toa[labelled] / policy.Ts) > (
        ekf.MAX_SAMPLES_PER_PULSE * (labelled + 1) + ekf.MAX_SAMPLES_EXTRA)


@pytest.mark.parametrize("spec, message", [
    ("cdif:x=-1", "x=-1 is invalid: a number in (0, 100]"),
    ("sdif:k=0", "k=0 is invalid: a number in (0, 100]"),
    ("sdif:x=2", "x=2 is invalid: a number in (0, 1]"),
    ("pri-transform:eps=-1", "eps=-1 is invalid: a number in (0, 1)"),
    ("pri-transform:gamma=1e300", "gamma=1e+300 is invalid"),
    ("cdif:max_miss=-1", "max_miss=-1 is invalid: an integer in [0, 1000]"),
    ("sdif:align=maybe", "align='maybe' is invalid: true or false"),
])
def test_blind_policy_parameters_out_of_range_are_one_line(capsys, spec, message):
    """Issue 26: the blind detectors' parameters are checked when the policy is built, not found out as a
    traceback (or an empty labelling) deep in a histogram."""
    code = main(["run", "--scenario", "blind-v0/blind-n3to3-jitter0.1", "--policy", spec, "--max-seeds", "1",
                 "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0] and spec in err[0]


@pytest.mark.parametrize("policy, limit", [("mht", 256), ("dokf", 256), ("pt-post", 256), ("agile-kf", 256),
                                           ("ekf-bank", 256), ("renewal-ml", 64)])
def test_more_prior_tracks_than_a_tracker_handles_is_not_applicable_at_once(tmp_path, capsys, policy, limit):
    """Issue 26: a priors file of 5,000 tracks ran mht (and renewal-ml, dokf, the EKF banks) for many minutes;
    the registry's track limit refuses it before the policy starts, with one line, through `deint label`."""
    toa, _ = pulses(200)
    n = limit + 1
    periods = list(np.linspace(100.0, 200.0, n))
    path, pri = tmp_path / "p.csv", tmp_path / "p.json"
    path.write_text("toa\n" + "".join(f"{float(t)!r}\n" for t in toa))
    pri.write_text(json.dumps({"period": periods, "jitter_std": SIGMA}))
    code = main(["label", str(path), "--priors", str(pri), "--policy", policy, "-o", str(tmp_path / "out.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f"policy '{policy}' handles at most {limit} tracks; this episode has {n} prior tracks" in err[0]
    assert not (tmp_path / "out.csv").exists()

"""Hostile inputs, round nine (docs/hostile-round9.md): pri-transform dividing by a zero PRI on coincident TOAs
(steps below float64's at 1e15), `deint dataset` on agile-v2 scenarios (their priors' modulations have no HDF5
type), blind renewal-ml and seq accepting records they label in minutes, tuned presets, test-look histories and
timings files tampered field by field, `evaluate` given a suite that is no string and `Priors.from_info` given
no mapping."""

from __future__ import annotations

import numpy as np
import pytest

import deint_env
from deint_env.cli import main
from deint_env.errors import DeintError


@pytest.fixture(autouse=True)
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


# ---- odd but legal pulse files ---------------------------------------------------------------------------
def test_pri_transform_skips_coincident_pulses(capsys):
    toa = (1e15 + 1e-3 * np.arange(300)).tolist()  # float64 steps of 0.125 there: runs of equal TOAs
    with open("x.csv", "w") as f:
        f.write("toa\n" + "".join(f"{t!r}\n" for t in toa))
    code = main(["label", "x.csv", "--policy", "pri-transform", "-o", "out.csv"])  # was ZeroDivisionError
    err = capsys.readouterr().err
    assert code == 0 and "labelled 300 pulses" in err, err


# ---- deint dataset ---------------------------------------------------------------------------------------
def test_a_dataset_of_an_agile_v2_scenario_records_its_modulations(capsys, monkeypatch):
    pytest.importorskip("minari")
    import minari

    code = main(["dataset", "deint/a2-v0", "--scenario", "agile-v2/agile2-dwells", "--seeds", "1", "--root", "ds"])
    assert code == 0, capsys.readouterr().err  # was TypeError: Object dtype dtype('O') has no native HDF5 equivalent
    monkeypatch.setenv("MINARI_DATASETS_PATH", "ds")
    episode = next(minari.load_dataset("deint/a2-v0").iterate_episodes())
    assert b'"dwell_switch"' in episode.infos["priors"]["modulation"][0]


# ---- the Python API --------------------------------------------------------------------------------------
def test_evaluate_refuses_a_suite_that_is_no_name():
    with pytest.raises(DeintError, match="suite=5 is invalid: a suite name"):
        deint_env.evaluate("random", suite=5, max_seeds=1, progress=False)  # was TypeError: not iterable


def test_priors_from_info_refuses_what_is_no_mapping():
    with pytest.raises(DeintError, match=r"priors: info=\[1\] is invalid: a mapping"):
        deint_env.Priors.from_info([1])  # was AttributeError: 'list' object has no attribute 'get'


# ---- blind policies at their stated sizes ----------------------------------------------------------------
@pytest.mark.parametrize("spec, limit", [("renewal-ml", 20_000), ("seq", 25_000)])
def test_a_blind_policy_refuses_a_record_it_cannot_label_within_a_minute(spec, limit):
    if spec == "seq":
        pytest.importorskip("torch")
    from deint_env.policies import make_policy

    policy = make_policy(spec)
    with pytest.raises(DeintError, match=f"at most {limit} pulses"):
        # 10^5 were allowed: blind renewal-ml took about 200 s of CPU, seq about 160 s
        policy.reset(deint_env.Priors(n_labels=3, blind=True), {"n_pulses": limit + 1})


# ---- tuned presets ---------------------------------------------------------------------------------------
@pytest.fixture
def preset(monkeypatch, tmp_path):
    """Writes a tampered copy of mht's core-v0 offline preset where `mht-tuned` reads it."""
    import json

    import baselines.tuned

    good = json.loads(baselines.tuned.preset_path("mht", "core-v0", "offline").read_text())
    monkeypatch.setattr(baselines.tuned, "PRESET_DIR", tmp_path / "presets")
    (tmp_path / "presets" / "mht").mkdir(parents=True)

    def write(**changes):
        (tmp_path / "presets" / "mht" / "core-v0.offline.json").write_text(json.dumps({**good, **changes}))
    return write


@pytest.mark.parametrize("changes, says", [
    ({"base_version": 10.0}, "was tuned for mht version 10.0, not the current 10"),  # was accepted
    ({"base_version": "10"}, "was tuned for mht version '10', not the current 10"),  # said "version 10, not ... 10"
    ({"params": [1]}, "its params [1] are not a JSON object"),  # said "its spec 'mht:beam=128' is not a mht spec"
    ({"suite": "paper-v0"}, "its suite 'paper-v0' is not 'core-v0', as its path says"),  # was accepted
    ({"division": "nope"}, "its division 'nope' is not 'offline', as its path says"),  # was accepted
])
def test_a_tampered_preset_is_refused_saying_which_field(preset, changes, says):
    from deint_env.policies import make_policy

    preset(**changes)
    with pytest.raises(DeintError, match="preset .*core-v0.offline.json") as e:
        make_policy("mht-tuned:suite=core-v0")
    assert says in str(e.value), str(e.value)


def test_a_preset_nested_too_deep_is_one_line(preset, tmp_path):
    from deint_env.policies import make_policy

    preset()
    (tmp_path / "presets" / "mht" / "core-v0.offline.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(DeintError, match=r"is unreadable \(RecursionError"):
        make_policy("mht-tuned:suite=core-v0")  # was RecursionError


# ---- board files -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("data, says", [
    ({"format": "deint-test-looks", "looks": [{"family": 5, "version": "1"}]}, "field looks[0].family is 5"),
    ({"format": "deint-test-looks", "looks": [{"family": "mht", "version": {}}]}, "field looks[0].version is {}"),
    ({"format": "nope", "looks": []}, "field format is 'nope', not 'deint-test-looks'"),
])
def test_a_tampered_test_look_history_is_refused_field_by_field(tmp_path, data, says):
    import json

    from deint_env.leaderboard import history

    (tmp_path / history.HISTORY).write_text(json.dumps(data))
    with pytest.raises(DeintError, match="history.json: field ") as e:
        history.read(tmp_path)  # was read as family '5', version '{}' and written back so
    assert says in str(e.value), str(e.value)


@pytest.mark.parametrize("change, says", [
    (lambda d: d["policies"]["fdp"].update(us_per_pulse="fast"), "field policies['fdp'].us_per_pulse is 'fast'"),
    (lambda d: d["policies"]["fdp"].update(us_per_pulse=-1), "field policies['fdp'].us_per_pulse is -1"),
    (lambda d: d["policies"]["fdp"].update(vs_fdp=float("nan")), "field policies['fdp'].vs_fdp is nan"),
    (lambda d: d["policies"]["fdp"].update(batch=0), "field policies['fdp'].batch is 0, not an integer >= 1"),
    (lambda d: d.update(reference=None), "field reference is None, not an object"),  # was TypeError
    (lambda d: d.update(suite="paper-v0"), "field suite is 'paper-v0', not 'core-v0' (its board's)"),
])
def test_a_tampered_timings_file_is_refused_field_by_field(tmp_path, change, says):
    import json
    from pathlib import Path

    from deint_env.leaderboard import timing

    data = json.loads((Path(__file__).parents[1] / "leaderboards" / "core-v0" / timing.TIMINGS).read_text())
    change(data)
    (tmp_path / timing.TIMINGS).write_text(json.dumps(data))
    with pytest.raises(DeintError, match="timings.json: field ") as e:
        timing.read(tmp_path, "core-v0")  # was accepted (shown on the page as is), or a TypeError on the page
    assert says in str(e.value), str(e.value)


# ---- fixed after the round -------------------------------------------------------------------------------
def test_pt_post_refuses_more_particles_than_a_minute_holds():
    from deint_env.policies import make_policy

    make_policy("pt-post:particles=256")
    with pytest.raises(DeintError, match="particles=1024"):
        make_policy("pt-post:particles=1024")  # was declared legal: 86 s of CPU for a 1000-pulse episode


def test_cdif_renewal_refuses_a_record_it_cannot_label_within_a_minute():
    from deint_env.policies import make_policy

    policy = make_policy("cdif-renewal")
    with pytest.raises(DeintError, match="at most 2000 pulses"):  # 10^5 pulses had not ended after 221 s of CPU
        policy.reset(deint_env.Priors(n_labels=3, blind=True), {"n_pulses": 2001})
    with pytest.raises(DeintError, match=r"window=7 is invalid: an integer in \[8, "):
        make_policy("cdif-renewal:window=7")  # no train of 8 pulses fits: every window failed after the read


def test_frame_seeding_finds_no_frame_among_coincident_pulses():
    from baselines.blind.frame_seed import frame_trains

    toa = np.repeat(np.arange(300.0), 2)  # equal-TOA pairs: the median spacing, hence the bin width, is 0
    assert frame_trains(toa, 0.0, 3) == []  # was ZeroDivisionError

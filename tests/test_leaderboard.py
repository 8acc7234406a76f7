"""Leaderboards: rliable statistics against ours, deterministic and resumable builds, submissions."""

from __future__ import annotations

import csv
import io
import json
import shutil

import numpy as np
import pytest

from deint_env import runner
from deint_env.cli import main
from deint_env import stats
from deint_env.leaderboard import Scope, build, default_policies, write
from deint_env.metrics import iqm, mean, stratified_bootstrap

SUITE = "core-v0"
SCENARIOS = ("core-n2-spread1.5-jitter0.05", "core-n3-spread4-jitter0.2")
SCOPE = Scope(SUITE, SCENARIOS, max_seeds=2)
POLICIES = ["genie", "random", "nearest-prior"]
REPS = 200  # bootstrap replicates: enough to test, fast
SCOPE_ARGS = ["--scenarios", ",".join(SCENARIOS), "--max-seeds", "2"]
TIMING = "us_per_pulse"
COMPARED = ("score_iqm", "score_iqm_low", "score_iqm_high", "score_mean", "score_mean_low", "score_mean_high",
            "accuracy", "matched_accuracy", "mean_pe", "v_measure", "ari", "coverage", "scored", "tags", "by_setting")


def _build_cli(root, *extra: str) -> int:
    return main(["leaderboard", "--suite", SUITE, "--policies", ",".join(POLICIES), "--workers", "1", "--root",
                 str(root), "--reps", str(REPS), "--no-progress", *SCOPE_ARGS, *extra])


def _files(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def board_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("lb")
    build(SCOPE, POLICIES, workers=1, root=root, progress=False, reps=REPS)
    return root


# ---------------------------------------------------------------------------------------------------
# statistics
# ---------------------------------------------------------------------------------------------------
def test_rliable_agrees_with_our_stratified_bootstrap():
    rng = np.random.default_rng(3)
    strata = {f"s{i}": rng.beta(2, 5, 10) for i in range(6)}
    strata["short"] = rng.beta(5, 2, 7)  # uneven strata take the same path
    state = np.random.get_state()[1].copy()
    est, profile = stats.estimates(strata, {"all": list(strata)}, np.linspace(0, 1, 11), reps=2000)
    assert np.array_equal(np.random.get_state()[1], state)  # the global generator is put back
    again, _ = stats.estimates(strata, {"all": list(strata)}, reps=2000)
    assert again == est  # seeded
    for name, fn in (("iqm", iqm), ("mean", mean)):
        point, lo, hi = stratified_bootstrap(list(strata.values()), fn, reps=2000)
        assert est["all"][name][0] == point
        assert abs(est["all"][name][1] - lo) < 0.02 and abs(est["all"][name][2] - hi) < 0.02
    assert profile[0][0] == 1.0 and np.all(profile[1] <= profile[0]) and np.all(profile[0] <= profile[2])


def test_fast_statistics_equal_rliables():
    library, metrics = stats.rliable()
    rng = np.random.default_rng(0)
    taus = np.linspace(-0.5, 1.5, 41)
    for n in (1, 2, 3, 4, 5, 7, 10, 33):
        for x in (rng.normal(size=n), rng.integers(0, 3, n) / 2):
            assert stats.trim_mean25(x) == metrics.aggregate_iqm(x)
            assert np.array_equal(stats.score_fractions(x, taus), library.score_distributions(x, taus))
            y = rng.integers(0, 3, n + 2) / 2
            assert stats.improvement_pairs(x, y) == metrics.probability_of_improvement(x[:, None], y[:, None])


def test_default_policies_are_the_reference_ones():
    names = default_policies()
    assert {"genie", "random", "nearest-prior", "fdp", "ppo"} <= set(names)
    assert "tdc" not in names  # needs a model named


# ---------------------------------------------------------------------------------------------------
# building: determinism and resuming
# ---------------------------------------------------------------------------------------------------
def _count_jobs(monkeypatch) -> list:
    calls = []
    real = runner.run_job

    def counting(job):
        calls.append(job.key)
        return real(job)

    monkeypatch.setattr(runner, "run_job", counting)
    return calls


def _without_timing(name: str, data: bytes):
    if name == "leaderboard.json":
        board = json.loads(data)
        for row in board["rows"]:
            row.pop(TIMING)
        return board
    if name == "leaderboard.csv":
        rows = list(csv.DictReader(io.StringIO(data.decode())))
        for r in rows:
            r.pop(TIMING)
        return rows
    if name == "results.jsonl":
        return [{k: v for k, v in json.loads(line).items() if k != TIMING} for line in data.decode().splitlines()]
    if name in ("README.md", "index.html"):  # their us/pulse cells differ; compared from the same results below
        return None
    return data


def test_rerun_is_identical_and_recomputes_nothing(tmp_path, monkeypatch):
    calls = _count_jobs(monkeypatch)
    assert _build_cli(tmp_path / "a") == 0
    assert len(calls) == len(POLICIES) * len(SCENARIOS) * 2
    first = _files(tmp_path / "a" / SUITE)
    assert {"results.jsonl", "leaderboard.json", "leaderboard.csv", "README.md", "index.html", "history.json",
            "profiles.png", "pareto.png", "score_vs_n_sources.png", "score_vs_jitter_rel.png"} <= set(first)
    assert "intervals.png" not in first  # 2 seeds per scenario: no intervals (fewer than 3)
    calls.clear()
    assert _build_cli(tmp_path / "a") == 0
    assert calls == []
    assert _files(tmp_path / "a" / SUITE) == first  # byte for byte, timing included (nothing was rerun)

    # From scratch: only the measured timing differs.
    assert _build_cli(tmp_path / "b") == 0
    fresh = _files(tmp_path / "b" / SUITE)
    assert fresh.keys() == first.keys()
    for name in first:
        assert _without_timing(name, fresh[name]) == _without_timing(name, first[name]), name
    # The same results give the same files, README and HTML included.
    (tmp_path / "c" / SUITE).mkdir(parents=True)
    shutil.copy(tmp_path / "a" / SUITE / "results.jsonl", tmp_path / "c" / SUITE)
    write(tmp_path / "c" / SUITE, SCOPE, reps=REPS)
    assert _files(tmp_path / "c" / SUITE) == first


def test_interrupted_run_resumes_without_replaying(tmp_path, monkeypatch):
    folder = tmp_path / SUITE
    build(SCOPE, POLICIES, workers=1, root=tmp_path, progress=False, reps=REPS)
    lines = (folder / "results.jsonl").read_text().splitlines(keepends=True)
    kept = lines[:5]
    (folder / "results.jsonl").write_text("".join(kept) + lines[5][:40])  # killed mid-write
    calls = _count_jobs(monkeypatch)
    build(SCOPE, POLICIES, workers=1, root=tmp_path, progress=False, reps=REPS)
    assert len(calls) == len(lines) - len(kept)
    after = (folder / "results.jsonl").read_text().splitlines(keepends=True)
    assert len(after) == len(lines) and set(kept) <= set(after)  # finished episodes untouched


def test_incomplete_policy_is_left_out(tmp_path):
    build(SCOPE, POLICIES, workers=1, root=tmp_path, progress=False, reps=REPS)
    path = tmp_path / SUITE / "results.jsonl"
    recs = [json.loads(line) for line in path.read_text().splitlines()]
    drop = next(r for r in recs if r["policy"] == "random")
    path.write_text("".join(json.dumps(r) + "\n" for r in recs if r is not drop))
    board = write(tmp_path / SUITE, SCOPE, reps=REPS)
    assert [r["policy"] for r in board["rows"]] == ["genie", "nearest-prior"]
    assert board["incomplete"] == {"random": 3}


# ---------------------------------------------------------------------------------------------------
# submissions
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("policy,suffix", [("random", ".jsonl"), ("nearest-prior", ".npz")])
def test_exported_labels_score_as_the_policy(board_root, tmp_path, policy, suffix):
    root = tmp_path / "root"
    shutil.copytree(board_root, root)
    sub = tmp_path / f"sub{suffix}"
    assert main(["leaderboard", "export", "--suite", SUITE, "--policy", policy, "-o", str(sub), "--no-progress",
                 *SCOPE_ARGS]) == 0
    assert main(["leaderboard", "submit", str(sub), "--suite", SUITE, "--name", "mine", "--root", str(root),
                 "--reps", str(REPS), "--no-progress"]) == 0
    rows = {r["policy"]: r for r in json.loads((root / SUITE / "leaderboard.json").read_text())["rows"]}
    ours, theirs = rows["mine (submitted)"], rows[policy]
    assert ours["kind"] == "submitted" and ours[TIMING] is None
    for key in COMPARED:
        assert ours[key] == theirs[key], key
    assert "mine (submitted)" in (root / SUITE / "README.md").read_text()
    # A second submission under the same name replaces the first.
    assert main(["leaderboard", "submit", str(sub), "--suite", SUITE, "--name", "mine", "--root", str(root),
                 "--reps", str(REPS), "--no-progress"]) == 0
    recs = [json.loads(line) for line in (root / SUITE / "results.jsonl").read_text().splitlines()]
    assert sum(r["policy"] == "mine (submitted)" for r in recs) == len(SCENARIOS) * 2


def _lines(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _dump(objs) -> str:
    return "".join(json.dumps(o) + "\n" for o in objs)


def _bad_files(good: list[dict]) -> dict[str, tuple[str, str]]:
    """name -> (file text, what the error line must contain)."""
    head, eps = good[0], good[1:]
    text = _dump(good)
    last = text.rstrip("\n").rsplit("\n", 1)[1]
    ep1 = eps[1]
    nan = dict(ep1, labels=ep1["labels"][:3] + [float("nan")] + ep1["labels"][4:])
    out_of_range = dict(ep1, labels=[0, 7] + ep1["labels"][2:])
    short = dict(ep1, labels=ep1["labels"][:-1])
    extra = dict(ep1, seed=ep1["seed"] + 5)
    name = lambda e: f"scenario {e['scenario']}, seed {e['seed']}"  # noqa: E731
    return {
        "truncated": (text[: len(text) - len(last) // 2 - 1], name(eps[-1])),
        "nan": (_dump([head, eps[0], nan] + eps[2:]), name(ep1)),
        "out_of_range": (_dump([head, eps[0], out_of_range] + eps[2:]), name(ep1)),
        "missing": (_dump([head] + eps[:1] + eps[2:]), name(ep1)),
        "duplicate": (_dump(good + [ep1]), name(ep1)),
        "extra": (_dump(good + [extra]), name(extra)),
        "wrong_count": (_dump([head, eps[0], short] + eps[2:]), name(ep1)),
        "bad_json": (_dump([head, eps[0]]) + json.dumps(ep1)[:-1] + ",}\n" + _dump(eps[2:]), name(ep1)),
        "other_suite": (_dump([dict(head, suite="robust-v0")] + eps), "robust-v0"),
    }


@pytest.fixture(scope="module")
def good_submission(board_root, tmp_path_factory):
    path = tmp_path_factory.mktemp("sub") / "good.jsonl"
    assert main(["leaderboard", "export", "--suite", SUITE, "--policy", "nearest-prior", "-o", str(path),
                 "--no-progress", *SCOPE_ARGS]) == 0
    return _lines(path)


@pytest.mark.parametrize("case", ["truncated", "nan", "out_of_range", "missing", "duplicate", "extra", "wrong_count",
                                  "bad_json", "other_suite"])
def test_bad_submission_is_refused_and_changes_nothing(board_root, good_submission, tmp_path, capsys, case):
    text, named = _bad_files(good_submission)[case]
    path = tmp_path / "bad.jsonl"
    path.write_text(text)
    before = _files(board_root / SUITE)
    capsys.readouterr()
    code = main(["leaderboard", "submit", str(path), "--suite", SUITE, "--name", "bad", "--root", str(board_root),
                 "--reps", str(REPS), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("deint: error: ") and named in err, err
    assert _files(board_root / SUITE) == before


def test_bad_npz_submissions_are_refused(board_root, tmp_path, capsys):
    good = tmp_path / "good.npz"
    assert main(["leaderboard", "export", "--suite", SUITE, "--policy", "random", "-o", str(good), "--no-progress",
                 *SCOPE_ARGS]) == 0
    with np.load(good) as z:
        arrays = dict(z)
    key = f"{SCENARIOS[0]}/1000001"
    floats = arrays[key].astype(float)
    np.savez(tmp_path / "floats.npz", **{**arrays, key: floats})
    floats[2] = np.nan
    np.savez(tmp_path / "nan.npz", **{**arrays, key: floats})
    (tmp_path / "torn.npz").write_bytes(good.read_bytes()[:-100])
    before = _files(board_root / SUITE)
    for name, named in (("nan.npz", "seed 1000001): label at pulse 2 is NaN"), ("floats.npz", "dtype float64"),
                        ("torn.npz", "truncated")):
        capsys.readouterr()
        assert main(["leaderboard", "submit", str(tmp_path / name), "--suite", SUITE, "--name", "x", "--root",
                     str(board_root), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and named in err, err
    assert _files(board_root / SUITE) == before


def test_submission_needs_a_valid_name(board_root, tmp_path, good_submission, capsys):
    path = tmp_path / "anon.jsonl"
    path.write_text(_dump(good_submission[1:]))
    assert main(["leaderboard", "submit", str(path), "--suite", SUITE, "--root", str(board_root)]) == 2
    assert "--name" in capsys.readouterr().err
    assert main(["leaderboard", "submit", str(path), "--suite", SUITE, "--name", "<b>", "--root",
                 str(board_root)]) == 2


def test_published_suites_are_the_folders_holding_a_leaderboard(tmp_path):
    from deint_env.leaderboard import published_suites

    (tmp_path / "core-v0").mkdir()
    (tmp_path / "core-v0" / "leaderboard.json").write_text("{}")
    (tmp_path / "robust-v0").mkdir()  # a folder without a built leaderboard is not published
    (tmp_path / "no-such-suite").mkdir()
    (tmp_path / "no-such-suite" / "leaderboard.json").write_text("{}")
    assert published_suites(tmp_path) == ["core-v0"]
    assert set(published_suites("leaderboards")) >= {"paper-v0", "core-v0", "robust-v0", "agile-v0"}


def test_all_rebuilds_each_board_with_its_own_policies_and_scope(tmp_path, monkeypatch):
    """`deint leaderboard --all` plays on each board exactly the specs its leaderboard.json records
    (parameters included; incomplete ones too; submissions are not played) at the board's own scope."""
    import importlib

    build_module = importlib.import_module("deint_env.leaderboard.build")  # the module, not the function
    core = Scope(SUITE, SCENARIOS[:1], max_seeds=2)
    paper = Scope("paper-v0", ("mk94-single-var9",), max_seeds=1)
    build(core, ["random", "fdp:lookahead=2"], workers=1, root=tmp_path, progress=False, reps=REPS)
    build(paper, ["nearest-prior"], workers=1, root=tmp_path, progress=False, reps=REPS)
    sub = tmp_path / "sub.jsonl"
    scope_args = ["--scenarios", SCENARIOS[0], "--max-seeds", "2"]
    assert main(["leaderboard", "export", "--suite", SUITE, "--policy", "nearest-prior", "-o", str(sub),
                 "--no-progress", *scope_args]) == 0
    assert main(["leaderboard", "submit", str(sub), "--suite", SUITE, "--name", "mine", "--root", str(tmp_path),
                 "--reps", str(REPS), "--no-progress"]) == 0
    path = tmp_path / SUITE / "results.jsonl"  # an interrupted run: random lacks one episode
    recs = [json.loads(line) for line in path.read_text().splitlines()]
    drop = next(r for r in recs if r["policy"] == "random")
    path.write_text("".join(json.dumps(r) + "\n" for r in recs if r is not drop))
    assert write(tmp_path / SUITE, core, reps=REPS)["incomplete"] == {"random": 1}

    played, real = [], build_module.evaluate
    monkeypatch.setattr(build_module, "evaluate", lambda policies, target, **kw: (
        played.append((sorted(policies), target, kw["max_seeds"])), real(policies, target, **kw))[1])
    jobs = _count_jobs(monkeypatch)
    assert main(["leaderboard", "--all", "--root", str(tmp_path), "--workers", "1", "--reps", str(REPS),
                 "--no-progress"]) == 0
    assert played == [(["fdp:lookahead=2", "random"], f"{SUITE}/{SCENARIOS[0]}", 2),
                      (["nearest-prior"], "paper-v0/mk94-single-var9", 1)]
    assert len(jobs) == 1  # only random's missing episode
    board = json.loads((tmp_path / SUITE / "leaderboard.json").read_text())
    assert sorted(r["policy"] for r in board["rows"]) == ["fdp:lookahead=2", "mine (submitted)", "random"]
    assert board["incomplete"] == {} and board["scope"] == {"scenarios": [SCENARIOS[0]], "max_seeds": 2}

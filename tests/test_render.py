"""The views: the env's ΔTOA-against-TOA frame (checked by pixel statistics), human mode, `deint plot`
and the leaderboard's example-episode pictures."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from deint_env.cli import main
from deint_env.envs import DeinterleaveEnv
from deint_env.envs.render import FRAME, GRID, PALETTE, draw, png, render_rgb
from deint_env.errors import DeintError
from deint_env import formats
from deint_env.scenario import ScenarioSpec, SourceSpec
from deint_env.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def two_sources(turns: bool, n: int = 160) -> ScenarioSpec:
    """Periods 1 and 10 (each on a decade grid line), on in turn (`turns`: every pulse's ΔTOA is its own
    source's period) or together (interleaved)."""
    windows = (((0.0, 0.5),), ((0.5, 1.0),)) if turns else ((), ())
    return ScenarioSpec(name="two-periods", n_pulses=n, toa_jitter_std=0.005,
                        sources=tuple(SourceSpec(period=p, active=w) for p, w in zip((1.0, 10.0), windows)))


def play(env: DeinterleaveEnv, seed: int, steps: int | None = None, actions=None) -> np.ndarray:
    """Step `env` (true labels unless `actions`) and return its frame."""
    env.reset(seed=seed)
    ep = env.episode
    truth = np.where(ep.source >= 0, ep.source, env.n_labels) if actions is None else actions
    for k in range(len(ep) + env.lag if steps is None else steps):
        env.step(int(truth[max(k - env.lag, 0)]))
    return env.render()


def panels(img: np.ndarray) -> list[tuple[int, int]]:
    """The (left, right) inner columns of each framed panel: frame columns are FRAME grey on most rows."""
    edges = np.flatnonzero((img[:, :, 0] == FRAME).mean(0) > 0.9)
    return [(int(a) + 1, int(b)) for a, b in zip(edges[::2], edges[1::2])]


def decade_rows(img: np.ndarray, cols: tuple[int, int]) -> list[int]:
    """The rows of a panel's decade grid lines (only they are GRID grey; dots may hide most of one), top first."""
    return [int(r) for r in np.flatnonzero((img[:, cols[0]:cols[1], 0] == GRID).any(1))]


def rows_of(img: np.ndarray, cols: tuple[int, int], colour: np.ndarray) -> np.ndarray:
    return np.nonzero((img[:, cols[0]:cols[1]] == colour).all(2))[0]


def test_truth_panel_draws_each_source_in_a_narrow_band_at_its_period():
    env = DeinterleaveEnv(two_sources(turns=True), render_mode="rgb_array")
    img = play(env, seed=0)
    assert img.shape == (480, 720, 3) and img.dtype == np.uint8
    labels, truth, hist = panels(img)
    ten, one = decade_rows(img, truth)  # ΔTOA 10 above ΔTOA 1: the y axis grows upwards
    assert one - ten > 100  # a decade spans a good part of the panel
    for source, row in ((0, one), (1, ten)):
        rows = rows_of(img, truth, PALETTE[source])
        assert rows.size > 100
        lo, hi = np.percentile(rows, [5, 95])
        assert hi - lo <= 10, (source, lo, hi)  # narrow: 3 px dots, ΔTOA jitter ~1 px; a decade is > 100 px
        assert abs(np.median(rows) - row) <= 3, (source, np.median(rows), row)
    # the agent's labels are the truth here: the label panel draws the same picture
    assert np.array_equal(img[:, labels[0]:labels[1]], img[:, truth[0]:truth[1]])


def test_histogram_shows_each_labelled_trains_pri_as_a_spike():
    """Interleaved, the slow source's ΔTOAs spread below its period; its intervals between pulses of
    the same label still peak at the period's row."""
    env = DeinterleaveEnv(two_sources(turns=False, n=400), render_mode="rgb_array")
    img = play(env, seed=1)
    _, truth, hist = panels(img)
    ten, one = decade_rows(img, hist)[:2]  # the top two decades: the ΔTOAs reach further down
    spread = np.percentile(rows_of(img, truth, PALETTE[1]), [5, 95])
    assert spread[1] - spread[0] > 40  # the slow source's dots are not a band at its period
    for source, row in ((0, one), (1, ten)):
        rows = rows_of(img, hist, PALETTE[source])
        assert abs(np.bincount(rows).argmax() - row) <= 3, source


def test_a_pending_pulses_truth_is_never_drawn():
    spec = two_sources(turns=False, n=60)
    env = DeinterleaveEnv(spec, lag=4, render_mode="rgb_array")
    empty = render_rgb(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int32), env.n_labels)
    env.reset(seed=2)
    for _ in range(4):  # the first lag steps label nothing: nothing is drawn
        env.step(0)
        assert np.array_equal(env.render(), empty)
    for _ in range(20):
        env.step(1)
    before = env.render()
    done = 20
    env.episode.source[done:] = 1 - env.episode.source[done:]  # other truth for every pending pulse
    assert np.array_equal(env.render(), before)
    assert np.array_equal(before, render_rgb(env.episode.toa[:done], env.labels[:done], env.episode.source[:done],
                                             env.n_labels))
    env.episode.source[done - 1] = 1 - env.episode.source[done - 1]  # a labelled pulse's truth is drawn
    assert not np.array_equal(env.render(), before)


def test_human_mode_runs_headless_with_agg(tmp_path):
    code = """
import matplotlib.pyplot as plt, numpy as np
import gymnasium as gym
import deint_env
from deint_env.envs.render import render_rgb
env = gym.make("deint_env/Deinterleave-v0", scenario="core-v0/core-n2-spread4-jitter0.05", render_mode="human")
env.reset(seed=0)
for _ in range(8):
    env.step(0)
assert env.render() is None
inner = env.unwrapped
(fig,) = [plt.figure(n) for n in plt.get_fignums()]
shown = fig.axes[0].get_images()[0].get_array()
ep = inner.episode
assert np.array_equal(shown, render_rgb(ep.toa[:8], inner.labels[:8], ep.source[:8], inner.n_labels))
env.close()
assert plt.get_fignums() == []
print("human ok")
"""
    out = subprocess.run([sys.executable, "-W", "error::UserWarning", "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, env={**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT)}, timeout=120)
    assert out.returncode == 0 and "human ok" in out.stdout, out.stderr[-2000:]


def test_human_mode_without_matplotlib_is_one_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    with pytest.raises(DeintError, match=r"pip install 'deint-bench\[plot\]'"):
        DeinterleaveEnv(render_mode="human")


def test_png_round_trips():
    ep = simulate(two_sources(turns=False), 3)
    img = draw(ep.toa, [(ep.source, ep.source < 0)], 480, 300)
    data = png(img)
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) < 20_000  # indexed colour: small
    back = matplotlib.image.imread(io.BytesIO(data))
    assert np.array_equal(np.round(back[..., :3] * 255).astype(np.uint8), img)
    noise = np.random.default_rng(0).integers(0, 256, (7, 9, 3), dtype=np.uint8)  # > 256 colours: RGB
    assert np.array_equal(np.round(matplotlib.image.imread(io.BytesIO(png(noise)))[..., :3] * 255), noise)


# ---- deint plot ------------------------------------------------------------------------------------
@pytest.fixture
def pulse_files(tmp_path):
    ep = simulate(two_sources(turns=False, n=300), 4)
    pulses, labels = tmp_path / "p.csv", tmp_path / "l.csv"
    formats.write_pulses(pulses, ep)
    formats.write_labels(labels, ep.toa, np.where(ep.source >= 0, ep.source, ep.n_labels), ep.n_labels)
    return pulses, labels


def _png_size(path: Path) -> tuple[int, int]:
    img = matplotlib.image.imread(path)
    return img.shape[1], img.shape[0]


def test_plot_writes_a_png_per_colouring(pulse_files, tmp_path, capsys):
    pulses, labels = pulse_files
    assert main(["plot", str(pulses), "--labels", str(labels), "-o", str(tmp_path / "both.png")]) == 0
    assert main(["plot", str(pulses), "-o", str(tmp_path / "truth.png"), "--first", "100"]) == 0
    assert "100 pulses coloured by sources" in capsys.readouterr().err
    assert (tmp_path / "both.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    both, truth = _png_size(tmp_path / "both.png"), _png_size(tmp_path / "truth.png")
    assert both[1] == truth[1] == 500 and both[0] == truth[0] + 400  # one more 4-inch panel


@pytest.mark.parametrize("case", ["missing", "same-as-input", "not-png", "symlink", "short-first"])
def test_plot_refuses_bad_input_with_one_line(pulse_files, tmp_path, capsys, case):
    pulses, labels = pulse_files
    out = tmp_path / "out.png"
    args = {"missing": [str(tmp_path / "none.csv"), "-o", str(out)],
            "same-as-input": [str(pulses), "-o", str(pulses)],
            "not-png": [str(pulses), "-o", str(tmp_path / "out.pdf")],
            "symlink": [str(pulses), "-o", str(out)],
            "short-first": [str(pulses), "-o", str(out), "--first", "1"]}[case]
    if case == "symlink":
        out.symlink_to(tmp_path / "elsewhere.png")
    before = pulses.read_bytes()
    capsys.readouterr()
    assert main(["plot", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("deint: error: ") and err.count("\n") == 1, err
    assert pulses.read_bytes() == before and not (tmp_path / "elsewhere.png").exists()
    assert case == "symlink" or not out.exists()
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind


def test_plot_without_matplotlib_names_the_extra(pulse_files, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    assert main(["plot", str(pulse_files[0]), "-o", str(tmp_path / "x.png")]) == 2
    assert "pip install 'deint-bench[plot]'" in capsys.readouterr().err


# ---- the leaderboard's example episodes ------------------------------------------------------------
def test_board_writes_and_links_an_example_episode_per_scenario(tmp_path):
    from deint_env.leaderboard import Scope, write
    from deint_env.suites import load_suite

    names = ("core-n2-spread1.5-jitter0.05", "core-n3-spread4-jitter0.2")
    folder = tmp_path / "core-v0"
    folder.mkdir()
    board = write(folder, Scope("core-v0", names, max_seeds=1), records=[], reps=10)
    first = {p.name: p.read_bytes() for p in folder.iterdir()}
    html, readme = first["index.html"].decode(), first["README.md"].decode()
    for name, row in zip(names, board["examples"]):
        entry = load_suite("core-v0").entry(name)
        picture = f"episode-{name}.png"
        assert row["scenario"] == name and row["seed"] == entry.seeds("validation")[0] and row["picture"] == picture
        assert f'<a href="{picture}">{name}</a>' in html and f"[{name}]({picture})" in readme
        img = matplotlib.image.imread(folder / picture)
        assert img.shape[:2] == (300, 480) and len(first[picture]) < 20_000
        ep = simulate(entry.spec, row["seed"])
        assert first[picture] == png(draw(ep.toa[:1000], [(ep.source[:1000], ep.source[:1000] < 0)], 480, 300))
    # rebuilt: the same bytes; a scenario left out of the scope loses its picture
    write(folder, Scope("core-v0", names, max_seeds=1), records=[], reps=10)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == first
    write(folder, Scope("core-v0", names[:1], max_seeds=1), records=[], reps=10)
    assert not (folder / f"episode-{names[1]}.png").exists() and (folder / f"episode-{names[0]}.png").exists()

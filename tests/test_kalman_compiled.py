"""The compiled Kalman step of baselines/kalman_jit.py (`kf_predict`, `kf_predict_steps`, `kf_update`,
`kf_update_div`, `drift_terms`), which the compiled trackers inline, against the numpy form (`predict`,
`update`: bit for bit where the operations are the same), against filterpy's KalmanFilter, and against
its interpreted self; and `baselines.jit_cache.guard`, which keeps numba's disk cache of a kernel module
in step with the files it compiles in."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from baselines import kalman_jit
from baselines.jit_cache import dependencies, kernels
from baselines.kalman import Block, DLMModel, predict, update
from baselines.kalman_jit import drift_terms, kf_predict, kf_predict_steps, kf_update, kf_update_div

filterpy = pytest.importorskip("filterpy.kalman")


def _blocks(seed: int, n: int = 64) -> Block:
    """Random filtered blocks: positive-definite 2x2 covariances of varied scale and correlation."""
    rng = np.random.default_rng(seed)
    ptt = rng.uniform(1e-6, 4.0, n)
    pxx = rng.uniform(1e-4, 1e4, n)
    ptx = rng.uniform(-0.99, 0.99, n) * np.sqrt(ptt * pxx)
    return Block(rng.uniform(5.0, 200.0, n), rng.uniform(0.0, 1e4, n), ptt, ptx, pxx)


MODELS = [DLMModel(jitter_var=0.04), DLMModel(jitter_var=0.3, alpha=0.999, drift_var=0.01, interval_var=0.04),
          DLMModel(jitter_var=1e-6, drift_var=0.5, interval_var=2.0)]


@pytest.mark.parametrize("model", MODELS)
def test_compiled_step_is_the_numpy_step_bit_for_bit(model):
    b = _blocks(1)
    y = b.tau + b.period + np.random.default_rng(2).normal(0.0, 1.0, b.period.size)
    pred = predict(b, model)
    e, s = y - pred.tau, pred.p_xx + model.jitter_var
    want_pred, want = np.stack(list(pred)), np.stack(list(update(pred, e, s, model)))
    for f in (kf_predict, kf_predict.py_func):
        got = np.array([f(*(a[j] for a in b), model.alpha, model.drift_var, model.interval_var)
                        for j in range(b.period.size)]).T
        assert np.array_equal(got, want_pred)
    for f in (kf_update, kf_update.py_func):
        got = np.array([f(*(a[j] for a in pred), e[j], s[j], model.jitter_var) for j in range(e.size)]).T
        assert np.array_equal(got, want)
    # the division form: the same filter within rounding
    got = np.array([kf_update_div(*(a[j] for a in pred), e[j], s[j], model.jitter_var) for j in range(e.size)]).T
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("m", [1.0, 2.0, 5.0])
def test_m_step_prediction_is_m_numpy_predictions(m):
    """`kf_predict_steps` (closed form, alpha = 1, no drift) equals `predict` applied m times; with a
    drifting period the caller adds `drift_terms`, which equal the random walk's (2.8) m times."""
    b = _blocks(3)
    for drift in (0.0, 0.002):
        model = DLMModel(jitter_var=0.04, interval_var=0.01)
        # predict's random walk in the closed form's convention: q = (drift T)^2 of the filtered T
        q = (drift * b.period) ** 2
        p = b
        for _ in range(int(m)):
            p = predict(p, DLMModel(jitter_var=0.04, interval_var=0.01))
            p = Block(p.period, p.tau, p.p_tt + q, p.p_tx, p.p_xx)
        got = np.array([kf_predict_steps(*(a[j] for a in b), m, model.interval_var) for j in range(b.period.size)]).T
        d = np.array([drift_terms(drift, b.period[j], m) for j in range(b.period.size)]).T
        np.testing.assert_allclose(got[0], p.tau, rtol=1e-13)
        np.testing.assert_allclose(got[1] + d[1], p.p_tx, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got[2] + d[0], p.p_xx, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(b.p_tt + d[2], p.p_tt, rtol=1e-9, atol=1e-12)
        if drift == 0.0:
            assert not np.any(d)  # adding the terms changes no bit


@pytest.mark.parametrize("model", MODELS)
def test_compiled_step_is_filterpys(model):
    """filterpy's KalmanFilter on x = (T, tau), F = [[alpha, 0], [1, 1]] (2.8), H = [0, 1], Q = diag(q_T,
    q_tau) after the arrival's tau' = tau + T: one predict and one update, block by block."""
    b = _blocks(4, 16)
    y = b.tau + b.period + np.random.default_rng(5).normal(0.0, 1.0, b.period.size)
    for j in range(b.period.size):
        kf = filterpy.KalmanFilter(dim_x=2, dim_z=1)
        kf.x = np.array([b.period[j], b.tau[j]])
        kf.P = np.array([[b.p_tt[j], b.p_tx[j]], [b.p_tx[j], b.p_xx[j]]])
        kf.F = np.array([[model.alpha, 0.0], [1.0, 1.0]])
        kf.Q = np.diag([model.drift_var, model.interval_var])
        kf.H = np.array([[0.0, 1.0]])
        kf.R = np.array([[model.jitter_var]])
        kf.predict()
        t, tau, ptt, ptx, pxx = kf_predict(*(a[j] for a in b), model.alpha, model.drift_var, model.interval_var)
        np.testing.assert_allclose([t, tau, ptt, ptx, pxx], [*kf.x, kf.P[0, 0], kf.P[0, 1], kf.P[1, 1]], rtol=1e-12)
        kf.update(np.array([y[j]]))
        for f in (kf_update, kf_update_div):
            got = f(t, tau, ptt, ptx, pxx, y[j] - tau, pxx + model.jitter_var, model.jitter_var)
            # filterpy's Joseph form loses digits where P >> R: compare to the covariance's own scale
            np.testing.assert_allclose(got[:2], kf.x, rtol=1e-10)
            np.testing.assert_allclose(got[2:], [kf.P[0, 0], kf.P[0, 1], kf.P[1, 1]], rtol=1e-7,
                                       atol=1e-9 * (ptt + abs(ptx) + pxx))


def test_every_compiled_kalman_function_is_tested():
    assert {k.__name__ for k in kernels(vars(kalman_jit))} == {"kf_predict", "kf_predict_steps", "kf_update",
                                                          "kf_update_div", "drift_terms"}


def test_the_covariance_update_is_written_once_per_form():
    """P_TT' = P_TT - P_Tx^2 / S, the update's signature term, is written in kalman.py (numpy) and
    kalman_jit.py (compiled) only: every tracker calls one of them (issue 24)."""
    import re

    root = Path(__file__).resolve().parents[1]
    term = re.compile(r"\bp_?tx\s*\*\s*(?:\w+\.)?p_?tx\b", re.IGNORECASE)
    files = sorted((root / "baselines").rglob("*.py")) + sorted((root / "agents").rglob("*.py"))
    where = {str(f.relative_to(root)) for f in files if term.search(f.read_text())}
    assert where == {"baselines/kalman.py", "baselines/kalman_jit.py"}


def test_a_kernel_modules_dependencies_are_the_project_files_it_imports_from():
    import baselines.mht.kernels as k

    names = {p.relative_to(p.parents[1]).as_posix() for p in dependencies(k.__name__, Path(k.__file__))}
    assert {"baselines/kalman_jit.py", "baselines/survivor.py", "mht/scorer.py", "mht/start.py", "mht/state.py"} <= names


GUARDED = """
from numba import njit
from baselines.jit_cache import guard
from dep import helper


@njit(cache=True)
def kernel(x):
    return helper(x)


guard(globals())
print(kernel(1.0))
"""


def test_guard_recompiles_a_cached_kernel_when_a_file_it_compiles_in_changes(tmp_path):
    """numba alone would load `kernel` from its cache (its own file unchanged) with the old helper inlined."""
    (tmp_path / "main.py").write_text(textwrap.dedent(GUARDED))
    dep = tmp_path / "dep.py"

    def run(value: float) -> str:
        dep.write_text(f"from numba import njit\n\n\n@njit(inline='always')\ndef helper(x):\n    return x + {value}\n")
        out = subprocess.run([sys.executable, "main.py"], cwd=tmp_path, capture_output=True, text=True, check=True)
        return out.stdout.strip()

    assert run(1.0) == "2.0"
    assert list((tmp_path / "__pycache__").glob("main.kernel-*.nbi"))  # really cached
    assert run(1.0) == "2.0"
    assert run(5.0) == "6.0"


def test_guard_parses_no_source_while_nothing_changed(tmp_path):
    """Finding the dependencies parses sources (start-up time): a run whose module and dependencies are
    those the stamp recorded only hashes them; a changed dependency is parsed for again."""
    (tmp_path / "main.py").write_text(textwrap.dedent(GUARDED))
    dep = tmp_path / "dep.py"
    no_parsing = ("import baselines.jit_cache as jit_cache\n"
                  "def refused(*args):\n"
                  "    raise SystemExit('parsed')\n"
                  "jit_cache._imported = refused\n"
                  "import main\n")

    def run(value: float, code: str | None = None) -> subprocess.CompletedProcess:
        dep.write_text(f"from numba import njit\n\n\n@njit(inline='always')\ndef helper(x):\n    return x + {value}\n")
        return subprocess.run([sys.executable] + (["-c", code] if code else ["main.py"]), cwd=tmp_path,
                              capture_output=True, text=True)

    assert run(1.0).stdout.strip() == "2.0"  # writes the stamp
    unchanged = run(1.0, no_parsing)
    assert unchanged.returncode == 0 and unchanged.stdout.strip() == "2.0", unchanged.stderr[-500:]
    assert run(5.0, no_parsing).stderr.strip().endswith("parsed")
    assert run(5.0).stdout.strip() == "6.0"

"""The package structure (issue 8): every module imports in a fresh interpreter, `deint_env` imports
nothing from `baselines` or `agents` (the command line on top of all three aside), and the import
graph has no cycle."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("deint_env", "baselines", "agents")
ON_TOP = {"deint_env.cli", "deint_env.cli_import"}  # the command line sits on top of all three packages


def modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project modules `name` imports anywhere in its text (lazy imports in functions included)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        out |= {t for t in targets if t in known and t != name}
    return out


def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def test_deint_env_imports_no_baselines_or_agents():
    bad = {(a, b) for a, targets in graph().items() if a.split(".")[0] == "deint_env" and a not in ON_TOP
           for b in targets if b.split(".")[0] in ("baselines", "agents")}
    assert not bad, sorted(bad)


def test_no_import_cycle():
    g = graph()
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    cycles = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(g[node]):
            if state.get(nxt) == 1:
                cycles.append(path[path.index(nxt):] + [nxt] if nxt in path else [node, nxt])
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for node in sorted(g):
        if node not in state:
            visit(node, [node])
    assert not cycles, [" -> ".join(c) for c in cycles]


def test_the_graph_sees_imports():
    """The checks above can fail: the graph finds known edges, lazy ones included."""
    g = graph()
    assert "deint_env.receiver" in g["deint_env.simulate"] and "deint_env.oracle" in g["deint_env.runner"]
    assert "deint_env.oracle" in g["baselines.genie"] and "baselines.kalman" in g["baselines.fdp"]


def test_every_module_imports_in_a_fresh_interpreter():
    names = sorted(modules())
    code = ("import importlib, sys\n"
            f"for name in {names!r}:\n"
            "    importlib.import_module(name)\n"
            "print(len(sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]


# Libraries a command must not import unless it uses them: each costs a fresh `deint` process from 0.3 s
# (numba) to seconds (scipy.signal, scikit-learn, torch) before any work (issue 22; times in
# benchmarks/bench_startup.py, never asserted here).
HEAVY = ("numba", "scipy", "sklearn", "torch")


def loaded_after(code: str, tmp_path: Path) -> set[str]:
    """The modules a fresh interpreter holds after running `code` in the source tree (cwd tmp_path)."""
    script = f"import sys, json\n{code}\nprint('MODULES=' + json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-2000:]
    line = next(x for x in out.stdout.splitlines() if x.startswith("MODULES="))
    return set(json.loads(line.removeprefix("MODULES=")))


def heavy(mods: set[str]) -> list[str]:
    return sorted({m.split(".")[0] for m in mods} & set(HEAVY))


def test_import_deint_env_registers_the_envs_and_imports_no_heavy_library(tmp_path):
    mods = loaded_after("import deint_env, gymnasium\nassert 'deint_env/Deinterleave-v0' in gymnasium.registry",
                        tmp_path)
    assert "deint_env" in mods and not heavy(mods), heavy(mods)


def test_deint_help_imports_no_policy_and_no_heavy_library(tmp_path):
    mods = loaded_after("from deint_env.cli import main\nassert main(['--help']) == 0", tmp_path)
    assert "deint_env.cli" in mods and not heavy(mods), heavy(mods)
    assert not {m for m in mods if m.split(".")[0] in ("baselines", "agents")}


def test_deint_policies_imports_the_providers_but_no_algorithm(tmp_path):
    mods = loaded_after("from deint_env.cli import main\nassert main(['policies']) == 0", tmp_path)
    assert {"baselines", "agents"} <= mods and not heavy(mods), heavy(mods)
    assert not {m for m in mods if m.startswith(("baselines.", "agents."))}


def test_labelling_imports_only_what_the_policy_needs(tmp_path):
    """`deint label` with a policy without kernels loads no numba (scipy: the env's metrics use its
    assignment solver); building one with kernels loads numba but not scikit-learn or torch."""
    plain = loaded_after("from deint_env.cli import main\n"
                         "assert main(['simulate', 'core-v0/core-n2-spread4-jitter0.05', '--seed', '0', '-o', 'p.csv', "
                         "'--priors-out', 'p.json']) == 0\n"
                         "assert main(['label', 'p.csv', '--priors', 'p.json', '--policy', 'pt-post', "
                         "'-o', 'l.csv']) == 0",
                         tmp_path)
    assert "baselines.pt" in plain and not {"numba", "sklearn", "torch"} & {m.split(".")[0] for m in plain}
    compiled = loaded_after("from deint_env.policies import make_policy\nmake_policy('fdp')", tmp_path)
    assert "numba" in compiled and not {"sklearn", "torch"} & {m.split(".")[0] for m in compiled}


def test_density_clustering_labels_without_scikit_learn(tmp_path):
    """`dbscan`, `hdbscan`, `pdw-hdbscan`, `pdw-pipeline` and the blind policies' descriptor presort
    (`cdif` on a file with PDWs) cluster with baselines/blind/density.py: no scikit-learn is loaded (its
    `sklearn.cluster` import alone takes about 1 s)."""
    mods = loaded_after("from deint_env.cli import main\n"
                        "from deint_env.policies import make_policy\n"
                        "make_policy('pdw-pipeline')\n"
                        "assert main(['simulate', 'pdw-v0/pdw-staring-n5-blind', '--seed', '0', '-o', 'p.h5', "
                        "'--priors-out', 'p.json']) == 0\n"
                        "for policy in ('dbscan', 'hdbscan', 'pdw-hdbscan', 'cdif'):\n"
                        "    assert main(['label', 'p.h5', '--priors', 'p.json', '--policy', policy, "
                        "'-o', 'l.csv']) == 0",
                        tmp_path)
    assert {"baselines.blind.density", "baselines.pdw.pipeline"} <= mods
    assert "sklearn" not in {m.split(".")[0] for m in mods}


def test_labelling_loads_neither_the_runner_nor_the_installed_metadata(tmp_path):
    """`deint label` plays through `deint_env.play`, without the runner's process pool, progress bar and
    results files, and finds a shipped policy without reading the installed metadata (importlib.metadata:
    the entry points, read only for a name the shipped providers lack, and the version, read for
    `--version`).  `import deint_env` reads no metadata either, yet `deint_env.__version__` is there.
    (What the bare interpreter already holds, e.g. through a .pth file, is not counted.)"""
    bare = loaded_after("pass", tmp_path)
    mods = loaded_after("from deint_env.cli import main\n"
                        "assert main(['simulate', 'core-v0/core-n2-spread4-jitter0.05', '--seed', '0', '-o', 'p.csv', "
                        "'--priors-out', 'p.json']) == 0\n"
                        "assert main(['label', 'p.csv', '--priors', 'p.json', '--policy', 'random', "
                        "'-o', 'l.csv']) == 0",
                        tmp_path)
    unwanted = {"deint_env.runner", "deint_env.results", "importlib.metadata", "tqdm", "concurrent.futures"} - bare
    assert "deint_env.play" in mods and not unwanted & mods, sorted(unwanted & mods)
    plain = loaded_after("import deint_env\nassert deint_env.__version__", tmp_path)
    assert "importlib.metadata" in plain  # read on first use of __version__
    if "importlib.metadata" not in bare:
        assert "importlib.metadata" not in loaded_after("import deint_env", tmp_path)


def test_the_command_defers_numpy_modules_it_never_uses(tmp_path):
    """`deint label` with a compiled policy imports scipy.linalg through numba, whose array-API shim
    touches numpy.f2py and numpy.testing; the command leaves them unexecuted (lazy) yet usable."""
    code = ("from deint_env.cli import main\n"
            "assert main(['simulate', 'core-v0/core-n2-spread4-jitter0.05', '--seed', '0', '-o', 'p.csv', "
            "'--priors-out', 'p.json']) == 0\n"
            "assert main(['label', 'p.csv', '--priors', 'p.json', '--policy', 'fdp', '-o', 'l.csv']) == 0\n"
            "import importlib.util, numpy\n"
            "assert 'scipy.linalg' in sys.modules\n"
            "lazy = {n: isinstance(sys.modules[n], importlib.util._LazyModule) for n in ('numpy.f2py', 'numpy.testing')}\n"
            "assert lazy == {'numpy.f2py': True, 'numpy.testing': True}, lazy\n"
            "numpy.testing.assert_equal(1, 1)  # executed on first use\n"
            "assert callable(numpy.f2py.run_main)\n")
    mods = loaded_after(code, tmp_path)
    assert "numpy.f2py.crackfortran" in mods  # loaded by the use above, not before


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))  # dunders are public


def test_no_module_imports_a_private_name_of_another_package():
    """A name with a leading underscore is private to its top-level package: agents/ may use baselines'
    public kernel API (e.g. `baselines.mht.step`), never `baselines.mht.kernels._future`."""
    bad = []
    for name, path in modules().items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            top = base.split(".")[0]
            if top in PACKAGES and top != name.split(".")[0]:
                bad += [f"{name}: from {base} import {a.name}" for a in node.names
                        if _private(a.name) or any(_private(p) for p in base.split("."))]
    assert not bad, bad


def test_the_private_import_check_sees_private_imports():
    """The check above can fail: the old lmht import of mht's private kernels is caught."""
    old = "from baselines.mht import (MHT, _count, _step)\nfrom baselines.mht import step\n"
    names = [a.name for node in ast.walk(ast.parse(old)) if isinstance(node, ast.ImportFrom) for a in node.names]
    assert [n for n in names + ["__version__"] if _private(n)] == ["_count", "_step"]

"""numba's on-disk cache, made to notice the other files a kernel module compiles in.

numba keys a cached kernel to its own file's timestamp and size only, but compiles its callees into it
(and freezes module constants): a kernel of baselines/mht/kernels.py that inlines `kf_update` of
baselines/kalman_jit.py kept the old filter after kalman_jit.py changed.  `guard(globals())`, the last line of
a kernel module that compiles in code or constants of other files, hashes the source of every project module (or module holding kernels) it imports from
(`from X import ...`; and, transitively, those such modules holding kernels import from) and, when the
hash differs from the stamp stored beside the module's cache, empties the module's cache index before
anything compiles.
Compiled helpers are therefore imported by name from their module, never reached as `module.name`.
Finding the dependencies parses sources (tens of ms per module at every start-up), so the stamp also
records them with the hash of the module's own source: while neither changed, `guard` only hashes files.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

PROJECT = ("baselines", "agents", "deint_env")


def kernels(namespace: dict[str, Any]) -> list[Any]:
    """The numba dispatchers a module defines (not those it imports)."""
    name = namespace["__name__"]
    return [v for v in namespace.values() if hasattr(v, "py_func") and v.py_func.__module__ == name]


def _imported(path: Path, package: str) -> set[str]:
    """The modules `path` imports names from (relative imports resolved against `package`)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            out.add(base)
    return out


def _source(name: str) -> Path | None:
    spec = importlib.util.find_spec(name)
    return Path(spec.origin) if spec is not None and spec.origin and spec.origin.endswith(".py") else None


def _holds_kernels(name: str) -> bool:
    module = sys.modules.get(name)
    return isinstance(module, ModuleType) and bool(kernels(vars(module)))


def dependencies(name: str, path: Path) -> list[Path]:
    """The source files whose change makes module `name`'s cached kernels stale, besides its own."""
    return sorted(set(_dependencies(name, path).values()))


def _dependencies(name: str, path: Path) -> dict[str, Path]:
    """Module name -> source file of each of `dependencies`."""
    seen: dict[str, Path] = {}
    todo = [(name, path)]
    while todo:
        mod, file = todo.pop()
        package = mod if file.name == "__init__.py" else mod.rpartition(".")[0]
        for dep in sorted(_imported(file, package)):
            if dep in seen or dep == __name__ or not (dep.split(".")[0] in PROJECT or _holds_kernels(dep)):
                continue
            src = _source(dep)
            if src is None or src == path:
                continue
            seen[dep] = src
            if _holds_kernels(dep):  # its kernels' own callees are compiled into ours too
                todo.append((dep, src))
    return seen


def digest(paths: list[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def guard(namespace: dict[str, Any]) -> bool:
    """Empty the cache index of the module's kernels when its dependencies' sources changed since the
    stamp; returns whether it did.  A no-op without cached kernels (e.g. NUMBA_DISABLE_JIT=1)."""
    cached = [k for k in kernels(namespace) if getattr(k, "_cache", None) is not None
              and hasattr(k._cache, "cache_path")]
    if not cached:
        return False
    name, path = namespace["__name__"], Path(namespace["__file__"])
    stamp = Path(cached[0]._cache.cache_path) / f"{path.stem}.deps-sha256"
    try:  # {"module": own source's hash, "deps": the dependencies' module names, "sha256": their sources' hash}
        recorded = json.loads(stamp.read_text())
        files = [_source(dep) for dep in recorded["deps"]]
        # the dependencies follow from the module's source and theirs: both unchanged, nothing to parse
        if None not in files and digest([path]) == recorded["module"] and \
                digest(sorted(set(files))) == recorded["sha256"]:
            return False
    except (OSError, ValueError, KeyError, TypeError, ImportError):  # no stamp, an unreadable one, a lost module
        recorded = {}
    deps = _dependencies(name, path)
    want = digest(sorted(set(deps.values())))
    flushed = want != recorded.get("sha256")
    if flushed:
        for k in cached:
            k._cache.flush()
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(json.dumps({"module": digest([path]), "deps": sorted(deps), "sha256": want}))
    except OSError:  # a read-only cache: numba then recompiles in memory anyway
        pass
    return flushed

"""Start-up and first-call times of the `deint` command (issue 22, item 4; target: under 1 s warm).

Each figure is the wall time of a fresh process (the CPU time it used beside it: the wall time on a
busy machine is the CPU time stretched by the other load):
1. `deint --help` and `python -c "import deint_env"`;
2. `deint label` of a 1000-pulse file by every reference policy of the registry (`deint policies`):
   anchored ones on a core-v0 episode with its priors file, blind-only ones on a blind-v0 episode with
   its blind priors file, the pdw-* ones on pdw-v0's 5-emitter staring scenario cut to 1000 pulses and
   written as a challenge file (their descriptors); `tree` on that core-v0 scenario cut to its limit of
   20 pulses (it cannot label 1000).  Cold: a fresh numba cache (NUMBA_CACHE_DIR a new temporary
   folder: every kernel the policy calls is compiled); warm: the median of --repeats runs on the cache
   the cold run filled.  "Warm" means numba's cache and Python's bytecode cache are both filled: the
   child processes run without PYTHONDONTWRITEBYTECODE (removed from their environment if this shell
   sets it), so they write and reuse .pyc files as a user's install does, and every figure follows one
   untimed run.  The `notice` column says whether the run printed deint's "compiling ..." line (it
   should, cold, for a policy with numba kernels, and never warm).
3. For scale, the floor any numba-compiled policy pays: a fresh process importing numba and calling one
   trivial kernel from a warm cache (numba's import, its BLAS check importing scipy.linalg, and the set-up
   of its code generator on the first cached load).

Policies that need an input a pulse file cannot give (an adapter's model) are listed as skipped;
genie is labelled from the true priors file.  Learned agents are not reference policies (their
start-up is torch's: benchmarks/bench_agent.py).  Prints figures; asserts nothing.

    python benchmarks/bench_startup.py [--repeats 5] [--policies fdp,cdif] [--no-cold]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from deint_env.policies import list_policies
from deint_env.suites import resolve_scenario

ANCHORED_SCENARIO = "core-v0/core-n4-spread4-jitter0.2"
BLIND_SCENARIO = "blind-v0/blind-n3to3-jitter0.1"
PDW_SCENARIO = "pdw-v0/pdw-staring-n5-blind"  # cut to 1000 pulses, written as a challenge (HDF5) file
TARGET = 1.0  # seconds, warm
DEINT = shutil.which("deint", path=str(Path(sys.executable).parent)) or shutil.which("deint")
# The children's environment: bytecode is written and reused, as in a user's install (a shell that sets
# PYTHONDONTWRITEBYTECODE would make every run recompile deint's sources)
CHILD_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def timed(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float, subprocess.CompletedProcess]:
    """(wall s, CPU s, the finished process) of one fresh process (environment `env`, else CHILD_ENV)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env or CHILD_ENV)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), out


def median_of(cmd: list[str], repeats: int, env: dict[str, str] | None = None) -> tuple[float, float, list]:
    """Medians of `repeats` timed runs after one untimed run (which fills the bytecode cache)."""
    subprocess.run(cmd, capture_output=True, env=env or CHILD_ENV)
    runs = [timed(cmd, env) for _ in range(repeats)]
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs), [r[2] for r in runs]


def simulate_files(folder: Path) -> dict[str, tuple[str, str, str]]:
    """kind -> (pulse file, priors file, true priors file) of the episodes the policies label."""
    files = {}
    short = resolve_scenario(ANCHORED_SCENARIO).to_dict() | {"n_pulses": 20, "name": "startup-tree"}
    (folder / "tree-scenario.json").write_text(json.dumps(short))
    pdw = resolve_scenario(PDW_SCENARIO).to_dict() | {"n_pulses": 1000, "name": "startup-pdw"}
    (folder / "pdw-scenario.json").write_text(json.dumps(pdw))
    for kind, scenario in (("anchored", ANCHORED_SCENARIO), ("blind", BLIND_SCENARIO),
                           ("tree", str(folder / "tree-scenario.json")), ("pdw", str(folder / "pdw-scenario.json"))):
        pulses, priors, true = (str(folder / f"{kind}{suffix}")
                                for suffix in (".h5" if kind == "pdw" else ".csv", ".json", "-true.json"))
        subprocess.run([DEINT, "simulate", scenario, "--seed", "0", "-o", pulses, "--priors-out", priors,
                        "--true-priors-out", true], check=True, capture_output=True, env=CHILD_ENV)
        files[kind] = (pulses, priors, true)
    return files


def label_command(info, files, out: str) -> tuple[list[str], str] | None:
    if info.required:
        return None
    kind = ("tree" if info.limits.max_pulses is not None else "pdw" if info.name.startswith("pdw-")
            else "anchored" if "anchored" in info.modes else "blind")
    pulses, priors, true = files[kind]
    what = {"tree": f"{ANCHORED_SCENARIO} cut to 20 pulses", "anchored": ANCHORED_SCENARIO,
            "blind": BLIND_SCENARIO, "pdw": f"{PDW_SCENARIO} cut to 1000 pulses (.h5)"}[kind] + \
        (" (true priors)" if info.oracle else "")
    return [DEINT, "label", pulses, "--priors", true if info.oracle else priors, "--policy", info.name, "-o", out], what


def said_compiling(proc: subprocess.CompletedProcess) -> bool:
    return "deint: compiling" in proc.stderr


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5, help="warm runs per figure (their median; default 5)")
    ap.add_argument("--policies", help="only these policies (comma-separated)")
    ap.add_argument("--no-cold", action="store_true",
                    help="skip the cold runs (each compiles a policy's kernels); warm runs use numba's usual cache")
    args = ap.parse_args()
    if DEINT is None:
        sys.exit("bench_startup: no `deint` command beside this Python or on PATH (pip install -e .)")
    print(f"# deint start-up: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start; "
          f"wall (CPU) seconds of fresh processes, warm = median of {args.repeats}")
    for what, cmd in (("python -c pass", [sys.executable, "-c", "pass"]),
                      ("python -c 'import numpy' (for scale)", [sys.executable, "-c", "import numpy"]),
                      ("python -c 'import deint_env'", [sys.executable, "-c", "import deint_env"]),
                      ("deint --help", [DEINT, "--help"])):
        wall, cpu, _ = median_of(cmd, args.repeats)
        print(f"{what:<40} {wall:6.2f} s ({cpu:.2f} s CPU)")
    with tempfile.TemporaryDirectory(prefix="deint-numba-floor-") as tmp:
        (Path(tmp) / "floor_kernel.py").write_text(
            "import numba\n\n@numba.njit(cache=True)\ndef one(x):\n    return x + 1.0\n")
        cmd = [sys.executable, "-c",
               f"import sys; sys.path.insert(0, {tmp!r}); import floor_kernel; floor_kernel.one(1.0)"]
        subprocess.run(cmd, check=True, env=dict(CHILD_ENV, NUMBA_CACHE_DIR=tmp))  # fills the cache
        wall, cpu, _ = median_of(cmd, args.repeats, dict(CHILD_ENV, NUMBA_CACHE_DIR=tmp))
        print(f"{'numba floor: one cached kernel':<40} {wall:6.2f} s ({cpu:.2f} s CPU)")

    wanted = set(args.policies.split(",")) if args.policies else None
    infos = [p for p in list_policies() if p.kind in ("reference", "oracle", "adapter")
             and (wanted is None or p.name in wanted)]
    rows, skipped = [], []
    with tempfile.TemporaryDirectory(prefix="deint-startup-") as tmp:
        folder = Path(tmp)
        files = simulate_files(folder)
        for info in infos:
            made = label_command(info, files, str(folder / f"{info.name}.labels.csv"))
            if made is None:
                skipped.append(f"{info.name} ({info.kind}: needs {', '.join(info.required)}=...)")
                continue
            cmd, what = made
            if args.no_cold:  # numba's cache as it is, filled by median_of's untimed run if it is not yet
                env, cold = None, None
            else:
                env = dict(CHILD_ENV, NUMBA_CACHE_DIR=str(folder / f"numba-{info.name}"))
                cold = timed(cmd, env)
            wall, cpu, procs = median_of(cmd, args.repeats, env)
            failed = next((p for p in ([cold[2]] if cold else []) + procs if p.returncode != 0), None)
            if failed is not None:
                rows.append([info.name, what, "-", "-", "-", "-", "failed: " + failed.stderr.strip()[-120:]])
                continue
            notice = ("-" if cold is None else "yes" if said_compiling(cold[2]) else "no") + \
                " / " + ("yes" if any(map(said_compiling, procs)) else "no")
            rows.append([info.name, what, "-" if cold is None else f"{cold[0]:.2f} ({cold[1]:.2f})",
                         f"{wall:.2f} ({cpu:.2f})", "yes" if wall < TARGET else "no", notice, ""])
            print(f"  {info.name}: done", file=sys.stderr)
    head = ["policy", "file", "cold s (CPU)", "warm s (CPU)", f"warm < {TARGET:g} s", "notice cold / warm", ""]
    widths = [max(len(str(r[i])) for r in rows + [head]) for i in range(len(head))]
    print()
    for r in [head, ["-" * w for w in widths]] + rows:
        print("  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip())
    if skipped:
        print("skipped: " + "; ".join(skipped))
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
